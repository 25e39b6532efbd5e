//! What the viewer draws is the state it shows: curves of moving constraints are sent with
//! every frame at the frame's t and lie on C(x, t) = 0 at that t; frames carry the path of
//! the simulation's own steps and the core's energy split; a curve edit gives the panel a
//! new curve and view box, and the panels it does not apply to say so.

use std::sync::Arc;
use std::time::Instant;

use bead::scene::Scene;
use bead_viewer::protocol::{
    decode_frame, parse_client_message, Encoded, Limits, PanelFrame, PanelInfo, ServerMessage,
};
use bead_viewer::scenes::Catalog;
use bead_viewer::session::Session;

mod generated;
use generated::SHAKEN;

/// The shipped spinning hoop (not in the viewer's catalog).
fn hoop() -> String {
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/spinning-hoop.toml");
    std::fs::read_to_string(path).expect("scenes/spinning-hoop.toml")
}

fn send(session: &mut Session, json: &str) -> Vec<ServerMessage> {
    let message = parse_client_message(json, &Limits::default()).expect("a valid message");
    session.handle(message)
}

fn frames(session: &mut Session) -> Vec<PanelFrame> {
    match session.frame() {
        ServerMessage::Frame { panels, .. } => panels,
        other => panic!("not a frame: {other:?}"),
    }
}

fn panels_of(replies: &[ServerMessage]) -> Vec<PanelInfo> {
    replies
        .iter()
        .find_map(|m| match m {
            ServerMessage::Panels { panels } => Some(panels.clone()),
            _ => None,
        })
        .expect("a panels message")
}

fn load(session: &mut Session, toml: &str) -> Vec<PanelInfo> {
    let request = serde_json::json!({"type": "load_scene", "toml": toml, "file_name": "t.toml"});
    panels_of(&send(session, &request.to_string()))
}

fn run(session: &mut Session, frames: usize) {
    for _ in 0..frames {
        session.advance(1.0 / 60.0);
    }
}

/// The largest |C_row(x, t)| over the points of `lines` (`dim` numbers a point), the
/// particle `particle` placed at each.
fn worst_residual(scene: &Scene, lines: &[Vec<f64>], t: f64, particle: usize) -> f64 {
    let system = &scene.system;
    let dim = system.dim();
    let set = system.constraints();
    let mut ws = set.workspace();
    let (mut x, _) = system.initial_particle_state();
    let mut worst: f64 = 0.0;
    for line in lines {
        for point in line.chunks(dim) {
            x[particle * dim..(particle + 1) * dim].copy_from_slice(point);
            for &r in set.residuals(t, &x, &mut ws) {
                worst = worst.max(r.abs());
            }
        }
    }
    worst
}

#[test]
fn a_moving_contour_is_sent_at_the_frames_time_and_lies_on_the_curve_then() {
    let mut session = Session::new(Arc::new(Catalog::shipped()), Limits::default());
    let panels = load(&mut session, SHAKEN);
    assert!(panels[0].curves_move, "a driven constraint's curve moves");
    let scene = Scene::parse(SHAKEN, "t.toml", &[]).unwrap();
    let mut times = Vec::new();
    for _ in 0..2 {
        run(&mut session, 40);
        let frame = &frames(&mut session)[0];
        let curves = frame.curves.as_ref().expect("moving curves in the frame");
        assert!(curves.len() > 20, "{} segments", curves.len());
        // Marching squares interpolate C linearly along a cell's edge: the error is of
        // order the curvature times the cell squared, far below this.
        let worst = worst_residual(&scene, curves, frame.t, 0);
        assert!(worst < 2e-3, "|C(x, t)| up to {worst} at t = {}", frame.t);
        // ...while the curve of t = 0 is far from it: the test can fail.
        let frozen = worst_residual(&scene, curves, 0.0, 0);
        assert!(
            frozen > 0.05,
            "the curve did not move: {frozen} at t = {}",
            frame.t
        );
        // The bead is on the curve drawn: some point of it within a few cells of the bead.
        let bead = &frame.x;
        let nearest = curves
            .iter()
            .flat_map(|l| l.chunks(2))
            .map(|p| (p[0] - bead[0]).hypot(p[1] - bead[1]))
            .fold(f64::INFINITY, f64::min);
        assert!(nearest < 0.05, "the bead is {nearest} from its curve");
        times.push(frame.t);
    }
    assert!(times[1] > times[0]);
}

#[test]
fn the_spinning_hoops_curve_turns_with_the_hoop() {
    let mut session = Session::new(Arc::new(Catalog::shipped()), Limits::default());
    let text = hoop();
    let panels = load(&mut session, &text);
    let scene = Scene::parse(&text, "spinning-hoop.toml", &[]).unwrap();
    // Both panels (implicit and parametric) draw the map x(q, t), in 3D.
    for info in &panels {
        assert!(info.curves_move, "{info:?}");
        assert!(info.curves.iter().all(|l| l.len() % 3 == 0));
    }
    run(&mut session, 30);
    for frame in frames(&mut session) {
        let curves = frame.curves.as_ref().expect("moving curves");
        // The map's points satisfy the implicit form's constraints at the frame's t...
        let worst = worst_residual(&scene, curves, frame.t, 0);
        assert!(worst < 1e-9, "|C(x(q, t), t)| = {worst} at t = {}", frame.t);
        // ...and not those of t = 0 (the hoop has turned by w t = 2.5 rad).
        let frozen = worst_residual(&scene, curves, 0.0, 0);
        assert!(frozen > 0.1, "{frozen}");
    }
}

#[test]
fn frames_carry_the_steps_path_and_the_cores_energy_split() {
    let mut session = Session::new(Arc::new(Catalog::shipped()), Limits::default());
    send(&mut session, r#"{"type": "load_scene", "name": "circle"}"#);
    run(&mut session, 1);
    let before = frames(&mut session)[0].t;
    session.advance(1.0 / 60.0);
    let frame = &frames(&mut session)[0];
    // dt = 0.001: about 16 steps in a frame of 1/60 s, every one on the path, in order,
    // ending at the frame's state.
    let sample = 1 + frame.x.len();
    let path: Vec<&[f64]> = frame.path.chunks(sample).collect();
    assert!(path.len() >= 10, "{} samples", path.len());
    assert!(path[0][0] > before && path.windows(2).all(|w| w[1][0] > w[0][0]));
    let last = path.last().unwrap();
    assert_eq!(last[0], frame.t);
    assert_eq!(&last[1..], &frame.x[..]);
    for s in &path {
        // On the circle of radius 1, every one.
        assert!((s[1].hypot(s[2]) - 1.0).abs() < 1e-6, "{s:?}");
    }
    // T + V is the energy, T = 1/2 m |v|^2 > 0 once moving.
    assert!(frame.kinetic > 0.0);
    assert!((frame.kinetic + frame.potential - frame.energy).abs() < 1e-12);
    assert!(frame.energy_scale > 0.0);
    // The encoded frame decodes to the same path.
    let Ok(Encoded::Binary(bytes)) = session.frame().encode() else {
        panic!("a binary frame")
    };
    let decoded = decode_frame(&bytes).unwrap();
    let decoded_path = decoded["panels"][0]["path"].as_array().unwrap();
    assert_eq!(decoded_path.len(), path.len());
    assert_eq!(decoded_path[0][0].as_f64().unwrap(), path[0][0]);
}

#[test]
fn a_curve_edit_gives_a_new_curve_and_view_and_parametric_panels_say_so() {
    let mut session = Session::new(Arc::new(Catalog::shipped()), Limits::default());
    let before = panels_of(&send(
        &mut session,
        r#"{"type": "load_scene", "name": "circle"}"#,
    ));
    // The whole circle is in view, its center (the pivot) too.
    let v = before[0].view;
    assert!(
        v[0] < -1.0 && v[1] < -1.0 && v[2] > 1.0 && v[3] > 1.0,
        "{v:?}"
    );
    let after = panels_of(&send(
        &mut session,
        r#"{"type": "set_curve", "constraint": 0, "expr": "bead.x^2 + bead.y^2 - 9"}"#,
    ));
    let (implicit, parametric) = (&after[0], &after[1]);
    assert_ne!(implicit.curves, before[0].curves);
    let on_new = implicit
        .curves
        .iter()
        .flat_map(|l| l.chunks(2))
        .all(|p| (p[0].hypot(p[1]) - 3.0).abs() < 0.02);
    let worst = implicit
        .curves
        .iter()
        .flat_map(|l| l.chunks(2))
        .map(|p| (p[0].hypot(p[1]) - 3.0).abs())
        .fold(0.0, f64::max);
    assert!(
        on_new,
        "the implicit panel draws the new circle of radius 3: off by {worst}, view {:?}",
        implicit.view
    );
    assert!(
        implicit.view[2] > 3.0 && implicit.view[0] < -3.0,
        "{:?}",
        implicit.view
    );
    assert!(implicit.curve_note.is_none());
    assert_eq!(parametric.curves, before[1].curves);
    let note = parametric.curve_note.as_deref().unwrap_or_default();
    assert!(note.contains("not applied"), "{note}");
}

/// Figures for DESIGN.md: the bytes of a frame and the server's cost of one (advance,
/// moving curves, encoding), for the shaken parabola and the spinning hoop. Prints only.
#[test]
fn frame_cost_of_moving_curves() {
    for (name, request) in [
        (
            "shaken parabola",
            serde_json::json!({"type": "load_scene", "toml": SHAKEN}),
        ),
        (
            "spinning hoop",
            serde_json::json!({"type": "load_scene", "toml": hoop()}),
        ),
        (
            "circle",
            serde_json::json!({"type": "load_scene", "name": "circle"}),
        ),
    ] {
        let mut session = Session::new(Arc::new(Catalog::shipped()), Limits::default());
        send(&mut session, &request.to_string());
        run(&mut session, 5);
        let count = 60;
        let start = Instant::now();
        let mut bytes = 0;
        for _ in 0..count {
            session.advance(1.0 / 60.0);
            if let Ok(Encoded::Binary(b)) = session.frame().encode() {
                bytes += b.len();
            }
        }
        let per_frame = start.elapsed().as_secs_f64() * 1e3 / count as f64;
        let start = Instant::now();
        for _ in 0..count {
            let _ = session.frame().encode();
        }
        let encode = start.elapsed().as_secs_f64() * 1e3 / count as f64;
        eprintln!(
            "{name}: {} bytes a frame (2 panels), {per_frame:.3} ms a frame (advance + frame + encode), {encode:.3} ms frame + encode alone",
            bytes / count
        );
    }
}
