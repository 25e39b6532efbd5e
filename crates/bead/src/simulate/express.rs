//! Express steps: a single run's plain fixed steps taken through its compiled RK4 step and
//! the lane monitor for one lane, with the bits and the figures of [`Simulation`]'s own
//! steps.
//!
//! A step of `run` goes through `advance_to`, the fixed step's retry loop, the integrator,
//! the formulation's compiled step, then `accept`: the observation copied into the monitor,
//! the energy, the divergence and regularity checks, the shift of the step ends, the maxima.
//! That machinery serves events, substeps, projections, the ledger and every integrator, and
//! cost three times the compiled step itself on the article's scene. Where a run needs none
//! of it — RK4 at a fixed step without substeps, projection, ledger, external forces or
//! events, on a formulation with a compiled step (a small system under constant forces) —
//! [`Simulation::express`] takes the steps itself: the formulation's own compiled step
//! ([`crate::formulation::SecondOrderSystem::compiled_rk4_step`]), then the sweep lanes'
//! monitor for one lane ([`LaneMonitor`]`<1>`, the same operations in the same order as
//! [`super::monitor::Monitor`]) on the observation the step evaluated at its end.
//!
//! Anything more than a plain step goes back to the simulation's own path, as it does for a
//! sweep lane: a step whose pivot test fails, a non-finite or diverging state, a candidate
//! singular point (the lane monitor flags every first-order candidate, so it errs towards
//! leaving), a step off the time grid. The simulation then stands after the last express
//! step exactly as if it had taken every step itself (state, step counts, the monitor's step
//! ends, longest gradients and maxima, its observation taken again), and takes the next step
//! alone. Rows happen between express runs, at the output intervals `run` asks for, so the
//! sink sees the same samples (a sink that discards them asks for none but the first and
//! the last); progress and interruptions are seen where an express run ends, at most
//! [`EXPRESS_CHUNK`] intervals apart.

use super::lane_monitor::LaneMonitor;
use super::vector::{compiled_per_vector_set, VectorSet};
use super::{RunOptions, Simulation, Stepper};
use crate::expr::Tape;
use crate::formulation::Method;
use crate::integrate::IntegratorKind;

/// At most this many output intervals per express run, so that an interruption is seen
/// within a fraction of a millisecond.
pub(super) const EXPRESS_CHUNK: u64 = 1024;

/// Output intervals the simulation's own path takes after an express run stopped short,
/// before the next express run is tried (a step the lane monitor flags, e.g. near a sharp
/// bend the regularity monitor accepts, would otherwise be taken twice at every step).
pub(super) const EXPRESS_COOLDOWN: u64 = 16;

/// Steps checked at once by [`Simulation::express_batch`], where a run takes that many
/// in a row: the lane monitor over them, as over a sweep's lanes.
const BATCH: usize = super::lanes::LANES;

/// A batch's steps, structure of arrays (value i of step k at `i * BATCH + k`): their
/// observation (the observation tape's outputs at each end), end and start states and times.
struct Batch {
    monitor: LaneMonitor<BATCH>,
    /// Outputs of the observation tape
    observed: usize,
    observation: Vec<f64>,
    q: Vec<f64>,
    qdot: Vec<f64>,
    q_back: Vec<f64>,
    qdot_back: Vec<f64>,
    t: [f64; BATCH],
    t_start: [f64; BATCH],
}

/// An express stepper for one simulation's run (see the module).
pub(super) struct Express {
    monitor: LaneMonitor<1>,
    /// The batches' buffers
    batch: Option<Batch>,
    /// The form's observation tape, evaluated where the compiled step did not evaluate it
    /// at the step's end; its variables (q, qdot, t), scratch and outputs
    observe_tape: Tape,
    vars: Vec<f64>,
    scratch: Vec<f64>,
    out: Vec<f64>,
    /// The state at the start of the step in progress, and at the start of the last
    /// accepted one (t, q, qdot)
    start: (f64, Vec<f64>, Vec<f64>),
    before: (f64, Vec<f64>, Vec<f64>),
}

impl Express {
    /// An express stepper for `simulation`'s run, when its run can take express steps
    /// (see the module); built before the run's first step, at the state it starts from.
    pub(super) fn new(simulation: &Simulation) -> Option<Express> {
        let config = &simulation.config;
        let formulation = &simulation.formulation;
        let system = formulation.system();
        let method = formulation.method();
        let plain = matches!(simulation.stepper, Stepper::Fixed(_))
            && config.integrator == IntegratorKind::Rk4
            && !config.project
            && config.substeps <= 1
            && simulation.ledger.is_none()
            && formulation.external_forces().is_empty()
            && simulation.watches.is_empty()
            && formulation.compiles_rk4_step()
            && match method {
                Method::Implicit => system.constraints().only_taped(),
                Method::Parametric => system.parametric().is_some(),
            };
        if !plain || !simulation.express_ready() {
            return None;
        }
        let observe_tape = match method {
            Method::Implicit => system.constraints().gradient_tape().clone(),
            Method::Parametric => system.parametric()?.observation_tape().clone(),
        };
        let n = simulation.n;
        let state = (0.0, vec![0.0; n], vec![0.0; n]);
        let observed = observe_tape.n_outputs();
        let soa = |width: usize| vec![0.0; width * BATCH];
        let batch = Batch {
            monitor: LaneMonitor::new(system, method, &[&simulation.monitor]),
            observed,
            observation: soa(observed),
            q: soa(n),
            qdot: soa(n),
            q_back: soa(n),
            qdot_back: soa(n),
            t: [0.0; BATCH],
            t_start: [0.0; BATCH],
        };
        Some(Express {
            monitor: LaneMonitor::new(system, method, &[&simulation.monitor]),
            batch: simulation.express_batches.then_some(batch),
            vars: vec![0.0; 2 * n + 1],
            scratch: vec![0.0; observe_tape.n_slots()],
            out: vec![0.0; observe_tape.n_outputs()],
            observe_tape,
            start: state.clone(),
            before: state,
        })
    }
}

impl Simulation {
    /// Whether the simulation stands where an express run can start: at its last accepted
    /// step end (the regularity monitor's reference, bit for bit), with no retried substeps
    /// in force.
    fn express_ready(&self) -> bool {
        self.sticky.substeps <= 1
            && self.state.q.len() == self.n
            && self
                .monitor
                .step_end(true)
                .is_some_and(|(q, _)| crate::same_bits(q, &self.state.q))
    }

    /// Take the output intervals `from + 1 ..= to` of a run of `options` from t0 (one step
    /// of dt each, as [`Simulation::advance_to`] would take them) as express steps (see the
    /// module), stopping before the first one that needs the simulation's own path. Returns
    /// the last interval reached (`from` when none was). `express` must have been built
    /// for this simulation at the start of this run, and the simulation must stand after
    /// interval `from`.
    pub(super) fn express(
        &mut self,
        express: &mut Express,
        t0: f64,
        from: u64,
        to: u64,
        options: &RunOptions,
    ) -> u64 {
        if !self.express_ready() {
            return from;
        }
        // The lane monitor takes up where the simulation's own stands (it may have taken
        // steps since the last express run).
        express.monitor.load(&[&self.monitor]);
        if let Some(batch) = &mut express.batch {
            batch.monitor.load(&[&self.monitor]);
        }
        let mut reached = from;
        while reached < to {
            let (accepted, go_on) = if to - reached >= BATCH as u64 && express.batch.is_some() {
                self.express_batch(express, t0, reached, options)
            } else {
                let accepted = self.express_step(express, t0, reached + 1, options);
                (u64::from(accepted), accepted)
            };
            reached += accepted;
            if !go_on {
                break;
            }
        }
        if reached > from {
            self.express_done(express);
        }
        reached
    }

    /// Where output interval `interval`'s end lands (`options.output_time`) and the step to
    /// it from the simulation's time, `steps` steps after its last (as `advance_to` takes
    /// it: one step onto the grid point it lands on); `None` off the grid (e.g. a duration
    /// that ends between grid points: the simulation's own path).
    fn express_target(
        &self,
        t0: f64,
        interval: u64,
        steps: u64,
        options: &RunOptions,
    ) -> Option<f64> {
        let dt = self.config.dt;
        let target = options.output_time(t0, interval, dt);
        let next = self.grid_origin + (self.grid_steps + steps + 1) as f64 * dt;
        let off_grid = (next - target).abs();
        (!off_grid.is_nan() && off_grid <= 1e-9 * dt).then_some(target)
    }

    /// One express step, to the end of output interval `interval`, checked by the lane
    /// monitor for one lane; whether it was accepted (else the simulation stands where it
    /// stood, for its own path).
    fn express_step(
        &mut self,
        express: &mut Express,
        t0: f64,
        interval: u64,
        options: &RunOptions,
    ) -> bool {
        let n = self.n;
        let Some(target) = self.express_target(t0, interval, 0, options) else {
            return false;
        };
        let t = self.state.t;
        let h = (target - t) / 1.0;
        let (t_start, q_start, qdot_start) = &mut express.start;
        *t_start = t;
        q_start.copy_from_slice(&self.state.q);
        qdot_start.copy_from_slice(&self.state.qdot);
        if !self.formulation.compiled_rk4_step(&mut self.state, h) {
            return false;
        }
        self.state.t = target;
        let (q, qdot) = (&self.state.q[..], &self.state.qdot[..]);
        debug_assert!(same_observation(&*self.formulation, target, q, qdot));
        let out = match self.formulation.compiled_step_observation_after(target) {
            Some(out) => out,
            None => {
                let vars = &mut express.vars;
                vars[..n].copy_from_slice(q);
                vars[n..2 * n].copy_from_slice(qdot);
                vars[2 * n] = target;
                express
                    .observe_tape
                    .eval(vars, &mut express.scratch, &mut express.out);
                &express.out
            }
        };
        let monitor = &self.monitor;
        let [failed] = express.monitor.check(
            self.formulation.system(),
            1,
            |_, t| monitor.limits(t),
            &[target],
            out,
            q,
            qdot,
            &express.start.1,
        );
        if failed {
            let (t, q, qdot) = &express.start;
            self.state.t = *t;
            self.state.q.copy_from_slice(q);
            self.state.qdot.copy_from_slice(qdot);
            return false;
        }
        express.monitor.accept(out);
        std::mem::swap(&mut express.start, &mut express.before);
        self.steps += 1;
        self.grid_steps += 1;
        true
    }

    /// [`BATCH`] express steps from the end of output interval `from`, then the lane
    /// monitor's checks of all of them at once, the steps as its lanes (lane k the step
    /// after lane k - 1, its memory what the run's monitor holds after the steps before:
    /// [`LaneMonitor::chain_from`]); the steps before the first that fails a check are
    /// accepted and the simulation stands at the end of the last, as if it had taken them
    /// one by one. Returns how many were accepted, and whether all were (else the next
    /// step is the simulation's own). A step that its pivot tests or the time grid refuse
    /// ends the batch there.
    fn express_batch(
        &mut self,
        express: &mut Express,
        t0: f64,
        from: u64,
        options: &RunOptions,
    ) -> (u64, bool) {
        let n = self.n;
        let batch = express.batch.as_mut().expect("checked by the caller");
        let width = batch.observed;
        let mut taken = BATCH;
        for k in 0..BATCH {
            let Some(target) = self.express_target(t0, from + 1 + k as u64, k as u64, options)
            else {
                taken = k;
                break;
            };
            batch.t_start[k] = self.state.t;
            batch.t[k] = target;
            for i in 0..n {
                batch.q_back[i * BATCH + k] = self.state.q[i];
                batch.qdot_back[i * BATCH + k] = self.state.qdot[i];
            }
            let h = (target - self.state.t) / 1.0;
            if !self.formulation.compiled_rk4_step(&mut self.state, h) {
                taken = k;
                break;
            }
            self.state.t = target;
            let (q, qdot) = (&self.state.q[..], &self.state.qdot[..]);
            debug_assert!(same_observation(&*self.formulation, target, q, qdot));
            let out = match self.formulation.compiled_step_observation_after(target) {
                Some(out) => out,
                None => {
                    let vars = &mut express.vars;
                    vars[..n].copy_from_slice(q);
                    vars[n..2 * n].copy_from_slice(qdot);
                    vars[2 * n] = target;
                    express
                        .observe_tape
                        .eval(vars, &mut express.scratch, &mut express.out);
                    &express.out
                }
            };
            debug_assert_eq!(out.len(), width, "the observation tape's outputs");
            for (i, v) in out[..width].iter().enumerate() {
                batch.observation[i * BATCH + k] = *v;
            }
            for i in 0..n {
                batch.q[i * BATCH + k] = q[i];
                batch.qdot[i * BATCH + k] = qdot[i];
            }
        }
        // Lanes past the steps taken repeat the last one taken (checked, never accepted).
        for k in taken.max(1)..BATCH {
            let last = taken.max(1) - 1;
            let rows = [
                &mut batch.observation[..],
                &mut batch.q[..],
                &mut batch.qdot[..],
                &mut batch.q_back[..],
            ];
            for soa in rows {
                for row in soa.as_chunks_mut::<BATCH>().0 {
                    row[k] = row[last];
                }
            }
            batch.t[k] = batch.t[last];
        }
        let mut accepted = 0;
        if taken > 0 {
            let system = self.formulation.system();
            let monitor = &self.monitor;
            // AVX-512 measured 1-3% slower here than AVX2 (a run of the article's scene,
            // 72-74 ns a step against 71-72, on an AMD EPYC), and 7-15% faster in the lanes.
            let set = VectorSet::best().at_most_avx2();
            accepted = check_batch(set, batch, &mut express.monitor, system, monitor, taken);
            if accepted > 0 {
                // The last accepted step's start, for `express_done`.
                let (t, q, qdot) = &mut express.before;
                *t = batch.t_start[accepted - 1];
                for i in 0..n {
                    q[i] = batch.q_back[i * BATCH + accepted - 1];
                    qdot[i] = batch.qdot_back[i * BATCH + accepted - 1];
                }
            }
            #[cfg(test)]
            tests::BATCHES.with(|b| {
                let (all, partial) = b.get();
                b.set((all + 1, partial + usize::from(accepted < taken)));
            });
            if accepted < taken {
                // Stand at the end of the last accepted step (the start of the first that
                // failed), as the step-by-step path leaves it; the steps taken after that
                // one were never taken there.
                self.state.t = batch.t_start[accepted];
                for i in 0..n {
                    self.state.q[i] = batch.q_back[i * BATCH + accepted];
                    self.state.qdot[i] = batch.qdot_back[i * BATCH + accepted];
                }
                self.formulation
                    .discount_compiled_steps((taken - accepted - 1) as u64);
            }
        }
        self.steps += accepted as u64;
        self.grid_steps += accepted as u64;
        (accepted as u64, accepted == BATCH)
    }

    /// After express steps: the simulation as its own steps would have left it (see
    /// [`super::lanes`]'s handover, which does the same for a sweep lane).
    fn express_done(&mut self, express: &Express) {
        let n = self.n;
        let (t_before, q_before, qdot_before) = &express.before;
        self.previous.t = *t_before;
        self.previous.q.copy_from_slice(q_before);
        self.previous.qdot.copy_from_slice(qdot_before);
        self.substeps_max = self.substeps_max.max(1);
        self.last_substeps = 1;
        self.stopped_at_event = false;
        self.output_behind = false;
        if let Stepper::Fixed(integrator) = &mut self.stepper {
            integrator.unprime();
        }
        // One lane: the lane monitor's buffers are that lane's values.
        let lanes = &express.monitor;
        self.monitor.adopt(
            &self.state.q[..n],
            &lanes.last,
            Some((q_before, &lanes.before)),
            &lanes.longest,
            &lanes.searched,
            lanes.maxima_of(0),
        );
        let (q, qdot, work) = super::split(&self.state, n);
        self.monitor
            .observe(&mut *self.formulation, self.state.t, q, qdot, work);
    }
}

/// Whether the observation after a compiled step (only t compared) is the one the full
/// comparison finds, at the state (t, q, qdot) the step left.
fn same_observation(
    formulation: &dyn crate::formulation::Formulation,
    t: f64,
    q: &[f64],
    qdot: &[f64],
) -> bool {
    let pointer = |o: Option<&[f64]>| o.map(<[f64]>::as_ptr);
    pointer(formulation.compiled_step_observation_after(t))
        == pointer(formulation.compiled_step_observation(t, q, qdot))
}

compiled_per_vector_set! {
    /// The lane monitor's checks of a batch's first `taken` steps (its lanes, chained from
    /// the run's monitor `one`: [`LaneMonitor::chain_from`]), in the vector instructions of
    /// `set` (the same bits in each); the steps before the first that fails one are accepted
    /// into `one`. Returns how many.
    fn check_batch(
        batch: &mut Batch,
        one: &mut LaneMonitor<1>,
        system: &crate::model::System,
        monitor: &super::monitor::Monitor,
        taken: usize,
    ) -> usize = check_batch_body
}

/// [`check_batch`]'s body, inlined into each compilation of it.
#[inline(always)]
fn check_batch_body(
    batch: &mut Batch,
    one: &mut LaneMonitor<1>,
    system: &crate::model::System,
    monitor: &super::monitor::Monitor,
    taken: usize,
) -> usize {
    let lanes = &mut batch.monitor;
    lanes.observe(system, taken, &batch.t, &batch.observation);
    lanes.chain_from(one, &batch.observation);
    let failed = lanes.check_observed(
        system,
        taken,
        |_, t| monitor.limits(t),
        &batch.t,
        &batch.observation,
        &batch.q,
        &batch.qdot,
        &batch.q_back,
    );
    let accepted = failed[..taken].iter().position(|&f| f).unwrap_or(taken);
    if accepted > 0 {
        lanes.accept(&batch.observation);
        lanes.hand_prefix(one, accepted);
    }
    accepted
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::plan::{methods, Plan, PlanRequest};
    use crate::scene::Scene;
    use crate::simulate::vector::with_vector_set;
    use crate::simulate::{run, RunOptions, RunStats, Sample, SimulationConfig, Sink};

    thread_local! {
        /// Batches checked on this thread, and those that accepted fewer steps than they
        /// took.
        pub(super) static BATCHES: std::cell::Cell<(usize, usize)> =
            const { std::cell::Cell::new((0, 0)) };
    }

    /// A run's outcome, its statistics or its failure, but for the wall time.
    fn outcome(r: Result<RunStats, crate::simulate::RunFailure>) -> String {
        match r {
            Ok(stats) => format!(
                "{:?}",
                RunStats {
                    wall_seconds: 0.0,
                    ..stats
                }
            ),
            Err(mut failure) => {
                failure.stats.wall_seconds = 0.0;
                format!("{failure:?}")
            }
        }
    }

    /// Every recorded sample's numbers, as bits.
    #[derive(Default)]
    struct Bits(Vec<u64>);
    impl Sink for Bits {
        fn record(&mut self, s: &Sample) -> std::io::Result<()> {
            let head = [s.step as f64, s.t, s.energy, s.constraint_error];
            let values = head
                .iter()
                .chain(s.x)
                .chain(s.xdot)
                .chain(s.q)
                .chain(s.qdot);
            self.0.extend(values.map(|v| v.to_bits()));
            Ok(())
        }
    }

    /// A simulation's end: its statistics, then t, E, max |C|, q and qdot as bits.
    fn end_state(s: &Simulation) -> String {
        let v = [s.t(), s.energy(), s.constraint_error()];
        let bits: Vec<u64> = v
            .iter()
            .chain(s.q())
            .chain(s.qdot())
            .map(|v| v.to_bits())
            .collect();
        format!("{:?} {bits:?}", s.stats(0.0))
    }

    /// Every shipped scene with a compiled step (chains and cloth have none, and are slow
    /// in a debug build), each of its forms under rk4 at its plan's dt: `visit(what, plan,
    /// a, b)` with two simulations set up alike.
    fn for_each_rk4_pair(mut visit: impl FnMut(String, &Plan, Simulation, Simulation)) {
        for path in crate::shipped_scene_paths() {
            let scene = Scene::load(&path, &[]).unwrap_or_else(|e| panic!("{e}"));
            let plan = Plan::resolve(&scene, &PlanRequest::default()).expect("a plan");
            if scene.system.n_coords() > 60 {
                continue;
            }
            for method in methods(&scene) {
                let config = SimulationConfig {
                    integrator: IntegratorKind::Rk4,
                    ..plan.config(method)
                };
                let new = || Simulation::new(scene.system.clone(), config);
                if let (Ok(a), Ok(b)) = (new(), new()) {
                    visit(format!("{} {}", path.display(), method.name()), &plan, a, b);
                }
            }
        }
    }

    /// Express steps checked in batches give what they give checked one by one: every
    /// shipped scene's samples, statistics, end state and evaluation count, bit for bit,
    /// both forms, rk4, for twice its duration with a row every 1000 intervals (long express
    /// runs); batches ran, and some accepted fewer steps than they took (a step that fails
    /// a check in mid-batch: the article's implicit bead drifting off its curve).
    /// The batches' checks run in every instruction set this CPU runs (one scene and form
    /// after another: see [`crate::simulate::vector`]).
    #[test]
    fn express_batches_change_no_number() {
        BATCHES.with(|b| b.set((0, 0)));
        let mut sets = VectorSet::available();
        sets.retain(|&set| set.at_most_avx2() == set);
        let mut compared = 0;
        let mut per_set = vec![0; sets.len()];
        for_each_rk4_pair(|what, plan, mut batched, mut single| {
            single.express_batches = false;
            let options = RunOptions {
                steps: (2 * plan.steps).min(20_000),
                every: 1000,
                duration: None,
            };
            let (mut a, mut b) = (Bits::default(), Bits::default());
            let set = compared % sets.len();
            let before = BATCHES.with(std::cell::Cell::get).0;
            let ra = with_vector_set(sets[set], || outcome(run(&mut batched, options, &mut a)));
            per_set[set] += BATCHES.with(std::cell::Cell::get).0 - before;
            let what = format!("{what} ({:?})", sets[set]);
            let rb = outcome(run(&mut single, options, &mut b));
            assert_eq!(ra, rb, "{what}");
            assert!(a.0 == b.0, "{what}: the samples differ");
            let figures = |s: &Simulation| format!("{} {}", end_state(s), s.evaluations());
            assert_eq!(figures(&batched), figures(&single), "{what}");
            compared += 1;
        });
        let (batches, partial) = BATCHES.with(std::cell::Cell::get);
        assert!(compared >= 10, "only {compared} runs compared");
        assert!(batches >= 1000, "only {batches} batches");
        assert!(
            per_set.iter().all(|&b| b >= 100),
            "batches per set {sets:?}: {per_set:?}"
        );
        assert!(partial >= 1, "no batch accepted fewer steps than it took");
    }

    /// A run into a sink that discards its samples (`bead run` without `--trace`) takes its
    /// express steps in batches at the scene's own duration, progress reported as it goes,
    /// and ends where the simulation's own steps, recording every sample, end: the same
    /// outcome, statistics and state, bit for bit, on every shipped scene, both forms.
    #[test]
    fn a_run_that_keeps_no_samples_batches_and_changes_no_figure() {
        struct Reports(u64, u64);
        impl crate::simulate::Progress for Reports {
            fn advance(&mut self, step: u64, total: u64) {
                assert!(
                    step > self.1 && step <= total,
                    "{step} after {} of {total}",
                    self.1
                );
                (self.0, self.1) = (self.0 + 1, step);
            }
        }
        BATCHES.with(|b| b.set((0, 0)));
        let (mut compared, mut batched_runs) = (0, 0);
        for_each_rk4_pair(|what, plan, mut fast, mut own| {
            own.express = false;
            let options = RunOptions {
                steps: plan.steps,
                every: 1,
                duration: None,
            };
            let before = BATCHES.with(std::cell::Cell::get).0;
            let mut reports = Reports(0, 0);
            let rf = outcome(crate::simulate::run_with_progress(
                &mut fast,
                options,
                &mut crate::simulate::NullSink,
                &mut reports,
            ));
            let ro = outcome(run(&mut own, options, &mut Bits::default()));
            assert_eq!(rf, ro, "{what}");
            assert_eq!(end_state(&fast), end_state(&own), "{what}");
            if fast.stats(0.0).steps == plan.steps {
                assert_eq!(reports.1, plan.steps, "{what}: the end is reported");
            }
            assert!(reports.0 <= 101, "{what}: {} reports", reports.0);
            batched_runs += usize::from(BATCHES.with(std::cell::Cell::get).0 > before);
            compared += 1;
        });
        assert!(compared >= 10, "only {compared} runs compared");
        assert!(batched_runs >= 6, "only {batched_runs} runs took batches");
    }

    /// `run` with express steps gives every shipped scene's samples, final state, outcome
    /// and statistics bit for bit as the simulation's own steps do: both forms, rk4 at the
    /// scene's dt, run for twice its duration (the article's implicit bead drifts off its
    /// curve and trips the regularity monitor's candidates on the way, which hands steps
    /// back), rows every 7 intervals; and it takes the express path where it applies.
    #[test]
    fn express_steps_change_no_number() {
        let (mut compared, mut express_runs) = (0, 0);
        // Rows every 7 intervals (express runs shorter than a batch) and every 100.
        for every in [7, 100] {
            for_each_rk4_pair(|what, plan, mut fast, mut own| {
                own.express = false;
                express_runs += usize::from(Express::new(&fast).is_some());
                let options = RunOptions {
                    steps: (2 * plan.steps).min(20_000),
                    every,
                    duration: None,
                };
                let (mut a, mut b) = (Bits::default(), Bits::default());
                let ra = outcome(run(&mut fast, options, &mut a));
                let rb = outcome(run(&mut own, options, &mut b));
                let what = format!("{what} every {every}");
                assert_eq!(ra, rb, "{what}");
                assert!(a.0 == b.0, "{what}: the samples differ");
                assert_eq!(end_state(&fast), end_state(&own), "{what}");
                // And on from there by the simulation's own steps: the same again.
                for _ in 0..50 {
                    let (x, y) = (fast.step(), own.step());
                    assert_eq!(format!("{x:?}"), format!("{y:?}"), "{what}");
                }
                assert_eq!(end_state(&fast), end_state(&own), "{what}");
                compared += 1;
            });
        }
        assert!(compared >= 10, "only {compared} runs compared");
        assert!(
            express_runs >= 6,
            "only {express_runs} runs took express steps"
        );
    }
}
