//! The oracle through the viewer: a session (`bead_viewer::session::Session`, what `bead
//! serve` runs per connection) with one panel per case, advanced on its clock, every frame
//! encoded as sent and decoded as the page does; the frames' states (the current one and
//! the path samples between frames) against the library and the reference.

use std::sync::Arc;

use bead::formulation::Method;
use bead_oracle::harness::each;
use bead_oracle::rows::error;
use bead_oracle::{checks, listing, matrix, Row, Spec};
use bead_viewer::protocol::{decode_frame, parse_client_message, Limits, ServerMessage};
use bead_viewer::scenes::Catalog;
use bead_viewer::session::Session;
use serde_json::{json, Value};

fn send(session: &mut Session, message: Value) -> Vec<ServerMessage> {
    let message = parse_client_message(&message.to_string(), &Limits::default())
        .unwrap_or_else(|e| panic!("{message}: {e}"));
    session.handle(message)
}

/// A session running `spec`'s scene in one panel of its method, integrator and dt.
fn session(spec: &Spec) -> Session {
    let mut s = Session::new(Arc::new(Catalog::shipped()), Limits::default());
    let text = std::fs::read_to_string(spec.scene_path()).expect("scene");
    let replies = send(
        &mut s,
        json!({"type": "load_scene", "toml": text, "file_name": spec.system.scene}),
    );
    let ids: Vec<u32> = replies
        .iter()
        .find_map(|m| match m {
            ServerMessage::Panels { panels } => Some(panels.iter().map(|p| p.id).collect()),
            _ => None,
        })
        .unwrap_or_else(|| panic!("the scene did not load: {replies:?}"));
    for id in ids {
        send(&mut s, json!({"type": "remove_panel", "panel": id}));
    }
    let replies = send(
        &mut s,
        json!({"type": "add_panel", "method": spec.method.name(),
               "integrator": spec.integrator.name(), "dt": spec.dt}),
    );
    assert!(
        !replies
            .iter()
            .any(|m| matches!(m, ServerMessage::Error { .. })),
        "{replies:?}"
    );
    send(&mut s, json!({"type": "play"}));
    s
}

/// The frame as the page gets it: encoded, then decoded.
fn frame(s: &mut Session) -> Value {
    let ServerMessage::Frame { .. } = s.frame() else {
        panic!("not a frame")
    };
    let bytes = match s.frame().encode().expect("encodes") {
        bead_viewer::protocol::Encoded::Binary(b) => b,
        other => panic!("a frame is binary: {other:?}"),
    };
    let mut value = decode_frame(&bytes).expect("decodes");
    value["panels"][0].take()
}

fn numbers(v: &Value) -> Vec<f64> {
    v.as_array()
        .expect("array")
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect()
}

#[test]
fn frames_are_the_library_run_and_meet_the_oracle() {
    let cases: Vec<Spec> = listing::cases_for("viewer")
        .into_iter()
        .map(|mut s| {
            // The viewer has no tolerance setting: dopri5 runs at the library's default.
            if s.integrator.is_adaptive() {
                s.rtol = Some(bead::integrate::IntegratorSettings::default().rtol);
            }
            s
        })
        .collect();
    each("viewer frames", &cases, Spec::label, |spec| {
        let what = format!("viewer {}", spec.label());
        let parametric = spec.method == Method::Parametric;
        // The library, driven as a panel drives it: from the initial state moved onto the
        // constraints, advance_to(k dt) for k = 1, 2, ...
        let mut library = spec.simulation();
        library
            .reset_onto_constraints()
            .expect("starts on the constraints");
        let run = spec.run();
        let duration = spec.duration.unwrap();
        let steps = (duration / spec.dt).round() as u64;
        let start = Row::of_sample(&library.sample(0), parametric);
        // The projection leaves a start on the constraints where it is, or moves it by a
        // few ulps (the helix's initial velocity, written as numbers in its scene, is off
        // its tangent by 1e-16): then the panel's run is `bead run`'s to round-off only.
        let moved = !start.same_bits(&run.rows[0]);
        let mut expected = vec![start];
        // What the live plot reads besides the positions: the velocities, and a parametric
        // panel's q then q'.
        let state = |l: &bead::simulate::Simulation| {
            let generalized: Vec<f64> = l.q().iter().chain(l.qdot()).copied().collect();
            (l.velocities().to_vec(), generalized)
        };
        let mut expected_state = vec![state(&library)];
        for k in 1..=steps {
            library.advance_to(k as f64 * spec.dt).expect("advances");
            expected.push(Row::of_sample(&library.sample(k), parametric));
            expected_state.push(state(&library));
        }
        if !spec.integrator.is_adaptive() {
            // Fixed steps: the panel's states are the run's (`bead run`), bit for bit.
            for (k, (a, b)) in expected.iter().zip(&run.rows).enumerate() {
                let close = || {
                    let d = error(spec.system, a) - error(spec.system, b);
                    let apart =
                        a.x.iter()
                            .zip(&b.x)
                            .fold(0.0f64, |m, (p, q)| m.max((p - q).abs()));
                    d.abs() <= 1e-12 && apart <= 1e-12 * spec.system.length
                };
                assert!(
                    a.same_bits(b) || (moved && close()),
                    "{what}: step {k}: the panel's simulation {a:?}, the run {b:?}"
                );
            }
        }
        let mut s = session(spec);
        let mut seen = 0;
        let mut frames = 0;
        let mut reached = Vec::new();
        while seen < steps {
            s.advance(0.05);
            let f = frame(&mut s);
            frames += 1;
            assert!(
                frames < 10 * steps + 100,
                "{what}: the panel does not advance"
            );
            let t = f["t"].as_f64().unwrap();
            let k = (t / spec.dt).round() as u64;
            // Running, or stopped at the scene's end (its duration is the spec's): after the
            // last step, not a step early.
            let status = f["status"].as_str().unwrap();
            assert!(
                status == "running" || (status == "paused" && k == steps),
                "{what}: {status} at step {k} of {steps}"
            );
            assert!(k <= steps + 1, "{what}: t = {t}");
            if k > steps {
                break;
            }
            let row = &expected[k as usize];
            // (c) the frame's state is the library's at the same t, bit for bit.
            let same = |a: f64, b: f64| a.to_bits() == b.to_bits();
            assert!(
                same(t, row.t),
                "{what}: frame at t = {t}, step {k} at {}",
                row.t
            );
            let x = numbers(&f["x"]);
            assert!(
                x.iter().zip(&row.x).all(|(a, b)| same(*a, *b)),
                "{what}: frame x {x:?} at t = {t}, the library's {:?}",
                row.x
            );
            let (velocities, generalized) = &expected_state[k as usize];
            if let Some(arrows) = f.get("arrows") {
                let v = numbers(&arrows["velocity"]);
                assert!(
                    v.iter().zip(velocities).all(|(a, b)| same(*a, *b))
                        && v.len() == velocities.len(),
                    "{what}: frame velocities {v:?} at t = {t}, the library's {velocities:?}"
                );
            }
            if parametric {
                let q = numbers(&f["generalized"]);
                assert!(
                    q.len() == generalized.len()
                        && q.iter().zip(generalized).all(|(a, b)| same(*a, *b)),
                    "{what}: frame q, q' {q:?} at t = {t}, the library's {generalized:?}"
                );
            }
            let figure = |key: &str| f[key].as_f64().unwrap_or_else(|| panic!("{key}"));
            assert!(
                same(figure("energy"), row.energy),
                "{what}: energy at t = {t}"
            );
            assert!(
                same(figure("constraint_error"), row.constraint_error),
                "{what}: constraint_error at t = {t}"
            );
            assert!(
                same(figure("work"), row.work.unwrap_or(0.0)),
                "{what}: work at t = {t}"
            );
            // (b) T + V of the frame is its energy.
            let tv = figure("kinetic") + figure("potential");
            assert!(
                (tv - figure("energy")).abs() <= 1e-13 * spec.system.energy_scale(),
                "{what}: kinetic + potential {tv}, energy {}",
                figure("energy")
            );
            // The path samples between frames: t and positions of states of the same run.
            for sample in f["path"].as_array().unwrap() {
                let sample = numbers(sample);
                let j = (sample[0] / spec.dt).round() as usize;
                let row = &expected[j];
                assert!(
                    same(sample[0], row.t)
                        && sample[1..].iter().zip(&row.x).all(|(a, b)| same(*a, *b)),
                    "{what}: path sample {sample:?}, the library's state at {} is {:?}",
                    row.t,
                    row.x
                );
            }
            seen = k;
            reached.push(row.clone());
        }
        assert_eq!(seen, steps, "{what}");
        // (a) the panel's states against the reference.
        if spec.integrator.is_adaptive() {
            checks::within(
                spec.system,
                &expected,
                matrix::DOPRI_BOUND * spec.rtol.unwrap(),
                &what,
            );
        } else {
            let largest = run
                .rows
                .iter()
                .map(|r| error(spec.system, r))
                .fold(0.0, f64::max);
            checks::against_reference(spec, &run.rows, &what);
            checks::within(spec.system, &reached, largest, &what);
        }
    });
}

#[test]
fn decode_frame_reads_header_numbers_exactly() {
    // A frame's header numbers (t, energies, errors) are written shortest round-trip and
    // the reference decoder reads them back bit for bit, as the page's JSON.parse does.
    // 2.3103527979628775e-9 and 0.1 + 0.2 are numbers serde_json's default parser reads
    // one ulp off or exactly; the suite's own data met the first.
    use bead_viewer::protocol::{encode_frame, PanelFrame};
    let numbers = [
        2.3103527979628775e-9,
        0.1 + 0.2,
        1.0 / 3.0,
        5e-324,
        1.7976931348623157e308,
    ];
    for (i, &v) in numbers.iter().enumerate() {
        let frame = PanelFrame {
            id: 1,
            epoch: 1,
            t: v,
            steps: 1,
            x: vec![v, -v],
            energy: v,
            kinetic: v,
            potential: -v,
            energy_initial: v,
            energy_scale: v,
            energy_error: v,
            energy_conserved: true,
            work: v,
            not_conserved_by: Vec::new(),
            constraint_error: v,
            steps_per_second: v,
            distance: Some(v),
            reference: None,
            reference_note: None,
            contact: None,
            status: "running".into(),
            error: None,
            behind: false,
            drag: None,
            path: vec![v, v, -v],
            curves: None,
            curve_region: [-v, -v, v, v],
            arrows: None,
            generalized: None,
        };
        let decoded = decode_frame(&encode_frame(1.0, &[frame]).unwrap()).unwrap();
        let panel = &decoded["panels"][0];
        for key in [
            "t",
            "energy",
            "kinetic",
            "energy_initial",
            "energy_scale",
            "energy_error",
            "work",
            "constraint_error",
            "distance",
        ] {
            let got = panel[key].as_f64().unwrap();
            assert_eq!(
                got.to_bits(),
                v.to_bits(),
                "number {i}: {key} {got:e}, sent {v:e}"
            );
        }
        assert_eq!(
            panel["potential"].as_f64().unwrap().to_bits(),
            (-v).to_bits()
        );
        assert_eq!(numbers_of(&panel["x"]), vec![v, -v]);
    }
}

fn numbers_of(v: &Value) -> Vec<f64> {
    numbers(v)
}
