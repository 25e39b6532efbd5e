//! The built-in constraint kinds (distance, pin) evaluated by direct code: the rows of every
//! chain and cloth, where the general tape's interpretation overhead is most of a step.
//!
//! Each row is also compiled symbolically (an [`super::constraint::ExprRow`], for `bead
//! check`, the singular-point search and messages); this is the same function, written out:
//!
//! ```text
//! distance(a, b) = L:  d = x_a - x_b,  u = v_a - v_b
//!     C = (|d|^2 - L^2) / (2 L)    dC/dx_a = d / L = -dC/dx_b    Cdot = d.u / L
//!     bias = Cddot - J a = |u|^2 / L
//! pin (one row per axis):  C = x_k - p_k,  dC/dx_k = 1,  Cdot = v_k,  bias = 0
//! ```
//!
//! (b may be a fixed point: then u = v_a and only a's coordinates have entries.)

/// A row evaluated natively. Coordinates are indices into x; `entries_a[axis]` is the
/// position of x_a's coordinate `axis` among the row's Jacobian entries (and likewise b).
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum NativeRow {
    Distance {
        dim: usize,
        /// First coordinate of particle a
        a: usize,
        /// First coordinate of particle b, or `None` for a fixed point
        b: Option<usize>,
        /// The fixed point (when b is `None`)
        anchor: [f64; 3],
        length: f64,
        entries_a: [usize; 3],
        entries_b: [usize; 3],
    },
    Pin {
        coordinate: usize,
        anchor: f64,
    },
}

impl NativeRow {
    /// d = x_a - x_b (or minus the anchor) and u = v_a - v_b (v_a), per axis.
    #[inline]
    fn separation(&self, x: &[f64], v: Option<&[f64]>) -> ([f64; 3], [f64; 3]) {
        let NativeRow::Distance {
            dim, a, b, anchor, ..
        } = self
        else {
            unreachable!("separation of a distance row")
        };
        let (mut d, mut u) = ([0.0; 3], [0.0; 3]);
        for axis in 0..*dim {
            let (xb, vb) = match b {
                Some(b) => (x[b + axis], v.map_or(0.0, |v| v[b + axis])),
                None => (anchor[axis], 0.0),
            };
            d[axis] = x[a + axis] - xb;
            u[axis] = v.map_or(0.0, |v| v[a + axis]) - vb;
        }
        (d, u)
    }

    /// A distance row's C = (|d|^2 - L^2) / (2L) from its separation d, with its Jacobian
    /// entries d / L (for a) and -d / L (for b) written.
    #[inline]
    fn distance_value_and_gradient(&self, d: &[f64; 3], jacobian: &mut [f64]) -> f64 {
        let NativeRow::Distance {
            dim,
            b,
            length,
            entries_a,
            entries_b,
            ..
        } = self
        else {
            unreachable!("a distance row")
        };
        let mut dd = 0.0;
        for axis in 0..*dim {
            dd += d[axis] * d[axis];
            jacobian[entries_a[axis]] = d[axis] / length;
            if b.is_some() {
                jacobian[entries_b[axis]] = -d[axis] / length;
            }
        }
        (dd - length * length) / (2.0 * length)
    }

    /// C, Cdot, bias and the row's Jacobian entries (in the row's column order) at (x, v).
    #[inline]
    pub(crate) fn evaluate(&self, x: &[f64], v: &[f64], jacobian: &mut [f64]) -> (f64, f64, f64) {
        match self {
            NativeRow::Distance { dim, length, .. } => {
                let (d, u) = self.separation(x, Some(v));
                let c = self.distance_value_and_gradient(&d, jacobian);
                let (mut du, mut uu) = (0.0, 0.0);
                for axis in 0..*dim {
                    du += d[axis] * u[axis];
                    uu += u[axis] * u[axis];
                }
                (c, du / length, uu / length)
            }
            NativeRow::Pin { coordinate, anchor } => {
                jacobian[0] = 1.0;
                (x[*coordinate] - anchor, v[*coordinate], 0.0)
            }
        }
    }

    /// C and the row's Jacobian entries at x.
    #[inline]
    pub(crate) fn gradient(&self, x: &[f64], jacobian: &mut [f64]) -> f64 {
        match self {
            NativeRow::Distance { .. } => {
                let (d, _) = self.separation(x, None);
                self.distance_value_and_gradient(&d, jacobian)
            }
            NativeRow::Pin { coordinate, anchor } => {
                jacobian[0] = 1.0;
                x[*coordinate] - anchor
            }
        }
    }

    /// C at x.
    #[inline]
    pub(crate) fn value(&self, x: &[f64]) -> f64 {
        match self {
            NativeRow::Distance { dim, length, .. } => {
                let (d, _) = self.separation(x, None);
                let dd: f64 = d[..*dim].iter().map(|c| c * c).sum();
                (dd - length * length) / (2.0 * length)
            }
            NativeRow::Pin { coordinate, anchor } => x[*coordinate] - anchor,
        }
    }
}
