//! The sparse and the dense linear algebra agree (issue 8).
//!
//! Law: J W J^T solved by faer's sparse LDL^T (any ordering), by the tridiagonal LDL^T of
//! chains (rows in their own or in path order; other structures fall back to faer) and by the
//! dense LDL^T give the same accelerations and multipliers to 1e-12 (relative to the
//! largest), the same projections and the same RATTLE steps, on random states of a chain (also
//! declared out of order), a tree, a closed ring, a cloth patch and every shipped scene.
//! Dependent rows are named on every path.

mod common;

use std::path::Path;
use std::sync::Arc;

use bead::formulation::{ConstrainedSystem, Feedback, Implicit, SecondOrderSystem, State};
use bead::integrate::{Integrator, IntegratorSettings, NewtonMatrix, Rattle};
use bead::linalg::LinearSolver;
use bead::model::{Endpoint, ParticleId, System, SystemBuilder};
use bead::scene::Scene;
use common::{chain, cloth, ring, tree, Random};

/// The structures and the shipped scenes' systems with implicit constraints, by name.
fn systems() -> Vec<(String, Arc<System>)> {
    let mut out: Vec<(String, Arc<System>)> = vec![
        ("chain of 20".into(), Arc::new(chain(20))),
        (
            "chain of 20, interleaved".into(),
            Arc::new(chain_interleaved(20)),
        ),
        ("tree".into(), Arc::new(tree())),
        ("ring of 12".into(), Arc::new(ring(12))),
        ("cloth 5 x 6".into(), Arc::new(cloth(5, 6))),
    ];
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    assert!(files.len() >= 8, "{files:?}");
    for file in files {
        // The generated scenes at a size the dense path factors quickly and a random state
        // at this test's dt stays tame (their full size, 1000 and 4900 rods, takes the
        // dense O(m^3) factorization minutes per state).
        let overrides: Vec<(String, f64)> = match file.file_name().unwrap().to_str().unwrap() {
            "chain.toml" => vec![("N".into(), 20.0)],
            // This test's random speeds turn a rod by about 1e-2 N radians per step (the
            // speed scale over the rope's length N L, dt 1e-2 of their ratio); at N = 20
            // some draws of the rope's exceed what RATTLE's simplified Newton converges for.
            "rope.toml" => vec![("N".into(), 10.0), ("L".into(), 1.0)],
            "net.toml" => vec![("W".into(), 6.0), ("R".into(), 2.0), ("L".into(), 1.0)],
            "cloth.toml" => vec![("W".into(), 8.0), ("H".into(), 7.0)],
            "tassel.toml" => ["T", "B", "K", "L"]
                .into_iter()
                .zip([3.0, 3.0, 4.0, 1.0])
                .map(|(name, value)| (name.into(), value))
                .collect(),
            _ => vec![],
        };
        let scene = Scene::load(&file, &overrides).unwrap();
        if scene.system.constraints().n_rows() > 0 {
            let name = file.file_name().unwrap().to_string_lossy().into_owned();
            out.push((name, scene.system.clone()));
        }
    }
    out
}

/// The chain of [`chain`] with its rods declared even ones first (rod 0, 2, 4, ..., then 1,
/// 3, ...): its rows couple in a path, but not in their own order.
fn chain_interleaved(links: usize) -> System {
    let mut b = SystemBuilder::new(&[0.0, common::G]);
    let ids: Vec<ParticleId> = (0..links)
        .map(|i| {
            b.particle(&format!("p{i}"), 1.0, &[(i + 1) as f64, 0.0], &[0.0, 0.0])
                .unwrap()
        })
        .collect();
    for i in (0..links).step_by(2).chain((1..links).step_by(2)) {
        let end = match i {
            0 => Endpoint::Fixed(vec![0.0, 0.0]),
            _ => Endpoint::Particle(ids[i - 1]),
        };
        b.distance(&format!("rod {i}"), ids[i], end, 1.0).unwrap();
    }
    b.build().unwrap()
}

/// The system's length and speed scales: its largest initial coordinate (at least 1) and
/// sqrt(|g| length).
fn scales(system: &System) -> (f64, f64) {
    let (x, _) = system.initial_particle_state();
    let length = x.iter().fold(1.0f64, |l, c| l.max(c.abs()));
    let g = system
        .gravity()
        .iter()
        .map(|g| g * g)
        .sum::<f64>()
        .sqrt()
        .max(1.0);
    (length, (g * length).sqrt())
}

/// A random state near the initial one: positions moved by `spread` of the length scale,
/// velocities of the speed scale, t in [0, 1).
fn random_state(system: &System, random: &mut Random, spread: f64) -> State {
    let (length, speed) = scales(system);
    let (mut q, mut qdot) = system.initial_particle_state();
    for c in &mut q {
        *c += spread * length * random.next();
    }
    for v in &mut qdot {
        *v += speed * random.next();
    }
    State {
        t: random.next() + 0.5,
        q,
        qdot,
    }
}

/// max_i |a_i - b_i| / max_i |b_i|
fn relative_difference(a: &[f64], b: &[f64]) -> f64 {
    let scale = b.iter().fold(f64::MIN_POSITIVE, |m, v| m.max(v.abs()));
    a.iter()
        .zip(b)
        .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()))
        / scale
}

/// The solvers compared with the dense LDL^T (`Auto`: rods in paths and trees fused along
/// the rods, `RodPath`).
const SPARSE_SOLVERS: [LinearSolver; 3] = [
    LinearSolver::Sparse,
    LinearSolver::Tridiagonal,
    LinearSolver::Auto,
];
const SOLVERS: [LinearSolver; 3] = [
    LinearSolver::Dense,
    LinearSolver::Sparse,
    LinearSolver::Tridiagonal,
];

#[test]
fn accelerations_and_multipliers_agree() {
    let feedback = Feedback { ks: 30.0, kd: 4.0 };
    for (name, system) in systems() {
        for solver in SPARSE_SOLVERS {
            let mut dense = Implicit::with_solver(system.clone(), feedback, LinearSolver::Dense);
            let mut sparse = Implicit::with_solver(system.clone(), feedback, solver);
            let mut random = Random(0x5eed_0000 + name.len() as u64);
            let n = system.n_coords();
            let mut worst = (0.0f64, 0.0f64);
            for _ in 0..5 {
                let s = random_state(&system, &mut random, 0.01);
                let (mut a_dense, mut a_sparse) = (vec![0.0; n], vec![0.0; n]);
                dense
                    .acceleration(s.t, &s.q, &s.qdot, &mut a_dense)
                    .unwrap();
                sparse
                    .acceleration(s.t, &s.q, &s.qdot, &mut a_sparse)
                    .unwrap();
                let da = relative_difference(&a_sparse, &a_dense);
                let dl = relative_difference(sparse.multipliers(), dense.multipliers());
                assert!(
                    da <= 1e-12 && dl <= 1e-12,
                    "{name}, {solver:?}: a {da:e}, lambda {dl:e}"
                );
                worst = (worst.0.max(da), worst.1.max(dl));
            }
            println!(
                "{name}: {} rows, {}: accelerations {:.1e}, multipliers {:.1e}",
                system.constraints().n_rows(),
                sparse.constraint_matrix().describe(),
                worst.0,
                worst.1
            );
        }
    }
}

/// The tridiagonal solver takes the chains, in their own order or in path order, and leaves
/// the tree, the ring and the cloth to faer; the chains and the tree are solved along their
/// rods.
#[test]
fn chains_get_the_tridiagonal_solver() {
    for (name, system) in systems() {
        let f = Implicit::with_solver(system.clone(), Feedback::default(), LinearSolver::Auto);
        let described = f.constraint_matrix().describe();
        let expected = match name.as_str() {
            "chain of 20" | "chain.toml" | "rope.toml" => {
                Some("tridiagonal LDL^T (rows in their own order)")
            }
            "chain of 20, interleaved" => Some("tridiagonal LDL^T (rows in path order)"),
            "tree" | "ring of 12" | "cloth 5 x 6" | "cloth.toml" | "net.toml" | "tassel.toml" => {
                Some("sparse LDL^T")
            }
            _ => None,
        };
        if let Some(expected) = expected {
            assert!(
                described.starts_with(expected),
                "{name}: {described}, expected {expected}"
            );
        }
        // The chains' and the tree's rows are all rods in paths or trees: solved along them
        // (the matrix only described); not the ring's or the cloths'.
        let rods = match name.as_str() {
            "chain of 20"
            | "chain of 20, interleaved"
            | "chain.toml"
            | "rope.toml"
            | "tree"
            | "tassel.toml" => Some(true),
            "ring of 12" | "cloth 5 x 6" | "cloth.toml" | "net.toml" => Some(false),
            _ => None,
        };
        if let Some(rods) = rods {
            assert_eq!(f.fused_rods(), rods, "{name}");
        }
    }
}

#[test]
fn projections_agree() {
    for (name, system) in systems() {
        for solver in SPARSE_SOLVERS {
            let mut dense =
                Implicit::with_solver(system.clone(), Feedback::default(), LinearSolver::Dense);
            let mut sparse = Implicit::with_solver(system.clone(), Feedback::default(), solver);
            let mut random = Random(0xab5 + name.len() as u64);
            let (length, _) = scales(&system);
            for _ in 0..3 {
                let s = random_state(&system, &mut random, 1e-3);
                let (mut q_dense, mut q_sparse) = (s.q.clone(), s.q.clone());
                let tolerance = 1e-13 * length * length;
                let k_dense = dense
                    .project_positions(s.t, &mut q_dense, tolerance, 50)
                    .unwrap();
                let k_sparse = sparse
                    .project_positions(s.t, &mut q_sparse, tolerance, 50)
                    .unwrap();
                let dq = relative_difference(&q_sparse, &q_dense);
                assert!(
                    dq <= 1e-12,
                    "{name}, {solver:?}: positions {dq:e} ({k_dense} vs {k_sparse})"
                );
                let (mut v_dense, mut v_sparse) = (s.qdot.clone(), s.qdot.clone());
                dense
                    .project_velocities(s.t, &q_dense, &mut v_dense)
                    .unwrap();
                sparse
                    .project_velocities(s.t, &q_dense, &mut v_sparse)
                    .unwrap();
                let dv = relative_difference(&v_sparse, &v_dense);
                assert!(dv <= 1e-12, "{name}, {solver:?}: velocities {dv:e}");
            }
        }
    }
}

/// RATTLE with the same Newton matrix on both paths takes the same steps (50, from a random
/// moving state on the constraints); the exact and the simplified Newton matrices reach the
/// same solution to the solver tolerance.
/// Its warm start too: on the chain of 20, whose multipliers jump 20x between its first
/// steps, a warm start not checked against the cold one led the dense exact iteration to
/// another root of C(q(nu)) = 0 (multipliers 30-200x the cold steps') until a step failed.
#[test]
fn rattle_agrees() {
    for (name, system) in systems() {
        let (length, speed) = scales(&system);
        let dt = 1e-2 * length / speed;
        let mut start = random_state(&system, &mut Random(0x7a77 + name.len() as u64), 1e-3);
        let mut oracle =
            Implicit::with_solver(system.clone(), Feedback::default(), LinearSolver::Dense);
        oracle
            .project_positions(start.t, &mut start.q, 1e-14 * length * length, 50)
            .unwrap();
        oracle
            .project_velocities(start.t, &start.q, &mut start.qdot)
            .unwrap();
        let settings = IntegratorSettings {
            constraint_tolerance: 1e-14 * length * length,
            constraint_max_iterations: 100,
            ..IntegratorSettings::default()
        };
        let mut finals = Vec::new();
        let cases = [
            (LinearSolver::Dense, NewtonMatrix::Simplified),
            (LinearSolver::Sparse, NewtonMatrix::Simplified),
            (LinearSolver::Dense, NewtonMatrix::Exact),
            (LinearSolver::Tridiagonal, NewtonMatrix::Simplified),
            // The exact matrix by tridiagonal elimination on chains, densely elsewhere.
            (LinearSolver::Tridiagonal, NewtonMatrix::Exact),
            // The default: on chains and ropes the exact Newton step and the velocity
            // projection fused along the path of rods (`RodPath`).
            (LinearSolver::Auto, NewtonMatrix::Auto),
        ];
        let rods = matches!(
            name.as_str(),
            "chain of 20"
                | "chain of 20, interleaved"
                | "tree"
                | "tassel.toml"
                | "chain.toml"
                | "rope.toml"
                | "double-pendulum.toml"
        );
        for (solver, newton) in cases {
            let mut formulation =
                Implicit::with_solver(system.clone(), Feedback::default(), solver);
            let mut state = start.clone();
            let mut rattle = Rattle::with_settings(state.q.len(), &settings).with_newton(newton);
            for step in 0..50 {
                rattle
                    .step(&mut formulation, &mut state, dt)
                    .unwrap_or_else(|e| panic!("{name}, {solver:?}, {newton:?}, step {step}: {e}"));
            }
            let fused = newton == NewtonMatrix::Auto && rods;
            assert_eq!(rattle.fused_rods(), fused, "{name}, {solver:?}, {newton:?}");
            finals.push(state);
        }
        let [dense, sparse, exact] = [&finals[0], &finals[1], &finals[2]];
        let dq = relative_difference(&sparse.q, &dense.q);
        let dv = relative_difference(&sparse.qdot, &dense.qdot);
        println!("{name}: rattle sparse vs dense after 50 steps: q {dq:.1e}, v {dv:.1e}");
        assert!(dq <= 1e-12 && dv <= 1e-12, "{name}: q {dq:e}, v {dv:e}");
        // Each converges to the tolerance (2e-13 of the largest coordinate here), the chains
        // amplify the difference over 50 steps.
        let dq = relative_difference(&exact.q, &dense.q);
        assert!(dq <= 1e-10, "{name}: exact vs simplified Newton: q {dq:e}");
        let [tridiagonal, tridiagonal_exact] = [&finals[3], &finals[4]];
        let dq = relative_difference(&tridiagonal.q, &dense.q);
        let dv = relative_difference(&tridiagonal.qdot, &dense.qdot);
        assert!(
            dq <= 1e-12 && dv <= 1e-12,
            "{name}: tridiagonal q {dq:e}, v {dv:e}"
        );
        let dq = relative_difference(&tridiagonal_exact.q, &exact.q);
        assert!(
            dq <= 1e-12,
            "{name}: exact Newton, tridiagonal vs dense: q {dq:e}"
        );
        // On rods, fused or not, the same exact Newton iteration; elsewhere the default is
        // the simplified matrix.
        let default = &finals[5];
        let dq = relative_difference(&default.q, &exact.q);
        let dv = relative_difference(&default.qdot, &exact.qdot);
        println!("{name}: rattle by default vs exact dense after 50 steps: q {dq:.1e}, v {dv:.1e}");
        if rods {
            assert!(
                dq <= 1e-12 && dv <= 1e-12,
                "{name}: fused q {dq:e}, v {dv:e}"
            );
        } else {
            assert!(dq <= 1e-10, "{name}: default vs exact Newton: q {dq:e}");
        }
    }
}

/// The fused rods' residual (`RodPath::values_and_residual`) is the formulation's
/// (`ConstraintScales::residual`), bit for bit, on the chains: near the constraints (where
/// the rounding allowance decides), off them, and with a NaN coordinate.
#[test]
fn fused_residual_is_the_formulations() {
    use bead::formulation::{ConstrainedSystem, ConstraintScales, Formulation};
    use bead::linalg::{PathOrder, RodPath};
    let mut compared: Vec<String> = Vec::new();
    for (name, system) in systems() {
        let mut f = Implicit::with_solver(system.clone(), Feedback::default(), LinearSolver::Auto);
        f.set_constraint_scales(Some(ConstraintScales::of(&system)));
        let Some(order) = PathOrder::of(f.constraint_matrix().pattern()) else {
            continue;
        };
        let set = system.constraints();
        let Some(mut rods) = RodPath::new(&order, |r| set.distance_row(r)) else {
            continue;
        };
        let scales = f.constraint_scales().expect("set above").clone();
        let mut random = Random(0x5ca1e + name.len() as u64);
        let m = set.n_rows();
        for spread in [1e-15, 1e-13, 1e-9, 1e-3] {
            for trial in 0..4 {
                let mut s = random_state(&system, &mut random, 0.0);
                f.project_positions(s.t, &mut s.q, 1e-15, 50).unwrap();
                for q in &mut s.q {
                    *q *= 1.0 + spread * random.next();
                }
                if spread == 1e-3 && trial == 3 {
                    s.q[3] = f64::NAN;
                }
                let (mut fused, mut general) = (vec![0.0; m], vec![0.0; m]);
                let got =
                    rods.values_and_residual(&s.q, &mut fused, &scales.scale, &scales.rounding);
                f.constraint_values(s.t, &s.q, &mut general);
                let expected = f.constraint_residual(&s.q, &general);
                assert!(
                    got.to_bits() == expected.to_bits(),
                    "{name}, spread {spread:e}: {got:e} vs {expected:e}"
                );
                assert!(
                    fused
                        .iter()
                        .zip(&general)
                        .all(|(a, b)| a.to_bits() == b.to_bits()),
                    "{name}: C differs"
                );
            }
        }
        compared.push(name);
    }
    // The chains, the interleaved one, chain.toml, rope.toml and the double pendulum.
    assert_eq!(compared.len(), 5, "{compared:?}");
}

/// A duplicated rod is named on both paths, whatever the sparse ordering: the row whose pivot
/// fails first in the elimination, mapped back through the permutation.
#[test]
fn dependent_rows_are_named_on_both_paths() {
    let mut b = SystemBuilder::new(&[0.0, common::G]);
    let mut previous = None;
    for i in 0..20 {
        let p = b
            .particle(&format!("p{i}"), 1.0, &[(i + 1) as f64, 0.0], &[0.0, 0.0])
            .unwrap();
        let end = previous.map_or(Endpoint::Fixed(vec![0.0, 0.0]), Endpoint::Particle);
        b.distance(&format!("rod {i}"), p, end, 1.0).unwrap();
        previous = Some(p);
    }
    b.distance(
        "again",
        ParticleId(12),
        Endpoint::Particle(ParticleId(11)),
        1.0,
    )
    .unwrap();
    let system = Arc::new(b.build().unwrap());
    let (q, qdot) = system.initial_particle_state();
    for solver in SOLVERS {
        let mut f = Implicit::with_solver(system.clone(), Feedback::default(), solver);
        let mut a = vec![0.0; q.len()];
        let error = f.acceleration(0.0, &q, &qdot, &mut a).unwrap_err();
        let text = error.to_string();
        assert!(
            text.contains("rod 12") || text.contains("again"),
            "{solver:?}: {text}"
        );
        assert!(text.contains("duplicates other constraints"), "{text}");
    }
}

/// A rod whose ends coincide has a vanishing gradient: every solver, the tridiagonal one of
/// the chain included (in its own order and in path order), names it.
#[test]
fn a_vanishing_rod_is_named_by_every_solver() {
    for system in [chain(20), chain_interleaved(20)] {
        let system = Arc::new(system);
        let (mut q, qdot) = system.initial_particle_state();
        // p7 onto p6: rod 7's gradient (x_7 - x_6) / L vanishes.
        q[14] = q[12];
        q[15] = q[13];
        for solver in SOLVERS {
            let mut f = Implicit::with_solver(system.clone(), Feedback::default(), solver);
            let mut a = vec![0.0; q.len()];
            let error = f.acceleration(0.0, &q, &qdot, &mut a).unwrap_err();
            let text = error.to_string();
            assert!(
                text.contains("rod 7") && !text.contains("rod 8"),
                "{solver:?}, {}: {text}",
                f.constraint_matrix().describe()
            );
        }
    }
}
