//! Output sinks and run reports: what a run leaves behind.
//!
//! - [`CsvTrace`]: a [`Sink`](crate::simulate::Sink) that writes one CSV row per recorded
//!   sample (time, particle positions and velocities, energy, constraint error and, for the
//!   parametric form, q and qdot).
//! - [`Summary`]: the figures of a run ([`RunStats`](crate::simulate::RunStats)) as a
//!   serializable record with a fixed set of keys, written as JSON by `bead run --json`.
//!
//! - [`plot`]: figures as PNG or SVG files, and bounded-memory decimation of long series.
//! - [`report`]: a [`Sink`](crate::simulate::Sink) that records a run's series in bounded
//!   memory, period detection, and the HTML report of a set of runs with its plots.
//!
//! The CSV trace and the summary format numbers exactly: a CSV field or JSON number reads back to the same `f64`, so
//! two runs of the same scene give byte-identical files.

mod csv;
pub mod plot;
pub mod report;
mod summary;

pub use csv::{trace_header, CsvTrace};
pub use summary::{CoordinateStates, ParticleState, ParticleStates, Summary};
