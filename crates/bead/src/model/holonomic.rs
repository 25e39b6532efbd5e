//! Constraints written as Rust types: a user writes only C(x, t). When it is declared,
//! [`super::SystemBuilder::holonomic`] traces its code into an expression (see
//! `super::trace`), which then takes the path of a constraint typed in a scene file; code a
//! trace cannot follow (it branches on a value) is differentiated at every evaluation by
//! forward-mode automatic differentiation with num-dual's dual numbers (here).

use std::sync::Arc;

use num_dual::{Dual2_64, Dual64, HyperDual64};

use super::ParticleId;
use crate::Scalar;

/// A holonomic constraint C(x, t) = 0 written in Rust, generic over the number type so that
/// the engine differentiates it exactly, never by finite differences: traced once into an
/// expression with symbolic derivatives and machine code, as a scene file's constraint, or,
/// when the code compares or reads a value (`if x[0] > 0.0`, `re()`) or calls a function
/// expressions do not have (`cbrt`, `exp2`, `log2`, the inverse hyperbolic functions...),
/// by forward-mode dual numbers at every evaluation. [`crate::model::ConstraintInfo`]'s
/// description says which.
///
/// `x` holds the coordinates of [`Holonomic::particles`], concatenated, `dim` entries each.
///
/// ```
/// use bead::model::{Holonomic, ParticleId, SystemBuilder};
/// use bead::Scalar;
///
/// /// The article's parabola x^2 + 100 y = 0.
/// struct Parabola(ParticleId);
/// impl Holonomic for Parabola {
///     fn particles(&self) -> Vec<ParticleId> { vec![self.0] }
///     fn value<T: Scalar>(&self, x: &[T], _t: T) -> T { x[0] * x[0] + x[1] * 100.0 }
///     fn time_dependent(&self) -> bool { false }
/// }
///
/// let mut b = SystemBuilder::new(&[0.0, 500.0]);
/// let bead = b.particle("bead", 1.0, &[150.0, -225.0], &[0.0, 0.0]).unwrap();
/// b.holonomic("parabola", Parabola(bead));
/// let system = b.build().unwrap();
/// assert_eq!(system.constraints().n_rows(), 1);
/// assert_eq!(
///     system.constraint_description(0),
///     "Rust constraint (traced into an expression: symbolic derivatives)"
/// );
/// ```
pub trait Holonomic: Send + Sync + 'static {
    /// The particles whose coordinates the constraint reads, in the order of `x`.
    fn particles(&self) -> Vec<ParticleId>;
    /// C(x, t): a function of x, t and the type's own fixed data. Declared with
    /// [`crate::model::SystemBuilder::holonomic`], it runs once there, at the particles'
    /// positions, to be traced (a panic here is one there), and the expression it records
    /// stands for it from then on: state it reads besides x and t (a parameter changed
    /// through a `Mutex` or an atomic, a clock, a counter) would be frozen, so such code
    /// needs [`crate::model::SystemBuilder::holonomic_by_dual_numbers`], which calls it at
    /// every evaluation. (A trace refuses code that gives another value when run again.)
    fn value<T: Scalar>(&self, x: &[T], t: T) -> T;
    /// Whether C depends on t (a moving or driven constraint). Such a constraint does work on
    /// the particles, which the energy ledger counts. The default, `true`, is the safe answer:
    /// a constraint that does not in fact depend on t then does no work, and the ledger shows
    /// it. Return `false` for a fixed constraint so that its energy is reported as conserved.
    /// Read only by dual numbers: a traced constraint depends on t when its expression does.
    fn time_dependent(&self) -> bool {
        true
    }
}

/// Object-safe face of a [`Holonomic`]: value, gradient and the acceleration bias by
/// dual numbers.
pub(crate) trait ErasedHolonomic: Send + Sync {
    fn value(&self, x: &[f64], t: f64) -> f64;
    fn time_dependent(&self) -> bool;
    /// The gradient (k) and Hessian (k x k, row-major) of C at (x, t), by hyper-dual numbers
    /// (one pass per pair of coordinates). Allocates; for diagnostics only.
    fn gradient_hessian(&self, x: &[f64], t: f64, gradient: &mut [f64], hessian: &mut [f64]);
    /// Fills `gradient` (local coordinates) with dC/dx and returns (C, Cdot, bias) where
    /// Cdot = J v + C_t and bias = v^T H v + 2 C_xt v + C_tt, the second derivative of
    /// s -> C(x + s v, t + s) at s = 0: one Dual2 pass along (v, 1), plus one Dual64 pass per
    /// coordinate for the gradient.
    fn derivatives(
        &self,
        x: &[f64],
        v: &[f64],
        t: f64,
        scratch: &mut DualScratch,
        gradient: &mut [f64],
    ) -> (f64, f64, f64);
}

/// Dual-number buffers reused across evaluations (sized for the largest custom constraint).
#[derive(Clone, Debug, Default)]
pub(crate) struct DualScratch {
    first: Vec<Dual64>,
    second: Vec<Dual2_64>,
}

impl DualScratch {
    pub(crate) fn with_capacity(n: usize) -> Self {
        DualScratch {
            first: vec![Dual64::from(0.0); n],
            second: vec![Dual2_64::from(0.0); n],
        }
    }
}

pub(crate) struct Erased<H>(pub(crate) H);

impl<H: Holonomic> ErasedHolonomic for Erased<H> {
    fn value(&self, x: &[f64], t: f64) -> f64 {
        self.0.value(x, t)
    }

    fn time_dependent(&self) -> bool {
        self.0.time_dependent()
    }

    fn gradient_hessian(&self, x: &[f64], t: f64, gradient: &mut [f64], hessian: &mut [f64]) {
        let n = x.len();
        let mut point = vec![HyperDual64::from(0.0); n];
        for i in 0..n {
            for j in i..n {
                for (k, p) in point.iter_mut().enumerate() {
                    let e1 = if k == i { 1.0 } else { 0.0 };
                    let e2 = if k == j { 1.0 } else { 0.0 };
                    *p = HyperDual64::new(x[k], e1, e2, 0.0);
                }
                let c = self.0.value(&point, HyperDual64::from(t));
                hessian[i * n + j] = c.eps1eps2;
                hessian[j * n + i] = c.eps1eps2;
                if j == i {
                    gradient[i] = c.eps1;
                }
            }
        }
    }

    fn derivatives(
        &self,
        x: &[f64],
        v: &[f64],
        t: f64,
        scratch: &mut DualScratch,
        gradient: &mut [f64],
    ) -> (f64, f64, f64) {
        let n = x.len();
        let first = &mut scratch.first[..n];
        for (k, g) in gradient.iter_mut().enumerate().take(n) {
            for (j, d) in first.iter_mut().enumerate() {
                *d = Dual64::new(x[j], if j == k { 1.0 } else { 0.0 });
            }
            *g = self.0.value(first, Dual64::from(t)).eps;
        }
        let second = &mut scratch.second[..n];
        for (j, d) in second.iter_mut().enumerate() {
            *d = Dual2_64::new(x[j], v[j], 0.0);
        }
        let c = self.0.value(second, Dual2_64::new(t, 1.0, 0.0));
        (c.re, c.v1, c.v2)
    }
}

/// A shared, type-erased Rust constraint.
pub(crate) type SharedHolonomic = Arc<dyn ErasedHolonomic>;
