//! Protocol parsing and validation, limits and the simulation behind a session, without a
//! network.

use std::sync::Arc;

use bead::integrate::IntegratorKind;
use bead::simulate::{ConfigError, Requirement};
use bead_viewer::protocol::{
    decode_frame, encode_frame, parse_client_message, AtEnd, ClientMessage, Encoded, ErrorCode,
    Limits, PanelFrame, PanelInfo, Pin, Rod, SceneInfo, ServerMessage, FRAME_MAGIC,
    PROTOCOL_VERSION,
};
use bead_viewer::scenes::{Catalog, SHIPPED};
use bead_viewer::session::{parse_scene, Session};
use bead_viewer::NamedScene;

mod generated;

fn session() -> Session {
    Session::new(Arc::new(Catalog::shipped()), Limits::default())
}

/// Parse and handle one JSON message.
fn send(session: &mut Session, json: &str) -> Vec<ServerMessage> {
    match parse_client_message(json, &Limits::default()) {
        Ok(message) => session.handle(message),
        Err(e) => panic!("{json} did not parse: {e}"),
    }
}

fn frames(session: &mut Session) -> Vec<PanelFrame> {
    match session.frame() {
        ServerMessage::Frame { panels, .. } => panels,
        other => panic!("not a frame: {other:?}"),
    }
}

fn panels_of(replies: &[ServerMessage]) -> Option<Vec<PanelInfo>> {
    replies.iter().find_map(|m| match m {
        ServerMessage::Panels { panels } => Some(panels.clone()),
        _ => None,
    })
}

fn error_of(replies: &[ServerMessage]) -> Option<String> {
    replies.iter().find_map(|m| match m {
        ServerMessage::Error { message, .. } => Some(message.clone()),
        _ => None,
    })
}

fn code_of(replies: &[ServerMessage]) -> Option<ErrorCode> {
    replies.iter().find_map(|m| match m {
        ServerMessage::Error { code, .. } => Some(*code),
        _ => None,
    })
}

/// Advance `seconds` of wall time in frames of 1/60 s.
fn run(session: &mut Session, seconds: f64) {
    let frames = (seconds * 60.0).round() as usize;
    for _ in 0..frames {
        session.advance(1.0 / 60.0);
    }
}

#[test]
fn greeting_has_welcome_scene_and_default_panels() {
    let mut s = session();
    let greeting = s.greeting();
    let ServerMessage::Welcome(welcome) = &greeting[0] else {
        panic!("first message is not welcome: {:?}", greeting[0]);
    };
    assert_eq!(welcome.protocol, PROTOCOL_VERSION);
    assert_eq!(welcome.scenes[0], "parabola");
    assert!(welcome.integrators.iter().any(|k| k.name == "rk4"));
    assert!(welcome.integrators.iter().any(|k| k.name == "rattle"));
    let ServerMessage::Scene(scene) = &greeting[1] else {
        panic!("second message is not the scene");
    };
    assert_eq!(scene.dim, 2);
    assert_eq!(
        scene.constraints[0].expr.as_deref(),
        Some("bead.x^2 + 100*bead.y")
    );
    // The view box holds the swing from x = -150 to 150 and the bottom at y = 0.
    assert!(
        scene.view[0] <= -150.0 && scene.view[2] >= 150.0,
        "{:?}",
        scene.view
    );
    assert!(
        scene.view[1] <= -225.0 && scene.view[3] >= 0.0,
        "{:?}",
        scene.view
    );
    let panels = panels_of(&greeting).unwrap();
    assert_eq!(panels.len(), 2);
    assert_eq!(panels[0].method, "implicit");
    assert_eq!(panels[1].method, "parametric");
    assert_eq!(panels[0].curve_source, "contour");
    assert_eq!(panels[1].curve_source, "parametric");
    assert!(!panels[0].curves.is_empty() && !panels[1].curves.is_empty());
    // Every message encodes: JSON text, the frame binary.
    for m in &greeting {
        assert!(matches!(m.encode(), Ok(Encoded::Text(_))), "{m:?}");
    }
    assert!(matches!(s.frame().encode(), Ok(Encoded::Binary(_))));
}

#[test]
fn panels_advance_in_real_time() {
    let mut s = session();
    run(&mut s, 1.0);
    for f in frames(&mut s) {
        assert_eq!(f.status, "running");
        assert!((f.t - 1.0).abs() < 0.05, "t = {}", f.t);
        // RK4 at dt = 1/60 on the implicit form drifts slowly (the article's observation).
        assert!(f.constraint_error < 0.1, "{f:?}");
        assert!(f.steps_per_second > 0.0);
    }
    send(&mut s, r#"{"type":"set_time_scale","scale":2}"#);
    run(&mut s, 0.5);
    assert!((frames(&mut s)[0].t - 2.0).abs() < 0.05);
    send(&mut s, r#"{"type":"pause"}"#);
    let t = frames(&mut s)[0].t;
    run(&mut s, 0.5);
    assert_eq!(frames(&mut s)[0].t, t);
    send(&mut s, r#"{"type":"step"}"#);
    let f = &frames(&mut s)[0];
    assert!((f.t - (t + 1.0 / 60.0)).abs() < 1e-9 && f.status == "paused");
    send(&mut s, r#"{"type":"reset"}"#);
    assert_eq!(frames(&mut s)[0].t, 0.0);
}

#[test]
fn malformed_messages_are_rejected_with_a_reason() {
    let limits = Limits::default();
    for bad in [
        "",
        "not json",
        "{}",
        "[1,2]",
        r#"{"type":"launch_missiles"}"#,
        r#"{"type":"set_time_scale","scale":"NaN"}"#,
        r#"{"type":"set_time_scale","scale":1e999}"#,
        r#"{"type":"add_panel","dt":"fast"}"#,
        r#"{"type":"remove_panel","panel":-1}"#,
        r#"{"type":"remove_panel","panel":1e20}"#,
        r#"{"type":"drag_start","panel":1,"particle":0,"target":"here"}"#,
        r#"{"type":"set_curve","constraint":0}"#,
    ] {
        assert!(
            parse_client_message(bad, &limits).is_err(),
            "accepted {bad:?}"
        );
    }
    let huge = format!(
        r#"{{"type":"set_curve","constraint":0,"expr":"{}"}}"#,
        "x".repeat(70_000)
    );
    let e = parse_client_message(&huge, &limits).unwrap_err();
    assert!(e.to_string().contains("too large"), "{e}");
    assert_eq!(e.code(), ErrorCode::TooLarge);
    assert_eq!(
        parse_client_message(r#"{"type":"play"}"#, &limits),
        Ok(ClientMessage::Play { panel: None })
    );
}

#[test]
fn invalid_values_get_error_replies_and_change_nothing() {
    let mut s = session();
    let before = s.panel_count();
    for bad in [
        r#"{"type":"set_time_scale","scale":-1}"#,
        r#"{"type":"set_time_scale","scale":1000}"#,
        r#"{"type":"add_panel","dt":0}"#,
        r#"{"type":"add_panel","dt":-0.01}"#,
        r#"{"type":"add_panel","dt":1e300}"#,
        r#"{"type":"add_panel","integrator":"bogus"}"#,
        r#"{"type":"add_panel","method":"magic"}"#,
        r#"{"type":"add_panel","method":"parametric","integrator":"rattle"}"#,
        r#"{"type":"add_panel","method":"parametric","ks":5}"#,
        r#"{"type":"add_panel","ks":1e300}"#,
        r#"{"type":"add_panel","method":"parametric","project":true}"#,
        r#"{"type":"add_panel","integrator":"dopri5","project":true}"#,
        r#"{"type":"remove_panel","panel":99}"#,
        r#"{"type":"configure_panel","panel":99,"dt":0.01}"#,
        r#"{"type":"configure_panel","panel":1,"dt":-1}"#,
        r#"{"type":"play","panel":42}"#,
        r#"{"type":"drag_start","panel":1,"particle":7,"target":[0,0]}"#,
        r#"{"type":"drag_start","panel":1,"particle":0,"target":[0,0,0,0]}"#,
        r#"{"type":"drag_start","panel":1,"particle":0,"target":[1e300,0]}"#,
        r#"{"type":"drag_move","panel":1,"target":[0,0]}"#,
        r#"{"type":"load_scene","name":"nope"}"#,
        r#"{"type":"load_scene"}"#,
        r#"{"type":"load_scene","name":"circle","toml":"x"}"#,
    ] {
        let replies = send(&mut s, bad);
        assert!(
            error_of(&replies).is_some(),
            "{bad}: no error in {replies:?}"
        );
    }
    assert_eq!(s.panel_count(), before);
}

#[test]
fn panel_limit() {
    let mut s = session();
    let limit = Limits::default().max_panels;
    for _ in s.panel_count()..limit {
        let replies = send(&mut s, r#"{"type":"add_panel","integrator":"midpoint"}"#);
        assert!(panels_of(&replies).is_some(), "{replies:?}");
    }
    let replies = send(&mut s, r#"{"type":"add_panel"}"#);
    assert!(error_of(&replies).unwrap().contains("too many panels"));
    assert_eq!(s.panel_count(), limit);
    run(&mut s, 0.2);
    assert!(frames(&mut s).iter().all(|f| f.status == "running"));
}

#[test]
fn steps_per_frame_are_capped() {
    let mut s = session();
    let limits = Limits::default();
    send(
        &mut s,
        r#"{"type":"configure_panel","panel":1,"dt":1e-6,"integrator":"euler"}"#,
    );
    send(&mut s, r#"{"type":"set_time_scale","scale":100}"#);
    s.advance(1.0 / 60.0);
    let f = &frames(&mut s)[0];
    assert!(f.steps <= limits.max_steps_per_frame / 2, "{}", f.steps);
    assert!(f.behind);
}

#[test]
fn every_integrator_runs_where_it_applies() {
    let mut s = session();
    for kind in [
        "euler",
        "symplectic-euler",
        "midpoint",
        "rk4",
        "verlet",
        "rattle",
        "gauss-legendre",
        "dopri5",
        "fast-projection",
    ] {
        let replies = send(
            &mut s,
            &format!(r#"{{"type":"configure_panel","panel":1,"integrator":"{kind}"}}"#),
        );
        assert!(panels_of(&replies).is_some(), "{kind}: {replies:?}");
        run(&mut s, 0.3);
        let f = &frames(&mut s)[0];
        assert_eq!(f.status, "running", "{kind}: {f:?}");
        assert!(f.t > 0.2, "{kind}: t = {}", f.t);
    }
}

/// Every scene of `scenes/` is in the picker, once, under its file's name: a new scene cannot
/// be shipped without it (the picker once listed 6 of 10).
#[test]
fn the_picker_lists_every_shipped_scene() {
    let folder = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let mut files: Vec<String> = std::fs::read_dir(&folder)
        .unwrap()
        .map(|entry| entry.unwrap().path())
        .filter(|path| path.extension().is_some_and(|e| e == "toml"))
        .map(|path| path.file_stem().unwrap().to_string_lossy().into_owned())
        .collect();
    files.sort();
    let mut listed: Vec<String> = SHIPPED.iter().map(|(n, _)| n.to_string()).collect();
    listed.sort();
    assert_eq!(listed, files);
    for (name, text) in SHIPPED {
        let on_disk = std::fs::read_to_string(folder.join(format!("{name}.toml"))).unwrap();
        assert_eq!(text, on_disk, "{name}: the embedded text is the file's");
    }
    let welcome = match &session().greeting()[0] {
        ServerMessage::Welcome(welcome) => welcome.scenes.clone(),
        other => panic!("{other:?}"),
    };
    assert_eq!(welcome, SHIPPED.map(|(n, _)| n.to_string()).to_vec());
}

#[test]
fn shipped_scenes_load_and_run() {
    let mut s = session();
    for (name, _) in SHIPPED {
        let replies = send(
            &mut s,
            &format!(r#"{{"type":"load_scene","name":"{name}"}}"#),
        );
        let panels = panels_of(&replies).unwrap_or_else(|| panic!("{name}: {replies:?}"));
        assert!(!panels.is_empty());
        // The large scenes (a chain of 1000 links, a cloth of 2500 masses, a rope, a tassel
        // and a net of hundreds) get a few frames,
        // within the frame budget: a debug build falls behind real time there, so only
        // that they step is asked.
        let (seconds, least) = match name {
            "chain" | "cloth" | "rope" | "tassel" | "net" => (0.05, 0.0),
            _ => (0.5, 0.4),
        };
        run(&mut s, seconds);
        let frames = frames(&mut s);
        let said = |f: &PanelFrame| format!("{name}: {} at t = {}, {:?}", f.status, f.t, f.error);
        for f in &frames {
            match (name, f.status.as_str()) {
                (_, "running") => assert!(f.t > least && f.steps > 0, "{}", said(f)),
                // The singular curves' lesson: the implicit form stops at the singular point
                // and says so, where the parametric form goes through.
                ("cusp" | "node", "failed") => assert!(
                    f.error
                        .as_deref()
                        .is_some_and(|e| e.contains("is singular")),
                    "{}",
                    said(f)
                ),
                _ => panic!("{}", said(f)),
            }
        }
        assert!(
            frames.iter().any(|f| f.status == "running"),
            "{name}: no panel running"
        );
    }
}

#[test]
fn scene_errors_are_located() {
    let mut s = session();
    let text = SHIPPED[0]
        .1
        .replace("bead.x^2 + 100*bead.y", "bead.x^2 + 100*bead.w");
    let message = serde_json::json!({"type": "load_scene", "toml": text, "file_name": "bad.toml"});
    let replies = send(&mut s, &message.to_string());
    let ServerMessage::SceneError { message, line, .. } = &replies[0] else {
        panic!("{replies:?}");
    };
    assert!(message.starts_with("bad.toml:"), "{message}");
    assert!(
        message.contains("`bead` has no coordinate `w`"),
        "{message}"
    );
    assert!(*line > 0);
    // The old scene still runs.
    assert_eq!(s.panel_count(), 2);
    let message =
        serde_json::json!({"type": "load_scene", "toml": SHIPPED[1].1, "file_name": "mine.toml"});
    let replies = send(&mut s, &message.to_string());
    assert!(replies
        .iter()
        .any(|m| matches!(m, ServerMessage::Scene(info) if info.name == "mine.toml")));
}

/// A 60 kB scene whose name template repeats `{i}` 20,000 times cost the viewer 2 GB per
/// `load_scene` at N = 4000: the loader refuses it before expanding it (the library's
/// limit on generated text), and the session replies with the located error.
#[test]
fn generated_text_beyond_the_limit_is_refused_before_it_is_made() {
    let mut s = session();
    let text = format!(
        "[params]\nN = 4000\n[world]\ngravity = [0.0, 1.0]\n[[particle]]\nfor = {{ i = \"0..N\" }}\nname = \"p{}\"\nmass = 1.0\nposition = [\"i\", 0.0]\n",
        "{i}".repeat(20_000)
    );
    let message = serde_json::json!({"type": "load_scene", "toml": text, "file_name": "big.toml"});
    let start = std::time::Instant::now();
    let replies = send(&mut s, &message.to_string());
    assert!(start.elapsed().as_secs_f64() < 1.0, "{:?}", start.elapsed());
    let ServerMessage::SceneError { message, line, .. } = &replies[0] else {
        panic!("{replies:?}");
    };
    assert!(
        message.starts_with("big.toml:6:7: particle 1: `for` would expand the table's 60 kB of strings 4000 times, to about 240 MB of text; a scene's generated tables may expand to at most 16 MiB"),
        "{message}"
    );
    assert_eq!(*line, 6);
    assert_eq!(s.panel_count(), 2);
}

#[test]
fn curve_edit_errors_point_into_the_expression_and_leave_panels_alone() {
    let mut s = session();
    run(&mut s, 0.5);
    let replies = send(
        &mut s,
        r#"{"type":"set_curve","constraint":0,"expr":"bead.x^2 + 100*bead.w"}"#,
    );
    let ServerMessage::CurveError {
        message, columns, ..
    } = &replies[0]
    else {
        panic!("{replies:?}");
    };
    assert!(message.contains("no coordinate `w`"), "{message}");
    assert_eq!(*columns, Some([15, 21]), "{message}");
    for (expr, contains) in [
        ("bead.x^2 + (", "expected"),
        ("", "empty"),
        ("bead.x \" + 1", "unexpected character"),
    ] {
        let message = serde_json::json!({"type": "set_curve", "constraint": 0, "expr": expr});
        let replies = send(&mut s, &message.to_string());
        match &replies[0] {
            ServerMessage::CurveError { message, .. } => {
                assert!(message.contains(contains), "{expr}: {message}")
            }
            other => panic!("{expr}: {other:?}"),
        }
    }
    let long = "x+".repeat(2000) + "x";
    let message = serde_json::json!({"type": "set_curve", "constraint": 0, "expr": long});
    assert!(matches!(
        &send(&mut s, &message.to_string())[0],
        ServerMessage::CurveError { message, .. } if message.contains("too long")
    ));
    // Integers are numbers too.
    let replies = send(
        &mut s,
        r#"{"type":"configure_panel","panel":2,"dt":1,"ks":0,"kd":0}"#,
    );
    assert_eq!(panels_of(&replies).unwrap()[1].dt, 1.0);
    send(
        &mut s,
        r#"{"type":"configure_panel","panel":2,"dt":0.016666666666666666}"#,
    );
    // (A configuration restarts every panel: one clock.)
    let t = frames(&mut s)[0].t;
    let replies = send(
        &mut s,
        r#"{"type":"set_curve","constraint":3,"expr":"bead.x"}"#,
    );
    assert!(matches!(&replies[0], ServerMessage::CurveError { .. }));
    // Untouched: still running from where it was.
    run(&mut s, 0.1);
    let f = &frames(&mut s)[0];
    assert!(f.t > t && f.status == "running");

    // A valid edit: a flatter parabola; the implicit panel restarts on it.
    let replies = send(
        &mut s,
        r#"{"type":"set_curve","constraint":0,"expr":"bead.x^2 + 200*bead.y"}"#,
    );
    let panels = panels_of(&replies).unwrap_or_else(|| panic!("{replies:?}"));
    assert_eq!(panels[0].exprs[0].as_deref(), Some("bead.x^2 + 200*bead.y"));
    assert_eq!(panels[1].exprs[0].as_deref(), Some("bead.x^2 + 100*bead.y"));
    let f = &frames(&mut s)[0];
    assert!(f.t < 0.05, "{f:?}");
    assert!(f.constraint_error < 1e-6, "{f:?}");
    run(&mut s, 0.5);
    assert!(frames(&mut s)[0].constraint_error < 1e-2);
    // Without implicit panels there is nothing to apply a curve to.
    send(&mut s, r#"{"type":"remove_panel","panel":1}"#);
    let replies = send(
        &mut s,
        r#"{"type":"set_curve","constraint":0,"expr":"bead.x^2 + 300*bead.y"}"#,
    );
    assert!(
        matches!(&replies[0], ServerMessage::CurveError { message, .. } if message.contains("no implicit panel"))
    );
    // Parametric panels cannot take a curve edit.
    let replies = send(
        &mut s,
        r#"{"type":"set_curve","panel":2,"constraint":0,"expr":"bead.x^2 + 200*bead.y"}"#,
    );
    assert!(matches!(&replies[0], ServerMessage::CurveError { .. }));
}

/// A scene whose implicit panel diverges with explicit Euler: a stiff spring.
const STIFF: &str = r#"
title = "stiff"
[world]
gravity = [0.0, 0.0]
[[particle]]
name = "bead"
mass = 1.0
position = [1.0, 0.0]
[[force]]
kind = "spring"
particle = "bead"
anchor = [0.0, 0.0]
stiffness = 1e6
[[constraint]]
expr = "bead.y"
[parametric]
coordinates = ["q"]
initial = [1.0]
[parametric.positions]
bead = ["q", "0"]
[run]
integrator = "euler"
dt = 0.01
"#;

#[test]
fn divergence_stops_one_panel_only() {
    let mut s = session();
    let message =
        serde_json::json!({"type": "load_scene", "toml": STIFF, "file_name": "stiff.toml"});
    let replies = send(&mut s, &message.to_string());
    let panels = panels_of(&replies).unwrap_or_else(|| panic!("{replies:?}"));
    let (implicit, parametric) = (panels[0].id, panels[1].id);
    let replies = send(
        &mut s,
        &format!(
            r#"{{"type":"configure_panel","panel":{parametric},"integrator":"rk4","dt":1e-4}}"#
        ),
    );
    assert!(panels_of(&replies).is_some(), "{replies:?}");
    run(&mut s, 3.0);
    let f = frames(&mut s);
    assert_eq!(f[0].status, "failed", "{:?}", f[0]);
    let error = f[0].error.as_deref().unwrap();
    assert!(error.contains("diverged"), "{error}");
    assert_eq!(f[1].status, "running", "{:?}", f[1]);
    assert!(f[1].t > 2.5);
    // Frames stay valid (no NaN) and play does not restart a failed panel.
    let ServerMessage::Frame {
        time_scale, panels, ..
    } = s.frame()
    else {
        unreachable!()
    };
    decode_frame(&encode_frame(time_scale, &panels).unwrap()).unwrap();
    send(&mut s, r#"{"type":"play"}"#);
    assert_eq!(frames(&mut s)[0].status, "failed");
    send(&mut s, &format!(r#"{{"type":"reset","panel":{implicit}}}"#));
    assert_eq!(frames(&mut s)[0].status, "paused");
}

#[test]
fn dragging_pulls_the_bead_along_the_curve() {
    let mut s = session();
    send(
        &mut s,
        r#"{"type":"configure_panel","panel":1,"project":true}"#,
    );
    send(&mut s, r#"{"type":"reset"}"#);
    // Hold the bead at the bottom-left: target (-100, -100) is off the curve.
    for panel in [1, 2] {
        let replies = send(
            &mut s,
            &format!(
                r#"{{"type":"drag_start","panel":{panel},"particle":0,"target":[-100,-100]}}"#
            ),
        );
        assert!(replies.is_empty(), "{replies:?}");
    }
    send(&mut s, r#"{"type":"play"}"#);
    run(&mut s, 3.0);
    for f in frames(&mut s) {
        let (x, y) = (f.x[0], f.x[1]);
        assert!(f.drag.is_some());
        assert!(x < -50.0, "panel {}: x = {x}", f.id);
        assert!(
            (x * x + 100.0 * y).abs() < 1e-3,
            "panel {}: off the curve",
            f.id
        );
        assert!(f.constraint_error < 1e-3, "{f:?}");
    }
    for panel in [1, 2] {
        send(
            &mut s,
            &format!(r#"{{"type":"drag_move","panel":{panel},"target":[100,-100]}}"#),
        );
    }
    run(&mut s, 3.0);
    for f in frames(&mut s) {
        assert!(f.x[0] > 50.0, "panel {}: x = {}", f.id, f.x[0]);
    }
    for panel in [1, 2] {
        send(&mut s, &format!(r#"{{"type":"drag_end","panel":{panel}}}"#));
    }
    run(&mut s, 1.0);
    for f in frames(&mut s) {
        assert!(f.drag.is_none() && f.status == "running");
        // The drag did work (about half the scene's energy scale, 1.1e5) and it is counted:
        // E - W stays conserved to rk4's accuracy against the stiff spring (omega dt = 0.2).
        assert!(!f.energy_conserved, "{f:?}");
        assert_eq!(f.not_conserved_by, vec!["external forces".to_string()]);
        assert!(f.work.abs() > 1e4, "{f:?}");
        assert!(f.energy_error < 2e-2, "{f:?}");
    }
}

#[test]
fn large_scenes_stay_responsive() {
    // 300 beads, each on its own circle: 300 constraint rows, a dense 300 x 300 solve per
    // evaluation. Loading and every frame must stay bounded in time.
    let mut text = String::from("title = \"many\"\n[world]\ngravity = [0.0, 9.81]\n");
    for i in 0..300 {
        text.push_str(&format!(
            "[[particle]]\nname = \"p{i}\"\nmass = 1.0\nposition = [{}.0, 1.0]\n",
            2 * i
        ));
    }
    for i in 0..300 {
        text.push_str(&format!(
            "[[constraint]]\nexpr = \"(p{i}.x - {}.0)^2 + p{i}.y^2 - 1\"\n",
            2 * i
        ));
    }
    assert!(text.len() < Limits::default().max_message_bytes);
    let mut s = session();
    let message = serde_json::json!({"type": "load_scene", "toml": text, "file_name": "many.toml"});
    let start = std::time::Instant::now();
    let replies = send(&mut s, &message.to_string());
    assert!(panels_of(&replies).is_some(), "{replies:?}");
    assert!(
        start.elapsed().as_secs_f64() < 10.0,
        "load took {:?}",
        start.elapsed()
    );
    for _ in 0..5 {
        let start = std::time::Instant::now();
        s.advance(1.0 / 60.0);
        assert!(
            start.elapsed().as_secs_f64() < 2.0,
            "a frame took {:?}",
            start.elapsed()
        );
    }
    // Too many particles are refused (a scene given on the command line: a text sent by the
    // page is smaller than the message limit).
    let limit = Limits::default().max_particles;
    let mut text = String::from("title = \"too many\"\n[world]\ngravity = [0.0, 1.0]\n");
    for i in 0..=limit {
        text.push_str(&format!(
            "[[particle]]\nname = \"p{i}\"\nmass = 1\nposition = [0, 0]\n"
        ));
    }
    let error = parse_scene(&text, "many.toml").unwrap_err();
    assert_eq!(
        error.message,
        format!("too many particles: {} (limit {limit})", limit + 1)
    );
    let s = session_with("many.toml", text);
    assert_eq!(s.panel_count(), 0);
}

/// Drag panel `panel` towards `target`.
fn drag(s: &mut Session, panel: u32, target: [f64; 2]) {
    let replies = send(
        s,
        &format!(
            r#"{{"type":"drag_start","panel":{panel},"particle":0,"target":[{},{}]}}"#,
            target[0], target[1]
        ),
    );
    assert!(replies.is_empty(), "{replies:?}");
}

#[test]
fn the_drag_does_counted_work_and_e_minus_w_is_conserved() {
    let mut s = session();
    // dopri5 follows the drag spring to its tolerance, so that the balance shows the
    // ledger's own accuracy.
    let replies = send(
        &mut s,
        r#"{"type":"configure_panel","panel":1,"integrator":"dopri5"}"#,
    );
    assert!(panels_of(&replies).is_some(), "{replies:?}");
    let f = &frames(&mut s)[0];
    assert!(f.energy_conserved && f.work == 0.0 && f.not_conserved_by.is_empty());
    drag(&mut s, 1, [-100.0, -100.0]);
    run(&mut s, 2.0);
    send(
        &mut s,
        r#"{"type":"drag_move","panel":1,"target":[100,-100]}"#,
    );
    run(&mut s, 2.0);
    let during = frames(&mut s)[0].clone();
    send(&mut s, r#"{"type":"drag_end","panel":1}"#);
    run(&mut s, 1.0);
    let f = &frames(&mut s)[0];
    assert_eq!(f.status, "running", "{f:?}");
    for f in [&during, f] {
        assert!(!f.energy_conserved, "{f:?}");
        assert_eq!(f.not_conserved_by, vec!["external forces".to_string()]);
        assert!(f.work.abs() > 1e4, "{f:?}");
        assert!(f.energy_error < 1e-6, "{f:?}");
    }
    // A reset starts a new epoch without external forces: T + V is conserved again.
    send(&mut s, r#"{"type":"reset","panel":1}"#);
    let f = &frames(&mut s)[0];
    assert!(
        f.energy_conserved && f.work == 0.0 && f.energy_error == 0.0,
        "{f:?}"
    );
}

#[test]
fn dragging_works_with_verlet_and_rattle_at_the_default_dt() {
    for integrator in ["verlet", "rattle"] {
        let mut s = session();
        let replies = send(
            &mut s,
            &format!(r#"{{"type":"configure_panel","panel":1,"integrator":"{integrator}"}}"#),
        );
        assert!(panels_of(&replies).is_some(), "{replies:?}");
        drag(&mut s, 1, [-100.0, -100.0]);
        run(&mut s, 3.0);
        let f = &frames(&mut s)[0];
        assert_eq!(f.status, "running", "{integrator}: {f:?}");
        assert!(f.drag.is_some() && f.x[0] < -50.0, "{integrator}: {f:?}");
        send(
            &mut s,
            r#"{"type":"drag_move","panel":1,"target":[100,-100]}"#,
        );
        run(&mut s, 3.0);
        let f = &frames(&mut s)[0];
        assert_eq!(f.status, "running", "{integrator}: {f:?}");
        assert!(f.x[0] > 50.0, "{integrator}: {f:?}");
        if integrator == "rattle" {
            assert!(f.constraint_error < 1e-6, "{f:?}");
        }
    }
    // At dt = 0.1 and at the viewer's largest dt, 1, their velocity kick cannot converge
    // against the drag's damping in one step (dt c/(2m) = 1.26 and 12.6 > 1): each step is
    // retried in more substeps (at most 64) and the panel keeps running and follows the drag. (The
    // panel's explanation of a kick that fails while dragging stays for failures that
    // retries cannot fix.)
    for integrator in ["verlet", "rattle"] {
        for dt in ["0.1", "1"] {
            let mut s = session();
            send(
                &mut s,
                &format!(
                    r#"{{"type":"configure_panel","panel":1,"integrator":"{integrator}","dt":{dt}}}"#
                ),
            );
            drag(&mut s, 1, [-100.0, -100.0]);
            run(&mut s, 4.0);
            let f = &frames(&mut s)[0];
            assert_eq!(f.status, "running", "{integrator} dt = {dt}: {f:?}");
            assert!(f.x[0] < -50.0, "{integrator} dt = {dt}: {f:?}");
        }
    }
}

#[test]
fn illegal_combinations_get_the_librarys_words_as_in_the_cli() {
    let mut s = session();
    // The CLI prints `error: ` and this (crates/bead-cli/tests/cli.rs,
    // rattle_on_the_parametric_form_is_an_error).
    let cli = "rattle needs the implicit form: the parametric form has no constraints to project onto (it stays on them by construction); use gauss-legendre or rk4 with the parametric form";
    let expected =
        ConfigError::NeedsConstraints(Requirement::Integrator(IntegratorKind::Rattle)).to_string();
    assert_eq!(expected, cli);
    for request in [
        r#"{"type":"add_panel","method":"parametric","integrator":"rattle"}"#,
        r#"{"type":"configure_panel","panel":2,"integrator":"rattle"}"#,
    ] {
        let replies = send(&mut s, request);
        assert_eq!(error_of(&replies).as_deref(), Some(cli), "{request}");
        assert_eq!(code_of(&replies), Some(ErrorCode::IllegalCombination));
    }
    let expected = ConfigError::ProjectionWithAdaptive(IntegratorKind::Dopri5).to_string();
    for request in [
        r#"{"type":"add_panel","integrator":"dopri5","project":true}"#,
        r#"{"type":"configure_panel","panel":1,"integrator":"dopri5","project":true}"#,
    ] {
        let replies = send(&mut s, request);
        assert_eq!(error_of(&replies), Some(expected.clone()), "{request}");
        assert_eq!(code_of(&replies), Some(ErrorCode::IllegalCombination));
    }
    assert_eq!(s.panel_count(), 2);
}

#[test]
fn error_replies_carry_stable_codes() {
    let mut s = session();
    for (request, code) in [
        (r#"{"type":"remove_panel","panel":99}"#, ErrorCode::NoPanel),
        (r#"{"type":"add_panel","dt":0}"#, ErrorCode::BadValue),
        (
            r#"{"type":"add_panel","integrator":"bogus"}"#,
            ErrorCode::BadValue,
        ),
        (
            r#"{"type":"set_time_scale","scale":-1}"#,
            ErrorCode::BadValue,
        ),
        (
            r#"{"type":"add_panel","method":"parametric","ks":5}"#,
            ErrorCode::IllegalCombination,
        ),
        (
            r#"{"type":"drag_start","panel":1,"particle":7,"target":[0,0]}"#,
            ErrorCode::BadValue,
        ),
        (
            r#"{"type":"drag_move","panel":1,"target":[0,0]}"#,
            ErrorCode::NoDrag,
        ),
        (
            r#"{"type":"load_scene","name":"nope"}"#,
            ErrorCode::UnknownScene,
        ),
        (r#"{"type":"load_scene"}"#, ErrorCode::BadRequest),
    ] {
        let replies = send(&mut s, request);
        assert_eq!(code_of(&replies), Some(code), "{request}: {replies:?}");
        let json = serde_json::to_value(&replies[0]).unwrap();
        assert_eq!(json["code"], serde_json::to_value(code).unwrap());
    }
    assert_eq!(
        serde_json::to_value(ErrorCode::IllegalCombination).unwrap(),
        "illegal_combination"
    );
    // A step that fails says so to the request, and in the panel's frame.
    let message =
        serde_json::json!({"type": "load_scene", "toml": STIFF, "file_name": "stiff.toml"});
    send(&mut s, &message.to_string());
    let mut failed = None;
    for _ in 0..1000 {
        let replies = send(&mut s, r#"{"type":"step"}"#);
        if let Some(code) = code_of(&replies) {
            failed = Some((code, replies));
            break;
        }
    }
    let (code, replies) = failed.expect("explicit Euler on the stiff spring never failed");
    assert_eq!(code, ErrorCode::StepFailed);
    let f = &frames(&mut s)[0];
    assert_eq!(f.status, "failed");
    assert_eq!(error_of(&replies), f.error);
}

#[test]
fn epochs_change_whenever_a_panel_restarts_and_frames_carry_them() {
    let mut s = session();
    let epochs = |replies: &[ServerMessage]| -> Vec<u64> {
        panels_of(replies)
            .unwrap()
            .iter()
            .map(|p| p.epoch)
            .collect()
    };
    let first = epochs(&s.greeting());
    assert_ne!(first[0], first[1]);
    let frame_epochs =
        |s: &mut Session| -> Vec<u64> { frames(s).iter().map(|f| f.epoch).collect() };
    assert_eq!(frame_epochs(&mut s), first);
    // Play, pause, step and the time scale keep the epoch.
    for request in [
        r#"{"type":"pause"}"#,
        r#"{"type":"step"}"#,
        r#"{"type":"play"}"#,
        r#"{"type":"set_time_scale","scale":2}"#,
    ] {
        send(&mut s, request);
    }
    run(&mut s, 0.2);
    assert_eq!(frame_epochs(&mut s), first);
    // configure_panel, reset and a curve edit start a new epoch of every panel: the panels
    // share one clock, so that one restarting restarts all (protocol version 5).
    let configured = epochs(&send(
        &mut s,
        r#"{"type":"configure_panel","panel":1,"integrator":"midpoint"}"#,
    ));
    assert!(configured.iter().all(|&e| e > first[1]));
    assert_eq!(frame_epochs(&mut s), configured);
    let reset = epochs(&send(&mut s, r#"{"type":"reset","panel":2}"#));
    assert!(reset.iter().all(|&e| e > configured[0].max(configured[1])));
    let curve = epochs(&send(
        &mut s,
        r#"{"type":"set_curve","constraint":0,"expr":"bead.x^2 + 200*bead.y"}"#,
    ));
    assert!(curve.iter().all(|&e| e > reset[0].max(reset[1])));
    assert_eq!(frame_epochs(&mut s), curve);
    // A failed request changes nothing.
    send(&mut s, r#"{"type":"configure_panel","panel":1,"dt":-1}"#);
    assert_eq!(frame_epochs(&mut s), curve);
    // A new scene: new panels, new epochs.
    let loaded = epochs(&send(&mut s, r#"{"type":"load_scene","name":"circle"}"#));
    assert!(loaded.iter().all(|&e| e > curve[0]));
    assert_eq!(frame_epochs(&mut s), loaded);
}

#[test]
fn curve_error_columns_count_characters() {
    let scene = r#"
title = "accented"
[world]
gravity = [0.0, 500.0]
[[particle]]
name = "perlé"
mass = 1.0
position = [150.0, -225.0]
[[constraint]]
expr = "perlé.x^2 + 100*perlé.y"
"#;
    let mut s = session();
    let message = serde_json::json!({"type": "load_scene", "toml": scene, "file_name": "p.toml"});
    let replies = send(&mut s, &message.to_string());
    assert!(panels_of(&replies).is_some(), "{replies:?}");
    let expr = "perlé.x^2 + 100*perlé.w";
    let message = serde_json::json!({"type": "set_curve", "constraint": 0, "expr": expr});
    let replies = send(&mut s, &message.to_string());
    let ServerMessage::CurveError {
        code,
        message,
        columns,
        ..
    } = &replies[0]
    else {
        panic!("{replies:?}");
    };
    assert_eq!(*code, ErrorCode::Expression);
    assert!(message.contains("no coordinate `w`"), "{message}");
    // Characters 16..23 (`perlé.w`), which are bytes 17..25.
    assert_eq!(*columns, Some([16, 23]));
    let underlined: String = expr.chars().skip(16).take(7).collect();
    assert_eq!(underlined, "perlé.w");
    // At the end of the input, the place just after it.
    let message =
        serde_json::json!({"type": "set_curve", "constraint": 0, "expr": "perlé.x^2 + ("});
    let replies = send(&mut s, &message.to_string());
    assert!(
        matches!(
            &replies[0],
            ServerMessage::CurveError {
                columns: Some([13, 14]),
                ..
            }
        ),
        "{replies:?}"
    );
}

#[test]
fn frames_say_what_is_conserved() {
    // A bead on a circle whose radius is driven: the driver does work, E - W is conserved.
    let scene = r#"
title = "driven"
[world]
gravity = [0.0, 9.81]
[[particle]]
name = "bead"
mass = 1.0
position = [1.0, 0.0]
[[constraint]]
expr = "bead.x^2 + bead.y^2 - (1 + 0.2*sin(3*t))^2"
"#;
    let mut s = session();
    let message = serde_json::json!({"type": "load_scene", "toml": scene, "file_name": "d.toml"});
    let replies = send(&mut s, &message.to_string());
    assert!(panels_of(&replies).is_some(), "{replies:?}");
    run(&mut s, 1.0);
    let f = &frames(&mut s)[0];
    assert_eq!(f.status, "running", "{f:?}");
    assert!(!f.energy_conserved);
    assert_eq!(
        f.not_conserved_by,
        vec!["driven constraint: constraint 1 depends on t".to_string()]
    );
    assert!(f.work.abs() > 1e-2, "{f:?}");
    assert!(f.energy_error < 1e-4, "{f:?}");
}

/// A session whose first scene is `text`.
fn session_with(name: &str, text: String) -> Session {
    let catalog = Catalog::with_first(NamedScene {
        name: name.into(),
        text,
    });
    Session::new(Arc::new(catalog), Limits::default())
}

fn scene_of(s: &Session) -> SceneInfo {
    match &s.greeting()[1] {
        ServerMessage::Scene(scene) => scene.clone(),
        other => panic!("no scene: {other:?}"),
    }
}

#[test]
fn frames_are_binary_with_the_positions_packed_after_a_json_header() {
    let mut s = session();
    run(&mut s, 0.5);
    // A frame with no step since the last one: no path (tests/truthful.rs has the path).
    s.advance(0.0);
    let ServerMessage::Frame {
        time_scale, panels, ..
    } = s.frame()
    else {
        unreachable!()
    };
    let bytes = encode_frame(time_scale, &panels).unwrap();
    assert_eq!(bytes[..4], FRAME_MAGIC);
    let header_len = u32::from_le_bytes(bytes[4..8].try_into().unwrap()) as usize;
    let header: serde_json::Value = serde_json::from_slice(&bytes[8..8 + header_len]).unwrap();
    assert_eq!(header["type"], "frame");
    let start = (8 + header_len).next_multiple_of(8);
    assert!(bytes[8 + header_len..start].iter().all(|&b| b == 0));
    // 2 panels of 1 particle in 2D: 4 numbers after the header, nothing else.
    assert_eq!(bytes.len(), start + 8 * 4);
    for (k, panel) in panels.iter().enumerate() {
        let h = &header["panels"][k];
        assert!(h.get("x").is_none(), "positions in the header: {h}");
        assert_eq!(h["x_offset"], 2 * k);
        assert_eq!(h["x_count"], 2);
        assert_eq!(h["epoch"], panel.epoch);
        for (i, &x) in panel.x.iter().enumerate() {
            let at = start + 8 * (2 * k + i);
            assert_eq!(f64::from_le_bytes(bytes[at..at + 8].try_into().unwrap()), x);
        }
    }
    // The reference decoder gives the frame back, positions exact.
    let decoded = decode_frame(&bytes).unwrap();
    assert_eq!(decoded["time_scale"], time_scale);
    for (k, panel) in panels.iter().enumerate() {
        let x: Vec<f64> = decoded["panels"][k]["x"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        assert_eq!(x, panel.x);
        assert_eq!(decoded["panels"][k]["t"], panel.t);
    }
    // Not frames: wrong magic, a header past the end, positions cut short.
    assert!(decode_frame(b"beat\0\0\0\0").is_err());
    assert!(decode_frame(&[b'b', b'e', b'a', b'd', 255, 0, 0, 0, b'{']).is_err());
    assert!(decode_frame(&bytes[..bytes.len() - 8]).is_err());
    assert!(decode_frame(&bytes[..bytes.len() - 3]).is_err());
}

#[test]
fn generated_chains_and_cloths_have_their_rods_and_pins() {
    // A chain: a rod to the anchor, then rods between neighbours.
    let n = 100;
    let s = session_with("chain.toml", generated::chain(n, "rattle"));
    let scene = scene_of(&s);
    assert_eq!(scene.particles.len(), n);
    assert_eq!(scene.rods.len(), n);
    assert_eq!(
        scene.rods[0],
        Rod {
            a: 0,
            b: None,
            anchor: Some(vec![0.0, 0.0])
        }
    );
    for i in 1..n {
        assert_eq!(
            scene.rods[i],
            Rod {
                a: i - 1,
                b: Some(i),
                anchor: None
            }
        );
    }
    assert!(scene.pins.is_empty());
    // The view holds everywhere the chain can swing: the disc around the anchor whose
    // radius is the chain's length (no trial run for 100 particles: the reach of its rods).
    let length = n as f64 * generated::LINK;
    let v = scene.view;
    assert!(
        v[0] <= -length && v[1] <= -length && v[2] >= length && v[3] >= length,
        "{v:?}"
    );
    assert!(
        v[2] - v[0] < 3.0 * length && v[3] - v[1] < 3.0 * length,
        "{v:?}"
    );

    // A cloth: rods along the rows and down the columns, pins at the top corners.
    let (rows, cols) = (10, 10);
    let s = session_with("cloth.toml", generated::cloth(rows, cols, "rattle"));
    let scene = scene_of(&s);
    assert_eq!(scene.particles.len(), rows * cols);
    let links = generated::cloth_links(rows, cols);
    assert_eq!(scene.rods.len(), links.len());
    assert_eq!(links.len(), 2 * rows * (cols - 1));
    for (rod, (a, b)) in scene.rods.iter().zip(&links) {
        assert_eq!(
            *rod,
            Rod {
                a: generated::index(cols, a.0, a.1),
                b: Some(generated::index(cols, b.0, b.1)),
                anchor: None
            }
        );
    }
    assert_eq!(
        scene.pins,
        vec![
            Pin {
                particle: 0,
                anchor: vec![0.0, 0.0]
            },
            Pin {
                particle: cols - 1,
                anchor: vec![1.0, 0.0]
            }
        ]
    );
    // Every node stays within its rod distance of the nearer pin: the bottom corners 1, the
    // bottom middle 1 + 4/9 (the view box holds the union of those discs).
    let v = scene.view;
    assert!(v[0] <= -1.5 && v[3] >= 1.5 && v[2] >= 2.5, "{v:?}");
    // One panel (implicit, rattle), and it runs on the rods.
    let mut s = s;
    run(&mut s, 0.1);
    let f = &frames(&mut s)[0];
    assert_eq!(f.status, "running", "{f:?}");
    assert!(f.t > 0.0 && f.constraint_error < 1e-6, "{f:?}");
    assert_eq!(f.x.len(), 2 * rows * cols);

    // The same cloth in 3D: the same rods and pins (drawn at their x-y), three numbers a
    // particle in the frames, and the rows bowed along z.
    let mut s = session_with("cloth.toml", generated::cloth_3d(rows, cols, "rattle"));
    let scene = scene_of(&s);
    assert_eq!(scene.dim, 3);
    assert_eq!(scene.rods.len(), links.len());
    assert_eq!(
        scene
            .pins
            .iter()
            .map(|p| p.anchor.clone())
            .collect::<Vec<_>>(),
        vec![vec![0.0, 0.0, 0.0], vec![1.0, 0.0, 0.0]]
    );
    let bottom_middle = 3 * generated::index(cols, rows - 1, cols / 2) + 2;
    assert!(frames(&mut s)[0].x[bottom_middle] > 0.9 * generated::BOW);
    run(&mut s, 0.1);
    let f = &frames(&mut s)[0];
    assert_eq!(f.status, "running", "{f:?}");
    assert!(f.t > 0.0 && f.constraint_error < 1e-6, "{f:?}");
    assert_eq!(f.x.len(), 3 * rows * cols);
}

#[test]
fn the_view_box_of_a_large_scene_is_bounded_work() {
    // 1000 particles held by nothing: no trial run (the dense solver is not even built for
    // the view), the initial positions padded.
    let mut text = String::from("title = \"free\"\n[world]\ngravity = [0.0, 9.81]\n");
    for i in 0..1000 {
        text.push_str(&format!(
            "[[particle]]\nname = \"p{i}\"\nmass = 1.0\nposition = [{}.0, 0.0]\nvelocity = [0.0, -1.0]\n",
            i % 10
        ));
    }
    let start = std::time::Instant::now();
    let s = session_with("free.toml", text);
    let scene = scene_of(&s);
    assert!(
        start.elapsed().as_secs_f64() < 20.0,
        "{:?}",
        start.elapsed()
    );
    // 9 wide: 0.15 * 9 padding on each side, 0.4 * 9 tall at least.
    let v = scene.view;
    assert!(
        (v[0] + 1.35).abs() < 1e-9 && (v[2] - 10.35).abs() < 1e-9,
        "{v:?}"
    );
    assert!(
        (v[3] - v[1] - (0.4 * 9.0 + 2.0 * 1.35)).abs() < 1e-9,
        "{v:?}"
    );
}

/// A drop while paused, off the parabola x^2 + 100 y = 0 (issue 15's drop (-100, -200)):
/// the session moves it once onto the point of the curve closest to it, (x*, -x*^2/100)
/// with x* the root of x^3 - 15000 x + 500000 = 0 near -136.6 (by Newton here, apart from
/// bead), says so (`start_placed`, the distance moved), and both panels start there, equal
/// to 1e-9. The implicit panel used to start at (-135, -183), the parametric one at
/// (100, -100) on the other side of the bowl.
#[test]
fn drag_start_puts_both_panels_at_the_closest_point_and_says_how_far_it_moved() {
    let mut s = session();
    run(&mut s, 0.5);
    send(&mut s, r#"{"type":"pause"}"#);
    let replies = send(
        &mut s,
        r#"{"type":"set_start","panel":1,"particle":0,"target":[-100,-200]}"#,
    );
    let mut x = -136.0f64;
    for _ in 0..50 {
        x -= (x * x * x - 15000.0 * x + 500000.0) / (3.0 * x * x - 15000.0);
    }
    let exact = [x, -x * x / 100.0];
    let Some(ServerMessage::StartPlaced {
        panel,
        particle,
        dropped,
        placed,
        moved,
        positions,
    }) = replies.first()
    else {
        panic!("{replies:?}");
    };
    assert_eq!((*panel, *particle), (1, 0));
    // Every particle's start (one here): the placed point.
    assert_eq!(positions, placed);
    assert_eq!(dropped, &[-100.0, -200.0]);
    assert!(
        (placed[0] - exact[0]).abs() < 1e-9 && (placed[1] - exact[1]).abs() < 1e-9,
        "{placed:?} {exact:?}"
    );
    let distance = ((exact[0] + 100.0).powi(2) + (exact[1] + 200.0).powi(2)).sqrt();
    assert!((moved - distance).abs() < 1e-9, "{moved} {distance}");
    assert!(panels_of(&replies).is_some(), "{replies:?}");
    let panels = frames(&mut s);
    assert_eq!(panels.len(), 2);
    for p in &panels {
        assert_eq!(p.t, 0.0);
        assert!(
            (p.x[0] - exact[0]).abs() < 1e-9 && (p.x[1] - exact[1]).abs() < 1e-9,
            "panel {}: {:?}",
            p.id,
            p.x
        );
    }
    // A drop on the curve is not moved.
    let replies = send(
        &mut s,
        r#"{"type":"set_start","panel":2,"particle":0,"target":[50,-25]}"#,
    );
    let Some(ServerMessage::StartPlaced { moved, .. }) = replies.first() else {
        panic!("{replies:?}");
    };
    assert!(*moved < 1e-9, "{moved}");
}

/// A scene of 1 s: a bead on a circle (two panels, dt 0.01).
fn one_second() -> Session {
    let text = SHIPPED
        .iter()
        .find(|(n, _)| *n == "circle")
        .unwrap()
        .1
        .replace("dt = 0.001", "dt = 0.01")
        .replace("duration = 10.0", "duration = 1.0");
    let mut s = session();
    let message =
        serde_json::json!({"type": "load_scene", "toml": text, "file_name": "short.toml"});
    assert!(panels_of(&send(&mut s, &message.to_string())).is_some());
    s
}

fn clock(s: &mut Session) -> bead_viewer::protocol::Clock {
    match s.frame() {
        ServerMessage::Frame { clock, .. } => clock,
        other => panic!("not a frame: {other:?}"),
    }
}

/// The viewer runs the scene's duration, as `bead run` does, and stops there (issue 18: it
/// ran forever): every panel at its last step within the end, paused; Play starts again
/// from the start. Loop starts again by itself; Continue goes on past the end.
#[test]
fn the_clock_stops_loops_or_goes_on_at_the_scenes_end() {
    let mut s = one_second();
    assert_eq!(clock(&mut s).end, Some(1.0));
    assert_eq!(clock(&mut s).at_end, AtEnd::Stop);
    run(&mut s, 1.5);
    let c = clock(&mut s);
    assert!(c.ended);
    for f in frames(&mut s) {
        assert_eq!(f.status, "paused", "{} at {}", f.status, f.t);
        assert_eq!(f.steps, 100);
        assert!((f.t - 1.0).abs() < 1e-12, "t = {}", f.t);
    }
    // Stays there.
    run(&mut s, 0.5);
    assert!(frames(&mut s).iter().all(|f| f.steps == 100));
    // Play: from the start again, one restart.
    let generation = c.generation;
    send(&mut s, r#"{"type":"play"}"#);
    run(&mut s, 0.25);
    let c = clock(&mut s);
    assert!(!c.ended && c.generation == generation + 1);
    assert!(frames(&mut s)
        .iter()
        .all(|f| f.status == "running" && (f.t - 0.25).abs() < 0.011));
    // Loop: at the end every panel starts again and goes on.
    send(&mut s, r#"{"type":"set_at_end","at_end":"loop"}"#);
    run(&mut s, 1.0);
    let c = clock(&mut s);
    assert_eq!((c.at_end, c.ended), (AtEnd::Loop, false));
    assert_eq!(c.generation, generation + 2);
    for f in frames(&mut s) {
        assert_eq!(f.status, "running");
        assert!(f.t < 0.3, "t = {}", f.t);
    }
    // Continue: past the end.
    send(&mut s, r#"{"type":"set_at_end","at_end":"continue"}"#);
    run(&mut s, 1.5);
    assert!(frames(&mut s)
        .iter()
        .all(|f| f.status == "running" && f.t > 1.2));
    // Back to Stop past the end: the clock stops where it stands.
    send(&mut s, r#"{"type":"set_at_end","at_end":"stop"}"#);
    run(&mut s, 0.1);
    assert!(clock(&mut s).ended);
    assert!(frames(&mut s).iter().all(|f| f.status == "paused"));
    let message = parse_client_message(
        r#"{"type":"set_at_end","at_end":"later"}"#,
        &Limits::default(),
    );
    assert!(message.is_err());
}

/// Advance `seconds` of wall time in frames of 1/60 s, a frame after each advance as the
/// server sends them, keeping in `drawn` the curves each panel's page draws (the panel's, or
/// the last a frame carried); calls `check` with every frame's panels and their curves.
fn run_drawn(
    s: &mut Session,
    seconds: f64,
    drawn: &mut [Vec<Vec<f64>>],
    mut check: impl FnMut(&PanelFrame, &[Vec<f64>]),
) {
    for _ in 0..(seconds * 60.0).round() as usize {
        s.advance(1.0 / 60.0);
        for (k, f) in frames(s).iter().enumerate() {
            if let Some(curves) = &f.curves {
                drawn[k] = curves.clone();
            }
            check(f, &drawn[k]);
        }
    }
}

/// The distance from point `x` to the nearest segment of `lines` (points of `dim` numbers).
fn distance_to_lines(x: &[f64], lines: &[Vec<f64>], dim: usize) -> f64 {
    let mut best = f64::INFINITY;
    for line in lines {
        let points: Vec<&[f64]> = line.chunks(dim).collect();
        for pair in points.windows(2) {
            let (a, b) = (pair[0], pair[1]);
            let ab: Vec<f64> = (0..dim).map(|i| b[i] - a[i]).collect();
            let ax: Vec<f64> = (0..dim).map(|i| x[i] - a[i]).collect();
            let len2: f64 = ab.iter().map(|v| v * v).sum();
            let s = if len2 > 0.0 {
                (ab.iter().zip(&ax).map(|(u, v)| u * v).sum::<f64>() / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let d2: f64 = (0..dim).map(|i| (ax[i] - s * ab[i]).powi(2)).sum();
            best = best.min(d2.sqrt());
        }
    }
    best
}

#[test]
fn the_helix_wire_is_drawn_under_the_bead_at_every_frame() {
    // The bead climbs to phi = 2.4 and slides down past phi = -7.9 at 4.9 s, beyond the
    // first interval drawn (phi in [-2 pi, 2 pi]); with at_end = continue it is at phi = -760
    // at 30 s. The wire drawn (both panels: the parametric map, the implicit panel's map)
    // is under the bead at every frame: to 1e-3 m of R = 1 m.
    let mut s = session();
    let replies = send(&mut s, r#"{"type":"load_scene","name":"helix"}"#);
    let panels = panels_of(&replies).expect("panels");
    assert_eq!(panels.len(), 2);
    let mut drawn: Vec<Vec<Vec<f64>>> = panels.iter().map(|p| p.curves.clone()).collect();
    assert!(panels.iter().all(|p| p.curve_source == "parametric"));
    send(&mut s, r#"{"type":"play"}"#);
    let mut checked = 0usize;
    let mut latest = 0.0f64;
    let mut check = |f: &PanelFrame, curves: &[Vec<f64>]| {
        let d = distance_to_lines(&f.x, curves, 3);
        assert!(
            d < 1e-3,
            "panel {} at t = {}: the bead is {d} m from the drawn wire",
            f.id,
            f.t
        );
        latest = latest.max(f.t);
        checked += 1;
    };
    // To the end (5 s), where it stops; then a loop around and past the end again.
    run_drawn(&mut s, 5.2, &mut drawn, &mut check);
    assert!(clock(&mut s).ended);
    send(&mut s, r#"{"type":"set_at_end","at_end":"loop"}"#);
    send(&mut s, r#"{"type":"play"}"#);
    run_drawn(&mut s, 6.0, &mut drawn, &mut check);
    // Going on far past the end: the drawn part is a window around the bead.
    send(&mut s, r#"{"type":"set_at_end","at_end":"continue"}"#);
    send(&mut s, r#"{"type":"set_time_scale","scale":4}"#);
    run_drawn(&mut s, 7.0, &mut drawn, &mut check);
    assert!(checked > 2 * 1000, "{checked} frames checked");
    assert!(latest > 25.0, "ran to t = {latest}");
    // A frame carries the curves only when they were made again.
    let carried = frames(&mut s).iter().filter(|f| f.curves.is_some()).count();
    assert_eq!(carried, 0);
}

#[test]
fn set_view_makes_the_curves_again_over_the_region_shown() {
    let mut s = session();
    send(&mut s, r#"{"type":"load_scene","name":"parabola"}"#);
    let first = frames(&mut s);
    assert!(first.iter().all(|f| f.curves.is_none()));
    let id = first[0].id;
    // Far to the right of the view box: the parabola x^2 + 100 y = 0 at x in [2000, 3000]
    // has y in [-90000, -40000].
    let view = [2000.0, -95000.0, 3000.0, -35000.0];
    let replies = send(
        &mut s,
        &format!(r#"{{"type":"set_view","panel":{id},"view":{view:?}}}"#),
    );
    assert!(replies.is_empty(), "{replies:?}");
    let f = frames(&mut s);
    assert_eq!(f[0].curve_region, view);
    let curves = f[0].curves.as_ref().expect("the new curves");
    let points: Vec<&[f64]> = curves.iter().flat_map(|l| l.chunks(2)).collect();
    assert!(points.len() > 100);
    for p in &points {
        assert!(p[0] >= 1900.0 && p[0] <= 3100.0, "{p:?}");
        // On the parabola, to the contour's resolution (1.2 * 60000 / 160 in y).
        assert!((p[1] + p[0] * p[0] / 100.0).abs() < 500.0, "{p:?}");
    }
    // Sent once; the other panel keeps its own.
    assert!(f[1].curves.is_none() && f[1].curve_region != view);
    assert!(frames(&mut s).iter().all(|f| f.curves.is_none()));
    // Regions that are not one.
    for bad in [
        "[1, 0, 0, 1]",
        "[0, 0, 1, 0]",
        "[0, 0, 1e13, 1]",
        r#"[0, 0, 1, "x"]"#,
    ] {
        let json = format!(r#"{{"type":"set_view","panel":{id},"view":{bad}}}"#);
        match parse_client_message(&json, &Limits::default()) {
            Ok(message) => {
                let replies = s.handle(message);
                assert_eq!(code_of(&replies), Some(ErrorCode::BadValue), "{bad}");
                assert!(
                    error_of(&replies).unwrap().contains("x_min < x_max"),
                    "{bad}"
                );
            }
            Err(_) => assert!(bad.contains('"'), "{bad} should parse"),
        }
    }
    assert_eq!(frames(&mut s)[0].curve_region, view);
}

/// Law: a panel asked for its reference runs dopri5 at rtol 1e-12 on its own system and form
/// from its own start, stands at the panel's t in every frame, and reports the distance
/// between the two, largest over particles: the panel's error. Checked against the same
/// reference run by the library alone (the same bits), against the parametric form's
/// solution at rtol 1e-13 (an independent formulation: the ghost is the true motion), and
/// against the distance recomputed from the frame's positions.
#[test]
fn the_reference_ghost_is_the_true_motion_and_its_distance_the_panels_error() {
    use bead::formulation::Method;
    use bead::simulate::{Simulation, SimulationConfig};
    let mut s = session();
    let replies = send(
        &mut s,
        r#"{"type":"configure_panel","panel":1,"reference":true}"#,
    );
    let panels = panels_of(&replies).expect("panels");
    assert!(panels[0].reference && !panels[1].reference);
    send(&mut s, r#"{"type":"play"}"#);
    run(&mut s, 2.0);
    let all = frames(&mut s);
    let (f, other) = (&all[0], &all[1]);
    assert!(other.reference.is_none() && other.reference_note.is_none());
    let reference = f.reference.as_ref().expect("a reference");
    assert!(f.t > 1.0, "{}", f.t);
    assert_eq!(reference.t, f.t);
    let distance =
        f.x.iter()
            .zip(&reference.x)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f64>()
            .sqrt();
    assert_eq!(reference.distance, distance);
    // rk4 at 1/60 on the parabola: a visible but small error.
    assert!(distance > 1e-6 && distance < 1.0, "{distance}");

    // The library alone, the same way: the same positions bit for bit.
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/parabola.toml");
    let scene = bead::scene::Scene::load(&path, &[]).unwrap();
    let dt = 1.0 / 60.0;
    let steps = (f.t / dt).round() as u64;
    let alone = |method: Method, rtol: f64| {
        let mut config = SimulationConfig {
            method,
            integrator: IntegratorKind::Dopri5,
            dt,
            ..SimulationConfig::default()
        };
        config.settings.rtol = rtol;
        config.settings.atol = rtol * 225.0;
        let mut sim = Simulation::new(scene.system.clone(), config).unwrap();
        sim.reset_onto_constraints().unwrap();
        for k in 1..=steps {
            sim.advance_to(k as f64 * dt).unwrap();
        }
        sim.positions().to_vec()
    };
    assert_eq!(alone(Method::Implicit, 1e-12), reference.x);
    let truth = alone(Method::Parametric, 1e-13);
    for (a, b) in reference.x.iter().zip(&truth) {
        assert!((a - b).abs() < 1e-6, "{:?} vs {truth:?}", reference.x);
    }

    // Off again: no reference, and none is sent.
    send(
        &mut s,
        r#"{"type":"configure_panel","panel":1,"reference":false}"#,
    );
    assert!(frames(&mut s)[0].reference.is_none());
}

/// Law: the reference follows a drag as the panel does (the same spring and damping act on
/// it), so a panel that is itself accurate stays within its tolerance of it; a scene too
/// large for a reference says so instead of holding the panel back.
#[test]
fn the_reference_is_dragged_with_the_panel_and_large_scenes_say_why_they_have_none() {
    let mut s = session();
    send(
        &mut s,
        r#"{"type":"configure_panel","panel":1,"integrator":"dopri5","reference":true}"#,
    );
    send(&mut s, r#"{"type":"play"}"#);
    drag(&mut s, 1, [-100.0, -100.0]);
    run(&mut s, 1.0);
    let f = &frames(&mut s)[0];
    let reference = f.reference.as_ref().expect("a reference");
    assert!(f.x[0] < -20.0, "the drag pulled the bead: {:?}", f.x);
    assert!(reference.distance < 1e-3, "{reference:?}");
    send(&mut s, r#"{"type":"drag_end","panel":1}"#);
    run(&mut s, 0.5);
    assert!(frames(&mut s)[0].reference.is_some());

    let replies = send(&mut s, r#"{"type":"load_scene","name":"net"}"#);
    assert!(error_of(&replies).is_none(), "{replies:?}");
    let id = panels_of(&replies).expect("panels")[0].id;
    let replies = send(
        &mut s,
        &format!(r#"{{"type":"configure_panel","panel":{id},"reference":true}}"#),
    );
    assert!(error_of(&replies).is_none(), "{replies:?}");
    let f = &frames(&mut s)[0];
    assert!(f.reference.is_none());
    let note = f.reference_note.as_deref().expect("a note");
    assert!(note.contains("coordinates"), "{note}");
}

/// The ball of `bounce` leaves the drawn bowl: its frames put it off the curve (C < 0, in
/// flight, far more than the drift of a bead on a wire) and later back on it, one panel of
/// the implicit form; the curve is the bowl's contour.
#[test]
fn the_bounce_scene_shows_the_ball_off_the_curve_and_back() {
    let mut s = session();
    let replies = send(&mut s, r#"{"type":"load_scene","name":"bounce"}"#);
    let panels = panels_of(&replies).unwrap();
    assert_eq!(panels.len(), 2);
    assert_eq!(panels[0].curve_source, "contour");
    assert_eq!(panels[1].curve_source, "parametric");
    // Per panel: after its first touch of the bowl, how far it flies off again (a bounce),
    // and whether it later stays on it (t > 1 s).
    let mut seen = [(false, 0.0_f64, false); 2];
    for _ in 0..(6 * 60) {
        s.advance(1.0 / 60.0);
        let frames = frames(&mut s);
        for (f, (touched, highest_off, landed)) in frames.iter().zip(seen.iter_mut()) {
            let (x, y) = (f.x[0], f.x[1]);
            // Distance above the bowl (+y down): |C| / |grad C|, C = x^2 + 100 y <= 0.
            let c = x * x + 100.0 * y;
            assert!(
                c <= 1e-6 * (x * x).max(1.0),
                "panel {}: below the bowl at t = {}: C = {c}",
                f.id,
                f.t
            );
            let off = -c / (4.0 * x * x + 1e4).sqrt();
            if *touched {
                *highest_off = highest_off.max(off);
            }
            // In flight (off by more than a pixel) the bowl exerts no force; on it, it pushes.
            let arrows = f.arrows.as_ref().expect("a one-particle scene has arrows");
            let force = arrows.constraint[0].hypot(arrows.constraint[1]);
            if off > 1.0 {
                assert_eq!(
                    force, 0.0,
                    "panel {}: a force in flight at t = {}",
                    f.id, f.t
                );
            }
            if f.t > 4.0 {
                assert!(
                    force > 0.0,
                    "panel {}: no force on the bowl at t = {}",
                    f.id,
                    f.t
                );
            }
            // Within a pixel: frames fall between impacts.
            *touched |= off < 1.0;
            *landed |= f.t > 1.0 && off < 1e-6;
            assert!(
                f.energy_error < 1e-4,
                "panel {}: E - W at t = {}: {}",
                f.id,
                f.t,
                f.energy_error
            );
            let contact = f.contact.as_ref().expect("a unilateral scene");
            assert_eq!(contact.detached.len(), 1);
        }
        // Both forms switch alike: the same counts in every frame.
        assert_eq!(frames[0].contact, frames[1].contact, "t = {}", frames[0].t);
    }
    for (touched, highest_off, landed) in seen {
        // Bounced off by several pixels (about 6.5 px at e = 0.7).
        assert!(touched && highest_off > 3.0, "{highest_off}");
        assert!(landed);
    }
}
