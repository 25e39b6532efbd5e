//! The oracle suite's shared half (tests only): systems whose answers bead did not compute,
//! their references (closed forms here, numeric ones from `tests/oracle/make_references.py`),
//! the run every front end is compared with, and the checks:
//!
//! - (a) the error at every recorded time against the reference, bounded by the method's
//!   order ([`checks::convergence`], [`checks::within`]);
//! - (b) each row's numbers belong to one state ([`rows::check_consistent`]);
//! - (c) every front end prints the same numbers, bit for bit ([`rows::Row::same_bits`]).
//!
//! [`matrix`] says which system, method, integrator and step each check runs at, and
//! [`listing`] what the suite covers (docs/oracle.md). The tests live beside the front ends:
//! `tests/library.rs` here, `crates/bead-cli/tests/oracle.rs`, `crates/bead-viewer/tests/
//! oracle.rs` and `crates/bead-py/tests/test_oracle.py`.

pub mod checks;
pub mod elliptic;
pub mod harness;
pub mod listing;
pub mod matrix;
pub mod reference;
pub mod rows;
pub mod run;
pub mod summary;
pub mod systems;

use std::path::PathBuf;

pub use rows::Row;
pub use run::{Outcome, Spec};
pub use systems::System;

/// The repository's root.
pub fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()
        .expect("the repository root")
}
