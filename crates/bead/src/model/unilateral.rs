//! Unilateral constraints: a scalar constraint that holds one side of C = 0 only.
//!
//! A row marked [`Side::Above`] allows C >= 0, [`Side::Below`] C <= 0 (with s = +1 or -1,
//! s C >= 0). While attached it is an ordinary row whose force must push: s lambda >= 0
//! (the force J^T lambda points into the allowed side). Where s lambda would turn
//! negative the particle detaches and the row is left out of the equations; where s C
//! reaches 0 again it lands with an impulse that turns the normal velocity s Cdot into
//! -e s Cdot (restitution e in [0, 1], the tangential velocity kept in the mass metric).
//! The switching itself is the simulation's (`simulate/contact.rs`); the model only says
//! which rows are unilateral.

use std::sync::Arc;

use super::builder::{compile, ConstraintSpec};
use super::{ModelError, System, SystemBuilder};

/// Which side of C = 0 a unilateral constraint allows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Side {
    /// C >= 0
    Above,
    /// C <= 0
    Below,
}

impl Side {
    /// s = +1 for [`Side::Above`], -1 for [`Side::Below`]: the allowed side is s C >= 0.
    pub fn sign(self) -> f64 {
        match self {
            Side::Above => 1.0,
            Side::Below => -1.0,
        }
    }

    /// `above` or `below`, as a scene writes it.
    pub fn name(self) -> &'static str {
        match self {
            Side::Above => "above",
            Side::Below => "below",
        }
    }
}

impl std::str::FromStr for Side {
    type Err = String;
    fn from_str(s: &str) -> Result<Side, String> {
        match s {
            "above" => Ok(Side::Above),
            "below" => Ok(Side::Below),
            other => Err(format!(
                "unknown side `{other}`; use above (C >= 0) or below (C <= 0)"
            )),
        }
    }
}

/// A unilateral constraint as declared: its side and restitution coefficient.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Unilateral {
    pub side: Side,
    /// e in [0, 1]: the normal velocity after an impact is -e times the one before.
    pub restitution: f64,
}

/// A unilateral row of a compiled system.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UnilateralRow {
    /// Its row in the stacked constraint vector.
    pub row: usize,
    /// The declared constraint it is (its index among the system's declarations).
    pub constraint: usize,
    pub side: Side,
    pub restitution: f64,
}

impl SystemBuilder {
    /// Make the constraint declared last unilateral: it holds only `side` of C = 0 and
    /// lands with restitution coefficient `restitution` (see the module documentation).
    /// Only scalar constraints can be unilateral: expressions, distances and Rust constraints
    /// traced into expressions (see [`SystemBuilder::holonomic`]).
    ///
    /// ```
    /// use bead::model::{Side, SystemBuilder};
    /// let mut b = SystemBuilder::new(&[0.0, -9.81]);
    /// b.particle("ball", 1.0, &[0.0, 1.0], &[0.0, 0.0])?;
    /// b.constraint_expr("ball.x^2 + ball.y^2 - 1")?; // on or outside the unit circle
    /// b.unilateral(Side::Above, 0.5)?;
    /// let system = b.build()?;
    /// assert_eq!(system.unilateral().len(), 1);
    /// assert!(b_err().is_err());
    /// fn b_err() -> Result<(), bead::model::ModelError> {
    ///     let mut b = SystemBuilder::new(&[0.0, -9.81]);
    ///     b.particle("ball", 1.0, &[0.0, 1.0], &[0.0, 0.0])?;
    ///     b.constraint_expr("ball.y - 1")?;
    ///     b.unilateral(Side::Below, 1.5)?; // e must be in [0, 1]
    ///     Ok(())
    /// }
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn unilateral(&mut self, side: Side, restitution: f64) -> Result<&mut Self, ModelError> {
        let Some(index) = self.constraints.len().checked_sub(1) else {
            return Err(ModelError::Unilateral(
                "no constraint declared yet to make unilateral".into(),
            ));
        };
        let name = &self.constraints[index].0;
        match &self.constraints[index].1 {
            ConstraintSpec::Expression(..)
            | ConstraintSpec::Distance { .. }
            | ConstraintSpec::Custom(_, _, Ok(_)) => {}
            ConstraintSpec::Custom(_, _, Err(why)) => {
                return Err(ModelError::Unilateral(format!(
                    "{name}: a Rust constraint can be unilateral only when it is traced into an \
                     expression, and this one keeps dual numbers ({why})"
                )));
            }
            ConstraintSpec::Pin { .. } => {
                return Err(ModelError::Unilateral(format!(
                    "{name}: only a scalar constraint (an expression, a distance or a traced \
                     Rust constraint) can be unilateral"
                )));
            }
        }
        if !(0.0..=1.0).contains(&restitution) {
            return Err(ModelError::Unilateral(format!(
                "{name}: the restitution coefficient must be between 0 and 1, got {}",
                crate::readable(restitution)
            )));
        }
        if self.unilateral.iter().any(|(i, _)| *i == index) {
            return Err(ModelError::Unilateral(format!(
                "{name} is unilateral already"
            )));
        }
        self.unilateral
            .push((index, Unilateral { side, restitution }));
        Ok(self)
    }
}

impl System {
    /// The unilateral rows (see [`SystemBuilder::unilateral`]), in row order.
    pub fn unilateral(&self) -> &[UnilateralRow] {
        &self.unilateral
    }

    /// This system without the declared constraints `drop` (indices among the
    /// declarations), compiled again: the equations of motion while those rows are detached.
    /// The other rows keep their order; the particles, forces, parameters and initial state
    /// are the same.
    pub(crate) fn without_constraints(&self, drop: &[usize]) -> Result<System, ModelError> {
        let mut declared = (*self.declared).clone();
        let mut new_index = Vec::with_capacity(declared.constraints.len());
        let mut kept = Vec::with_capacity(declared.constraints.len());
        for (i, constraint) in declared.constraints.drain(..).enumerate() {
            if drop.contains(&i) {
                new_index.push(None);
            } else {
                new_index.push(Some(kept.len()));
                kept.push(constraint);
            }
        }
        declared.constraints = kept;
        declared.unilateral = declared
            .unilateral
            .iter()
            .filter_map(|&(i, u)| new_index[i].map(|j| (j, u)))
            .collect();
        compile(Arc::new(declared))
    }
}
