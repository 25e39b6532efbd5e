//! The vectors whose collapse makes a formulation singular, as the run's regularity monitor
//! sees them.
//!
//! - Implicit form: row i is the gradient J_i = dC_i/dx over the coordinates C_i reads. Where
//!   it vanishes (a cusp or a self-crossing of the curve) the constraint force
//!   (J W J^T)^-1 (...) is undefined, and near it the level set C_i = C_i(x) through a
//!   slightly drifted state may belong to another branch.
//! - Parametric form: row j is the column dx/dq_j over all particle coordinates. Where it
//!   vanishes the mass matrix M = J^T m J loses rank in q_j (a cusp of the parametrization).
//!
//! Rows have a fixed sparse structure; [`Gradients::row`] gives the current values.

/// Gradient rows with a fixed structure, refilled by [`super::Formulation::observe`].
#[derive(Clone, Debug, Default)]
pub struct Gradients {
    /// Row r owns entries start[r]..start[r + 1] of `values` (rows + 1)
    pub(crate) start: Vec<usize>,
    /// The vectors' entries (nnz)
    pub(crate) values: Vec<f64>,
    /// How far the state is off row r's constraint, |C_r| / |J_r| (rows); 0 for the
    /// parametric form, which cannot leave its curve.
    pub(crate) offset: Vec<f64>,
    /// Whether `values` are kept: a run that watches no row (a chain, a cloth) reads only
    /// the offsets, and drops the values ([`Gradients::drop_values`]).
    pub(crate) values_kept: bool,
}

impl Gradients {
    /// Rows with the given entry counts.
    pub(crate) fn with_rows(counts: impl Iterator<Item = usize>) -> Self {
        let mut start = vec![0];
        for count in counts {
            start.push(start.last().copied().unwrap_or(0) + count);
        }
        let nnz = start.last().copied().unwrap_or(0);
        let rows = start.len() - 1;
        Gradients {
            start,
            values: vec![0.0; nnz],
            offset: vec![0.0; rows],
            values_kept: true,
        }
    }

    /// Keep the offsets only: the rows' entries are neither stored nor copied from now on
    /// (reading a row then panics rather than give a stale value).
    pub(crate) fn drop_values(&mut self) {
        self.values = Vec::new();
        self.values_kept = false;
    }

    /// The number of entries of all rows, kept or not.
    pub(crate) fn n_entries(&self) -> usize {
        self.start.last().copied().unwrap_or(0)
    }

    /// Number of rows.
    pub fn n_rows(&self) -> usize {
        self.start.len().saturating_sub(1)
    }

    /// The entries of row `r`.
    pub fn row(&self, r: usize) -> &[f64] {
        &self.values[self.start[r]..self.start[r + 1]]
    }

    /// How far the state is off row `r`'s constraint (0 for the parametric form).
    pub fn offset(&self, r: usize) -> f64 {
        self.offset[r]
    }
}

/// Everything the run's monitors read about one state, filled by one evaluation
/// ([`super::Formulation::observe`]).
#[derive(Clone, Debug, Default)]
pub struct Observation {
    /// Particle positions (n_coords)
    pub x: Vec<f64>,
    /// Particle velocities (n_coords)
    pub xdot: Vec<f64>,
    /// The system's implicit constraints C(x, t) (m), evaluated for both forms
    pub constraints: Vec<f64>,
    /// The formulation's gradient rows (see [`Gradients`])
    pub gradients: Gradients,
}

impl Observation {
    /// max_i |C_i|, NaN if any is NaN; 0 without constraints.
    pub fn constraint_error(&self) -> f64 {
        crate::linalg::max_abs(&self.constraints)
    }
    /// max_i |C_i| / |grad C_i|: how far the state is off the constraints to first order, in
    /// length units whatever C's units (0 for the parametric form, which cannot leave its
    /// curve); NaN if any is NaN.
    pub fn constraint_distance(&self) -> f64 {
        crate::linalg::max_abs(&self.gradients.offset)
    }
}

/// The result of a search for a singular point ([`super::Formulation::locate_singular_point`]).
#[derive(Clone, Debug, PartialEq)]
pub struct SingularSearch {
    /// Where the search ended, in the row's variables ([`super::Formulation::row_variables`]).
    pub point: Vec<f64>,
    /// |g(point)| / |g(start)|: below 1e-6 or so when a point where g vanishes was found.
    pub reduction: f64,
    /// |g(point)| itself.
    pub residual: f64,
    /// The constraint's value C at the point (0 for a column of the parametric map, whose
    /// points all lie on the curve): a singular point of the curve has C = 0 there; a
    /// critical point of C off the curve (the centre of an ellipse) is harmless.
    pub value: f64,
}
