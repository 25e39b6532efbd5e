//! Fused accelerations for small systems: the whole acceleration of a step in one tape.
//!
//! For a system with a few constraint rows (implicit form) or generalized coordinates
//! (parametric form), the general path evaluates the constraint or map tape, then assembles
//! and factors a small matrix through the sparse-capable [`crate::linalg`] machinery: loops
//! over patterns and product lists, dynamic dispatch to the solver, copies between buffers.
//! Here the same arithmetic is written once, at load time, into one straight-line
//! [`Tape`] (so one evaluation, interpreted or compiled to machine code, does it all):
//!
//! ```text
//! implicit:   C, Cdot, bias, J (the constraint tape); A = J W J^T;
//!             A lambda = -bias - J W F [- ks C - kd Cdot] (dense LDL^T); a = W (F + J^T lambda)
//! parametric: x, xdot, h, J (the map's tape); M = sum_k m_k J_k^T J_k;
//!             M qddot = sum_k J_k^T (F_k - m_k h_k) (dense LDL^T)
//! ```
//!
//! Every operation is the one the general path does, in its order (the same sums from the
//! same first term, the zeros outside the pattern multiplied as there, the LDL^T's
//! divisions), so a fused acceleration equals the general one **bit for bit**; tests compare
//! them on every shipped scene. The LDL^T's pivots come out with the accelerations: when one
//! fails the relative pivot test, the caller runs the general path, which reports the
//! singular matrix (or the non-finite input) exactly as before.
//!
//! An RK4 step ([`compiled_rk4_step`] for a simulation, [`FusedStep::step_lanes`] for the
//! sweep lanes, whose members share one system) is one tape of four stages with the
//! system's constants (F, W, the feedback gains; F and the masses) folded in: products by 1
//! and sums with -0 vanish and products of constants are done once. Each fold is exact,
//! so the step keeps the general path's bits.
use super::{Feedback, State};
use crate::expr::{Sym, Tape, TapeBuilder};
use crate::integrate::rk4::{self, AccelerationTape};
use crate::linalg::{ConstraintMatrix, LinearSolver, SymmetricPattern};
use crate::model::{ConstraintEval, ConstraintSet, Force, FusedTapes, ParametricMap, System};

/// The variant of the fused tapes without feedback terms (a parametric map's only one).
const NO_FEEDBACK: usize = 0;

/// The most rows (implicit) or generalized coordinates (parametric) fused: the factorization's
/// code grows as m^3 / 6 and the general path's overhead stops dominating.
pub(crate) const FUSE_MAX_ROWS: usize = 8;

/// Outputs of the dense LDL^T in a tape: the factor's pivots D_j and the diagonals they are
/// tested against.
struct Pivots {
    diagonal: Vec<Sym>,
    pivot: Vec<Sym>,
}

/// `terms` summed as `Iterator::sum` does: from -0.0, so the sum of no terms is -0.0 and
/// otherwise starts exactly at the first term (-0.0 + x == x for every x).
fn sum(b: &mut TapeBuilder, terms: impl IntoIterator<Item = Sym>) -> Sym {
    let mut total: Option<Sym> = None;
    for t in terms {
        total = Some(match total {
            None => t,
            Some(s) => b.add(s, t),
        });
    }
    total.unwrap_or_else(|| b.constant(-0.0))
}

/// [`crate::linalg::ldlt_in_place`] on the dense m x m lower triangle `a` (row-major),
/// then [`crate::linalg::ldlt_substitute`] of `rhs`, as tape operations in the same order.
/// Returns the pivots for the caller's test.
fn ldlt_solve(b: &mut TapeBuilder, m: usize, a: &mut [Sym], rhs: &mut [Sym]) -> Pivots {
    let at = |r: usize, c: usize| r * m + c;
    let mut pivots = Pivots {
        diagonal: Vec::with_capacity(m),
        pivot: Vec::with_capacity(m),
    };
    for j in 0..m {
        // w_i = L_ji D_i in the upper triangle, L_ji below.
        for i in 0..j {
            let mut w = a[at(j, i)];
            for k in 0..i {
                let p = b.mul(a[at(k, j)], a[at(i, k)]);
                w = b.sub(w, p);
            }
            a[at(i, j)] = w;
            a[at(j, i)] = b.div(w, a[at(i, i)]);
        }
        let diagonal = a[at(j, j)];
        let mut pivot = diagonal;
        for k in 0..j {
            let p = b.mul(a[at(k, j)], a[at(j, k)]);
            pivot = b.sub(pivot, p);
        }
        pivots.diagonal.push(diagonal);
        pivots.pivot.push(pivot);
        a[at(j, j)] = pivot;
    }
    for i in 0..m {
        let mut y = rhs[i];
        for k in 0..i {
            let p = b.mul(a[at(i, k)], rhs[k]);
            y = b.sub(y, p);
        }
        rhs[i] = y;
    }
    for i in 0..m {
        rhs[i] = b.div(rhs[i], a[at(i, i)]);
    }
    for i in (0..m).rev() {
        let mut z = rhs[i];
        for k in i + 1..m {
            let p = b.mul(a[at(k, i)], rhs[k]);
            z = b.sub(z, p);
        }
        rhs[i] = z;
    }
    pivots
}

/// The dense lower triangle (row-major m x m, zero elsewhere) of a matrix whose pattern
/// `pattern` holds `values` by slot, as [`crate::linalg::DenseLdlt`] scatters it.
fn scatter(b: &TapeBuilder, pattern: &SymmetricPattern, values: &[Sym]) -> Vec<Sym> {
    let m = pattern.dim();
    let mut dense = vec![b.constant(0.0); m * m];
    for j in 0..m {
        for (slot, &i) in pattern.column(j) {
            dense[j * m + i] = values[slot];
        }
    }
    dense
}

/// Whether the LDL^T's pivots pass the relative test of
/// [`crate::linalg::ldlt_in_place`] (else the matrix counts as singular).
fn pivots_pass(diagonal: &[f64], pivot: &[f64], tolerance: f64) -> bool {
    diagonal
        .iter()
        .zip(pivot)
        .all(|(&d, &p)| d > 0.0 && p > tolerance * d)
}

/// The implicit form's fused acceleration. Variables: x (n), v (n), t, F (n), the applied
/// forces computed before (so that every force, the viewer's drag included, enters), W (n),
/// ks, kd (read only with feedback).
/// Outputs: C, Cdot, bias (m each), J (nnz), lambda (m), F + J^T lambda (n), a (n), then the
/// LDL^T's diagonals and pivots (m each).
#[derive(Clone, Debug)]
pub(crate) struct FusedImplicit {
    tape: Tape,
    n: usize,
    m: usize,
    nnz: usize,
    tolerance: f64,
    vars: Vec<f64>,
    scratch: Vec<f64>,
    out: Vec<f64>,
    /// The system's own F when its forces are constant (gravity, constant forces): then in
    /// `vars` too, unless `vars_force_given` (a given F overwrote it).
    constant_force: Option<Vec<f64>>,
    vars_force_given: bool,
    /// The compiled RK4 steps, once asked for
    steps: CompiledSteps,
}

/// Where a fused implicit acceleration leaves what the general path leaves.
pub(crate) struct ImplicitBuffers<'a> {
    pub(crate) constraints: &'a mut ConstraintEval,
    pub(crate) lambda: &'a mut [f64],
    pub(crate) force: &'a mut [f64],
}

/// Build, once, the fused tapes of `system`'s forms where they apply, and the RK4 step a
/// simulation compiles from them where the forces are constant (each form builds
/// its own on first use; this lets [`System::machine_code`] count them all before any run).
pub fn prepare(system: &System) {
    let set = system.constraints();
    // Without feedback, as scenes run by default; any tolerance.
    if let Some(mut fused) = FusedImplicit::new(system, Some(0.0), Feedback::default()) {
        if fused.has_constant_force() {
            // With the monitors' observation, as single runs and the lanes build it.
            compiled_step(&mut fused, set.fused(), Some(set.gradient_tape()));
        }
    }
    if let Some(map) = system.parametric() {
        // The system's constant forces (x, v are not read) and masses.
        let zeros = vec![0.0; system.n_coords()];
        let mut force = zeros.clone();
        system.accumulate_forces(&zeros, &zeros, &mut force);
        let masses = system.coordinate_masses();
        if let Some(mut fused) = FusedParametric::new(system, &force, &masses, 0.0) {
            // With the monitors' observation, as single runs and the lanes build it: one
            // tape for both.
            compiled_step(&mut fused, map.fused(), Some(map.observation_tape()));
        }
    }
}

/// The implicit form's fused tape for `set` (n coordinates), when it applies: 1 to
/// [`FUSE_MAX_ROWS`] rows, all evaluated by the constraint tape. Variables: x, v (n each), t,
/// F (n), w (n, the inverse masses), ks, kd (read only with `feedback`: without, the terms
/// are absent, as [`Feedback::subtract`] leaves them); outputs as [`FusedImplicit`] reads
/// them. Masses, forces and gains are variables so that one tape serves every system and
/// run that shares the set (a sweep's members).
fn implicit_tape(set: &ConstraintSet, n: usize, feedback: bool) -> Option<Tape> {
    let m = set.n_rows();
    if m == 0 || m > FUSE_MAX_ROWS || !set.only_taped() {
        return None;
    }
    // The pattern and product lists of J W J^T (the solver kind does not change them).
    let matrix = ConstraintMatrix::new(set.structure(), LinearSolver::Dense);
    let mut b = TapeBuilder::new();
    let full = b.append(set.full_tape());
    let (value, rest) = full.split_at(m);
    let (velocity, rest) = rest.split_at(m);
    let (bias, jacobian) = rest.split_at(m);
    let mut force: Vec<Sym> = (0..n).map(|k| b.var(2 * n + 1 + k)).collect();
    let w: Vec<Sym> = (0..n).map(|k| b.var(3 * n + 1 + k)).collect();
    let (ks, kd) = (b.var(4 * n + 1), b.var(4 * n + 2));
    // A = J W J^T by slot: sum over the products J_i(a) w_k J_j(b).
    let values: Vec<Sym> = (0..matrix.pattern().nnz())
        .map(|s| {
            let terms: Vec<Sym> = matrix
                .slot_products(s)
                .map(|(a, bb, k)| {
                    let jw = b.mul(jacobian[a], w[k]);
                    b.mul(jw, jacobian[bb])
                })
                .collect();
            sum(&mut b, terms)
        })
        .collect();
    // lambda = -bias - J W F [- ks C - kd Cdot]
    let mut lambda: Vec<Sym> = (0..m)
        .map(|i| {
            let terms: Vec<Sym> = set
                .row_columns(i)
                .iter()
                .zip(set.row_entries(i))
                .map(|(&k, e)| {
                    let jw = b.mul(jacobian[e], w[k]);
                    b.mul(jw, force[k])
                })
                .collect();
            let jwf = sum(&mut b, terms);
            let nb = b.neg(bias[i]);
            let r = b.sub(nb, jwf);
            if !feedback {
                return r;
            }
            let sc = b.mul(ks, value[i]);
            let r = b.sub(r, sc);
            let dc = b.mul(kd, velocity[i]);
            b.sub(r, dc)
        })
        .collect();
    let mut dense = scatter(&b, matrix.pattern(), &values);
    let pivots = ldlt_solve(&mut b, m, &mut dense, &mut lambda);
    // F + J^T lambda, row by row, then a = W F.
    for (i, &li) in lambda.iter().enumerate() {
        for (&k, e) in set.row_columns(i).iter().zip(set.row_entries(i)) {
            let p = b.mul(jacobian[e], li);
            force[k] = b.add(force[k], p);
        }
    }
    let acceleration: Vec<Sym> = (0..n).map(|k| b.mul(w[k], force[k])).collect();
    let mut outputs = full.clone();
    outputs.extend(&lambda);
    outputs.extend(&force);
    outputs.extend(&acceleration);
    outputs.extend(&pivots.diagonal);
    outputs.extend(&pivots.pivot);
    Some(b.finish(&outputs))
}

impl FusedImplicit {
    /// The fused acceleration of `system`'s implicit form with `feedback`, when it applies
    /// (see [`implicit_tape`]) and J W J^T is factored by the dense LDL^T, whose relative
    /// pivot tolerance `tolerance` is. The tape is built once per constraint set and
    /// feedback variant.
    pub(crate) fn new(
        system: &System,
        tolerance: Option<f64>,
        feedback: Feedback,
    ) -> Option<FusedImplicit> {
        let tolerance = tolerance?;
        let set = system.constraints();
        let n = system.n_coords();
        let variant = FusedTapes::variant(!feedback.is_off());
        let tape = set.fused().acceleration[variant]
            .get_or_init(|| implicit_tape(set, n, !feedback.is_off()))
            .clone()?;
        let mut vars = vec![0.0; 4 * n + 3];
        let constant = |f: &Force| matches!(f, Force::Constant { .. });
        let constant_force = system.forces().iter().all(constant).then(|| {
            // F does not depend on x, v: computed once (the same operations as every time).
            let (zeros, mut force) = (vec![0.0; n], vec![0.0; n]);
            system.accumulate_forces(&zeros, &zeros, &mut force);
            vars[2 * n + 1..3 * n + 1].copy_from_slice(&force);
            force
        });
        vars[3 * n + 1..4 * n + 1].copy_from_slice(&system.inverse_mass);
        vars[4 * n + 1] = feedback.ks;
        vars[4 * n + 2] = feedback.kd;
        Some(FusedImplicit {
            scratch: vec![0.0; tape.n_slots()],
            out: vec![0.0; tape.n_outputs()],
            tape,
            n,
            m: set.n_rows(),
            nnz: set.n_nonzeros(),
            tolerance,
            vars,
            constant_force,
            vars_force_given: false,
            steps: CompiledSteps {
                step: None,
                tolerance,
            },
        })
    }

    /// Whether F is constant (and kept by the fused acceleration) while no external force is
    /// applied: the caller then need not compute it.
    pub(crate) fn has_constant_force(&self) -> bool {
        self.constant_force.is_some()
    }

    /// a at (t, x, v) into `a`, under the applied forces `force` when given, else the
    /// constant F kept (see [`Self::has_constant_force`]); false when J W J^T fails the pivot
    /// test (run the general path). What the general path also leaves (C, Cdot, bias, J,
    /// lambda, F + J^T lambda) stays in the tape's outputs until [`Self::unpack`] or
    /// [`Self::multipliers`] reads it: most evaluations are never asked for it.
    pub(crate) fn accelerate(
        &mut self,
        t: f64,
        x: &[f64],
        v: &[f64],
        a: &mut [f64],
        force: Option<&[f64]>,
    ) -> bool {
        let (n, m, nnz) = (self.n, self.m, self.nnz);
        self.vars[..n].copy_from_slice(x);
        self.vars[n..2 * n].copy_from_slice(v);
        self.vars[2 * n] = t;
        if let Some(force) = force {
            self.vars[2 * n + 1..3 * n + 1].copy_from_slice(force);
            self.vars_force_given = true;
        } else if self.vars_force_given {
            if let Some(force) = &self.constant_force {
                self.vars[2 * n + 1..3 * n + 1].copy_from_slice(force);
                self.vars_force_given = false;
            }
        }
        self.tape.eval(&self.vars, &mut self.scratch, &mut self.out);
        let out = &self.out;
        let pivots = 3 * m + nnz + m + 2 * n;
        if !pivots_pass(
            &out[pivots..pivots + m],
            &out[pivots + m..pivots + 2 * m],
            self.tolerance,
        ) {
            return false;
        }
        let acceleration = 3 * m + nnz + m + n;
        a.copy_from_slice(&out[acceleration..acceleration + n]);
        true
    }

    /// The observation tape's outputs at the end of the last compiled RK4 step, if it ended
    /// at exactly (t, x, v) (see [`FusedStep::observation_at`]).
    pub(crate) fn observation_at(&self, t: f64, x: &[f64], v: &[f64]) -> Option<&[f64]> {
        self.steps.observation_at(t, x, v)
    }

    /// The same, the state known to be the step's end (see
    /// [`FusedStep::observation_after_step`]).
    pub(crate) fn observation_after_step(&self, t: f64) -> Option<&[f64]> {
        self.steps.observation_after_step(t)
    }

    /// C (m) and J's entries (nnz) at the end of the last compiled RK4 step, if it ended at
    /// exactly (t, x, v) (see [`FusedStep::observation_at`]): what the monitors observe
    /// there, evaluated inside the step's tape.
    pub(crate) fn step_observation(
        &self,
        t: f64,
        x: &[f64],
        v: &[f64],
    ) -> Option<(&[f64], &[f64])> {
        let out = self.steps.observation_at(t, x, v)?;
        Some((&out[..self.m], &out[self.m..self.m + self.nnz]))
    }

    /// lambda (m) of the last [`Self::accelerate`] that returned true.
    pub(crate) fn multipliers(&self) -> &[f64] {
        let start = 3 * self.m + self.nnz;
        &self.out[start..start + self.m]
    }

    /// C (m) of the last [`Self::accelerate`] that returned true.
    pub(crate) fn values(&self) -> &[f64] {
        &self.out[..self.m]
    }

    /// J's entries (nnz) of the last [`Self::accelerate`] that returned true.
    pub(crate) fn jacobian(&self) -> &[f64] {
        &self.out[3 * self.m..3 * self.m + self.nnz]
    }

    /// What the general path leaves, from the last [`Self::accelerate`] that returned true,
    /// into `buffers`.
    pub(crate) fn unpack(&self, buffers: ImplicitBuffers<'_>) {
        let (n, m, nnz) = (self.n, self.m, self.nnz);
        let out = &self.out;
        let ce = buffers.constraints;
        ce.value.copy_from_slice(&out[..m]);
        ce.velocity.copy_from_slice(&out[m..2 * m]);
        ce.bias.copy_from_slice(&out[2 * m..3 * m]);
        ce.jacobian.copy_from_slice(&out[3 * m..3 * m + nnz]);
        let rest = &out[3 * m + nnz..];
        buffers.lambda.copy_from_slice(&rest[..m]);
        buffers.force.copy_from_slice(&rest[m..m + n]);
    }
}

/// The stages of an RK4 step, each with its pivot tests in the step's outputs.
const STAGES: usize = 4;

/// One RK4 step of a fused acceleration as one tape ([`rk4::step_tape`]), run for one
/// state ([`Self::step_one`], a simulation's steps) or L lanes at once
/// ([`Self::step_lanes`], the sweep lanes).
#[derive(Clone, Debug)]
pub(crate) struct FusedStep {
    tape: Tape,
    n: usize,
    rows: usize,
    constants: usize,
    tolerance: f64,
    vars: Vec<f64>,
    scratch: Vec<f64>,
    out: Vec<f64>,
    /// The lanes the buffers are sized for (0: none yet)
    lanes: usize,
    /// Whether the last [`Self::step_one`] passed (its outputs hold the step end and, for a
    /// step built with one, the observation there)
    stepped: bool,
}

impl FusedStep {
    /// The step of `accel` with `constants` folded into its tape (see [`rk4::step_tape`]),
    /// `observe` at its end; kept in `tapes` by the constants while there is room (see
    /// [`FusedTapes::FOLDED_KEPT`]).
    fn folded(
        accel: AccelerationTape<'_>,
        tapes: &FusedTapes,
        observe: Option<&Tape>,
        tolerance: f64,
        constants: &[f64],
    ) -> FusedStep {
        let observed = observe.is_some();
        // Built under the lock (a few milliseconds, once per constants): another formulation
        // of the same set that asks for the same step meanwhile waits for it, not builds it.
        let mut folded = tapes.folded();
        let kept = FusedTapes::find(&folded, constants, observed).cloned();
        let tape = kept.unwrap_or_else(|| {
            let tape = rk4::step_tape(&accel, observe, Some(constants));
            if folded.len() < FusedTapes::FOLDED_KEPT {
                let key = constants.iter().map(|c| c.to_bits()).collect();
                folded.push((key, observed, tape.clone()));
            }
            tape
        });
        drop(folded);
        let mut step = Self::with_tape(tape, accel, tolerance);
        step.size_for::<1>();
        step
    }

    fn with_tape(tape: Tape, accel: AccelerationTape<'_>, tolerance: f64) -> FusedStep {
        FusedStep {
            tape,
            n: accel.n,
            rows: accel.rows,
            constants: accel.constants,
            tolerance,
            vars: Vec::new(),
            scratch: Vec::new(),
            out: Vec::new(),
            lanes: 0,
            stepped: false,
        }
    }

    /// Size the buffers for L lanes.
    fn size_for<const L: usize>(&mut self) {
        if self.lanes != L {
            let vars = 2 * self.n + 1 + self.constants + 5;
            self.vars = vec![0.0; vars * L];
            self.scratch = vec![0.0; self.tape.n_slots() * L];
            self.out = vec![0.0; self.tape.n_outputs() * L];
            self.lanes = L;
        }
    }

    /// Evaluate the step of every lane from (t, q, qdot) by h: the new state stays in the
    /// outputs; returns which lanes passed every stage's pivot test (`pivots_pass`).
    #[inline(always)]
    fn run<const L: usize>(&mut self, t: f64, h: f64, q: &[f64], qdot: &[f64]) -> [bool; L] {
        let (n, rows) = (self.n, self.rows);
        let after = 2 * n + 1 + self.constants;
        self.vars[..n * L].copy_from_slice(q);
        self.vars[n * L..2 * n * L].copy_from_slice(qdot);
        self.vars[2 * n * L..(2 * n + 1) * L].fill(t);
        for (i, value) in rk4::step_variables(t, h).into_iter().enumerate() {
            self.vars[(after + i) * L..(after + i + 1) * L].fill(value);
        }
        self.tape
            .eval_lanes::<L>(&self.vars, &mut self.scratch, &mut self.out);
        let tests = &self.out[2 * n * L..(2 * n + 2 * rows * STAGES) * L];
        let (diagonals, pivots) = tests.split_at(rows * STAGES * L);
        let tolerance = self.tolerance;
        // Rows of L (fixed-size arrays) and one 64-bit flag per lane, as wide as the values,
        // so that the lanes' tests run in vector registers.
        let mut pass = [1u64; L];
        for (diagonal, pivot) in diagonals
            .as_chunks::<L>()
            .0
            .iter()
            .zip(pivots.as_chunks::<L>().0)
        {
            pass = std::array::from_fn(|l| {
                pass[l] & u64::from((diagonal[l] > 0.0) & (pivot[l] > tolerance * diagonal[l]))
            });
        }
        pass.map(|pass| pass != 0)
    }

    /// One step of one state from time t by h (the constants are in the tape):
    /// (q, qdot) advanced in place. False, (q, qdot) untouched, when a stage's matrix fails
    /// the pivot test. Only what changes from step to step is written (q, qdot, t and the
    /// step's variables).
    #[inline]
    pub(crate) fn step_one(&mut self, t: f64, h: f64, q: &mut [f64], qdot: &mut [f64]) -> bool {
        // Small states by fixed-length moves (a copy of unknown length is a `memcpy` call,
        // which costs more than the copy) and no bounds check per value.
        match self.n {
            1 => self.step_sized::<1>(t, h, q, qdot),
            2 => self.step_sized::<2>(t, h, q, qdot),
            3 => self.step_sized::<3>(t, h, q, qdot),
            4 => self.step_sized::<4>(t, h, q, qdot),
            6 => self.step_sized::<6>(t, h, q, qdot),
            _ => self.step_sized::<0>(t, h, q, qdot),
        }
    }

    /// [`Self::step_one`] for n = N (N = 0: any n).
    #[inline(always)]
    fn step_sized<const N: usize>(
        &mut self,
        t: f64,
        h: f64,
        q: &mut [f64],
        qdot: &mut [f64],
    ) -> bool {
        debug_assert_eq!(self.lanes, 1, "sized for one lane by `folded`");
        debug_assert!(q.len() == self.n && qdot.len() == self.n);
        let n = if N == 0 { self.n } else { N };
        let after = 2 * n + 1 + self.constants;
        let vars = &mut self.vars[..after + 5];
        vars[..n].copy_from_slice(&q[..n]);
        vars[n..2 * n].copy_from_slice(&qdot[..n]);
        vars[2 * n] = t;
        vars[after..].copy_from_slice(&rk4::step_variables(t, h));
        self.tape.eval(&self.vars, &mut self.scratch, &mut self.out);
        let (state, tests) = self.out.split_at(2 * n);
        let (diagonals, pivots) = tests[..2 * self.rows * STAGES].split_at(self.rows * STAGES);
        self.stepped = pivots_pass(diagonals, pivots, self.tolerance);
        if !self.stepped {
            return false;
        }
        q[..n].copy_from_slice(&state[..n]);
        qdot[..n].copy_from_slice(&state[n..]);
        true
    }

    /// The observation tape's outputs at the end of the last [`Self::step_one`], if the step
    /// was built with one, passed, and ended at exactly (t, q, qdot) (bit for bit: not
    /// moved since by a projection, a restore, or a time set to the step grid that the
    /// step's own t + h misses by a rounding).
    pub(crate) fn observation_at(&self, t: f64, q: &[f64], qdot: &[f64]) -> Option<&[f64]> {
        let n = self.n;
        self.observation_after_step(t).filter(|_| {
            crate::same_bits(&self.out[..n], q) && crate::same_bits(&self.out[n..2 * n], qdot)
        })
    }

    /// [`Self::observation_at`] for a state known to be the end of the last
    /// [`Self::step_one`], which passed (its q and qdot, untouched since): only the time is
    /// compared (the step's own t + h may miss the grid's t by a rounding).
    pub(crate) fn observation_after_step(&self, t: f64) -> Option<&[f64]> {
        let n = self.n;
        // The outputs after the step end and the pivot tests: the observation, if any.
        let observation = &self.out[(2 * n + 2 * self.rows * STAGES).min(self.out.len())..];
        if !(self.stepped && self.lanes == 1) || observation.is_empty() {
            return None;
        }
        let t_end = self.vars[2 * n + 1 + self.constants + 1];
        (t_end.to_bits() == t.to_bits()).then_some(observation)
    }

    /// The observation tape's outputs at the end of the last [`Self::step_lanes`] (lanes
    /// innermost, as the observation tape evaluated there leaves them), for a step built
    /// with one.
    pub(crate) fn observation<const L: usize>(&self) -> &[f64] {
        &self.out[(2 * self.n + 2 * self.rows * STAGES) * L..]
    }

    /// One step of every lane from time t by h (the lanes share the constants, which are in
    /// the tape): from `start` = (q, qdot) (n x L each) to `end`;
    /// `failed[l] = true` where a stage's matrix fails the pivot test (the lane's end is
    /// then garbage).
    #[inline(always)]
    pub(crate) fn step_lanes<const L: usize>(
        &mut self,
        t: f64,
        h: f64,
        start: (&[f64], &[f64]),
        end: (&mut [f64], &mut [f64]),
        failed: &mut [bool; L],
    ) {
        self.size_for::<L>();
        let pass = self.run::<L>(t, h, start.0, start.1);
        let n = self.n;
        end.0.copy_from_slice(&self.out[..n * L]);
        end.1.copy_from_slice(&self.out[n * L..2 * n * L]);
        for l in 0..L {
            failed[l] = !pass[l];
        }
    }
}

impl FusedImplicit {
    /// One RK4 step as one tape for sweep lanes, with the monitors' observation (C and J,
    /// the gradient tape) at its end and `constants` (see [`Self::step_constants`]) folded
    /// in: the single runs' step where the constants are theirs.
    pub(crate) fn rk4_step(&self, set: &ConstraintSet, constants: &[f64]) -> FusedStep {
        let observe = Some(set.gradient_tape());
        FusedStep::folded(
            self.layout(),
            set.fused(),
            observe,
            self.tolerance,
            constants,
        )
    }

    /// The step's constants under the applied forces `force`: F, then W, ks, kd as kept.
    pub(crate) fn step_constants(&self, force: &[f64]) -> Vec<f64> {
        let mut constants = force.to_vec();
        constants.extend_from_slice(&self.vars[3 * self.n + 1..]);
        constants
    }
}

impl CompiledAcceleration for FusedImplicit {
    fn steps(&mut self) -> &mut CompiledSteps {
        &mut self.steps
    }
    /// The acceleration tape's layout for a compiled step: the constants after (x, v, t)
    /// are F, W (n each), ks and kd.
    fn layout(&self) -> AccelerationTape<'_> {
        let (n, m) = (self.n, self.m);
        AccelerationTape::new(&self.tape, n, 2 * n + 2, 3 * m + self.nnz + m + n, m)
    }
    /// The constant F (not a force given to [`Self::accelerate`] since), W, ks, kd.
    fn constants(&self) -> Vec<f64> {
        let force = self.constant_force.as_ref().expect("checked by `Implicit`");
        self.step_constants(force)
    }
}

/// What a compiled RK4 step needs of a fused acceleration (see [`compiled_rk4_step`]).
pub(crate) trait CompiledAcceleration {
    fn steps(&mut self) -> &mut CompiledSteps;
    fn layout(&self) -> AccelerationTape<'_>;
    /// The constants after (q, qdot, t) as the step reads them: fixed for the
    /// acceleration's life.
    fn constants(&self) -> Vec<f64>;
}

/// One RK4 step of a simulation (see `SecondOrderSystem::compiled_rk4_step`): `state`'s q
/// and qdot advanced by dt, the step's tape, with the constants folded in, built on first
/// use (see [`FusedStep::folded`]), with `observe` (what the monitors evaluate at a step's
/// end) at its end when given (see [`CompiledSteps::observation_at`]). False, `state`
/// untouched, when a pivot test failed.
#[inline]
pub(crate) fn compiled_rk4_step(
    fused: &mut impl CompiledAcceleration,
    tapes: &FusedTapes,
    observe: Option<&Tape>,
    state: &mut State,
    dt: f64,
) -> bool {
    let step = compiled_step(fused, tapes, observe);
    step.step_one(state.t, dt, &mut state.q, &mut state.qdot)
}

/// The compiled RK4 step of `fused`, built the first time.
#[inline(always)]
fn compiled_step<'a>(
    fused: &'a mut impl CompiledAcceleration,
    tapes: &FusedTapes,
    observe: Option<&Tape>,
) -> &'a mut FusedStep {
    if fused.steps().step.is_none() {
        build_compiled_step(fused, tapes, observe);
    }
    fused.steps().step.as_deref_mut().expect("built above")
}

#[cold]
#[inline(never)]
fn build_compiled_step(
    fused: &mut impl CompiledAcceleration,
    tapes: &FusedTapes,
    observe: Option<&Tape>,
) {
    let tolerance = fused.steps().tolerance;
    let constants = fused.constants();
    let step = FusedStep::folded(fused.layout(), tapes, observe, tolerance, &constants);
    fused.steps().step = Some(Box::new(step));
}

/// The RK4 step a formulation compiles from its fused acceleration (see
/// `SecondOrderSystem::compiled_rk4_step`), built the first time a step is asked for.
#[derive(Clone, Debug, Default)]
pub(crate) struct CompiledSteps {
    step: Option<Box<FusedStep>>,
    /// The LDL^T's relative pivot tolerance
    tolerance: f64,
}

impl CompiledSteps {
    /// The observation at the end of the last compiled step, if it ended at exactly (t, q,
    /// qdot) (see [`FusedStep::observation_at`]).
    pub(crate) fn observation_at(&self, t: f64, q: &[f64], qdot: &[f64]) -> Option<&[f64]> {
        self.step.as_deref()?.observation_at(t, q, qdot)
    }

    /// See [`FusedStep::observation_after_step`].
    pub(crate) fn observation_after_step(&self, t: f64) -> Option<&[f64]> {
        self.step.as_deref()?.observation_after_step(t)
    }
}

/// The parametric form's fused acceleration, for maps whose applied forces are constant
/// (gravity and constant forces: F is folded in). Variables: q, qdot (n_q each), t.
/// Outputs: x, xdot, h (n each), J (nnz), qddot (n_q), the LDL^T's diagonals and pivots.
#[derive(Clone, Debug)]
pub(crate) struct FusedParametric {
    tape: Tape,
    n: usize,
    n_q: usize,
    nnz: usize,
    tolerance: f64,
    /// F (constant)
    force: Vec<f64>,
    vars: Vec<f64>,
    scratch: Vec<f64>,
    out: Vec<f64>,
    /// The compiled RK4 steps, once asked for
    steps: CompiledSteps,
}

/// Where a fused parametric acceleration leaves the map's evaluation.
pub(crate) struct ParametricBuffers<'a> {
    pub(crate) position: &'a mut [f64],
    pub(crate) velocity: &'a mut [f64],
    pub(crate) bias: &'a mut [f64],
    pub(crate) jacobian: &'a mut [f64],
    /// F, which the general path computes each time
    pub(crate) force: &'a mut [f64],
}

/// The parametric form's fused tape for `map`, when it applies: 1 to [`FUSE_MAX_ROWS`]
/// coordinates. Variables: q, qdot (n_q each), t, F and the coordinates' masses (n each);
/// outputs as [`FusedParametric`] reads them.
fn parametric_tape(map: &ParametricMap) -> Option<Tape> {
    let n_q = map.n_q();
    if n_q == 0 || n_q > FUSE_MAX_ROWS {
        return None;
    }
    let n = map.positions.len();
    let mut b = TapeBuilder::new();
    let evaluation = b.append(map.evaluation_tape());
    let (bias, jacobian) = (&evaluation[2 * n..3 * n], &evaluation[3 * n..]);
    let force: Vec<Sym> = (0..n).map(|k| b.var(2 * n_q + 1 + k)).collect();
    let mass: Vec<Sym> = (0..n).map(|k| b.var(2 * n_q + 1 + n + k)).collect();
    let columns = map.jacobian_columns();
    let zero = b.constant(0.0);
    // M's lower triangle packed by rows, rhs; both from +0.0, as the general assembly.
    let mut matrix = vec![zero; n_q * (n_q + 1) / 2];
    let mut rhs = vec![zero; n_q];
    for k in 0..n {
        let entries = map.row_entries(k);
        let values = &jacobian[entries.clone()];
        let cols = &columns[entries];
        let mh = b.mul(mass[k], bias[k]);
        let reduced = b.sub(force[k], mh);
        for (e, (&j, &value)) in cols.iter().zip(values).enumerate() {
            let p = b.mul(value, reduced);
            rhs[j] = b.add(rhs[j], p);
            let weighted = b.mul(mass[k], value);
            // Columns ascend within a row: entries up to this one are the lower triangle.
            for (&l, &other) in cols[..=e].iter().zip(values) {
                let p = b.mul(weighted, other);
                let slot = j * (j + 1) / 2 + l;
                matrix[slot] = b.add(matrix[slot], p);
            }
        }
    }
    let pattern = SymmetricPattern::dense(n_q);
    let mut dense = scatter(&b, &pattern, &matrix);
    let pivots = ldlt_solve(&mut b, n_q, &mut dense, &mut rhs);
    let mut outputs = evaluation;
    outputs.extend(&rhs);
    outputs.extend(&pivots.diagonal);
    outputs.extend(&pivots.pivot);
    Some(b.finish(&outputs))
}

impl FusedParametric {
    /// The fused acceleration of `system`'s parametric form when it applies (see
    /// [`parametric_tape`]) and every applied force is constant. `force` is F (any x, v: it
    /// does not depend on them), `mass` each coordinate's mass, `tolerance` the dense
    /// LDL^T's relative pivot tolerance. The tape is built once per map.
    pub(crate) fn new(
        system: &System,
        force: &[f64],
        mass: &[f64],
        tolerance: f64,
    ) -> Option<FusedParametric> {
        let map = system.parametric()?;
        let constant = |f: &Force| matches!(f, Force::Constant { .. });
        if !system.forces().iter().all(constant) {
            return None;
        }
        let tape = map.fused().acceleration[NO_FEEDBACK]
            .get_or_init(|| parametric_tape(map))
            .clone()?;
        let (n, n_q) = (map.positions.len(), map.n_q());
        let mut vars = vec![0.0; 2 * n_q + 1 + 2 * n];
        vars[2 * n_q + 1..2 * n_q + 1 + n].copy_from_slice(force);
        vars[2 * n_q + 1 + n..].copy_from_slice(mass);
        Some(FusedParametric {
            scratch: vec![0.0; tape.n_slots()],
            out: vec![0.0; tape.n_outputs()],
            nnz: tape.n_outputs() - 3 * n - 3 * n_q,
            tape,
            n,
            n_q,
            tolerance,
            force: force.to_vec(),
            vars,
            steps: CompiledSteps {
                step: None,
                tolerance,
            },
        })
    }

    /// One RK4 step as one tape for sweep lanes, with the monitors' observation (x, xdot
    /// and J, the observation tape) at its end and [`Self::step_constants`] folded in.
    pub(crate) fn rk4_step(&self, map: &ParametricMap) -> FusedStep {
        let observe = Some(map.observation_tape());
        let constants = self.step_constants();
        FusedStep::folded(
            self.layout(),
            map.fused(),
            observe,
            self.tolerance,
            constants,
        )
    }

    /// The observation tape's outputs at the end of the last compiled RK4 step, if it was
    /// built with them and ended at exactly (t, q, qdot) (see [`FusedStep::observation_at`]).
    pub(crate) fn observation_at(&self, t: f64, q: &[f64], qdot: &[f64]) -> Option<&[f64]> {
        self.steps.observation_at(t, q, qdot)
    }

    /// See [`FusedStep::observation_after_step`].
    pub(crate) fn observation_after_step(&self, t: f64) -> Option<&[f64]> {
        self.steps.observation_after_step(t)
    }

    /// The step's constants: F and the masses.
    pub(crate) fn step_constants(&self) -> &[f64] {
        &self.vars[2 * self.n_q + 1..]
    }

    /// qddot at (t, q, qdot) into `qddot`; false when M fails the pivot test (run the
    /// general path). The map's evaluation (x, xdot, h, J) stays in the tape's outputs until
    /// [`Self::unpack`] or [`Self::evaluation`] reads it.
    pub(crate) fn accelerate(
        &mut self,
        t: f64,
        q: &[f64],
        qdot: &[f64],
        qddot: &mut [f64],
    ) -> bool {
        let (n, n_q, nnz) = (self.n, self.n_q, self.nnz);
        self.vars[..n_q].copy_from_slice(q);
        self.vars[n_q..2 * n_q].copy_from_slice(qdot);
        self.vars[2 * n_q] = t;
        self.tape.eval(&self.vars, &mut self.scratch, &mut self.out);
        let out = &self.out;
        let pivots = 3 * n + nnz + n_q;
        if !pivots_pass(
            &out[pivots..pivots + n_q],
            &out[pivots + n_q..pivots + 2 * n_q],
            self.tolerance,
        ) {
            return false;
        }
        qddot.copy_from_slice(&out[3 * n + nnz..3 * n + nnz + n_q]);
        true
    }

    /// The map's evaluation of the last [`Self::accelerate`] that returned true: x, xdot,
    /// h (n each), J (nnz) and the constant F (n).
    pub(crate) fn evaluation(&self) -> [&[f64]; 5] {
        let (n, nnz) = (self.n, self.nnz);
        let out = &self.out;
        [
            &out[..n],
            &out[n..2 * n],
            &out[2 * n..3 * n],
            &out[3 * n..3 * n + nnz],
            &self.force,
        ]
    }

    /// [`Self::evaluation`] into `buffers`.
    pub(crate) fn unpack(&self, buffers: ParametricBuffers<'_>) {
        let [position, velocity, bias, jacobian, force] = self.evaluation();
        buffers.position.copy_from_slice(position);
        buffers.velocity.copy_from_slice(velocity);
        buffers.bias.copy_from_slice(bias);
        buffers.jacobian.copy_from_slice(jacobian);
        buffers.force.copy_from_slice(force);
    }
}

impl CompiledAcceleration for FusedParametric {
    fn steps(&mut self) -> &mut CompiledSteps {
        &mut self.steps
    }
    /// The acceleration tape's layout for a compiled step: the constants after (q, qdot, t)
    /// are F and each coordinate's mass (n each).
    fn layout(&self) -> AccelerationTape<'_> {
        let (n, n_q) = (self.n, self.n_q);
        AccelerationTape::new(&self.tape, n_q, 2 * n, 3 * n + self.nnz, n_q)
    }
    fn constants(&self) -> Vec<f64> {
        self.step_constants().to_vec()
    }
}

#[cfg(test)]
mod tests {
    use std::path::{Path, PathBuf};
    use std::sync::Arc;

    use super::{CompiledAcceleration, CompiledSteps};
    use crate::expr::testutil::Rng;
    use crate::formulation::{
        Feedback, Formulation, Implicit, Parametric, SecondOrderSystem, State, StepError,
    };
    use crate::integrate::{Integrator, Rk4};
    use crate::model::{FusedTapes, System};
    use crate::scene::Scene;

    /// Two particles of unlike masses in 3D under gravity and a constant force, held by
    /// three expression rows (one moving), with a two-coordinate map: products by the
    /// inverse masses, off-diagonal LDL^T entries and every buffer are exercised.
    const MIXED: &str = r#"
[world]
gravity = [0.3, 9.81, -1.7]
[[particle]]
name = "a"
mass = 0.37
position = [1.0, 0.0, 0.0]
[[particle]]
name = "b"
mass = 2.9
position = [1.0, 0.0, 0.5]
velocity = [0.0, 0.0, -0.2]
[[force]]
kind = "constant"
particle = "b"
vector = [0.7, -0.3, 1.1]
[[constraint]]
expr = "a.x^2 + a.y^2 + a.z^2 - 1"
[[constraint]]
expr = "a.x*b.y - a.y*b.x + 0.3*b.z - 0.15"
[[constraint]]
expr = "b.z + 0.2*sin(t) - 0.5"
[parametric]
coordinates = ["th", "ph"]
initial = [0.4, 1.3]
rates = [0.7, -0.2]
[parametric.positions]
a = ["sin(th)*cos(ph)", "sin(th)*sin(ph)", "cos(th)"]
b = ["sin(th) + 0.3*ph", "cos(ph)*th", "0.5 + 0.1*sin(th*ph)"]
"#;

    /// Every shipped scene and every oracle scene, loaded, with [`MIXED`].
    fn scenes() -> Vec<(String, Scene)> {
        let mut scenes: Vec<(String, Scene)> = scene_files()
            .into_iter()
            .map(|file| {
                let scene = Scene::load(&file, &[]).unwrap_or_else(|e| panic!("{e}"));
                (
                    file.file_name().unwrap().to_string_lossy().to_string(),
                    scene,
                )
            })
            .collect();
        let mixed = Scene::parse(MIXED, "mixed.toml", &[]).unwrap_or_else(|e| panic!("{e}"));
        scenes.push(("mixed.toml".to_string(), mixed));
        scenes
    }

    /// Every shipped scene and every oracle scene.
    fn scene_files() -> Vec<PathBuf> {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        let mut files = Vec::new();
        for dir in ["scenes", "tests/oracle/scenes"] {
            for entry in std::fs::read_dir(root.join(dir)).unwrap() {
                let path = entry.unwrap().path();
                if path.extension().is_some_and(|e| e == "toml") {
                    files.push(path);
                }
            }
        }
        files.sort();
        assert!(files.len() >= 12, "{files:?}");
        files
    }

    fn bits(v: &[f64]) -> Vec<u64> {
        v.iter().map(|x| x.to_bits()).collect()
    }

    /// A state near `base`: each value moved by up to `spread` of its size (and off the
    /// constraints, which the acceleration must not care about), at a random time.
    fn perturbed(rng: &mut Rng, base: &[f64], spread: f64) -> Vec<f64> {
        base.iter()
            .map(|&x| x + spread * (rng.uniform(0.0, 1.0) - 0.5) * (x.abs() + 1.0))
            .collect()
    }

    /// The general path's result at (t, x, v) and what it leaves behind.
    fn general_implicit(
        f: &mut Implicit,
        t: f64,
        x: &[f64],
        v: &[f64],
    ) -> (Result<Vec<f64>, StepError>, Vec<Vec<u64>>) {
        let fused = f.fused.take();
        let mut a = vec![0.0; x.len()];
        let result = f.acceleration(t, x, v, &mut a).map(|()| a);
        f.fused = fused;
        let ce = &f.constraints;
        let left = vec![
            bits(&ce.value),
            bits(&ce.velocity),
            bits(&ce.bias),
            bits(&ce.jacobian),
            bits(&f.lambda),
            bits(&f.force),
        ];
        (result, left)
    }

    fn fused_implicit(
        f: &mut Implicit,
        t: f64,
        x: &[f64],
        v: &[f64],
    ) -> (Result<Vec<f64>, StepError>, Vec<Vec<u64>>) {
        let mut a = vec![0.0; x.len()];
        let result = f.acceleration(t, x, v, &mut a).map(|()| a);
        // Read lazily (lambda straight from the tape's outputs), then unpacked.
        let (lambda, jacobian) = (bits(f.multipliers()), bits(f.jacobian()));
        f.unpack();
        assert_eq!(lambda, bits(&f.lambda));
        assert_eq!(jacobian, bits(&f.constraints.jacobian));
        let ce = &f.constraints;
        let left = vec![
            bits(&ce.value),
            bits(&ce.velocity),
            bits(&ce.bias),
            bits(&ce.jacobian),
            bits(&f.lambda),
            bits(&f.force),
        ];
        (result, left)
    }

    fn same(a: &Result<Vec<f64>, StepError>, b: &Result<Vec<f64>, StepError>) -> bool {
        match (a, b) {
            (Ok(a), Ok(b)) => bits(a) == bits(b),
            (Err(a), Err(b)) => a.to_string() == b.to_string(),
            _ => false,
        }
    }

    fn check_implicit(system: Arc<System>, feedback: Feedback, name: &str, rng: &mut Rng) -> bool {
        let mut f = Implicit::new(system, feedback);
        if f.fused.is_none() {
            return false;
        }
        let (x0, v0) = f.system.initial_particle_state();
        for case in 0..300 {
            let spread = [0.0, 1e-6, 0.1, 2.0][case % 4];
            let (x, v) = (perturbed(rng, &x0, spread), perturbed(rng, &v0, spread));
            let t = 10.0 * rng.uniform(0.0, 1.0);
            let want = general_implicit(&mut f, t, &x, &v);
            let got = fused_implicit(&mut f, t, &x, &v);
            assert!(
                same(&want.0, &got.0),
                "{name} at t {t}, x {x:?}, v {v:?}: {:?} vs {:?}",
                want.0,
                got.0
            );
            if want.0.is_ok() {
                assert_eq!(
                    want.1, got.1,
                    "{name}: buffers differ at t {t}, x {x:?}, v {v:?}"
                );
            }
        }
        true
    }

    #[test]
    fn fused_implicit_acceleration_equals_the_general_path_bit_for_bit() {
        let mut rng = Rng::new(16);
        let mut fused = Vec::new();
        for (name, scene) in scenes() {
            for feedback in [Feedback::default(), Feedback { ks: 25.0, kd: 10.0 }] {
                if check_implicit(Arc::clone(&scene.system), feedback, &name, &mut rng) {
                    fused.push(name.clone());
                }
            }
        }
        // The article's scenes are among those fused.
        for must in [
            "parabola.toml",
            "circle.toml",
            "helix.toml",
            "cusp.toml",
            "mixed.toml",
        ] {
            assert!(
                fused.iter().any(|f| f == must),
                "{must} not fused: {fused:?}"
            );
        }
    }

    #[test]
    fn fused_parametric_acceleration_equals_the_general_path_bit_for_bit() {
        let mut rng = Rng::new(61);
        let mut fused = Vec::new();
        for (file, scene) in scenes() {
            let Ok(mut f) = Parametric::new(Arc::clone(&scene.system)) else {
                continue;
            };
            if f.fused.is_none() {
                continue;
            }
            fused.push(file.clone());
            let start = crate::formulation::Formulation::initial_state(&f);
            for case in 0..300 {
                let spread = [0.0, 1e-6, 0.1, 2.0][case % 4];
                let (q, qdot) = (
                    perturbed(&mut rng, &start.q, spread),
                    perturbed(&mut rng, &start.qdot, spread),
                );
                let t = 10.0 * rng.uniform(0.0, 1.0);
                let saved = f.fused.take();
                let mut want = vec![0.0; q.len()];
                let want_result = f
                    .acceleration(t, &q, &qdot, &mut want)
                    .map(|()| bits(&want));
                let ws = &f.map;
                let want_left = vec![
                    bits(&ws.position),
                    bits(&ws.velocity),
                    bits(&ws.bias),
                    bits(&ws.jacobian),
                    bits(&f.force),
                ];
                f.fused = saved;
                let mut got = vec![0.0; q.len()];
                let got_result = f.acceleration(t, &q, &qdot, &mut got).map(|()| bits(&got));
                // Read lazily (straight from the tape's outputs), then unpacked.
                let lazy: Vec<Vec<u64>> = f.evaluated().iter().map(|v| bits(v)).collect();
                f.unpack();
                let ws = &f.map;
                let got_left = vec![
                    bits(&ws.position),
                    bits(&ws.velocity),
                    bits(&ws.bias),
                    bits(&ws.jacobian),
                    bits(&f.force),
                ];
                assert_eq!(lazy, got_left, "{file}: read lazily");
                match (&want_result, &got_result) {
                    (Ok(a), Ok(b)) => {
                        assert_eq!(a, b, "{} at t {t}, q {q:?}, qdot {qdot:?}", file);
                        assert_eq!(want_left, got_left, "{}: buffers", file);
                    }
                    (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string()),
                    _ => panic!("{}: {want_result:?} vs {got_result:?}", file),
                }
            }
        }
        for must in [
            "parabola.toml",
            "circle.toml",
            "double-pendulum.toml",
            "cycloid.toml",
        ] {
            assert!(
                fused.iter().any(|f| f == must),
                "{must} not fused: {fused:?}"
            );
        }
    }

    /// An external force (the viewer's drag) enters the fused acceleration while applied,
    /// and leaves it when removed: the same bits as the general path before, during, after.
    #[test]
    fn external_forces_come_and_go_as_in_the_general_path() {
        use crate::formulation::Formulation;
        use crate::model::{Force, ParticleId};
        let scene = Scene::parse(MIXED, "mixed.toml", &[]).unwrap();
        let mut f = Implicit::new(Arc::clone(&scene.system), Feedback::default());
        assert!(f.fused.as_ref().is_some_and(|f| f.has_constant_force()));
        let mut rng = Rng::new(7);
        let (x0, v0) = f.system.initial_particle_state();
        for phase in 0..3 {
            f.external_forces_mut().clear();
            if phase == 1 {
                f.external_forces_mut().push(Force::Constant {
                    particle: ParticleId(0),
                    vector: vec![3.0, -1.5, 0.25],
                });
            }
            for _ in 0..20 {
                let (x, v) = (perturbed(&mut rng, &x0, 0.1), perturbed(&mut rng, &v0, 0.1));
                let want = general_implicit(&mut f, 0.5, &x, &v);
                let got = fused_implicit(&mut f, 0.5, &x, &v);
                assert!(
                    same(&want.0, &got.0),
                    "phase {phase}: {:?} vs {:?}",
                    want.0,
                    got.0
                );
                assert_eq!(want.1, got.1, "phase {phase}");
            }
        }
    }

    /// Where J W J^T is singular (the circle's centre: grad C = 0) the fused path hands over
    /// to the general one, which reports it as before.
    #[test]
    fn a_singular_matrix_is_reported_by_the_general_path() {
        let scene = Scene::parse(
            "[world]\ngravity = [0.0, 9.81]\n[[particle]]\nname = \"b\"\nmass = 1.0\nposition = [1.0, 0.0]\n[[constraint]]\nexpr = \"b.x^2 + b.y^2 - 1\"\n",
            "circle.toml",
            &[],
        )
        .unwrap();
        let mut f = Implicit::new(Arc::clone(&scene.system), Feedback::default());
        assert!(f.fused.is_some());
        let (x, v) = ([0.0, 0.0], [0.0, 0.0]);
        let got = fused_implicit(&mut f, 0.0, &x, &v).0;
        let want = general_implicit(&mut f, 0.0, &x, &v).0;
        assert!(got.is_err(), "{got:?}");
        assert!(same(&want, &got), "{want:?} vs {got:?}");
        let nan = fused_implicit(&mut f, 0.0, &[f64::NAN, 0.0], &v).0;
        let want = general_implicit(&mut f, 0.0, &[f64::NAN, 0.0], &v).0;
        assert!(nan.is_err() && same(&want, &nan), "{want:?} vs {nan:?}");
    }

    /// The bits of each value, every NaN as one (a sum's operand order decides which NaN's
    /// sign and payload come out of it; every output prints and tests them alike).
    fn values(v: &[f64]) -> Vec<u64> {
        v.iter()
            .map(|x| if x.is_nan() { f64::NAN } else { *x }.to_bits())
            .collect()
    }

    /// RK4 steps from perturbed states near `start` through `compiled` (its fused
    /// acceleration kept) and through `general` (the same system without it, so every stage
    /// takes the general path), unprimed and primed: the same bits (NaNs aside: see
    /// [`values`]), or the same error where a pivot test fails. Returns how many direct
    /// compiled steps were taken (a step the system declines leaves the state untouched),
    /// and of those how many left the monitors' observation at their end, which must be
    /// what the general path's `observe` gives there, bit for bit.
    fn check_rk4_steps(
        compiled: &mut dyn Formulation,
        general: &mut dyn Formulation,
        start: &State,
        rng: &mut Rng,
        file: &str,
    ) -> (usize, usize) {
        let n = start.q.len();
        let (mut count, mut observed) = (0, 0);
        for case in 0..120 {
            let spread = [0.0, 1e-6, 0.1, 2.0][case % 4];
            let mut from = State {
                t: 10.0 * rng.uniform(0.0, 1.0),
                q: perturbed(rng, &start.q, spread),
                qdot: perturbed(rng, &start.qdot, spread),
            };
            // Non-finite velocities and steps long enough to blow up: the same outcome.
            if case >= 100 {
                let k = case % n;
                from.qdot[k] = [f64::NAN, f64::INFINITY, -f64::INFINITY, 1e300][case % 4];
            }
            let dt = [1.0 / 60.0, 1e-3, 0.1, 1e150][case % 4];
            let run = |system: &mut dyn SecondOrderSystem, primed: bool| {
                let mut rk4 = Rk4::new(n);
                let mut state = from.clone();
                if primed {
                    let _ = rk4.prime(system, &state);
                }
                rk4.step(system, &mut state, dt)
                    .map(|()| (state.t.to_bits(), values(&state.q), values(&state.qdot)))
            };
            let want = run(general, false);
            for primed in [false, true] {
                let got = run(compiled, primed);
                let what = format!("{file}: primed {primed}, dt {dt}, from {from:?}");
                match (&want, &got) {
                    (Ok(a), Ok(b)) => assert_eq!(a, b, "{what}"),
                    (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string(), "{what}"),
                    _ => panic!("{what}: {want:?} vs {got:?}"),
                }
            }
            // Asked directly: done with the same bits, or declined with the state untouched.
            let mut state = from.clone();
            if compiled.compiled_rk4_step(&mut state, dt) {
                count += 1;
                state.t += dt;
                let got = (state.t.to_bits(), values(&state.q), values(&state.qdot));
                assert_eq!(want.as_ref().ok(), Some(&got), "{file}: direct");
                // What the monitors observe there: taken from the step's outputs where it
                // evaluated them, the general path's own evaluation's bits.
                let (t, q, qdot) = (state.t, &state.q, &state.qdot);
                if compiled.compiled_step_observation(t, q, qdot).is_some() {
                    observed += 1;
                    let observation = |f: &mut dyn Formulation| {
                        let mut o = f.new_observation();
                        f.observe(t, q, qdot, &mut o);
                        let g = &o.gradients;
                        [&o.x, &o.xdot, &o.constraints, &g.values, &g.offset].map(|v| bits(v))
                    };
                    assert_eq!(
                        observation(compiled),
                        observation(general),
                        "{file}: the observation at the step's end"
                    );
                }
            } else {
                assert_eq!(bits(&state.q), bits(&from.q), "{file}: declined");
                assert_eq!(bits(&state.qdot), bits(&from.qdot), "{file}: declined");
            }
        }
        (count, observed)
    }

    #[test]
    fn compiled_rk4_steps_equal_the_general_path_bit_for_bit() {
        let mut rng = Rng::new(67);
        let mut compiled = Vec::new();
        for (file, scene) in scenes() {
            let system = &scene.system;
            for feedback in [Feedback::default(), Feedback { ks: 4.0, kd: 3.0 }] {
                let mut f = Implicit::new(Arc::clone(system), feedback);
                let mut general = Implicit::new(Arc::clone(system), feedback);
                general.fused = None;
                let start = crate::formulation::Formulation::initial_state(&f);
                let (steps, observed) =
                    check_rk4_steps(&mut f, &mut general, &start, &mut rng, &file);
                if steps > 0 {
                    compiled.push(format!("implicit {file}"));
                }
                if observed > 0 {
                    compiled.push(format!("implicit {file}, observed"));
                }
            }
            if let (Ok(mut f), Ok(mut general)) = (
                Parametric::new(Arc::clone(system)),
                Parametric::new(Arc::clone(system)),
            ) {
                general.fused = None;
                let start = crate::formulation::Formulation::initial_state(&f);
                let (steps, observed) =
                    check_rk4_steps(&mut f, &mut general, &start, &mut rng, &file);
                if steps > 0 {
                    compiled.push(format!("parametric {file}"));
                }
                if observed > 0 {
                    compiled.push(format!("parametric {file}, observed"));
                }
            }
        }
        for must in [
            "implicit parabola.toml",
            "implicit mixed.toml",
            "implicit helix.toml",
            "implicit spinning-hoop.toml",
            "parametric parabola.toml",
            "parametric mixed.toml",
            "parametric cycloid.toml",
            "parametric double-pendulum.toml",
            "implicit parabola.toml, observed",
            "parametric parabola.toml, observed",
            "parametric double-pendulum.toml, observed",
            "parametric mixed.toml, observed",
            "parametric cycloid.toml, observed",
        ] {
            assert!(
                compiled.iter().any(|c| c == must),
                "{must} not compiled: {compiled:?}"
            );
        }
    }

    /// The article's scene, as shipped.
    fn parabola_scene() -> Scene {
        let file = scene_files()[0].with_file_name("parabola.toml");
        Scene::load(&file, &[]).unwrap_or_else(|e| panic!("{e}"))
    }

    /// The observation a compiled step evaluated at its end is given only for bitwise that
    /// end: a state or a time one ulp off gets none (the caller evaluates its own), for both
    /// forms.
    #[test]
    fn a_compiled_steps_observation_is_given_only_at_its_end() {
        let scene = parabola_scene();
        let system = &scene.system;
        let forms: [Box<dyn Formulation>; 2] = [
            Box::new(Implicit::new(Arc::clone(system), Feedback::default())),
            Box::new(Parametric::new(Arc::clone(system)).unwrap()),
        ];
        for mut f in forms {
            let mut state = f.initial_state();
            assert!(f.compiled_rk4_step(&mut state, 1.0 / 60.0));
            state.t += 1.0 / 60.0;
            let (t, q, qdot) = (state.t, &state.q[..], &state.qdot[..]);
            assert!(f.compiled_step_observation(t, q, qdot).is_some());
            let ulp = |v: f64| f64::from_bits(v.to_bits() + 1);
            assert!(f.compiled_step_observation(ulp(t), q, qdot).is_none());
            let mut moved = q.to_vec();
            moved[0] = ulp(moved[0]);
            assert!(f.compiled_step_observation(t, &moved, qdot).is_none());
            let mut moved = qdot.to_vec();
            moved[0] = ulp(moved[0]);
            assert!(f.compiled_step_observation(t, q, &moved).is_none());
        }
    }

    /// The parametric form's single runs, its sweep lanes and `prepare` ask for one step
    /// tape for the same constants (the one with the monitors' observation at its end).
    #[test]
    fn a_parametric_step_is_one_tape_for_runs_lanes_and_prepare() {
        let scene = parabola_scene();
        let system = &scene.system;
        let map = system.parametric().unwrap();
        let kept = || map.fused().folded().len();
        assert_eq!(kept(), 0);
        super::prepare(system);
        assert_eq!(kept(), 1, "prepare builds the one step");
        let mut f = Parametric::new(Arc::clone(system)).unwrap();
        let mut state = crate::formulation::Formulation::initial_state(&f);
        assert!(f.compiled_rk4_step(&mut state, 1.0 / 60.0));
        assert_eq!(kept(), 1, "a single run's step is prepare's");
        let fused = f.fused.as_ref().unwrap();
        let lanes = fused.rk4_step(map);
        assert_eq!(kept(), 1, "the lanes' step is the single run's");
        let single = fused.steps.step.as_ref().unwrap();
        assert_eq!(format!("{:?}", lanes.tape), format!("{:?}", single.tape));
    }

    /// The sweep lanes' four-chain machine code computes the article's RK4 steps in an order
    /// that holds far fewer values at once than the tapes' (`expr::jit::emission_order`: each
    /// stage's slopes summed as they come): 16 -> 9 (implicit) and 8 -> 5 (parametric) when
    /// written. (The scalar code too for the implicit step; the parametric's 8 values fit.)
    #[test]
    fn the_articles_steps_are_emitted_holding_fewer_values() {
        let scene = parabola_scene();
        let system = &scene.system;
        let mut implicit = Implicit::new(Arc::clone(system), Feedback::default());
        let mut parametric = Parametric::new(Arc::clone(system)).unwrap();
        let mut state = crate::formulation::Formulation::initial_state(&implicit);
        assert!(implicit.compiled_rk4_step(&mut state, 1.0 / 60.0));
        let mut state = crate::formulation::Formulation::initial_state(&parametric);
        assert!(parametric.compiled_rk4_step(&mut state, 1.0 / 60.0));
        let live = |steps: &CompiledSteps| steps.step.as_ref().unwrap().tape.most_live_values();
        let implicit = live(&implicit.fused.as_ref().unwrap().steps);
        let parametric = live(&parametric.fused.as_ref().unwrap().steps);
        for (live, fewer, form) in [(implicit, 6, "implicit"), (parametric, 3, "parametric")] {
            let (in_tape_order, emitted) = live;
            assert!(
                emitted + fewer <= in_tape_order,
                "{form}: {emitted} live at most, against {in_tape_order} in the tape's order"
            );
        }
    }

    /// A simulation's RK4 step folds the system's constants in: the parabola's step has
    /// fewer instructions than the lanes' (the products by the mass 1 vanish); simulations
    /// with the same constants share one folded tape, and a set keeps at most
    /// `FOLDED_KEPT` of them, while every step keeps the general path's bits.
    #[test]
    fn folded_steps_are_shared_by_their_constants_and_kept_to_a_bound() {
        let scene = parabola_scene();
        let system = &scene.system;
        let tapes = system.constraints().fused();
        let kept = || tapes.folded().len();
        assert_eq!(kept(), 0);
        let mut rng = Rng::new(5);
        let start = {
            let f = Implicit::new(Arc::clone(system), Feedback::default());
            crate::formulation::Formulation::initial_state(&f)
        };
        let step = |feedback: Feedback, rng: &mut Rng| {
            let mut f = Implicit::new(Arc::clone(system), feedback);
            let mut general = Implicit::new(Arc::clone(system), feedback);
            general.fused = None;
            assert!(check_rk4_steps(&mut f, &mut general, &start, rng, "parabola.toml").0 > 0);
            f
        };
        let a = step(Feedback::default(), &mut rng);
        let b = step(Feedback::default(), &mut rng);
        assert_eq!(kept(), 1, "the same constants share a tape");
        let fused = a.fused.as_ref().unwrap();
        let folded = fused.steps.step.as_ref().unwrap();
        // The same step with the constants as variables.
        let observe = Some(system.constraints().gradient_tape());
        let unfolded = crate::integrate::rk4::step_tape(&fused.layout(), observe, None);
        let (short, long) = (folded.tape.n_instructions(), unfolded.n_instructions());
        assert!(short + 4 <= long, "folded {short} vs {long} instructions");
        // The lanes' step for these constants is that tape.
        let lanes = fused.rk4_step(system.constraints(), &fused.constants());
        assert_eq!(format!("{:?}", lanes.tape), format!("{:?}", folded.tape));
        assert_eq!(kept(), 1);
        drop(b);
        for k in 1..=FusedTapes::FOLDED_KEPT + 2 {
            step(
                Feedback {
                    ks: k as f64,
                    kd: 0.5,
                },
                &mut rng,
            );
        }
        assert_eq!(kept(), FusedTapes::FOLDED_KEPT);
    }

    /// Zero gains are no term at all: a -0 right-hand side stays -0 and an infinite C
    /// does not turn it into NaN; nonzero gains subtract in the order written.
    #[test]
    fn feedback_off_adds_no_term() {
        let off = Feedback::default();
        assert!(off.is_off());
        assert_eq!(off.subtract(-0.0, 3.0, -2.0).to_bits(), (-0.0f64).to_bits());
        assert_eq!(off.subtract(1.5, f64::INFINITY, f64::NAN), 1.5);
        let on = Feedback { ks: 4.0, kd: 0.0 };
        assert!(!on.is_off());
        assert_eq!(on.subtract(1.0, 0.25, 7.0), 1.0 - 4.0 * 0.25 - 0.0 * 7.0);
        assert!(on.subtract(1.0, f64::INFINITY, 0.0).is_infinite());
    }
}
