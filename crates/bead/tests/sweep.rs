//! Sweeps: members in their places (grid order, zip), each equal to a run of the scene loaded
//! with the same overrides, the same numbers whatever the threads or chunks, and failed
//! members that do not stop the others.

use std::sync::Arc;
use std::time::Instant;

mod common;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::output::Trajectory;
use bead::plan::{Plan, PlanRequest};
use bead::scene::Scene;
use bead::simulate::{run, run_at_times, Event, NoProgress, NullSink, RunStats, Simulation};
use bead::sweep::{Axis, Combine, CsvFormat, Member, Recording, Sweep, SweepError};

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
        assert_eq!(a.layout, b.layout);
        assert_eq!(a.stats.as_ref().map(figures), b.stats.as_ref().map(figures));
    }
}

#[test]
fn grid_members_are_in_row_major_order_first_axis_outermost() {
    let sweep = Sweep::new(
        &scene(),
        vec![
            Axis::linspace("x0", 10.0, 30.0, 3).unwrap(),
            Axis::new("g", vec![100.0, 200.0]),
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
    let members = sweep.run(2).unwrap();
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
    let members = sweep.run(1).unwrap();
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
    assert_eq!(axis.values().collect::<Vec<_>>(), expected);
    assert_eq!(
        Axis::linspace("a", 3.0, 9.0, 1)
            .unwrap()
            .values()
            .collect::<Vec<_>>(),
        vec![3.0]
    );
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
        let members = sweep.run(2).unwrap();
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
    let one = sweep.run(1).unwrap();
    let two = sweep.run(2).unwrap();
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
        sweep.write_csv(CsvFormat::Wide, members, &mut out).unwrap();
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
        vec![Axis::new("mass", vec![1.0, -1.0, 2.0])],
        Combine::Grid,
        request(Method::Implicit, 120),
        None,
    )
    .unwrap();
    let members = sweep.run(2).unwrap();
    assert_eq!(members[0].status(), "ok");
    assert_eq!(members[1].status(), "failed");
    assert!(members[1].stats.is_none());
    let error = members[1].error.as_deref().unwrap();
    assert!(error.contains("mass"), "{error}");
    assert_eq!(members[2].status(), "ok");
    // Its CSV row has the values and the error, and empty figures.
    let row = sweep.csv_row(&members[1]).unwrap();
    let columns = sweep.csv_header().split(',').count();
    assert_eq!(fields_before_error(&row, columns), "1,-1,failed", "{row}");
    // The long format's one row for it, as wide as its header too.
    let long = sweep.long_csv_rows(&members[1]);
    let long_columns = sweep.long_csv_header().split(',').count();
    assert_eq!(
        fields_before_error(&long, long_columns),
        "1,-1,failed",
        "{long}"
    );
}

/// A row of `columns` fields whose last is an error message (which may hold commas):
/// its leading non-empty fields, after checking that every field between them and the
/// error is empty and the error is where the header says.
fn fields_before_error(row: &str, columns: usize) -> String {
    let fields: Vec<&str> = row.splitn(columns, ',').collect();
    assert_eq!(fields.len(), columns, "{row}");
    let error = fields[columns - 1];
    assert!(!error.is_empty() && error.contains("mass"), "{row}");
    let filled = fields[..columns - 1]
        .iter()
        .take_while(|f| !f.is_empty())
        .count();
    assert!(
        fields[filled..columns - 1].iter().all(|f| f.is_empty()),
        "{row}"
    );
    fields[..filled].join(",")
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
        "unknown parameter `h`; the scene's parameters are g, x0, mass; or sweep the initial \
         state: NAME.x, NAME.vx (a particle's position and velocity), q.NAME, qdot.NAME (the \
         parametric form's)"
    );
    assert_eq!(
        make(vec![
            Axis::linspace("g", 1.0, 2.0, 2).unwrap(),
            Axis::linspace("g", 1.0, 2.0, 2).unwrap()
        ]),
        "`g` is swept twice"
    );
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
        "member,x0,status,t_final,stop_time,steps,energy_rel_error_max,energy_balance_error_max,constraint_error_max,newton_iterations,bead.x,bead.y,bead.vx,bead.vy,q.q,qdot.q,error"
    );
    let members = sweep.run(1).unwrap();
    let row = sweep.csv_row(&members[1]).unwrap();
    let fields: Vec<&str> = row.split(',').collect();
    assert_eq!(fields.len(), 17);
    let stats = members[1].stats.as_ref().unwrap();
    assert_eq!(fields[0], "1");
    assert_eq!(fields[1].parse::<f64>().unwrap(), 20.0);
    assert_eq!(fields[2], "ok");
    assert_eq!(fields[3].parse::<f64>().unwrap(), stats.t_final);
    assert_eq!(fields[4], "");
    assert_eq!(fields[5].parse::<u64>().unwrap(), 120);
    assert_eq!(
        fields[6].parse::<f64>().unwrap(),
        stats.energy_rel_error_max
    );
    // Nothing does work on the bead: no energy balance.
    assert_eq!(fields[7], "");
    assert_eq!(
        fields[8].parse::<f64>().unwrap(),
        stats.constraint_error_max
    );
    // rk4 solves nothing: no Newton iterations.
    assert_eq!((fields[9], stats.newton_iterations), ("", None));
    assert_eq!(fields[10].parse::<f64>().unwrap(), stats.x[0]);
    assert_eq!(fields[15].parse::<f64>().unwrap(), stats.qdot[0]);
    assert_eq!(fields[16], "");
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
        vec![Axis::new("x0", vec![3.0, 150.0])],
        Combine::Grid,
        PlanRequest::default(),
        None,
    )
    .unwrap();
    let members = sweep.run(2).unwrap();
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

/// A chain of N links hanging from the origin (rods of length 1, rattle's scene).
const CHAIN: &str = r#"title = "chain"
[params]
N = 3
g = 9.81
[world]
gravity = [0.0, "g"]
[[particle]]
for = { i = "0..N" }
name = "p{i}"
mass = 1.0
position = ["i+1", 0.0]
[[constraint]]
name = "pivot"
kind = "distance"
particle = "p0"
anchor = [0.0, 0.0]
length = 1.0
[[constraint]]
for = { i = "1..N" }
name = "rod {i}"
kind = "distance"
between = ["p{i-1}", "p{i}"]
length = 1.0
[run]
integrator = "rattle"
dt = 0.01
"#;

/// A sweep over the number of links refuses, in the wide CSV, the first member whose
/// particles are not the scene's, with the rows before it written; the long CSV has every
/// member's own coordinates, each row as long as the header.
#[test]
fn sweep_csv_refuses_members_with_another_particle_count() {
    let scene = Scene::parse(CHAIN, "chain.toml", &[]).unwrap();
    let sweep = Sweep::new(
        &scene,
        vec![Axis::new("N", vec![3.0, 2.0, 4.0])],
        Combine::Grid,
        PlanRequest {
            steps: Some(5),
            ..Default::default()
        },
        None,
    )
    .unwrap();
    let members = sweep.run(2).unwrap();
    assert!(members.iter().all(|m| m.status() == "ok"), "{members:?}");
    assert_eq!(members[0].layout, None);
    let other = members[1].layout.as_deref().unwrap();
    assert_eq!(other.particles, ["p0", "p1"]);
    assert_eq!(members[2].layout.as_ref().unwrap().particles.len(), 4);
    let refused = sweep.csv_row(&members[1]).unwrap_err();
    assert!(matches!(refused, SweepError::OtherLayout { index: 1, .. }));
    assert_eq!(
        refused.to_string(),
        "member 1 (N = 2) has 2 particles (p0, p1), where the scene swept has 3 (p0, p1, p2)"
    );
    // write_csv stops at that member: the header and member 0's row, each of the header's width.
    let mut out = Vec::new();
    let error = sweep
        .write_csv(CsvFormat::Wide, &members, &mut out)
        .unwrap_err();
    assert!(matches!(
        error,
        bead::sweep::CsvError::Member(SweepError::OtherLayout { index: 1, .. })
    ));
    let text = String::from_utf8(out).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(lines.len(), 2);
    let width = lines[0].split(',').count();
    assert_eq!(width, 1 + 1 + 8 + 4 * 3 + 1);
    assert_eq!(lines[1].split(',').count(), width);
    // Long: one row per member and coordinate, named after the member's own particles.
    let mut out = Vec::new();
    sweep
        .write_csv(CsvFormat::Long, &members, &mut out)
        .unwrap();
    let text = String::from_utf8(out).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert_eq!(
        lines[0],
        "member,N,status,t_final,stop_time,steps,energy_rel_error_max,energy_balance_error_max,constraint_error_max,newton_iterations,coordinate,position,velocity,error"
    );
    assert_eq!(lines.len(), 1 + 2 * (3 + 2 + 4));
    for line in &lines[1..] {
        assert_eq!(line.split(',').count(), 14, "{line}");
    }
    let rows_of = |index: usize| -> Vec<Vec<&str>> {
        lines[1..]
            .iter()
            .map(|l| l.split(',').collect::<Vec<_>>())
            .filter(|f| f[0] == index.to_string())
            .collect()
    };
    for (index, n) in [(0, 3), (1, 2), (2, 4)] {
        let rows = rows_of(index);
        let stats = members[index].stats.as_ref().unwrap();
        assert_eq!(rows.len(), 2 * n);
        for (k, row) in rows.iter().enumerate() {
            let axis = ["x", "y"][k % 2];
            assert_eq!(row[10], format!("p{}.{axis}", k / 2));
            assert_eq!(
                row[11].parse::<f64>().unwrap().to_bits(),
                stats.x[k].to_bits()
            );
            assert_eq!(
                row[12].parse::<f64>().unwrap().to_bits(),
                stats.xdot[k].to_bits()
            );
            assert_eq!(row[5], "5");
            // The chain's plan steps it with rattle: its Newton iterations, one a step at
            // least.
            let newton = stats.newton_iterations.expect("rattle solves");
            assert!(newton >= 5);
            assert_eq!(row[9].parse::<u64>().unwrap(), newton);
        }
    }
}

/// A parametric member with other generalized coordinates does not fit either; a member
/// that could not start is one long row with empty coordinate columns.
#[test]
fn long_csv_rows_of_parametric_and_failed_members() {
    let sweep = Sweep::new(
        &scene(),
        vec![Axis::new("mass", vec![1.0, -1.0])],
        Combine::Grid,
        request(Method::Parametric, 3),
        None,
    )
    .unwrap();
    let members = sweep.run(1).unwrap();
    let rows = sweep.long_csv_rows(&members[0]);
    let names: Vec<&str> = rows
        .lines()
        .map(|l| l.split(',').nth(10).unwrap())
        .collect();
    assert_eq!(names, ["bead.x", "bead.y", "q.q"]);
    let stats = members[0].stats.as_ref().unwrap();
    let q_row: Vec<&str> = rows.lines().nth(2).unwrap().split(',').collect();
    assert_eq!(q_row[11].parse::<f64>().unwrap(), stats.q[0]);
    assert_eq!(q_row[12].parse::<f64>().unwrap(), stats.qdot[0]);
    let failed = sweep.long_csv_rows(&members[1]);
    assert_eq!(failed.lines().count(), 1);
    let columns = sweep.long_csv_header().split(',').count();
    assert_eq!(
        fields_before_error(&failed, columns),
        "1,-1,failed",
        "{failed}"
    );
}

/// Counts past [`MAX_MEMBERS`] (one axis, a grid whose product passes it or overflows u64)
/// are an error at once, and a linspace of any count costs no memory.
#[test]
fn sweep_count_beyond_limit_is_an_error_not_an_abort() {
    use bead::sweep::MAX_MEMBERS;
    let make = |axes: Vec<Axis>, combine: Combine| {
        Sweep::new(&scene(), axes, combine, request(Method::Implicit, 1), None)
    };
    let huge = Axis::linspace("x0", 1.0, 2.0, usize::MAX).unwrap();
    assert_eq!(huge.len(), usize::MAX);
    assert_eq!(huge.value(usize::MAX - 1), 2.0);
    assert_eq!(
        make(vec![huge.clone()], Combine::Grid).unwrap_err().to_string(),
        format!(
            "the sweep would have {} members, more than the 4294967296 (2^32) a sweep may have; sweep fewer values, or cut the values into several sweeps",
            usize::MAX
        )
    );
    let half = Axis::linspace("g", 1.0, 2.0, 1 << 32).unwrap();
    let two = Axis::linspace("x0", 1.0, 2.0, 2).unwrap();
    assert!(matches!(
        make(vec![two.clone(), half.clone()], Combine::Grid),
        Err(SweepError::TooLarge { .. })
    ));
    // A product that overflows u64 is counted exactly in the message.
    let error = make(
        vec![
            half.clone(),
            Axis::linspace("x0", 1.0, 2.0, 1 << 32).unwrap(),
        ],
        Combine::Grid,
    )
    .unwrap_err()
    .to_string();
    assert!(
        error.starts_with(
            "the sweep would have 18446744073709551616 members (4294967296 x 4294967296)"
        ),
        "{error}"
    );
    let error = make(
        vec![
            huge.clone(),
            Axis::linspace("mass", 1.0, 2.0, usize::MAX).unwrap(),
        ],
        Combine::Zip,
    )
    .unwrap_err();
    assert!(matches!(error, SweepError::TooLarge { .. }), "{error}");
    // 2^32 members exactly is a sweep; its members are numbered lazily.
    let limit = make(vec![half], Combine::Grid).unwrap();
    assert_eq!(limit.len() as u64, MAX_MEMBERS);
    assert_eq!(limit.params_of(limit.len() - 1), vec![2.0]);
}

/// Members stream: `run_each` hands them over in index order on the calling thread while
/// the others still run (the first long before the last), with the numbers of a one-thread
/// run bit for bit; an error from the consumer stops the sweep at once. (The CLI's
/// `sweep_rows_stream_in_member_order_with_bounded_memory` measures the memory.)
#[test]
fn sweep_members_stream_in_order_and_stop_when_asked() {
    let sweep = Sweep::new(
        &scene(),
        vec![Axis::linspace("x0", 10.0, 200.0, 4000).unwrap()],
        Combine::Grid,
        request(Method::Implicit, 60),
        None,
    )
    .unwrap();
    let one = sweep.run(1).unwrap();
    let start = Instant::now();
    let mut streamed = Vec::new();
    let mut arrivals = Vec::new();
    sweep
        .run_each(0..sweep.len(), 2, |member| {
            arrivals.push(start.elapsed().as_secs_f64());
            streamed.push(member);
            Ok::<(), SweepError>(())
        })
        .unwrap();
    same(&one, &streamed);
    let (first, last) = (arrivals[0], arrivals[arrivals.len() - 1]);
    assert!(
        first < 0.25 * last,
        "first member after {first} s, last after {last} s"
    );
    // A consumer that stops: nothing after its error is handed over, and the sweep ends
    // without running the rest (a fraction of the time of the whole).
    let start = Instant::now();
    let mut seen = 0;
    let stopped = sweep.run_each(0..sweep.len(), 2, |member| {
        seen += 1;
        if member.index == 40 {
            return Err(SweepError::NoValues {
                name: "stop".into(),
            });
        }
        Ok(())
    });
    assert_eq!(
        stopped,
        Err(SweepError::NoValues {
            name: "stop".into()
        })
    );
    assert_eq!(seen, 41);
    assert!(start.elapsed().as_secs_f64() < 0.5 * last);
    // A chunk streams the same members.
    let mut chunk = Vec::new();
    sweep
        .run_each(1000..1100, 2, |m| {
            chunk.push(m);
            Ok::<(), SweepError>(())
        })
        .unwrap();
    same(&one[1000..1100], &chunk);
    assert!(matches!(
        sweep.run_each(5..4001, 2, |_| Ok::<(), SweepError>(())),
        Err(SweepError::OutOfRange { .. })
    ));
}

/// A sweep over the initial state (`bead.x`) with a parameter: each member is the scene with
/// that parameter, started at that x on the curve (the bead's y solved, at rest), as
/// `Scene::with_state` starts it, bit for bit; `q.q` sets the parametric coordinate itself.
#[test]
fn initial_state_axes_start_each_member_on_the_curve_at_that_coordinate() {
    let scene = scene();
    for method in [Method::Implicit, Method::Parametric] {
        let sweep = Sweep::new(
            &scene,
            vec![
                Axis::new("bead.x", vec![40.0, -80.0, 120.0]),
                Axis::new("g", vec![100.0, 200.0]),
            ],
            Combine::Grid,
            request(method, 60),
            None,
        )
        .unwrap();
        assert!(sweep.reload_reasons()[0].contains("`bead.x`"));
        let members = sweep.run(2).unwrap();
        for member in &members {
            let (x, g) = (member.params[0], member.params[1]);
            let start = bead::simulate::StateRequest {
                positions: Some(vec![x, -x * x / 100.0]),
                velocities: Some(vec![0.0, 0.0]),
                ..Default::default()
            };
            let (alone, _) = scene
                .with_params(&[("g".into(), g)])
                .unwrap()
                .with_state(&start)
                .unwrap();
            let plan = Plan::resolve(&alone, &request(method, 60)).unwrap();
            let mut sim = Simulation::new(Arc::clone(&alone.system), plan.config(method)).unwrap();
            let stats = run(&mut sim, plan.options(), &mut NullSink).unwrap();
            assert_eq!(member.error, None);
            assert_eq!(
                member.stats.as_ref().map(figures),
                Some(figures(&stats)),
                "{method:?}"
            );
        }
    }
    // The parametric coordinate, and the errors.
    let sweep = Sweep::new(
        &scene,
        vec![Axis::new("q.q", vec![10.0, 20.0])],
        Combine::Grid,
        request(Method::Parametric, 1),
        None,
    )
    .unwrap();
    let members = sweep.run(1).unwrap();
    for (member, q) in members.iter().zip([10.0, 20.0]) {
        let x = &member.stats.as_ref().unwrap().x;
        assert!((x[0] - q).abs() < 2.0 && (x[1] + x[0] * x[0] / 100.0).abs() < 1e-9);
    }
    let unknown = Sweep::new(
        &scene,
        vec![Axis::new("bead.w", vec![1.0])],
        Combine::Grid,
        request(Method::Implicit, 1),
        None,
    )
    .unwrap_err();
    assert!(unknown.to_string().contains("NAME.x"), "{unknown}");
}

/// Holding the start's coordinates swept: on the helix (two rows), `bead.z` puts the bead at
/// (R cos(z/b), R sin(z/b), z); on the circle, both x and y given leave nothing to solve:
/// the start is the closest point to them, as `Scene::with_state` places it.
#[test]
fn held_coordinates_of_the_start_are_kept_and_the_rest_solved() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/helix.toml");
    let helix = Scene::parse(&std::fs::read_to_string(path).unwrap(), "helix.toml", &[]).unwrap();
    let request = PlanRequest {
        method: Some(Method::Implicit),
        dt: Some(1e-9),
        steps: Some(1),
        ..Default::default()
    };
    let sweep = Sweep::new(
        &helix,
        vec![Axis::new("bead.z", vec![0.1, 0.5, -0.7])],
        Combine::Grid,
        request.clone(),
        None,
    )
    .unwrap();
    for member in sweep.run(1).unwrap() {
        let z = member.params[0];
        let x = &member.stats.as_ref().unwrap().x;
        let expected = [(z / 0.2).cos(), (z / 0.2).sin(), z];
        for (a, b) in x.iter().zip(expected) {
            assert!((a - b).abs() < 1e-6, "{x:?} vs {expected:?}");
        }
    }
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../../scenes/circle.toml");
    let circle = Scene::parse(&std::fs::read_to_string(path).unwrap(), "circle.toml", &[]).unwrap();
    let sweep = Sweep::new(
        &circle,
        vec![
            Axis::new("bead.x", vec![0.6, 1.2]),
            Axis::new("bead.y", vec![0.8, 1.6]),
        ],
        Combine::Zip,
        request,
        None,
    )
    .unwrap();
    for member in sweep.run(1).unwrap() {
        let x = &member.stats.as_ref().unwrap().x;
        assert!(
            (x[0] - 0.6).abs() < 1e-6 && (x[1] - 0.8).abs() < 1e-6,
            "{x:?}"
        );
    }
}

/// A scene's `[[event]]` tables are watched by every member as by a run of the member's
/// scene alone: a non-terminal event's crossing times and a terminal one's stop, bit for bit,
/// on the lanes and alone, members set up from the compiled equations or loaded again.
#[test]
fn members_watch_the_scene_event_tables_as_a_run_does() {
    let text = format!(
        "{}\n[[event]]\nexpr = \"bead.x\"\n\n[[event]]\nexpr = \"bead.vx - x0/20\"\ndirection = 1\nterminal = true\n",
        common::PARABOLA_SWEPT
    );
    let base = Scene::parse(&text, "parabola.toml", &[]).unwrap();
    assert_eq!(base.run.events.len(), 2);
    for (method, integrator) in [
        (Method::Implicit, IntegratorKind::Rk4),
        (Method::Parametric, IntegratorKind::Rk4),
        (Method::Implicit, IntegratorKind::Dopri5),
    ] {
        // x0 reaches the terminal event: every member is loaded again; g does not.
        for axis in [
            Axis::linspace("x0", 10.0, 200.0, 4).unwrap(),
            Axis::linspace("g", 300.0, 900.0, 4).unwrap(),
        ] {
            let name = axis.name.clone();
            let mut req = request(method, 600);
            req.integrator = Some(integrator);
            let sweep = Sweep::new(&base, vec![axis], Combine::Grid, req.clone(), None).unwrap();
            let members = sweep.run(2).unwrap();
            let mut crossed = 0;
            for member in &members {
                let alone =
                    Scene::parse(&text, "parabola.toml", &[(name.clone(), member.params[0])])
                        .unwrap();
                let plan = Plan::resolve(&alone, &req).unwrap();
                let mut simulation =
                    Simulation::new(Arc::clone(&alone.system), plan.config(method)).unwrap();
                simulation.set_events(alone.run.events_with(None)).unwrap();
                let stats = run(&mut simulation, plan.options(), &mut NullSink).unwrap();
                let swept = member.stats.as_ref().unwrap();
                assert_eq!(
                    figures(swept),
                    figures(&stats),
                    "{name} {method:?} {integrator:?}"
                );
                crossed += swept.events[0].times.len();
            }
            assert!(
                crossed > 0,
                "{name} {method:?} {integrator:?}: no crossing tested"
            );
        }
    }
}

/// Members that record (every K-th step, or chosen times) keep the figures of the members
/// that do not, bit for bit, and record exactly the rows of the same run alone: for both
/// forms, a fixed-step and an adaptive integrator, members that stop at their event early
/// (fewer rows) and a restarted and a reloaded sweep.
#[test]
fn recording_members_record_the_rows_of_their_run_alone() {
    let times: Arc<[f64]> = vec![0.0, 0.1, 0.37, 0.37, 1.0, 2.5, 4.0].into();
    for (method, integrator) in [
        (Method::Implicit, IntegratorKind::Rk4),
        (Method::Parametric, IntegratorKind::Rk4),
        (Method::Implicit, IntegratorKind::Dopri5),
    ] {
        for axis in [
            Axis::linspace("x0", 10.0, 200.0, 5).unwrap(),
            Axis::linspace("g", 300.0, 900.0, 3).unwrap(),
        ] {
            for recording in [Recording::Steps, Recording::Times(Arc::clone(&times))] {
                let name = axis.name.clone();
                let mut req = request(method, 240);
                req.integrator = Some(integrator);
                req.every = Some(7);
                let stop = Some("bead.vx - 25".to_string());
                let plain = Sweep::new(
                    &scene(),
                    vec![axis.clone()],
                    Combine::Grid,
                    req.clone(),
                    stop.clone(),
                )
                .unwrap();
                let recorder = plain.clone().recording(recording.clone()).unwrap();
                let recorded = recorder.run(2).unwrap();
                if recording == Recording::Steps {
                    // Recording every K-th step changes no number of the run.
                    same(&plain.run(2).unwrap(), &recorded);
                }
                let mut rows_seen = Vec::new();
                for member in &recorded {
                    let alone = Scene::parse(
                        common::PARABOLA_SWEPT,
                        "parabola.toml",
                        &[(name.clone(), member.params[0])],
                    )
                    .unwrap();
                    let plan = Plan::resolve(&alone, &req).unwrap();
                    let mut simulation =
                        Simulation::new(Arc::clone(&alone.system), plan.config(method)).unwrap();
                    let event = Event::parse(&alone.system, "bead.vx - 25").unwrap();
                    simulation.set_stop_when(Some(event)).unwrap();
                    let k = if method == Method::Parametric { 1 } else { 0 };
                    let mut rows = Trajectory::with_room(0, 2, k, false);
                    // t_eval lands a fixed step on each time: a run of its own.
                    let stats = match &recording {
                        Recording::Times(times) => {
                            run_at_times(&mut simulation, times, &mut rows, &mut NoProgress)
                        }
                        _ => run(&mut simulation, plan.options(), &mut rows),
                    }
                    .unwrap();
                    assert_eq!(figures(member.stats.as_ref().unwrap()), figures(&stats));
                    let swept = member.trajectory.as_deref().unwrap();
                    assert_eq!(swept, &rows, "{name} {method:?} {integrator:?}");
                    assert_eq!(swept.q.len(), k * swept.rows());
                    rows_seen.push(swept.rows());
                }
                // Some members stop at the event before the end, with fewer rows.
                let (least, most) = (rows_seen.iter().min(), rows_seen.iter().max());
                assert!(
                    least < most,
                    "{name} {method:?} {recording:?}: {rows_seen:?}"
                );
                assert!(*most.unwrap() as u64 <= recorder.rows_per_member());
            }
        }
    }
}

#[test]
fn recording_times_are_checked_and_a_sweep_of_no_axes_is_the_scene() {
    let sweep = Sweep::new(
        &scene(),
        Vec::new(),
        Combine::Grid,
        request(Method::Implicit, 60),
        None,
    )
    .unwrap();
    assert_eq!((sweep.len(), sweep.shape()), (1, &[][..]));
    let members = sweep.run(1).unwrap();
    let alone = scene();
    let plan = Plan::resolve(&alone, &request(Method::Implicit, 60)).unwrap();
    let mut simulation =
        Simulation::new(Arc::clone(&alone.system), plan.config(Method::Implicit)).unwrap();
    let stats = run(&mut simulation, plan.options(), &mut NullSink).unwrap();
    assert_eq!(figures(members[0].stats.as_ref().unwrap()), figures(&stats));
    for (times, says) in [
        (vec![], "no times given"),
        (vec![0.5, 0.25], "time 1 (0.25) is before time 0 (0.5)"),
        (vec![-1.0], "time 0 is -1: times must be finite and >= 0"),
        (vec![f64::NAN], "time 0 is NaN"),
    ] {
        let error = sweep
            .clone()
            .recording(Recording::Times(times.into()))
            .unwrap_err()
            .to_string();
        assert!(error.contains(says), "{error}");
    }
}
