//! Step and project (`fast-projection`) on the shipped cloth at frame-size steps, where
//! RATTLE cannot go: the cloth's taut threads oscillate across themselves at up to
//! F = 2 sqrt(T / (m L)) (the scene's parameter F), and RATTLE, explicit in those
//! directions, needs dt F < 2.

use std::sync::Arc;

use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::scene::Scene;
use bead::simulate::{Simulation, SimulationConfig};

/// The shipped cloth at W x H masses.
fn cloth(w: f64, h: f64) -> Scene {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/cloth.toml");
    Scene::load(&path, &[("W".into(), w), ("H".into(), h)]).unwrap_or_else(|e| panic!("{e}"))
}

/// A simulation of `system` in the implicit form with `integrator` at `dt`, no step retried
/// in substeps.
fn stepped_alone(
    system: &Arc<bead::model::System>,
    integrator: IntegratorKind,
    dt: f64,
) -> Simulation {
    let config = SimulationConfig {
        method: Method::Implicit,
        integrator,
        dt,
        max_substeps: 1,
        ..Default::default()
    };
    Simulation::new(Arc::clone(system), config).unwrap()
}

/// The largest rod stretch |d - L| / L at the simulation's state.
fn stretch(sim: &Simulation, ws: &mut bead::model::ConstraintEval) -> f64 {
    let set = sim.system().constraints();
    let c = set.residuals(sim.t(), sim.positions(), ws);
    let mut stretch = 0.0_f64;
    for (rows, length) in set.declared_rows() {
        if let Some(l) = length {
            // C = (|d|^2 - L^2) / (2 L), so |d| = sqrt(L^2 + 2 L C).
            let d = (l * l + 2.0 * l * c[rows.start]).sqrt();
            stretch = stretch.max((d - l).abs() / l);
        }
    }
    stretch
}

/// Law: at dt = 1/60 s on a 12 x 12 cloth (dt F = 4.2), fast projection holds every rod to
/// 1e-10 of its length after every one of 1,200 steps (20 s, ten times the scene's default
/// duration), its energy never rises above the start and ends below it (the modes it cannot
/// resolve are damped); RATTLE at the same step fails within the first second (with no
/// substeps to retry in), and runs at dt F = 1.5.
#[test]
fn fast_projection_steps_a_stiff_cloth_at_frame_size_steps_where_rattle_cannot() {
    let scene = cloth(12.0, 12.0);
    let f = scene.params.iter().find(|p| p.0 == "F").unwrap().1;
    let dt = 1.0 / 60.0;
    assert!(dt * f > 4.0, "dt F = {}", dt * f);
    let system = Arc::clone(&scene.system);
    let mut sim = stepped_alone(&system, IntegratorKind::FastProjection, dt);
    let mut ws = system.constraints().workspace();
    let e0 = sim.energy();
    let mut worst = (0.0_f64, f64::NEG_INFINITY);
    for step in 0..1200 {
        sim.step()
            .unwrap_or_else(|e| panic!("fast-projection, step {step}: {e}"));
        worst.0 = worst.0.max(stretch(&sim, &mut ws));
        worst.1 = worst.1.max(sim.energy() - e0);
    }
    println!(
        "fast-projection at dt F = {:.2}: stretch {:.1e}, max E - E0 {:.1e} (E0 {e0:.4})",
        dt * f,
        worst.0,
        worst.1
    );
    assert!(worst.0 <= 1e-10, "stretch {:e}", worst.0);
    assert!(worst.1 <= 1e-12 * e0.abs(), "energy rose by {:e}", worst.1);
    // The energy goes: the stiff modes it cannot resolve are damped.
    assert!(sim.energy() < e0);

    let mut rattle = stepped_alone(&system, IntegratorKind::Rattle, dt);
    let failed = (0..60).any(|_| rattle.step().is_err());
    assert!(failed, "rattle at dt F = {:.1} ran a second", dt * f);
    let mut rattle = stepped_alone(&system, IntegratorKind::Rattle, 1.5 / f);
    for step in 0..200 {
        rattle
            .step()
            .unwrap_or_else(|e| panic!("rattle at dt F = 1.5, step {step}: {e}"));
    }
}

/// Law: on a particle held at distance L from a fixed point (2D, under gravity), every step
/// is the closed form of step and project: q* = q + h (v + h g), the closest point of the
/// circle to q* (along the ray from the centre: the mass metric is round for one particle),
/// v = (q_{n+1} - q_n) / h with its radial part removed. Each of 600 steps at dt = 1/30
/// from a swing of 120 degrees, taken from bead's state before it, agrees with bead's
/// Newton projection to 1e-10 of the step's correction |q* - q_{n+1}| (the projection's
/// stationarity tolerance). (For one particle Gauss-Newton lands there too; the cloth
/// below tells the two apart.)
#[test]
fn each_step_is_the_closest_point_on_a_circle() {
    let text = r#"
        title = "pendulum"
        [world]
        gravity = [0.0, 9.81]
        [[particle]]
        name = "p"
        mass = 2.0
        position = ["1.3*sin(2*pi/3)", "1.3*cos(2*pi/3)"]
        velocity = [0.0, 0.0]
        [[constraint]]
        name = "rod"
        kind = "distance"
        particle = "p"
        anchor = [0.0, 0.0]
        length = 1.3
    "#;
    let scene = Scene::parse(text, "pendulum.toml", &[]).unwrap_or_else(|e| panic!("{e}"));
    let dt = 1.0 / 30.0;
    let mut sim = stepped_alone(&scene.system, IntegratorKind::FastProjection, dt);
    let (length, g) = (1.3, 9.81);
    let mut worst = 0.0_f64;
    for step in 0..600 {
        let (mut q, mut v) = ([0.0; 2], [0.0; 2]);
        q.copy_from_slice(sim.positions());
        v.copy_from_slice(sim.velocities());
        let v_free = [v[0], v[1] + dt * g];
        let q_free = [q[0] + dt * v_free[0], q[1] + dt * v_free[1]];
        let r = q_free[0].hypot(q_free[1]);
        let next = [length * q_free[0] / r, length * q_free[1] / r];
        let mut v_next = [(next[0] - q[0]) / dt, (next[1] - q[1]) / dt];
        let radial = (v_next[0] * next[0] + v_next[1] * next[1]) / (length * length);
        v_next = [v_next[0] - radial * next[0], v_next[1] - radial * next[1]];
        (q, v) = (next, v_next);
        sim.step().unwrap_or_else(|e| panic!("step {step}: {e}"));
        let (x, u) = (sim.positions(), sim.velocities());
        let correction = (q_free[0] - q[0]).hypot(q_free[1] - q[1]);
        for axis in 0..2 {
            worst = worst.max((x[axis] - q[axis]).abs() / correction);
            worst = worst.max((u[axis] - v[axis]).abs() * dt / correction);
        }
    }
    println!("largest difference from the closed form: {worst:.1e} of the correction");
    assert!(worst <= 1e-10, "{worst:e}");
}

/// Law: on a 6 x 6 cloth at dt = 1/60 (dt F = 1.4), the projected positions are the closest
/// point on the constraints in the mass metric: M (q_{n+1} - q*) is a combination of the
/// rows of J(q_{n+1}) (a least-squares fit by dense elimination leaves 1e-10 of it), step
/// after step; the Gauss-Newton iteration of the paper, which stops on the constraints but
/// not at the closest point, leaves 1e-2 after one step.
#[test]
fn the_projection_is_the_closest_point_on_a_cloth() {
    let scene = cloth(6.0, 6.0);
    let system = Arc::clone(&scene.system);
    let dt = 1.0 / 60.0;
    let mut sim = stepped_alone(&system, IntegratorKind::FastProjection, dt);
    let w = system.inverse_mass().to_vec();
    let gravity: Vec<f64> = system.gravity().to_vec();
    let dim = gravity.len();
    let n = w.len();
    let set = system.constraints();
    let mut ws = set.workspace();
    // The part of M (q - q*) outside the span of J(q)^T, relative to its size: with
    // r = M (q - q*), mu = (J W J^T)^-1 J W r, the rest r - J^T mu in the W norm.
    let off_span = |q: &[f64], q_free: &[f64], ws: &mut bead::model::ConstraintEval| {
        set.gradient(0.0, q, ws);
        let m = set.n_rows();
        let r: Vec<f64> = (0..n).map(|k| (q[k] - q_free[k]) / w[k]).collect();
        let mut rows = vec![vec![0.0; n]; m];
        for (i, row) in rows.iter_mut().enumerate() {
            for (s, &k) in set.row_entries(i).zip(set.row_columns(i)) {
                row[k] = ws.jacobian[s];
            }
        }
        let mut normal = vec![0.0; m * m];
        let mut rhs = vec![0.0; m];
        for i in 0..m {
            rhs[i] = (0..n).map(|k| rows[i][k] * w[k] * r[k]).sum();
            for j in 0..m {
                normal[i * m + j] = (0..n).map(|k| rows[i][k] * w[k] * rows[j][k]).sum();
            }
        }
        let mut scale = vec![0.0; m];
        bead::linalg::solve_general(m, &mut normal, &mut rhs, &mut scale).unwrap();
        let (mut rest, mut size) = (0.0_f64, 0.0_f64);
        for k in 0..n {
            let fitted: f64 = (0..m).map(|i| rows[i][k] * rhs[i]).sum();
            rest += (r[k] - fitted).powi(2) * w[k];
            size += r[k] * r[k] * w[k];
        }
        (rest / size).sqrt()
    };
    let free_of = |q: &[f64], v: &[f64]| -> Vec<f64> {
        (0..n)
            .map(|k| q[k] + dt * (v[k] + dt * gravity[k % dim]))
            .collect()
    };
    // Gauss-Newton from the first step's q*, by the formulation's own projection.
    let q_free = free_of(sim.positions(), sim.velocities());
    let mut gauss_newton = q_free.clone();
    let mut formulation = bead::formulation::Implicit::new(Arc::clone(&system), Default::default());
    let cs = bead::formulation::SecondOrderSystem::as_constrained(&mut formulation).unwrap();
    cs.project_positions(dt, &mut gauss_newton, 1e-13, 100)
        .unwrap();
    let gauss_newton_rest = off_span(&gauss_newton, &q_free, &mut ws);
    let mut worst = 0.0_f64;
    for step in 0..120 {
        let q_free = free_of(sim.positions(), sim.velocities());
        sim.step().unwrap_or_else(|e| panic!("step {step}: {e}"));
        worst = worst.max(off_span(sim.positions(), &q_free, &mut ws));
    }
    println!("off the span of J^T: {worst:.1e} (Gauss-Newton {gauss_newton_rest:.1e})");
    assert!(worst <= 1e-10, "{worst:e}");
    assert!(
        gauss_newton_rest >= 1e3 * worst.max(1e-12),
        "{gauss_newton_rest:e}"
    );
}

/// Law: on the shipped 50 x 50 cloth at dt = 1/60 (dt F = 39), the projection's Newton
/// iteration converges in a few iterations (at most 13 from the cold start, about 5 on
/// average) with about one factorization of its matrix per step, every rod within 1e-10
/// of its length after every one of 60 steps. (Gauss-Newton, the paper's iteration, needs
/// up to ~170 here.)
#[test]
fn the_shipped_cloth_projects_in_a_few_newton_iterations_at_a_frame() {
    use bead::formulation::{ConstraintScales, Feedback, Formulation, Implicit};
    use bead::integrate::{FastProjection, Integrator, IntegratorSettings};
    let scene = cloth(50.0, 50.0);
    let system = Arc::clone(&scene.system);
    let mut formulation = Implicit::new(Arc::clone(&system), Feedback::default());
    formulation.set_constraint_scales(Some(ConstraintScales::of(&system)));
    let mut state = formulation.initial_state();
    let settings = IntegratorSettings {
        constraint_tolerance: 1e-12,
        ..Default::default()
    };
    let mut integrator = FastProjection::with_settings(state.q.len(), &settings);
    let set = system.constraints();
    let mut ws = set.workspace();
    let steps = 60;
    let mut stretch = 0.0_f64;
    for step in 0..steps {
        integrator
            .step(&mut formulation, &mut state, 1.0 / 60.0)
            .unwrap_or_else(|e| panic!("step {step}: {e}"));
        let c = set.residuals(state.t, &state.q, &mut ws);
        for (rows, length) in set.declared_rows() {
            if let Some(l) = length {
                let d = (l * l + 2.0 * l * c[rows.start]).sqrt();
                stretch = stretch.max((d - l).abs() / l);
            }
        }
    }
    let iterations = integrator.projection_iterations_total() as f64 / steps as f64;
    let factorizations = integrator.factorizations_total() as f64 / steps as f64;
    let most = integrator.newton_iterations_max().unwrap();
    println!(
        "50 x 50 cloth at 1/60: {iterations:.2} iterations and {factorizations:.2} \
         factorizations per step, at most {most}; stretch {stretch:.1e}"
    );
    assert!(stretch <= 1e-10, "{stretch:e}");
    assert!(most <= 15, "{most}");
    assert!(iterations <= 7.0, "{iterations}");
    assert!(factorizations <= 1.5, "{factorizations}");
}

/// Law: with the energy ledger on (a dragged cloth in the viewer turns it on), the projection
/// keeps its Newton matrix and its warm start (the ledger's work entry, which the simulation
/// adds to after every step, is no change of state: `Integrator::continued`): the 12 x 12
/// cloth at dt = 1/60 steps as without the ledger, the same positions bit for bit (1.4e-12
/// apart when the ledger's entry made every step start from lambda = 0) and as many
/// iterations in all, with no step retried.
#[test]
fn the_ledger_keeps_the_newton_matrix() {
    let scene = cloth(12.0, 12.0);
    let system = Arc::clone(&scene.system);
    let run = |track_work| {
        let config = SimulationConfig {
            method: Method::Implicit,
            integrator: IntegratorKind::FastProjection,
            dt: 1.0 / 60.0,
            max_substeps: 1,
            track_work: Some(track_work),
            ..Default::default()
        };
        let mut sim = Simulation::new(Arc::clone(&system), config).unwrap();
        for step in 0..120 {
            sim.step()
                .unwrap_or_else(|e| panic!("ledger {track_work}, step {step}: {e}"));
        }
        let iterations = sim.newton_iterations_total().unwrap();
        (sim.positions().to_vec(), iterations)
    };
    let (plain, plain_iterations) = run(false);
    let (ledger, ledger_iterations) = run(true);
    let difference = plain
        .iter()
        .zip(&ledger)
        .fold(0.0_f64, |m, (a, b)| m.max((a - b).abs()));
    println!(
        "ledger: {difference:.1e} apart, iterations {ledger_iterations} and {plain_iterations}"
    );
    assert_eq!(ledger, plain, "{difference:e} apart");
    assert_eq!(ledger_iterations, plain_iterations);
}

/// Law: a constraint that repeats another is named, not stepped through: a simulation
/// refuses the start, and the integrator alone (no start check) fails its step naming it:
/// the projection's regularized Newton matrix factors the pair, but the velocity
/// projection's J W J^T finds the dependent row.
#[test]
fn a_repeated_rod_is_named() {
    use bead::formulation::{Feedback, Formulation, Implicit};
    use bead::integrate::{FastProjection, Integrator, IntegratorSettings};
    let text = r#"
        title = "two rods on one pendulum"
        [world]
        gravity = [0.0, 9.81]
        [[particle]]
        name = "p"
        mass = 1.0
        position = [0.6, 0.8]
        velocity = [0.0, 0.0]
        [[constraint]]
        name = "rod"
        kind = "distance"
        particle = "p"
        anchor = [0.0, 0.0]
        length = 1.0
        [[constraint]]
        name = "the same rod again"
        kind = "distance"
        particle = "p"
        anchor = [0.0, 0.0]
        length = 1.0
    "#;
    let scene = Scene::parse(text, "twice.toml", &[]).unwrap_or_else(|e| panic!("{e}"));
    let refused = match Simulation::new(Arc::clone(&scene.system), SimulationConfig::default()) {
        Err(refused) => refused.to_string(),
        Ok(_) => panic!("a start on a repeated rod"),
    };
    assert!(refused.contains("the same rod again"), "{refused}");
    let mut formulation = Implicit::new(Arc::clone(&scene.system), Feedback::default());
    let mut state = formulation.initial_state();
    let mut integrator =
        FastProjection::with_settings(state.q.len(), &IntegratorSettings::default());
    let error = integrator
        .step(&mut formulation, &mut state, 1.0 / 60.0)
        .expect_err("a step through a repeated rod")
        .to_string();
    println!("{error}");
    assert!(error.contains("the same rod again"), "{error}");
}

/// The last step's multipliers start the projection only for a step from bitwise the state
/// that step ended at (stale ones, after a state set from outside, may lead Newton's method
/// to another stationary point of the projection). From any other state (kicked, moved by
/// an ulp, at another time) a step has a fresh integrator's bits; the control: from its own
/// end the step differs from a fresh one.
#[test]
fn the_last_multipliers_start_only_a_step_from_where_the_last_one_ended() {
    use bead::formulation::{ConstraintScales, Feedback, Formulation, Implicit, State};
    use bead::integrate::{FastProjection, Integrator, IntegratorSettings};
    let scene = cloth(8.0, 8.0);
    let system = Arc::clone(&scene.system);
    let mut formulation = Implicit::new(Arc::clone(&system), Feedback::default());
    formulation.set_constraint_scales(Some(ConstraintScales::of(&system)));
    let settings = IntegratorSettings {
        constraint_tolerance: 1e-12,
        ..Default::default()
    };
    let n = system.n_coords();
    let dt = 1.0 / 60.0;
    let mut state = formulation.initial_state();
    let mut warm = FastProjection::with_settings(n, &settings);
    for _ in 0..30 {
        warm.step(&mut formulation, &mut state, dt).unwrap();
    }
    let fresh_step = |formulation: &mut Implicit, from: &State| {
        let mut s = from.clone();
        FastProjection::with_settings(n, &settings)
            .step(formulation, &mut s, dt)
            .unwrap();
        s
    };
    let mut own = state.clone();
    warm.step(&mut formulation, &mut own, dt).unwrap();
    assert_ne!(
        own.q,
        fresh_step(&mut formulation, &state).q,
        "no warm start"
    );
    type Perturbation = fn(&mut State);
    let perturbations: [(&str, Perturbation); 3] = [
        ("kicked", |s| s.qdot[7] += 1e-3),
        ("moved", |s| s.q[4] = f64::from_bits(s.q[4].to_bits() + 1)),
        ("later", |s| s.t += 1e-9),
    ];
    for (what, perturb) in perturbations {
        let mut other = FastProjection::with_settings(n, &settings);
        let mut ended = state.clone();
        for _ in 0..2 {
            other.step(&mut formulation, &mut ended, dt).unwrap();
        }
        let mut from = ended.clone();
        perturb(&mut from);
        let mut s = from.clone();
        other.step(&mut formulation, &mut s, dt).unwrap();
        let fresh = fresh_step(&mut formulation, &from);
        assert_eq!(s.q, fresh.q, "{what}: positions are not a fresh step's");
        assert_eq!(
            s.qdot, fresh.qdot,
            "{what}: velocities are not a fresh step's"
        );
    }
}
