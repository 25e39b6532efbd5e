//! Output sinks and run records: what a run leaves behind.
//!
//! - [`CsvTrace`]: a [`Sink`](crate::simulate::Sink) that writes one CSV row per recorded
//!   sample (time, particle positions and velocities, energy, constraint error and, for the
//!   parametric form, q and qdot; optionally the constraint forces).
//! - [`Summary`]: the figures of a run ([`RunStats`](crate::simulate::RunStats)) as a
//!   serializable record with a fixed set of keys, written as JSON by `bead run --json`.
//! - [`Trajectory`]: a [`Sink`](crate::simulate::Sink) that keeps every sample in memory, in
//!   flat vectors (the Python package's arrays, a sweep member's trajectory).
//!
//! Plots and HTML reports live in the separate crate `bead-report`, so that the library does
//! not depend on plotting.
//!
//! The CSV trace and the summary format numbers exactly: a CSV field or JSON number reads back to the same `f64`, so
//! two runs of the same scene give byte-identical files.

mod csv;
mod summary;
mod trajectory;

pub use csv::{constraint_force_header, trace_header, CsvTrace};
pub use summary::{CoordinateStates, EventTimes, ParticleState, ParticleStates, Summary};
pub use trajectory::Trajectory;
