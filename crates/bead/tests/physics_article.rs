//! The article's bead on the parabola x^2 + 100 y = 0 (+y down, gravity g = 500 along +y).
//!
//! Physical law checked: Newton's second law for a bead held on a frictionless wire,
//! m a = F + F_c, where the constraint force F_c does no work on any motion the wire allows
//! (d'Alembert's principle). The implicit form realises it as F_c = J^T lambda chosen so that
//! the acceleration keeps C = 0 (Cddot = 0); the parametric form as Lagrange's equation in the
//! coordinate q along the wire. Every expected value below is a closed form derived by hand in
//! the comment above its test, independently of the engine, and compared at ~100 random states
//! with random constant forces and masses to 1e-12 relative.

use std::sync::Arc;

use bead::formulation::{Feedback, Implicit, Parametric, SecondOrderSystem};
use bead::model::{Force, Holonomic, ParticleId, SystemBuilder};
use bead::Scalar;

const G: f64 = 500.0;
const SAMPLES: usize = 100;
const TOLERANCE: f64 = 1e-12;

/// SplitMix64: a small deterministic generator so the tests need no dependency.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    /// Uniform in [lo, hi).
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        let unit = (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        lo + (hi - lo) * unit
    }
}

/// One random test case: a mass, a constant applied force (gravity comes on top), and a
/// state on the parabola moving along it.
#[derive(Clone, Copy, Debug)]
struct Case {
    mass: f64,
    /// Applied force without gravity.
    force: [f64; 2],
    /// Position of the bead along x (= the parametric coordinate q).
    x: f64,
    /// Velocity along x (= qdot).
    vx: f64,
}

impl Case {
    fn random(rng: &mut SplitMix64, i: usize) -> Case {
        // The first quarter of the cases use the article's unit mass; the rest vary it.
        let mass = if i < SAMPLES / 4 {
            1.0
        } else {
            rng.uniform(0.05, 20.0)
        };
        Case {
            mass,
            force: [
                rng.uniform(-1000.0, 1000.0) * mass,
                rng.uniform(-1000.0, 1000.0) * mass,
            ],
            x: rng.uniform(-300.0, 300.0),
            vx: rng.uniform(-400.0, 400.0),
        }
    }
    /// Total applied force including gravity m g along +y.
    fn total_force(&self) -> [f64; 2] {
        [self.force[0], self.force[1] + self.mass * G]
    }
    /// Position on the parabola, y = -x^2/100.
    fn position(&self) -> [f64; 2] {
        [self.x, -self.x * self.x / 100.0]
    }
    /// Tangent velocity v = vx (1, -2x/100): then Cdot = 2x vx + 100 vy = 0.
    fn velocity(&self) -> [f64; 2] {
        [self.vx, -2.0 * self.x * self.vx / 100.0]
    }
}

fn cases(seed: u64) -> Vec<Case> {
    let mut rng = SplitMix64(seed);
    (0..SAMPLES).map(|i| Case::random(&mut rng, i)).collect()
}

/// How the implicit constraint is written.
#[derive(Clone, Copy, Debug)]
enum Written {
    Expression,
    /// A Rust `Holonomic` type, traced into an expression when the system is built
    RustType,
    /// The same type by dual numbers at every evaluation
    RustDuals,
}

/// The article's parabola as a Rust type: C = x^2 + 100 y, differentiated by dual numbers.
struct Parabola(ParticleId);

impl Holonomic for Parabola {
    fn particles(&self) -> Vec<ParticleId> {
        vec![self.0]
    }
    fn value<T: Scalar>(&self, x: &[T], _t: T) -> T {
        x[0] * x[0] + x[1] * 100.0
    }
}

/// The article's system for one case: the implicit constraint written as `written`, and the
/// parametric map x = (q, -q^2/100).
fn article_system(case: &Case, written: Written) -> Arc<bead::model::System> {
    let mut b = SystemBuilder::new(&[0.0, G]);
    let bead = b
        .particle("bead", case.mass, &case.position(), &case.velocity())
        .unwrap();
    b.force(Force::Constant {
        particle: bead,
        vector: case.force.to_vec(),
    })
    .unwrap();
    match written {
        Written::Expression => {
            b.constraint_expr("bead.x^2 + 100*bead.y").unwrap();
        }
        Written::RustType => {
            b.holonomic("parabola", Parabola(bead));
        }
        Written::RustDuals => {
            b.holonomic_by_dual_numbers("parabola", Parabola(bead));
        }
    }
    b.parametric(&["q"], &[case.x], &[case.vx]).unwrap();
    b.parametric_position_exprs("bead", &["q", "-q^2/100"])
        .unwrap();
    Arc::new(b.build().unwrap())
}

fn implicit_acceleration(case: &Case, written: Written) -> [f64; 2] {
    let mut implicit = Implicit::new(article_system(case, written), Feedback::default());
    let mut a = [0.0; 2];
    implicit
        .acceleration(0.0, &case.position(), &case.velocity(), &mut a)
        .unwrap();
    a
}

fn parametric_acceleration(case: &Case) -> f64 {
    let mut parametric = Parametric::new(article_system(case, Written::Expression)).unwrap();
    let mut qddot = [0.0];
    parametric
        .acceleration(0.0, &[case.x], &[case.vx], &mut qddot)
        .unwrap();
    qddot[0]
}

/// Hand derivation of the implicit form (Witkin's constraint-force method) for
/// C(x, y) = x^2 + 100 y with mass m, applied force F = (Fx, Fy) (gravity included), W = 1/m:
///
/// ```text
/// J     = dC/dx = (2x, 100)
/// Cdot  = 2x vx + 100 vy
/// Cddot = 2 vx^2 + 2x ax + 100 ay  = J a + bias,   bias = 2 vx^2
/// a     = W (F + J^T lambda)
/// Cddot = 0  =>  J W J^T lambda = -(bias + J W F)
///   lambda = -(2 vx^2 + (2x Fx + 100 Fy)/m) / ((4x^2 + 10000)/m)
///          = -(2 m vx^2 + 2x Fx + 100 Fy) / (4x^2 + 10000)
/// F_c   = J^T lambda = (2x lambda, 100 lambda)
/// ```
///
/// Returns (acceleration, constraint force).
fn implicit_closed_form(case: &Case) -> ([f64; 2], [f64; 2]) {
    let m = case.mass;
    let [fx, fy] = case.total_force();
    let x = case.x;
    let vx = case.vx;
    let lambda = -(2.0 * m * vx * vx + 2.0 * x * fx + 100.0 * fy) / (4.0 * x * x + 10000.0);
    let fc = [2.0 * x * lambda, 100.0 * lambda];
    ([(fx + fc[0]) / m, (fy + fc[1]) / m], fc)
}

/// |a - b| <= tol * scale, with a message naming the case; returns |a - b| / scale.
fn assert_close(what: &str, got: &[f64], want: &[f64], scale: f64, case: &Case) -> f64 {
    let error = got
        .iter()
        .zip(want)
        .map(|(g, w)| (g - w) * (g - w))
        .sum::<f64>()
        .sqrt();
    assert!(
        error <= TOLERANCE * scale,
        "{what}: got {got:?}, want {want:?}, error {error:e} > {TOLERANCE:e} * scale {scale:e} at {case:?}"
    );
    error / scale
}

/// Print the worst relative error seen by a test.
fn report(test: &str, worst: f64) {
    println!(
        "{test}: worst relative error over {SAMPLES} cases {worst:.2e} (tolerance {TOLERANCE:e})"
    );
}

/// Scale of an implicit acceleration a = (F + F_c)/m: the size of its two contributions (a can
/// be much smaller than either when the applied force is mostly normal to the wire).
fn implicit_scale(case: &Case, fc: [f64; 2]) -> f64 {
    let f = case.total_force();
    (f[0].hypot(f[1]) + fc[0].hypot(fc[1])) / case.mass
}

// Test (a). Derivation: see `implicit_closed_form`. The engine evaluates the same equations
// from its own symbolic derivatives of the constraint text; the two must agree to rounding.
#[test]
fn implicit_acceleration_equals_hand_derived_witkin_solution() {
    let mut worst: f64 = 0.0;
    for case in cases(1) {
        let (want, fc) = implicit_closed_form(&case);
        let got = implicit_acceleration(&case, Written::Expression);
        worst = worst.max(assert_close(
            "implicit acceleration",
            &got,
            &want,
            implicit_scale(&case, fc),
            &case,
        ));
    }
    report(
        "implicit_acceleration_equals_hand_derived_witkin_solution",
        worst,
    );
}

// Test (a), cross-check against the article's printed constraint force,
//
//   Fc.y = (-50 m vx^2 - 100 x Fx - 2500 Fy) / (x^2 + 2500),   Fc.x = Fc.y x / 50.
//
// From the derivation above, Fc.y = 100 lambda = -(200 m vx^2 + 200 x Fx + 10000 Fy) /
// (4 x^2 + 10000) = (-50 m vx^2 - 50 x Fx - 2500 Fy) / (x^2 + 2500), and Fc.x = 2x lambda =
// Fc.y x / 50. The two agree whenever Fx = 0, which is the article's case (gravity only); the
// printed coefficient 100 of x Fx does not follow from the derivation (see the next test), so
// the cross-check uses applied forces that are vertical: gravity plus a random vertical force.
#[test]
fn implicit_constraint_force_matches_article_formula_for_vertical_forces() {
    let mut worst: f64 = 0.0;
    for mut case in cases(2) {
        case.force[0] = 0.0;
        let m = case.mass;
        let [fx, fy] = case.total_force();
        let x = case.x;
        let vx = case.vx;
        let fcy = (-50.0 * m * vx * vx - 100.0 * x * fx - 2500.0 * fy) / (x * x + 2500.0);
        let fc = [fcy * x / 50.0, fcy];
        let want = [(fx + fc[0]) / m, (fy + fc[1]) / m];
        let got = implicit_acceleration(&case, Written::Expression);
        worst = worst.max(assert_close(
            "implicit acceleration vs article's Fc",
            &got,
            &want,
            implicit_scale(&case, fc),
            &case,
        ));
    }
    report(
        "implicit_constraint_force_matches_article_formula_for_vertical_forces",
        worst,
    );
}

// Independent of any formula: the engine's constraint force must be (1) normal to the wire,
// Fc . (1, -2x/100) = 0 (it does no work on the allowed motion), and (2) exactly what keeps
// the bead on the wire: Cddot = 2 vx^2 + 2x ax + 100 ay = 0. Horizontal forces included. These
// two conditions determine Fc uniquely, and the hand derivation satisfies them, so they also
// show that the article's printed coefficient of x Fx (100 instead of 50) is a misprint: at
// x = 50, vx = 0, F = (1, 0), the printed formula gives Fc = (-1, -1), whose component along
// the tangent (1, -1) is 0 but which makes Cddot = 2x ax + 100 ay = 100 (1 - 1) + 100 (-1) =
// -100 != 0, whereas -50 gives Fc = (-1/2, -1/2) and Cddot = 0.
#[test]
fn implicit_constraint_force_is_normal_and_keeps_the_bead_on_the_wire() {
    for case in cases(3) {
        let a = implicit_acceleration(&case, Written::Expression);
        let f = case.total_force();
        let m = case.mass;
        let fc = [m * a[0] - f[0], m * a[1] - f[1]];
        let x = case.x;
        let tangent = [1.0, -2.0 * x / 100.0];
        let fc_norm = fc[0].hypot(fc[1]);
        let tangent_norm = tangent[0].hypot(tangent[1]);
        let work_rate = (fc[0] * tangent[0] + fc[1] * tangent[1]) / tangent_norm;
        // Rounding of F_c = m a - F is relative to |F| + |F_c|.
        let force_scale = f[0].hypot(f[1]) + fc_norm;
        assert!(
            work_rate.abs() <= 1e-12 * force_scale,
            "tangential constraint force {work_rate:e} at {case:?}"
        );
        let cddot = 2.0 * case.vx * case.vx + 2.0 * x * a[0] + 100.0 * a[1];
        let cddot_scale = 2.0 * case.vx * case.vx + (2.0 * x * a[0]).abs() + (100.0 * a[1]).abs();
        assert!(
            cddot.abs() <= 1e-12 * cddot_scale.max(1.0),
            "Cddot = {cddot:e} at {case:?}"
        );
    }
    // The worked example from the comment, with the article's printed coefficient.
    let (x, fx) = (50.0, 1.0);
    let fcy_printed = (-100.0 * x * fx) / (x * x + 2500.0);
    let fc_printed = [fcy_printed * x / 50.0, fcy_printed];
    let cddot_printed = 2.0 * x * (fx + fc_printed[0]) + 100.0 * fc_printed[1];
    assert_eq!(cddot_printed, -100.0);
}

/// Hand derivation of the parametric form. With x(q) = (q, -q^2/100):
///
/// ```text
/// dx/dq = (1, -q/50),   |dx/dq|^2 = 1 + q^2/2500
/// T = m/2 qdot^2 (1 + q^2/2500)
/// dT/dqdot = m qdot (1 + q^2/2500)
/// d/dt dT/dqdot = m qddot (1 + q^2/2500) + 2 m q qdot^2 / 2500
/// dT/dq = m q qdot^2 / 2500
/// Q = F . dx/dq = Fx - Fy q / 50         (generalized force of the applied force F)
/// Lagrange: d/dt dT/dqdot - dT/dq = Q
///   =>  m qddot (1 + q^2/2500) + m q qdot^2 / 2500 = Q
///   =>  qddot = (2500 Q / m - q qdot^2) / (2500 + q^2)
/// ```
///
/// With gravity only, F = (0, m g), Q = -m g q / 50 and qddot = (-q qdot^2 - 50 g q) /
/// (2500 + q^2), the article's formula. Returns (qddot, scale of its numerator terms).
fn parametric_closed_form(case: &Case) -> (f64, f64) {
    let [fx, fy] = case.total_force();
    let (q, qdot, m) = (case.x, case.vx, case.mass);
    let generalized_force = fx - fy * q / 50.0;
    let numerator = 2500.0 * generalized_force / m - q * qdot * qdot;
    let denominator = 2500.0 + q * q;
    let scale =
        ((2500.0 / m) * (fx.abs() + (fy * q / 50.0).abs()) + (q * qdot * qdot).abs()) / denominator;
    (numerator / denominator, scale)
}

// Test (b). Derivation: see `parametric_closed_form`.
#[test]
fn parametric_acceleration_equals_lagrange_equation_with_general_force() {
    let mut worst: f64 = 0.0;
    for case in cases(4) {
        let (want, scale) = parametric_closed_form(&case);
        let got = parametric_acceleration(&case);
        worst = worst.max(assert_close(
            "parametric qddot",
            &[got],
            &[want],
            scale,
            &case,
        ));
    }
    report(
        "parametric_acceleration_equals_lagrange_equation_with_general_force",
        worst,
    );
}

// Test (b), the article's own formula: with gravity alone (no applied force), Lagrange's
// equation above reduces to qddot = (-q qdot^2 - 50 g q) / (2500 + q^2).
#[test]
fn parametric_acceleration_with_gravity_only_matches_article_formula() {
    let mut worst: f64 = 0.0;
    for mut case in cases(5) {
        case.force = [0.0, 0.0];
        let (q, qdot) = (case.x, case.vx);
        let want = (-q * qdot * qdot - 50.0 * G * q) / (2500.0 + q * q);
        let scale = ((q * qdot * qdot).abs() + (50.0 * G * q).abs()) / (2500.0 + q * q);
        let got = parametric_acceleration(&case);
        worst = worst.max(assert_close(
            "parametric qddot vs article",
            &[got],
            &[want],
            scale,
            &case,
        ));
    }
    report(
        "parametric_acceleration_with_gravity_only_matches_article_formula",
        worst,
    );
}

// Test (c). Same derivation as (a); only the way the engine gets J and the bias changes: a
// Rust `Holonomic` type instead of text, traced into an expression when the system is built
// and, separately, by dual numbers at every evaluation. The engine's paths must also agree
// with each other to rounding.
#[test]
fn rust_holonomic_constraint_equals_hand_derived_witkin_solution() {
    let mut worst: f64 = 0.0;
    for case in cases(6) {
        let (want, fc) = implicit_closed_form(&case);
        let scale = implicit_scale(&case, fc);
        let from_text = implicit_acceleration(&case, Written::Expression);
        for (written, what) in [
            (Written::RustType, "Holonomic type, traced"),
            (Written::RustDuals, "Holonomic type, dual numbers"),
        ] {
            let got = implicit_acceleration(&case, written);
            worst = worst.max(assert_close(what, &got, &want, scale, &case));
            let versus = format!("{what} vs expression");
            worst = worst.max(assert_close(&versus, &got, &from_text, scale, &case));
        }
    }
    report(
        "rust_holonomic_constraint_equals_hand_derived_witkin_solution",
        worst,
    );
}

// Test (d). Both forms describe the same motion. With x(q) = (q, -q^2/100):
//
//   xdot  = J qdot,            J = dx/dq = (1, -q/50)
//   xddot = J qddot + h,       h = d2x/dq2 qdot^2 = (0, -qdot^2/50)
//
// So at the matching state x = (q, -q^2/100), v = J qdot, the implicit form's particle
// acceleration must equal J qddot + h with the parametric form's qddot.
#[test]
fn implicit_and_parametric_accelerations_agree_at_matching_states() {
    let mut worst: f64 = 0.0;
    for case in cases(7) {
        let (q, qdot) = (case.x, case.vx);
        let qddot = parametric_acceleration(&case);
        let jacobian = [1.0, -q / 50.0];
        let h = [0.0, -qdot * qdot / 50.0];
        let from_parametric = [jacobian[0] * qddot + h[0], jacobian[1] * qddot + h[1]];
        let implicit = implicit_acceleration(&case, Written::Expression);
        let (_, fc) = implicit_closed_form(&case);
        // Both sides carry the rounding of the parametric scale too, mapped through |J|.
        let (_, parametric_scale) = parametric_closed_form(&case);
        let scale = implicit_scale(&case, fc)
            + parametric_scale * jacobian[0].hypot(jacobian[1])
            + h[1].abs();
        worst = worst.max(assert_close(
            "implicit vs J qddot + h",
            &implicit,
            &from_parametric,
            scale,
            &case,
        ));
    }
    report(
        "implicit_and_parametric_accelerations_agree_at_matching_states",
        worst,
    );
}
