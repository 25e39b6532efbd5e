//! Building and checking a [`System`].

use std::hash::BuildHasher;
use std::sync::Arc;

use super::constraint::{ConstraintSet, CustomRow, Declaration, ExprRow, RowForm};
use super::holonomic::{Erased, SharedHolonomic};
use super::native::{distance_expression, NativeRow};
use super::{Endpoint, Force, Holonomic, ParametricMap, Particle, ParticleId, System};
use super::{Unilateral, UnilateralRow};
use crate::expr::{parse, Expr, ExprError, Resolved};

/// Slot that stands for time while a system is being built; replaced by the real time slot
/// (2 n) when the system is compiled, because n is known only then. Far above any slot a
/// system can have on a 32-bit target too (wasm32).
const TIME_PLACEHOLDER: usize = 1 << 30;
const AXES: [&str; 3] = ["x", "y", "z"];
/// The masses a particle may have: products of masses, inverse masses and squared speeds stay
/// far from overflow and underflow (1/1e308 is subnormal, so W would lose all precision).
pub(crate) const MASS_RANGE: (f64, f64) = (1e-100, 1e100);
/// Names a parameter may not take.
const RESERVED: [&str; 6] = ["t", "pi", "e", "x", "y", "z"];

/// A model that cannot be built, with what is wrong in words.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum ModelError {
    #[error("more than 2^32 constraints (or rows in one constraint) in one system")]
    TooManyConstraints,
    #[error("gravity must have 2 or 3 components (it sets the dimension), got {0}")]
    BadDimension(usize),
    #[error("{what} must have {expected} components (the scene is {expected}D), got {got}")]
    DimensionMismatch {
        what: String,
        expected: usize,
        got: usize,
    },
    #[error("duplicate {kind} name `{name}`")]
    Duplicate { kind: &'static str, name: String },
    #[error("`{0}` is reserved and cannot name a parameter or coordinate")]
    Reserved(String),
    #[error("particle `{name}`: mass must be between 1e-100 and 1e100, got {}", crate::readable(*mass))]
    BadMass { name: String, mass: f64 },
    #[error("{what} must be finite, got {}", crate::readable(*value))]
    NotFinite { what: String, value: f64 },
    #[error("{what} must be positive, got {}", crate::readable(*value))]
    NotPositive { what: String, value: f64 },
    #[error("unknown particle `{0}`")]
    UnknownParticle(String),
    #[error("no external force #{0}: it was removed, or never added")]
    UnknownForce(u64),
    #[error("a system needs at least one particle")]
    NoParticles,
    #[error("{0}")]
    Parametric(String),
    #[error("{0}")]
    Unilateral(String),
    #[error("in `{source_text}`: {error}")]
    Expression {
        source_text: String,
        error: ExprError,
    },
}

/// A constraint as declared. Expressions keep their source so that edits can parse them
/// again (see `edit.rs`).
#[derive(Clone)]
pub(super) enum ConstraintSpec {
    Expression(Expr, String),
    Distance {
        a: ParticleId,
        b: Endpoint,
        length: f64,
    },
    Pin {
        particle: ParticleId,
        anchor: Vec<f64>,
    },
    /// A Rust constraint, its particles, and its trace: C as an expression over the
    /// coordinates and t (see `super::trace`), or why it has none (its derivatives then come
    /// from dual numbers at every evaluation).
    Custom(SharedHolonomic, Vec<ParticleId>, Result<Expr, &'static str>),
}

/// The parametric form as declared.
#[derive(Clone)]
pub(super) struct ParametricSpec {
    pub(super) coordinates: Vec<String>,
    pub(super) initial: Vec<f64>,
    pub(super) rates: Vec<f64>,
    /// Per particle, one component per axis: the expression and, when it was parsed from
    /// text, that text (numbers and already built expressions have none).
    pub(super) positions: Vec<Option<Vec<Component>>>,
}

/// A parametric position component: its expression and the text it was parsed from.
pub(super) type Component = (Expr, Option<String>);

/// Builds a [`System`] from particles, forces, constraints and an optional parametric map.
///
/// ```
/// use bead::model::SystemBuilder;
/// let mut b = SystemBuilder::new(&[0.0, 500.0]);
/// b.particle("bead", 1.0, &[150.0, -225.0], &[0.0, 0.0]).unwrap();
/// b.constraint_expr("bead.x^2 + 100*bead.y").unwrap();
/// b.parametric(&["q"], &[150.0], &[0.0]).unwrap();
/// b.parametric_position_exprs("bead", &["q", "-q^2/100"]).unwrap();
/// let system = b.build().unwrap();
/// assert_eq!(system.degrees_of_freedom(), 1);
/// ```
///
/// The [`System`] it builds keeps the builder (what the system was declared from), so that
/// [`System::with_constraint_expr`] and [`System::with_param`] can change one declaration and
/// compile again through the same code path as `build`.
#[derive(Clone)]
pub struct SystemBuilder {
    pub(super) gravity: Vec<f64>,
    pub(super) params: Vec<(String, f64)>,
    pub(super) particles: Vec<Particle>,
    /// Particle index by name, so that lookups stay O(1) in scenes of 10^4 particles.
    index: NameIndex,
    pub(super) forces: Vec<Force>,
    pub(super) constraints: Vec<(String, ConstraintSpec)>,
    /// The unilateral constraints: (declaration index, side and restitution).
    pub(super) unilateral: Vec<(usize, Unilateral)>,
    pub(super) parametric: Option<ParametricSpec>,
}

impl std::fmt::Debug for SystemBuilder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SystemBuilder")
            .field("dim", &self.gravity.len())
            .field("params", &self.params)
            .field("particles", &self.particles.len())
            .field("forces", &self.forces.len())
            .field("constraints", &self.constraints.len())
            .field("parametric", &self.parametric.is_some())
            .finish()
    }
}

impl SystemBuilder {
    /// A builder for a world with gravitational acceleration `gravity`; its length (2 or 3)
    /// sets the dimension.
    pub fn new(gravity: &[f64]) -> Self {
        SystemBuilder {
            gravity: gravity.to_vec(),
            params: Vec::new(),
            particles: Vec::new(),
            index: NameIndex::default(),
            forces: Vec::new(),
            constraints: Vec::new(),
            unilateral: Vec::new(),
            parametric: None,
        }
    }

    /// Spatial dimension (the length of gravity).
    pub fn dim(&self) -> usize {
        self.gravity.len()
    }

    /// A named number usable in expressions.
    pub fn param(&mut self, name: &str, value: f64) -> Result<&mut Self, ModelError> {
        if RESERVED.contains(&name) {
            return Err(ModelError::Reserved(name.into()));
        }
        finite(&format!("parameter `{name}`"), value)?;
        if self.params.iter().any(|(n, _)| n == name) {
            return Err(ModelError::Duplicate {
                kind: "parameter",
                name: name.into(),
            });
        }
        self.params.push((name.into(), value));
        Ok(self)
    }

    /// The value of parameter `name`.
    pub fn param_value(&self, name: &str) -> Option<f64> {
        self.params.iter().find(|(n, _)| n == name).map(|(_, v)| *v)
    }

    /// Add a particle.
    pub fn particle(
        &mut self,
        name: &str,
        mass: f64,
        position: &[f64],
        velocity: &[f64],
    ) -> Result<ParticleId, ModelError> {
        if !crate::expr::is_identifier(name) {
            return Err(ModelError::Parametric(format!(
                "particle name `{name}` must be a letter or `_` followed by letters, digits or `_`"
            )));
        }
        if self.index.get(&self.particles, name).is_some() {
            return Err(ModelError::Duplicate {
                kind: "particle",
                name: name.into(),
            });
        }
        if !(MASS_RANGE.0..=MASS_RANGE.1).contains(&mass) {
            return Err(ModelError::BadMass {
                name: name.into(),
                mass,
            });
        }
        self.vector(&format!("particle `{name}` position"), position)?;
        self.vector(&format!("particle `{name}` velocity"), velocity)?;
        self.particles.push(Particle {
            name: name.into(),
            mass,
            position: position.to_vec(),
            velocity: velocity.to_vec(),
        });
        self.index.insert(&self.particles, self.particles.len() - 1);
        Ok(ParticleId(self.particles.len() - 1))
    }

    /// Look a particle up by name.
    pub fn particle_id(&self, name: &str) -> Result<ParticleId, ModelError> {
        self.index
            .get(&self.particles, name)
            .map(ParticleId)
            .ok_or_else(|| ModelError::UnknownParticle(name.into()))
    }

    /// Add an applied force (checked for dimension and finiteness here).
    pub fn force(&mut self, force: Force) -> Result<&mut Self, ModelError> {
        check_force(self.dim(), self.particles.len(), &force)?;
        self.forces.push(force);
        Ok(self)
    }

    /// Resolve a name in a constraint expression: `t`, a parameter, `NAME.x|y|z`, or with a
    /// single particle plain `x y z`.
    pub fn resolve_constraint_name(&self, name: &str) -> Result<Resolved, String> {
        if name == "t" {
            return Ok(Resolved::Var(TIME_PLACEHOLDER));
        }
        if let Some(v) = self.param_value(name) {
            return Ok(Resolved::Value(v));
        }
        let dim = self.dim();
        let coordinate = |p: usize, axis: &str| {
            AXES[..dim.min(3)]
                .iter()
                .position(|a| *a == axis)
                .map(|a| Resolved::Var(p * dim + a))
        };
        if let Some((particle, axis)) = name.split_once('.') {
            if let Some(p) = self.index.get(&self.particles, particle) {
                return coordinate(p, axis).ok_or_else(|| {
                    format!(
                        "`{particle}` has no coordinate `{axis}`; in {dim}D use {}",
                        self.axis_list()
                    )
                });
            }
            return Err(format!(
                "unknown particle `{particle}`; particles: {}",
                self.particle_list()
            ));
        }
        if self.particles.len() == 1 {
            if let Some(r) = coordinate(0, name) {
                return Ok(r);
            }
        }
        Err(format!(
            "unknown name `{name}`; expressions may use t, pi, e, parameters ({}) and particle coordinates like {}",
            self.param_list(),
            self.particles.first().map(|p| format!("{}.x", p.name)).unwrap_or_else(|| "NAME.x".into())
        ))
    }

    /// Parse a constraint expression in this builder's names.
    pub fn parse_constraint_expr(&self, source: &str) -> Result<Expr, ExprError> {
        parse(source, &|name| self.resolve_constraint_name(name))
    }

    /// Add the constraint `source = 0`, an expression over particle coordinates, t and params.
    pub fn constraint_expr(&mut self, source: &str) -> Result<&mut Self, ModelError> {
        let expr = self
            .parse_constraint_expr(source)
            .map_err(|error| ModelError::Expression {
                source_text: source.into(),
                error,
            })?;
        let name = format!("constraint {}", self.constraints.len() + 1);
        Ok(self.add_constraint_expr(&name, expr, source))
    }

    /// Add an already parsed constraint expression (from [`Self::parse_constraint_expr`]).
    pub fn add_constraint_expr(&mut self, name: &str, expr: Expr, source: &str) -> &mut Self {
        self.constraints
            .push((name.into(), ConstraintSpec::Expression(expr, source.into())));
        self
    }

    /// A rigid rod |x_a - x_b| = length.
    pub fn distance(
        &mut self,
        name: &str,
        a: ParticleId,
        b: Endpoint,
        length: f64,
    ) -> Result<&mut Self, ModelError> {
        self.check_particle(a)?;
        self.endpoint("distance anchor", &b)?;
        finite("distance length", length)?;
        if length <= 0.0 {
            return Err(ModelError::NotPositive {
                what: "distance length".into(),
                value: length,
            });
        }
        self.constraints
            .push((name.into(), ConstraintSpec::Distance { a, b, length }));
        Ok(self)
    }

    /// Pin a particle at a fixed point (one constraint row per axis).
    pub fn pin(
        &mut self,
        name: &str,
        particle: ParticleId,
        anchor: &[f64],
    ) -> Result<&mut Self, ModelError> {
        self.check_particle(particle)?;
        self.vector("pin anchor", anchor)?;
        self.constraints.push((
            name.into(),
            ConstraintSpec::Pin {
                particle,
                anchor: anchor.to_vec(),
            },
        ));
        Ok(self)
    }

    /// A constraint written as a Rust type, differentiated automatically.
    ///
    /// Its `value` is traced once, here, into an expression at the particles' positions (see
    /// [`Holonomic::value`]; a panic in it is a panic here): a constraint whose code does not
    /// branch on a value then runs as one typed in a scene file (symbolic derivatives,
    /// machine code). Code that compares or reads a value, or calls a function expressions
    /// do not have, keeps dual numbers at every evaluation, as
    /// [`Self::holonomic_by_dual_numbers`] does; [`crate::model::ConstraintInfo::description`]
    /// says which.
    pub fn holonomic<H: Holonomic>(&mut self, name: &str, constraint: H) -> &mut Self {
        let particles = constraint.particles();
        let dim = self.dim();
        let traced = if particles.iter().all(|p| p.0 < self.particles.len()) {
            let x: Vec<f64> = (particles.iter())
                .flat_map(|p| self.particles[p.0].position.iter().copied())
                .collect();
            let vars: Vec<usize> = (particles.iter())
                .flat_map(|p| (0..dim).map(move |axis| p.0 * dim + axis))
                .collect();
            super::trace::trace(&constraint, &x, &vars, TIME_PLACEHOLDER)
        } else {
            Err("it names a particle the system does not have")
        };
        self.constraints.push((
            name.into(),
            ConstraintSpec::Custom(Arc::new(Erased(constraint)), particles, traced),
        ));
        self
    }

    /// A constraint written as a Rust type, differentiated by dual numbers at every
    /// evaluation (never traced, see [`Self::holonomic`]): for code that must run as written
    /// each time, or to compare the two.
    pub fn holonomic_by_dual_numbers<H: Holonomic>(
        &mut self,
        name: &str,
        constraint: H,
    ) -> &mut Self {
        let particles = constraint.particles();
        self.constraints.push((
            name.into(),
            ConstraintSpec::Custom(
                Arc::new(Erased(constraint)),
                particles,
                Err("declared with holonomic_by_dual_numbers"),
            ),
        ));
        self
    }

    /// Declare the parametric form: generalized coordinates with initial values and rates.
    pub fn parametric(
        &mut self,
        coordinates: &[&str],
        initial: &[f64],
        rates: &[f64],
    ) -> Result<&mut Self, ModelError> {
        if coordinates.is_empty() {
            return Err(ModelError::Parametric(
                "the parametric form needs at least one coordinate".into(),
            ));
        }
        for (i, c) in coordinates.iter().enumerate() {
            if RESERVED.contains(c) || self.param_value(c).is_some() || c.contains('.') {
                return Err(ModelError::Reserved((*c).into()));
            }
            if coordinates[..i].contains(c) {
                return Err(ModelError::Duplicate {
                    kind: "coordinate",
                    name: (*c).into(),
                });
            }
        }
        for (what, values) in [("parametric initial", initial), ("parametric rates", rates)] {
            if values.len() != coordinates.len() {
                return Err(ModelError::Parametric(format!(
                    "{what} has {} values for {} coordinates",
                    values.len(),
                    coordinates.len()
                )));
            }
            for v in values {
                finite(what, *v)?;
            }
        }
        self.parametric = Some(ParametricSpec {
            coordinates: coordinates.iter().map(|c| c.to_string()).collect(),
            initial: initial.to_vec(),
            rates: rates.to_vec(),
            positions: Vec::new(),
        });
        Ok(self)
    }

    /// Resolve a name in a parametric position expression: a coordinate, `t` or a parameter.
    pub fn resolve_parametric_name(&self, name: &str) -> Result<Resolved, String> {
        let coordinates = self
            .parametric
            .as_ref()
            .map(|p| p.coordinates.as_slice())
            .unwrap_or(&[]);
        if name == "t" {
            return Ok(Resolved::Var(TIME_PLACEHOLDER));
        }
        if let Some(j) = coordinates.iter().position(|c| c == name) {
            return Ok(Resolved::Var(j));
        }
        if let Some(v) = self.param_value(name) {
            return Ok(Resolved::Value(v));
        }
        Err(format!(
            "unknown name `{name}`; parametric positions may use the coordinates ({}), t, pi, e and parameters ({})",
            coordinates.join(", "),
            self.param_list()
        ))
    }

    /// Parse a parametric position expression.
    pub fn parse_parametric_expr(&self, source: &str) -> Result<Expr, ExprError> {
        parse(source, &|name| self.resolve_parametric_name(name))
    }

    /// Set particle `name`'s position as expressions of q and t (one per axis). These have no
    /// source text, so [`System::with_param`] keeps them as they are: give expressions of
    /// parameters with [`Self::parametric_position_exprs`] or
    /// [`Self::parametric_position_with_sources`].
    pub fn parametric_position(
        &mut self,
        name: &str,
        exprs: Vec<Expr>,
    ) -> Result<&mut Self, ModelError> {
        let sources = vec![None; exprs.len()];
        self.parametric_position_with_sources(name, exprs, sources)
    }

    /// [`Self::parametric_position`] with the text each expression was parsed from (`None`
    /// for a number), which [`System::with_param`] parses again.
    pub fn parametric_position_with_sources(
        &mut self,
        name: &str,
        exprs: Vec<Expr>,
        sources: Vec<Option<String>>,
    ) -> Result<&mut Self, ModelError> {
        let p = self.particle_id(name)?.0;
        if sources.len() != exprs.len() {
            return Err(ModelError::Parametric(format!(
                "parametric position of `{name}`: {} sources for {} expressions",
                sources.len(),
                exprs.len()
            )));
        }
        if exprs.len() != self.dim() {
            return Err(ModelError::DimensionMismatch {
                what: format!("parametric position of `{name}`"),
                expected: self.dim(),
                got: exprs.len(),
            });
        }
        let n_particles = self.particles.len();
        let spec = self.parametric.as_mut().ok_or_else(|| {
            ModelError::Parametric("declare the parametric coordinates first".into())
        })?;
        spec.positions.resize(n_particles, None);
        if spec.positions[p].is_some() {
            return Err(ModelError::Duplicate {
                kind: "parametric position for particle",
                name: name.into(),
            });
        }
        spec.positions[p] = Some(exprs.into_iter().zip(sources).collect());
        Ok(self)
    }

    /// Parse and set particle `name`'s parametric position.
    pub fn parametric_position_exprs(
        &mut self,
        name: &str,
        sources: &[&str],
    ) -> Result<&mut Self, ModelError> {
        let exprs = sources
            .iter()
            .map(|s| {
                self.parse_parametric_expr(s)
                    .map_err(|error| ModelError::Expression {
                        source_text: (*s).into(),
                        error,
                    })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let sources = sources.iter().map(|s| Some(s.to_string())).collect();
        self.parametric_position_with_sources(name, exprs, sources)
    }

    /// Check everything and compile the constraints and the parametric map.
    pub fn build(mut self) -> Result<System, ModelError> {
        // Kept with the system (for edits, and its particles): no slack from growing.
        self.particles.shrink_to_fit();
        self.constraints.shrink_to_fit();
        compile(Arc::new(self))
    }

    /// Whether `self` and `other` declare the same equations of motion: the same gravity,
    /// particles (names and masses), forces, constraints (expressions of the same structure
    /// with the same constants, the same rods and pins, the same Rust constraint objects) and
    /// parametric map, compared bit for bit; initial positions, velocities, parametric
    /// initial values and parameter values may differ (parameters act through the numbers
    /// and expressions they gave, which are compared).
    pub(crate) fn same_dynamics(&self, other: &SystemBuilder) -> bool {
        let bits = crate::same_bits;
        let endpoints = |a: &Endpoint, b: &Endpoint| match (a, b) {
            (Endpoint::Particle(p), Endpoint::Particle(q)) => p == q,
            (Endpoint::Fixed(p), Endpoint::Fixed(q)) => bits(p, q),
            _ => false,
        };
        let forces = |a: &Force, b: &Force| match (a, b) {
            (
                Force::Constant {
                    particle: p,
                    vector: u,
                },
                Force::Constant {
                    particle: q,
                    vector: v,
                },
            ) => p == q && bits(u, v),
            (
                Force::Spring {
                    a: a1,
                    b: b1,
                    stiffness: k1,
                    rest_length: l1,
                },
                Force::Spring {
                    a: a2,
                    b: b2,
                    stiffness: k2,
                    rest_length: l2,
                },
            ) => a1 == a2 && endpoints(b1, b2) && bits(&[*k1, *l1], &[*k2, *l2]),
            (
                Force::Drag {
                    particle: p,
                    coefficient: c,
                },
                Force::Drag {
                    particle: q,
                    coefficient: d,
                },
            ) => p == q && c.to_bits() == d.to_bits(),
            _ => false,
        };
        let constraints = |(n1, a): &(String, ConstraintSpec),
                           (n2, b): &(String, ConstraintSpec)| {
            n1 == n2
                && match (a, b) {
                    (ConstraintSpec::Expression(e, s), ConstraintSpec::Expression(f, t)) => {
                        s == t && crate::expr::same_structure(&[e], &[f])
                    }
                    (
                        ConstraintSpec::Distance {
                            a: a1,
                            b: b1,
                            length: l1,
                        },
                        ConstraintSpec::Distance {
                            a: a2,
                            b: b2,
                            length: l2,
                        },
                    ) => a1 == a2 && endpoints(b1, b2) && l1.to_bits() == l2.to_bits(),
                    (
                        ConstraintSpec::Pin {
                            particle: p,
                            anchor: u,
                        },
                        ConstraintSpec::Pin {
                            particle: q,
                            anchor: v,
                        },
                    ) => p == q && bits(u, v),
                    (ConstraintSpec::Custom(c, p, _), ConstraintSpec::Custom(d, q, _)) => {
                        Arc::ptr_eq(c, d) && p == q
                    }
                    _ => false,
                }
        };
        let parametric = match (&self.parametric, &other.parametric) {
            (None, None) => true,
            (Some(a), Some(b)) => {
                a.coordinates == b.coordinates
                    && a.initial.len() == b.initial.len()
                    && a.rates.len() == b.rates.len()
                    && a.positions.len() == b.positions.len()
                    && a.positions
                        .iter()
                        .zip(&b.positions)
                        .all(|(p, q)| match (p, q) {
                            (None, None) => true,
                            (Some(p), Some(q)) => {
                                p.len() == q.len()
                                    && p.iter().zip(q).all(|((e, s), (f, t))| {
                                        s == t && crate::expr::same_structure(&[e], &[f])
                                    })
                            }
                            _ => false,
                        })
            }
            _ => false,
        };
        bits(&self.gravity, &other.gravity)
            && self.particles.len() == other.particles.len()
            && self
                .particles
                .iter()
                .zip(&other.particles)
                .all(|(p, q)| p.name == q.name && p.mass.to_bits() == q.mass.to_bits())
            && self.forces.len() == other.forces.len()
            && self
                .forces
                .iter()
                .zip(&other.forces)
                .all(|(a, b)| forces(a, b))
            && self.constraints.len() == other.constraints.len()
            && self
                .constraints
                .iter()
                .zip(&other.constraints)
                .all(|(a, b)| constraints(a, b))
            && self.unilateral == other.unilateral
            && parametric
    }

    fn check_particle(&self, p: ParticleId) -> Result<(), ModelError> {
        check_particle(self.particles.len(), p)
    }

    fn endpoint(&self, what: &str, e: &Endpoint) -> Result<(), ModelError> {
        check_endpoint(self.dim(), self.particles.len(), what, e)
    }

    /// What declared constraint `index` is, as [`super::ConstraintInfo::description`] gives
    /// it: `source = 0`, `distance(a, b) = L`, `pin(p) at [x, y]` or a Rust constraint.
    pub(crate) fn describe_constraint(&self, index: usize) -> String {
        match &self.constraints[index].1 {
            ConstraintSpec::Expression(_, source) => format!("{source} = 0"),
            ConstraintSpec::Distance { a, b, length } => format!(
                "distance({}, {}) = {length}",
                self.particles[a.0].name,
                self.endpoint_name(b)
            ),
            ConstraintSpec::Pin { particle, anchor } => {
                format!("pin({}) at {anchor:?}", self.particles[particle.0].name)
            }
            ConstraintSpec::Custom(_, _, Ok(_)) => {
                "Rust constraint (traced into an expression: symbolic derivatives)".into()
            }
            ConstraintSpec::Custom(_, _, Err(why)) => {
                format!("Rust constraint (derivatives by dual numbers: {why})")
            }
        }
    }

    /// Declared constraint `index`'s own length, when it is a distance (see
    /// [`super::ConstraintInfo::length`]).
    pub(crate) fn constraint_length(&self, index: usize) -> Option<f64> {
        match &self.constraints[index].1 {
            ConstraintSpec::Distance { length, .. } => Some(*length),
            _ => None,
        }
    }

    fn endpoint_name(&self, e: &Endpoint) -> String {
        match e {
            Endpoint::Particle(p) => self.particles[p.0].name.clone(),
            Endpoint::Fixed(point) => format!("{point:?}"),
        }
    }

    fn vector(&self, what: &str, v: &[f64]) -> Result<(), ModelError> {
        check_vector(self.dim(), what, v)
    }

    fn particle_list(&self) -> String {
        crate::name_list(self.particles.iter().map(|p| p.name.as_str()))
    }
    fn param_list(&self) -> String {
        if self.params.is_empty() {
            "none".into()
        } else {
            self.params
                .iter()
                .map(|(n, _)| n.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        }
    }
    fn axis_list(&self) -> String {
        AXES[..self.dim().min(3)].join(", ")
    }
}

/// Check a declaration and compile its constraints and parametric map: the one compile step
/// of [`SystemBuilder::build`] and of the edits ([`System::with_constraint_expr`],
/// [`System::with_param`]). The system keeps `declared`.
/// Compile `declared`, reusing `previous`'s compiled equations when `declared` describes the
/// same dynamics (see [`SystemBuilder::same_dynamics`]) and differs only in the initial
/// state and parameter values: then the system is `previous` with `declared`'s particles
/// (their initial positions and velocities), parametric initial values and parameters, and
/// nothing is differentiated or compiled again. The result is the system [`compile`] would
/// make: the same derivatives and tapes, since they are a function of the dynamics alone.
pub(crate) fn compile_reusing(
    declared: Arc<SystemBuilder>,
    previous: &System,
) -> Result<System, ModelError> {
    if !declared.same_dynamics(&previous.declared) {
        return compile(declared);
    }
    Ok(previous.restarted(declared))
}

impl System {
    /// This system's compiled equations with `declared`'s initial state (particles,
    /// parametric initial values) and parameters: what [`compile_reusing`] makes when
    /// `declared` has the same dynamics as `self` (the caller knows it does).
    pub(crate) fn restarted(&self, declared: Arc<SystemBuilder>) -> System {
        let b = &*declared;
        let parametric = match (&self.parametric, &b.parametric) {
            (Some(map), Some(spec)) => Some(map.with_initial(&spec.initial, &spec.rates)),
            _ => None,
        };
        System {
            params: b.params.clone(),
            parametric,
            declared,
            ..self.clone()
        }
    }
}

impl System {
    /// This system started elsewhere: particle positions `x` and velocities `v` (n_coords
    /// each) and, when the system has a parametric form, its initial q and qdot. The
    /// equations are shared, not compiled again; the values are taken as they are (the
    /// caller placed them on the constraints).
    pub fn with_initial_state(
        &self,
        x: &[f64],
        v: &[f64],
        parametric: Option<(Vec<f64>, Vec<f64>)>,
    ) -> System {
        let dim = self.dim();
        let particles = (0..self.particles().len())
            .map(|p| {
                let range = p * dim..(p + 1) * dim;
                (p, x[range.clone()].to_vec(), v[range].to_vec())
            })
            .collect();
        let declared = self
            .declared
            .restarted(self.declared.params.clone(), particles, parametric);
        self.restarted(Arc::new(declared))
    }
}

impl SystemBuilder {
    /// This declaration with parameters `params` (every one, in order), the initial position
    /// and velocity of the particles `particles` (index, position, velocity) and, when given,
    /// the parametric form's initial values and rates replaced: the same dynamics, started
    /// elsewhere. The values are taken as they are (the scene loader checked them).
    pub(crate) fn restarted(
        &self,
        params: Vec<(String, f64)>,
        particles: Vec<(usize, Vec<f64>, Vec<f64>)>,
        parametric: Option<(Vec<f64>, Vec<f64>)>,
    ) -> SystemBuilder {
        let mut b = self.clone();
        b.params = params;
        for (p, position, velocity) in particles {
            b.particles[p].position = position;
            b.particles[p].velocity = velocity;
        }
        if let (Some(spec), Some((initial, rates))) = (b.parametric.as_mut(), parametric) {
            spec.initial = initial;
            spec.rates = rates;
        }
        b
    }
}

/// Particle indices by name, with no second copy of the names (a chain of 10^5 links would
/// hold 10^5 more strings): the table holds indices and compares through the particles'
/// own names.
#[derive(Clone, Default)]
struct NameIndex {
    table: hashbrown::HashTable<usize>,
    hasher: std::hash::RandomState,
}

impl NameIndex {
    /// The index of the particle named `name`.
    fn get(&self, particles: &[Particle], name: &str) -> Option<usize> {
        let hash = self.hasher.hash_one(name);
        self.table
            .find(hash, |&i| particles[i].name == name)
            .copied()
    }

    /// Index particle `index` by its name (not yet indexed).
    fn insert(&mut self, particles: &[Particle], index: usize) {
        let hasher = &self.hasher;
        let hash = |i: usize| hasher.hash_one(particles[i].name.as_str());
        self.table.insert_unique(hash(index), index, |&i| hash(i));
    }
}

/// A declared constraint's index or row count as [`Declaration`] keeps it.
fn declaration_index(k: usize) -> Result<u32, ModelError> {
    u32::try_from(k).map_err(|_| ModelError::TooManyConstraints)
}

pub(super) fn compile(declared: Arc<SystemBuilder>) -> Result<System, ModelError> {
    let b = &*declared;
    let dim = b.dim();
    if !(2..=3).contains(&dim) {
        return Err(ModelError::BadDimension(dim));
    }
    for g in &b.gravity {
        finite("gravity", *g)?;
    }
    if b.particles.is_empty() {
        return Err(ModelError::NoParticles);
    }
    let n = b.particles.len() * dim;
    let time = |k: usize| {
        if k == TIME_PLACEHOLDER {
            Expr::var(2 * n)
        } else {
            Expr::var(k)
        }
    };
    let mut declarations = Vec::new();
    // Expression rows, each symbolic or native (distances and pins).
    let mut rows: Vec<RowForm> = Vec::new();
    let mut custom = Vec::new();
    // Rust rows go after all expression rows; remember which declarations they are.
    let mut custom_declarations = Vec::new();
    let mut unilateral = Vec::new();
    for (index, (_, spec)) in b.constraints.iter().enumerate() {
        let start = rows.len();
        if let Some((_, u)) = b.unilateral.iter().find(|(i, _)| *i == index) {
            // Its row is `start` only in declaration order: `unilateral` refuses the others.
            debug_assert!(!matches!(spec, ConstraintSpec::Custom(_, _, Err(_))));
            unilateral.push(UnilateralRow {
                row: start,
                constraint: index,
                side: u.side,
                restitution: u.restitution,
            });
        }
        match spec {
            ConstraintSpec::Expression(expr, _) => {
                rows.push(RowForm::Symbolic(ExprRow::new(expr.substitute(&time), n)));
            }
            ConstraintSpec::Distance { a, b: end, length } => {
                let a_first = a.0 * dim;
                rows.push(match end {
                    // A particle's distance to itself is a constant row, left to the tape
                    // (and to the checks that reject a row with no gradient).
                    Endpoint::Particle(p) if p.0 == a.0 => RowForm::Symbolic(ExprRow::new(
                        distance_expression(dim, a_first, Some(a_first), &[], *length),
                        n,
                    )),
                    Endpoint::Particle(p) => RowForm::Native(NativeRow::distance_row(
                        dim,
                        a_first,
                        Some(p.0 * dim),
                        &[],
                        *length,
                    )),
                    Endpoint::Fixed(point) => {
                        RowForm::Native(NativeRow::distance_row(dim, a_first, None, point, *length))
                    }
                });
            }
            ConstraintSpec::Pin { particle, anchor } => {
                for (axis, value) in anchor.iter().enumerate() {
                    rows.push(RowForm::Native(NativeRow::Pin {
                        coordinate: particle.0 * dim + axis,
                        anchor: *value,
                    }));
                }
            }
            ConstraintSpec::Custom(_, particles, Ok(expr)) => {
                for p in particles {
                    b.check_particle(*p)?;
                }
                rows.push(RowForm::Symbolic(ExprRow::new(expr.substitute(&time), n)));
            }
            ConstraintSpec::Custom(constraint, particles, Err(_)) => {
                let mut coords = Vec::new();
                for p in particles {
                    b.check_particle(*p)?;
                    coords.extend((0..dim).map(|axis| p.0 * dim + axis));
                }
                custom.push(CustomRow {
                    constraint: constraint.clone(),
                    coords,
                });
                custom_declarations.push(index);
                continue;
            }
        };
        declarations.push(Declaration {
            index: declaration_index(index)?,
            n_rows: declaration_index(rows.len() - start)?,
            first_row: start,
        });
    }
    let n_expr = rows.len();
    for (i, index) in custom_declarations.into_iter().enumerate() {
        declarations.push(Declaration {
            index: declaration_index(index)?,
            n_rows: 1,
            first_row: n_expr + i,
        });
    }
    let constraints = ConstraintSet::new(n, Arc::clone(&declared), declarations, rows, custom);

    let parametric = match &b.parametric {
        None => None,
        Some(spec) => {
            let n_q = spec.coordinates.len();
            let time = |k: usize| {
                if k == TIME_PLACEHOLDER {
                    Expr::var(2 * n_q)
                } else {
                    Expr::var(k)
                }
            };
            let mut positions = Vec::with_capacity(n);
            for (p, particle) in b.particles.iter().enumerate() {
                let exprs = spec.positions.get(p).and_then(|e| e.as_ref()).ok_or_else(|| {
                    ModelError::Parametric(format!(
                        "the parametric form gives no position for particle `{}`; every particle needs one",
                        particle.name
                    ))
                })?;
                positions.extend(exprs.iter().map(|(e, _)| e.substitute(&time)));
            }
            Some(ParametricMap::new(
                spec.coordinates.clone(),
                spec.initial.clone(),
                spec.rates.clone(),
                positions,
            ))
        }
    };
    let inverse_mass = b
        .particles
        .iter()
        .flat_map(|p| std::iter::repeat_n(1.0 / p.mass, dim))
        .collect::<Vec<f64>>()
        .into();
    // m g per coordinate, the products `System::accumulate_forces` starts from.
    let weight = b
        .particles
        .iter()
        .flat_map(|p| b.gravity.iter().map(move |g| p.mass * g))
        .collect();
    Ok(System {
        weight,
        params: b.params.clone(),
        dim,
        gravity: b.gravity.clone(),
        forces: b.forces.clone(),
        constraints: Arc::new(constraints),
        unilateral,
        parametric,
        inverse_mass,
        declared,
    })
}

/// Check a force against a system of `n_particles` particles in `dim` dimensions.
pub(crate) fn check_force(dim: usize, n_particles: usize, force: &Force) -> Result<(), ModelError> {
    match force {
        Force::Constant { particle, vector } => {
            check_particle(n_particles, *particle)?;
            check_vector(dim, "constant force vector", vector)
        }
        Force::Spring {
            a,
            b,
            stiffness,
            rest_length,
        } => {
            check_particle(n_particles, *a)?;
            check_endpoint(dim, n_particles, "spring anchor", b)?;
            finite("spring stiffness", *stiffness)?;
            finite("spring rest_length", *rest_length)?;
            if *rest_length < 0.0 {
                return Err(ModelError::NotPositive {
                    what: "spring rest_length".into(),
                    value: *rest_length,
                });
            }
            Ok(())
        }
        Force::Drag {
            particle,
            coefficient,
        } => {
            if let Some(p) = particle {
                check_particle(n_particles, *p)?;
            }
            finite("drag coefficient", *coefficient)
        }
    }
}

fn check_particle(n_particles: usize, p: ParticleId) -> Result<(), ModelError> {
    if p.0 < n_particles {
        Ok(())
    } else {
        Err(ModelError::UnknownParticle(format!("#{}", p.0)))
    }
}

fn check_endpoint(
    dim: usize,
    n_particles: usize,
    what: &str,
    e: &Endpoint,
) -> Result<(), ModelError> {
    match e {
        Endpoint::Particle(p) => check_particle(n_particles, *p),
        Endpoint::Fixed(point) => check_vector(dim, what, point),
    }
}

fn check_vector(dim: usize, what: &str, v: &[f64]) -> Result<(), ModelError> {
    if v.len() != dim {
        return Err(ModelError::DimensionMismatch {
            what: what.into(),
            expected: dim,
            got: v.len(),
        });
    }
    for c in v {
        finite(what, *c)?;
    }
    Ok(())
}

/// The native form of a distance row between particle `a` and `end`, built from the
/// symbolic row's columns (which fix where each coordinate's entry goes); `None` when the
/// row is degenerate (a particle tied to itself) and stays on the tape.
fn finite(what: &str, value: f64) -> Result<(), ModelError> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(ModelError::NotFinite {
            what: what.into(),
            value,
        })
    }
}
