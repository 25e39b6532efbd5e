//! Ensemble stepping: up to [`LANES`] members of one system (the same equations, each its
//! own initial state) advanced together, for sweeps.
//!
//! Each member is a [`Simulation`] set up as usual (its checks, energy scale and reach are
//! its own); the lanes then take over its steps. Where the formulation has a fused
//! acceleration (a small system; gravity and constant forces) the whole RK4 step is one tape
//! built from it (`FusedStep`: the four stages and the update, `integrate::rk4`'s arithmetic),
//! run once per step for all lanes ([`crate::expr::Tape::eval_lanes`], structure of arrays,
//! compiled as up to four chains of lane pairs, see `expr::jit`). Otherwise, per RK4 stage, the formulation's compiled tape runs
//! once for all lanes; with gravity as the only force the evaluation is finished across the
//! lanes too
//! ([`implicit_across_lanes`], [`Parametric::accelerate_across_lanes`]: the same operations in
//! the same order per member); otherwise each lane is finished by the formulation's own code
//! ([`Implicit::accelerate_evaluated`], [`Parametric::accelerate_evaluated`]). Either way every
//! number is the one the member's own `Simulation` would compute, bit for bit. The monitors
//! after each step run across the lanes too ([`super::lane_monitor`]): the energy and
//! constraint-error maxima, the divergence test and the regularity monitor's first-order
//! candidate tests, with the same operations in the same order per member; the stop
//! condition's screen inside the step stays per lane (the member's own watch, so that a look
//! it asks for is taken alone).
//!
//! Whatever needs more than the plain step (a non-finite or diverged state, a candidate
//! singular point that the simulation would search for, a failed factorization, the stop
//! condition firing) takes the member out of the lanes: its `Simulation` is handed the state
//! and monitor of the step before ([`LaneOutcome::Handover`]), as if it had taken every step
//! so far itself, and takes that step again alone, which gives the numbers and the message it
//! always gives (a located event, a confirmed singular point, a divergence). The lanes are an
//! acceleration, never a second behaviour.
//!
//! Which runs the lanes take ([`lanes_can_run`]): RK4 at a fixed step without substeps,
//! projection, external forces or the energy ledger; the implicit form when all its rows are
//! expression rows (no native rods or pins, no Rust rows), the parametric form always.

use std::sync::Arc;

use super::lane_monitor::{any_of, gather, LaneMonitor};
use super::vector::{compiled_per_vector_set, VectorSet};
use super::{RunOptions, Simulation, Stepper};
use crate::expr::Tape;
use crate::formulation::{Implicit, LaneScratch, Method, Parametric};
use crate::integrate::IntegratorKind;
use crate::model::System;

/// Members stepped together: the tapes' instructions are interpreted once per this many
/// evaluations, and their machine code is compiled for this many lanes.
pub(crate) const LANES: usize = crate::expr::VECTOR_LANES;

/// What became of a member given to [`run_lanes`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum LaneOutcome {
    /// It ran its steps; its `Simulation` holds the end state and the run's figures.
    Done,
    /// Its next step needs what only its own `Simulation` does (see the module): the
    /// simulation stands after `intervals` output intervals, exactly as if it had taken them
    /// itself, and goes on alone ([`super::run_rest`]).
    Handover { intervals: u64 },
    /// The lanes could not take it: run it again alone.
    Leave,
}

/// Whether the lanes can step `simulation`'s run (see the module).
pub(crate) fn lanes_can_run(simulation: &Simulation) -> bool {
    let config = &simulation.config;
    let system = simulation.formulation.system();
    matches!(simulation.stepper, Stepper::Fixed(_))
        && config.integrator == IntegratorKind::Rk4
        && !config.project
        && config.substeps <= 1
        && simulation.ledger.is_none()
        && simulation.formulation.external_forces().is_empty()
        && simulation.contact.is_none()
        && simulation.steps == 0
        && simulation.state.t == 0.0
        && match simulation.method() {
            Method::Implicit => system.constraints().only_taped(),
            Method::Parametric => system.parametric().is_some(),
        }
}

/// The formulation that finishes every lane's evaluation.
enum Kernel {
    Implicit(Box<Implicit>),
    Parametric(Box<Parametric>),
}

/// The lanes' state and scratch, structure of arrays: coordinate k of lane l at `k * LANES + l`.
struct Lanes {
    n: usize,
    q: Vec<f64>,
    qdot: Vec<f64>,
    /// RK4's stage slopes and stage position
    velocity: [Vec<f64>; 4],
    acceleration: [Vec<f64>; 4],
    q_stage: Vec<f64>,
    /// The state one and two step ends back (for a handover)
    q_back: Vec<f64>,
    qdot_back: Vec<f64>,
    q_back2: Vec<f64>,
    /// Tape variables (q, qdot, t), scratch and outputs
    vars: Vec<f64>,
    scratch: Vec<f64>,
    out: Vec<f64>,
    /// The implicit form across lanes (see [`implicit_across_lanes`]): F (n), J W J^T dense
    /// (m x m) and lambda (m), per lane
    force: Vec<f64>,
    dense: Vec<f64>,
    lambda: Vec<f64>,
    /// The parametric form across lanes (see [`Parametric::accelerate_across_lanes`])
    parametric: LaneScratch,
    /// One lane's q, qdot and acceleration
    q_one: Vec<f64>,
    qdot_one: Vec<f64>,
    a_one: Vec<f64>,
}

impl Lanes {
    fn new(n: usize, tapes: &[&Tape]) -> Lanes {
        let slots = tapes.iter().map(|t| t.n_slots()).max().unwrap_or(0);
        let outputs = tapes.iter().map(|t| t.n_outputs()).max().unwrap_or(0);
        let buffer = || vec![0.0; n * LANES];
        Lanes {
            n,
            q: buffer(),
            qdot: buffer(),
            velocity: [buffer(), buffer(), buffer(), buffer()],
            acceleration: [buffer(), buffer(), buffer(), buffer()],
            q_stage: buffer(),
            q_back: buffer(),
            qdot_back: buffer(),
            q_back2: buffer(),
            vars: vec![0.0; (2 * n + 1) * LANES],
            scratch: vec![0.0; slots * LANES],
            out: vec![0.0; outputs * LANES],
            force: buffer(),
            dense: Vec::new(),
            lambda: Vec::new(),
            parametric: LaneScratch::default(),
            q_one: vec![0.0; n],
            qdot_one: vec![0.0; n],
            a_one: vec![0.0; n],
        }
    }

    /// Load the tape variables (q, qdot, t) of every lane.
    fn load_vars(&mut self, t: f64, q: &[f64], qdot: &[f64]) {
        let n = self.n;
        self.vars[..n * LANES].copy_from_slice(q);
        self.vars[n * LANES..2 * n * LANES].copy_from_slice(qdot);
        self.vars[2 * n * LANES..].fill(t);
    }
}

/// Advance `members` (at most [`LANES`], all at t = 0 before their first step, each set up
/// for a system with `system`'s dynamics and its own initial state) over the output intervals
/// of `options` (their ends [`RunOptions::output_time`]), as [`super::run`] would with a null
/// sink. Returns each member's outcome; a `Done` member's
/// simulation then holds the end state and its [`Simulation::stats`] are the run's.
pub(crate) fn run_lanes(
    system: &Arc<System>,
    members: &mut [Simulation],
    options: RunOptions,
) -> Vec<LaneOutcome> {
    run_lanes_in(VectorSet::best(), system, members, options)
}

compiled_per_vector_set! {
    /// [`run_lanes`] in the vector instructions of `set` (the same bits in each).
    fn run_lanes_in(
        system: &Arc<System>,
        members: &mut [Simulation],
        options: RunOptions,
    ) -> Vec<LaneOutcome> = run_lanes_body
}

/// [`run_lanes`] itself, inlined into each compilation of it.
#[inline(always)]
fn run_lanes_body(
    system: &Arc<System>,
    members: &mut [Simulation],
    options: RunOptions,
) -> Vec<LaneOutcome> {
    let steps = options.steps;
    assert!(!members.is_empty() && members.len() <= LANES);
    let count = members.len();
    let system: Arc<System> = Arc::clone(system);
    let config = members[0].config;
    let method = members[0].method();
    let mut kernel = match method {
        Method::Implicit => Kernel::Implicit(Box::new(Implicit::new(
            Arc::clone(&system),
            config.feedback,
        ))),
        Method::Parametric => match Parametric::new(Arc::clone(&system)) {
            Ok(p) => Kernel::Parametric(Box::new(p)),
            Err(_) => return vec![LaneOutcome::Leave; count],
        },
    };
    let n = members[0].n;
    let (step_tape, observe_tape) = match &kernel {
        Kernel::Implicit(_) => (
            system.constraints().full_tape().clone(),
            system.constraints().gradient_tape().clone(),
        ),
        Kernel::Parametric(_) => {
            let map = system.parametric().expect("checked by lanes_can_run");
            (
                map.evaluation_tape().clone(),
                map.observation_tape().clone(),
            )
        }
    };
    let mut lanes = Lanes::new(n, &[&step_tape, &observe_tape]);
    // The whole RK4 step as one tape, where the fused acceleration applies. Building it costs
    // a few milliseconds once per system: not for a lone member (a sweep whose members each
    // load their own equations) unless it is built already.
    let constants = match &kernel {
        Kernel::Implicit(implicit) => implicit
            .fused
            .as_ref()
            .map(|fused| fused.step_constants(&gravity_force(&system))),
        Kernel::Parametric(parametric) => parametric
            .fused
            .as_ref()
            .map(|fused| fused.step_constants().to_vec()),
    };
    let tapes = match &kernel {
        Kernel::Implicit(_) => Some(system.constraints().fused()),
        Kernel::Parametric(_) => system.parametric().map(|map| map.fused()),
    };
    let built = match (&constants, tapes) {
        (Some(constants), Some(tapes)) => tapes.step_kept(constants, true),
        _ => false,
    };
    let worth_building = count > 1 || built;
    let mut fused_step = match (&kernel, constants) {
        (Kernel::Implicit(implicit), Some(constants)) => implicit
            .fused
            .as_ref()
            .filter(|_| worth_building && across_lanes(implicit).is_some())
            .map(|fused| fused.rk4_step(system.constraints(), &constants)),
        (Kernel::Parametric(parametric), Some(_)) => parametric
            .fused
            .as_ref()
            .filter(|_| worth_building && parametric.across_lanes())
            .map(|fused| fused.rk4_step(system.parametric().expect("checked by lanes_can_run"))),
        _ => None,
    };
    // Every lane starts from its member's state; lanes beyond `count` repeat the first.
    for l in 0..LANES {
        let member = &members[l.min(count - 1)];
        for k in 0..n {
            lanes.q[k * LANES + l] = member.state.q[k];
            lanes.qdot[k * LANES + l] = member.state.qdot[k];
        }
    }
    let mut outcome = vec![LaneOutcome::Done; count];
    let mut active = [false; LANES];
    active[..count].fill(true);
    let monitors: Vec<&super::monitor::Monitor> = members.iter().map(|m| &m.monitor).collect();
    let mut monitor = LaneMonitor::<LANES>::new(&system, method, &monitors);
    drop(monitors);
    // Whether any member has a stop condition to screen (a lane that screens nothing
    // leaves only when a check fails).
    let any_watch = members.iter().any(|member| !member.watches.is_empty());
    let t0 = members[0].state.t;
    let dt = config.dt;
    let mut t = t0;
    for k in 1..=steps {
        // As `run` asks and `advance_to` steps: to t0 + k dt (the last to t0 + duration when
        // set), one step of (t_end - t) / 1.
        let t_end = options.output_time(t0, k, dt);
        let h = (t_end - t) / 1.0;
        // The step's start becomes the state one step end back, and the state two back
        // moves on; the step writes its end into the buffers that held the oldest.
        std::mem::swap(&mut lanes.q_back2, &mut lanes.q_back);
        std::mem::swap(&mut lanes.q_back, &mut lanes.q);
        std::mem::swap(&mut lanes.qdot_back, &mut lanes.qdot);
        let active_before = active;
        if let Some(step) = fused_step.as_mut() {
            let mut failed = [false; LANES];
            let start = (&lanes.q_back[..], &lanes.qdot_back[..]);
            let end = (&mut lanes.q[..], &mut lanes.qdot[..]);
            step.step_lanes::<LANES>(t, h, start, end, &mut failed);
            leave_where_failed(&failed, &mut active, &mut outcome);
        } else {
            // Stage by stage, in place from the start.
            lanes.q.copy_from_slice(&lanes.q_back);
            lanes.qdot.copy_from_slice(&lanes.qdot_back);
            rk4_step(
                &mut kernel,
                &mut lanes,
                &step_tape,
                t,
                h,
                &mut active,
                &mut outcome,
            );
        }
        if active != active_before {
            for l in 0..count {
                if active_before[l] && !active[l] {
                    handover(&mut members[l], &lanes, &monitor, l, k, t);
                    outcome[l] = LaneOutcome::Handover { intervals: k - 1 };
                }
            }
        }
        let t_previous = t;
        t = t_end;
        // The checks of `Simulation::accept`, every lane at once; a lane that fails one, or
        // whose stop condition asks for a look, leaves: its member is handed the state of
        // the step before. The observation is the fused step's own, evaluated at its end
        // t + h, where that is bitwise t (whenever t_end - t is exact, as it is once
        // t >= t_end / 2); else the observation tape's at t.
        let out = match &fused_step {
            Some(step) if (t_previous + h).to_bits() == t.to_bits() => step.observation::<LANES>(),
            _ => {
                observe_lanes(&mut lanes, &observe_tape, t);
                &lanes.out[..observe_tape.n_outputs() * LANES]
            }
        };
        let failed = monitor.check(
            &system,
            count,
            |l, t| members[l].monitor.limits(t),
            &[t; LANES],
            out,
            &lanes.q,
            &lanes.qdot,
            &lanes.q_back,
        );
        // Lanes that pass every check and screen nothing stay, with no member touched.
        let to_screen = if any_watch || any_of(&failed, LANES) {
            0..count
        } else {
            0..0
        };
        for l in to_screen {
            if !active[l] {
                continue;
            }
            let member = &mut members[l];
            // The events' screen (`screen_all`, which remembers this step end when no event
            // needs a look); a look is the member's own to take.
            let leaves = failed[l]
                || (!member.watches.is_empty() && {
                    gather::<LANES>(&lanes.q, l, &mut lanes.q_one);
                    gather::<LANES>(&lanes.qdot, l, &mut lanes.qdot_one);
                    let (q, qdot) = (&lanes.q_one[..], &lanes.qdot_one[..]);
                    let (x, xdot) = monitor.lane_state(out, &lanes.q, &lanes.qdot, l);
                    super::watching::screen_all(
                        &mut member.watches,
                        &mut member.g_now,
                        t,
                        (x, xdot, q, qdot),
                    )
                });
            if leaves {
                active[l] = false;
                handover(member, &lanes, &monitor, l, k, t_previous);
                outcome[l] = LaneOutcome::Handover { intervals: k - 1 };
            }
        }
        // The others' step ends are accepted: the monitor's reference and maxima move on.
        monitor.accept(out);
        if !any_of(&active, count) {
            break;
        }
    }
    // The members that ran to the end take their state and figures.
    for l in 0..count {
        if outcome[l] != LaneOutcome::Done {
            continue;
        }
        let member = &mut members[l];
        for k in 0..n {
            member.state.q[k] = lanes.q[k * LANES + l];
            member.state.qdot[k] = lanes.qdot[k * LANES + l];
        }
        member.state.t = t;
        member.steps = steps;
        // As `advance_to` leaves it: a last step shortened to the duration restarts the grid.
        if (t0 + steps as f64 * dt - t).abs() <= 1e-9 * dt {
            member.grid_steps = steps;
        } else {
            member.grid_origin = t;
            member.grid_steps = 0;
        }
        if steps > 0 {
            member.substeps_max = member.substeps_max.max(1);
        }
        let (q, qdot, work) = super::split(&member.state, n);
        member
            .monitor
            .observe(&mut *member.formulation, t, q, qdot, work);
        let [energy, balance, constraint, distance] = monitor.maxima_of(l);
        member.monitor.energy_rel_error_max = energy;
        member.monitor.balance_error_max = balance;
        member.monitor.constraint_error_max = constraint;
        member.monitor.constraint_distance_max = distance;
    }
    outcome
}

/// Hand lane l's member its state and monitor at the end of step k - 1 (time t), as its
/// own `Simulation` would stand after taking steps 1 to k - 1: the state, the step count,
/// the observation (taken again), the regularity monitor's last two step ends, the longest
/// gradient lengths and the maxima. The stop condition's watch is the member's own, which the
/// lanes screened with, so it already remembers the end of step k - 1.
fn handover(
    member: &mut Simulation,
    lanes: &Lanes,
    monitor: &LaneMonitor<LANES>,
    l: usize,
    k: u64,
    t: f64,
) {
    let n = lanes.n;
    let done = k - 1;
    let mut q_before = vec![0.0; n];
    gather::<LANES>(&lanes.q_back, l, &mut member.state.q[..n]);
    gather::<LANES>(&lanes.qdot_back, l, &mut member.state.qdot[..n]);
    gather::<LANES>(&lanes.q_back2, l, &mut q_before);
    member.state.t = t;
    member.previous.clone_from(&member.state);
    member.steps = done;
    member.grid_steps = done;
    if done > 0 {
        member.substeps_max = member.substeps_max.max(1);
    }
    let (q, qdot, work) = super::split(&member.state, n);
    member
        .monitor
        .observe(&mut *member.formulation, t, q, qdot, work);
    let (last, before, longest, searched, maxima) = monitor.lane(l);
    let before = (done > 0).then_some((q_before.as_slice(), before.as_slice()));
    let q = member.state.q[..n].to_vec();
    member
        .monitor
        .adopt(&q, &last, before, &longest, &searched, maxima);
}

/// F = m g per coordinate, gravity the only force (as `System::accumulate_forces`).
fn gravity_force(system: &System) -> Vec<f64> {
    let gravity = system.gravity();
    system
        .particles()
        .iter()
        .flat_map(|particle| gravity.iter().map(move |g| particle.mass * g))
        .collect()
}

/// Active lanes whose evaluation failed leave (to be run alone).
#[inline(always)]
fn leave_where_failed(
    failed: &[bool; LANES],
    active: &mut [bool; LANES],
    outcome: &mut [LaneOutcome],
) {
    if !any_of(failed, LANES) {
        return;
    }
    for l in 0..LANES {
        if active[l] && failed[l] {
            active[l] = false;
            if l < outcome.len() {
                outcome[l] = LaneOutcome::Leave;
            }
        }
    }
}

/// One RK4 step of every lane from time t by h: `integrate::rk4`'s arithmetic, lane by lane:
/// stage s + 1 starts from q + c_s v_s, qdot + c_s a_s with c = (h/2, h/2, h).
#[allow(clippy::too_many_arguments)]
fn rk4_step(
    kernel: &mut Kernel,
    lanes: &mut Lanes,
    tape: &Tape,
    t: f64,
    h: f64,
    active: &mut [bool; LANES],
    outcome: &mut [LaneOutcome],
) {
    let half = 0.5 * h;
    let (mut q, mut qdot) = (
        std::mem::take(&mut lanes.q),
        std::mem::take(&mut lanes.qdot),
    );
    let mut velocity = std::mem::take(&mut lanes.velocity);
    let mut stage_q = std::mem::take(&mut lanes.q_stage);
    velocity[0].copy_from_slice(&qdot);
    accelerate(kernel, lanes, tape, t, &q, &velocity[0], 0, active, outcome);
    for (s, (c, time)) in [(half, t + half), (half, t + half), (h, t + h)]
        .into_iter()
        .enumerate()
    {
        axpy_into(&mut stage_q, &q, c, &velocity[s]);
        axpy_into(&mut velocity[s + 1], &qdot, c, &lanes.acceleration[s]);
        accelerate(
            kernel,
            lanes,
            tape,
            time,
            &stage_q,
            &velocity[s + 1],
            s + 1,
            active,
            outcome,
        );
    }
    let [v1, v2, v3, v4] = &velocity;
    let [a1, a2, a3, a4] = &lanes.acceleration;
    let sixth = h / 6.0;
    for i in 0..q.len() {
        q[i] += sixth * (v1[i] + 2.0 * v2[i] + 2.0 * v3[i] + v4[i]);
        qdot[i] += sixth * (a1[i] + 2.0 * a2[i] + 2.0 * a3[i] + a4[i]);
    }
    lanes.q = q;
    lanes.qdot = qdot;
    lanes.velocity = velocity;
    lanes.q_stage = stage_q;
}

/// y = x + h z, element by element (as `integrate::axpy_into`).
fn axpy_into(y: &mut [f64], x: &[f64], h: f64, z: &[f64]) {
    for ((y, x), z) in y.iter_mut().zip(x).zip(z) {
        *y = x + h * z;
    }
}

/// Accelerations of every lane at (t, q, qdot) into `lanes.acceleration[stage]`: the tape
/// for all lanes, then the formulation's own finish per active lane. A lane whose
/// evaluation fails leaves.
#[allow(clippy::too_many_arguments)]
fn accelerate(
    kernel: &mut Kernel,
    lanes: &mut Lanes,
    tape: &Tape,
    t: f64,
    q: &[f64],
    qdot: &[f64],
    stage: usize,
    active: &mut [bool; LANES],
    outcome: &mut [LaneOutcome],
) {
    lanes.load_vars(t, q, qdot);
    let width = tape.n_outputs();
    tape.eval_lanes::<LANES>(
        &lanes.vars,
        &mut lanes.scratch,
        &mut lanes.out[..width * LANES],
    );
    let mut acceleration = std::mem::take(&mut lanes.acceleration[stage]);
    if let Kernel::Implicit(implicit) = kernel {
        if let Some(tolerance) = across_lanes(implicit) {
            let mut failed = [None; LANES];
            implicit_across_lanes(implicit, lanes, tolerance, &mut acceleration, &mut failed);
            for l in 0..LANES {
                if active[l] && failed[l].is_some() {
                    active[l] = false;
                    if l < outcome.len() {
                        outcome[l] = LaneOutcome::Leave;
                    }
                }
            }
            lanes.acceleration[stage] = acceleration;
            return;
        }
    }
    if let Kernel::Parametric(parametric) = kernel {
        if parametric.across_lanes() {
            let mut failed = [None; LANES];
            parametric.accelerate_across_lanes::<LANES>(
                &lanes.out[..width * LANES],
                &mut lanes.parametric,
                &mut acceleration,
                &mut failed,
            );
            for l in 0..LANES {
                if active[l] && failed[l].is_some() {
                    active[l] = false;
                    if l < outcome.len() {
                        outcome[l] = LaneOutcome::Leave;
                    }
                }
            }
            lanes.acceleration[stage] = acceleration;
            return;
        }
    }
    let system = match kernel {
        Kernel::Implicit(implicit) => Arc::clone(&implicit.system),
        Kernel::Parametric(parametric) => Arc::clone(&parametric.system),
    };
    for l in 0..LANES {
        if !active[l] {
            continue;
        }
        gather::<LANES>(q, l, &mut lanes.q_one);
        gather::<LANES>(qdot, l, &mut lanes.qdot_one);
        let outputs = &lanes.out[..width * LANES];
        let result = match kernel {
            Kernel::Implicit(implicit) => {
                let ws = implicit.evaluation_mut();
                gather::<LANES>(outputs, l, &mut ws.tape_out_mut()[..width]);
                system.constraints().unpack_full(ws);
                implicit.accelerate_evaluated(t, &lanes.q_one, &lanes.qdot_one, &mut lanes.a_one)
            }
            Kernel::Parametric(parametric) => {
                let ws = parametric.evaluation_mut();
                gather::<LANES>(outputs, l, &mut ws.out_mut()[..width]);
                system
                    .parametric()
                    .expect("checked by lanes_can_run")
                    .unpack_evaluation(ws);
                parametric.accelerate_evaluated(t, &lanes.q_one, &lanes.qdot_one, &mut lanes.a_one)
            }
        };
        if result.is_err() {
            active[l] = false;
            if l < outcome.len() {
                outcome[l] = LaneOutcome::Leave;
            }
            lanes.a_one.fill(0.0);
        }
        for (k, a) in lanes.a_one.iter().enumerate() {
            acceleration[k * LANES + l] = *a;
        }
    }
    lanes.acceleration[stage] = acceleration;
}

/// The dense pivot tolerance when the implicit form's finish can run across lanes: gravity
/// the only force and J W J^T factored densely; `None` otherwise (each lane is then finished
/// by [`Implicit::accelerate_evaluated`]).
fn across_lanes(implicit: &Implicit) -> Option<f64> {
    let system = &implicit.system;
    if !system.forces().is_empty() || !implicit.external.is_empty() {
        return None;
    }
    implicit
        .matrix
        .dense_pivot_tolerance(system.constraints().structure())
}

/// [`Implicit::accelerate_evaluated`] for every lane at once from the full tape's outputs in
/// `lanes.out` (gravity the only force, J W J^T dense): the same operations in the same
/// order per lane, lanes innermost.
///
/// ```text
/// F = M g;  (J W J^T) lambda = -bias - J W F - ks C - kd Cdot;  a = W (F + J^T lambda)
/// ```
fn implicit_across_lanes(
    implicit: &mut Implicit,
    lanes: &mut Lanes,
    tolerance: f64,
    acceleration: &mut [f64],
    failed: &mut [Option<crate::linalg::Singular>; LANES],
) {
    let system = Arc::clone(&implicit.system);
    let set = system.constraints();
    let w = &system.inverse_mass;
    let dim = system.dim();
    let gravity = system.gravity();
    for (p, particle) in system.particles().iter().enumerate() {
        for (a, g) in gravity.iter().enumerate() {
            lanes.force[(p * dim + a) * LANES..(p * dim + a + 1) * LANES].fill(particle.mass * g);
        }
    }
    let m = set.n_rows();
    if m > 0 {
        let feedback = implicit.feedback();
        let out = &lanes.out;
        let (value, velocity, bias, jacobian) = (
            &out[..m * LANES],
            &out[m * LANES..2 * m * LANES],
            &out[2 * m * LANES..3 * m * LANES],
            &out[3 * m * LANES..],
        );
        lanes.dense.resize(m * m * LANES, 0.0);
        lanes.lambda.resize(m * LANES, 0.0);
        implicit
            .matrix
            .get(set.structure())
            .assemble_dense_lanes::<LANES>(jacobian, w, &mut lanes.dense);
        for i in 0..m {
            let columns = set.row_columns(i);
            let entries = set.row_entries(i);
            for l in 0..LANES {
                // sum() of f64 starts from -0.0.
                let mut jwf = -0.0;
                for (&k, e) in columns.iter().zip(entries.clone()) {
                    jwf += jacobian[e * LANES + l] * w[k] * lanes.force[k * LANES + l];
                }
                let at = i * LANES + l;
                lanes.lambda[at] = feedback.subtract(-bias[at] - jwf, value[at], velocity[at]);
            }
        }
        crate::linalg::ldlt_lanes::<LANES>(m, &mut lanes.dense, tolerance, failed);
        crate::linalg::ldlt_substitute_lanes::<LANES>(m, &lanes.dense, &mut lanes.lambda);
        // F += J^T lambda.
        for i in 0..m {
            let columns = set.row_columns(i);
            for (&k, e) in columns.iter().zip(set.row_entries(i)) {
                for l in 0..LANES {
                    lanes.force[k * LANES + l] +=
                        jacobian[e * LANES + l] * lanes.lambda[i * LANES + l];
                }
            }
        }
    }
    for (k, w) in w.iter().enumerate() {
        for l in 0..LANES {
            acceleration[k * LANES + l] = w * lanes.force[k * LANES + l];
        }
    }
}

/// The observation tape (C and J of the implicit form at x = q; x, xdot and J of the
/// parametric map) for every lane at time t, into `lanes.out`.
fn observe_lanes(lanes: &mut Lanes, tape: &Tape, t: f64) {
    let (q, qdot) = (
        std::mem::take(&mut lanes.q),
        std::mem::take(&mut lanes.qdot),
    );
    lanes.load_vars(t, &q, &qdot);
    let width = tape.n_outputs();
    tape.eval_lanes::<LANES>(
        &lanes.vars,
        &mut lanes.scratch,
        &mut lanes.out[..width * LANES],
    );
    lanes.q = q;
    lanes.qdot = qdot;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Scene;
    use crate::simulate::{run, NullSink, RunOptions, SimulationConfig};

    const PARABOLA: &str = "[params]\nx0 = 150.0\n[world]\ngravity = [0.0, 500.0]\n[[particle]]\nname = \"bead\"\nmass = 1.0\nposition = [\"x0\", \"-x0^2/100\"]\n[[constraint]]\nexpr = \"bead.x^2 + 100*bead.y\"\n[parametric]\ncoordinates = [\"q\"]\ninitial = [\"x0\"]\n[parametric.positions]\nbead = [\"q\", \"-q^2/100\"]\n";

    fn members(method: Method, x0: &[f64]) -> (Arc<System>, Vec<Simulation>) {
        let base = Scene::parse(PARABOLA, "p.toml", &[]).unwrap();
        let config = SimulationConfig {
            method,
            dt: 1.0 / 60.0,
            ..Default::default()
        };
        let sims = x0
            .iter()
            .map(|&x| {
                let scene = base.with_params(&[("x0".to_string(), x)]).unwrap();
                Simulation::new(Arc::clone(&scene.system), config).unwrap()
            })
            .collect();
        (Arc::clone(&base.system), sims)
    }

    /// The lanes take the parabola's runs to the end, and each member's figures are its run's
    /// alone, bit for bit, in every instruction set this CPU runs (the baseline, AVX2,
    /// AVX-512).
    #[test]
    fn the_lanes_run_the_parabola_to_the_end_as_each_member_alone() {
        let x0: Vec<f64> = (0..LANES - 3).map(|i| 10.0 + 12.5 * i as f64).collect();
        for (method, set) in [Method::Implicit, Method::Parametric]
            .into_iter()
            .flat_map(|method| {
                VectorSet::available()
                    .into_iter()
                    .map(move |set| (method, set))
            })
        {
            let (system, mut together) = members(method, &x0);
            assert!(together.iter().all(lanes_can_run));
            let outcomes = run_lanes_in(set, &system, &mut together, RunOptions::steps(240));
            assert!(
                outcomes.iter().all(|&o| o == LaneOutcome::Done),
                "{outcomes:?}"
            );
            let (_, mut alone) = members(method, &x0);
            for (a, b) in together.iter().zip(&mut alone) {
                let want = run(b, RunOptions::steps(240), &mut NullSink).unwrap();
                let got = a.stats(want.wall_seconds);
                assert_eq!(format!("{got:?}"), format!("{want:?}"));
            }
        }
    }

    /// A lone member (no fused step built for it: the stages evaluated one by one across
    /// the lanes, `implicit_across_lanes` and `accelerate_across_lanes`) is its run alone too.
    #[test]
    fn a_lone_member_runs_stage_by_stage_as_alone() {
        for method in [Method::Implicit, Method::Parametric] {
            let (system, mut together) = members(method, &[70.0]);
            let outcomes = run_lanes(&system, &mut together, RunOptions::steps(240));
            assert_eq!(outcomes, [LaneOutcome::Done]);
            let (_, mut alone) = members(method, &[70.0]);
            let want = run(&mut alone[0], RunOptions::steps(240), &mut NullSink).unwrap();
            let got = together[0].stats(want.wall_seconds);
            assert_eq!(format!("{got:?}"), format!("{want:?}"));
        }
    }

    /// A member whose state stops being finite is handed back before the step that broke it
    /// (here the first); the others go on.
    #[test]
    fn a_member_that_diverges_leaves_and_the_others_go_on() {
        let (system, mut together) = members(Method::Parametric, &[20.0, 40.0, 60.0]);
        together[1].state.qdot[0] = f64::INFINITY;
        let outcomes = run_lanes(&system, &mut together, RunOptions::steps(10));
        assert_eq!(
            outcomes,
            [
                LaneOutcome::Done,
                LaneOutcome::Handover { intervals: 0 },
                LaneOutcome::Done
            ]
        );
    }

    #[test]
    fn what_the_lanes_do_not_take() {
        let base = Scene::parse(PARABOLA, "p.toml", &[]).unwrap();
        let with = |config: SimulationConfig| {
            let simulation = Simulation::new(Arc::clone(&base.system), config).unwrap();
            lanes_can_run(&simulation)
        };
        let rk4 = SimulationConfig {
            dt: 0.01,
            ..Default::default()
        };
        assert!(with(rk4));
        assert!(!with(SimulationConfig {
            integrator: IntegratorKind::GaussLegendre,
            ..rk4
        }));
        assert!(!with(SimulationConfig {
            project: true,
            ..rk4
        }));
        assert!(!with(SimulationConfig { substeps: 2, ..rk4 }));
    }
}
