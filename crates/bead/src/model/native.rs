//! The built-in constraint kinds (distance, pin) evaluated by direct code: the rows of every
//! chain and cloth, where the general tape's interpretation overhead is most of a step.
//!
//! Each row also has a symbolic form (an [`super::constraint::ExprRow`], for `bead check`,
//! the singular-point search and messages), built on demand from the same parameters by
//! [`NativeRow::symbolic`] (a chain of 10^5 rods keeps no expression trees); this is the same
//! function, written out:
//!
//! ```text
//! distance(a, b) = L:  d = x_a - x_b,  u = v_a - v_b
//!     C = (|d|^2 - L^2) / (2 L)    dC/dx_a = d / L = -dC/dx_b    Cdot = d.u / L
//!     bias = Cddot - J a = |u|^2 / L
//! pin (one row per axis):  C = x_k - p_k,  dC/dx_k = 1,  Cdot = v_k,  bias = 0
//! ```
//!
//! (b may be a fixed point: then u = v_a and only a's coordinates have entries.)

use super::constraint::ExprRow;
use crate::expr::Expr;

/// C = (|x_a - x_b|^2 - L^2) / (2L) as an expression over the coordinates (x_b the fixed
/// point `anchor` when `b` is `None`); `a` and `b` are first coordinates.
pub(crate) fn distance_expression(
    dim: usize,
    a: usize,
    b: Option<usize>,
    anchor: &[f64],
    length: f64,
) -> Expr {
    // Zero on the rod, |grad C| = |d|/L = 1 there, and smooth even where |d| = 0.
    let squared = (0..dim)
        .map(|axis| {
            let end = match b {
                Some(b) => Expr::var(b + axis),
                None => Expr::constant(anchor[axis]),
            };
            let d = Expr::var(a + axis) - end;
            &d * &d
        })
        .fold(Expr::constant(0.0), |acc, s| acc + s);
    (squared - length * length) / (2.0 * length)
}

/// A row evaluated natively. Coordinates are indices into x. A distance row's Jacobian
/// entries are its coordinates in order: x_a's `dim` first, then x_b's, or x_b's first when
/// `b_first` (b's particle comes first). Kept small: a chain holds one per rod.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum NativeRow {
    Distance {
        dim: u8,
        /// Whether x_b's entries come before x_a's
        b_first: bool,
        /// First coordinate of particle a
        a: usize,
        /// First coordinate of particle b, or `None` for a fixed point
        b: Option<usize>,
        /// The fixed point (when b is `None`)
        anchor: [f64; 3],
        length: f64,
    },
    Pin {
        coordinate: usize,
        anchor: f64,
    },
}

impl NativeRow {
    /// The distance row between distinct particles with first coordinates `a` and `b` (or
    /// `a` and the fixed point `anchor`): its Jacobian entries in coordinate order, as the
    /// symbolic row's gradient lists them.
    pub(crate) fn distance_row(
        dim: usize,
        a: usize,
        b: Option<usize>,
        anchor: &[f64],
        length: f64,
    ) -> NativeRow {
        debug_assert!(b != Some(a), "a rod needs two particles");
        debug_assert!((1..=3).contains(&dim), "dimension {dim}");
        let mut fixed = [0.0; 3];
        if b.is_none() {
            fixed[..dim].copy_from_slice(&anchor[..dim]);
        }
        NativeRow::Distance {
            dim: dim as u8,
            // Columns are sorted coordinates.
            b_first: b.is_some_and(|b| b < a),
            a,
            b,
            anchor: fixed,
            length,
        }
    }

    /// The row's expression C(x).
    pub(crate) fn expression(&self) -> Expr {
        match self {
            NativeRow::Distance {
                dim,
                a,
                b,
                anchor,
                length,
                ..
            } => distance_expression((*dim).into(), *a, *b, anchor, *length),
            NativeRow::Pin { coordinate, anchor } => Expr::var(*coordinate) - *anchor,
        }
    }

    /// The row's symbolic form over slots [x (n_coords), v (n_coords), t], built now.
    pub(crate) fn symbolic(&self, n_coords: usize) -> ExprRow {
        ExprRow::new(self.expression(), n_coords)
    }

    /// The coordinates the row reads, in the order of its Jacobian entries.
    pub(crate) fn columns(&self) -> Vec<usize> {
        match self {
            NativeRow::Distance { dim, a, b, .. } => {
                let dim = usize::from(*dim);
                let mut columns: Vec<usize> = (*a..*a + dim).collect();
                if let Some(b) = b {
                    columns.extend(*b..*b + dim);
                }
                columns.sort_unstable();
                columns
            }
            NativeRow::Pin { coordinate, .. } => vec![*coordinate],
        }
    }

    /// d = x_a - x_b (or minus the anchor) and u = v_a - v_b (v_a) in `D` dimensions.
    #[inline(always)]
    fn separation<const D: usize>(
        a: usize,
        b: Option<usize>,
        anchor: &[f64; 3],
        x: &[f64],
        v: Option<&[f64]>,
    ) -> ([f64; D], [f64; D]) {
        let (mut d, mut u) = ([0.0; D], [0.0; D]);
        for axis in 0..D {
            let (xb, vb) = match b {
                Some(b) => (x[b + axis], v.map_or(0.0, |v| v[b + axis])),
                None => (anchor[axis], 0.0),
            };
            d[axis] = x[a + axis] - xb;
            u[axis] = v.map_or(0.0, |v| v[a + axis]) - vb;
        }
        (d, u)
    }

    /// A distance row in `D` dimensions: C = (|d|^2 - L^2) / (2L), with the Jacobian entries
    /// d / L (for a) and -d / L (for b) written when `jacobian` is given, and (Cdot, bias) =
    /// (d.u / L, |u|^2 / L) when `v` is.
    #[inline(always)]
    fn distance<const D: usize>(
        &self,
        x: &[f64],
        v: Option<&[f64]>,
        jacobian: Option<&mut [f64]>,
    ) -> (f64, f64, f64) {
        let NativeRow::Distance {
            a,
            b,
            anchor,
            length,
            b_first,
            ..
        } = self
        else {
            unreachable!("a distance row")
        };
        let (d, u) = Self::separation::<D>(*a, *b, anchor, x, v);
        let inverse_length = 1.0 / length;
        if let Some(jacobian) = jacobian {
            let (entries_a, entries_b) = if *b_first { (D, 0) } else { (0, D) };
            for axis in 0..D {
                let g = d[axis] * inverse_length;
                jacobian[entries_a + axis] = g;
                if b.is_some() {
                    jacobian[entries_b + axis] = -g;
                }
            }
        }
        let (mut dd, mut du, mut uu) = (0.0, 0.0, 0.0);
        for axis in 0..D {
            dd += d[axis] * d[axis];
            du += d[axis] * u[axis];
            uu += u[axis] * u[axis];
        }
        (
            (dd - length * length) * (0.5 * inverse_length),
            du * inverse_length,
            uu * inverse_length,
        )
    }

    /// [`NativeRow::distance`] in the row's own dimension.
    #[inline(always)]
    fn distance_any(
        &self,
        dim: u8,
        x: &[f64],
        v: Option<&[f64]>,
        jacobian: Option<&mut [f64]>,
    ) -> (f64, f64, f64) {
        debug_assert!((1..=3).contains(&dim), "dimension {dim}");
        match dim {
            1 => self.distance::<1>(x, v, jacobian),
            2 => self.distance::<2>(x, v, jacobian),
            _ => self.distance::<3>(x, v, jacobian),
        }
    }

    /// C, Cdot, bias and the row's Jacobian entries (in the row's column order) at (x, v).
    #[inline]
    pub(crate) fn evaluate(&self, x: &[f64], v: &[f64], jacobian: &mut [f64]) -> (f64, f64, f64) {
        match self {
            NativeRow::Distance { dim, .. } => self.distance_any(*dim, x, Some(v), Some(jacobian)),
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
            NativeRow::Distance { dim, .. } => self.distance_any(*dim, x, None, Some(jacobian)).0,
            NativeRow::Pin { coordinate, anchor } => {
                jacobian[0] = 1.0;
                x[*coordinate] - anchor
            }
        }
    }

    /// C and |J|^2 at x, without writing J: the value [`NativeRow::gradient`] returns and
    /// the sum of its entries' squares in their order (the same bits: (-g)^2 = g^2, and a
    /// sum of squares is the same from 0 or from -0).
    #[inline]
    pub(crate) fn value_and_squared_gradient(&self, x: &[f64]) -> (f64, f64) {
        match self {
            NativeRow::Distance { dim, .. } => match dim {
                1 => self.distance_squared_gradient::<1>(x),
                2 => self.distance_squared_gradient::<2>(x),
                _ => self.distance_squared_gradient::<3>(x),
            },
            NativeRow::Pin { coordinate, anchor } => (x[*coordinate] - anchor, 1.0),
        }
    }

    /// A distance row's C = (|d|^2 - L^2) / (2L) and |J|^2 = sum over its entries
    /// (+-d_k / L)^2, in entry order: the a side's and the b side's squares are the same
    /// numbers, so the order of the sides does not matter.
    #[inline(always)]
    fn distance_squared_gradient<const D: usize>(&self, x: &[f64]) -> (f64, f64) {
        let NativeRow::Distance {
            a,
            b,
            anchor,
            length,
            ..
        } = self
        else {
            unreachable!("a distance row")
        };
        let (d, _) = Self::separation::<D>(*a, *b, anchor, x, None);
        let inverse_length = 1.0 / length;
        let mut squared = 0.0;
        for _side in 0..if b.is_some() { 2 } else { 1 } {
            for axis in d {
                let g = axis * inverse_length;
                squared += g * g;
            }
        }
        let mut dd = 0.0;
        for axis in d {
            dd += axis * axis;
        }
        ((dd - length * length) * (0.5 * inverse_length), squared)
    }

    /// C at x.
    #[inline]
    pub(crate) fn value(&self, x: &[f64]) -> f64 {
        match self {
            NativeRow::Distance { dim, .. } => self.distance_any(*dim, x, None, None).0,
            NativeRow::Pin { coordinate, anchor } => x[*coordinate] - anchor,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// C and |J|^2 without J give the bits of C and the sum of squares of J's entries in
    /// their order: rods with either particle first, anchored rods, 2D and 3D, pins.
    #[test]
    fn value_and_squared_gradient_match_the_gradient() {
        let x = [0.3, -1.7, 2.25, 1e-3, 4.0, -0.6, 0.1, 7.5, -3.3];
        let rows = [
            NativeRow::distance_row(2, 0, Some(4), &[], 1.3),
            NativeRow::distance_row(2, 4, Some(0), &[], 1.3),
            NativeRow::distance_row(2, 2, None, &[0.5, -0.25], 0.7),
            NativeRow::distance_row(3, 0, Some(6), &[], 2.9),
            NativeRow::distance_row(3, 6, Some(3), &[], 0.31),
            NativeRow::distance_row(3, 3, None, &[1.0, 2.0, -3.0], 5.0),
            NativeRow::Pin {
                coordinate: 5,
                anchor: 0.4,
            },
        ];
        for row in &rows {
            let mut jacobian = vec![0.0; row.columns().len()];
            let value = row.gradient(&x, &mut jacobian);
            let squared: f64 = jacobian.iter().map(|g| g * g).sum();
            let (got_value, got_squared) = row.value_and_squared_gradient(&x);
            assert_eq!(got_value.to_bits(), value.to_bits(), "{row:?}");
            assert_eq!(got_squared.to_bits(), squared.to_bits(), "{row:?}");
            assert!(squared > 0.0);
        }
    }
}
