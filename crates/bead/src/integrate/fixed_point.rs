//! The stopping rule shared by the fixed-point iterations on accelerations: gauss-legendre's
//! stage equations and the implicit velocity half kick of verlet and rattle.
//!
//! Each sweep replaces the accelerations A by f evaluated at the velocities (and positions)
//! that A implies; the iteration contracts by about dt ||df/dqdot|| (+ dt^2 ||df/dq|| for
//! gauss-legendre) per sweep. It has converged when the increment's max norm is at most
//! `tolerance` times the max norm of the new A, or when the increments stop shrinking at a
//! level that is already round-off (below STAGNATION_LEVEL of A). A non-finite increment or
//! more than `max_iterations` sweeps is [`StepError::ImplicitStageFailed`], naming the method
//! and the equations: never a silent continuation.

use crate::formulation::StepError;

/// Increments that stop shrinking below this fraction of |A| have reached round-off.
const STAGNATION_LEVEL: f64 = 1e-10;

/// Tolerance, iteration limit and names of one implicit solve.
#[derive(Clone, Copy, Debug)]
pub(crate) struct FixedPoint {
    pub(crate) method: &'static str,
    pub(crate) equations: &'static str,
    pub(crate) tolerance: f64,
    pub(crate) max_iterations: u32,
}

/// (max_k |new_k - old_k|, max_k |new_k|) folded into `(increment, scale)`: the increment is
/// NaN as soon as one difference is, so that a non-finite iterate never looks converged.
pub(crate) fn increment_and_scale(
    new: &[f64],
    old: &[f64],
    (increment, scale): (f64, f64),
) -> (f64, f64) {
    new.iter()
        .zip(old)
        .fold((increment, scale), |(increment, scale), (new, old)| {
            let d = (new - old).abs();
            (
                if d.is_nan() || increment.is_nan() {
                    f64::NAN
                } else {
                    increment.max(d)
                },
                scale.max(new.abs()),
            )
        })
}

impl FixedPoint {
    /// After sweep number `iterations` (from 1) at time `t`, with the sweep's increment and
    /// scale (see [`increment_and_scale`]) and the previous sweep's increment (infinite on
    /// the first): `Ok(true)` when converged, `Ok(false)` to sweep again, `Err` when the
    /// iteration failed.
    pub(crate) fn converged(
        &self,
        t: f64,
        iterations: u32,
        increment: f64,
        previous: f64,
        scale: f64,
    ) -> Result<bool, StepError> {
        let failed = |residual| StepError::ImplicitStageFailed {
            method: self.method,
            equations: self.equations,
            t,
            iterations,
            residual,
        };
        if !increment.is_finite() || !scale.is_finite() {
            return Err(failed(f64::NAN));
        }
        if increment <= self.tolerance * scale
            || (increment >= previous && increment <= STAGNATION_LEVEL * scale)
        {
            return Ok(true);
        }
        if iterations >= self.max_iterations {
            return Err(failed(if scale > 0.0 {
                increment / scale
            } else {
                increment
            }));
        }
        Ok(false)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const RULE: FixedPoint = FixedPoint {
        method: "test",
        equations: "test equations",
        tolerance: 1e-14,
        max_iterations: 3,
    };

    #[test]
    fn converges_at_the_tolerance_or_at_round_off_stagnation() {
        assert_eq!(RULE.converged(0.0, 1, 1e-15, f64::INFINITY, 1.0), Ok(true));
        assert_eq!(RULE.converged(0.0, 1, 0.0, f64::INFINITY, 0.0), Ok(true));
        assert_eq!(RULE.converged(0.0, 1, 1e-6, f64::INFINITY, 1.0), Ok(false));
        // Stopped shrinking, but at round-off: done.
        assert_eq!(RULE.converged(0.0, 2, 2e-13, 1e-13, 1.0), Ok(true));
        // Stopped shrinking far above round-off: keep going (and fail at the limit).
        assert_eq!(RULE.converged(0.0, 2, 2e-6, 1e-6, 1.0), Ok(false));
    }

    #[test]
    fn fails_on_non_finite_values_and_after_the_iteration_limit() {
        // NaN stays NaN whatever follows (f64::max alone would drop it).
        let increment = increment_and_scale(&[f64::NAN, 1.0], &[1.0, 2.0], (0.0, 0.0)).0;
        assert!(increment.is_nan());
        let increment = increment_and_scale(&[1.0, f64::NAN], &[1.0, 2.0], (0.0, 0.0)).0;
        assert!(increment.is_nan());
        let increment = increment_and_scale(&[3.0], &[1.0], (f64::NAN, 0.0)).0;
        assert!(increment.is_nan());
        assert!(matches!(
            RULE.converged(0.5, 1, increment, f64::INFINITY, 1.0),
            Err(StepError::ImplicitStageFailed {
                method: "test",
                iterations: 1,
                ..
            })
        ));
        let err = RULE.converged(0.5, 3, 1e-3, 1e-2, 2.0).unwrap_err();
        assert_eq!(
            err,
            StepError::ImplicitStageFailed {
                method: "test",
                equations: "test equations",
                t: 0.5,
                iterations: 3,
                residual: 5e-4,
            }
        );
        assert!(err
            .to_string()
            .contains("test: the implicit test equations did not converge"));
    }
}
