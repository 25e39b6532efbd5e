//! Reports of a set of runs: a recording [`Sink`] that keeps every series in bounded memory,
//! period detection, the comparison table and the HTML report with its plots.
//!
//! ```text
//! Recorder (a Sink, one per run) --finish--> Recording
//! Recording + RunStats + names ----------->  ReportRun
//! [ReportRun] + title -------------------->  Report --write_report(dir)--> report.html + plots
//! ```
//!
//! A [`Recorder`] keeps at most a given number of min/max buckets (by default
//! [`plot::DEFAULT_BUCKETS`], 2000 points) per time series and as many trajectory points, whatever the number of steps, and detects the
//! period from every sample it sees (not only the kept ones).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;

// Everything this module takes from the physics library, in one place.
use bead::formulation::Method;
use bead::integrate::IntegratorKind;
use bead::model::{ConstraintEval, System};
use bead::simulate::{RunStats, Sample, Sink};

use crate::plot::{
    self, Dash, Figure, HeadTail, Look, Marker, MinMaxDecimator, Panel, PlotError, Series, Style,
};

/// Detects the period of an oscillating signal from its upward zero crossings (negative to
/// non-negative), each placed by linear interpolation between the two samples around it.
///
/// The period is the mean interval between the first and the last crossing (complete cycles
/// only); it is reported only with at least two crossings and when the intervals agree to
/// [`PeriodDetector::REGULARITY`] (relative spread), so that a motion that is not periodic
/// (chaotic, or accelerating like a bead sliding down a helix) has none.
#[derive(Clone, Debug, Default)]
pub struct PeriodDetector {
    previous: Option<(f64, f64)>,
    first: f64,
    last: f64,
    crossings: u64,
    min_interval: f64,
    max_interval: f64,
    max_abs: f64,
}

impl PeriodDetector {
    /// Largest relative spread (max - min) / mean of the cycle lengths of a periodic signal.
    pub const REGULARITY: f64 = 0.05;

    pub fn new() -> Self {
        PeriodDetector {
            min_interval: f64::INFINITY,
            ..Default::default()
        }
    }

    /// Add a sample; t must increase.
    pub fn push(&mut self, t: f64, v: f64) {
        if !v.is_finite() || !t.is_finite() {
            self.previous = None;
            return;
        }
        self.max_abs = self.max_abs.max(v.abs());
        if let Some((t0, v0)) = self.previous {
            if v0 < 0.0 && v >= 0.0 {
                let crossing = t0 + (t - t0) * (-v0) / (v - v0);
                if self.crossings > 0 {
                    let interval = crossing - self.last;
                    self.min_interval = self.min_interval.min(interval);
                    self.max_interval = self.max_interval.max(interval);
                } else {
                    self.first = crossing;
                }
                self.last = crossing;
                self.crossings += 1;
            }
        }
        self.previous = Some((t, v));
    }

    /// Upward crossings seen.
    pub fn crossings(&self) -> u64 {
        self.crossings
    }

    /// Largest |v| seen.
    pub fn max_abs(&self) -> f64 {
        self.max_abs
    }

    /// The mean period over complete cycles, when the signal is periodic (see the type).
    pub fn period(&self) -> Option<f64> {
        if self.crossings < 2 {
            return None;
        }
        let mean = (self.last - self.first) / (self.crossings - 1) as f64;
        if mean > 0.0 && (self.max_interval - self.min_interval) <= Self::REGULARITY * mean {
            Some(mean)
        } else {
            None
        }
    }
}

/// A [`Sink`] that records a run for a report in bounded memory: the constraint error and the
/// relative error of the conserved energy ([`Sample::conserved_energy_error`]: |E - E0| / E_scale, or
/// |E - W - E0| / E_scale when something does work on the system and the energy ledger runs)
/// as min/max-decimated series (with and without its sign), the particle positions of the first and last samples (see
/// [`HeadTail`]), and the period of each particle velocity component from every sample.
pub struct Recorder {
    system: Arc<System>,
    constraint: MinMaxDecimator,
    /// The distance off the constraint set: the true distance to the closest point when
    /// the constraint is one scalar row on one particle's coordinates (see
    /// [`ClosestPoint`]), else the first-order estimate max_i |C_i| / |grad C_i|
    deviation: MinMaxDecimator,
    /// C and its gradient rows at a sample (for `deviation`)
    eval: ConstraintEval,
    /// The closest-point search, when the constraint set is one row on one particle.
    closest: Option<ClosestPoint>,
    /// Samples where the closest-point search did not converge (left out of `deviation`).
    closest_failures: u64,
    energy: MinMaxDecimator,
    /// (E - W - E0) / E_scale with its sign
    energy_signed: MinMaxDecimator,
    trajectory: HeadTail,
    periods: Vec<PeriodDetector>,
    /// Whether the energy series is the balance E - W (the ledger ran).
    balance: bool,
    /// The trajectory row being assembled: t, then the particle coordinates (n + 1)
    row: Vec<f64>,
    samples: u64,
}

impl Recorder {
    /// A recorder for runs of `system`, keeping at most `2 * buckets` points per series and
    /// `2 * buckets` trajectory points.
    pub fn new(system: Arc<System>, buckets: usize) -> Self {
        let n = system.n_coords();
        Recorder {
            constraint: MinMaxDecimator::new(buckets),
            deviation: MinMaxDecimator::new(buckets),
            eval: system.constraints().workspace(),
            closest: ClosestPoint::of(&system),
            closest_failures: 0,
            energy: MinMaxDecimator::new(buckets),
            energy_signed: MinMaxDecimator::new(buckets),
            trajectory: HeadTail::new(n + 1, buckets),
            periods: vec![PeriodDetector::new(); n],
            system,
            balance: false,
            row: vec![0.0; n + 1],
            samples: 0,
        }
    }

    /// What was recorded.
    pub fn recording(&self) -> Recording {
        // The first velocity component that moves (beyond round-off) and is periodic.
        let largest = self
            .periods
            .iter()
            .map(PeriodDetector::max_abs)
            .fold(0.0, f64::max);
        let period = self
            .periods
            .iter()
            .enumerate()
            .filter(|(_, p)| p.max_abs() > 1e-6 * largest)
            .find_map(|(k, p)| {
                p.period().map(|period| Period {
                    seconds: period,
                    cycles: p.crossings() - 1,
                    signal: velocity_name(&self.system, k),
                })
            });
        Recording {
            constraint_error: self.constraint.points(),
            deviation: self.deviation.points(),
            deviation_is_distance: self.closest.is_some(),
            closest_failures: self.closest_failures,
            energy_error: self.energy.points(),
            energy_change: self.energy_signed.points(),
            trajectory: self.trajectory.rows(),
            period,
            samples: self.samples,
            energy_balance: self.balance,
        }
    }
}

impl Recorder {
    /// The distance of x off the constraint set to first order, max_i |C_i(x, t)| /
    /// |grad C_i(x, t)| (the Newton step onto each row's level set C_i = 0), in length
    /// units whatever the constraint's own units; `None` without constraints or where a
    /// gradient vanishes (a singular point, where the estimate means nothing).
    fn deviation_of(&mut self, t: f64, x: &[f64]) -> Option<f64> {
        let set = self.system.constraints();
        if set.n_rows() == 0 {
            return None;
        }
        set.gradient(t, x, &mut self.eval);
        let mut distance: f64 = 0.0;
        for i in 0..set.n_rows() {
            let row = &self.eval.jacobian[set.row_entries(i)];
            let norm = row.iter().map(|j| j * j).sum::<f64>().sqrt();
            if norm.is_nan() || norm <= 0.0 {
                return None;
            }
            distance = distance.max(self.eval.value[i].abs() / norm);
        }
        Some(distance)
    }
}

/// The true distance from a particle to the constraint set C(y, t) = 0 of a single scalar
/// constraint row on that particle's coordinates (a curve in 2D, a surface in 3D): the
/// closest point y* solves
///
/// ```text
/// min |y - x|^2  subject to  C(y) = 0,
/// ```
///
/// whose Lagrange conditions are F(y, lambda) = (y - x + lambda grad C(y), C(y)) = 0. Newton's
/// method on F solves, per iteration,
///
/// ```text
/// [ I + lambda H   grad C ] [ dy      ]     [ y - x + lambda grad C ]
/// [ grad C^T       0      ] [ dlambda ] = - [ C                     ]
/// ```
///
/// with H the Hessian of C by central differences of the exact gradient (an approximate
/// Jacobian slows Newton's convergence but does not move its solution: F itself is exact).
/// It starts at (x, 0), where the first step is the first-order projection x - C grad C /
/// |grad C|^2, so it finds the closest point the first-order estimate |C| / |grad C| points
/// at, and it stops when the step is below 1e-13 of the coordinates' scale. Other
/// coordinates (other particles, if any) are held at their values.
#[derive(Clone, Debug)]
struct ClosestPoint {
    /// The particle's coordinates in x (dim of them).
    coords: Vec<usize>,
    /// Scratch: the whole state with the particle at the trial point.
    trial: Vec<f64>,
}

impl ClosestPoint {
    const MAX_ITERATIONS: usize = 60;
    const STEP_TOLERANCE: f64 = 1e-13;

    /// The search for `system`, when its constraint set is one row on the coordinates of
    /// one particle; `None` otherwise (several rows, or a row coupling particles, where the
    /// closest point is not the simple question this answers).
    fn of(system: &System) -> Option<ClosestPoint> {
        let set = system.constraints();
        if set.n_rows() != 1 {
            return None;
        }
        let dim = system.dim();
        if dim > 3 {
            return None;
        }
        let columns = set.row_columns(0);
        let particle = columns.first()? / dim;
        if columns.iter().any(|&k| k / dim != particle) {
            return None;
        }
        Some(ClosestPoint {
            coords: (particle * dim..(particle + 1) * dim).collect(),
            trial: vec![0.0; system.n_coords()],
        })
    }

    /// C and its gradient with respect to the particle's coordinates at the trial point.
    fn evaluate(
        &mut self,
        system: &System,
        t: f64,
        y: &[f64],
        eval: &mut ConstraintEval,
        gradient: &mut [f64],
    ) -> f64 {
        let set = system.constraints();
        for (k, &c) in self.coords.iter().enumerate() {
            self.trial[c] = y[k];
        }
        set.gradient(t, &self.trial, eval);
        gradient.iter_mut().for_each(|g| *g = 0.0);
        for (entry, &column) in eval.jacobian[set.row_entries(0)]
            .iter()
            .zip(set.row_columns(0))
        {
            if let Some(k) = self.coords.iter().position(|&c| c == column) {
                gradient[k] = *entry;
            }
        }
        eval.value[0]
    }

    /// The distance from the state x at time t to the closest point of the constraint
    /// set; `None` when Newton's method does not converge (or a gradient vanishes).
    fn distance(
        &mut self,
        system: &System,
        t: f64,
        x: &[f64],
        eval: &mut ConstraintEval,
    ) -> Option<f64> {
        let d = self.coords.len();
        if x.len() != self.trial.len() {
            return None;
        }
        self.trial.copy_from_slice(x);
        // A particle has at most 3 coordinates: every buffer lives on the stack (the recorder
        // runs at every step, which allocates nothing).
        let mut start = [0.0; 3];
        for (s, &c) in start.iter_mut().zip(&self.coords) {
            *s = x[c];
        }
        let start = &start[..d];
        let scale = start.iter().fold(1.0_f64, |m, v| m.max(v.abs()));
        let mut y_buffer = [0.0; 3];
        let y = &mut y_buffer[..d];
        y.copy_from_slice(start);
        let mut lambda = 0.0;
        let (mut g, mut plus, mut minus) = ([0.0; 3], [0.0; 3], [0.0; 3]);
        let (g, plus, minus) = (&mut g[..d], &mut plus[..d], &mut minus[..d]);
        // The (d + 1) x (d + 1) system, row-major, and its right-hand side.
        let n = d + 1;
        let (mut a, mut b, mut pivots) = ([0.0; 16], [0.0; 4], [0.0; 4]);
        let (a, b, pivots) = (&mut a[..n * n], &mut b[..n], &mut pivots[..n]);
        for _ in 0..Self::MAX_ITERATIONS {
            let c = self.evaluate(system, t, y, eval, g);
            if !c.is_finite() || g.iter().all(|&v| v == 0.0) || g.iter().any(|v| !v.is_finite()) {
                return None;
            }
            a.iter_mut().for_each(|v| *v = 0.0);
            // I + lambda H by central differences of the gradient.
            let h = 1e-5 * scale;
            let mut probe_buffer = [0.0; 3];
            let probe = &mut probe_buffer[..d];
            probe.copy_from_slice(y);
            for j in 0..d {
                probe[j] = y[j] + h;
                self.evaluate(system, t, probe, eval, plus);
                probe[j] = y[j] - h;
                self.evaluate(system, t, probe, eval, minus);
                probe[j] = y[j];
                for i in 0..d {
                    a[i * n + j] += lambda * (plus[i] - minus[i]) / (2.0 * h);
                }
            }
            for i in 0..d {
                for j in 0..i {
                    let mean = 0.5 * (a[i * n + j] + a[j * n + i]);
                    a[i * n + j] = mean;
                    a[j * n + i] = mean;
                }
                a[i * n + i] += 1.0;
                a[i * n + d] = g[i];
                a[d * n + i] = g[i];
                b[i] = -(y[i] - start[i] + lambda * g[i]);
            }
            b[d] = -c;
            // The library's pivoted elimination (the matrix is symmetric indefinite).
            bead::linalg::solve_general(n, a, b, pivots).ok()?;
            let step = &*b;
            for i in 0..d {
                y[i] += step[i];
            }
            lambda += step[d];
            let moved = step[..d].iter().fold(0.0_f64, |m, v| m.max(v.abs()));
            if moved <= Self::STEP_TOLERANCE * scale {
                let c = self.evaluate(system, t, y, eval, g);
                let norm = g.iter().map(|v| v * v).sum::<f64>().sqrt();
                // On the set, to the accuracy of the coordinates.
                if c.abs() / norm <= 1e-10 * scale {
                    let distance = y
                        .iter()
                        .zip(start)
                        .map(|(a, b)| (a - b) * (a - b))
                        .sum::<f64>()
                        .sqrt();
                    return Some(distance);
                }
                return None;
            }
        }
        None
    }
}

/// `bead.vx` for particle coordinate k.
fn velocity_name(system: &System, k: usize) -> String {
    let name = system.coordinate_name(k);
    match name.rsplit_once('.') {
        Some((particle, axis)) => format!("{particle}.v{axis}"),
        None => format!("d({name})/dt"),
    }
}

impl Sink for Recorder {
    fn record(&mut self, sample: &Sample) -> std::io::Result<()> {
        self.samples += 1;
        self.balance = sample.work.is_some();
        self.constraint.push(sample.t, sample.constraint_error);
        let distance = match &mut self.closest {
            Some(search) => {
                let found = search.distance(&self.system, sample.t, sample.x, &mut self.eval);
                if found.is_none() {
                    self.closest_failures += 1;
                }
                found
            }
            None => self.deviation_of(sample.t, sample.x),
        };
        if let Some(distance) = distance {
            self.deviation.push(sample.t, distance);
        }
        self.energy.push(sample.t, sample.conserved_energy_error());
        let change = sample.energy - sample.work.unwrap_or(0.0) - sample.energy_initial;
        self.energy_signed
            .push(sample.t, change / sample.energy_scale);
        // Row: t, then the particle coordinates.
        let n = sample.x.len().min(self.row.len() - 1);
        self.row[0] = sample.t;
        self.row[1..=n].copy_from_slice(&sample.x[..n]);
        self.trajectory.push(&self.row[..=n]);
        for (detector, &v) in self.periods.iter_mut().zip(sample.xdot) {
            detector.push(sample.t, v);
        }
        Ok(())
    }
}

/// A measured period.
#[derive(Clone, Debug, PartialEq)]
pub struct Period {
    /// Mean period over complete cycles (s).
    pub seconds: f64,
    /// Complete cycles measured.
    pub cycles: u64,
    /// The signal whose upward zero crossings were timed, e.g. `bead.vx`.
    pub signal: String,
}

/// The decimated series of one run.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Recording {
    /// (t, max_i |C_i|)
    pub constraint_error: Vec<(f64, f64)>,
    /// (t, distance off the constraint set) in length units: the true distance to the
    /// closest point of the constraint set when `deviation_is_distance`, else the
    /// first-order estimate max_i |C_i| / |grad C_i| (left out where a gradient vanishes or
    /// the closest-point search did not converge)
    pub deviation: Vec<(f64, f64)>,
    /// Whether `deviation` is the true distance (one scalar constraint on one particle's
    /// coordinates: a curve in 2D, a surface in 3D) rather than the first-order estimate.
    pub deviation_is_distance: bool,
    /// Samples where the closest-point search did not converge (none in practice; left
    /// out of `deviation`).
    pub closest_failures: u64,
    /// (t, |E - E0| / E_scale), or (t, |E - W - E0| / E_scale) when `energy_balance`
    pub energy_error: Vec<(f64, f64)>,
    /// The same with its sign: (t, (E - E0) / E_scale) or (t, (E - W - E0) / E_scale); above
    /// zero the run gained energy, below it lost some
    pub energy_change: Vec<(f64, f64)>,
    /// Whether `energy_error` is the error of the balance E - W (something did work on the
    /// system and the energy ledger ran) rather than of T + V.
    pub energy_balance: bool,
    /// Rows `t, x_0, x_1, ...` (particle coordinates): the first and the last samples at full
    /// resolution, with a row of NaN between them when samples were dropped.
    pub trajectory: Vec<Vec<f64>>,
    pub period: Option<Period>,
    /// Samples seen.
    pub samples: u64,
}

/// One run of a report.
#[derive(Clone, Debug)]
pub struct ReportRun {
    pub method: Method,
    /// Whether the positions were projected onto the constraints after each step.
    pub projected: bool,
    pub integrator: IntegratorKind,
    pub dt: f64,
    /// dt as the user wrote it (e.g. `1/60`).
    pub dt_label: String,
    /// The relative tolerance of an adaptive run (dopri5), which chooses its own steps (dt
    /// is then its output interval only): such a run is labelled, dashed and placed on the
    /// work-precision figure by its tolerance. `None` for fixed-step runs.
    pub rtol: Option<f64>,
    pub stats: RunStats,
    /// Why the run stopped early, if it did.
    pub error: Option<String>,
    pub recording: Recording,
}

impl ReportRun {
    /// `implicit`, `implicit+project` or `parametric`.
    pub fn method_label(&self) -> String {
        if self.projected {
            format!("{}+project", self.method.name())
        } else {
            self.method.name().to_string()
        }
    }

    /// `implicit rk4 dt=1/60`, or `implicit dopri5 rtol=1e-9` for an adaptive run.
    pub fn label(&self) -> String {
        match self.rtol {
            Some(rtol) => format!(
                "{} {} rtol={}",
                self.method_label(),
                self.integrator.name(),
                sig(rtol, 4)
            ),
            None => format!(
                "{} {} dt={}",
                self.method_label(),
                self.integrator.name(),
                self.dt_label
            ),
        }
    }

    /// The dt column: the step size, or `adaptive, rtol R (output every dt)` for an adaptive
    /// run.
    pub fn dt_text(&self) -> String {
        match self.rtol {
            Some(rtol) => format!(
                "adaptive, rtol {} (output every {})",
                sig(rtol, 4),
                self.dt_label
            ),
            None => self.dt_label.clone(),
        }
    }
}

/// A set of runs of one scene. Each run is drawn with its own [`Look`]: the colour of its
/// integrator, the dash of its dt (largest first) and the marker of its method.
#[derive(Clone, Debug)]
pub struct Report {
    pub title: String,
    /// One line about the scene and the runs (file, duration, flags).
    pub description: String,
    pub system: Arc<System>,
    pub runs: Vec<ReportRun>,
    /// Combinations that were not run, with the reason: `parametric x rattle: ...`.
    pub skipped: Vec<String>,
    /// The scene as the report states it (file text, parameters, command line); `None`
    /// for a report of runs without a scene file.
    pub scene: Option<SceneStatement>,
}

/// What a report says about its scene, so that it can be checked and reproduced from the
/// report alone: the file's text, every parameter's value (after `--set`), the units and the
/// command line that wrote the report. The initial state is read from the report's system.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SceneStatement {
    /// The scene file as given.
    pub file: String,
    /// The file's text as loaded.
    pub text: String,
    /// `[world] units`, if the scene says.
    pub units: Option<String>,
    /// Every parameter, in file order.
    pub params: Vec<ParamValue>,
    /// The command line that reproduces the report (shell-quoted).
    pub command: String,
}

/// One parameter of a scene as a report states it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ParamValue {
    pub name: String,
    pub value: f64,
    pub unit: Option<String>,
    pub description: Option<String>,
    /// Whether `--set` gave the value (else the file did).
    pub overridden: bool,
}

impl SceneStatement {
    /// The statement of `scene` (loaded with its overrides) written by `command`.
    pub fn of(scene: &bead::scene::Scene, command: impl Into<String>) -> Self {
        let params = scene
            .params
            .iter()
            .map(|(name, value)| {
                let spec = scene.param_specs.iter().find(|p| &p.name == name);
                ParamValue {
                    name: name.clone(),
                    value: *value,
                    unit: spec.and_then(|p| p.unit.clone()),
                    description: spec.and_then(|p| p.description.clone()),
                    overridden: scene.overrides().iter().any(|(n, _)| n == name),
                }
            })
            .collect();
        SceneStatement {
            file: scene.file.clone(),
            text: scene.text().to_string(),
            units: scene.units.clone(),
            params,
            command: command.into(),
        }
    }
}

/// `args` as one shell command line: each argument quoted with single quotes when it holds
/// anything but letters, digits and `-_./=,:+@%`.
pub fn shell_command<I, S>(args: I) -> String
where
    I: IntoIterator<Item = S>,
    S: AsRef<str>,
{
    args.into_iter()
        .map(|a| {
            let a = a.as_ref();
            let plain = !a.is_empty()
                && a.chars()
                    .all(|c| c.is_ascii_alphanumeric() || "-_./=,:+@%".contains(c));
            if plain {
                a.to_string()
            } else {
                format!("'{}'", a.replace('\'', "'\\''"))
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// `x` with `sig` significant digits in the shorter of fixed and exponent notation: the
/// library's [`bead::significant`], so that reports, the CLI and the library's messages print
/// numbers alike.
pub use bead::significant as sig;

/// A run whose largest relative energy change is this many times the median of the
/// others' is drawn off scale on the signed energy panel (see [`Panel::outlier_factor`]).
pub const OUTLIER_FACTOR: f64 = 100.0;

/// A trajectory that reaches this many times farther from the common centre than the median
/// of the others is drawn off scale, so that one run leaving the curve does not shrink the
/// others to a smudge.
pub const TRAJECTORY_OUTLIER_FACTOR: f64 = 10.0;

/// Significant digits of every figure in the comparison table (errors, period, rates).
pub const TABLE_DIGITS: usize = 4;

/// Significant digits of the periods listed under the table: runs' periods differ in the
/// fifth digit and beyond, which the list is there to show.
pub const PERIOD_DIGITS: usize = 6;

impl Report {
    /// The look of `run` in every figure: a hue per run of the grid (per integrator and
    /// dt, or tolerance for an adaptive run, in the order the runs come), shared by the
    /// formulations of that run, the parametric one in a lighter shade, and the line style
    /// (implicit: solid, parametric: dashed, implicit+project: dotted); the marker by
    /// integrator (its place in [`IntegratorKind::ALL`]).
    pub fn look(&self, run: &ReportRun) -> Look {
        let key = |r: &ReportRun| {
            (
                r.integrator,
                r.rtol.is_some(),
                r.rtol.unwrap_or(r.dt).to_bits(),
            )
        };
        let mut keys = Vec::new();
        for r in &self.runs {
            if !keys.contains(&key(r)) {
                keys.push(key(r));
            }
        }
        let color = keys.iter().position(|k| *k == key(run)).unwrap_or(0);
        let dash = match (run.method, run.projected) {
            (Method::Parametric, _) => Dash::Dashed,
            (_, true) => Dash::Dotted,
            _ => Dash::Solid,
        };
        let integrator = IntegratorKind::ALL
            .iter()
            .position(|&k| k == run.integrator)
            .unwrap_or(0);
        Look {
            color: Some(color),
            light: run.method == Method::Parametric,
            dash,
            marker: Some(Marker::ALL[integrator % Marker::ALL.len()]),
        }
    }

    /// What colour, line and marker stand for, above every legend.
    fn legend_note(&self) -> Vec<String> {
        let mut styles = Vec::new();
        for (label, dash) in [
            ("implicit", "solid"),
            ("implicit+project", "dotted"),
            ("parametric", "dashed"),
        ] {
            if self.runs.iter().any(|r| r.method_label() == label) {
                styles.push(format!("{dash}: {label}"));
            }
        }
        vec![
            "colour: one per integrator and dt, lighter for parametric".to_string(),
            format!("line: {}", styles.join(", ")),
        ]
    }

    /// The length unit of the scene, for axis labels: `px`, `m` (SI), else `length units`.
    fn length_unit(&self) -> String {
        match self.scene.as_ref().and_then(|s| s.units.as_deref()) {
            Some("SI") => "m".into(),
            Some(unit) => unit.to_string(),
            None => "scene length units".into(),
        }
    }

    /// The line of `run` in a time series figure.
    fn series(&self, run: &ReportRun, points: &[(f64, f64)]) -> Series {
        Series::line(run.label(), points.to_vec()).with_look(self.look(run))
    }

    /// The comparison table: a header row, then one row per run. Columns: method,
    /// integrator, dt, final and max constraint error, the largest distance off the
    /// constraints |C|/|grad C| (implicit form; `-` for the parametric form, which cannot
    /// leave its curve), max relative energy error, period
    /// (`-` when the motion is not periodic or shows fewer than two crossings), steps/s, and
    /// when any run is adaptive its accepted/rejected steps, when any failed its status.
    pub fn rows(&self) -> Vec<Vec<String>> {
        let adaptive = self.runs.iter().any(|r| r.stats.accepted_steps.is_some());
        let failed = self.runs.iter().any(|r| r.error.is_some());
        let mut header: Vec<String> = [
            "method",
            "integrator",
            "dt",
            "final constraint error",
            "max constraint error",
            "max |C|/|grad C|",
            "max rel energy error",
            "period (s)",
            "steps/s",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        if adaptive {
            header.push("accepted/rejected".into());
        }
        if failed {
            header.push("status".into());
        }
        let mut rows = vec![header];
        for run in &self.runs {
            let s = &run.stats;
            let mut row = vec![
                run.method_label(),
                run.integrator.name().to_string(),
                run.dt_text(),
                sig(s.constraint_error_final, TABLE_DIGITS),
                sig(s.constraint_error_max, TABLE_DIGITS),
                s.constraint_distance_max
                    .map(|d| sig(d, TABLE_DIGITS))
                    .unwrap_or_else(|| "-".into()),
                if s.energy_conserved {
                    sig(s.energy_rel_error_max, TABLE_DIGITS)
                } else {
                    format!(
                        "{} (E-W)",
                        sig(s.conserved_energy_error_max(), TABLE_DIGITS)
                    )
                },
                run.recording
                    .period
                    .as_ref()
                    .map(|p| sig(p.seconds, TABLE_DIGITS))
                    .unwrap_or_else(|| "-".into()),
                sig(s.steps_per_second(), TABLE_DIGITS),
            ];
            if adaptive {
                row.push(match (s.accepted_steps, s.rejected_steps) {
                    (Some(a), Some(r)) => format!("{a}/{r}"),
                    _ => "-".into(),
                });
            }
            if failed {
                row.push(match &run.error {
                    None => "ok".into(),
                    Some(e) => format!("stopped at t = {}: {e}", sig(s.t_final, 6)),
                });
            }
            rows.push(row);
        }
        rows
    }

    /// The running maximum ([`plot::running_max`]) of each run's `series`: the envelope
    /// drawn on the log panels, so that an error oscillating through zero reads as the
    /// error reached so far rather than as zigzags down to its zero crossings.
    fn envelopes(&self, series: fn(&Recording) -> &[(f64, f64)]) -> Vec<Series> {
        self.runs
            .iter()
            .map(|r| self.series(r, &plot::running_max(series(&r.recording))))
            .collect()
    }

    /// Whether every run's deviation is the true distance to the constraint set (see
    /// [`Recording::deviation_is_distance`]).
    pub fn deviation_is_distance(&self) -> bool {
        !self.runs.is_empty() && self.runs.iter().all(|r| r.recording.deviation_is_distance)
    }

    /// Constraint error vs time, and the distance off the constraint set vs time (the true
    /// distance to the closest point where it is one scalar constraint on one particle, else
    /// the first-order estimate, labelled so); both as running maxima on log axes.
    pub fn constraint_figure(&self) -> Figure {
        let unit = self.length_unit();
        let (title, y_label) = if self.deviation_is_distance() {
            (
                "distance to the constraint set (closest point), running max (log scale)"
                    .to_string(),
                format!("distance ({unit})"),
            )
        } else {
            (
                "first-order estimate |C|/|grad C| of the distance, max over rows, running max (log scale)".to_string(),
                format!("first-order estimate |C|/|grad C| ({unit})"),
            )
        };
        Figure {
            columns: 1,
            title: format!(
                "{}: constraint error and distance off the constraints",
                self.title
            ),
            panels: vec![
                Panel {
                    title: "max_i |C_i|, running max (log scale)".into(),
                    x_label: "t (s)".into(),
                    y_label: "max |C_i| (constraint units)".into(),
                    y_log: true,
                    legend_note: self.legend_note(),
                    series: self.envelopes(|r| &r.constraint_error),
                    ..Panel::default()
                },
                Panel {
                    title,
                    x_label: "t (s)".into(),
                    y_label,
                    y_log: true,
                    legend_note: self.legend_note(),
                    series: self.envelopes(|r| &r.deviation),
                    ..Panel::default()
                },
            ],
            size: (1100, 900),
        }
    }

    /// Energy error vs time: signed, so that gain and loss read apart (the article's
    /// point: the parametric form loses energy), on robust axes (a run 100 times off the
    /// others is drawn clipped and named); and its running maximum on a log scale.
    pub fn energy_figure(&self) -> Figure {
        let balance = self.runs.iter().any(|r| r.recording.energy_balance);
        let (quantity, title) = if balance {
            (
                "E - W - E0",
                format!(
                    "{}: energy balance error (energy not conserved: E - W is; W = work done on the system)",
                    self.title
                ),
            )
        } else {
            ("E - E0", format!("{}: energy error", self.title))
        };
        Figure {
            columns: 1,
            title,
            panels: vec![
                Panel {
                    title: format!("({quantity}) / E_scale vs time, its range per pixel column: above 0 gained, below 0 lost"),
                    x_label: "t (s)".into(),
                    y_label: "relative energy change (1)".into(),
                    outlier_factor: Some(OUTLIER_FACTOR),
                    legend_note: self.legend_note(),
                    // Bands: the change oscillates with the motion, hundreds of times in
                    // a long run, and lines down to every extreme would be hatching.
                    series: self
                        .runs
                        .iter()
                        .map(|r| Series {
                            style: Style::Band,
                            ..self.series(r, &r.recording.energy_change)
                        })
                        .collect(),
                    ..Panel::default()
                },
                Panel {
                    title: format!("|{quantity}| / E_scale, running max (log scale)"),
                    x_label: "t (s)".into(),
                    y_label: "relative energy error (1)".into(),
                    y_log: true,
                    legend_note: self.legend_note(),
                    series: self.envelopes(|r| &r.energy_error),
                    ..Panel::default()
                },
            ],
            size: (1100, 900),
        }
    }

    /// Trajectories in particle space: the x-y plane in 2D; in 3D two panels, the
    /// projections onto x-y and x-z. The constraint curve is drawn under them from the
    /// parametric run with the smallest dt (and of those the highest order) when there is one (it stays on C = 0 to round-off).
    pub fn trajectory_figure(&self) -> Figure {
        let dim = self.system.dim();
        let planes: Vec<(usize, &str)> = if dim == 3 {
            vec![(1, "y"), (2, "z")]
        } else {
            vec![(1, "y")]
        };
        let reference = self
            .runs
            .iter()
            .filter(|r| r.method == Method::Parametric && r.error.is_none())
            .min_by(|a, b| {
                a.dt.total_cmp(&b.dt)
                    .then(b.integrator.order().cmp(&a.integrator.order()))
            });
        let particles = self.system.particles();
        let gravity = self.system.gravity();
        let unit = self.length_unit();
        let panels = planes
            .iter()
            .map(|&(axis, axis_name)| {
                let mut series = Vec::new();
                let coords = |row: &[f64], p: usize| {
                    let base = 1 + p * dim;
                    (
                        row.get(base).copied().unwrap_or(f64::NAN),
                        row.get(base + axis).copied().unwrap_or(f64::NAN),
                    )
                };
                if let Some(reference) = reference {
                    for p in 0..particles.len() {
                        series.push(Series {
                            look: Look::default(),
                            label: if p == 0 {
                                format!("constraint curve (from {})", reference.label())
                            } else {
                                String::new()
                            },
                            points: reference
                                .recording
                                .trajectory
                                .iter()
                                .map(|r| coords(r, p))
                                .collect(),
                            style: Style::Reference,
                        });
                    }
                }
                for run in &self.runs {
                    for (p, particle) in particles.iter().enumerate() {
                        let label = if particles.len() > 1 {
                            format!("{} {}", run.label(), particle.name)
                        } else {
                            run.label()
                        };
                        let mut look = self.look(run);
                        if particles.len() > 1 {
                            // Particles of one run apart by marker.
                            look.marker = Some(Marker::ALL[p % Marker::ALL.len()]);
                        }
                        series.push(
                            Series::line(
                                label,
                                run.recording
                                    .trajectory
                                    .iter()
                                    .map(|r| coords(r, p))
                                    .collect(),
                            )
                            .with_look(look),
                        );
                    }
                }
                // Gravity along +axis: that axis points down on the page, as the scene's
                // world does (the article's +y down).
                let down = gravity.get(axis).is_some_and(|&g| g > 0.0);
                Panel {
                    title: format!("x-{axis_name} plane (equal scales)"),
                    x_label: format!("x ({unit})"),
                    y_label: if down {
                        format!("{axis_name}, pointing down ({unit})")
                    } else {
                        format!("{axis_name} ({unit})")
                    },
                    y_down: down,
                    equal_aspect: true,
                    outlier_factor: Some(TRAJECTORY_OUTLIER_FACTOR),
                    legend_note: self.legend_note(),
                    series,
                    ..Panel::default()
                }
            })
            .collect();
        Figure {
            columns: 0,
            title: format!("{}: trajectories", self.title),
            panels,
            size: if dim == 3 { (1400, 620) } else { (1100, 640) },
        }
    }

    /// Work-precision: max constraint error and max relative energy error vs the number of
    /// steps (deterministic, unlike wall time), one series per method x integrator across
    /// the dts, in that integrator's colour and that method's marker.
    pub fn work_precision_figure(&self) -> Figure {
        let mut keys: Vec<&ReportRun> = Vec::new();
        for r in &self.runs {
            if !keys
                .iter()
                .any(|k| k.method_label() == r.method_label() && k.integrator == r.integrator)
            {
                keys.push(r);
            }
        }
        let series = |error: fn(&RunStats) -> f64| -> Vec<Series> {
            keys.iter()
                .map(|key| {
                    let mut points: Vec<(f64, f64)> = self
                        .runs
                        .iter()
                        .filter(|r| {
                            r.method_label() == key.method_label()
                                && r.integrator == key.integrator
                                && r.error.is_none()
                        })
                        .map(|r| (r.stats.steps as f64, error(&r.stats)))
                        .collect();
                    points.sort_by(|a, b| a.0.total_cmp(&b.0));
                    let look = self.look(key);
                    Series {
                        label: format!("{} {}", key.method_label(), key.integrator.name()),
                        points,
                        style: Style::LineAndMarkers,
                        look,
                    }
                })
                .collect()
        };
        Figure {
            columns: 0,
            title: format!(
                "{}: work-precision (one point per dt; per tolerance for adaptive runs)",
                self.title
            ),
            panels: vec![
                Panel {
                    title: "max constraint error vs steps".into(),
                    x_label: "steps".into(),
                    y_label: "max |C_i| (constraint units)".into(),
                    x_log: true,
                    y_log: true,
                    legend_note: self.legend_note(),
                    series: series(|s| s.constraint_error_max),
                    ..Panel::default()
                },
                Panel {
                    title: "max relative energy error vs steps".into(),
                    x_label: "steps".into(),
                    y_label: "max |E - E0| / E_scale, or of E - W (1)".into(),
                    x_log: true,
                    y_log: true,
                    legend_note: self.legend_note(),
                    series: series(|s| s.conserved_energy_error_max()),
                    ..Panel::default()
                },
            ],
            size: (1500, 560),
        }
    }
}

/// The files of a written report.
#[derive(Clone, Debug)]
pub struct ReportFiles {
    pub html: PathBuf,
    /// Every plot file (PNG and SVG).
    pub plots: Vec<PathBuf>,
}

/// Why a report could not be written. The message includes the cause (no `source()`, so
/// that printing the chain shows it once).
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error(transparent)]
    Plot(#[from] PlotError),
    #[error("cannot write `{path}`: {error}")]
    Io { path: String, error: std::io::Error },
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

const CSS: &str = "body{font-family:sans-serif;max-width:1250px;margin:1.5em auto;padding:0 1em;color:#222}\
table{border-collapse:collapse;font-size:14px}th,td{border:1px solid #ccc;padding:3px 8px}\
td{text-align:right;font-variant-numeric:tabular-nums}td:first-child,td:nth-child(2){text-align:left}\
th{background:#f0f0f0}figure{margin:1.5em 0}figcaption{font-size:14px;color:#444;margin-top:.3em}\
svg{max-width:100%;height:auto}.skipped{color:#844}\
pre{background:#f6f6f6;border:1px solid #ddd;padding:.6em;overflow-x:auto;font-size:13px}";

/// The figures of a report by file stem; each is written as `STEM.png` and `STEM.svg`.
pub const FIGURES: [&str; 4] = [
    "constraint_error",
    "energy_error",
    "trajectories",
    "work_precision",
];

/// Every file [`write_report`] writes into `dir`: `report.html` and each figure's PNG and SVG.
pub fn report_files(dir: &Path) -> Vec<PathBuf> {
    let mut files = vec![dir.join("report.html")];
    for name in FIGURES {
        files.push(dir.join(format!("{name}.png")));
        files.push(dir.join(format!("{name}.svg")));
    }
    files
}

/// Write `report` into `dir` (created if needed): `report.html` and, per figure, a PNG and an
/// SVG (`constraint_error`, `energy_error`, `trajectories`, `work_precision`). The HTML is
/// self-contained: inline CSS, the table, the SVGs inline, and relative links to the PNG and
/// SVG files beside it.
pub fn write_report(report: &Report, dir: &Path) -> Result<ReportFiles, ReportError> {
    let io = |path: &Path| {
        let path = path.display().to_string();
        move |error| ReportError::Io { path, error }
    };
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let balance = report.runs.iter().any(|r| r.recording.energy_balance);
    let down = report
        .system
        .gravity()
        .iter()
        .enumerate()
        .find(|&(_, &g)| g > 0.0)
        .map(|(axis, _)| ["x", "y", "z"][axis.min(2)]);
    let trajectory_caption = format!(
        "Trajectories in particle space{}, over the constraint curve, at equal scales on both axes{}; for long runs the first and the last samples of each run (each at full resolution).",
        if report.system.dim() == 3 {
            ", projected onto the x-y plane (left) and the x-z plane (right)"
        } else {
            " (the x-y plane)"
        },
        match down {
            Some(axis) => format!(", with {axis} pointing down as the scene's gravity does"),
            None => String::new(),
        }
    );
    let figures = [
        (
            FIGURES[0],
            "Constraint error",
            report.constraint_figure(),
            if report.deviation_is_distance() {
                "Constraint error max_i |C_i| against time, per run (top), and the distance of the particle to the constraint set, found by a closest-point search (Newton's method on the Lagrange conditions of min |y - x|^2 subject to C(y) = 0), in the scene's length units (bottom); both as their running maximum from t = 0 (the envelope: the largest value reached so far).".to_string()
            } else {
                "Constraint error max_i |C_i| against time, per run (top), and a first-order estimate of the distance off the constraint set, max_i |C_i| / |grad C_i| (the Newton step onto each row's level set; not the true distance, which is not simply defined for several rows or particles), in the scene's length units (bottom); both as their running maximum from t = 0 (the envelope: the largest value reached so far).".to_string()
            },
        ),
        (
            FIGURES[1],
            "Energy",
            report.energy_figure(),
            if balance {
                "Energy is not conserved here (something does work on the system): the change of the conserved balance E - W, (E - W - E0) / E_scale, with its sign (top: above zero the balance gained, below it lost) and the running maximum of its size on a log scale (bottom), against time, per run (W: the work done on the system, integrated by the run's integrator; E_scale = max(|E0|, T0 + |V0|, T0 + M |g| L)).".to_string()
            } else {
                "Relative energy change (E - E0) / E_scale with its sign (top: above zero the run gained energy, below it lost some) and the running maximum of its size on a log scale (bottom), against time, per run (E_scale = max(|E0|, T0 + |V0|, T0 + M |g| L): M the total mass, L the largest initial coordinate magnitude).".to_string()
            },
        ),
        (FIGURES[2], "Trajectories", report.trajectory_figure(), trajectory_caption),
        (
            FIGURES[3],
            "Work-precision",
            report.work_precision_figure(),
            "Work-precision: the largest error of each run against its number of steps; one point per dt (per tolerance for the adaptive dopri5, which chooses its own steps), one line per method and integrator (steps rather than wall time: they do not change from run to run).".to_string(),
        ),
    ];
    let mut html = String::new();
    let _ = write!(
        html,
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n<title>{}</title>\n<style>{CSS}</style>\n</head>\n<body>\n<h1>{}</h1>\n<p>{}</p>\n",
        escape(&report.title),
        escape(&report.title),
        escape(&report.description)
    );
    // The setup: what was run, by which bead, on which system.
    let system = &report.system;
    let gravity: Vec<String> = system.gravity().iter().map(|g| sig(*g, 6)).collect();
    let _ = write!(
        html,
        "<h2>Setup</h2>\n<ul>\n<li>bead {}</li>\n<li>{} in {}D, {}, gravity ({})</li>\n<li>runs: {}</li>\n</ul>\n",
        env!("CARGO_PKG_VERSION"),
        counted(system.particles().len(), "particle"),
        system.dim(),
        counted(system.constraints().n_rows(), "constraint row"),
        gravity.join(", "),
        escape(
            &report
                .runs
                .iter()
                .map(|r| r.label())
                .collect::<Vec<_>>()
                .join("; ")
        )
    );
    scene_html(&mut html, report);
    html.push_str("<h2>Runs</h2>\n<table>\n");
    for (i, row) in report.rows().iter().enumerate() {
        let cell = if i == 0 { "th" } else { "td" };
        html.push_str("<tr>");
        for c in row {
            let _ = write!(html, "<{cell}>{}</{cell}>", escape(c));
        }
        html.push_str("</tr>\n");
    }
    html.push_str("</table>\n");
    let periods: Vec<String> = report
        .runs
        .iter()
        .filter_map(|r| {
            r.recording.period.as_ref().map(|p| {
                format!(
                    "{}: {} s over {} cycles (upward zero crossings of {})",
                    r.label(),
                    sig(p.seconds, PERIOD_DIGITS),
                    p.cycles,
                    p.signal
                )
            })
        })
        .collect();
    if !periods.is_empty() {
        html.push_str(
            "<h2>Periods</h2>\n<p>From linearly interpolated zero crossings of every sample, to 6 significant digits (the table rounds every figure to 4); a motion whose cycles differ by more than 5% has none:</p>\n<ul>\n",
        );
        for p in periods {
            let _ = writeln!(html, "<li>{}</li>", escape(&p));
        }
        html.push_str("</ul>\n");
    }
    if !report.skipped.is_empty() {
        html.push_str("<p>Not run:</p>\n<ul class=\"skipped\">\n");
        for s in &report.skipped {
            let _ = writeln!(html, "<li>skipped: {}</li>", escape(s));
        }
        html.push_str("</ul>\n");
    }
    let mut plots = Vec::new();
    for (name, heading, figure, caption) in &figures {
        let png = dir.join(format!("{name}.png"));
        let svg_path = dir.join(format!("{name}.svg"));
        plot::write_figure(figure, &png)?;
        let svg = plot::svg_string(figure).map_err(|message| PlotError::Draw {
            path: svg_path.display().to_string(),
            message,
        })?;
        std::fs::write(&svg_path, &svg).map_err(io(&svg_path))?;
        plots.push(png);
        plots.push(svg_path);
        let mut caption = caption.to_string();
        if let Some(note) = figure.note() {
            let _ = write!(caption, " Log axes: {note}; NaN points are skipped.");
        }
        for note in figure.off_scale_notes() {
            let _ = write!(
                caption,
                " {note}: more than {} times the others' reach, so the axes are scaled to the others and this run is drawn clipped at the frame.",
                if name == &FIGURES[2] { TRAJECTORY_OUTLIER_FACTOR } else { OUTLIER_FACTOR }
            );
        }
        let _ = write!(
            html,
            "<h2>{heading}</h2>\n<figure>\n{}\n<figcaption>{} Files: <a href=\"{name}.png\">{name}.png</a>, <a href=\"{name}.svg\">{name}.svg</a>.</figcaption>\n</figure>\n",
            strip_xml_declaration(&svg),
            escape(&caption)
        );
    }
    let _ = writeln!(
        html,
        "<p>Each series is recorded in a bounded number of points (the minimum and maximum of each bucket of consecutive samples, so spikes survive), and each drawn line keeps per two pixel columns its lowest and highest point (a trajectory a point every four pixels); periods use every sample. Colour: one per integrator and dt; line: solid implicit, dashed parametric, dotted implicit+project.</p>\n</body>\n</html>"
    );
    let path = dir.join("report.html");
    std::fs::write(&path, html).map_err(io(&path))?;
    Ok(ReportFiles { html: path, plots })
}

/// The report's scene section: the command line that reproduces it, the parameters, the
/// initial state and the scene file's text.
fn scene_html(html: &mut String, report: &Report) {
    let system = &report.system;
    let exact = |v: f64| bead::readable(v);
    let vector = |v: &[f64]| {
        let parts: Vec<String> = v.iter().map(|x| exact(*x)).collect();
        format!("({})", parts.join(", "))
    };
    html.push_str("<h2>Scene</h2>\n");
    if let Some(scene) = &report.scene {
        let _ = write!(
            html,
            "<p>Reproduce this report with:</p>\n<pre class=\"command\">{}</pre>\n",
            escape(&scene.command)
        );
        if let Some(units) = &scene.units {
            let _ = writeln!(html, "<p>Units: {}</p>", escape(units));
        }
        if !scene.params.is_empty() {
            html.push_str("<h3>Parameters</h3>\n<table>\n<tr><th>name</th><th>value</th><th>unit</th><th>description</th></tr>\n");
            for p in &scene.params {
                let _ = writeln!(
                    html,
                    "<tr><td>{}</td><td>{}{}</td><td>{}</td><td>{}</td></tr>",
                    escape(&p.name),
                    exact(p.value),
                    if p.overridden { " (--set)" } else { "" },
                    escape(p.unit.as_deref().unwrap_or("")),
                    escape(p.description.as_deref().unwrap_or(""))
                );
            }
            html.push_str("</table>\n");
        }
    }
    html.push_str("<h3>Initial state</h3>\n<ul>\n");
    for particle in system.particles() {
        let _ = writeln!(
            html,
            "<li>{}: mass {}, position {}, velocity {}</li>",
            escape(&particle.name),
            exact(particle.mass),
            vector(&particle.position),
            vector(&particle.velocity)
        );
    }
    if let Some(map) = system.parametric() {
        let described: Vec<String> = map
            .coordinates()
            .iter()
            .zip(map.initial().iter().zip(map.rates()))
            .map(|(c, (q, r))| format!("{c} = {}, {c}' = {}", exact(*q), exact(*r)))
            .collect();
        let _ = writeln!(
            html,
            "<li>parametric form: {}</li>",
            escape(&described.join("; "))
        );
    }
    html.push_str("</ul>\n");
    if let Some(scene) = &report.scene {
        let _ = write!(
            html,
            "<h3>Scene file <code>{}</code></h3>\n<pre class=\"scene\">{}</pre>\n",
            escape(&scene.file),
            escape(&scene.text)
        );
    }
}

/// `1 particle`, `2 particles`.
fn counted(n: usize, noun: &str) -> String {
    if n == 1 {
        format!("1 {noun}")
    } else {
        format!("{n} {noun}s")
    }
}

fn strip_xml_declaration(svg: &str) -> &str {
    match svg.find("<svg") {
        Some(i) => &svg[i..],
        None => svg,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn period_of_a_sine_from_interpolated_crossings() {
        let mut d = PeriodDetector::new();
        let period = 2.153;
        let dt = 0.01;
        for i in 0..2000 {
            let t = i as f64 * dt;
            d.push(t, (2.0 * std::f64::consts::PI * t / period + 0.3).sin());
        }
        let measured = d.period().unwrap();
        assert!((measured - period).abs() < 1e-4 * period, "{measured}");
    }

    #[test]
    fn no_period_without_two_crossings_or_when_irregular() {
        let mut d = PeriodDetector::new();
        for i in 0..100 {
            let t = i as f64 * 0.01;
            d.push(t, (6.0 * t).sin()); // one upward crossing at most
        }
        assert_eq!(d.period(), None);
        // A chirp: the cycles get shorter.
        let mut d = PeriodDetector::new();
        for i in 0..10_000 {
            let t = i as f64 * 0.01;
            d.push(t, (t * t).sin());
        }
        assert!(d.crossings() > 2);
        assert_eq!(d.period(), None);
    }

    #[test]
    fn sig_formats() {
        assert_eq!(sig(1.0 / 60.0, 4), "0.01667");
        assert_eq!(sig(1.234e-8, 4), "1.234e-8");
        assert_eq!(sig(0.0, 4), "0");
    }
}
