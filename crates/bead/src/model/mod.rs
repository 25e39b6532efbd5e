//! The model: particles, forces and constraints as data, and the compiled [`System`] that both
//! formulations read.
//!
//! A [`SystemBuilder`] collects particles, forces, holonomic constraints and (optionally) a
//! parametric map x_i(q, t); [`SystemBuilder::build`] checks it and compiles every constraint
//! once, with its exact derivatives, into straight-line code.
//!
//! A compiled system keeps its declaration: [`System::with_constraint_expr`] and
//! [`System::with_param`] return a new system with one expression or parameter changed,
//! compiled by the same code as `build`; errors are typed ([`EditError`]) and carry byte
//! spans into the new expression.
//!
//! Coordinates are numbered globally: particle p, axis a is coordinate `p * dim + a`; the
//! configuration vector x has `n_coords = n_particles * dim` entries.

mod builder;
mod constraint;
mod edit;
mod force;
mod holonomic;
mod native;
mod parametric;
mod trace;
mod unilateral;

pub(crate) use builder::compile_reusing;
pub(crate) use builder::MASS_RANGE;
pub use builder::{ModelError, SystemBuilder};
pub use constraint::{ConstraintEval, ConstraintInfo, ConstraintSet, DistanceRow, ExprRow};
pub use edit::{DeclaredConstraint, EditError};
pub use force::{Endpoint, Force};
pub use holonomic::Holonomic;
pub use parametric::{ParametricEval, ParametricMap, SymbolicRow};
pub use unilateral::{Side, Unilateral, UnilateralRow};

/// Index of a particle in its system.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ParticleId(pub usize);

/// A point mass with its initial state.
#[derive(Clone, Debug, PartialEq)]
pub struct Particle {
    pub name: String,
    pub mass: f64,
    /// Initial position (dim).
    pub position: Vec<f64>,
    /// Initial velocity (dim).
    pub velocity: Vec<f64>,
}

/// An immutable, compiled system: what the formulations advance.
#[derive(Clone, Debug)]
pub struct System {
    pub(crate) dim: usize,
    /// Gravitational acceleration (dim).
    pub(crate) gravity: Vec<f64>,
    pub(crate) forces: Vec<Force>,
    pub(crate) constraints: std::sync::Arc<ConstraintSet>,
    /// The unilateral rows (see [`SystemBuilder::unilateral`]).
    pub(crate) unilateral: Vec<UnilateralRow>,
    pub(crate) parametric: Option<ParametricMap>,
    /// Inverse masses per coordinate (n_coords): W = M^-1 as a diagonal (shared with the
    /// integrators that keep W, see [`crate::formulation::ConstrainedSystem::shared_inverse_mass`]).
    pub(crate) inverse_mass: std::sync::Arc<[f64]>,
    /// Gravity's force per coordinate, m_p g_a (n_coords).
    pub(crate) weight: Vec<f64>,
    /// The parameters the expressions were parsed with, in declaration order.
    pub(crate) params: Vec<(String, f64)>,
    /// What the system was declared from: edits change it and compile again. Its particles
    /// are the system's (with their initial states).
    pub(crate) declared: std::sync::Arc<SystemBuilder>,
}

impl System {
    /// Whether `other` has the same equations of motion (it may start elsewhere): see
    /// `SystemBuilder::same_dynamics`.
    pub(crate) fn same_dynamics_as(&self, other: &System) -> bool {
        self.declared.same_dynamics(&other.declared)
    }

    /// Spatial dimension, 2 or 3.
    pub fn dim(&self) -> usize {
        self.dim
    }
    /// The particles with their initial states.
    pub fn particles(&self) -> &[Particle] {
        &self.declared.particles
    }
    /// Number of particle coordinates, n_particles * dim.
    pub fn n_coords(&self) -> usize {
        self.declared.particles.len() * self.dim
    }
    /// Gravitational acceleration.
    pub fn gravity(&self) -> &[f64] {
        &self.gravity
    }
    /// The applied forces (gravity excluded).
    pub fn forces(&self) -> &[Force] {
        &self.forces
    }
    /// The implicit constraints, compiled.
    pub fn constraints(&self) -> &ConstraintSet {
        &self.constraints
    }
    /// The parametric form, when the system has one.
    pub fn parametric(&self) -> Option<&ParametricMap> {
        self.parametric.as_ref()
    }
    /// The named parameters the system was built with, in declaration order.
    pub fn params(&self) -> &[(String, f64)] {
        &self.params
    }
    /// The inverse mass of every coordinate (n_coords): the diagonal of W = M^-1.
    pub fn inverse_mass(&self) -> &[f64] {
        &self.inverse_mass
    }
    /// Look a particle up by name.
    pub fn particle_id(&self, name: &str) -> Option<ParticleId> {
        self.declared
            .particles
            .iter()
            .position(|p| p.name == name)
            .map(ParticleId)
    }
    /// The scene's length scale: the largest magnitude of an initial coordinate, 1 when all
    /// are 0 ([`length_scale`] of the initial positions). Tolerances in length (a reference
    /// run's atol, the floors of a convergence study) are relative to it.
    pub fn length_scale(&self) -> f64 {
        length_scale(&self.initial_particle_state().0)
    }

    /// Initial particle positions and velocities as flat coordinate vectors (n_coords each).
    pub fn initial_particle_state(&self) -> (Vec<f64>, Vec<f64>) {
        let x = self
            .particles()
            .iter()
            .flat_map(|p| p.position.iter().copied())
            .collect();
        let v = self
            .particles()
            .iter()
            .flat_map(|p| p.velocity.iter().copied())
            .collect();
        (x, v)
    }
    /// How the system's tapes (constraint values and derivatives, the parametric map) are
    /// evaluated: how many have machine code, their instructions and compile time, and the
    /// tapes left to the interpreter with why (`bead check` prints it).
    pub fn machine_code(&self) -> crate::expr::NativeSummary {
        let mut summary = crate::expr::NativeSummary::default();
        let parametric = self.parametric.iter().flat_map(|p| p.tapes());
        for tape in self.constraints.tapes().into_iter().chain(parametric) {
            summary.add(&tape);
        }
        summary
    }

    /// Degrees of freedom: n_coords minus the number of independent constraint rows (assumed
    /// independent; a dependent set is reported as singular when the system is solved).
    pub fn degrees_of_freedom(&self) -> isize {
        self.n_coords() as isize - self.constraints.n_rows() as isize
    }

    /// Accumulate every applied force, gravity included, into `force` (n_coords), which is
    /// overwritten: F = sum over forces at positions x and velocities v.
    pub fn accumulate_forces(&self, x: &[f64], v: &[f64], force: &mut [f64]) {
        let dim = self.dim;
        force.copy_from_slice(&self.weight);
        for f in &self.forces {
            f.accumulate(dim, x, v, force);
        }
    }

    /// Each coordinate's mass (its particle's), n_coords.
    pub(crate) fn coordinate_masses(&self) -> Vec<f64> {
        self.particles()
            .iter()
            .flat_map(|p| std::iter::repeat_n(p.mass, self.dim))
            .collect()
    }

    /// Kinetic energy T = 1/2 sum m_i |v_i|^2.
    pub fn kinetic_energy(&self, v: &[f64]) -> f64 {
        let dim = self.dim;
        self.declared
            .particles
            .iter()
            .enumerate()
            .map(|(p, particle)| {
                let s: f64 = v[p * dim..(p + 1) * dim].iter().map(|c| c * c).sum();
                0.5 * particle.mass * s
            })
            .sum()
    }

    /// Potential energy of the conservative forces: gravity -sum m_i g.x_i, constant forces
    /// -F.x, springs k (|d| - L)^2 / 2. Drag has none.
    pub fn potential_energy(&self, x: &[f64]) -> f64 {
        let dim = self.dim;
        let gravity: f64 = self
            .particles()
            .iter()
            .enumerate()
            .map(|(p, particle)| {
                let gx: f64 = (0..dim).map(|a| self.gravity[a] * x[p * dim + a]).sum();
                -particle.mass * gx
            })
            .sum();
        gravity + self.forces.iter().map(|f| f.potential(dim, x)).sum::<f64>()
    }

    /// Total mechanical energy E = T + V.
    pub fn energy(&self, x: &[f64], v: &[f64]) -> f64 {
        self.kinetic_energy(v) + self.potential_energy(x)
    }

    /// The power sum F . v of the forces without a potential (drag), at positions `x` and
    /// velocities `v`: the rate at which they change the energy T + V.
    pub fn nonconservative_power(&self, x: &[f64], v: &[f64]) -> f64 {
        self.forces
            .iter()
            .filter(|f| !f.is_conservative())
            .map(|f| f.power(self.dim, x, v))
            .sum()
    }

    /// Whether any applied force depends on the velocities (drag).
    pub fn has_velocity_dependent_forces(&self) -> bool {
        self.forces.iter().any(Force::depends_on_velocity)
    }

    /// Names of the forces that do work without a potential, e.g. `drag on \`bead\``.
    pub fn nonconservative_forces(&self) -> Vec<String> {
        self.forces
            .iter()
            .filter(|f| !f.is_conservative())
            .map(|f| f.describe(&self.declared.particles))
            .collect()
    }

    /// Check a force against this system (particles exist, vectors have its dimension, numbers
    /// are finite), as [`SystemBuilder::force`] does.
    pub fn check_force(&self, force: &Force) -> Result<(), ModelError> {
        builder::check_force(self.dim, self.declared.particles.len(), force)
    }

    /// Name of velocity component k, e.g. `bead.vy` (as in the CSV trace's header).
    pub fn velocity_name(&self, k: usize) -> String {
        const AXES: [&str; 3] = ["vx", "vy", "vz"];
        format!(
            "{}.{}",
            self.declared.particles[k / self.dim].name,
            AXES[k % self.dim]
        )
    }

    /// Name of coordinate k, e.g. `bead.y`.
    pub fn coordinate_name(&self, k: usize) -> String {
        const AXES: [&str; 3] = ["x", "y", "z"];
        format!(
            "{}.{}",
            self.declared.particles[k / self.dim].name,
            AXES[k % self.dim]
        )
    }
}

/// The fused tapes a constraint set or a parametric map keeps for its formulation (see
/// `formulation::fused`), each built on first use and shared by the set's or map's clones:
/// the whole acceleration (`None`: none applies) by [`FusedTapes::variant`] (the implicit
/// form's feedback off or on; a map's is always off), and the RK4 steps that simulations
/// and the sweep lanes run, with their constants folded in.
#[derive(Debug, Default)]
pub(crate) struct FusedTapes {
    pub(crate) acceleration: [std::sync::OnceLock<Option<crate::expr::Tape>>; 2],
    /// Steps with their constants folded in, by the constants' bits and whether the
    /// monitors' observation is at their end (at most [`FusedTapes::FOLDED_KEPT`]; a
    /// formulation whose constants find no room builds its own)
    pub(crate) rk4_folded: std::sync::Mutex<Vec<(Vec<u64>, bool, crate::expr::Tape)>>,
}

impl Clone for FusedTapes {
    fn clone(&self) -> Self {
        FusedTapes {
            acceleration: self.acceleration.clone(),
            rk4_folded: std::sync::Mutex::new(self.folded().clone()),
        }
    }
}

impl FusedTapes {
    /// The most folded steps kept per set or map. Systems that share a set have the same
    /// masses and forces, so its steps differ only by the feedback gains: a run's, and a
    /// few more (a notebook's loop over gains, the viewer's) before each builds its own.
    pub(crate) const FOLDED_KEPT: usize = 8;

    /// The variant index of the acceleration tape with feedback terms (`true`) or without.
    pub(crate) fn variant(feedback: bool) -> usize {
        usize::from(feedback)
    }

    /// The folded steps kept.
    pub(crate) fn folded(
        &self,
    ) -> std::sync::MutexGuard<'_, Vec<(Vec<u64>, bool, crate::expr::Tape)>> {
        self.rk4_folded
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// The fused accelerations' tapes and the RK4 steps, those built (for the machine code
    /// summary).
    pub(crate) fn built(&self) -> Vec<crate::expr::Tape> {
        let cells = self.acceleration.iter();
        cells
            .filter_map(|cell| cell.get().and_then(Option::clone))
            .chain(self.folded().iter().map(|(_, _, tape)| tape.clone()))
            .collect()
    }

    /// Whether the step with `constants` folded in (and the observation at its end, or not)
    /// is kept.
    pub(crate) fn step_kept(&self, constants: &[f64], observed: bool) -> bool {
        Self::find(&self.folded(), constants, observed).is_some()
    }

    /// The step among `folded` with `constants` folded in (bit for bit) and the observation
    /// at its end, or not.
    pub(crate) fn find<'a>(
        folded: &'a [(Vec<u64>, bool, crate::expr::Tape)],
        constants: &[f64],
        observed: bool,
    ) -> Option<&'a crate::expr::Tape> {
        let bits = || constants.iter().map(|c| c.to_bits());
        folded
            .iter()
            .find(|(key, o, _)| *o == observed && key.iter().copied().eq(bits()))
            .map(|(_, _, tape)| tape)
    }
}

/// A length scale of positions `x`: the largest coordinate magnitude, 1 when that is 0 or
/// not finite (a system at the origin).
pub fn length_scale(x: &[f64]) -> f64 {
    let length = x.iter().fold(0.0_f64, |m, c| m.max(c.abs()));
    if length > 0.0 && length.is_finite() {
        length
    } else {
        1.0
    }
}
