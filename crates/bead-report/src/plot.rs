//! Plots as PNG or SVG files: series data in, files out.
//!
//! - [`MinMaxDecimator`] keeps a bounded, envelope-preserving picture of a long time series:
//!   it fills at most `capacity` buckets of consecutive samples and keeps each bucket's
//!   minimum and maximum (so at most `2 * capacity` points, and a one-sample spike survives).
//!   When the buckets run out, neighbouring buckets merge and the bucket width doubles, so it
//!   works on streams of unknown length in constant memory.
//! - [`StrideDecimator`] keeps every k-th row of a multi-column stream (k doubling as needed),
//!   for trajectories, where a point must keep its coordinates together.
//! - [`Figure`] / [`Panel`] / [`Series`] describe a figure of one or more panels side by side;
//!   [`write_figure`] draws it to a file whose extension (`.png` or `.svg`) picks the format,
//!   [`svg_string`] returns the SVG text.
//!
//! Each series has its own [`Look`] (colour, dash, marker), so that runs stay apart in print
//! and in grey; legends sit beside the data, never over it. Log axes leave out values at or
//! below zero (the figure's [`Figure::note`] says how many, e.g. exact zeros) and every axis
//! skips NaN and infinite points. Tick labels carry the digits their spacing needs. A panel
//! may draw its y axis pointing down (a scene whose gravity is +y) and keep equal scales on
//! both axes (trajectories). Text is drawn with DejaVu Sans, embedded in this crate, so
//! drawing a PNG needs no system font.

use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters::style::{register_font, FontStyle};

/// DejaVu Sans (see `assets/DejaVuSans.LICENSE`): the only font the plots use.
static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
const FAMILY: &str = "sans-serif";

/// Default number of min/max buckets of a [`MinMaxDecimator`]: at most 2000 points.
pub const DEFAULT_BUCKETS: usize = 1000;

fn register_fonts() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // The font is a fixed, valid TrueType file; a failure would leave text undrawn (PNG)
        // rather than fail the plot.
        let _ = register_font(FAMILY, FontStyle::Normal, FONT);
    });
}

/// Why a plot could not be written. Each message includes its cause, and no variant has a
/// [`std::error::Error::source`]: printing the chain (`{:#}` in anyhow) shows every cause once.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error("`{0}`: unknown plot format; use a .png or .svg file name")]
    Format(String),
    #[error("cannot draw `{path}`: {message}")]
    Draw { path: String, message: String },
    #[error("cannot write `{path}`: {error}")]
    Io { path: String, error: std::io::Error },
}

/// File format of a plot.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Png,
    Svg,
}

impl Format {
    /// The format named by `path`'s extension (case-insensitive): `.png` or `.svg`.
    pub fn from_path(path: &Path) -> Result<Format, PlotError> {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase())
            .as_deref()
        {
            Some("png") => Ok(Format::Png),
            Some("svg") => Ok(Format::Svg),
            _ => Err(PlotError::Format(path.display().to_string())),
        }
    }
}

#[derive(Clone, Copy, Debug)]
struct Bucket {
    n: u64,
    min: (f64, f64),
    max: (f64, f64),
}

/// Min/max bucket decimation of a stream of (t, y) points in bounded memory (see the module
/// documentation). Non-finite y values are skipped (they cannot be drawn).
#[derive(Clone, Debug)]
pub struct MinMaxDecimator {
    capacity: usize,
    width: u64,
    buckets: Vec<Bucket>,
}

impl MinMaxDecimator {
    /// At most `capacity` buckets (at least 2), so at most `2 * capacity` points.
    pub fn new(capacity: usize) -> Self {
        let capacity = capacity.max(2);
        MinMaxDecimator {
            capacity,
            width: 1,
            buckets: Vec::with_capacity(capacity + 1),
        }
    }

    /// Add a point; t must not decrease.
    pub fn push(&mut self, t: f64, y: f64) {
        if !y.is_finite() || !t.is_finite() {
            return;
        }
        match self.buckets.last_mut() {
            Some(b) if b.n < self.width => {
                b.n += 1;
                if y < b.min.1 {
                    b.min = (t, y);
                }
                if y > b.max.1 {
                    b.max = (t, y);
                }
            }
            _ => {
                if self.buckets.len() == self.capacity {
                    self.merge();
                }
                self.buckets.push(Bucket {
                    n: 1,
                    min: (t, y),
                    max: (t, y),
                });
            }
        }
    }

    /// Merge neighbouring buckets pairwise and double the width.
    fn merge(&mut self) {
        let n = self.buckets.len();
        let mut write = 0;
        let mut read = 0;
        while read < n {
            let mut b = self.buckets[read];
            if read + 1 < n {
                let c = self.buckets[read + 1];
                b.n += c.n;
                if c.min.1 < b.min.1 {
                    b.min = c.min;
                }
                if c.max.1 > b.max.1 {
                    b.max = c.max;
                }
            }
            self.buckets[write] = b;
            write += 1;
            read += 2;
        }
        self.buckets.truncate(write);
        self.width *= 2;
    }

    /// Samples per bucket now.
    pub fn bucket_width(&self) -> u64 {
        self.width
    }

    /// The kept points in time order: each bucket's minimum and maximum (once when they are
    /// the same sample).
    pub fn points(&self) -> Vec<(f64, f64)> {
        let mut points = Vec::with_capacity(2 * self.buckets.len());
        for b in &self.buckets {
            let (first, second) = if b.min.0 <= b.max.0 {
                (b.min, b.max)
            } else {
                (b.max, b.min)
            };
            points.push(first);
            if second != first {
                points.push(second);
            }
        }
        points
    }
}

/// Keeps every k-th row of a stream of rows of `width` numbers in at most `capacity` rows
/// (plus the latest row), doubling k when full.
#[derive(Clone, Debug)]
pub struct StrideDecimator {
    width: usize,
    capacity: usize,
    stride: u64,
    seen: u64,
    rows: Vec<f64>,
    last: Vec<f64>,
    last_kept: bool,
}

impl StrideDecimator {
    /// Rows of `width` numbers, at most `capacity` (at least 2) kept.
    pub fn new(width: usize, capacity: usize) -> Self {
        let capacity = capacity.max(2);
        StrideDecimator {
            width,
            capacity,
            stride: 1,
            seen: 0,
            rows: Vec::with_capacity(width * capacity),
            last: vec![0.0; width],
            last_kept: true,
        }
    }

    /// Add a row (`width` numbers; extra are ignored, missing count as NaN).
    pub fn push(&mut self, row: &[f64]) {
        for (k, slot) in self.last.iter_mut().enumerate() {
            *slot = row.get(k).copied().unwrap_or(f64::NAN);
        }
        if self.seen.is_multiple_of(self.stride) {
            if self.rows.len() / self.width.max(1) == self.capacity {
                // Keep rows 0, 2, 4, ...: the kept rows stay at multiples of the new stride.
                let width = self.width;
                let n = self.rows.len() / width.max(1);
                let mut write = 0;
                for r in (0..n).step_by(2) {
                    self.rows
                        .copy_within(r * width..(r + 1) * width, write * width);
                    write += 1;
                }
                self.rows.truncate(write * width);
                self.stride *= 2;
            }
            if self.seen.is_multiple_of(self.stride) {
                self.rows.extend_from_slice(&self.last);
                self.last_kept = true;
            } else {
                self.last_kept = false;
            }
        } else {
            self.last_kept = false;
        }
        self.seen += 1;
    }

    /// The kept rows, the latest row included.
    pub fn rows(&self) -> Vec<&[f64]> {
        let mut rows: Vec<&[f64]> = if self.width == 0 {
            Vec::new()
        } else {
            self.rows.chunks_exact(self.width).collect()
        };
        if !self.last_kept && self.seen > 0 {
            rows.push(&self.last);
        }
        rows
    }
}

/// Keeps the first and the last `half` rows of a stream of rows of `width` numbers, for
/// trajectories: each window is drawn at full resolution (no chords across the path), and
/// the two together show where a run started and where it ended up.
#[derive(Clone, Debug)]
pub struct HeadTail {
    width: usize,
    half: usize,
    head: Vec<f64>,
    tail: Vec<f64>,
    /// Rows pushed in all.
    seen: u64,
}

impl HeadTail {
    /// Rows of `width` numbers, `half` (at least 1) kept at each end.
    pub fn new(width: usize, half: usize) -> Self {
        let half = half.max(1);
        HeadTail {
            width,
            half,
            head: Vec::with_capacity(width * half),
            tail: Vec::with_capacity(width * half),
            seen: 0,
        }
    }

    /// Add a row (`width` numbers; extra are ignored, missing count as NaN).
    pub fn push(&mut self, row: &[f64]) {
        let value = |k: usize| row.get(k).copied().unwrap_or(f64::NAN);
        if self.head.len() < self.width * self.half {
            self.head.extend((0..self.width).map(value));
        } else {
            // The tail is a ring buffer: slot seen % half (counting from the first tail row).
            let slot = ((self.seen - self.half as u64) % self.half as u64) as usize;
            if self.tail.len() < self.width * self.half {
                self.tail.extend((0..self.width).map(value));
            } else {
                for k in 0..self.width {
                    self.tail[slot * self.width + k] = value(k);
                }
            }
        }
        self.seen += 1;
    }

    /// Whether rows between the head and the tail were dropped.
    pub fn has_gap(&self) -> bool {
        self.seen > 2 * self.half as u64
    }

    /// The head rows, then (after a row of NaN when rows were dropped, which breaks a drawn
    /// line) the tail rows in order.
    pub fn rows(&self) -> Vec<Vec<f64>> {
        let w = self.width.max(1);
        let mut rows: Vec<Vec<f64>> = self.head.chunks_exact(w).map(<[f64]>::to_vec).collect();
        let n_tail = self.tail.len() / w;
        if n_tail == 0 {
            return rows;
        }
        if self.has_gap() {
            rows.push(vec![f64::NAN; self.width]);
        }
        let start = if n_tail < self.half {
            0
        } else {
            ((self.seen - self.half as u64) % self.half as u64) as usize
        };
        for i in 0..n_tail {
            let r = (start + i) % n_tail;
            rows.push(self.tail[r * w..(r + 1) * w].to_vec());
        }
        rows
    }
}

/// How a series is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Style {
    Line,
    /// Markers joined by a line (e.g. a work-precision curve).
    LineAndMarkers,
    /// A wide, light line drawn under the others (e.g. a reference curve).
    Reference,
    /// An oscillating time series as the band between its lowest and highest value in each
    /// column of pixels, filled light with its edges in the series' dash, where it turns more
    /// often than every few pixel columns (see `dense`): a signal that oscillates hundreds of
    /// times across the panel reads as a band, not as hatching; a slower one is a line.
    Band,
}

/// The dash pattern of a line.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Dash {
    #[default]
    Solid,
    Dashed,
    Dotted,
    LongDashed,
}

impl Dash {
    /// The patterns in the order [`Look`]s take them.
    pub const ALL: [Dash; 4] = [Dash::Solid, Dash::Dashed, Dash::Dotted, Dash::LongDashed];

    /// (dash, gap) in pixels, `None` for a solid line.
    fn pattern(self) -> Option<(i32, i32)> {
        match self {
            Dash::Solid => None,
            Dash::Dashed => Some((7, 4)),
            Dash::Dotted => Some((2, 3)),
            Dash::LongDashed => Some((14, 5)),
        }
    }
}

/// The marker shape of a series.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Marker {
    Circle,
    Square,
    Triangle,
    Cross,
}

impl Marker {
    /// The shapes in the order [`Look`]s take them.
    pub const ALL: [Marker; 4] = [
        Marker::Circle,
        Marker::Square,
        Marker::Triangle,
        Marker::Cross,
    ];
}

/// How one series looks: a colour of the palette (`None`: the next one in the panel), a dash
/// pattern and an optional marker. A line series with a marker shows it at about a dozen
/// evenly spaced points (every point for [`Style::LineAndMarkers`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Look {
    pub color: Option<usize>,
    /// A lighter shade of the colour (the report's parametric runs: the same hue as the
    /// implicit run of the same integrator and dt, so related but not alike).
    pub light: bool,
    pub dash: Dash,
    pub marker: Option<Marker>,
}

/// One named series of (x, y) points.
#[derive(Clone, Debug)]
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    pub style: Style,
    pub look: Look,
}

impl Series {
    pub fn line(label: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series {
            label: label.into(),
            points,
            style: Style::Line,
            look: Look::default(),
        }
    }

    /// The same with `look`.
    pub fn with_look(mut self, look: Look) -> Self {
        self.look = look;
        self
    }
}

/// One chart: axes, labels and series.
#[derive(Clone, Debug, Default)]
pub struct Panel {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub x_log: bool,
    pub y_log: bool,
    /// Draw the y axis pointing down (larger y lower on the page), e.g. for a scene whose
    /// gravity points along +y.
    pub y_down: bool,
    /// One unit of x and one of y take the same length on the page (trajectories).
    pub equal_aspect: bool,
    /// Robust axis ranges on the linear axes: a series whose largest distance from the
    /// series' common centre is more than this factor times the median of the others' is an
    /// outlier. The axes are then scaled to the other series, and the outlier is drawn
    /// clipped at the frame with a note saying so and giving its extreme value (see
    /// [`Panel::off_scale`]); it is never left out silently. `None`: every series sets the
    /// range.
    pub outlier_factor: Option<f64>,
    /// Lines written above the legend's entries (e.g. what colour and dash stand for).
    pub legend_note: Vec<String>,
    pub series: Vec<Series>,
}

/// A series drawn clipped at the frame of its panel's robust range (see
/// [`Panel::outlier_factor`]).
#[derive(Clone, Debug, PartialEq)]
pub struct OffScale {
    /// The series' index in [`Panel::series`].
    pub series: usize,
    /// `x` or `y`: the axis it leaves.
    pub axis: &'static str,
    /// Its value farthest from the others on that axis.
    pub extreme: f64,
}

impl Panel {
    /// The series drawn off scale (clipped at the frame), each once with the axis it leaves
    /// most, in series order. A series is an outlier on a linear axis when its largest
    /// distance m_i from the centre c (the median of the series' midranges) exceeds
    /// [`Panel::outlier_factor`] times the median of m_j over the other drawn series (at
    /// least three series, reference lines not counted, and the median above zero).
    pub fn off_scale(&self) -> Vec<OffScale> {
        let Some(factor) = self.outlier_factor else {
            return Vec::new();
        };
        let runs: Vec<usize> = (0..self.series.len())
            .filter(|&i| self.series[i].style != Style::Reference)
            .collect();
        if runs.len() < 3 {
            return Vec::new();
        }
        let mut found: Vec<OffScale> = Vec::new();
        for (axis, log) in [("x", self.x_log), ("y", self.y_log)] {
            if log {
                continue;
            }
            let value = |p: &(f64, f64)| if axis == "x" { p.0 } else { p.1 };
            let finite = |i: usize| {
                self.series[i]
                    .points
                    .iter()
                    .filter(|p| p.0.is_finite() && p.1.is_finite())
                    .map(value)
                    .collect::<Vec<f64>>()
            };
            let values: Vec<Vec<f64>> = runs.iter().map(|&i| finite(i)).collect();
            let midranges: Vec<f64> = values
                .iter()
                .filter(|v| !v.is_empty())
                .map(|v| {
                    let lo = v.iter().copied().fold(f64::INFINITY, f64::min);
                    let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
                    0.5 * (lo + hi)
                })
                .collect();
            let Some(centre) = median(midranges) else {
                continue;
            };
            // (largest |v - c|, the v that reaches it) per series with data.
            let reach: Vec<Option<(f64, f64)>> = values
                .iter()
                .map(|v| {
                    v.iter()
                        .map(|&x| ((x - centre).abs(), x))
                        .max_by(|a, b| a.0.total_cmp(&b.0))
                })
                .collect();
            for (k, &i) in runs.iter().enumerate() {
                let Some((m, extreme)) = reach[k] else {
                    continue;
                };
                let others: Vec<f64> = reach
                    .iter()
                    .enumerate()
                    .filter(|&(j, r)| j != k && r.is_some())
                    .filter_map(|(_, r)| r.map(|r| r.0))
                    .collect();
                if others.len() < 2 {
                    continue;
                }
                let typical = median(others).unwrap_or(0.0);
                if typical > 0.0 && m > factor * typical && !found.iter().any(|o| o.series == i) {
                    found.push(OffScale {
                        series: i,
                        axis,
                        extreme,
                    });
                }
            }
        }
        found.sort_by_key(|o| o.series);
        found
    }

    /// The sentences that say which series are off scale: `off scale: LABEL, y max = V`.
    pub fn off_scale_notes(&self) -> Vec<String> {
        self.off_scale()
            .iter()
            .map(|o| {
                format!(
                    "off scale: {}, {} {} = {}",
                    self.series[o.series].label,
                    o.axis,
                    if o.extreme < 0.0 { "min" } else { "max" },
                    bead::significant(o.extreme, 4)
                )
            })
            .collect()
    }
}

/// The median of `values` (the mean of the middle two for an even count); `None` when empty.
fn median(mut values: Vec<f64>) -> Option<f64> {
    values.retain(|v| v.is_finite());
    if values.is_empty() {
        return None;
    }
    values.sort_by(f64::total_cmp);
    let n = values.len();
    Some(if n % 2 == 1 {
        values[n / 2]
    } else {
        0.5 * (values[n / 2 - 1] + values[n / 2])
    })
}

/// The running maximum of a time series, its envelope from t = 0: m(t) = max over s <= t of
/// y(s), drawn as steps (a new maximum is reached from the old one at the same t, so the
/// line never slopes between maxima). Non-finite points are skipped. An oscillating error
/// |E - E0| drawn on a log axis dips to -infinity at every zero crossing; its envelope does
/// not, and reads as the error reached so far.
pub fn running_max(points: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = Vec::new();
    let mut best = f64::NEG_INFINITY;
    let mut last_t = f64::NAN;
    for &(t, y) in points {
        if !(t.is_finite() && y.is_finite()) {
            continue;
        }
        last_t = t;
        if y > best {
            if best.is_finite() {
                out.push((t, best));
            }
            out.push((t, y));
            best = y;
        }
    }
    if let Some(&(t, y)) = out.last() {
        if last_t > t {
            out.push((last_t, y));
        }
    }
    out
}

/// A figure: a title over one or more panels, `columns` to a row.
#[derive(Clone, Debug)]
pub struct Figure {
    pub title: String,
    pub panels: Vec<Panel>,
    /// Panels per row (0: all in one row).
    pub columns: usize,
    /// Pixels (PNG) or SVG units.
    pub size: (u32, u32),
}

impl Figure {
    /// How many finite points of log axes are at or below zero, and so left out.
    pub fn left_out(&self) -> usize {
        self.panels
            .iter()
            .flat_map(|p| p.series.iter().map(move |s| (p, s)))
            .map(|(p, s)| {
                s.points
                    .iter()
                    .filter(|&&(x, y)| {
                        (p.x_log && x.is_finite() && x <= 0.0)
                            || (p.y_log && y.is_finite() && y <= 0.0)
                    })
                    .count()
            })
            .sum()
    }

    /// Every panel's [`Panel::off_scale_notes`], in panel order.
    pub fn off_scale_notes(&self) -> Vec<String> {
        self.panels
            .iter()
            .flat_map(Panel::off_scale_notes)
            .collect()
    }

    /// The note printed under the figure: what log axes leave out, when they leave out
    /// anything.
    pub fn note(&self) -> Option<String> {
        let count = self.left_out();
        (count > 0).then(|| {
            format!(
                "log axes leave out values at or below zero (e.g. exact zeros): {count} point{} not drawn",
                if count == 1 { "" } else { "s" }
            )
        })
    }
}

/// Write `figure` to `path`, as PNG or SVG by the extension.
pub fn write_figure(figure: &Figure, path: &Path) -> Result<(), PlotError> {
    let format = Format::from_path(path)?;
    register_fonts();
    let name = path.display().to_string();
    let draw_error = |message: String| PlotError::Draw {
        path: name.clone(),
        message,
    };
    match format {
        Format::Png => {
            let (width, height) = figure.size;
            let mut rgb = vec![0u8; width as usize * height as usize * 3];
            {
                let root = BitMapBackend::with_buffer(&mut rgb, figure.size).into_drawing_area();
                let lines = draw(figure, &root).map_err(draw_error)?;
                for line in &lines {
                    let mut points = line.points.clone();
                    if line.fill {
                        root.draw(&Polygon::new(
                            points.clone(),
                            line.color.mix(BAND_OPACITY).filled(),
                        ))
                        .map_err(|e| draw_error(e.to_string()))?;
                        if let Some(&first) = points.first() {
                            points.push(first);
                        }
                    }
                    draw_line(&root, points, line.dash, line.style()).map_err(draw_error)?;
                }
                root.present().map_err(|e| draw_error(e.to_string()))?;
            }
            let io = |error: std::io::Error| PlotError::Io {
                path: name.clone(),
                error,
            };
            let file = std::fs::File::create(path).map_err(io)?;
            let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), width, height);
            encoder.set_depth(png::BitDepth::Eight);
            // A plot has few colours: when they fit a palette, one byte per pixel instead of
            // three makes the file about three times smaller, losslessly.
            let (data, palette) = match indexed(&rgb) {
                Some((indices, palette)) => (indices, Some(palette)),
                None => (rgb, None),
            };
            match palette {
                Some(palette) => {
                    encoder.set_color(png::ColorType::Indexed);
                    encoder.set_palette(palette);
                }
                None => encoder.set_color(png::ColorType::Rgb),
            }
            let rgb = data;
            encoder.set_compression(png::Compression::Best);
            encoder.set_adaptive_filter(png::AdaptiveFilterType::Adaptive);
            let encoded = encoder
                .write_header()
                .and_then(|mut writer| writer.write_image_data(&rgb));
            encoded.map_err(|e| draw_error(format!("PNG encoding failed: {e}")))?;
        }
        Format::Svg => {
            let text = svg_string(figure).map_err(draw_error)?;
            std::fs::write(path, text).map_err(|error| PlotError::Io {
                path: name.clone(),
                error,
            })?;
        }
    }
    Ok(())
}

/// The RGB image as palette indices and the palette: exact when it has at most 256 colours;
/// otherwise the 256 most frequent colours, every other colour (in practice the
/// anti-aliased edges of text) mapped to the nearest of them.
fn indexed(rgb: &[u8]) -> Option<(Vec<u8>, Vec<u8>)> {
    use std::collections::HashMap;
    let mut counts: HashMap<[u8; 3], u64> = HashMap::new();
    for pixel in rgb.chunks_exact(3) {
        *counts.entry([pixel[0], pixel[1], pixel[2]]).or_insert(0) += 1;
    }
    let mut colours: Vec<([u8; 3], u64)> = counts.into_iter().collect();
    colours.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    let palette: Vec<[u8; 3]> = colours.iter().take(256).map(|c| c.0).collect();
    if palette.is_empty() {
        return None;
    }
    let mut lookup: HashMap<[u8; 3], u8> = palette
        .iter()
        .enumerate()
        .map(|(i, c)| (*c, i as u8))
        .collect();
    let mut indices = Vec::with_capacity(rgb.len() / 3);
    for pixel in rgb.chunks_exact(3) {
        let key = [pixel[0], pixel[1], pixel[2]];
        let index = *lookup.entry(key).or_insert_with(|| {
            let distance =
                |c: &[u8; 3]| -> i32 { (0..3).map(|k| (c[k] as i32 - key[k] as i32).pow(2)).sum() };
            (0..palette.len())
                .min_by_key(|&i| distance(&palette[i]))
                .unwrap_or(0) as u8
        });
        indices.push(index);
    }
    Some((indices, palette.concat()))
}

/// The SVG text of `figure`.
pub fn svg_string(figure: &Figure) -> Result<String, String> {
    register_fonts();
    let mut text = String::new();
    let lines;
    {
        let root = SVGBackend::with_string(&mut text, figure.size).into_drawing_area();
        lines = draw(figure, &root)?;
        root.present().map_err(|e| e.to_string())?;
    }
    // The series' lines, one polyline each (a dash pattern as a stroke-dasharray, not one
    // element per dash), before the closing tag.
    let mut polylines = String::new();
    for line in &lines {
        polylines.push_str(&line.svg());
    }
    match text.rfind("</svg>") {
        Some(end) => text.insert_str(end, &polylines),
        None => return Err("the SVG backend wrote no closing tag".into()),
    }
    Ok(text)
}

/// A series' line in pixels of the whole figure, drawn after the axes (plotters' dashed
/// paths write one SVG element per dash; this writes one per line).
#[derive(Clone, Debug)]
struct PixelLine {
    points: Vec<(i32, i32)>,
    color: RGBColor,
    width: u32,
    dash: Dash,
    /// The series' label and its panel, as `data-` attributes of the SVG element (so that
    /// a reader or a test can tell the lines apart).
    label: String,
    panel: usize,
    /// A closed outline to fill lightly ([`Style::Band`]) rather than a line.
    fill: bool,
}

/// How much of a band's colour its fill takes (the rest is the white behind).
const BAND_OPACITY: f64 = 0.3;
/// Columns on each side whose range a band's column takes in (see [`band`]).
const BAND_WINDOW: usize = 3;

impl PixelLine {
    fn style(&self) -> ShapeStyle {
        ShapeStyle::from(&self.color).stroke_width(self.width)
    }

    /// `<polyline .../>` (a band: `<polygon .../>`, filled) with the points as integers.
    fn svg(&self) -> String {
        let RGBColor(r, g, b) = self.color;
        let mut text = if self.fill {
            format!(
                "<polygon fill=\"#{r:02X}{g:02X}{b:02X}\" fill-opacity=\"{BAND_OPACITY}\" stroke=\"#{r:02X}{g:02X}{b:02X}\" stroke-width=\"{}\"",
                self.width
            )
        } else {
            format!(
                "<polyline fill=\"none\" stroke=\"#{r:02X}{g:02X}{b:02X}\" stroke-width=\"{}\"",
                self.width
            )
        };
        if let Some((on, off)) = self.dash.pattern() {
            text.push_str(&format!(" stroke-dasharray=\"{on} {off}\""));
        }
        text.push_str(&format!(
            " data-panel=\"{}\" data-series=\"{}\" points=\"",
            self.panel,
            xml_escape(&self.label)
        ));
        for (k, (x, y)) in self.points.iter().enumerate() {
            if k > 0 {
                text.push(' ');
            }
            text.push_str(&format!("{x},{y}"));
        }
        text.push_str("\"/>\n");
        text
    }
}

/// The band of a time series in pixels: per column of `bucket` pixels its highest and
/// lowest point (over the columns within [`BAND_WINDOW`]), as a closed outline (the top
/// edge left to right, then the bottom edge back).
fn band(points: &[(i32, i32)], bucket: i32) -> Vec<(i32, i32)> {
    let bucket = bucket.max(1);
    let mut columns: Vec<(i32, i32, i32)> = Vec::new(); // (x, top y, bottom y)
    for &(x, y) in points {
        let c = x.div_euclid(bucket) * bucket;
        match columns.last_mut() {
            Some(last) if last.0 == c => {
                last.1 = last.1.min(y);
                last.2 = last.2.max(y);
            }
            _ => columns.push((c, y, y)),
        }
    }
    // Each column spans the range of the columns within BAND_WINDOW of it: an oscillation
    // whose extremes fall in every few columns (not in every one: a short dip per period)
    // is a solid band rather than teeth, and a steep stretch stays continuous.
    let spread: Vec<(i32, i32, i32)> = (0..columns.len())
        .map(|k| {
            let window =
                &columns[k.saturating_sub(BAND_WINDOW)..(k + BAND_WINDOW + 1).min(columns.len())];
            let top = window.iter().map(|c| c.1).min().unwrap_or(columns[k].1);
            let bottom = window.iter().map(|c| c.2).max().unwrap_or(columns[k].2);
            (columns[k].0, top, bottom)
        })
        .collect();
    let mut outline: Vec<(i32, i32)> = spread.iter().map(|c| (c.0, c.1)).collect();
    outline.extend(spread.iter().rev().map(|c| (c.0, c.2)));
    outline
}

/// Whether a time series in pixels turns (up to down or back) more than once per
/// [`DENSE_COLUMNS`] pixel columns: an oscillation too fast to follow as a line, which a band
/// shows better. A slower one (a few periods across the panel) stays a line.
fn dense(points: &[(i32, i32)]) -> bool {
    let (Some(first), Some(last)) = (points.first(), points.last()) else {
        return false;
    };
    let columns = (last.0 - first.0).max(1);
    let mut turns = 0;
    let mut direction = 0;
    for w in points.windows(2) {
        let dy = (w[1].1 - w[0].1).signum();
        if dy != 0 {
            if direction != 0 && dy != direction {
                turns += 1;
            }
            direction = dy;
        }
    }
    turns * DENSE_COLUMNS > columns
}

/// Pixel columns per turn below which a [`Style::Band`] series is drawn as a band.
const DENSE_COLUMNS: i32 = 8;

fn xml_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A line in pixels with at most about one point per `bucket` pixels of its length: a line
/// whose x never decreases (a time series) keeps per bucket of `bucket` pixel columns the
/// lowest and the highest point, in their order (so every extreme survives, to within the
/// bucket's width); any other line (a trajectory) keeps a point when it is at least
/// `bucket` pixels from the last one kept. The first and the last points are kept.
fn thin(points: &[(i32, i32)], bucket: i32) -> Vec<(i32, i32)> {
    if points.len() <= 2 || bucket < 1 {
        return points.to_vec();
    }
    let monotone = points.windows(2).all(|w| w[1].0 >= w[0].0);
    let mut out: Vec<(i32, i32)> = vec![points[0]];
    if monotone {
        let column = |p: (i32, i32)| p.0.div_euclid(bucket);
        let mut k = 1;
        while k < points.len() - 1 {
            let c = column(points[k]);
            let start = k;
            while k < points.len() - 1 && column(points[k]) == c {
                k += 1;
            }
            let group = &points[start..k];
            // Image y grows downwards: the lowest value has the largest y.
            let (mut lo, mut hi) = (0, 0);
            for (j, p) in group.iter().enumerate() {
                if p.1 > group[lo].1 {
                    lo = j;
                }
                if p.1 < group[hi].1 {
                    hi = j;
                }
            }
            for j in [lo.min(hi), lo.max(hi)] {
                if out.last() != Some(&group[j]) {
                    out.push(group[j]);
                }
            }
        }
    } else {
        let far = |a: (i32, i32), b: (i32, i32)| {
            let (dx, dy) = ((a.0 - b.0) as i64, (a.1 - b.1) as i64);
            dx * dx + dy * dy >= (bucket as i64) * (bucket as i64)
        };
        for &p in &points[1..points.len() - 1] {
            if far(p, *out.last().unwrap_or(&p)) {
                out.push(p);
            }
        }
    }
    let last = points[points.len() - 1];
    if out.last() != Some(&last) {
        out.push(last);
    }
    out
}

/// The part of the segment a-b inside the rectangle [x0, x1] x [y0, y1] (Liang-Barsky), if
/// any.
fn clip_segment(
    a: (f64, f64),
    b: (f64, f64),
    x: (f64, f64),
    y: (f64, f64),
) -> Option<((f64, f64), (f64, f64))> {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let (mut t0, mut t1) = (0.0_f64, 1.0_f64);
    for (p, q) in [
        (-dx, a.0 - x.0),
        (dx, x.1 - a.0),
        (-dy, a.1 - y.0),
        (dy, y.1 - a.1),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let r = q / p;
            if p < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
        }
    }
    (t0 <= t1).then_some({
        (
            (a.0 + t0 * dx, a.1 + t0 * dy),
            (a.0 + t1 * dx, a.1 + t1 * dy),
        )
    })
}

/// A polyline cut to the rectangle: the pieces inside it, each a list of points.
fn clip_polyline(points: &[(f64, f64)], x: (f64, f64), y: (f64, f64)) -> Vec<Vec<(f64, f64)>> {
    let inside = |p: (f64, f64)| p.0 >= x.0 && p.0 <= x.1 && p.1 >= y.0 && p.1 <= y.1;
    let mut pieces: Vec<Vec<(f64, f64)>> = Vec::new();
    let mut current: Vec<(f64, f64)> = Vec::new();
    if points.len() == 1 && inside(points[0]) {
        return vec![points.to_vec()];
    }
    for w in points.windows(2) {
        match clip_segment(w[0], w[1], x, y) {
            Some((a, b)) => {
                if current.last() != Some(&a) {
                    if !current.is_empty() {
                        pieces.push(std::mem::take(&mut current));
                    }
                    current.push(a);
                }
                current.push(b);
                if b != w[1] {
                    pieces.push(std::mem::take(&mut current));
                }
            }
            None => {
                if !current.is_empty() {
                    pieces.push(std::mem::take(&mut current));
                }
            }
        }
    }
    if !current.is_empty() {
        pieces.push(current);
    }
    pieces
}

/// Axis value -> drawn value (log10 on log axes); None when it cannot be drawn (not finite,
/// or at or below zero on a log axis).
fn transform(v: f64, log: bool) -> Option<f64> {
    if !v.is_finite() || (log && v <= 0.0) {
        return None;
    }
    Some(if log { v.log10() } else { v })
}

/// A drawn range covering `values` with a margin. On linear axes a margin never crosses zero
/// when the values do not: a non-negative quantity gets no negative tick.
fn range(values: impl Iterator<Item = f64>, log: bool) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() || !hi.is_finite() {
        return (0.0, 1.0);
    }
    // The margin of values that span more than f64::MAX is computed without overflowing,
    // and the range clamped to finite numbers (such a range is not drawn: `drawable`).
    let (mut low, mut high) = if hi - lo <= 0.0 {
        let pad = if log { 1.0 } else { lo.abs().max(1.0) * 0.1 };
        (lo - pad, hi + pad)
    } else {
        let pad = if log { 0.25 } else { 0.05 * hi - 0.05 * lo };
        (lo - pad, hi + pad)
    };
    (low, high) = (low.max(f64::MIN), high.min(f64::MAX));
    if !log {
        if lo >= 0.0 && low < 0.0 {
            low = 0.0;
        }
        if hi <= 0.0 && high > 0.0 {
            high = 0.0;
        }
    }
    (low, high)
}

/// Tick labels on an axis.
const LABELS: usize = 8;

/// The spacing of about [`LABELS`] round ticks (1, 2 or 5 times a power of ten) over a
/// range of this width.
fn tick_step(width: f64) -> f64 {
    if !(width > 0.0 && width.is_finite()) {
        return 1.0;
    }
    let raw = width / LABELS as f64;
    let power = 10f64.powf(raw.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * power)
        .find(|&step| step >= raw)
        .unwrap_or(10.0 * power)
}

/// How tick labels of one axis are written: with the digits their spacing needs, so that
/// neighbouring ticks never read alike. When the values are large against their spread (a
/// near-constant column: 112500.0001 to 112500.0003, or -4.905 +- 1e-12), the labels would
/// need more than [`TickFormat::MAX_DIGITS`] significant digits; they then show the value
/// minus a round offset, and the axis label says `value = tick + OFFSET`.
#[derive(Clone, Copy, Debug)]
struct TickFormat {
    log: bool,
    /// Labels show -v (an axis drawn pointing down is drawn negated).
    negate: bool,
    step: f64,
    /// Exponent notation, when the values are very large or very small.
    exponent: bool,
    /// Subtracted from every shown value (0: none).
    offset: f64,
    /// Decimals that write the offset exactly.
    offset_decimals: usize,
}

impl TickFormat {
    /// Most significant digits of a tick label before an offset is taken out.
    const MAX_DIGITS: i32 = 6;

    fn new(range: (f64, f64), log: bool, negate: bool) -> Self {
        let span = range.1 - range.0;
        let step = tick_step(span);
        let shown = |v: f64| if negate { -v } else { v };
        let (a, b) = (shown(range.0), shown(range.1));
        let largest = a.abs().max(b.abs());
        let mut offset = 0.0;
        let mut offset_decimals = 0;
        if !log && largest > 0.0 && span > 0.0 && span.is_finite() {
            let digits = largest.log10().floor() - step.log10().floor() + 1.0;
            if digits > Self::MAX_DIGITS as f64 {
                // A round number at the decade above the spread, near the middle.
                let power = span.log10().floor() + 1.0;
                let unit = 10f64.powf(power);
                offset = (0.5 * (a + b) / unit).round() * unit;
                offset_decimals = (-power).max(0.0) as usize;
            }
        }
        let largest = (a - offset).abs().max((b - offset).abs());
        TickFormat {
            log,
            negate,
            step,
            exponent: !log && largest > 0.0 && !(1e-3..1e5).contains(&largest),
            offset,
            offset_decimals,
        }
    }

    /// `value = tick + 112500`, `value = tick - 4.905`, when the labels are offset.
    fn offset_text(&self) -> Option<String> {
        if self.offset == 0.0 {
            return None;
        }
        let mut number = format!("{:.*}", self.offset_decimals.min(17), self.offset.abs());
        if number.contains('.') {
            number = number
                .trim_end_matches('0')
                .trim_end_matches('.')
                .to_string();
        }
        let sign = if self.offset < 0.0 { '-' } else { '+' };
        Some(format!("value = tick {sign} {number}"))
    }

    fn label(&self, drawn: f64) -> String {
        let v = if self.negate { -drawn } else { drawn } - self.offset;
        if self.log {
            if (v - v.round()).abs() < 1e-9 {
                return format!("1e{}", v.round() as i64);
            }
            // Between powers of ten: two significant digits, in plain notation where short.
            let value = 10f64.powf(v);
            let rounded: f64 = format!("{value:.1e}").parse().unwrap_or(value);
            return if (1e-3..1e5).contains(&rounded) {
                format!("{rounded}")
            } else {
                bead::significant(rounded, 2)
            };
        }
        if v.abs() < 1e-9 * self.step {
            return "0".into();
        }
        if self.exponent {
            // Mantissa digits down to the spacing's.
            let digits = (v.abs().log10().floor() - self.step.log10().floor()).max(0.0) as usize;
            return format!("{:.*e}", digits, v);
        }
        let mut decimals = (-self.step.log10()).ceil().max(0.0) as usize;
        let scaled = self.step * 10f64.powi(decimals as i32);
        if (scaled - scaled.round()).abs() > 1e-6 {
            decimals += 1;
        }
        format!("{:.*}", decimals.min(15), v)
    }

    /// The axis label with the offset, when there is one.
    fn describe(&self, label: &str) -> String {
        match self.offset_text() {
            Some(offset) => format!("{label}   [{offset}]"),
            None => label.to_string(),
        }
    }
}

fn draw<DB: DrawingBackend>(
    figure: &Figure,
    root: &DrawingArea<DB, Shift>,
) -> Result<Vec<PixelLine>, String> {
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(err)?;
    let note = figure.note();
    let (body, footer) = if note.is_some() {
        let h = root.dim_in_pixel().1;
        root.split_vertically(h.saturating_sub(22))
    } else {
        let h = root.dim_in_pixel().1;
        root.split_vertically(h)
    };
    if let Some(note) = &note {
        footer
            .draw(&Text::new(
                note.clone(),
                (10, 4),
                (FAMILY, 13).into_font().color(&BLACK.mix(0.8)),
            ))
            .map_err(err)?;
    }
    let body = body.titled(&figure.title, (FAMILY, 20)).map_err(err)?;
    let n = figure.panels.len().max(1);
    let columns = if figure.columns == 0 {
        n
    } else {
        figure.columns.min(n)
    };
    let areas = body.split_evenly((n.div_ceil(columns), columns));
    // Panels stacked in one column share their x axis: the same range and the same plotting
    // width (one legend width for all), so that their time axes line up.
    let stacked = columns == 1 && figure.panels.len() > 1;
    let width = body.dim_in_pixel().0;
    let shared = Shared {
        legend_width: if stacked {
            figure
                .panels
                .iter()
                .filter_map(|p| legend_width(p, width))
                .max()
        } else {
            None
        },
        x_range: if stacked
            && figure.panels.iter().all(|p| !p.equal_aspect)
            && figure.panels.windows(2).all(|w| w[0].x_log == w[1].x_log)
        {
            let (lo, hi) = figure
                .panels
                .iter()
                .map(|p| extent(p, &drawn_points(p)).0)
                .fold((f64::INFINITY, f64::NEG_INFINITY), |a, b| {
                    (a.0.min(b.0), a.1.max(b.1))
                });
            (lo <= hi).then(|| range([lo, hi].into_iter(), figure.panels[0].x_log))
        } else {
            None
        },
    };
    let mut lines = Vec::new();
    for (index, (panel, area)) in figure.panels.iter().zip(&areas).enumerate() {
        draw_panel(panel, index, area, &shared, &mut lines)?;
    }
    Ok(lines)
}

/// What the panels of a figure share.
struct Shared {
    /// The legend's width in every panel (stacked panels), else each its own.
    legend_width: Option<u32>,
    /// The x range of every panel (stacked panels), else each its own.
    x_range: Option<(f64, f64)>,
}

/// The drawn points of each series of `panel` (log10 on log axes, y negated on an axis
/// pointing down), NaN where a point cannot be drawn: the line breaks there.
fn drawn_points(panel: &Panel) -> Vec<Vec<(f64, f64)>> {
    panel
        .series
        .iter()
        .map(|s| {
            s.points
                .iter()
                .map(
                    |&(x, y)| match (transform(x, panel.x_log), transform(y, panel.y_log)) {
                        (Some(x), Some(y)) => (x, if panel.y_down { -y } else { y }),
                        _ => (f64::NAN, f64::NAN),
                    },
                )
                .collect()
        })
        .collect()
}

/// The smallest and largest drawn x and y of the series that set the panel's scale (all
/// but those off scale); infinite when there are none.
fn extent(panel: &Panel, drawn: &[Vec<(f64, f64)>]) -> ((f64, f64), (f64, f64)) {
    let off: Vec<usize> = panel.off_scale().iter().map(|o| o.series).collect();
    let mut x = (f64::INFINITY, f64::NEG_INFINITY);
    let mut y = x;
    for (i, points) in drawn.iter().enumerate() {
        if off.contains(&i) {
            continue;
        }
        for p in points.iter().filter(|p| p.0.is_finite() && p.1.is_finite()) {
            x = (x.0.min(p.0), x.1.max(p.0));
            y = (y.0.min(p.1), y.1.max(p.1));
        }
    }
    (x, y)
}

/// The legend's width in a panel `width` pixels wide: at least 110 px, at most 2/5 of the
/// panel (never a panic on a narrow one); `None` when no series is named.
fn legend_width(panel: &Panel, width: u32) -> Option<u32> {
    let longest = panel
        .series
        .iter()
        .filter(|s| !s.label.is_empty())
        .map(|s| s.label.chars().count())
        .max()? as u32;
    // Note lines are in a smaller font, without the line sample.
    let note = panel
        .legend_note
        .iter()
        .map(|l| l.chars().count() as u32 * 6 + 12)
        .max()
        .unwrap_or(0);
    Some((longest * 7 + 48).max(note).max(110).min(width * 2 / 5))
}

/// Why a panel has nothing to draw, in words.
fn empty_message(panel: &Panel) -> String {
    let finite = panel
        .series
        .iter()
        .flat_map(|s| &s.points)
        .any(|p| p.0.is_finite() && p.1.is_finite());
    if finite && (panel.x_log || panel.y_log) {
        format!(
            "no data: no value above zero for the log {}",
            match (panel.x_log, panel.y_log) {
                (true, true) => "axes",
                (false, true) => "y axis",
                _ => "x axis",
            }
        )
    } else {
        "no data: no finite value".to_string()
    }
}

/// Whether an axis over `range` can be drawn: its width a finite number (values from
/// -1e308 to 1e308 span more than f64::MAX, and no tick spacing divides an infinite width).
fn drawable(range: (f64, f64)) -> bool {
    (range.1 - range.0).is_finite()
}

/// What a panel whose values span more than f64::MAX says instead of its curves: each
/// axis whose drawn range (the values with their margin, `(extent, range)`) cannot be
/// drawn, by its values.
fn too_wide_message(x: ((f64, f64), (f64, f64)), y: ((f64, f64), (f64, f64))) -> String {
    let axis = |name: &str, ((lo, hi), range): ((f64, f64), (f64, f64))| {
        (!drawable(range)).then(|| format!("{name} from {lo:e} to {hi:e}"))
    };
    let mut wide: Vec<String> = [axis("x", x), axis("y", y)].into_iter().flatten().collect();
    if wide.is_empty() {
        wide.push("at equal scales".into());
    }
    format!(
        "not drawn: the values span more than the largest number ({})",
        wide.join(", ")
    )
}

/// The runs of drawable points between non-finite ones.
fn segments(points: &[(f64, f64)]) -> Vec<Vec<(f64, f64)>> {
    let mut segments = vec![Vec::new()];
    for &p in points {
        if p.0.is_finite() && p.1.is_finite() {
            if let Some(last) = segments.last_mut() {
                last.push(p);
            }
        } else if segments.last().is_some_and(|s| !s.is_empty()) {
            segments.push(Vec::new());
        }
    }
    segments.retain(|s| !s.is_empty());
    segments
}

/// Margins of a panel's chart (pixels): around it, and the label areas below and left.
const MARGIN: u32 = 8;
const X_LABEL_AREA: u32 = 44;
const Y_LABEL_AREA: u32 = 72;

/// Widen the narrower of two drawn ranges about its centre so that a unit of each takes the
/// same length on a plotting area of `width` x `height` pixels.
fn equalize(x: (f64, f64), y: (f64, f64), width: u32, height: u32) -> ((f64, f64), (f64, f64)) {
    let (w, h) = (width.max(1) as f64, height.max(1) as f64);
    let (per_x, per_y) = ((x.1 - x.0) / w, (y.1 - y.0) / h);
    let widen = |r: (f64, f64), per: f64, pixels: f64| {
        let centre = 0.5 * (r.0 + r.1);
        let half = 0.5 * per * pixels;
        (centre - half, centre + half)
    };
    if per_x > per_y {
        (x, widen(y, per_x, h))
    } else {
        (widen(x, per_y, w), y)
    }
}

const COLORS: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// The colour of palette entry `index`.
fn palette(index: usize) -> RGBColor {
    COLORS[index % COLORS.len()]
}

/// `c` 45% of the way to white: a lighter shade of the same hue.
fn lighter(c: RGBColor) -> RGBColor {
    let mix = |v: u8| (f64::from(v) + 0.45 * (255.0 - f64::from(v))).round() as u8;
    RGBColor(mix(c.0), mix(c.1), mix(c.2))
}

/// Draw `points` (already split at breaks) as a line with `dash`.
fn draw_line<DB: DrawingBackend, CT: CoordTranslate>(
    area: &DrawingArea<DB, CT>,
    points: Vec<CT::From>,
    dash: Dash,
    style: ShapeStyle,
) -> Result<(), String>
where
    CT::From: Clone,
{
    let result = match dash.pattern() {
        None => area.draw(&PathElement::new(points, style)),
        Some((on, off)) => area.draw(&DashedPathElement::new(points, on, off, style)),
    };
    result.map_err(|e| e.to_string())
}

/// A marker of `shape` centred at `at` (a coordinate of `area`).
fn draw_marker<DB: DrawingBackend, CT: CoordTranslate>(
    area: &DrawingArea<DB, CT>,
    at: CT::From,
    shape: Marker,
    color: RGBColor,
) -> Result<(), String>
where
    CT::From: Clone,
{
    let size = 4;
    let result = match shape {
        Marker::Circle => {
            area.draw(&(EmptyElement::at(at) + Circle::new((0, 0), size, color.filled())))
        }
        Marker::Square => area.draw(
            &(EmptyElement::at(at)
                + Rectangle::new([(-size, -size), (size, size)], color.filled())),
        ),
        Marker::Triangle => area.draw(
            &(EmptyElement::at(at)
                + Polygon::new(
                    vec![(0, -size - 1), (size + 1, size), (-size - 1, size)],
                    color.filled(),
                )),
        ),
        Marker::Cross => area.draw(
            &(EmptyElement::at(at)
                + PathElement::new(vec![(-size, -size), (size, size)], color.stroke_width(2))
                + PathElement::new(vec![(-size, size), (size, -size)], color.stroke_width(2))),
        ),
    };
    result.map_err(|e| e.to_string())
}

fn draw_panel<DB: DrawingBackend>(
    panel: &Panel,
    index: usize,
    area: &DrawingArea<DB, Shift>,
    shared: &Shared,
    lines: &mut Vec<PixelLine>,
) -> Result<(), String> {
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    let drawn = drawn_points(panel);
    let off_scale = panel.off_scale();
    let off: Vec<usize> = off_scale.iter().map(|o| o.series).collect();
    let (x_extent, y_extent) = extent(panel, &drawn);
    let has_data = x_extent.0 <= x_extent.1;
    let mut x_range = shared
        .x_range
        .unwrap_or_else(|| range([x_extent.0, x_extent.1].into_iter(), panel.x_log));
    let mut y_range = range([y_extent.0, y_extent.1].into_iter(), panel.y_log);
    // Colours: the series' own, or the next free one of the panel.
    let mut next_color = 0;
    let colors: Vec<RGBColor> = panel
        .series
        .iter()
        .map(|s| match (s.style, s.look.color) {
            (Style::Reference, _) => RGBColor(190, 190, 190),
            (_, Some(c)) if s.look.light => lighter(palette(c)),
            (_, Some(c)) => palette(c),
            (_, None) => {
                next_color += 1;
                palette(next_color - 1)
            }
        })
        .collect();
    // The legend beside the data, when any series is named.
    let labelled: Vec<usize> = (0..panel.series.len())
        .filter(|&i| !panel.series[i].label.is_empty())
        .collect();
    let (width, _) = area.dim_in_pixel();
    let (plot_area, legend_area) = match shared.legend_width.or(legend_width(panel, width)) {
        Some(legend) if !labelled.is_empty() || shared.legend_width.is_some() => {
            let (left, right) = area.split_horizontally(width.saturating_sub(legend));
            (left, Some(right))
        }
        _ => (area.clone(), None),
    };
    let plot_area = plot_area.titled(&panel.title, (FAMILY, 15)).map_err(err)?;
    if panel.equal_aspect && has_data {
        let (w, h) = plot_area.dim_in_pixel();
        (x_range, y_range) = equalize(
            x_range,
            y_range,
            w.saturating_sub(2 * MARGIN + Y_LABEL_AREA),
            h.saturating_sub(2 * MARGIN + X_LABEL_AREA),
        );
    }
    let too_wide = has_data && !(drawable(x_range) && drawable(y_range));
    if !has_data || too_wide {
        // An honest empty panel: no invented axes, the reason in words.
        let message = if too_wide {
            too_wide_message((x_extent, x_range), (y_extent, y_range))
        } else {
            empty_message(panel)
        };
        let (w, h) = plot_area.dim_in_pixel();
        plot_area
            .draw(&Text::new(
                message,
                ((w / 2) as i32, (h / 2) as i32),
                (FAMILY, 15)
                    .into_font()
                    .color(&BLACK.mix(0.75))
                    .pos(Pos::new(HPos::Center, VPos::Center)),
            ))
            .map_err(err)?;
        plot_area
            .draw(&Rectangle::new(
                [
                    (MARGIN as i32, 0),
                    ((w - MARGIN) as i32, (h - MARGIN) as i32),
                ],
                BLACK.mix(0.15),
            ))
            .map_err(err)?;
        return Ok(());
    }
    let mut chart = ChartBuilder::on(&plot_area)
        .margin(MARGIN)
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(Y_LABEL_AREA)
        .build_cartesian_2d(x_range.0..x_range.1, y_range.0..y_range.1)
        .map_err(err)?;
    let x_format = TickFormat::new(x_range, panel.x_log, false);
    let y_format = TickFormat::new(y_range, panel.y_log, panel.y_down);
    let x_desc = x_format.describe(&panel.x_label);
    let y_desc = y_format.describe(&panel.y_label);
    let x_fmt = move |v: &f64| x_format.label(*v);
    let y_fmt = move |v: &f64| y_format.label(*v);
    chart
        .configure_mesh()
        .x_desc(x_desc.as_str())
        .y_desc(y_desc.as_str())
        .x_labels(LABELS)
        .y_labels(LABELS)
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .label_style((FAMILY, 12))
        .axis_desc_style((FAMILY, 13))
        .light_line_style(WHITE.mix(0.0))
        .bold_line_style(BLACK.mix(0.08))
        .draw()
        .map_err(err)?;
    let data = chart.plotting_area();
    // References first, so that they lie under the runs.
    let order: Vec<usize> = (0..panel.series.len())
        .filter(|&i| panel.series[i].style == Style::Reference)
        .chain((0..panel.series.len()).filter(|&i| panel.series[i].style != Style::Reference))
        .collect();
    let inside = |p: &(f64, f64)| {
        p.0 >= x_range.0 && p.0 <= x_range.1 && p.1 >= y_range.0 && p.1 <= y_range.1
    };
    // Pixels per kept point: 2 columns per min/max pair along a time series; 4 px chords
    // along a path (its sagitta stays below 0.1 px where the path bends less than a 20 px
    // radius), which a path retracing itself over many cycles needs to stay small.
    let thinning = if panel.equal_aspect { 4 } else { 2 };
    for &i in &order {
        let series = &panel.series[i];
        let color = colors[i];
        let width = match series.style {
            Style::Reference => 6,
            _ if series.look.dash == Dash::Solid => 1,
            _ => 2,
        };
        // Cut at the frame (a series off scale leaves it), then at most a point or two per
        // two pixels: what an SVG needs to show the line, extremes included.
        for segment in segments(&drawn[i]) {
            // A band is clamped to the frame (its extremes at the edge), not cut there: cut,
            // an oscillation reaching the edge would be a row of separate teeth.
            let pieces = if series.style == Style::Band {
                let clamped: Vec<(f64, f64)> = segment
                    .iter()
                    .filter(|p| p.0 >= x_range.0 && p.0 <= x_range.1)
                    .map(|p| {
                        (
                            p.0,
                            p.1.max(y_range.0.min(y_range.1))
                                .min(y_range.0.max(y_range.1)),
                        )
                    })
                    .collect();
                vec![clamped]
            } else {
                clip_polyline(&segment, x_range, y_range)
            };
            for piece in pieces {
                if piece.is_empty() {
                    continue;
                }
                let pixels: Vec<(i32, i32)> =
                    piece.iter().map(|p| chart.backend_coord(p)).collect();
                let fill = series.style == Style::Band && dense(&pixels);
                lines.push(PixelLine {
                    points: if fill {
                        band(&pixels, thinning)
                    } else {
                        thin(&pixels, thinning)
                    },
                    color,
                    width,
                    dash: series.look.dash,
                    label: series.label.clone(),
                    panel: index,
                    fill,
                });
            }
        }
        let marker = match (series.style, series.look.marker) {
            (Style::Reference, _) => None,
            (Style::LineAndMarkers, None) => Some(Marker::Circle),
            (_, marker) => marker,
        };
        if let Some(shape) = marker {
            let points: Vec<(f64, f64)> = drawn[i]
                .iter()
                .copied()
                .filter(|p| p.0.is_finite() && p.1.is_finite())
                .collect();
            // Every point of a work-precision curve; about a dozen along a time series,
            // offset by the series' number so that markers of overlapping series do not
            // hide each other.
            let every = if series.style == Style::LineAndMarkers {
                1
            } else {
                (points.len() / 12).max(1)
            };
            let offset = if every > 1 {
                (i * every / 5) % every
            } else {
                0
            };
            for p in points
                .iter()
                .skip(offset)
                .step_by(every)
                .filter(|p| inside(p))
            {
                draw_marker(data, *p, shape, color)?;
            }
        }
    }
    // Series off scale: said inside the frame, at its top left, in their colour.
    let base = plot_area.get_base_pixel();
    let corner = chart.backend_coord(&(x_range.0, y_range.1));
    for (row, (o, note)) in off_scale.iter().zip(panel.off_scale_notes()).enumerate() {
        plot_area
            .draw(&Text::new(
                format!("{note} (drawn clipped at the frame)"),
                (
                    corner.0 - base.0 + 6,
                    corner.1 - base.1 + 4 + 15 * row as i32,
                ),
                (FAMILY, 12).into_font().color(&colors[o.series]),
            ))
            .map_err(err)?;
    }
    if let Some(legend) = legend_area {
        draw_legend(panel, &labelled, &colors, &off, &legend)?;
    }
    Ok(())
}

/// The legend of a panel in its own area beside the data: a line sample (dash, colour,
/// marker) and the label per named series, as many as fit, then how many more there are.
fn draw_legend<DB: DrawingBackend>(
    panel: &Panel,
    labelled: &[usize],
    colors: &[RGBColor],
    off_scale: &[usize],
    area: &DrawingArea<DB, Shift>,
) -> Result<(), String> {
    let (_, height) = area.dim_in_pixel();
    for (row, line) in panel.legend_note.iter().enumerate() {
        area.draw(&Text::new(
            line.clone(),
            (6, 30 + 14 * row as i32),
            (FAMILY, 11).into_font().color(&BLACK.mix(0.75)),
        ))
        .map_err(|e| e.to_string())?;
    }
    let top = 34i32 + 14 * panel.legend_note.len() as i32;
    let available = height.saturating_sub(top as u32 + 8) as usize;
    let (font, spacing) = if labelled.len() * 17 <= available {
        (12, 17)
    } else {
        (11, 14)
    };
    let fits = (available / spacing).max(1);
    let shown = if labelled.len() <= fits {
        labelled.len()
    } else {
        fits - 1
    };
    for (row, &i) in labelled.iter().take(shown).enumerate() {
        let series = &panel.series[i];
        let y = top + (row * spacing) as i32 + spacing as i32 / 2;
        let color = colors[i];
        let style = match series.style {
            Style::Reference => ShapeStyle::from(&color).stroke_width(6),
            _ => ShapeStyle::from(&color).stroke_width(2),
        };
        draw_line(area, vec![(6, y), (34, y)], series.look.dash, style)?;
        let marker = match (series.style, series.look.marker) {
            (Style::Reference, _) => None,
            (Style::LineAndMarkers, None) => Some(Marker::Circle),
            (_, marker) => marker,
        };
        if let Some(shape) = marker {
            draw_marker(area, (20, y), shape, color)?;
        }
        let label = if off_scale.contains(&i) {
            format!("{} (off scale)", series.label)
        } else {
            series.label.clone()
        };
        area.draw(&Text::new(
            label,
            (40, y - font / 2 - 1),
            (FAMILY, font).into_font(),
        ))
        .map_err(|e| e.to_string())?;
    }
    if shown < labelled.len() {
        let y = top + (shown * spacing) as i32;
        area.draw(&Text::new(
            format!("... and {} more", labelled.len() - shown),
            (40, y),
            (FAMILY, font).into_font().color(&BLACK.mix(0.7)),
        ))
        .map_err(|e| e.to_string())?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn minmax_keeps_the_extremes_and_a_bounded_count() {
        let mut d = MinMaxDecimator::new(50);
        for i in 0..100_000u64 {
            let t = i as f64;
            let y = match i {
                31_337 => 1e6,
                77_777 => -1e6,
                _ => (t * 0.01).sin(),
            };
            d.push(t, y);
        }
        let points = d.points();
        assert!(points.len() <= 100, "{}", points.len());
        assert!(points.contains(&(31_337.0, 1e6)));
        assert!(points.contains(&(77_777.0, -1e6)));
        // Time order.
        assert!(points.windows(2).all(|w| w[0].0 <= w[1].0));
        // The envelope of the smooth part survives too.
        let max = points
            .iter()
            .filter(|p| p.1 < 10.0)
            .map(|p| p.1)
            .fold(f64::MIN, f64::max);
        assert!(max > 0.999, "{max}");
    }

    #[test]
    fn minmax_keeps_everything_while_it_fits_and_skips_nan() {
        let mut d = MinMaxDecimator::new(10);
        for i in 0..8 {
            d.push(i as f64, if i == 3 { f64::NAN } else { i as f64 });
        }
        assert_eq!(d.points().len(), 7);
        assert_eq!(d.bucket_width(), 1);
    }

    #[test]
    fn head_tail_keeps_both_ends_in_order_with_a_break_between() {
        let mut d = HeadTail::new(2, 3);
        for i in 0..10 {
            d.push(&[i as f64, 0.0]);
        }
        let t: Vec<f64> = d.rows().iter().map(|r| r[0]).collect();
        assert_eq!(t.len(), 7);
        assert_eq!(&t[..3], &[0.0, 1.0, 2.0]);
        assert!(t[3].is_nan());
        assert_eq!(&t[4..], &[7.0, 8.0, 9.0]);
        let mut short = HeadTail::new(1, 3);
        for i in 0..5 {
            short.push(&[i as f64]);
        }
        let t: Vec<f64> = short.rows().iter().map(|r| r[0]).collect();
        assert_eq!(t, vec![0.0, 1.0, 2.0, 3.0, 4.0]);
    }

    #[test]
    fn a_fast_oscillation_is_a_solid_band_and_a_slow_one_a_line() {
        // Short dips to y = 100 px every 5 columns of 2 px (an energy error's dips), the rest
        // at y = 10: every column of the band spans 10..100, no teeth.
        let dips: Vec<(i32, i32)> = (0..200)
            .map(|x| (x, if x % 10 == 0 { 100 } else { 10 }))
            .collect();
        assert!(dense(&dips));
        // Four periods across 600 columns: a line, not a band.
        let slow: Vec<(i32, i32)> = (0..600)
            .map(|x| {
                (
                    x,
                    (100.0 + 50.0 * (x as f64 * 4.0 * std::f64::consts::TAU / 600.0).sin()) as i32,
                )
            })
            .collect();
        assert!(!dense(&slow));
        // (The last columns' windows are cut short by the edge: they see the dip at x = 190
        // only up to column 196.)
        let outline = band(&dips, 2);
        let (top, bottom) = outline.split_at(outline.len() / 2);
        assert!(top.iter().all(|p| p.1 == 10), "{top:?}");
        assert!(
            bottom.iter().filter(|p| p.0 <= 196).all(|p| p.1 == 100),
            "{bottom:?}"
        );
        // A slow ramp (1 px per 10 columns) stays a line a few pixels thick.
        let ramp: Vec<(i32, i32)> = (0..200).map(|x| (x, x / 20)).collect();
        let outline = band(&ramp, 2);
        let n = outline.len() / 2;
        for k in 0..n {
            let (t, b) = (outline[k], outline[2 * n - 1 - k]);
            assert_eq!(t.0, b.0);
            assert!(b.1 - t.1 <= 1, "{t:?} {b:?}");
        }
    }

    #[test]
    fn segments_break_at_nan() {
        let s = segments(&[(0.0, 1.0), (1.0, f64::NAN), (2.0, 1.0), (3.0, 1.0)]);
        assert_eq!(s, vec![vec![(0.0, 1.0)], vec![(2.0, 1.0), (3.0, 1.0)]]);
    }

    #[test]
    fn stride_keeps_every_kth_row_and_the_last() {
        let mut d = StrideDecimator::new(2, 10);
        for i in 0..1001 {
            d.push(&[i as f64, -(i as f64)]);
        }
        let rows = d.rows();
        assert!(rows.len() <= 11, "{}", rows.len());
        assert_eq!(rows[0], &[0.0, -0.0]);
        assert_eq!(*rows.last().unwrap(), &[1000.0, -1000.0]);
        let step = rows[1][0] - rows[0][0];
        assert!(rows[..rows.len() - 1]
            .windows(2)
            .all(|w| w[1][0] - w[0][0] == step));
    }

    fn figure() -> Figure {
        Figure {
            title: "Test figure".into(),
            panels: vec![Panel {
                title: "errors".into(),
                x_label: "t (s)".into(),
                y_label: "|C|".into(),
                y_log: true,
                series: vec![
                    Series::line(
                        "a",
                        vec![(0.0, 0.0), (1.0, 1e-3), (2.0, f64::NAN), (3.0, 1.0)],
                    ),
                    Series::line("b", vec![(0.0, 1e-8), (3.0, 1e-6)]),
                ],
                ..Panel::default()
            }],
            columns: 0,
            size: (640, 400),
        }
    }

    /// Values that span more than f64::MAX (a run blown up to +-1e308) draw a panel that
    /// says so, where the axis' ticks once looped forever; one just inside still draws.
    #[test]
    fn values_spanning_more_than_the_largest_number_are_said_not_drawn() {
        let huge = vec![(0.0, -1e308), (1.0, 1e308)];
        let cases = [
            (huge.clone(), false, "y from -1e308 to 1e308"),
            (
                huge.iter().map(|&(t, v)| (v, t)).collect(),
                false,
                "x from -1e308 to 1e308",
            ),
            (huge.clone(), true, "y from -1e308 to 1e308"),
        ];
        for (points, equal_aspect, said) in cases {
            let mut wide = figure();
            wide.panels[0].y_log = false;
            wide.panels[0].equal_aspect = equal_aspect;
            wide.panels[0].series = vec![Series::line("a", points)];
            let svg = svg_string(&wide).unwrap();
            assert!(svg.contains("not drawn: the values span more"), "{said}");
            assert!(svg.contains(said), "{said}");
        }
        let mut inside = figure();
        inside.panels[0].y_log = false;
        inside.panels[0].series = vec![Series::line("a", vec![(0.0, -8e307), (1.0, 8e307)])];
        let svg = svg_string(&inside).unwrap();
        assert!(!svg.contains("not drawn"));
    }

    #[test]
    fn svg_parses_as_xml_and_has_the_labels() {
        let svg = svg_string(&figure()).unwrap();
        let doc = roxmltree::Document::parse(&svg).unwrap();
        assert_eq!(doc.root_element().tag_name().name(), "svg");
        assert!(svg.contains("Test figure"));
        assert!(svg.contains("t (s)"));
        assert!(
            svg.contains(
                "log axes leave out values at or below zero (e.g. exact zeros): 1 point not drawn"
            ),
            "the note on the left-out zero"
        );
    }

    #[test]
    fn png_decodes_with_the_right_size_and_is_not_blank() {
        let dir = std::env::temp_dir().join(format!("bead-plot-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("f.png");
        write_figure(&figure(), &path).unwrap();
        let decoder = png::Decoder::new(std::fs::File::open(&path).unwrap());
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!((info.width, info.height), (640, 400));
        let data = &buf[..info.buffer_size()];
        let dark = data
            .chunks(3)
            .filter(|p| p.iter().all(|&c| c < 100))
            .count();
        assert!(dark > 500, "too few dark pixels: {dark}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// Neighbouring ticks never read alike, zero reads "0", an axis drawn pointing down shows
    /// the values it stands for, and log ticks between powers of ten are short.
    #[test]
    fn tick_labels_carry_the_digits_their_spacing_needs() {
        // 110000..110070: the labels "1.1e5" seven times, before.
        let format = TickFormat::new((110_000.0, 110_070.0), false, false);
        let labels: Vec<String> = (0..8)
            .map(|k| format.label(110_000.0 + 10.0 * k as f64))
            .collect();
        let mut distinct = labels.clone();
        distinct.dedup();
        assert_eq!(distinct.len(), 8, "{labels:?}");
        assert_eq!(labels[1], "1.1001e5");
        let format = TickFormat::new((-0.1, 3.0), false, false);
        assert_eq!(format.label(1.5), "1.5");
        assert_eq!(format.label(2.0), "2.0");
        assert_eq!(format.label(1e-17), "0");
        let down = TickFormat::new((-225.0, 10.0), false, true);
        assert_eq!(down.label(-200.0), "200");
        let log = TickFormat::new((2.5, 3.4), true, false);
        assert_eq!(log.label(3.0), "1e3");
        assert_eq!(log.label(2.8), "630");
        assert_eq!(tick_step(0.8), 0.1);
        assert_eq!(tick_step(70.0), 10.0);
    }

    /// A non-negative quantity gets no negative tick; one that crosses zero keeps its margin.
    #[test]
    fn ranges_do_not_cross_zero_for_one_signed_data() {
        assert_eq!(range([0.0, 2.0].into_iter(), false).0, 0.0);
        assert_eq!(range([-2.0, 0.0].into_iter(), false).1, 0.0);
        let (lo, hi) = range([-1.0, 1.0].into_iter(), false);
        assert!(lo < -1.0 && hi > 1.0);
        // Log axes never see values at or below zero.
        assert_eq!(transform(0.0, true), None);
        assert_eq!(transform(-1.0, true), None);
        assert_eq!(transform(100.0, true), Some(2.0));
    }

    /// A panel too narrow for the legend's minimum width still draws.
    #[test]
    fn a_narrow_panel_with_a_legend_draws() {
        let mut narrow = figure();
        narrow.size = (200, 150);
        assert!(svg_string(&narrow).is_ok());
    }

    /// Equal scales: the narrower range widens about its centre until a unit of x and one of
    /// y take the same pixels.
    #[test]
    fn equal_aspect_widens_the_narrower_range() {
        let (x, y) = equalize((-150.0, 150.0), (-10.0, 0.0), 600, 400);
        assert_eq!(x, (-150.0, 150.0));
        assert!(((y.1 - y.0) / 400.0 - 300.0 / 600.0).abs() < 1e-12, "{y:?}");
        assert!((0.5 * (y.0 + y.1) + 5.0).abs() < 1e-12);
    }

    #[test]
    fn format_by_extension() {
        assert_eq!(Format::from_path(Path::new("a.PNG")).unwrap(), Format::Png);
        assert_eq!(Format::from_path(Path::new("a.svg")).unwrap(), Format::Svg);
        assert!(Format::from_path(Path::new("a.jpg")).is_err());
        assert!(Format::from_path(Path::new("a")).is_err());
    }
}
