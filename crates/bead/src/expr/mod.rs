//! Expressions: parsing with positions, exact symbolic differentiation, and compilation to a
//! flat tape that evaluates without allocating.
//!
//! An [`Expr`] is an immutable, cheaply clonable expression DAG over numbered variables
//! (`Var(k)` reads slot `k` of the variable vector handed to the evaluator). What a slot means
//! is the caller's business: the model numbers particle coordinates, velocities and time; the
//! parametric map numbers q, qdot and time. Names are resolved at parse time by a callback, so
//! scene parameters become constants and particle coordinates become variables.
//!
//! Derivatives are exact and symbolic ([`Expr::derivative`]), simplified as they are built, and
//! computed once at load time. [`Tape::compile`] then shares common subexpressions across all
//! outputs and produces straight-line code.
//!
//! ```
//! use bead::expr::{parse, Resolved, Tape};
//! // x^2 + 100 y over variables x = slot 0, y = slot 1
//! let c = parse("x^2 + 100*y", &|name: &str| match name {
//!     "x" => Ok(Resolved::Var(0)),
//!     "y" => Ok(Resolved::Var(1)),
//!     _ => Err(format!("unknown name `{name}`")),
//! })
//! .unwrap();
//! let dcdx = c.derivative(0);
//! assert_eq!(dcdx.eval(&[3.0, 0.0]), 6.0);
//! let tape = Tape::compile(&[c, dcdx]);
//! let mut scratch = vec![0.0; tape.n_slots()];
//! let mut out = [0.0; 2];
//! tape.eval(&[3.0, -0.09], &mut scratch, &mut out);
//! assert!((out[0] - 0.0).abs() < 1e-12 && out[1] == 6.0);
//! ```

mod ast;
mod diff;
mod display;
mod jit;
mod mathml;
mod parse;
mod tape;

pub(crate) use ast::same_structure;
pub(crate) use ast::{pow_const_f64, reads_any, share, unary_f64};
pub use ast::{Expr, Func};
pub(crate) use diff::gradients;
pub use jit::{
    jit_enabled, set_jit_enabled, with_forced_jit_failure, with_jit, NativeStatus, NativeSummary,
    MAX_NATIVE_INSTRUCTIONS, VECTOR_LANES,
};
pub use mathml::escape as mathml_escape;
pub use parse::{is_identifier, name_spans, parse, ExprError, Resolved, Span, MAX_DEPTH};
pub use tape::Tape;
pub(crate) use tape::{Sym, TapeBuilder};

#[cfg(test)]
pub(crate) mod testutil;
