//! Adaptive Dormand-Prince 5(4) (Dormand & Prince 1980; Hairer, Norsett & Wanner, *Solving
//! Ordinary Differential Equations I*, II.4-II.6) on the first-order form
//! y = (q, qdot), y' = (qdot, f):
//!
//! - seven stages, the seventh evaluated at the new solution (FSAL: it is the next step's
//!   first), order 5 propagated, the embedded order-4 solution giving the error estimate
//!   err = sqrt(mean_i (e_i / (atol + rtol max(|y0_i|, |y1_i|)))^2) over all 2n components;
//! - step-size control h_new = h min(FACMAX, max(FACMIN, 0.9 err^(-1/5))), FACMIN = 0.2,
//!   FACMAX = 10 (no growth right after a rejection); a step is accepted when err <= 1;
//! - the starting step of HNW II.4 (an explicit Euler probe of the second derivative);
//! - the continuous extension of order 4 (HNW II.6, the coefficients of Hairer's `dopri5`
//!   code), so that output at requested times is interpolated, not obtained by shortening
//!   steps.
//!
//! [`Dopri5::advance`] makes one accepted step towards an end time (the run loop's adaptive
//! path drives it and samples with [`Dopri5::interpolate`]); the [`Integrator`] impl advances
//! exactly to t + dt with as many steps as the tolerances need, for callers that want fixed
//! output steps. Buffers are allocated at construction; nothing allocates per step.

// Stage loops index the Butcher tableau as the formulas do (a_ij, c_i, b_i).
#![allow(clippy::needless_range_loop)]

use super::{Integrator, IntegratorSettings};
use crate::formulation::{SecondOrderSystem, State, StepError};

const C: [f64; 7] = [0.0, 0.2, 0.3, 0.8, 8.0 / 9.0, 1.0, 1.0];
const A: [[f64; 6]; 7] = [
    [0.0; 6],
    [0.2, 0.0, 0.0, 0.0, 0.0, 0.0],
    [3.0 / 40.0, 9.0 / 40.0, 0.0, 0.0, 0.0, 0.0],
    [44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0, 0.0, 0.0, 0.0],
    [
        19372.0 / 6561.0,
        -25360.0 / 2187.0,
        64448.0 / 6561.0,
        -212.0 / 729.0,
        0.0,
        0.0,
    ],
    [
        9017.0 / 3168.0,
        -355.0 / 33.0,
        46732.0 / 5247.0,
        49.0 / 176.0,
        -5103.0 / 18656.0,
        0.0,
    ],
    [
        35.0 / 384.0,
        0.0,
        500.0 / 1113.0,
        125.0 / 192.0,
        -2187.0 / 6784.0,
        11.0 / 84.0,
    ],
];
/// Error coefficients: 5th-order weights minus the embedded 4th-order ones.
const E: [f64; 7] = [
    71.0 / 57600.0,
    0.0,
    -71.0 / 16695.0,
    71.0 / 1920.0,
    -17253.0 / 339200.0,
    22.0 / 525.0,
    -1.0 / 40.0,
];
/// Dense output coefficients (Hairer's dopri5, HNW II.6).
const D: [f64; 7] = [
    -12715105075.0 / 11282082432.0,
    0.0,
    87487479700.0 / 32700410799.0,
    -10690763975.0 / 1880347072.0,
    701980252875.0 / 199316789632.0,
    -1453857185.0 / 822651844.0,
    69997945.0 / 29380423.0,
];
const SAFETY: f64 = 0.9;
const FACMIN: f64 = 0.2;
const FACMAX: f64 = 10.0;
/// A step below this fraction of the time scale max(|t|, |t_end|) is an underflow.
const STEP_UNDERFLOW: f64 = 1e-14;

/// Adaptive Dormand-Prince 5(4) with dense output.
pub struct Dopri5 {
    rtol: f64,
    atol: f64,
    /// Stage q-slopes (stage velocities), 7 x n
    kq: [Vec<f64>; 7],
    /// Stage qdot-slopes (stage accelerations), 7 x n
    kv: [Vec<f64>; 7],
    q_stage: Vec<f64>,
    v_stage: Vec<f64>,
    /// The state at the start of the last accepted step
    t_old: f64,
    q_old: Vec<f64>,
    v_old: Vec<f64>,
    /// The state at the end of the last accepted step (and of the last attempt)
    t_new: f64,
    q_new: Vec<f64>,
    v_new: Vec<f64>,
    /// Size of the last accepted step
    h_last: f64,
    /// Proposed size of the next step (0: not started)
    h_next: f64,
    /// Whether kq[0], kv[0] hold f at (t_new, q_new, v_new) (FSAL)
    fsal: bool,
    accepted: u64,
    rejected: u64,
}

impl Dopri5 {
    /// For n coordinates, with the tolerances `settings.rtol` and `settings.atol`.
    pub fn new(n: usize, settings: &IntegratorSettings) -> Self {
        let stages = || std::array::from_fn(|_| vec![0.0; n]);
        Dopri5 {
            rtol: settings.rtol,
            atol: settings.atol,
            kq: stages(),
            kv: stages(),
            q_stage: vec![0.0; n],
            v_stage: vec![0.0; n],
            t_old: 0.0,
            q_old: vec![0.0; n],
            v_old: vec![0.0; n],
            t_new: 0.0,
            q_new: vec![0.0; n],
            v_new: vec![0.0; n],
            h_last: 0.0,
            h_next: 0.0,
            fsal: false,
            accepted: 0,
            rejected: 0,
        }
    }

    /// Accepted steps so far.
    pub fn accepted_steps(&self) -> u64 {
        self.accepted
    }

    /// Rejected step attempts so far.
    pub fn rejected_steps(&self) -> u64 {
        self.rejected
    }

    /// The equations changed (a force added, a constraint detached): the last step's final
    /// stage is no longer the next step's first (no FSAL for the next step).
    pub fn forget_last_stage(&mut self) {
        self.fsal = false;
    }

    /// The last accepted step's interval [t_old, t_new].
    pub fn last_step(&self) -> (f64, f64) {
        (self.t_old, self.t_new)
    }

    /// Weighted RMS norm of (q-part, v-part) with scales atol + rtol |y|.
    fn norm(&self, q: &[f64], v: &[f64], sq: &[f64], sv: &[f64]) -> f64 {
        let scaled = |x: f64, y: f64| {
            let sc = self.atol + self.rtol * y.abs();
            if sc > 0.0 {
                x / sc
            } else if x == 0.0 {
                0.0
            } else {
                f64::INFINITY
            }
        };
        let mut sum = 0.0;
        for (x, y) in q.iter().zip(sq).chain(v.iter().zip(sv)) {
            let r = scaled(*x, *y);
            sum += r * r;
        }
        (sum / (2 * q.len()).max(1) as f64).sqrt()
    }

    /// The starting step of HNW II.4 at state `s`, with kq[0], kv[0] = F(s) already set.
    fn initial_step(
        &mut self,
        system: &mut dyn SecondOrderSystem,
        s: &State,
        span: f64,
    ) -> Result<f64, StepError> {
        let d0 = self.norm(&s.q, &s.qdot, &s.q, &s.qdot);
        let d1 = self.norm(&self.kq[0], &self.kv[0], &s.q, &s.qdot);
        let mut h0 = if d0 < 1e-5 || d1 < 1e-5 {
            1e-6
        } else {
            0.01 * d0 / d1
        };
        h0 = h0.min(span);
        // Explicit Euler probe.
        for k in 0..s.q.len() {
            self.q_stage[k] = s.q[k] + h0 * self.kq[0][k];
            self.v_stage[k] = s.qdot[k] + h0 * self.kv[0][k];
        }
        system.acceleration(s.t + h0, &self.q_stage, &self.v_stage, &mut self.kv[1])?;
        // F(y1) - F(y0): the q-part is v_stage - qdot.
        for k in 0..s.q.len() {
            self.kq[1][k] = (self.v_stage[k] - self.kq[0][k]) / h0;
            self.kv[1][k] = (self.kv[1][k] - self.kv[0][k]) / h0;
        }
        let d2 = self.norm(&self.kq[1], &self.kv[1], &s.q, &s.qdot);
        let h1 = if d1.max(d2) <= 1e-15 {
            (h0 * 1e-3).max(1e-6)
        } else {
            (0.01 / d1.max(d2)).powf(0.2)
        };
        let h = (100.0 * h0).min(h1).min(span);
        Ok(if h.is_finite() && h > 0.0 { h } else { span })
    }

    /// Make one accepted step from `s` towards `t_end` (> s.t), never past it: on return `s`
    /// is the new state (s.t == t_end exactly when the step reached it). Rejected attempts are
    /// retried with smaller steps; [`StepError::StepSizeUnderflow`] when the step falls below
    /// 1e-14 of the time scale max(|t|, |t_end|).
    pub fn advance(
        &mut self,
        system: &mut dyn SecondOrderSystem,
        s: &mut State,
        t_end: f64,
    ) -> Result<(), StepError> {
        let n = s.q.len();
        // FSAL only when the state is the one this integrator produced: then the last step's
        // 7th stage (slot 6) is this step's first.
        let continuing =
            self.fsal && self.t_new == s.t && self.q_new == s.q && self.v_new == s.qdot;
        if continuing {
            self.kq.swap(0, 6);
            self.kv.swap(0, 6);
        } else {
            self.kq[0].copy_from_slice(&s.qdot);
            system.acceleration(s.t, &s.q, &s.qdot, &mut self.kv[0])?;
        }
        self.fsal = false;
        if self.h_next <= 0.0 {
            self.h_next = self.initial_step(system, s, t_end - s.t)?;
        }
        let h_min = STEP_UNDERFLOW * s.t.abs().max(t_end.abs());
        let mut just_rejected = false;
        loop {
            let remaining = t_end - s.t;
            // As in Hairer's code: stretch a step that would stop within 1% of t_end, so
            // that no sliver of a step (possibly below the underflow limit) is left over.
            let last = 1.01 * self.h_next >= remaining;
            let h = if last { remaining } else { self.h_next };
            if h.is_nan() || h <= h_min {
                return Err(StepError::StepSizeUnderflow { t: s.t, h });
            }
            // Stages 2..7.
            for i in 1..7 {
                for k in 0..n {
                    let mut dq = 0.0;
                    let mut dv = 0.0;
                    for j in 0..i {
                        dq += A[i][j] * self.kq[j][k];
                        dv += A[i][j] * self.kv[j][k];
                    }
                    self.q_stage[k] = s.q[k] + h * dq;
                    self.v_stage[k] = s.qdot[k] + h * dv;
                }
                if i == 6 {
                    // The 7th stage is at the 5th-order solution.
                    self.q_new.copy_from_slice(&self.q_stage);
                    self.v_new.copy_from_slice(&self.v_stage);
                }
                self.kq[i].copy_from_slice(&self.v_stage);
                let t_stage = if i >= 5 && last {
                    t_end
                } else {
                    s.t + C[i] * h
                };
                system.acceleration(t_stage, &self.q_stage, &self.v_stage, &mut self.kv[i])?;
            }
            // Error estimate (reuse the stage buffers for e), scales from y0 and y1.
            let mut sum = 0.0;
            for k in 0..n {
                let mut eq = 0.0;
                let mut ev = 0.0;
                for j in 0..7 {
                    eq += E[j] * self.kq[j][k];
                    ev += E[j] * self.kv[j][k];
                }
                let sq = self.atol + self.rtol * s.q[k].abs().max(self.q_new[k].abs());
                let sv = self.atol + self.rtol * s.qdot[k].abs().max(self.v_new[k].abs());
                for (e, sc) in [(h * eq, sq), (h * ev, sv)] {
                    let r = if sc > 0.0 {
                        e / sc
                    } else if e == 0.0 {
                        0.0
                    } else {
                        f64::INFINITY
                    };
                    sum += r * r;
                }
            }
            let err = (sum / (2 * n).max(1) as f64).sqrt();
            let finite = err.is_finite()
                && self.q_new.iter().chain(&self.v_new).all(|x| x.is_finite())
                && self.kv[6].iter().all(|x| x.is_finite());
            if finite && err <= 1.0 {
                let mut factor = if err == 0.0 {
                    FACMAX
                } else {
                    (SAFETY * err.powf(-0.2)).clamp(FACMIN, FACMAX)
                };
                if just_rejected {
                    factor = factor.min(1.0);
                }
                self.accepted += 1;
                self.t_old = s.t;
                self.q_old.copy_from_slice(&s.q);
                self.v_old.copy_from_slice(&s.qdot);
                self.t_new = if last { t_end } else { s.t + h };
                s.t = self.t_new;
                s.q.copy_from_slice(&self.q_new);
                s.qdot.copy_from_slice(&self.v_new);
                self.h_last = h;
                // A step clamped to t_end says little about the natural step size: keep the
                // larger of the proposal and the controller's answer.
                let proposed = h * factor;
                self.h_next = if last {
                    proposed.max(self.h_next)
                } else {
                    proposed
                };
                // FSAL: the 7th stage is the next step's first (kept in slot 6 for the dense
                // output until the next step starts, which moves it to slot 0).
                self.fsal = true;
                return Ok(());
            }
            self.rejected += 1;
            just_rejected = true;
            let factor = if finite {
                (SAFETY * err.powf(-0.2)).clamp(FACMIN, 1.0)
            } else {
                FACMIN
            };
            self.h_next = h * factor;
        }
    }

    /// The dense output at time t in the last accepted step [t_old, t_new]: q and qdot
    /// (n each), order 4 in between, the step's own end points at t_old and t_new.
    pub fn interpolate(&self, t: f64, q: &mut [f64], qdot: &mut [f64]) {
        if t == self.t_new {
            q.copy_from_slice(&self.q_new);
            qdot.copy_from_slice(&self.v_new);
            return;
        }
        let h = self.h_last;
        let theta = (t - self.t_old) / h;
        let theta1 = 1.0 - theta;
        let dense = |y0: f64, y1: f64, k: &[Vec<f64>; 7], i: usize| {
            let ydiff = y1 - y0;
            let bspl = h * k[0][i] - ydiff;
            let r4 = ydiff - h * k[6][i] - bspl;
            let mut r5 = 0.0;
            for j in 0..7 {
                r5 += D[j] * k[j][i];
            }
            y0 + theta * (ydiff + theta1 * (bspl + theta * (r4 + theta1 * h * r5)))
        };
        for i in 0..q.len() {
            q[i] = dense(self.q_old[i], self.q_new[i], &self.kq, i);
            qdot[i] = dense(self.v_old[i], self.v_new[i], &self.kv, i);
        }
    }
}

impl Integrator for Dopri5 {
    /// Advance exactly to t + dt with as many accepted steps as the tolerances need.
    fn step(
        &mut self,
        system: &mut dyn SecondOrderSystem,
        s: &mut State,
        dt: f64,
    ) -> Result<(), StepError> {
        let t_end = s.t + dt;
        while s.t < t_end {
            self.advance(system, s, t_end)?;
        }
        Ok(())
    }
}
