//! The nonzero pattern of a symmetric matrix, fixed once.

/// The pattern of a symmetric m x m matrix: its upper triangle by columns (compressed sparse
/// columns), rows sorted within a column, every diagonal entry present (last in its column).
/// Values live in a flat array in this order; entry number `slot` of the pattern is the
/// value's index. Entries that are numerically zero in some evaluation stay in the pattern,
/// so that the pattern, and all the symbolic work done on it, never changes.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SymmetricPattern {
    dim: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
}

impl SymmetricPattern {
    /// The pattern with the diagonal and the entries (i, j) of `pairs` (either order;
    /// duplicates allowed), mirrored into the upper triangle.
    pub fn new(dim: usize, pairs: impl IntoIterator<Item = (usize, usize)>) -> Self {
        // (column, row) with row <= column
        let mut entries: Vec<(usize, usize)> = pairs
            .into_iter()
            .map(|(i, j)| (i.max(j), i.min(j)))
            .chain((0..dim).map(|i| (i, i)))
            .collect();
        entries.sort_unstable();
        entries.dedup();
        assert!(
            entries.last().is_none_or(|&(j, _)| j < dim),
            "index out of range"
        );
        let mut col_ptr = vec![0; dim + 1];
        for &(j, _) in &entries {
            col_ptr[j + 1] += 1;
        }
        for j in 0..dim {
            col_ptr[j + 1] += col_ptr[j];
        }
        SymmetricPattern {
            dim,
            col_ptr,
            row_idx: entries.into_iter().map(|(_, i)| i).collect(),
        }
    }

    /// The full (dense) pattern of an m x m matrix: slot of (i, j), i <= j, is j (j + 1) / 2 + i.
    pub fn dense(dim: usize) -> Self {
        SymmetricPattern::new(dim, (0..dim).flat_map(|j| (0..j).map(move |i| (i, j))))
    }

    /// m
    pub fn dim(&self) -> usize {
        self.dim
    }
    /// Number of stored entries (upper triangle with the diagonal).
    pub fn nnz(&self) -> usize {
        self.row_idx.len()
    }
    /// Column pointers (m + 1).
    pub fn col_ptr(&self) -> &[usize] {
        &self.col_ptr
    }
    /// Row indices (nnz), sorted within each column.
    pub fn row_idx(&self) -> &[usize] {
        &self.row_idx
    }
    /// (slot, row) of the entries of column j, rows ascending, the diagonal last.
    pub fn column(&self, j: usize) -> impl Iterator<Item = (usize, &usize)> {
        let range = self.col_ptr[j]..self.col_ptr[j + 1];
        range.clone().zip(&self.row_idx[range])
    }
    /// The slot of entry (i, j) (either order), if it is in the pattern.
    pub fn slot(&self, i: usize, j: usize) -> Option<usize> {
        let (row, column) = (i.min(j), i.max(j));
        let start = self.col_ptr[column];
        self.row_idx[start..self.col_ptr[column + 1]]
            .binary_search(&row)
            .ok()
            .map(|k| start + k)
    }
    /// The slot of diagonal entry (i, i).
    pub fn diagonal_slot(&self, i: usize) -> usize {
        self.col_ptr[i + 1] - 1
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn upper_triangle_by_columns_with_the_diagonal() {
        let p = SymmetricPattern::new(4, [(1, 0), (0, 1), (3, 1), (2, 2)]);
        assert_eq!(p.col_ptr(), &[0, 1, 3, 4, 6]);
        assert_eq!(p.row_idx(), &[0, 0, 1, 2, 1, 3]);
        assert_eq!(p.slot(1, 3), Some(4));
        assert_eq!(p.slot(3, 1), Some(4));
        assert_eq!(p.slot(0, 3), None);
        assert_eq!(
            (0..4).map(|i| p.diagonal_slot(i)).collect::<Vec<_>>(),
            [0, 2, 3, 5]
        );
        let dense = SymmetricPattern::dense(3);
        assert_eq!(dense.nnz(), 6);
        assert_eq!(dense.slot(1, 2), Some(2 * 3 / 2 + 1));
    }
}
