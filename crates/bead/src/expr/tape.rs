//! Straight-line compiled form. (Skeleton.)
use super::Expr;

/// Straight-line code for several outputs with common subexpressions shared.
#[derive(Clone, Debug)]
pub struct Tape {}

impl Tape {
    /// Compile `outputs`; equal subexpressions (structurally) are computed once.
    pub fn compile(outputs: &[Expr]) -> Tape { let _ = outputs; todo!() }
    /// Length of the scratch buffer [`Tape::eval`] needs.
    pub fn n_slots(&self) -> usize { todo!() }
    /// Number of outputs.
    pub fn n_outputs(&self) -> usize { todo!() }
    /// Number of instructions (for `bead check` and benchmarks).
    pub fn n_instructions(&self) -> usize { todo!() }
    /// Evaluate all outputs. Allocation-free. `vars` must cover every slot the outputs read,
    /// `scratch.len() >= n_slots()`, `out.len() == n_outputs()`.
    pub fn eval(&self, vars: &[f64], scratch: &mut [f64], out: &mut [f64]) { let _ = (vars, scratch, out); todo!() }
}
