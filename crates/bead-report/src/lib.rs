//! bead-report: plots and HTML reports of [`bead`] runs.
//!
//! The physics library `bead` writes what every front end needs from a run (the CSV trace and
//! the JSON summary, in `bead::output`); this crate adds what only reports need, with their
//! heavy dependencies (plotters, png and an embedded 750 KB font). The physics library does
//! not depend on it, so a library user compiles the physics only.
//!
//! - [`plot`]: figures as PNG or SVG files, and bounded-memory decimation of long series.
//! - [`report`]: a [`Sink`](bead::simulate::Sink) that records a run's series in bounded
//!   memory, period detection, and the HTML report of a set of runs with its plots.
//!
//! It uses only the public API of `bead`. The `bead` command line uses it for
//! `bead compare --report` and `bead plot`.
#![forbid(unsafe_code)]

pub mod plot;
pub mod report;
