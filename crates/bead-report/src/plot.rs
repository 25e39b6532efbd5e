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
//! Log axes clamp values at or below [`LOG_FLOOR`] to it (the panel's `note` says so when it
//! happens) and skip NaN and infinite points. Text is drawn with DejaVu Sans, embedded in this
//! crate, so drawing a PNG needs no system font.

use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};

/// DejaVu Sans (see `assets/DejaVuSans.LICENSE`): the only font the plots use.
static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");
const FAMILY: &str = "sans-serif";

/// Values at or below this are drawn at it on log axes.
pub const LOG_FLOOR: f64 = 1e-17;

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
}

/// One named series of (x, y) points.
#[derive(Clone, Debug)]
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    pub style: Style,
}

impl Series {
    pub fn line(label: impl Into<String>, points: Vec<(f64, f64)>) -> Self {
        Series {
            label: label.into(),
            points,
            style: Style::Line,
        }
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
    pub series: Vec<Series>,
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
    /// Whether any point of a log axis is at or below [`LOG_FLOOR`] (and so drawn at it).
    pub fn clamps(&self) -> bool {
        self.panels.iter().any(|p| {
            p.series.iter().any(|s| {
                s.points.iter().any(|&(x, y)| {
                    (p.x_log && x.is_finite() && x <= LOG_FLOOR)
                        || (p.y_log && y.is_finite() && y <= LOG_FLOOR)
                })
            })
        })
    }

    /// The note printed under the figure: how log axes treat zeros, when it matters.
    pub fn note(&self) -> Option<String> {
        self.clamps().then(|| {
            format!(
                "values at or below {LOG_FLOOR:e} (e.g. exact zeros) are drawn at {LOG_FLOOR:e} on log axes"
            )
        })
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
                draw(figure, &root).map_err(draw_error)?;
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
    {
        let root = SVGBackend::with_string(&mut text, figure.size).into_drawing_area();
        draw(figure, &root)?;
        root.present().map_err(|e| e.to_string())?;
    }
    Ok(text)
}

/// Axis value -> drawn value (log10 on log axes); None when it cannot be drawn.
fn transform(v: f64, log: bool) -> Option<f64> {
    if !v.is_finite() {
        return None;
    }
    if log {
        Some(v.max(LOG_FLOOR).log10())
    } else {
        Some(v)
    }
}

/// A drawn range covering `values` with a margin.
fn range(values: impl Iterator<Item = f64>, log: bool) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() || !hi.is_finite() {
        return (0.0, 1.0);
    }
    if hi - lo <= 0.0 {
        let pad = if log { 1.0 } else { lo.abs().max(1.0) * 0.1 };
        return (lo - pad, hi + pad);
    }
    let pad = if log { 0.25 } else { 0.05 * (hi - lo) };
    (lo - pad, hi + pad)
}

/// Tick label of a drawn value.
fn tick(v: f64, log: bool) -> String {
    if log {
        if (v - v.round()).abs() < 1e-9 {
            format!("1e{}", v.round() as i64)
        } else {
            let s = format!("{:.1e}", 10f64.powf(v));
            s.replace(".0e", "e")
        }
    } else {
        let a = v.abs();
        if a != 0.0 && !(1e-3..1e5).contains(&a) {
            format!("{v:.1e}")
        } else {
            let s = format!("{v:.4}");
            let s = s.trim_end_matches('0').trim_end_matches('.');
            if s == "-0" {
                "0".into()
            } else {
                s.to_string()
            }
        }
    }
}

fn draw<DB: DrawingBackend>(figure: &Figure, root: &DrawingArea<DB, Shift>) -> Result<(), String> {
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
    for (panel, area) in figure.panels.iter().zip(&areas) {
        draw_panel(panel, area)?;
    }
    Ok(())
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

fn draw_panel<DB: DrawingBackend>(
    panel: &Panel,
    area: &DrawingArea<DB, Shift>,
) -> Result<(), String> {
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    // Drawn points, with NaN where a point cannot be drawn: the line breaks there.
    let drawn: Vec<Vec<(f64, f64)>> = panel
        .series
        .iter()
        .map(|s| {
            s.points
                .iter()
                .map(
                    |&(x, y)| match (transform(x, panel.x_log), transform(y, panel.y_log)) {
                        (Some(x), Some(y)) => (x, y),
                        _ => (f64::NAN, f64::NAN),
                    },
                )
                .collect()
        })
        .collect();
    let finite = |p: &&(f64, f64)| p.0.is_finite() && p.1.is_finite();
    let x_range = range(
        drawn.iter().flatten().filter(finite).map(|p| p.0),
        panel.x_log,
    );
    let y_range = range(
        drawn.iter().flatten().filter(finite).map(|p| p.1),
        panel.y_log,
    );
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, (FAMILY, 15))
        .margin(8)
        .x_label_area_size(40)
        .y_label_area_size(64)
        .build_cartesian_2d(x_range.0..x_range.1, y_range.0..y_range.1)
        .map_err(err)?;
    let (x_log, y_log) = (panel.x_log, panel.y_log);
    let x_fmt = move |v: &f64| tick(*v, x_log);
    let y_fmt = move |v: &f64| tick(*v, y_log);
    chart
        .configure_mesh()
        .x_desc(panel.x_label.as_str())
        .y_desc(panel.y_label.as_str())
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .label_style((FAMILY, 12))
        .axis_desc_style((FAMILY, 13))
        .light_line_style(WHITE.mix(0.0))
        .bold_line_style(BLACK.mix(0.08))
        .draw()
        .map_err(err)?;
    let mut color_index = 0;
    let mut any_label = false;
    // References first, so that they lie under the runs.
    let order: Vec<usize> = (0..panel.series.len())
        .filter(|&i| panel.series[i].style == Style::Reference)
        .chain((0..panel.series.len()).filter(|&i| panel.series[i].style != Style::Reference))
        .collect();
    for i in order {
        let series = &panel.series[i];
        let points = &drawn[i];
        let label = series.label.clone();
        any_label |= !label.is_empty();
        match series.style {
            Style::Reference => {
                let color = RGBColor(190, 190, 190);
                let style = ShapeStyle::from(&color).stroke_width(6);
                let drawn = chart
                    .draw_series(
                        segments(points)
                            .into_iter()
                            .map(move |segment| PathElement::new(segment, style)),
                    )
                    .map_err(err)?;
                if !label.is_empty() {
                    drawn
                        .label(label)
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], style));
                }
            }
            Style::Line | Style::LineAndMarkers => {
                let color = COLORS[color_index % COLORS.len()];
                color_index += 1;
                let style = ShapeStyle::from(&color).stroke_width(1);
                let drawn = chart
                    .draw_series(
                        segments(points)
                            .into_iter()
                            .map(move |segment| PathElement::new(segment, style)),
                    )
                    .map_err(err)?;
                if !label.is_empty() {
                    drawn.label(label).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                    });
                }
                if series.style == Style::LineAndMarkers {
                    chart
                        .draw_series(PointSeries::of_element(
                            points
                                .iter()
                                .copied()
                                .filter(|p| p.0.is_finite() && p.1.is_finite()),
                            3,
                            color.filled(),
                            &|c, s, st| Circle::new(c, s, st),
                        ))
                        .map_err(err)?;
                }
            }
        }
    }
    if any_label {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.3))
            .label_font((FAMILY, 11))
            .draw()
            .map_err(err)?;
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
                x_log: false,
                y_log: true,
                series: vec![
                    Series::line(
                        "a",
                        vec![(0.0, 0.0), (1.0, 1e-3), (2.0, f64::NAN), (3.0, 1.0)],
                    ),
                    Series::line("b", vec![(0.0, 1e-8), (3.0, 1e-6)]),
                ],
            }],
            columns: 0,
            size: (640, 400),
        }
    }

    #[test]
    fn svg_parses_as_xml_and_has_the_labels() {
        let svg = svg_string(&figure()).unwrap();
        let doc = roxmltree::Document::parse(&svg).unwrap();
        assert_eq!(doc.root_element().tag_name().name(), "svg");
        assert!(svg.contains("Test figure"));
        assert!(svg.contains("t (s)"));
        assert!(svg.contains("drawn at 1e-17"), "the clamping note");
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

    #[test]
    fn format_by_extension() {
        assert_eq!(Format::from_path(Path::new("a.PNG")).unwrap(), Format::Png);
        assert_eq!(Format::from_path(Path::new("a.svg")).unwrap(), Format::Svg);
        assert!(Format::from_path(Path::new("a.jpg")).is_err());
        assert!(Format::from_path(Path::new("a")).is_err());
    }
}
