//! Sweeps: members in their places (grid order, zip), each equal to a run of the scene loaded
//! with the same overrides, the same numbers whatever the threads or chunks, and failed
//! members that do not stop the others.

use std::sync::Arc;

mod common;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::plan::{Plan, PlanRequest};
use bead::scene::Scene;
use bead::simulate::{run, Event, NullSink, RunStats, Simulation};
use bead::sweep::{Axis, Combine, Member, Sweep, SweepError};

fn scene() -> Scene {
    Scene::parse(common::PARABOLA_SWEPT, "parabola.toml", &[]).unwrap()
}

/// rk4 at dt = 1/60 for `steps` steps.
fn request(method: Method, steps: u64) -> PlanRequest {
    PlanRequest {
        method: Some(method),
        integrator: Some(IntegratorKind::Rk4),
        dt: Some(1.0 / 60.0),
        steps: Some(steps),
        ..Default::default()
    }
}

/// Stats without the wall time, the one figure that differs between runs.
fn figures(stats: &RunStats) -> RunStats {
    RunStats {
        wall_seconds: 0.0,
        ..stats.clone()
    }
}

fn same(a: &[Member], b: &[Member]) {
    assert_eq!(a.len(), b.len());
    for (a, b) in a.iter().zip(b) {
        assert_eq!(a.index, b.index);
        assert_eq!(a.params, b.params);
        assert_eq!(a.error, b.error);
        assert_eq!(a.stats.as_ref().map(figures), b.stats.as_ref().map(figures));
    }
}

#[test]
fn grid_members_are_in_row_major_order_first_axis_outermost() {
    let sweep = Sweep::new(
        &scene(),
        vec![
            Axis::linspace("x0", 10.0, 30.0, 3).unwrap(),
            Axis {
                name: "g".into(),
                values: vec![100.0, 200.0],
            },
        ],
        Combine::Grid,
        request(Method::Implicit, 120),
        None,
    )
    .unwrap();
    assert_eq!(sweep.len(), 6);
    assert_eq!(sweep.shape(), &[3, 2]);
    let expected = [
        [10.0, 100.0],
        [10.0, 200.0],
        [20.0, 100.0],
        [20.0, 200.0],
        [30.0, 100.0],
        [30.0, 200.0],
    ];
    for (i, values) in expected.iter().enumerate() {
        assert_eq!(sweep.params_of(i), values.to_vec());
    }
    let members = sweep.run(2);
    for (i, m) in members.iter().enumerate() {
        assert_eq!(m.index, i);
        assert_eq!(m.params, expected[i].to_vec());
        assert_eq!(m.status(), "ok");
        // The initial energy follows the member's values: V = m g x0^2 / 100 at rest.
        let stats = m.stats.as_ref().unwrap();
        let [x0, g] = expected[i];
        assert!((stats.energy_initial - g * x0 * x0 / 100.0).abs() < 1e-9 * stats.energy_scale);
    }
}

#[test]
fn zipped_members_take_the_values_side_by_side() {
    let sweep = Sweep::new(
        &scene(),
        vec![
            Axis::linspace("x0", 10.0, 40.0, 4).unwrap(),
            Axis::linspace("g", 400.0, 100.0, 4).unwrap(),
        ],
        Combine::Zip,
        request(Method::Parametric, 120),
        None,
    )
    .unwrap();
    assert_eq!(sweep.shape(), &[4]);
    let members = sweep.run(1);
    let params: Vec<Vec<f64>> = members.iter().map(|m| m.params.clone()).collect();
    assert_eq!(
        params,
        vec![
            vec![10.0, 400.0],
            vec![20.0, 300.0],
            vec![30.0, 200.0],
            vec![40.0, 100.0]
        ]
    );
    let error = Sweep::new(
        &scene(),
        vec![
            Axis::linspace("x0", 10.0, 40.0, 4).unwrap(),
            Axis::linspace("g", 400.0, 100.0, 3).unwrap(),
        ],
        Combine::Zip,
        request(Method::Parametric, 120),
        None,
    )
    .unwrap_err();
    assert_eq!(
        error.to_string(),
        "zipped parameters must have the same number of values: `x0` has 4, `g` has 3"
    );
}

#[test]
fn linspace_is_numpys() {
    // numpy.linspace(10, 200, 7): start + i * step, the last exactly stop.
    let axis = Axis::linspace("x0", 10.0, 200.0, 7).unwrap();
    let step = 190.0 / 6.0;
    let expected: Vec<f64> = (0..7)
        .map(|i| {
            if i == 6 {
                200.0
            } else {
                i as f64 * step + 10.0
            }
        })
        .collect();
    assert_eq!(axis.values, expected);
    assert_eq!(Axis::linspace("a", 3.0, 9.0, 1).unwrap().values, vec![3.0]);
    assert_eq!(
        Axis::linspace("a", 3.0, 9.0, 0).unwrap_err(),
        SweepError::NoValues { name: "a".into() }
    );
    assert!(Axis::linspace("a", f64::NAN, 9.0, 3).is_err());
}

/// A member is the scene loaded with its values as overrides and run as `config` says: the
/// same numbers as that run, bit for bit, for both methods and with a stop condition.
#[test]
fn a_member_equals_a_run_of_the_scene_loaded_with_its_values() {
    for method in [Method::Implicit, Method::Parametric] {
        let stop_when = "-bead.x";
        let sweep = Sweep::new(
            &scene(),
            vec![Axis::linspace("x0", 10.0, 200.0, 5).unwrap()],
            Combine::Grid,
            request(method, 600),
            Some(stop_when.into()),
        )
        .unwrap();
        let members = sweep.run(2);
        for member in &members {
            let alone = Scene::parse(
                common::PARABOLA_SWEPT,
                "parabola.toml",
                &[("x0".into(), member.params[0])],
            )
            .unwrap();
            let plan = Plan::resolve(&alone, &request(method, 600)).unwrap();
            let mut simulation =
                Simulation::new(Arc::clone(&alone.system), plan.config(method)).unwrap();
            simulation
                .set_stop_when(Some(Event::parse(&alone.system, stop_when).unwrap()))
                .unwrap();
            let stats = run(&mut simulation, plan.options(), &mut NullSink).unwrap();
            let swept = member.stats.as_ref().unwrap();
            assert_eq!(figures(swept), figures(&stats));
            // Every member reaches the bottom (x = 0) at a quarter of its period.
            assert!(swept.stop_time.is_some());
            assert_eq!(member.status(), "event");
        }
    }
}

#[test]
fn results_do_not_depend_on_threads_or_chunks() {
    let sweep = Sweep::new(
        &scene(),
        vec![
            Axis::linspace("x0", 10.0, 200.0, 5).unwrap(),
            Axis::linspace("g", 100.0, 900.0, 2).unwrap(),
        ],
        Combine::Grid,
        request(Method::Implicit, 600),
        Some("bead.y + x0^2/200".into()),
    )
    .unwrap();
    let one = sweep.run(1);
    let two = sweep.run(2);
    same(&one, &two);
    let mut chunked = Vec::new();
    let mut start = 0;
    while start < sweep.len() {
        let end = (start + 3).min(sweep.len());
        chunked.extend(sweep.run_range(start..end, 2).unwrap());
        start = end;
    }
    same(&one, &chunked);
    // The stop condition fired in every member (the bead descends through half its height).
    for m in &one {
        assert_eq!(m.status(), "event", "{:?}", m.params);
    }
    let csv = |members: &[Member]| {
        let mut out = Vec::new();
        sweep.write_csv(members, &mut out).unwrap();
        String::from_utf8(out).unwrap()
    };
    assert_eq!(csv(&one), csv(&chunked));
    assert!(matches!(
        sweep.run_range(8..11, 1),
        Err(SweepError::OutOfRange { .. })
    ));
}

#[test]
fn a_failed_member_does_not_stop_the_sweep() {
    let sweep = Sweep::new(
        &scene(),
        vec![Axis {
            name: "mass".into(),
            values: vec![1.0, -1.0, 2.0],
        }],
        Combine::Grid,
        request(Method::Implicit, 120),
        None,
    )
    .unwrap();
    let members = sweep.run(2);
    assert_eq!(members[0].status(), "ok");
    assert_eq!(members[1].status(), "failed");
    assert!(members[1].stats.is_none());
    let error = members[1].error.as_deref().unwrap();
    assert!(error.contains("mass"), "{error}");
    assert_eq!(members[2].status(), "ok");
    // Its CSV row has the values and the error, and empty figures.
    let row = sweep.csv_row(&members[1]);
    let columns = sweep.csv_header().split(',').count();
    assert!(row.starts_with("1,-1,failed,,,"), "{row}");
    assert!(row.len() > columns);
}

#[test]
fn unknown_and_repeated_parameters_are_refused() {
    let make = |axes: Vec<Axis>| {
        Sweep::new(
            &scene(),
            axes,
            Combine::Grid,
            request(Method::Implicit, 120),
            None,
        )
        .unwrap_err()
        .to_string()
    };
    assert_eq!(
        make(vec![Axis::linspace("h", 1.0, 2.0, 2).unwrap()]),
        "unknown parameter `h`; the scene's parameters are g, x0, mass"
    );
    assert_eq!(
        make(vec![
            Axis::linspace("g", 1.0, 2.0, 2).unwrap(),
            Axis::linspace("g", 1.0, 2.0, 2).unwrap()
        ]),
        "`g` is swept twice"
    );
    assert_eq!(make(vec![]), "a sweep needs at least one parameter to vary");
}

#[test]
fn csv_has_a_column_per_parameter_state_and_coordinate() {
    let sweep = Sweep::new(
        &scene(),
        vec![Axis::linspace("x0", 10.0, 20.0, 2).unwrap()],
        Combine::Grid,
        request(Method::Parametric, 120),
        None,
    )
    .unwrap();
    assert_eq!(
        sweep.csv_header(),
        "member,x0,status,t_final,stop_time,steps,energy_error_max,constraint_error_max,bead.x,bead.y,bead.vx,bead.vy,q.q,qdot.q,error"
    );
    let members = sweep.run(1);
    let row = sweep.csv_row(&members[1]);
    let fields: Vec<&str> = row.split(',').collect();
    assert_eq!(fields.len(), 15);
    let stats = members[1].stats.as_ref().unwrap();
    assert_eq!(fields[0], "1");
    assert_eq!(fields[1].parse::<f64>().unwrap(), 20.0);
    assert_eq!(fields[2], "ok");
    assert_eq!(fields[3].parse::<f64>().unwrap(), stats.t_final);
    assert_eq!(fields[4], "");
    assert_eq!(fields[5].parse::<u64>().unwrap(), 120);
    assert_eq!(fields[8].parse::<f64>().unwrap(), stats.x[0]);
    assert_eq!(fields[13].parse::<f64>().unwrap(), stats.qdot[0]);
    assert_eq!(fields[14], "");
}

/// Without a stop condition of its own, a sweep uses each member's `[run] stop_when`, and
/// `[run]` values written with a swept parameter follow the member, as `bead run --set`.
#[test]
fn the_scenes_run_table_follows_each_member() {
    let text = format!(
        "{}[run]\nstop_when = \"bead.y + x0^2/200\"\nsteps = \"x0\"\n",
        common::PARABOLA_SWEPT
    );
    let scene = Scene::parse(&text, "parabola.toml", &[]).unwrap();
    let sweep = Sweep::new(
        &scene,
        vec![Axis {
            name: "x0".into(),
            values: vec![3.0, 150.0],
        }],
        Combine::Grid,
        PlanRequest::default(),
        None,
    )
    .unwrap();
    let members = sweep.run(2);
    // x0 = 3: 3 steps of 1/60 s, too short to descend to half the height.
    let short = members[0].stats.as_ref().unwrap();
    assert_eq!((short.steps, short.stop_time), (3, None));
    // x0 = 150: the event fires where y = -x0^2/200 (x^2 = x0^2 / 2).
    let long = members[1].stats.as_ref().unwrap();
    assert!(long.stop_time.is_some());
    // (to the implicit form's drift off the curve at this dt)
    assert!(
        (long.x[0].abs() - 150.0 / 2f64.sqrt()).abs() < 1e-4,
        "{}",
        long.x[0]
    );
}
