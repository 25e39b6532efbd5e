//! Scenes for the viewer's tests: generated ones at scale (explicit `[[particle]]` and
//! `[[constraint]]` tables, as a scene file spells them) and the shaken parabola.
#![allow(dead_code)]

use std::fmt::Write as _;

/// A chain of `n` rods of length [`LINK`] in the x-y plane, +y down, under gravity
/// [`GRAVITY`]: particle `p0` on a rod to the anchor at the origin, each `p{i}` on a
/// rod to `p{i-1}`; at rest, straight at [`CHAIN_ANGLE`] from the downward vertical, so that
/// it swings.
///
/// Why these numbers: a chain under tension T has transverse modes up to about
/// ω = 2 sqrt(T / (m ℓ)) for links of mass m and length ℓ; at the top T ≈ n m g, so
/// ω ≈ 2 sqrt(n g / ℓ), and rattle or rk4 at dt = 1/120 need ω dt below about 2. With
/// ℓ = 1 and g = 1, ω dt = 0.53 for n = 1000 (0.17 for 100); a chain of 1000 links of
/// 1 mm under 9.81 m/s² would have ω dt ≈ 52 and fail within a few steps.
pub fn chain(n: usize, integrator: &str) -> String {
    let spacing = LINK;
    let (sin, cos) = CHAIN_ANGLE.sin_cos();
    let mut text = format!("title = \"Chain of {n}\"\n[world]\ngravity = [0.0, {GRAVITY:?}]\n");
    for i in 0..n {
        let r = (i + 1) as f64 * spacing;
        let (x, y) = (r * sin, r * cos);
        writeln!(
            text,
            "[[particle]]\nname = \"p{i}\"\nmass = 1.0\nposition = [{x:?}, {y:?}]"
        )
        .unwrap();
    }
    text.push_str("[[constraint]]\nkind = \"distance\"\nparticle = \"p0\"\nanchor = [0.0, 0.0]\n");
    for i in 1..n {
        writeln!(
            text,
            "[[constraint]]\nkind = \"distance\"\nbetween = [\"p{}\", \"p{i}\"]",
            i - 1
        )
        .unwrap();
    }
    writeln!(text, "[run]\nintegrator = \"{integrator}\"\ndt = \"1/120\"").unwrap();
    text
}

/// The angle of a chain at rest from the downward vertical (rad).
pub const CHAIN_ANGLE: f64 = 0.5;
/// The length of a chain's links.
pub const LINK: f64 = 1.0;
/// The gravity of the generated scenes (down): 1, so that their fastest modes stay within
/// what rk4 and rattle can step at dt = 1/120 (see [`chain`]; a 50 x 50 cloth of rods of
/// width 1 has ω dt ≈ 0.8 with it, 2.6 under 9.81).
pub const GRAVITY: f64 = 1.0;

/// The name of the particle at row `r`, column `c` of a cloth.
pub fn node(r: usize, c: usize) -> String {
    format!("p{r}_{c}")
}

/// The index of the particle at row `r`, column `c` of a cloth with `cols` columns.
pub fn index(cols: usize, r: usize, c: usize) -> usize {
    r * cols + c
}

/// The particles of a `rows` x `cols` cloth of width 1 in the x-y plane, row by row, at rest.
/// The rows sag by [`SAG`] in the middle: a top row pinned at both ends must not be a taut
/// straight line, where the rods and pins are singular (their gradients are dependent). In
/// 3D (`dim` 3) the rows also bow out of the plane, by up to [`BOW`] at the bottom row.
fn cloth_particles(rows: usize, cols: usize, dim: usize, text: &mut String) {
    let spacing = 1.0 / (cols - 1).max(1) as f64;
    for r in 0..rows {
        for c in 0..cols {
            // A parabola through the ends (exactly 0 there: the pins sit at y = 0).
            let (u, w) = (c as f64, (cols - 1).max(1) as f64);
            let arch = 4.0 * u * (w - u) / (w * w);
            let (x, y) = (c as f64 * spacing, r as f64 * spacing + SAG * arch);
            let position = if dim == 3 {
                let z = BOW * arch * r as f64 / (rows - 1).max(1) as f64;
                format!("[{x:?}, {y:?}, {z:?}]")
            } else {
                format!("[{x:?}, {y:?}]")
            };
            writeln!(
                text,
                "[[particle]]\nname = \"{}\"\nmass = 1.0\nposition = {position}",
                node(r, c)
            )
            .unwrap();
        }
    }
}

/// How far the middle of each row of a cloth sags below its ends.
pub const SAG: f64 = 0.05;
/// How far the middle of the bottom row of a 3D cloth bows out of the x-y plane (along z).
pub const BOW: f64 = 0.2;

/// Pins at the two top corners.
fn corner_pins(cols: usize, text: &mut String) {
    for c in [0, cols - 1] {
        writeln!(
            text,
            "[[constraint]]\nkind = \"pin\"\nparticle = \"{}\"",
            node(0, c)
        )
        .unwrap();
    }
}

/// A `rows` x `cols` cloth of rods (distance constraints between neighbours along rows, then
/// along columns, row by row) pinned at its two top corners, in the x-y plane (+y down).
pub fn cloth(rows: usize, cols: usize, integrator: &str) -> String {
    cloth_in(rows, cols, 2, integrator)
}

/// The cloth of [`cloth`] in 3D, as `scenes/cloth.toml` is: the same x and y (gravity along
/// +y), its rows bowed out of the x-y plane along z (see [`BOW`]), so that it swings in 3D.
/// The page draws it projected onto x-y.
pub fn cloth_3d(rows: usize, cols: usize, integrator: &str) -> String {
    cloth_in(rows, cols, 3, integrator)
}

fn cloth_in(rows: usize, cols: usize, dim: usize, integrator: &str) -> String {
    let gravity = if dim == 3 {
        format!("[0.0, {GRAVITY:?}, 0.0]")
    } else {
        format!("[0.0, {GRAVITY:?}]")
    };
    let mut text = format!("title = \"Cloth {rows} x {cols}\"\n[world]\ngravity = {gravity}\n");
    cloth_particles(rows, cols, dim, &mut text);
    for (a, b) in cloth_links(rows, cols) {
        writeln!(
            text,
            "[[constraint]]\nkind = \"distance\"\nbetween = [\"{}\", \"{}\"]",
            node(a.0, a.1),
            node(b.0, b.1)
        )
        .unwrap();
    }
    corner_pins(cols, &mut text);
    writeln!(text, "[run]\nintegrator = \"{integrator}\"\ndt = \"1/120\"").unwrap();
    text
}

/// A `rows` x `cols` cloth whose links are stiff springs (forces) instead of rods, pinned at
/// its two top corners: the constraint solver sees 2 pins only, so its cost does not depend
/// on the size, and the frames carry every particle. Stiffness 10^4 with unit masses:
/// 2 sqrt(k/m) dt = 1.7 at dt = 1/120, within rk4's limit of about 2.8; the top links
/// stretch by about a quarter of their length under the cloth's weight.
pub fn spring_cloth(rows: usize, cols: usize) -> String {
    let mut text = format!(
        "title = \"Spring cloth {rows} x {cols}\"\n[world]\ngravity = [0.0, {GRAVITY:?}]\n"
    );
    cloth_particles(rows, cols, 2, &mut text);
    let spacing = 1.0 / (cols - 1).max(1) as f64;
    for (a, b) in cloth_links(rows, cols) {
        writeln!(
            text,
            "[[force]]\nkind = \"spring\"\nbetween = [\"{}\", \"{}\"]\nstiffness = 10000.0\nrest_length = {spacing:?}",
            node(a.0, a.1),
            node(b.0, b.1)
        )
        .unwrap();
    }
    corner_pins(cols, &mut text);
    text.push_str("[run]\nintegrator = \"rk4\"\ndt = \"1/120\"\n");
    text
}

/// The links of a cloth: along each row, then down each column, row by row.
pub fn cloth_links(rows: usize, cols: usize) -> Vec<((usize, usize), (usize, usize))> {
    let mut links = Vec::new();
    for r in 0..rows {
        for c in 0..cols {
            if c + 1 < cols {
                links.push(((r, c), (r, c + 1)));
            }
            if r + 1 < rows {
                links.push(((r, c), (r + 1, c)));
            }
        }
    }
    links
}

/// `n` particles in a 100 x (n / 100) block of side 1, without gravity, held by nothing,
/// spreading slowly (0.05 at the edges).
pub fn free(n: usize) -> String {
    let mut text = format!("title = \"{n} free particles\"\n[world]\ngravity = [0.0, 0.0]\n");
    for i in 0..n {
        let (x, y) = ((i % 100) as f64 / 100.0, (i / 100) as f64 / 100.0);
        let (u, v) = (0.1 * (x - 0.5), 0.1 * (y - 0.5));
        writeln!(
            text,
            "[[particle]]\nname = \"p{i}\"\nmass = 1.0\nposition = [{x:?}, {y:?}]\nvelocity = [{u:?}, {v:?}]"
        )
        .unwrap();
    }
    text.push_str("[run]\nintegrator = \"rk4\"\ndt = \"1/120\"\n");
    text
}

/// A bead in a valley that moves up and down: y = -x^2 / 2 - 0.3 sin(2 t) (+y down here as
/// in the shipped scenes, so this is a valley), a driven constraint.
pub const SHAKEN: &str = r#"
title = "Bead on a shaken parabola (driven)"
[world]
gravity = [0.0, 9.81]
[[particle]]
name = "bead"
mass = 1.0
position = [0.8, -0.32]
velocity = [0.0, 0.0]
[[constraint]]
name = "shaken parabola"
expr = "bead.y + 0.5*bead.x^2 + 0.3*sin(2*t)"
[run]
method = "implicit"
integrator = "rk4"
dt = 0.002
duration = 6.0
"#;
