//! Typed edits of a compiled [`System`]: replace one expression constraint, or change one
//! parameter. Each returns a new system compiled from the changed declaration by the same
//! code as [`super::SystemBuilder::build`]; the original is untouched.

use std::ops::Range;
use std::sync::Arc;

use super::builder::{compile, ConstraintSpec, ModelError};
use super::{Endpoint, ParticleId, System};
use crate::expr::{Expr, ExprError};

/// Why an edit cannot be made. Nothing here is rendered text: expression errors carry the
/// byte span of the offending text inside the expression.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum EditError {
    /// An expression does not parse, or names something unknown.
    #[error("{message}")]
    Expression {
        /// The expression's text.
        source_text: String,
        message: String,
        /// Where, in bytes of `source_text` (on character boundaries; empty at end of input).
        span: Range<usize>,
    },
    /// A constraint expression that does not depend on any particle coordinate.
    #[error("the expression does not depend on any particle coordinate")]
    NoCoordinate { source_text: String },
    /// No declared constraint `index`.
    #[error("no constraint {index}: the system declares {count}")]
    UnknownConstraint { index: usize, count: usize },
    /// The constraint is a distance, a pin or a Rust type: it has no expression to replace.
    #[error("{name} is a {kind} constraint: only expression constraints can be edited")]
    NotAnExpression {
        index: usize,
        name: String,
        /// `distance`, `pin` or `Rust`.
        kind: &'static str,
    },
    /// No parameter of that name.
    #[error("unknown parameter `{name}`; {}", param_list(.known))]
    UnknownParam { name: String, known: Vec<String> },
    /// The changed declaration is not a valid model.
    #[error(transparent)]
    Model(#[from] ModelError),
}

fn param_list(known: &[String]) -> String {
    if known.is_empty() {
        "the system has no parameters".into()
    } else {
        format!("the parameters are {}", known.join(", "))
    }
}

impl EditError {
    fn expression(source: &str, error: ExprError) -> EditError {
        EditError::Expression {
            source_text: source.to_string(),
            message: error.message,
            span: error.span.start..error.span.end,
        }
    }
}

/// A constraint as declared (see [`System::declared_constraints`]).
#[derive(Clone, Debug, PartialEq)]
pub enum DeclaredConstraint<'a> {
    /// `source = 0`.
    Expression { name: &'a str, source: &'a str },
    /// A rod |x_a - x_b| = length.
    Distance {
        name: &'a str,
        a: ParticleId,
        b: &'a Endpoint,
        length: f64,
    },
    /// A particle pinned at `anchor`.
    Pin {
        name: &'a str,
        particle: ParticleId,
        anchor: &'a [f64],
    },
    /// A Rust type ([`super::Holonomic`]).
    Rust { name: &'a str },
}

impl DeclaredConstraint<'_> {
    /// Its name (`constraint 1` unless named).
    pub fn name(&self) -> &str {
        match self {
            DeclaredConstraint::Expression { name, .. }
            | DeclaredConstraint::Distance { name, .. }
            | DeclaredConstraint::Pin { name, .. }
            | DeclaredConstraint::Rust { name } => name,
        }
    }
    /// The expression's text, for expression constraints.
    pub fn source(&self) -> Option<&str> {
        match self {
            DeclaredConstraint::Expression { source, .. } => Some(source),
            _ => None,
        }
    }
}

impl System {
    /// The constraints in declaration order (the order of the builder's calls, or of a scene's
    /// `[[constraint]]` tables). [`crate::model::ConstraintSet::infos`] lists the same
    /// constraints, but with Rust constraints differentiated by dual numbers moved last.
    pub fn declared_constraints(&self) -> Vec<DeclaredConstraint<'_>> {
        self.declared
            .constraints
            .iter()
            .map(|(name, spec)| match spec {
                ConstraintSpec::Expression(_, source) => DeclaredConstraint::Expression {
                    name,
                    source: source.as_str(),
                },
                ConstraintSpec::Distance { a, b, length } => DeclaredConstraint::Distance {
                    name,
                    a: *a,
                    b,
                    length: *length,
                },
                ConstraintSpec::Pin { particle, anchor } => DeclaredConstraint::Pin {
                    name,
                    particle: *particle,
                    anchor,
                },
                ConstraintSpec::Custom(..) => DeclaredConstraint::Rust { name },
            })
            .collect()
    }

    /// What declared constraint `index` (see [`Self::declared_constraints`]) is, as
    /// [`crate::model::ConstraintInfo::description`] says it: `source = 0`,
    /// `distance(a, b) = L`, `pin(p) at [x, y]`, or a Rust constraint.
    pub fn constraint_description(&self, index: usize) -> String {
        self.declared.describe_constraint(index)
    }

    /// A new system with declared constraint `index` (see [`Self::declared_constraints`])
    /// replaced by `source = 0`, parsed with this system's particle names and parameters;
    /// every other declaration is unchanged. Only expression constraints can be replaced.
    ///
    /// ```
    /// use bead::model::{EditError, SystemBuilder};
    /// let mut b = SystemBuilder::new(&[0.0, 9.81]);
    /// b.particle("bead", 1.0, &[1.0, 0.0], &[0.0, 0.0])?;
    /// b.param("r", 1.0)?;
    /// b.constraint_expr("bead.x^2 + bead.y^2 - r^2")?;
    /// let circle = b.build()?;
    /// let ellipse = circle.with_constraint_expr(0, "bead.x^2 + 4*bead.y^2 - r^2")?;
    /// assert_eq!(ellipse.constraints().info(0).description, "bead.x^2 + 4*bead.y^2 - r^2 = 0");
    /// // Errors point into the new expression (bytes).
    /// let Err(EditError::Expression { span, .. }) = circle.with_constraint_expr(0, "bead.x + bead.w")
    /// else { panic!() };
    /// assert_eq!(span, 9..15);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn with_constraint_expr(&self, index: usize, source: &str) -> Result<System, EditError> {
        let mut declared = (*self.declared).clone();
        let count = declared.constraints.len();
        let (name, spec) = declared
            .constraints
            .get(index)
            .ok_or(EditError::UnknownConstraint { index, count })?;
        let kind = match spec {
            ConstraintSpec::Expression(..) => None,
            ConstraintSpec::Distance { .. } => Some("distance"),
            ConstraintSpec::Pin { .. } => Some("pin"),
            ConstraintSpec::Custom(..) => Some("Rust"),
        };
        if let Some(kind) = kind {
            return Err(EditError::NotAnExpression {
                index,
                name: name.clone(),
                kind,
            });
        }
        let expr = declared
            .parse_constraint_expr(source)
            .map_err(|e| EditError::expression(source, e))?;
        if !depends_on_coordinates(&expr, self.n_coords()) {
            return Err(EditError::NoCoordinate {
                source_text: source.to_string(),
            });
        }
        declared.constraints[index].1 = ConstraintSpec::Expression(expr, source.to_string());
        Ok(compile(Arc::new(declared))?)
    }

    /// A new system with parameter `name` set to `value`: every expression of the constraints
    /// and of the parametric map that was declared from text is parsed again with it. Numbers
    /// the builder received as numbers (masses, positions, lengths, forces) do not change: a
    /// scene evaluates those itself, see [`crate::scene::Scene::with_param`].
    pub fn with_param(&self, name: &str, value: f64) -> Result<System, EditError> {
        let mut declared = (*self.declared).clone();
        let known: Vec<String> = declared.params.iter().map(|(n, _)| n.clone()).collect();
        let Some(slot) = declared.params.iter_mut().find(|(n, _)| n == name) else {
            return Err(EditError::UnknownParam {
                name: name.to_string(),
                known,
            });
        };
        if !value.is_finite() {
            return Err(ModelError::NotFinite {
                what: format!("parameter `{name}`"),
                value,
            }
            .into());
        }
        slot.1 = value;
        let constraints: Vec<Option<Expr>> = declared
            .constraints
            .iter()
            .map(|(_, spec)| match spec {
                ConstraintSpec::Expression(_, source) => declared
                    .parse_constraint_expr(source)
                    .map(Some)
                    .map_err(|e| EditError::expression(source, e)),
                _ => Ok(None),
            })
            .collect::<Result<_, _>>()?;
        for ((_, spec), expr) in declared.constraints.iter_mut().zip(constraints) {
            if let (ConstraintSpec::Expression(old, _), Some(expr)) = (spec, expr) {
                *old = expr;
            }
        }
        let positions = match &declared.parametric {
            None => Vec::new(),
            Some(spec) => spec
                .positions
                .iter()
                .map(|components| {
                    components
                        .iter()
                        .flatten()
                        .map(|(_, source)| match source {
                            Some(source) => declared
                                .parse_parametric_expr(source)
                                .map(Some)
                                .map_err(|e| EditError::expression(source, e)),
                            None => Ok(None),
                        })
                        .collect::<Result<Vec<_>, _>>()
                })
                .collect::<Result<Vec<_>, _>>()?,
        };
        if let Some(spec) = &mut declared.parametric {
            for (components, parsed) in spec.positions.iter_mut().zip(positions) {
                for ((old, _), new) in components.iter_mut().flatten().zip(parsed) {
                    if let Some(new) = new {
                        *old = new;
                    }
                }
            }
        }
        Ok(compile(Arc::new(declared))?)
    }
}

/// Whether `expr` reads a particle coordinate (slots below `n`; t has a placeholder slot far
/// beyond).
fn depends_on_coordinates(expr: &Expr, n: usize) -> bool {
    expr.vars().iter().any(|&k| k < n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::SystemBuilder;

    /// A bead on a circle of radius r, with the parametric form of the same circle.
    fn circle() -> System {
        let mut b = SystemBuilder::new(&[0.0, 9.81]);
        b.param("r", 2.0).unwrap();
        b.particle("bead", 1.0, &[2.0, 0.0], &[0.0, 0.0]).unwrap();
        b.constraint_expr("bead.x^2 + bead.y^2 - r^2").unwrap();
        b.pin("hold", ParticleId(0), &[2.0, 0.0]).unwrap();
        b.parametric(&["theta"], &[0.0], &[0.0]).unwrap();
        b.parametric_position_exprs("bead", &["r*cos(theta)", "r*sin(theta)"])
            .unwrap();
        b.build().unwrap()
    }

    fn residual(system: &System, x: &[f64]) -> f64 {
        let set = system.constraints();
        let mut ws = set.workspace();
        set.residuals(0.0, x, &mut ws)[0]
    }

    #[test]
    fn a_constraint_expression_is_replaced_and_the_rest_kept() {
        let system = circle();
        let edited = system
            .with_constraint_expr(0, "bead.x^2 + 4*bead.y^2 - r^2")
            .unwrap();
        assert_eq!(
            edited.declared_constraints()[0],
            DeclaredConstraint::Expression {
                name: "constraint 1",
                source: "bead.x^2 + 4*bead.y^2 - r^2"
            }
        );
        // On the new ellipse (a = 2, b = 1), off the old circle.
        assert_eq!(residual(&edited, &[0.0, 1.0]), 0.0);
        assert_eq!(residual(&system, &[0.0, 1.0]), -3.0);
        // The pin and the parametric form are unchanged.
        assert_eq!(
            edited.declared_constraints()[1],
            system.declared_constraints()[1]
        );
        assert_eq!(edited.constraints().n_rows(), 3);
        assert!(edited.parametric().is_some());
    }

    #[test]
    fn edit_errors_are_typed_with_spans_into_the_new_expression() {
        let system = circle();
        let source = "bead.x^2 + 100*bead.w";
        match system.with_constraint_expr(0, source) {
            Err(EditError::Expression {
                source_text,
                message,
                span,
            }) => {
                assert_eq!(source_text, source);
                assert_eq!(&source[span], "bead.w");
                assert!(message.contains("no coordinate `w`"), "{message}");
            }
            other => panic!("{other:?}"),
        }
        // A span in bytes, after a name with a non-ASCII letter.
        let mut b = SystemBuilder::new(&[0.0, 1.0]);
        b.particle("perlé", 1.0, &[1.0, 0.0], &[0.0, 0.0]).unwrap();
        b.constraint_expr("perlé.x^2 + perlé.y^2 - 1").unwrap();
        let accented = b.build().unwrap();
        let source = "perlé.x^2 + perlé.q";
        let Err(EditError::Expression { span, .. }) = accented.with_constraint_expr(0, source)
        else {
            panic!()
        };
        assert_eq!(span, 13..21);
        assert_eq!(&source[span], "perlé.q");
        assert!(matches!(
            system.with_constraint_expr(0, "t - 1"),
            Err(EditError::NoCoordinate { .. })
        ));
        assert_eq!(
            system.with_constraint_expr(5, "bead.x").unwrap_err(),
            EditError::UnknownConstraint { index: 5, count: 2 }
        );
        let error = system.with_constraint_expr(1, "bead.x").unwrap_err();
        assert_eq!(
            error,
            EditError::NotAnExpression {
                index: 1,
                name: "hold".into(),
                kind: "pin"
            }
        );
        assert_eq!(
            error.to_string(),
            "hold is a pin constraint: only expression constraints can be edited"
        );
    }

    #[test]
    fn a_parameter_change_parses_every_expression_again() {
        let system = circle();
        let bigger = system.with_param("r", 3.0).unwrap();
        assert_eq!(bigger.params(), &[("r".to_string(), 3.0)]);
        assert_eq!(residual(&bigger, &[3.0, 0.0]), 0.0);
        assert_eq!(residual(&system, &[2.0, 0.0]), 0.0);
        let map = bigger.parametric().unwrap();
        let mut ws = map.workspace();
        map.state_at(0.0, &[0.0], &[0.0], &mut ws);
        assert_eq!(&ws.position[..2], &[3.0, 0.0]);
        // Edits made before survive a parameter change, and see the new value.
        let ellipse = system
            .with_constraint_expr(0, "bead.x^2 + 4*bead.y^2 - r^2")
            .unwrap()
            .with_param("r", 4.0)
            .unwrap();
        assert_eq!(residual(&ellipse, &[0.0, 2.0]), 0.0);
        assert_eq!(
            system.with_param("R", 1.0).unwrap_err().to_string(),
            "unknown parameter `R`; the parameters are r"
        );
        assert!(matches!(
            system.with_param("r", f64::NAN),
            Err(EditError::Model(ModelError::NotFinite { .. }))
        ));
    }
}
