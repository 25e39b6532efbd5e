//! Motions with closed-form answers: the engine must reproduce them.
//!
//! Laws checked: the exact period of a large-amplitude pendulum (complete elliptic integral,
//! computed here by the arithmetic-geometric mean); uniformly accelerated motion along a helix
//! (Lagrange's equation with constant coefficients); the tautochrone property of the cycloid
//! (period 4 pi sqrt(R/g) at every amplitude); and conservation of energy in a double pendulum,
//! whose two formulations (rods as distance constraints, or two angles) must describe the same
//! motion. Every reference value is derived in the comment above its test, without the engine.

use std::f64::consts::PI;
use std::sync::Arc;

use bead::formulation::{Feedback, Formulation, Implicit, Parametric, State};
use bead::integrate::IntegratorKind;
use bead::model::{Endpoint, System, SystemBuilder};

/// Advance `formulation` by `steps` RK4 steps of `dt` from its initial state, calling
/// `observe` on the initial state and after every step.
fn simulate<F: Formulation>(
    formulation: &mut F,
    dt: f64,
    steps: usize,
    mut observe: impl FnMut(&mut F, &State),
) {
    let mut state = formulation.initial_state();
    let mut integrator = IntegratorKind::Rk4.build(state.q.len());
    observe(formulation, &state);
    for _ in 0..steps {
        integrator.step(formulation, &mut state, dt).unwrap();
        observe(formulation, &state);
    }
}

/// Zero crossings of a sampled function f(t) whose derivative is known at every sample, each
/// located by the cubic Hermite interpolant through (f, f') at the two samples around it:
/// interpolation error O(dt^4), below the O(dt^4) error of RK4 itself.
#[derive(Default)]
struct Crossings {
    previous: Option<(f64, f64, f64)>,
    times: Vec<f64>,
}

impl Crossings {
    fn push(&mut self, t: f64, f: f64, df: f64) {
        if let Some((t0, f0, df0)) = self.previous {
            if f0 != 0.0 && (f == 0.0 || (f0 < 0.0) != (f < 0.0)) {
                let h = t - t0;
                let p = |s: f64| {
                    let (s2, s3) = (s * s, s * s * s);
                    (2.0 * s3 - 3.0 * s2 + 1.0) * f0
                        + (s3 - 2.0 * s2 + s) * h * df0
                        + (-2.0 * s3 + 3.0 * s2) * f
                        + (s3 - s2) * h * df
                };
                // Bisection: p(0) = f0 and p(1) = f have opposite signs (or p(1) = 0).
                let (mut lo, mut hi) = (0.0, 1.0);
                for _ in 0..60 {
                    let mid = 0.5 * (lo + hi);
                    if (p(mid) < 0.0) == (f0 < 0.0) {
                        lo = mid;
                    } else {
                        hi = mid;
                    }
                }
                self.times.push(t0 + 0.5 * (lo + hi) * h);
            }
        }
        self.previous = Some((t, f, df));
    }

    /// Mean period from the crossings: successive crossings are half a period apart, so the
    /// crossings 2k apart span k periods.
    fn period(&self, periods: usize) -> f64 {
        assert!(
            self.times.len() > 2 * periods,
            "only {} crossings: {:?}",
            self.times.len(),
            self.times
        );
        (self.times[2 * periods] - self.times[0]) / periods as f64
    }
}

/// Arithmetic-geometric mean of a and b. Convergence is quadratic (digits double each
/// iteration), so a fixed 40 iterations reach the limit; a tolerance loop could cycle forever
/// when a and b end one ulp apart.
fn agm(mut a: f64, mut b: f64) -> f64 {
    for _ in 0..40 {
        (a, b) = (0.5 * (a + b), (a * b).sqrt());
    }
    a
}

/// Complete elliptic integral of the first kind, K(k) = pi / (2 AGM(1, sqrt(1 - k^2))).
fn elliptic_k(k: f64) -> f64 {
    PI / (2.0 * agm(1.0, (1.0 - k * k).sqrt()))
}

// Sanity of the AGM route against two known values: K(0) = pi/2 and
// K(1/sqrt 2) = Gamma(1/4)^2 / (4 sqrt(pi)) = 1.854074677301372 (tabulated).
#[test]
fn elliptic_k_by_agm_matches_known_values() {
    assert!((elliptic_k(0.0) - PI / 2.0).abs() < 1e-15);
    assert!((elliptic_k(0.5f64.sqrt()) - 1.854_074_677_301_372).abs() < 1e-14);
}

mod pendulum {
    use super::*;

    const G: f64 = 9.81;
    const L: f64 = 1.0;
    const MASS: f64 = 1.3;

    /// A pendulum released at rest at angle `theta0` from the downward vertical (+y down,
    /// pivot at the origin): implicit constraint x^2 + y^2 - L^2 = 0, and the parametric map
    /// x = (L sin theta, L cos theta).
    fn system(theta0: f64) -> Arc<System> {
        let mut b = SystemBuilder::new(&[0.0, G]);
        b.param("L", L).unwrap();
        b.particle(
            "bead",
            MASS,
            &[L * theta0.sin(), L * theta0.cos()],
            &[0.0, 0.0],
        )
        .unwrap();
        b.constraint_expr("bead.x^2 + bead.y^2 - L^2").unwrap();
        b.parametric(&["theta"], &[theta0], &[0.0]).unwrap();
        b.parametric_position_exprs("bead", &["L*sin(theta)", "L*cos(theta)"])
            .unwrap();
        Arc::new(b.build().unwrap())
    }

    // Derivation: energy conservation, theta'^2 = (2g/L)(cos theta - cos theta0). The time
    // from the bottom to the turning point is a quarter period:
    //   T/4 = sqrt(L/2g) int_0^theta0 dtheta / sqrt(cos theta - cos theta0).
    // With cos theta = 1 - 2 sin^2(theta/2), k = sin(theta0/2) and sin(theta/2) = k sin u, the
    // integrand becomes sqrt(2) du / sqrt(1 - k^2 sin^2 u) (u from 0 to pi/2), so
    //   T = 4 sqrt(L/g) K(k),   K(k) = int_0^{pi/2} du / sqrt(1 - k^2 sin^2 u),
    // and K by Gauss's AGM: K(k) = pi / (2 AGM(1, sqrt(1 - k^2))).
    //
    // Measured: the horizontal coordinate x = L sin theta (implicit) or theta (parametric)
    // crosses zero every half period; crossings located by Hermite interpolation.
    const THETA0_DEGREES: f64 = 170.0;
    const DT: f64 = 1e-3;
    const PERIODS: usize = 2;

    fn exact_period() -> f64 {
        let k = (THETA0_DEGREES.to_radians() / 2.0).sin();
        4.0 * (L / G).sqrt() * elliptic_k(k)
    }

    fn steps() -> usize {
        // The first crossing is at T/4; PERIODS more periods after it, plus margin.
        ((PERIODS as f64 + 0.5) * exact_period() / DT) as usize
    }

    #[test]
    fn implicit_pendulum_at_170_degrees_has_the_elliptic_integral_period() {
        let exact = exact_period();
        let mut implicit = Implicit::new(system(THETA0_DEGREES.to_radians()), Feedback::default());
        let mut crossings = Crossings::default();
        simulate(&mut implicit, DT, steps(), |_, s| {
            crossings.push(s.t, s.q[0], s.qdot[0])
        });
        let measured = crossings.period(PERIODS);
        let error = (measured - exact).abs() / exact;
        println!("implicit pendulum 170 deg: period {measured:.12} s, exact {exact:.12} s, relative error {error:.2e}");
        assert!(
            error < 1e-6,
            "period {measured} vs exact {exact}: relative error {error:e}"
        );
    }

    #[test]
    fn parametric_pendulum_at_170_degrees_has_the_elliptic_integral_period() {
        let exact = exact_period();
        let mut parametric = Parametric::new(system(THETA0_DEGREES.to_radians())).unwrap();
        let mut crossings = Crossings::default();
        simulate(&mut parametric, DT, steps(), |_, s| {
            crossings.push(s.t, s.q[0], s.qdot[0])
        });
        let measured = crossings.period(PERIODS);
        let error = (measured - exact).abs() / exact;
        println!("parametric pendulum 170 deg: period {measured:.12} s, exact {exact:.12} s, relative error {error:.2e}");
        assert!(
            error < 1e-6,
            "period {measured} vs exact {exact}: relative error {error:e}"
        );
    }
}

mod helix {
    use super::*;

    const G: f64 = 9.81;
    const R: f64 = 1.0;
    const B: f64 = 0.25;
    const MASS: f64 = 0.7;
    const PHI0: f64 = 0.3;
    const OMEGA0: f64 = 5.0;
    const DT: f64 = 1e-3;
    const STEPS: usize = 3000;
    const TOLERANCE: f64 = 1e-8;

    // Derivation: x = (R cos phi, R sin phi, b phi), z up, gravity (0, 0, -g).
    //   |dx/dphi|^2 = R^2 sin^2 + R^2 cos^2 + b^2 = R^2 + b^2
    //   T = m/2 (R^2 + b^2) phi'^2,   V = m g z = m g b phi
    //   Lagrange: m (R^2 + b^2) phi'' = -m g b   =>   phi'' = -g b / (R^2 + b^2) =: -alpha
    // so phi(t) = phi0 + omega0 t - alpha t^2 / 2 exactly.
    fn phi(t: f64) -> f64 {
        let alpha = G * B / (R * R + B * B);
        PHI0 + OMEGA0 * t - 0.5 * alpha * t * t
    }

    fn position(phi: f64) -> [f64; 3] {
        [R * phi.cos(), R * phi.sin(), B * phi]
    }

    /// The helix as two implicit constraints x - R cos(z/b) = 0, y - R sin(z/b) = 0 (their
    /// gradients (1, 0, R sin(z/b)/b) and (0, 1, -R cos(z/b)/b) are independent everywhere),
    /// and as the parametric map of phi.
    fn system() -> Arc<System> {
        let mut b = SystemBuilder::new(&[0.0, 0.0, -G]);
        b.param("R", R).unwrap();
        b.param("b", B).unwrap();
        let (s, c) = PHI0.sin_cos();
        let velocity = [-R * s * OMEGA0, R * c * OMEGA0, B * OMEGA0];
        b.particle("bead", MASS, &position(PHI0), &velocity)
            .unwrap();
        b.constraint_expr("bead.x - R*cos(bead.z/b)").unwrap();
        b.constraint_expr("bead.y - R*sin(bead.z/b)").unwrap();
        b.parametric(&["phi"], &[PHI0], &[OMEGA0]).unwrap();
        b.parametric_position_exprs("bead", &["R*cos(phi)", "R*sin(phi)", "b*phi"])
            .unwrap();
        Arc::new(b.build().unwrap())
    }

    #[test]
    fn implicit_helix_bead_follows_the_closed_form_uniform_acceleration() {
        let mut implicit = Implicit::new(system(), Feedback::default());
        let mut worst: f64 = 0.0;
        simulate(&mut implicit, DT, STEPS, |_, s| {
            let want = position(phi(s.t));
            let error = (0..3)
                .map(|k| (s.q[k] - want[k]).powi(2))
                .sum::<f64>()
                .sqrt();
            worst = worst.max(error);
        });
        println!(
            "implicit helix: max position error {worst:.2e} over {} s",
            STEPS as f64 * DT
        );
        assert!(worst < TOLERANCE, "max position error {worst:e}");
    }

    #[test]
    fn parametric_helix_bead_follows_the_closed_form_uniform_acceleration() {
        let mut parametric = Parametric::new(system()).unwrap();
        let (mut worst_phi, mut worst_position): (f64, f64) = (0.0, 0.0);
        let (mut x, mut xdot) = ([0.0; 3], [0.0; 3]);
        simulate(&mut parametric, DT, STEPS, |f, s| {
            worst_phi = worst_phi.max((s.q[0] - phi(s.t)).abs());
            f.particle_state(s.t, &s.q, &s.qdot, &mut x, &mut xdot);
            let want = position(phi(s.t));
            let error = (0..3).map(|k| (x[k] - want[k]).powi(2)).sum::<f64>().sqrt();
            worst_position = worst_position.max(error);
        });
        println!("parametric helix: max phi error {worst_phi:.2e}, max position error {worst_position:.2e}");
        assert!(worst_phi < TOLERANCE, "max phi error {worst_phi:e}");
        assert!(
            worst_position < TOLERANCE,
            "max position error {worst_position:e}"
        );
    }
}

mod cycloid {
    use super::*;

    const G: f64 = 9.81;
    const R: f64 = 1.0;
    const MASS: f64 = 0.5;
    const DT: f64 = 1e-3;
    const PERIODS: usize = 2;

    // Sign convention (+y down): x = R (phi + sin phi), y = -R (1 - cos phi). At phi = 0 the
    // bead is at the origin; for phi != 0, y < 0, i.e. above the origin, rising to y = -2R at
    // the cusps phi = +-pi: the bowl opens upward with its lowest point at the origin.
    //
    // Derivation of the period: dx/dphi = R (1 + cos phi), dy/dphi = -R sin phi, so
    //   |dx/dphi|^2 = R^2 (2 + 2 cos phi) = 4 R^2 cos^2(phi/2),
    //   arc length from the bottom s = int 2R cos(phi/2) dphi = 4 R sin(phi/2),
    //   height above the bottom h = -y = R (1 - cos phi) = 2R sin^2(phi/2) = s^2 / (8R).
    // Energy m/2 s'^2 + m g s^2/(8R) is that of a harmonic oscillator in s with
    // omega^2 = g/(4R), whatever the amplitude: T = 2 pi / omega = 4 pi sqrt(R/g).
    fn exact_period() -> f64 {
        4.0 * PI * (R / G).sqrt()
    }

    fn system(phi0: f64) -> Arc<System> {
        let mut b = SystemBuilder::new(&[0.0, G]);
        b.param("R", R).unwrap();
        let position = [R * (phi0 + phi0.sin()), -R * (1.0 - phi0.cos())];
        b.particle("bead", MASS, &position, &[0.0, 0.0]).unwrap();
        b.parametric(&["phi"], &[phi0], &[0.0]).unwrap();
        b.parametric_position_exprs("bead", &["R*(phi + sin(phi))", "-R*(1 - cos(phi))"])
            .unwrap();
        Arc::new(b.build().unwrap())
    }

    fn measured_period(phi0: f64) -> f64 {
        let mut parametric = Parametric::new(system(phi0)).unwrap();
        let steps = ((PERIODS as f64 + 0.5) * exact_period() / DT) as usize;
        let mut crossings = Crossings::default();
        simulate(&mut parametric, DT, steps, |_, s| {
            crossings.push(s.t, s.q[0], s.qdot[0])
        });
        crossings.period(PERIODS)
    }

    #[test]
    fn cycloid_bowl_opens_upward_with_its_lowest_point_at_the_origin() {
        // The potential -m g y (y down) is 0 at phi = 0 and positive elsewhere up to the cusps.
        let system = system(0.0);
        let potential =
            |phi: f64| system.potential_energy(&[R * (phi + phi.sin()), -R * (1.0 - phi.cos())]);
        assert_eq!(potential(0.0), 0.0);
        for phi in [-3.0, -1.0, -0.1, 0.1, 1.0, 3.0] {
            assert!(
                potential(phi) > 0.0,
                "potential at phi = {phi} is not above the bottom's"
            );
        }
        assert!((potential(PI) - MASS * G * 2.0 * R).abs() < 1e-12);
    }

    #[test]
    fn cycloid_period_is_independent_of_amplitude_tautochrone() {
        let exact = exact_period();
        // Small, medium and near the cusp (pi).
        for phi0 in [0.1, 1.5, 3.0] {
            let measured = measured_period(phi0);
            let error = (measured - exact).abs() / exact;
            println!("cycloid amplitude phi0 = {phi0}: period {measured:.12} s, exact {exact:.12} s, relative error {error:.2e}");
            assert!(
                error < 1e-6,
                "amplitude {phi0}: period {measured} vs 4 pi sqrt(R/g) = {exact}: error {error:e}"
            );
        }
    }
}

mod double_pendulum {
    use super::*;

    const G: f64 = 9.81;
    const L1: f64 = 1.0;
    const L2: f64 = 0.7;
    const M1: f64 = 1.0;
    const M2: f64 = 1.5;
    const THETA1: f64 = 0.9;
    const THETA2: f64 = -0.5;
    const OMEGA1: f64 = 0.0;
    const OMEGA2: f64 = 1.0;
    const DT: f64 = 5e-4;
    const STEPS: usize = 8000;

    /// Positions and velocities of both bobs from the angles (measured from the downward
    /// vertical, +y down, pivot at the origin):
    ///   a = L1 (sin th1, cos th1),   b = a + L2 (sin th2, cos th2).
    fn particles(th: [f64; 2], om: [f64; 2]) -> ([f64; 4], [f64; 4]) {
        let (s1, c1) = th[0].sin_cos();
        let (s2, c2) = th[1].sin_cos();
        let x = [L1 * s1, L1 * c1, L1 * s1 + L2 * s2, L1 * c1 + L2 * c2];
        let v = [
            L1 * c1 * om[0],
            -L1 * s1 * om[0],
            L1 * c1 * om[0] + L2 * c2 * om[1],
            -L1 * s1 * om[0] - L2 * s2 * om[1],
        ];
        (x, v)
    }

    /// Mechanical energy computed here: T = sum m |v|^2 / 2, V = -sum m g y (+y down).
    fn energy(x: &[f64], v: &[f64]) -> f64 {
        let kinetic =
            0.5 * M1 * (v[0] * v[0] + v[1] * v[1]) + 0.5 * M2 * (v[2] * v[2] + v[3] * v[3]);
        let potential = -M1 * G * x[1] - M2 * G * x[3];
        kinetic + potential
    }

    /// Rods as distance constraints (implicit) and the two-angle map (parametric).
    fn system() -> Arc<System> {
        let mut b = SystemBuilder::new(&[0.0, G]);
        b.param("L1", L1).unwrap();
        b.param("L2", L2).unwrap();
        let (x, v) = particles([THETA1, THETA2], [OMEGA1, OMEGA2]);
        let a = b.particle("a", M1, &x[0..2], &v[0..2]).unwrap();
        let bob = b.particle("b", M2, &x[2..4], &v[2..4]).unwrap();
        b.distance("upper rod", a, Endpoint::Fixed(vec![0.0, 0.0]), L1)
            .unwrap();
        b.distance("lower rod", bob, Endpoint::Particle(a), L2)
            .unwrap();
        b.parametric(&["th1", "th2"], &[THETA1, THETA2], &[OMEGA1, OMEGA2])
            .unwrap();
        b.parametric_position_exprs("a", &["L1*sin(th1)", "L1*cos(th1)"])
            .unwrap();
        b.parametric_position_exprs(
            "b",
            &["L1*sin(th1) + L2*sin(th2)", "L1*cos(th1) + L2*cos(th2)"],
        )
        .unwrap();
        Arc::new(b.build().unwrap())
    }

    // Energy: both forces besides gravity are workless constraint forces (rods), so
    // E = T + V is conserved exactly; RK4 at dt = 5e-4 (omega dt ~ 2e-3) keeps it below 1e-8
    // relative of the energy scale T0 + |V0| over 4 s. The two forms integrate the same motion,
    // so their particle trajectories agree to the integration error.
    #[test]
    fn double_pendulum_conserves_energy_and_both_forms_agree() {
        let system = system();
        let mut implicit = Implicit::new(system.clone(), Feedback::default());
        let mut parametric = Parametric::new(system).unwrap();
        let mut si = implicit.initial_state();
        let mut sp = parametric.initial_state();
        let mut integrator_i = IntegratorKind::Rk4.build(si.q.len());
        let mut integrator_p = IntegratorKind::Rk4.build(sp.q.len());
        let (x0, v0) = particles([THETA1, THETA2], [OMEGA1, OMEGA2]);
        assert_eq!(si.q, x0);
        let e0 = energy(&x0, &v0);
        let scale = {
            let kinetic = energy(&[0.0; 4], &v0);
            kinetic + (e0 - kinetic).abs()
        };
        let (mut x, mut xdot) = ([0.0; 4], [0.0; 4]);
        let (mut drift_i, mut drift_p, mut disagreement): (f64, f64, f64) = (0.0, 0.0, 0.0);
        for _ in 0..STEPS {
            integrator_i.step(&mut implicit, &mut si, DT).unwrap();
            integrator_p.step(&mut parametric, &mut sp, DT).unwrap();
            drift_i = drift_i.max((energy(&si.q, &si.qdot) - e0).abs() / scale);
            parametric.particle_state(sp.t, &sp.q, &sp.qdot, &mut x, &mut xdot);
            drift_p = drift_p.max((energy(&x, &xdot) - e0).abs() / scale);
            let gap = (0..4).map(|k| (si.q[k] - x[k]).powi(2)).sum::<f64>().sqrt();
            disagreement = disagreement.max(gap);
        }
        println!(
            "double pendulum over {} s: max relative energy error implicit {drift_i:.2e}, parametric {drift_p:.2e}; max position gap {disagreement:.2e}",
            STEPS as f64 * DT
        );
        assert!(drift_i < 1e-8, "implicit energy drift {drift_i:e}");
        assert!(drift_p < 1e-8, "parametric energy drift {drift_p:e}");
        assert!(
            disagreement < 1e-7,
            "implicit and parametric positions differ by {disagreement:e}"
        );
    }
}
