//! Unilateral constraints against analytic answers: where a particle leaves a sphere and a
//! loop, how a bead bounces in a bowl, what the energy ledger counts, and the errors.

use std::sync::Arc;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::scene::Scene;
use bead::simulate::{Simulation, SimulationConfig, SwitchKind};

fn config(integrator: IntegratorKind, dt: f64) -> SimulationConfig {
    SimulationConfig {
        method: Method::Implicit,
        integrator,
        dt,
        ..Default::default()
    }
}

fn simulation(text: &str, integrator: IntegratorKind, dt: f64) -> Simulation {
    let scene = Scene::parse(text, "contact.toml", &[]).unwrap();
    Simulation::new(Arc::clone(&scene.system), config(integrator, dt)).unwrap()
}

/// A particle at the top of a sphere of radius 1 (C = |x|^2 - 1 >= 0), a tiny push along x.
const SPHERE: &str = r#"
[world]
gravity = [0.0, 0.0, -9.81]
[[particle]]
name = "p"
mass = 1.0
position = [0.0, 0.0, 1.0]
velocity = [1e-7, 0.0, 0.0]
[[constraint]]
expr = "p.x^2 + p.y^2 + p.z^2 - 1"
side = "above"
"#;

/// Released from rest at the top of a sphere, a particle slides off where the normal force
/// m g cos(theta) - m v^2 / R vanishes with v^2 = 2 g R (1 - cos(theta)): cos(theta) = 2/3
/// (plus v0^2 / (3 g R) for the push, 3e-16 here).
#[test]
fn a_particle_leaves_a_sphere_at_cos_theta_two_thirds() {
    for integrator in [
        IntegratorKind::Rk4,
        IntegratorKind::Rattle4,
        IntegratorKind::Dopri5,
    ] {
        let mut sim = simulation(SPHERE, integrator, 1e-3);
        assert_eq!(sim.detached(), vec![false]);
        sim.advance_to(8.0).unwrap();
        let switches = sim.contact_switches();
        assert!(!switches.is_empty(), "{integrator:?}: it never left");
        let detach = &switches[0];
        assert_eq!(detach.kind, SwitchKind::Detach);
        let x = &detach.x;
        let r = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
        let cos_theta = x[2] / r;
        let expected = 2.0 / 3.0 + 1e-14 / (3.0 * 9.81);
        println!(
            "{integrator:?}: t = {}, cos theta = {cos_theta:.15}, error {:.3e}",
            detach.t,
            cos_theta - expected
        );
        assert!(
            (cos_theta - expected).abs() < 1e-9,
            "{integrator:?}: {cos_theta}"
        );
        assert_eq!(sim.detached(), vec![true]);
        // In flight: a parabola, the sphere left behind (C > 0), nothing counted as error.
        assert_eq!(sim.constraint_error(), 0.0);
    }
}

/// A loop of radius R = 1 (centre (0, 1), the bead inside it: C = R^2 - |x - c|^2 >= 0),
/// entered at its bottom with the speed of a fall from height h, v0^2 = 2 g h.
fn loop_scene(h: f64) -> String {
    format!(
        r#"
[params]
g = 9.81
h = {h:?}
[world]
gravity = [0.0, "-g"]
[[particle]]
name = "car"
mass = 1.0
position = [0.0, 0.0]
velocity = ["sqrt(2*g*h)", 0.0]
[[constraint]]
expr = "1 - car.x^2 - (car.y - 1)^2"
side = "above"
"#
    )
}

/// The loop-the-loop: the normal force m v^2 / R - m g sin(phi) (phi above the centre's
/// height) vanishes where v^2 = g R sin(phi) and v^2 = 2 g (h - R - R sin(phi)), at height
/// y = (2 h + R) / 3 when R < h < 5R/2; from h >= 5R/2 the car goes round.
#[test]
fn a_loop_is_left_where_the_energy_balance_says_and_completed_from_five_halves_r() {
    for h in [1.5, 2.0, 2.4] {
        let mut sim = simulation(&loop_scene(h), IntegratorKind::Rk4, 1e-3);
        sim.advance_to(3.0).unwrap();
        let detach = &sim.contact_switches()[0];
        assert_eq!(detach.kind, SwitchKind::Detach);
        let expected = (2.0 * h + 1.0) / 3.0;
        println!(
            "h = {h}: detaches at y = {:.15} (expected {expected:.15})",
            detach.x[1]
        );
        assert!(
            (detach.x[1] - expected).abs() < 1e-9,
            "h = {h}: {}",
            detach.x[1]
        );
    }
    for h in [2.51, 3.0] {
        let mut sim = simulation(&loop_scene(h), IntegratorKind::Rk4, 1e-3);
        // Several times round (one lap takes under 2 s from these heights).
        sim.advance_to(10.0).unwrap();
        assert!(
            sim.contact_switches().is_empty(),
            "h = {h}: {:?}",
            sim.contact_switches()
        );
        // Still on the loop (rk4 on the implicit form drifts off slowly: the article's
        // observation, not a detach).
        assert_eq!(sim.detached(), vec![false]);
        assert!(sim.constraint_error() < 1e-6, "{}", sim.constraint_error());
    }
}

/// A ball dropped into the article's bowl (x^2 + 100 y = 0, +y down; the ball above the
/// curve: C <= 0) with restitution e.
fn bowl(e: f64) -> String {
    format!(
        r#"
[world]
gravity = [0.0, 500.0]
[[particle]]
name = "ball"
mass = 1.0
position = [50.0, -100.0]
[[constraint]]
expr = "ball.x^2 + 100*ball.y"
side = "below"
restitution = {e:?}
"#
    )
}

/// Every bounce turns the normal velocity v_n into -e v_n and keeps the tangential one, so
/// it takes (1 - e^2) m v_n^2 / 2: with e = 0.5, 75% of the normal kinetic energy; the
/// energy ledger counts it (E - W stays), and with e = 1 nothing is lost.
#[test]
fn a_ball_bounces_in_a_bowl_losing_one_minus_e_squared_of_its_normal_energy() {
    for (e, integrator) in [
        (1.0, IntegratorKind::Rk4),
        (0.5, IntegratorKind::Rk4),
        (0.5, IntegratorKind::Rattle),
        (0.5, IntegratorKind::Dopri5),
    ] {
        let mut sim = simulation(&bowl(e), integrator, 1e-4);
        let times =
            |sim: &Simulation| -> Vec<f64> { sim.contact_switches().iter().map(|s| s.t).collect() };
        assert_eq!(sim.detached(), vec![true]);
        let e0 = sim.energy();
        sim.advance_to(3.0).unwrap();
        let switches = sim.contact_switches().to_vec();
        let bounces: Vec<_> = switches
            .iter()
            .filter(|s| s.kind == SwitchKind::Bounce)
            .collect();
        assert!(bounces.len() >= 3, "e = {e}: {switches:?}");
        // The first landing: straight down from (50, -100) to the curve at y = -25.
        let first = &switches[0];
        assert!((first.x[0] - 50.0).abs() < 1e-12 && (first.x[1] + 25.0).abs() < 1e-6);
        assert!(
            (first.t - (2.0 * 75.0 / 500.0_f64).sqrt()).abs() < 1e-9,
            "{}",
            first.t
        );
        for b in &bounces {
            let (before, after) = b.normal_velocity;
            assert!(before < 0.0, "approaching: {before}");
            assert!(
                (after + e * before).abs() <= 1e-9 * before.abs(),
                "{before} -> {after}"
            );
            // v_n = Cdot / |grad C|, grad C = (2x, 100).
            let gradient = (4.0 * b.x[0] * b.x[0] + 100.0 * 100.0).sqrt();
            let vn = before / gradient;
            let lost = 0.5 * (1.0 - e * e) * vn * vn;
            assert!(
                (b.dissipated - lost).abs() <= 1e-9 * (0.5 * vn * vn),
                "e = {e}: took {} of the normal energy {}",
                b.dissipated,
                0.5 * vn * vn
            );
        }
        // Three integrators, one history: the same switches at the same times.
        if e == 0.5 {
            let mut reference = simulation(&bowl(e), IntegratorKind::Rk4, 1e-4);
            reference.advance_to(3.0).unwrap();
            let (ours, theirs) = (times(&sim), times(&reference));
            assert_eq!(ours.len(), theirs.len(), "{integrator:?}");
            assert_eq!(theirs.len(), 13, "the README's count");
            for (a, b) in ours.iter().zip(&theirs) {
                assert!((a - b).abs() < 1e-8, "{integrator:?}: {a} vs rk4 {b}");
            }
        }
        let balance = sim.energy_balance_error();
        println!(
            "e = {e} {integrator:?}: {} switches, E - E0 = {:.3e}, balance {balance:.3e}",
            switches.len(),
            sim.energy() - e0
        );
        let tolerance = if integrator == IntegratorKind::Rattle {
            1e-6
        } else {
            1e-8
        };
        assert!(
            balance < tolerance,
            "e = {e} {integrator:?}: E - W drifted by {balance}"
        );
        if e == 1.0 {
            assert!(
                (sim.energy() - e0).abs() < 1e-8 * e0.abs(),
                "{}",
                sim.energy() - e0
            );
        } else {
            // The bounces shrink until one lands softly; then it slides in the bowl.
            assert!(
                switches.iter().any(|s| s.kind == SwitchKind::Land),
                "{switches:?}"
            );
            assert!(sim.energy() < e0);
        }
    }
}

#[test]
fn unilateral_scenes_say_what_they_cannot_do() {
    let scene = Scene::parse(&bowl(0.5), "bowl.toml", &[]).unwrap();
    let system = Arc::clone(&scene.system);
    let err = Simulation::new(
        Arc::clone(&system),
        SimulationConfig {
            method: Method::Parametric,
            ..Default::default()
        },
    )
    .err()
    .unwrap()
    .to_string();
    assert!(err.contains("no parametric form"), "{err}");
    drop(system);
    // The parametric form takes one unilateral constraint (its map holds them all).
    let two_rows = format!(
        "{}[[constraint]]\nexpr = \"ball.x + 1000\"\nside = \"above\"\n[parametric]\ncoordinates = [\"q\"]\ninitial = [0.0]\n[parametric.positions]\nball = [\"q\", \"-q^2/100\"]\n",
        bowl(0.5)
    );
    let scene = Scene::parse(&two_rows, "bowl.toml", &[]).unwrap();
    let err = Simulation::new(
        scene.system,
        SimulationConfig {
            method: Method::Parametric,
            ..Default::default()
        },
    )
    .err()
    .unwrap()
    .to_string();
    assert!(
        err.contains("the parametric form simulates one unilateral constraint"),
        "{err}"
    );
    // A map that does not trace the constraint the ball lands on: an error at the landing,
    // not a motion through the bowl.
    let wrong_map = format!(
        "{}[parametric]\ncoordinates = [\"q\"]\ninitial = [50.0]\n[parametric.positions]\nball = [\"q\", \"-q^2/50\"]\n",
        bowl(0.0)
    );
    let scene = Scene::parse(&wrong_map, "bowl.toml", &[]).unwrap();
    let mut parametric = config(IntegratorKind::Rk4, 1e-3);
    parametric.method = Method::Parametric;
    let mut sim = Simulation::new(scene.system, parametric).unwrap();
    let err = sim.advance_to(2.0).unwrap_err().to_string();
    assert!(
        err.contains("the parametric map does not hold the unilateral constraint 1"),
        "{err}"
    );
    assert!(sim.t() < 1.0, "stopped at the landing, t = {}", sim.t());
    // It stands where it failed, in the modes it had: in flight, at the bowl's point below
    // where it fell from, never back at its start.
    assert_eq!(sim.detached(), vec![true]);
    let x = sim.positions();
    assert!(
        (x[0] - 50.0).abs() < 1e-9 && (x[1] + 25.0).abs() < 1e-3,
        "{x:?}"
    );
    for (from, to, says) in [
        ("restitution = 0.5", "restitution = 1.5", "between 0"),
        (
            "side = \"below\"",
            "side = \"under\"",
            "unknown side `under`",
        ),
        (
            "side = \"below\"\n",
            "",
            "applies to a unilateral constraint only",
        ),
        (
            "position = [50.0, -100.0]",
            "position = [50.0, 0.0]",
            "wrong side",
        ),
    ] {
        let text = bowl(0.5).replace(from, to);
        let message = match Scene::parse(&text, "bowl.toml", &[]) {
            Err(e) => e.to_string(),
            Ok(scene) => Simulation::new(scene.system, config(IntegratorKind::Rk4, 1e-3))
                .err()
                .unwrap()
                .to_string(),
        };
        assert!(message.contains(says), "{to}: {message}");
    }
    let pin = "[world]\ngravity = [0.0, 1.0]\n[[particle]]\nname = \"p\"\nmass = 1.0\nposition = [0.0, 0.0]\n[[constraint]]\nkind = \"pin\"\nparticle = \"p\"\nside = \"above\"\n";
    let message = Scene::parse(pin, "pin.toml", &[])
        .err()
        .unwrap()
        .to_string();
    assert!(
        message.contains("pin.toml:10:8") && message.contains("`side` does not apply to a pin"),
        "{message}"
    );
}

/// A state put in the air stays there (in flight), not on the bowl; one put on the bowl's
/// wrong side goes onto it (the closest point), attached.
#[test]
fn set_state_keeps_a_start_in_flight_and_projects_one_below_the_floor() {
    use bead::simulate::StateRequest;
    let mut sim = simulation(&bowl(0.5), IntegratorKind::Rk4, 1e-3);
    sim.advance_to(1.0).unwrap();
    let placed = sim
        .set_state(&StateRequest {
            positions: Some(vec![30.0, -300.0]),
            velocities: Some(vec![0.0, 0.0]),
            ..Default::default()
        })
        .unwrap();
    assert_eq!(placed.positions, vec![30.0, -300.0]);
    assert_eq!(sim.detached(), vec![true]);
    assert!(sim.contact_switches().is_empty());
    // Below the bowl (C > 0): onto it, then attached (at rest, pressed on by gravity).
    sim.set_state(&StateRequest {
        positions: Some(vec![30.0, 100.0]),
        velocities: Some(vec![0.0, 0.0]),
        ..Default::default()
    })
    .unwrap();
    let x = sim.positions().to_vec();
    assert!((x[0] * x[0] + 100.0 * x[1]).abs() < 1e-6, "{x:?}");
    assert_eq!(sim.detached(), vec![false]);
    sim.advance_to(2.0).unwrap();
    assert!(
        sim.contact_switches().is_empty(),
        "{:?}",
        sim.contact_switches()
    );
}

/// A pendulum (a rod, bilateral) swinging into a wall (x >= -1/2, unilateral): the impulse
/// must keep the rod's length, so it acts along the wall's normal and the rod together (the
/// attached rows in one solve). The bob has one degree of freedom, so v_x -> -e v_x turns
/// its whole speed into e times it: the impact takes (1 - e^2) of all its kinetic energy
/// (not only of its normal part), and with e = 1 it swings back to its start height.
#[test]
fn an_impact_keeps_the_other_constraints_a_pendulum_against_a_wall() {
    let scene = pendulum_wall;
    for e in [1.0, 0.5] {
        let mut sim = simulation(&scene(e), IntegratorKind::Rk4, 1e-3);
        let mut speeds = Vec::new();
        let mut highest_after = f64::NEG_INFINITY;
        while sim.t() < 1.5 {
            sim.step().unwrap();
            let v = sim.velocities();
            speeds.push((sim.t(), (v[0] * v[0] + v[1] * v[1]).sqrt()));
            if !sim.contact_switches().is_empty() {
                highest_after = highest_after.max(sim.positions()[1]);
            }
        }
        let hit = sim.contact_switches()[0].clone();
        assert_eq!(hit.constraint, "wall");
        assert_eq!(hit.kind, SwitchKind::Bounce);
        // At x = -1/2 on the unit circle, y = -sqrt(3)/2: speed^2 = 2 g sqrt(3)/2.
        assert!((hit.x[0] + 0.5).abs() < 1e-9 && (hit.x[1] + 0.75_f64.sqrt()).abs() < 1e-6);
        let kinetic = 0.5 * 2.0 * 2.0 * 9.81 * 0.75_f64.sqrt();
        let lost = (1.0 - e * e) * kinetic;
        println!("e = {e}: took {} (expected {lost})", hit.dissipated);
        assert!(
            (hit.dissipated - lost).abs() < 1e-6 * kinetic,
            "{}",
            hit.dissipated
        );
        let (before, after) = hit.normal_velocity;
        assert!((after + e * before).abs() < 1e-9 * before.abs());
        // The rod held through the impact: the speed is tangent, the length 1.
        let x = sim.positions();
        assert!(((x[0] * x[0] + x[1] * x[1]).sqrt() - 1.0).abs() < 1e-6);
        if e == 1.0 {
            // Back up to where it started (y = 0), energy kept.
            assert!(
                highest_after > -1e-6 && highest_after < 1e-6,
                "{highest_after}"
            );
            assert!(sim.energy_error() < 1e-8, "{}", sim.energy_error());
        }
        assert!(sim.energy_balance_error() < 1e-8);
    }
}

fn run_form(text: &str, method: Method, integrator: IntegratorKind, dt: f64, t: f64) -> Simulation {
    let scene = Scene::parse(text, "contact.toml", &[]).unwrap();
    let mut config = config(integrator, dt);
    config.method = method;
    let mut sim = Simulation::new(Arc::clone(&scene.system), config).unwrap();
    sim.advance_to(t).unwrap();
    sim
}

/// The parametric form leaves the track in Cartesian coordinates and comes back to q: on a
/// circle (q the angle from the top), in a loop (from the bottom) and in the article's bowl
/// (q = x), the two forms switch at the same times and places and move the same way between.
#[test]
fn both_forms_agree_on_leaving_flying_and_landing() {
    let circle = r#"
[world]
gravity = [0.0, -9.81]
[[particle]]
name = "p"
mass = 1.0
position = [0.0, 1.0]
velocity = [1e-7, 0.0]
[[constraint]]
expr = "p.x^2 + p.y^2 - 1"
side = "above"
[parametric]
coordinates = ["th"]
initial = [0.0]
rates = [1e-7]
[parametric.positions]
p = ["sin(th)", "cos(th)"]
"#;
    let loop_track = loop_scene(2.0).replace(
        "side = \"above\"\n",
        "side = \"above\"\n[parametric]\ncoordinates = [\"phi\"]\ninitial = [0.0]\nrates = [\"sqrt(2*g*h)\"]\n[parametric.positions]\ncar = [\"sin(phi)\", \"1 - cos(phi)\"]\n",
    );
    let bowl_track = format!(
        "{}[parametric]\ncoordinates = [\"q\"]\ninitial = [50.0]\n[parametric.positions]\nball = [\"q\", \"-q^2/100\"]\n",
        bowl(0.5)
    );
    // A rod and a wall: in flight the parametric form is the rod's implicit form.
    let pendulum = pendulum_wall(0.5)
        + r#"[parametric]
coordinates = ["th"]
initial = ["pi/2"]
[parametric.positions]
bob = ["sin(th)", "-cos(th)"]
"#;
    // The README's figures: the switches at the same times within 5e-11 s, the positions
    // (at each switch and at the end) within 1e-9. Measured: 8e-14 s and 1.0e-11 (circle),
    // 3.1e-11 s and 4.5e-10 (loop), 0 and 5.5e-13 (bowl).
    const TIME: f64 = 5e-11;
    const POSITION: f64 = 1e-9;
    for (name, text, dt, t_end) in [
        ("pendulum", pendulum, 1e-3, 6.0),
        ("circle", circle.to_string(), 1e-3, 7.0),
        ("loop", loop_track, 1e-3, 2.0),
        ("bowl", bowl_track, 1e-4, 3.0),
    ] {
        let implicit = run_form(&text, Method::Implicit, IntegratorKind::Rk4, dt, t_end);
        let parametric = run_form(&text, Method::Parametric, IntegratorKind::Rk4, dt, t_end);
        let (a, b) = (implicit.contact_switches(), parametric.contact_switches());
        println!("{name}: {} and {} switches", a.len(), b.len());
        assert!(!a.is_empty() && a.len() == b.len(), "{name}: {a:?}\n{b:?}");
        for (i, (s, r)) in a.iter().zip(b).enumerate() {
            assert_eq!(s.kind, r.kind, "{name} switch {i}");
            assert!(
                (s.t - r.t).abs() < TIME,
                "{name} switch {i}: {} vs {}",
                s.t,
                r.t
            );
            for (x, y) in s.x.iter().zip(&r.x) {
                assert!(
                    (x - y).abs() < POSITION,
                    "{name} switch {i}: {:?} vs {:?}",
                    s.x,
                    r.x
                );
            }
            assert!(
                (s.dissipated - r.dissipated).abs() <= 1e-6 * s.dissipated.abs().max(1.0),
                "{name} switch {i}: {} vs {}",
                s.dissipated,
                r.dissipated
            );
        }
        let (x, y) = (implicit.positions(), parametric.positions());
        let worst_t = a
            .iter()
            .zip(b)
            .map(|(s, r)| (s.t - r.t).abs())
            .fold(0.0, f64::max);
        let end = x
            .iter()
            .zip(y)
            .map(|(p, q)| (p - q).abs())
            .fold(0.0, f64::max);
        println!(
            "{name}: switch times within {worst_t:.2e}, positions at t = {t_end} within {end:.2e}"
        );
        assert!(end < POSITION, "{name} at the end: {x:?} vs {y:?}");
        assert_eq!(implicit.detached(), parametric.detached(), "{name}");
        assert!(
            parametric.energy_balance_error() < 1e-8,
            "{name}: {}",
            parametric.energy_balance_error()
        );
    }
}

/// Dropped in mid-air (the viewer's "drop here"), the ball stays there and falls, in both
/// forms; they land together where free fall says.
#[test]
fn restart_at_rest_in_the_air_stays_in_flight_in_both_forms() {
    let scene = Scene::load(
        std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../scenes/bounce.toml"
        )),
        &[],
    )
    .unwrap();
    let mut landings = Vec::new();
    for method in [Method::Implicit, Method::Parametric] {
        let mut config = config(IntegratorKind::Rk4, 1e-3);
        config.method = method;
        let mut sim = Simulation::new(Arc::clone(&scene.system), config).unwrap();
        sim.advance_to(2.0).unwrap();
        sim.restart_at_rest(&[30.0, -300.0]).unwrap();
        assert_eq!(sim.positions(), &[30.0, -300.0], "{method:?}");
        assert_eq!(sim.detached(), vec![true], "{method:?}");
        sim.advance_to(1.5).unwrap();
        let first = sim.contact_switches()[0].clone();
        // From y = -300 to the bowl at y = -30^2/100 = -9: t = sqrt(2 * 291 / 500).
        let expected = (2.0 * 291.0 / 500.0_f64).sqrt();
        assert!((first.t - expected).abs() < 1e-9, "{method:?}: {}", first.t);
        assert!((first.x[0] - 30.0).abs() < 1e-9 && (first.x[1] + 9.0).abs() < 1e-6);
        landings.push(first.t);
    }
    assert!((landings[0] - landings[1]).abs() < 1e-12);
    // A start asked of the scene in the air stays there too.
    let (placed, _) = scene
        .with_state(&bead::simulate::StateRequest {
            positions: Some(vec![-40.0, -120.0]),
            ..Default::default()
        })
        .unwrap();
    assert_eq!(
        placed.system.initial_particle_state().0,
        vec![-40.0, -120.0]
    );
}

/// A bob of mass 2 on a rod of length 1 from the origin, released level at (1, 0), and a wall
/// at x = -0.5 it may not cross (restitution e).
fn pendulum_wall(e: f64) -> String {
    format!(
        r#"
[world]
gravity = [0.0, -9.81]
[[particle]]
name = "bob"
mass = 2.0
position = [1.0, 0.0]
[[constraint]]
name = "rod"
kind = "distance"
particle = "bob"
anchor = [0.0, 0.0]
length = 1.0
[[constraint]]
name = "wall"
expr = "bob.x + 0.5"
side = "above"
restitution = {e:?}
"#
    )
}

/// The sphere above as a Rust type: |x|^2 - 1.
struct Sphere(bead::model::ParticleId);
impl bead::model::Holonomic for Sphere {
    fn particles(&self) -> Vec<bead::model::ParticleId> {
        vec![self.0]
    }
    fn value<T: bead::Scalar>(&self, x: &[T], _t: T) -> T {
        x[0] * x[0] + x[1] * x[1] + x[2] * x[2] - 1.0
    }
}

/// A second particle held to the plane z = 5 by a Rust constraint kept on dual numbers.
struct Plane(bead::model::ParticleId);
impl bead::model::Holonomic for Plane {
    fn particles(&self) -> Vec<bead::model::ParticleId> {
        vec![self.0]
    }
    fn value<T: bead::Scalar>(&self, x: &[T], _t: T) -> T {
        x[2] - 5.0
    }
}

/// A Rust constraint traced into an expression can be unilateral, and it is then the
/// constraint typed as text: the particle leaves the sphere at the same step, at the same
/// point, bit for bit, with a constraint by dual numbers declared before it (whose row goes
/// last, so that the sphere's declaration and row numbers differ). One that keeps dual
/// numbers cannot be unilateral, and the error says why.
#[test]
fn a_traced_rust_constraint_can_be_unilateral() {
    use bead::model::{Side, SystemBuilder};
    let builder = || {
        let mut b = SystemBuilder::new(&[0.0, 0.0, -9.81]);
        let p = b
            .particle("p", 1.0, &[0.0, 0.0, 1.0], &[0.5, 0.0, 0.0])
            .unwrap();
        let q = b
            .particle("q", 1.0, &[3.0, 0.0, 5.0], &[0.0, 0.2, 0.0])
            .unwrap();
        b.holonomic_by_dual_numbers("plane", Plane(q));
        (b, p)
    };
    let (mut rust, p) = builder();
    rust.holonomic("sphere", Sphere(p))
        .unilateral(Side::Above, 0.0)
        .unwrap();
    let (mut text, _) = builder();
    text.constraint_expr("p.x*p.x + p.y*p.y + p.z*p.z - 1")
        .unwrap()
        .unilateral(Side::Above, 0.0)
        .unwrap();
    let leave = |b: SystemBuilder| {
        let system = Arc::new(b.build().unwrap());
        let unilateral = system.unilateral();
        assert_eq!((unilateral.len(), unilateral[0].constraint), (1, 1));
        assert_eq!(
            unilateral[0].row, 0,
            "expression rows before the dual-number one"
        );
        let mut sim = Simulation::new(system, config(IntegratorKind::Rk4, 1e-3)).unwrap();
        sim.advance_to(2.0).unwrap();
        let switches = sim.contact_switches();
        assert!(!switches.is_empty(), "it never left");
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        (switches[0].t.to_bits(), bits(&switches[0].x), bits(sim.q()))
    };
    assert_eq!(leave(rust), leave(text));
    let (mut duals, p) = builder();
    let error = duals
        .holonomic_by_dual_numbers("sphere", Sphere(p))
        .unilateral(Side::Above, 0.0)
        .unwrap_err()
        .to_string();
    assert!(
        error.contains("sphere: a Rust constraint can be unilateral only when it is traced"),
        "{error}"
    );
}
