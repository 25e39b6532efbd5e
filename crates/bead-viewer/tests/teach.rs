//! Issue 9's comparison and teaching requests, on a session without a network: one clock
//! for all panels, the distance between formulations, parameter changes, a start state set
//! by dragging while paused, the equations, and the settings each panel offers.

use std::sync::Arc;

use bead_viewer::protocol::{
    parse_client_message, Clock, ErrorCode, Limits, PanelFrame, PanelInfo, SceneInfo, ServerMessage,
};
use bead_viewer::scenes::Catalog;
use bead_viewer::session::Session;

fn session() -> Session {
    Session::new(Arc::new(Catalog::shipped()), Limits::default())
}

fn send(session: &mut Session, json: &str) -> Vec<ServerMessage> {
    match parse_client_message(json, &Limits::default()) {
        Ok(message) => session.handle(message),
        Err(e) => panic!("{json} did not parse: {e}"),
    }
}

fn frame(session: &mut Session) -> (Clock, Vec<PanelFrame>) {
    match session.frame() {
        ServerMessage::Frame { clock, panels, .. } => (clock, panels),
        other => panic!("not a frame: {other:?}"),
    }
}

fn run(session: &mut Session, seconds: f64) {
    for _ in 0..(seconds * 60.0).round() as usize {
        session.advance(1.0 / 60.0);
    }
}

fn scene_of(replies: &[ServerMessage]) -> Option<SceneInfo> {
    replies.iter().find_map(|m| match m {
        ServerMessage::Scene(info) => Some(info.clone()),
        _ => None,
    })
}

fn panels_of(replies: &[ServerMessage]) -> Option<Vec<PanelInfo>> {
    replies.iter().find_map(|m| match m {
        ServerMessage::Panels { panels } => Some(panels.clone()),
        _ => None,
    })
}

fn error_of(replies: &[ServerMessage]) -> Option<(ErrorCode, String)> {
    replies.iter().find_map(|m| match m {
        ServerMessage::Error { code, message, .. } => Some((*code, message.clone())),
        _ => None,
    })
}

/// Panels of different formulations advance to the same t together, and the frame carries
/// each panel's distance to the first at that t, which is what the positions say.
#[test]
fn panels_share_one_clock_and_the_frame_has_their_distance() {
    let mut s = session();
    run(&mut s, 1.0);
    let (clock, panels) = frame(&mut s);
    assert_eq!(panels.len(), 2);
    assert_eq!(panels[0].t, panels[1].t, "{panels:?}");
    assert!(panels[0].t > 0.0);
    assert!(clock.sim_rate > 0.0, "{clock:?}");
    assert_eq!(panels[0].distance, None);
    let d = panels[1].distance.expect("same t: a distance");
    let by_hand = panels[0]
        .x
        .chunks(2)
        .zip(panels[1].x.chunks(2))
        .map(|(a, b)| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt())
        .fold(0.0, f64::max);
    assert_eq!(d, by_hand);
    // The two formulations of rk4 at dt = 1/60 agree closely on the parabola.
    assert!(d < 1.0, "{d}");
}

/// Adding a panel restarts every panel (one clock), and a reset of one panel resets all.
#[test]
fn add_and_reset_act_on_all_panels() {
    let mut s = session();
    run(&mut s, 0.5);
    let generation = frame(&mut s).0.generation;
    let replies = send(&mut s, r#"{"type":"add_panel","integrator":"verlet"}"#);
    assert_eq!(panels_of(&replies).unwrap().len(), 3);
    let (clock, panels) = frame(&mut s);
    assert!(clock.generation > generation);
    assert!(panels.iter().all(|p| p.t == 0.0), "{panels:?}");
    run(&mut s, 0.5);
    let panels = frame(&mut s).1;
    assert!(panels.iter().all(|p| p.t == panels[0].t && p.t > 0.0));
    send(&mut s, r#"{"type":"reset","panel":2}"#);
    assert!(frame(&mut s).1.iter().all(|p| p.t == 0.0));
}

/// A panel that cannot keep up holds the others back, and the frame names it.
#[test]
fn a_slow_panel_slows_every_panel_and_is_named() {
    let mut s = session();
    // 1e-6 s steps: real time needs 10^6 steps a second, far beyond a frame's budget.
    send(&mut s, r#"{"type":"configure_panel","panel":2,"dt":1e-6}"#);
    run(&mut s, 0.5);
    let (clock, panels) = frame(&mut s);
    assert_eq!(clock.limited_by, Some(2), "{clock:?}");
    assert!(panels[1].behind);
    // The fast panel waited: it is at most one frame of real time ahead.
    assert!(panels[0].t <= panels[1].t + 1.0 / 60.0 + 1e-9, "{panels:?}");
    // Below real time: at most 10^4 steps of 1e-6 s per panel in a frame of 1/60 s, 0.6 s/s.
    assert!(clock.sim_rate <= 0.6 + 1e-6, "{clock:?}");
}

/// A server held up for half a second (a loaded machine) advances the simulation by at
/// most 0.1 s, and says so: the rate is measured against the wall time that passed, 0.2,
/// not against what the clock was allowed to take.
#[test]
fn the_rate_tells_a_held_up_server() {
    let mut s = session();
    s.advance(0.5);
    let (clock, panels) = frame(&mut s);
    assert!((panels[0].t - 0.1).abs() < 1e-9, "{panels:?}");
    assert!(
        (clock.sim_rate - panels[0].t / 0.5).abs() < 1e-9,
        "{clock:?}"
    );
}

/// A slider change reloads the scene with the new value and restarts every panel: a new
/// generation, the parameter's new value, and physics that follows it (the potential of the
/// same start state scales with g).
#[test]
fn a_parameter_change_reloads_the_scene_and_restarts_the_panels() {
    let mut s = session();
    let scene = scene_of(&s.greeting()).unwrap();
    let g = scene
        .params
        .iter()
        .find(|p| p.name == "g")
        .expect("parabola has g");
    assert!(g.min < g.value && g.value < g.max);
    run(&mut s, 0.3);
    let (before, panels) = frame(&mut s);
    let v0 = panels[0].energy_initial;
    let replies = send(
        &mut s,
        &format!(
            r#"{{"type":"set_param","name":"g","value":{}}}"#,
            2.0 * g.value
        ),
    );
    let scene = scene_of(&replies).expect("a new scene");
    assert_eq!(
        scene.params.iter().find(|p| p.name == "g").unwrap().value,
        2.0 * g.value
    );
    // The range stays the first one.
    assert_eq!(
        scene.params.iter().find(|p| p.name == "g").unwrap().max,
        g.max
    );
    assert_eq!(panels_of(&replies).unwrap().len(), 2);
    let (after, panels) = frame(&mut s);
    assert!(after.generation > before.generation);
    assert!(panels.iter().all(|p| p.t == 0.0));
    assert!(
        (panels[0].energy_initial - 2.0 * v0).abs() < 1e-9 * v0.abs(),
        "{} vs {v0}",
        panels[0].energy_initial
    );
    // Out of range, unknown, not finite: an error, and nothing changes.
    for (json, code) in [
        (
            format!(
                r#"{{"type":"set_param","name":"g","value":{}}}"#,
                100.0 * g.max
            ),
            ErrorCode::BadValue,
        ),
        (
            r#"{"type":"set_param","name":"gee","value":1}"#.to_string(),
            ErrorCode::UnknownParam,
        ),
    ] {
        let replies = send(&mut s, &json);
        let (got, message) = error_of(&replies).expect("an error");
        assert_eq!(got, code, "{message}");
        assert!(message.contains('g'), "{message}");
        assert_eq!(frame(&mut s).0.generation, after.generation);
    }
    assert!(parse_client_message(
        r#"{"type":"set_param","name":"g","value":"NaN"}"#,
        &Limits::default()
    )
    .is_err());
}

/// Dragging while paused sets the start state: every panel restarts at t = 0 from it, on the
/// curve and at rest, both formulations at the same place.
#[test]
fn a_start_state_set_while_paused_restarts_every_panel_on_the_curve() {
    let mut s = session();
    send(&mut s, r#"{"type":"pause"}"#);
    let generation = frame(&mut s).0.generation;
    let replies = send(
        &mut s,
        r#"{"type":"set_start","panel":1,"particle":0,"target":[-70,-45]}"#,
    );
    assert!(panels_of(&replies).is_some(), "{replies:?}");
    let (clock, panels) = frame(&mut s);
    assert!(clock.generation > generation);
    for p in &panels {
        assert_eq!(p.t, 0.0);
        assert_eq!(p.status, "paused");
        let (x, y) = (p.x[0], p.x[1]);
        assert!((x * x + 100.0 * y).abs() < 1e-6, "{p:?}");
        assert!((x + 70.0).abs() < 5.0, "{p:?}");
        assert_eq!(p.kinetic, 0.0);
    }
    assert!(panels[1].distance.unwrap() < 0.5, "{panels:?}");
    // Bad targets are refused and change nothing.
    for json in [
        r#"{"type":"set_start","panel":1,"particle":7,"target":[0,0]}"#,
        r#"{"type":"set_start","panel":1,"particle":0,"target":[0]}"#,
        r#"{"type":"set_start","panel":1,"particle":0,"target":[1e300,0]}"#,
        r#"{"type":"set_start","panel":9,"particle":0,"target":[0,0]}"#,
    ] {
        let replies = send(&mut s, json);
        assert!(error_of(&replies).is_some(), "{json}: {replies:?}");
        assert_eq!(frame(&mut s).0.generation, clock.generation, "{json}");
    }
}

/// The equations each formulation derived, as `bead check` prints them.
#[test]
fn the_equations_of_each_formulation() {
    let mut s = session();
    for (panel, words) in [(1, "Cddot = J a + bias"), (2, "acceleration = J q'' + h")] {
        let replies = send(
            &mut s,
            &format!(r#"{{"type":"equations","panel":{panel}}}"#),
        );
        let Some(ServerMessage::Equations { text, mathml, .. }) = replies.first() else {
            panic!("{replies:?}");
        };
        assert!(text.contains(words), "{text}");
        // The equation of motion typeset, written out: lambda for the parabola's one row,
        // M(q) q'' = Q for its one coordinate.
        let written_out = if panel == 1 {
            "λ written out:</p>\n<math display=\"block\"><mi>λ</mi><mo>=</mo>"
        } else {
            "<p>With one coordinate, written out:</p>"
        };
        assert!(mathml.contains(written_out), "{mathml}");
    }
}

/// Which settings a panel offers comes from the library's legality check.
#[test]
fn settings_that_do_nothing_are_marked() {
    let s = session();
    let panels = panels_of(&s.greeting()).unwrap();
    assert!(panels[0].applies.feedback && panels[0].applies.project);
    assert!(!panels[1].applies.feedback && !panels[1].applies.project);
    let mut s = session();
    let replies = send(
        &mut s,
        r#"{"type":"configure_panel","panel":1,"integrator":"dopri5"}"#,
    );
    let panels = panels_of(&replies).unwrap();
    assert!(!panels[0].applies.project, "{:?}", panels[0].applies);
}

fn load(s: &mut Session, name: &str) -> SceneInfo {
    let replies = send(s, &format!(r#"{{"type":"load_scene","name":"{name}"}}"#));
    scene_of(&replies).unwrap_or_else(|| panic!("{name} did not load: {replies:?}"))
}

fn load_text(s: &mut Session, text: &str) -> SceneInfo {
    let message = serde_json::json!({"type": "load_scene", "toml": text, "file_name": "t.toml"});
    let replies = send(s, &message.to_string());
    scene_of(&replies).unwrap_or_else(|| panic!("did not load: {replies:?}"))
}

fn param<'a>(scene: &'a SceneInfo, name: &str) -> &'a bead_viewer::protocol::ParamInfo {
    scene.params.iter().find(|p| p.name == name).unwrap()
}

fn set(s: &mut Session, name: &str, field: &str, value: serde_json::Value) -> Vec<ServerMessage> {
    let message = serde_json::json!({"type": "set_param", "name": name, field: value});
    send(s, &message.to_string())
}

/// Issue 18, item 2: parameters a class can use. Ranges from the scene through 0 and
/// negatives with exact ends, typed values and expressions, whole numbers, derived
/// parameters shown and not set, units and descriptions.
#[test]
fn parameters_take_typed_values_zero_negatives_exact_ends_and_whole_numbers() {
    use std::f64::consts::PI;
    let mut s = session();
    let scene = load(&mut s, "circle");
    let theta0 = param(&scene, "theta0");
    assert_eq!((theta0.min, theta0.max), (-PI, PI));
    assert!(theta0.bounded && !theta0.integer && theta0.derived.is_none());
    assert_eq!(theta0.unit.as_deref(), Some("rad"));
    assert!(theta0
        .description
        .as_deref()
        .unwrap()
        .contains("initial angle"));
    assert_eq!(param(&scene, "g").unit.as_deref(), Some("m/s^2"));
    // The right end exactly (pi from the slider's end is the range's own bits), 0, negative
    // values, and an expression typed in the number box.
    for (field, value, expected) in [
        ("value", serde_json::json!(PI), PI),
        ("value", serde_json::json!(0.0), 0.0),
        ("value", serde_json::json!(-1.25), -1.25),
        ("expr", serde_json::json!("-pi/4"), -PI / 4.0),
        ("expr", serde_json::json!("pi/3"), PI / 3.0),
    ] {
        let replies = set(&mut s, "theta0", field, value.clone());
        let scene = scene_of(&replies).unwrap_or_else(|| panic!("{value}: {replies:?}"));
        assert_eq!(
            param(&scene, "theta0").value.to_bits(),
            expected.to_bits(),
            "{value}"
        );
        assert_eq!(param(&scene, "theta0").min, -PI);
    }
    // "pi/3" typed is the scene file's own "pi/3", bit for bit: the start is the same.
    let (_, panels) = frame(&mut s);
    let mut fresh = session();
    load(&mut fresh, "circle");
    assert_eq!(frame(&mut fresh).1[0].x, panels[0].x);
    // Beyond the scene's range, a bad expression, both or neither of value and expr.
    for (json, code, words) in [
        (
            r#"{"type":"set_param","name":"theta0","value":3.2}"#,
            ErrorCode::BadValue,
            "must be a number in [-3.14159",
        ),
        (
            r#"{"type":"set_param","name":"theta0","expr":"pi/"}"#,
            ErrorCode::BadValue,
            "parameter `theta0`: ",
        ),
        (
            r#"{"type":"set_param","name":"theta0","expr":"2*L"}"#,
            ErrorCode::BadValue,
            "unknown name `L`; a typed value may use numbers, pi and e",
        ),
        (
            r#"{"type":"set_param","name":"theta0","expr":"1/0"}"#,
            ErrorCode::BadValue,
            "not a finite number",
        ),
        (
            r#"{"type":"set_param","name":"theta0","value":1,"expr":"1"}"#,
            ErrorCode::BadRequest,
            "exactly one of `value` and `expr`",
        ),
        (
            r#"{"type":"set_param","name":"theta0"}"#,
            ErrorCode::BadRequest,
            "exactly one of `value` and `expr`",
        ),
    ] {
        let replies = send(&mut s, json);
        let (got, message) = error_of(&replies).unwrap_or_else(|| panic!("{json}: {replies:?}"));
        assert_eq!(got, code, "{json}: {message}");
        assert!(message.contains(words), "{json}: {message}");
    }

    // Whole numbers: the chain's N counts links (a `for` range).
    let chain = load_text(
        &mut s,
        &std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../scenes/chain.toml"
        ))
        .unwrap()
        .replace("N = { value = 1000,", "N = { value = 5,"),
    );
    let n = param(&chain, "N");
    assert!(
        n.integer && n.bounded && (n.min, n.max) == (1.0, 2000.0),
        "{n:?}"
    );
    let replies = set(&mut s, "N", "value", serde_json::json!(7));
    assert_eq!(scene_of(&replies).expect("N = 7").particles.len(), 7);
    let replies = set(&mut s, "N", "value", serde_json::json!(7.5));
    let (code, message) = error_of(&replies).unwrap();
    assert_eq!(code, ErrorCode::BadValue);
    assert_eq!(message, "parameter `N` is a whole number, got 7.5");

    // Derived parameters: shown with their expression, not set.
    let cloth = load_text(
        &mut s,
        &std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../scenes/cloth.toml"
        ))
        .unwrap()
        .replace("W = { value = 50,", "W = { value = 4,")
        .replace("H = { value = 50,", "H = { value = 4,"),
    );
    let l = param(&cloth, "L");
    assert_eq!(l.derived.as_deref(), Some("S/(W-1)"));
    assert_eq!(l.depends_on, ["S", "W"]);
    assert_eq!(l.value, 1.0 / 3.0);
    assert!(param(&cloth, "W").integer && param(&cloth, "H").integer);
    assert!(
        param(&cloth, "A").derived.is_none(),
        "pi/3 names no parameter"
    );
    let replies = set(&mut s, "L", "value", serde_json::json!(0.5));
    let (code, message) = error_of(&replies).unwrap();
    assert_eq!(code, ErrorCode::BadValue);
    assert_eq!(
        message,
        "parameter `L` is derived (L = S/(W-1)): change S, W instead"
    );
    // Changing W moves L with it.
    let replies = set(&mut s, "W", "value", serde_json::json!(5));
    assert_eq!(param(&scene_of(&replies).unwrap(), "L").value, 0.25);

    // No range in the scene: through 0 to twice the value, and any finite value typed
    // (the slider widens to it and stays so).
    let plain = load_text(
        &mut s,
        "[params]\nk = 3.0  # spring constant\n[world]\ngravity = [0.0, 1.0]\n[[particle]]\nname = \"a\"\nmass = 1.0\nposition = [\"k\", 0.0]\n",
    );
    let k = param(&plain, "k");
    assert!(!k.bounded && (k.min, k.max) == (0.0, 6.0), "{k:?}");
    assert_eq!(k.description.as_deref(), Some("spring constant"));
    let replies = set(&mut s, "k", "value", serde_json::json!(-40.0));
    let k = param(&scene_of(&replies).unwrap(), "k").clone();
    assert_eq!((k.value, k.min, k.max), (-40.0, -40.0, 6.0));
    let replies = set(&mut s, "k", "value", serde_json::json!(1.0));
    let k = param(&scene_of(&replies).unwrap(), "k").clone();
    assert_eq!((k.value, k.min, k.max), (1.0, -40.0, 6.0));
    let replies = set(&mut s, "k", "value", serde_json::json!(1e13));
    assert_eq!(error_of(&replies).unwrap().0, ErrorCode::BadValue);
}

/// The rod's force on the pendulum bob of mass m at x moving with v, gravity g along +y:
/// Newton along the rod, T = m (g y / r + |v|^2 / r), F = -T x / r (independent of bead).
fn rod_force(m: f64, g: f64, x: &[f64], v: &[f64]) -> [f64; 2] {
    let r = x[0].hypot(x[1]);
    let tension = m * (g * x[1] / r + (v[0] * v[0] + v[1] * v[1]) / r);
    [-tension * x[0] / r, -tension * x[1] / r]
}

/// Issue 18, item 4: the arrows' forces. On the circle pendulum the implicit panel's row
/// force lambda grad C and both panels' total constraint force are the rod's tension from
/// Newton's law; the weight is m g; nothing else acts.
#[test]
fn arrows_carry_the_rods_force_from_newtons_law() {
    let mut s = session();
    let replies = send(&mut s, r#"{"type":"load_scene","name":"circle"}"#);
    let methods: Vec<String> = panels_of(&replies)
        .unwrap()
        .iter()
        .map(|p| p.method.clone())
        .collect();
    assert_eq!(methods, ["implicit", "parametric"]);
    send(&mut s, r#"{"type":"play"}"#);
    run(&mut s, 0.7);
    let (_, panels) = frame(&mut s);
    assert_eq!(panels.len(), 2);
    for (k, f) in panels.iter().enumerate() {
        let arrows = f.arrows.as_ref().expect("arrows for a one-particle scene");
        let v = &arrows.velocity;
        let speed = v[0].hypot(v[1]);
        assert!(speed > 1.0, "the bob moves: {speed}");
        let expected = rod_force(1.0, 9.81, &f.x, v);
        let scale = expected[0].hypot(expected[1]);
        let close = |got: &[f64], what: &str| {
            let d = (got[0] - expected[0]).hypot(got[1] - expected[1]);
            assert!(
                d < 1e-8 * scale,
                "panel {} {what}: {got:?} vs {expected:?}",
                f.id
            );
        };
        close(&arrows.constraint, "total constraint force");
        assert_eq!(arrows.gravity, [0.0, 9.81]);
        assert_eq!(arrows.applied, [0.0, 0.0]);
        match k {
            // The implicit panel (first): one row, C = x^2 + y^2 - L^2, grad C = 2 x, |grad C| = 2 L.
            0 => {
                assert_eq!(arrows.rows.len(), 1);
                let row = &arrows.rows[0];
                close(&row.force, "lambda grad C");
                assert!((row.gradient_norm - 2.0 * f.x[0].hypot(f.x[1])).abs() < 1e-12);
                assert!((row.lambda.abs() * row.gradient_norm - scale).abs() < 1e-8 * scale);
            }
            // The parametric panel has no rows: its map's reaction only.
            _ => assert!(arrows.rows.is_empty(), "{arrows:?}"),
        }
        // References: the weight (m |g| = 9.81) and sqrt(2 E_scale / M).
        assert_eq!(arrows.force_ref, 9.81);
        assert!(
            arrows.speed_ref > 1.0 && arrows.speed_ref < 10.0,
            "{}",
            arrows.speed_ref
        );
    }
    // A scene of more than 16 particles sends none.
    let chain = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../scenes/chain.toml"
    ))
    .unwrap()
    .replace("N = { value = 1000,", "N = { value = 17,");
    load_text(&mut s, &chain);
    assert!(frame(&mut s).1.iter().all(|f| f.arrows.is_none()));
}

/// Issue 18, item 2: a typed start state (positions and velocities). At the bottom of the
/// circle a velocity with a radial part is projected onto the tangent, the same start for
/// both forms, and the energy of the start is 1/2 m |v|^2 + V of the placed state.
#[test]
fn a_typed_start_state_is_placed_on_the_constraints_for_every_panel() {
    let mut s = session();
    let replies = send(&mut s, r#"{"type":"load_scene","name":"circle"}"#);
    let ids: Vec<u32> = panels_of(&replies).unwrap().iter().map(|p| p.id).collect();
    // Off the circle (r = 1.1) at its bottom, moving right and outwards.
    let replies = send(
        &mut s,
        &format!(
            r#"{{"type":"set_start_state","panel":{},"positions":[0.0,1.1],"velocities":[2.0,0.5]}}"#,
            ids[0]
        ),
    );
    let (positions, velocities, position_moved, velocity_moved) = replies
        .iter()
        .find_map(|m| match m {
            ServerMessage::StateSet {
                positions,
                velocities,
                position_moved,
                velocity_moved,
                ..
            } => Some((
                positions.clone(),
                velocities.clone(),
                *position_moved,
                *velocity_moved,
            )),
            _ => None,
        })
        .unwrap_or_else(|| panic!("{replies:?}"));
    assert!(panels_of(&replies).is_some());
    // The closest point of the circle, and the tangential part of the velocity.
    assert!(
        (positions[0]).abs() < 1e-12 && (positions[1] - 1.0).abs() < 1e-9,
        "{positions:?}"
    );
    assert!((position_moved - 0.1).abs() < 1e-9);
    assert!(
        (velocities[0] - 2.0).abs() < 1e-9 && velocities[1].abs() < 1e-9,
        "{velocities:?}"
    );
    assert!((velocity_moved - 0.5).abs() < 1e-9);
    let (_, panels) = frame(&mut s);
    for f in &panels {
        assert_eq!(f.t, 0.0);
        assert!(
            (f.x[0]).abs() < 1e-9 && (f.x[1] - 1.0).abs() < 1e-9,
            "{:?}",
            f.x
        );
        let v = &f.arrows.as_ref().unwrap().velocity;
        assert!((v[0] - 2.0).abs() < 1e-9 && v[1].abs() < 1e-9, "{v:?}");
        // E0 = 1/2 m v^2 - m g y = 2 - 9.81.
        assert!(
            (f.energy_initial - (2.0 - 9.81)).abs() < 1e-8,
            "{}",
            f.energy_initial
        );
    }
    // Only velocities: the positions stay; wrong lengths and non-numbers are refused.
    let replies = send(
        &mut s,
        &format!(
            r#"{{"type":"set_start_state","panel":{},"velocities":[-1.0,0.0]}}"#,
            ids[1]
        ),
    );
    assert!(panels_of(&replies).is_some(), "{replies:?}");
    let (_, panels) = frame(&mut s);
    assert!(panels.iter().all(|f| (f.x[1] - 1.0).abs() < 1e-9));
    assert!(panels
        .iter()
        .all(|f| (f.arrows.as_ref().unwrap().velocity[0] + 1.0).abs() < 1e-9));
    let replies = send(
        &mut s,
        &format!(
            r#"{{"type":"set_start_state","panel":{},"positions":[1.0]}}"#,
            ids[0]
        ),
    );
    let (code, message) = error_of(&replies).unwrap();
    assert_eq!(code, ErrorCode::BadValue);
    assert_eq!(
        message,
        "positions need 2 numbers (the particles' coordinates), got 1"
    );
    assert!(parse_client_message(
        r#"{"type":"set_start_state","panel":1,"positions":[1.0,"x"]}"#,
        &Limits::default()
    )
    .is_err());
    // Without a panel (a share URL being restored), the first panel places the start.
    let replies = send(
        &mut s,
        r#"{"type":"set_start_state","velocities":[1.5,0.0]}"#,
    );
    assert!(
        matches!(replies.first(), Some(ServerMessage::StateSet { panel, .. }) if *panel == ids[0]),
        "{replies:?}"
    );
    let (_, panels) = frame(&mut s);
    assert!(panels
        .iter()
        .all(|f| (f.arrows.as_ref().unwrap().velocity[0] - 1.5).abs() < 1e-9));
    // And with no panel at all, a clear refusal.
    for id in &ids {
        send(
            &mut s,
            &format!(r#"{{"type":"remove_panel","panel":{id}}}"#),
        );
    }
    let replies = send(
        &mut s,
        r#"{"type":"set_start_state","velocities":[1.5,0.0]}"#,
    );
    let (code, message) = error_of(&replies).unwrap();
    assert_eq!(code, ErrorCode::NoPanel);
    assert_eq!(message, "no panel to start: add one first");
}
