//! Classic fourth-order Runge-Kutta on the first-order form y = (q, qdot), y' = (qdot, f):
//!
//! ```text
//! k1 = F(t, y)            k2 = F(t + dt/2, y + dt/2 k1)
//! k3 = F(t + dt/2, y + dt/2 k2)    k4 = F(t + dt, y + dt k3)
//! y' = y + dt/6 (k1 + 2 k2 + 2 k3 + k4)
//! ```
//! Order 4, four evaluations per step; not symplectic: on the article's parametric form the
//! energy slowly decays.

use super::{axpy_into, Integrator};
use crate::expr::{Sym, Tape, TapeBuilder};
use crate::formulation::{SecondOrderSystem, State, StepError};

/// Classic RK4.
pub struct Rk4 {
    /// Stage velocities (the q-slopes) k_i^q = qdot_i, 4 x n
    velocity: [Vec<f64>; 4],
    /// Stage accelerations k_i^qdot, 4 x n
    acceleration: [Vec<f64>; 4],
    q_stage: Vec<f64>,
    /// The state at which `acceleration[0]` was evaluated by [`Integrator::prime`], if it
    /// was and no step has used it since: t, then q and qdot (2n)
    primed: Option<f64>,
    primed_state: Vec<f64>,
}

impl Rk4 {
    pub fn new(n: usize) -> Self {
        let buffers = || [vec![0.0; n], vec![0.0; n], vec![0.0; n], vec![0.0; n]];
        Rk4 {
            velocity: buffers(),
            acceleration: buffers(),
            q_stage: vec![0.0; n],
            primed: None,
            primed_state: vec![0.0; 2 * n],
        }
    }
}

impl Rk4 {
    /// The classic step stage by stage, through the system's acceleration (kept out of
    /// [`Integrator::step`] so that a compiled step's call stays short).
    #[inline(never)]
    fn step_by_stages(
        &mut self,
        system: &mut dyn SecondOrderSystem,
        s: &mut State,
        dt: f64,
    ) -> Result<(), StepError> {
        let [v1, v2, v3, v4] = &mut self.velocity;
        let [a1, a2, a3, a4] = &mut self.acceleration;
        let q = &mut self.q_stage;
        // The first stage evaluated by `prime` at bitwise this state is this one.
        let primed = self.primed.take().is_some_and(|t| {
            let n = s.q.len();
            let (q, qdot) = self.primed_state.split_at(n);
            t.to_bits() == s.t.to_bits()
                && crate::same_bits(q, &s.q)
                && crate::same_bits(qdot, &s.qdot)
        });
        v1.copy_from_slice(&s.qdot);
        if !primed {
            system.acceleration(s.t, &s.q, v1, a1)?;
        }
        axpy_into(q, &s.q, 0.5 * dt, v1);
        axpy_into(v2, &s.qdot, 0.5 * dt, a1);
        system.acceleration(s.t + 0.5 * dt, q, v2, a2)?;
        axpy_into(q, &s.q, 0.5 * dt, v2);
        axpy_into(v3, &s.qdot, 0.5 * dt, a2);
        system.acceleration(s.t + 0.5 * dt, q, v3, a3)?;
        axpy_into(q, &s.q, dt, v3);
        axpy_into(v4, &s.qdot, dt, a3);
        system.acceleration(s.t + dt, q, v4, a4)?;
        let h = dt / 6.0;
        for i in 0..s.q.len() {
            s.q[i] += h * (v1[i] + 2.0 * v2[i] + 2.0 * v3[i] + v4[i]);
            s.qdot[i] += h * (a1[i] + 2.0 * a2[i] + 2.0 * a3[i] + a4[i]);
        }
        s.t += dt;
        Ok(())
    }
}

impl Integrator for Rk4 {
    fn step(
        &mut self,
        system: &mut dyn SecondOrderSystem,
        s: &mut State,
        dt: f64,
    ) -> Result<(), StepError> {
        // The whole step as one compiled tape, where the system has one (the same bits).
        if system.compiled_rk4_step(s, dt) {
            self.primed = None;
            s.t += dt;
            return Ok(());
        }
        self.step_by_stages(system, s, dt)
    }

    fn prime(
        &mut self,
        system: &mut dyn SecondOrderSystem,
        s: &State,
    ) -> Option<Result<(), StepError>> {
        self.primed = None;
        // A system with a compiled step evaluates all four stages in it, cheaper than the
        // first one apart: nothing to prime.
        if system.compiles_rk4_step() {
            return None;
        }
        let result = system.acceleration(s.t, &s.q, &s.qdot, &mut self.acceleration[0]);
        if result.is_ok() {
            let n = s.q.len();
            self.primed_state[..n].copy_from_slice(&s.q);
            self.primed_state[n..].copy_from_slice(&s.qdot);
            self.primed = Some(s.t);
        }
        Some(result)
    }

    fn unprime(&mut self) {
        self.primed = None;
    }
}

/// Where a system's acceleration tape keeps what a compiled step needs (see
/// [`step_tape`]). The tape's variables are x (n), v (n), t, then `constants` values the
/// system holds fixed over a step; its outputs include a (n) from `acceleration`, then the
/// `rows` diagonals and the `rows` pivots of its LDL^T factorization.
#[derive(Clone, Copy, Debug)]
pub(crate) struct AccelerationTape<'a> {
    pub(crate) tape: &'a Tape,
    pub(crate) n: usize,
    pub(crate) constants: usize,
    pub(crate) acceleration: usize,
    pub(crate) rows: usize,
}

impl<'a> AccelerationTape<'a> {
    pub(crate) fn new(
        tape: &'a Tape,
        n: usize,
        constants: usize,
        acceleration: usize,
        rows: usize,
    ) -> Self {
        AccelerationTape {
            tape,
            n,
            constants,
            acceleration,
            rows,
        }
    }

    /// Where the pivot tests start: right after a.
    fn pivots(&self) -> usize {
        self.acceleration + self.n
    }
}

/// The variables after (q, qdot, t, constants) of a [`step_tape`], computed as
/// [`Rk4::step`] computes them: t + h/2, t + h, h/2, h, h/6.
pub(crate) fn step_variables(t: f64, h: f64) -> [f64; 5] {
    let half = 0.5 * h;
    [t + half, t + h, half, h, h / 6.0]
}

/// One classic RK4 step of `accel` as one tape, with [`Rk4::step`]'s arithmetic in its
/// order (so the same bits):
///
/// ```text
/// v1 = qdot              a1 = f(t, q, v1)
/// v2 = qdot + h/2 a1     a2 = f(t + h/2, q + h/2 v1, v2)
/// v3 = qdot + h/2 a2     a3 = f(t + h/2, q + h/2 v2, v3)
/// v4 = qdot + h a3       a4 = f(t + h, q + h v3, v4)
/// q' = q + h/6 (v1 + 2 v2 + 2 v3 + v4),  qdot' = qdot + h/6 (a1 + 2 a2 + 2 a3 + a4)
/// ```
///
/// Variables: q, qdot (n each), t, the constants, then [`step_variables`]; with `values`,
/// the constants are those values, folded into the tape where exact (see
/// `TapeBuilder::append_with`), and their variable slots are not read. Outputs: q',
/// qdot' (n each), then the factorization's diagonals of the four stages (`rows` each),
/// then their pivots in the same order (so that the test is one pass over two runs), then, with
/// `observe` (a tape of variables q, qdot, t: what a run's monitors evaluate at a step's
/// end), its outputs at (q', qdot', t + h).
pub(crate) fn step_tape(
    accel: &AccelerationTape<'_>,
    observe: Option<&Tape>,
    values: Option<&[f64]>,
) -> Tape {
    let n = accel.n;
    let mut b = TapeBuilder::new();
    let q: Vec<Sym> = (0..n).map(|k| b.var(k)).collect();
    let qdot: Vec<Sym> = (0..n).map(|k| b.var(n + k)).collect();
    let t = b.var(2 * n);
    let constants: Vec<Sym> = match values {
        Some(values) => {
            debug_assert_eq!(values.len(), accel.constants);
            values.iter().map(|&c| b.constant(c)).collect()
        }
        None => (0..accel.constants).map(|k| b.var(2 * n + 1 + k)).collect(),
    };
    let after = 2 * n + 1 + accel.constants;
    let [t_half, t_full, half, h, sixth] = std::array::from_fn(|i| b.var(after + i));
    let mut diagonals = Vec::with_capacity(4 * accel.rows);
    let mut pivots = Vec::with_capacity(4 * accel.rows);
    let mut stage = |b: &mut TapeBuilder, x: &[Sym], v: &[Sym], t: Sym| -> Vec<Sym> {
        let vars: Vec<Sym> = x
            .iter()
            .chain(v)
            .chain([&t])
            .chain(&constants)
            .copied()
            .collect();
        let out = b.append_with(accel.tape, &vars);
        let at = accel.pivots();
        diagonals.extend_from_slice(&out[at..at + accel.rows]);
        pivots.extend_from_slice(&out[at + accel.rows..at + 2 * accel.rows]);
        out[accel.acceleration..accel.acceleration + n].to_vec()
    };
    // y = x + c z (`axpy_into`).
    let axpy = |b: &mut TapeBuilder, x: &[Sym], c: Sym, z: &[Sym]| -> Vec<Sym> {
        x.iter()
            .zip(z)
            .map(|(&x, &z)| {
                let p = b.mul(c, z);
                b.add(x, p)
            })
            .collect()
    };
    let v1 = qdot.clone();
    let a1 = stage(&mut b, &q, &v1, t);
    let (x2, v2) = (axpy(&mut b, &q, half, &v1), axpy(&mut b, &qdot, half, &a1));
    let a2 = stage(&mut b, &x2, &v2, t_half);
    let (x3, v3) = (axpy(&mut b, &q, half, &v2), axpy(&mut b, &qdot, half, &a2));
    let a3 = stage(&mut b, &x3, &v3, t_half);
    let (x4, v4) = (axpy(&mut b, &q, h, &v3), axpy(&mut b, &qdot, h, &a3));
    let a4 = stage(&mut b, &x4, &v4, t_full);
    // y += h/6 (k1 + 2 k2 + 2 k3 + k4), the sum left to right.
    let two = b.constant(2.0);
    let update = |b: &mut TapeBuilder, y: &[Sym], k: [&[Sym]; 4]| -> Vec<Sym> {
        (0..n)
            .map(|i| {
                let k2 = b.mul(two, k[1][i]);
                let s = b.add(k[0][i], k2);
                let k3 = b.mul(two, k[2][i]);
                let s = b.add(s, k3);
                let s = b.add(s, k[3][i]);
                let p = b.mul(sixth, s);
                b.add(y[i], p)
            })
            .collect()
    };
    let mut outputs = update(&mut b, &q, [&v1, &v2, &v3, &v4]);
    outputs.extend(update(&mut b, &qdot, [&a1, &a2, &a3, &a4]));
    outputs.extend(diagonals);
    outputs.extend(pivots);
    if let Some(observe) = observe {
        let end: Vec<Sym> = outputs[..2 * n].iter().chain([&t_full]).copied().collect();
        let observed = b.append_with(observe, &end);
        outputs.extend(observed);
    }
    b.finish(&outputs)
}
