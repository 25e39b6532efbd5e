//! Where a restart at rest from dragged positions starts ([`super::Simulation::restart_at_rest`]):
//! the point of the constraints closest to the drop, the same for both formulations.
//!
//! Closest is in the kinetic metric |y - x|_M^2 = sum_k m_k (y_k - x_k)^2 (for one particle,
//! or equal masses, the Euclidean distance), the metric of the implicit form's projections.
//! The mass-weighted projection of the drop onto C = 0 alone lands elsewhere (it follows the
//! gradient from the drop, not the normal through the answer), and the parametric form's fit
//! of x(q) from the current q can fall into a local minimum on the far side of a bowl; both
//! forms therefore start from [`closest_on_constraints`], the parametric one at the q whose
//! x(q) is that point ([`fit_coordinates`], from several seeds).

use std::sync::Arc;

use super::{project, RestartError, SimulationConfig};
use crate::formulation::{formulate, ConstraintScales, Feedback, Formulation, Method, State};
use crate::model::{ParametricMap, System};

/// Tangent steps at most (each one projection and one or two velocity projections).
const MAX_TANGENT_STEPS: usize = 200;
/// The iteration stops after [`SLOW_STEPS`] steps in a row that shrank the tangent residual
/// by less than this factor.
const SLOW_RATIO: f64 = 0.9;
const SLOW_STEPS: usize = 10;

/// The positions on C(y, t) = 0 closest to `x` in the kinetic metric: the first-order
/// conditions are C(y) = 0 and M (y - x) + J^T mu = 0, i.e. the tangent part of x - y
/// vanishes. Found by tangent steps and projections (gradient descent on the constraint
/// manifold in the M metric):
///
/// ```text
/// y_0 = Proj(x),  s_k = P(y_k) (x - y_k),  P = I - W J^T (J W J^T)^-1 J,
/// y_{k+1} = Proj(y_k + a s_k),  a halved while |x - y_{k+1}|_M > |x - y_k|_M,
/// ```
///
/// Proj the mass-weighted Gauss-Newton projection of the implicit form; a starts at twice
/// the last accepted one, at most 1. The ratio of convergence is about kappa d (the
/// curvature times the distance of the drop): a few steps for a drop near a curve, many for
/// one near a centre of curvature or for a stiff mesh of rods. It stops when |s_k|_M <=
/// 1e-13 of the configuration's size |x|_M, when no halving keeps the distance from
/// growing, after [`SLOW_STEPS`] steps in a row that shrank |s| by less than
/// [`SLOW_RATIO`] (the cloth of 2500 particles: 13 steps, 0.2 s, 0.16% closer than the
/// projection of the drop), or after [`MAX_TANGENT_STEPS`]; always at a point on the
/// constraints, the same for every form that asks. P d is computed by the
/// velocity projection (d - W J^T (J W J^T)^-1 (J d + C_t)), less its value at d = 0 when
/// the constraints move (C_t != 0).
pub(super) fn closest_on_constraints(
    system: Arc<System>,
    t: f64,
    x: &[f64],
    config: &SimulationConfig,
) -> Result<Vec<f64>, RestartError> {
    let mut formulation = implicit_projector(system, config)?;
    closest_with(&mut *formulation, t, x, config)
}

/// The implicit form of `system` as the placements use it: no feedback, the constraint
/// tolerance measured as `config` says.
pub(super) fn implicit_projector(
    system: Arc<System>,
    config: &SimulationConfig,
) -> Result<Box<dyn Formulation + Send>, RestartError> {
    let scales = config
        .scaled_constraint_tolerance
        .then(|| ConstraintScales::of(&system));
    let mut formulation = formulate(system, Method::Implicit, Feedback::default())
        .map_err(|_| RestartError::NoCoordinates("the system has no implicit form"))?;
    formulation.set_constraint_scales(scales);
    Ok(formulation)
}

/// [`closest_on_constraints`] with the implicit form `formulation` of the system.
pub(super) fn closest_with(
    formulation: &mut dyn Formulation,
    t: f64,
    x: &[f64],
    config: &SimulationConfig,
) -> Result<Vec<f64>, RestartError> {
    // A point off a unilateral constraint on its allowed side is where it is (in flight):
    // only the rows it is on, or on the wrong side of, are projected onto.
    if formulation.contact().is_some() {
        super::contact::mode_for_positions(formulation, t, x).map_err(RestartError::Projection)?;
    }
    let system = formulation.shared_system();
    let moving =
        (0..system.constraints().n_rows()).any(|r| system.constraints().is_time_dependent(r));
    let w = system.inverse_mass().to_vec();
    let norm = |v: &[f64]| -> f64 { v.iter().zip(&w).map(|(v, w)| v * v / w).sum::<f64>().sqrt() };
    let distance = |y: &[f64]| -> f64 {
        x.iter()
            .zip(y)
            .zip(&w)
            .map(|((x, y), w)| (x - y) * (x - y) / w)
            .sum::<f64>()
            .sqrt()
    };
    let n = x.len();
    let mut state = State {
        t,
        q: x.to_vec(),
        qdot: vec![0.0; n],
    };
    project(formulation, &mut state, config).map_err(RestartError::Projection)?;
    let Some(constrained) = formulation.as_constrained() else {
        return Ok(state.q);
    };
    let settings = &config.settings;
    let mut y = state.q;
    let mut best = distance(&y);
    let size = norm(x).max(norm(&y));
    let mut step = vec![0.0; n];
    let mut offset = vec![0.0; n];
    let mut trial = vec![0.0; n];
    let mut a_last: f64 = 1.0;
    let (mut slow, mut last_length) = (0, f64::INFINITY);
    for _ in 0..MAX_TANGENT_STEPS {
        for k in 0..n {
            step[k] = x[k] - y[k];
        }
        constrained
            .project_velocities(t, &y, &mut step)
            .map_err(RestartError::Projection)?;
        if moving {
            offset.fill(0.0);
            constrained
                .project_velocities(t, &y, &mut offset)
                .map_err(RestartError::Projection)?;
            for (s, o) in step.iter_mut().zip(&offset) {
                *s -= o;
            }
        }
        let length = norm(&step);
        if length.is_nan() || length <= 1e-13 * size {
            break;
        }
        // A contraction slower than 0.9 a step (kappa d near 1: a drop near a centre of
        // curvature, or a stiff mesh of rods such as the cloth) would not reach the
        // tolerance within the steps allowed: stop at the point reached.
        slow = if length > SLOW_RATIO * last_length {
            slow + 1
        } else {
            0
        };
        if slow >= SLOW_STEPS {
            break;
        }
        last_length = length;
        let mut a: f64 = (2.0 * a_last).min(1.0);
        let mut moved = false;
        while a >= 1e-6 {
            for k in 0..n {
                trial[k] = y[k] + a * step[k];
            }
            let projected = constrained.project_positions(
                t,
                &mut trial,
                settings.constraint_tolerance,
                settings.constraint_max_iterations,
            );
            if projected.is_ok() {
                // Not farther, up to rounding: near the answer the distance changes by
                // O(|s|^2) only, below its rounding once |s| < sqrt(eps) d, while the full
                // steps still shrink |s| linearly.
                let d = distance(&trial);
                if d <= best * (1.0 + 4.0 * f64::EPSILON) {
                    best = best.min(d);
                    y.copy_from_slice(&trial);
                    a_last = a;
                    moved = true;
                    break;
                }
            }
            a *= 0.5;
        }
        if !moved {
            break;
        }
    }
    Ok(y)
}

/// The coordinates q whose x(q, t) is closest to `target` in the kinetic metric (weighted
/// least squares, `masses` per particle coordinate), by [`closest_coordinates`] from each
/// of `seeds`; the closest of the results. Several seeds guard against the local minima of
/// the fit (a seed on the far side of a bowl).
pub(super) fn fit_coordinates(
    map: &ParametricMap,
    t: f64,
    seeds: &[&[f64]],
    target: &[f64],
    masses: &[f64],
) -> Result<Vec<f64>, RestartError> {
    let mut best: Option<(f64, Vec<f64>)> = None;
    let mut failure = None;
    for seed in seeds {
        match closest_coordinates(map, t, seed, target, masses) {
            Ok((q, residual)) => {
                if best.as_ref().is_none_or(|(r, _)| residual < *r) {
                    best = Some((residual, q));
                }
            }
            Err(e) => failure = Some(e),
        }
    }
    match (best, failure) {
        (Some((_, q)), _) => Ok(q),
        (None, Some(e)) => Err(e),
        (None, None) => Err(RestartError::NoCoordinates("no starting coordinates")),
    }
}

/// x(q, t) (particle positions) of the map at coordinates q.
pub(super) fn map_positions(map: &ParametricMap, t: f64, q: &[f64]) -> Vec<f64> {
    let mut ws = map.workspace();
    map.observe(t, q, &vec![0.0; q.len()], &mut ws);
    ws.position
}

/// The coordinates q whose x(q, t) is closest to `x` (least squares weighted by `masses`),
/// by Gauss-Newton from `q0`, with a little Levenberg damping so that a singular J^T M J (a
/// point where the map does not depend on q) does not stop it; with the weighted squared
/// distance reached.
fn closest_coordinates(
    map: &ParametricMap,
    t: f64,
    q0: &[f64],
    x: &[f64],
    masses: &[f64],
) -> Result<(Vec<f64>, f64), RestartError> {
    let n_q = map.n_q();
    if n_q > 256 {
        return Err(RestartError::NoCoordinates("more than 256 coordinates"));
    }
    let mut q = q0.to_vec();
    let zero = vec![0.0; n_q];
    let mut ws = map.workspace();
    let residual = |ws: &crate::model::ParametricEval| -> f64 {
        ws.position
            .iter()
            .zip(x)
            .zip(masses)
            .map(|((p, t), m)| m * (p - t) * (p - t))
            .sum()
    };
    for _ in 0..50 {
        map.observe(t, &q, &zero, &mut ws);
        let r0 = residual(&ws);
        // Normal equations J^T M J dq = J^T M (x - x(q)), dense (n_q is small).
        let (mut a, b) = normal_equations(map, &ws, masses, |k| x[k] - ws.position[k]);
        let scale = (0..n_q).map(|i| a[i * n_q + i]).fold(0.0_f64, f64::max);
        for i in 0..n_q {
            a[i * n_q + i] += 1e-9 * scale.max(1e-300);
        }
        let Some(dq) = solve_dense(a, b, n_q) else {
            return Err(RestartError::NoCoordinates("singular least-squares system"));
        };
        // Halve the step until the distance does not grow.
        let mut step = 1.0;
        let mut trial = q.clone();
        loop {
            for i in 0..n_q {
                trial[i] = q[i] + step * dq[i];
            }
            map.observe(t, &trial, &zero, &mut ws);
            if residual(&ws) <= r0 || step < 1e-6 {
                break;
            }
            step *= 0.5;
        }
        let moved = dq.iter().map(|d| (step * d).abs()).fold(0.0, f64::max);
        q.copy_from_slice(&trial);
        if moved <= 1e-12 * (1.0 + q.iter().map(|v| v.abs()).fold(0.0, f64::max)) {
            break;
        }
    }
    if q.iter().any(|v| !v.is_finite()) {
        return Err(RestartError::NoCoordinates("the fit diverged"));
    }
    map.observe(t, &q, &zero, &mut ws);
    let r = residual(&ws);
    Ok((q, r))
}

/// The rates qdot whose velocities xdot = J(q, t) qdot + dx/dt are closest to `v` in the
/// kinetic metric: the normal equations (J^T M J) qdot = J^T M (v - dx/dt), which for a map
/// that traces the constraints is the mass-weighted projection of `v` onto their velocity
/// constraint (the implicit form's).
pub(super) fn fit_rates(
    map: &ParametricMap,
    t: f64,
    q: &[f64],
    v: &[f64],
    masses: &[f64],
) -> Result<Vec<f64>, RestartError> {
    let n_q = map.n_q();
    let mut ws = map.workspace();
    map.observe(t, q, &vec![0.0; n_q], &mut ws);
    let (a, b) = normal_equations(map, &ws, masses, |k| v[k] - ws.velocity[k]);
    solve_dense(a, b, n_q)
        .filter(|qdot| qdot.iter().all(|r| r.is_finite()))
        .ok_or(RestartError::NoCoordinates(
            "the map does not depend on its coordinates here (J^T M J is singular)",
        ))
}

/// The normal equations of a weighted least-squares fit through the map's Jacobian J at the
/// evaluation `ws`: (J^T M J, J^T M r) with M = diag(`masses`) and r_k = `residual(k)`,
/// dense (n_q x n_q, row-major; n_q is small).
fn normal_equations(
    map: &ParametricMap,
    ws: &crate::model::ParametricEval,
    masses: &[f64],
    residual: impl Fn(usize) -> f64,
) -> (Vec<f64>, Vec<f64>) {
    let n_q = map.n_q();
    let columns = map.jacobian_columns();
    let mut a = vec![0.0; n_q * n_q];
    let mut b = vec![0.0; n_q];
    for (k, &m) in masses.iter().enumerate().take(ws.position.len()) {
        let entries = map.row_entries(k);
        let r = residual(k);
        for e in entries.clone() {
            let (i, ji) = (columns[e], ws.jacobian[e]);
            b[i] += m * ji * r;
            for f in entries.clone() {
                a[i * n_q + columns[f]] += m * ji * ws.jacobian[f];
            }
        }
    }
    (a, b)
}

/// Solve the dense n x n system `a` y = `b` (row-major) by Gaussian elimination with partial
/// pivoting; `None` when singular.
pub(super) fn solve_dense(mut a: Vec<f64>, mut b: Vec<f64>, n: usize) -> Option<Vec<f64>> {
    for col in 0..n {
        let pivot =
            (col..n).max_by(|&i, &j| a[i * n + col].abs().total_cmp(&a[j * n + col].abs()))?;
        if a[pivot * n + col].abs() < 1e-300 || !a[pivot * n + col].is_finite() {
            return None;
        }
        if pivot != col {
            for k in 0..n {
                a.swap(pivot * n + k, col * n + k);
            }
            b.swap(pivot, col);
        }
        for row in col + 1..n {
            let f = a[row * n + col] / a[col * n + col];
            for k in col..n {
                a[row * n + k] -= f * a[col * n + k];
            }
            b[row] -= f * b[col];
        }
    }
    let mut y = vec![0.0; n];
    for row in (0..n).rev() {
        let s: f64 = (row + 1..n).map(|k| a[row * n + k] * y[k]).sum();
        y[row] = (b[row] - s) / a[row * n + row];
    }
    Some(y)
}
