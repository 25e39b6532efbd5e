//! The equations a formulation derives, as text: what `bead check` prints for the constraint
//! rows (implicit form) and for the parametric map, and the viewer shows on demand. One
//! formatter for both, so that they say the same thing.

use std::fmt::Write as _;

use crate::expr::Expr;
use crate::formulation::Method;
use crate::model::{ExprRow, System};

/// Longest expression `bead check` prints, in characters: a longer one is cut there and says
/// how many characters are left (derivatives written out can be far larger than the scene).
pub const EXPRESSION_LIMIT: usize = 400;

/// `e` as `bead check` prints it: numeric factors collected, at most [`EXPRESSION_LIMIT`]
/// characters, slots named by `name`.
pub fn expression(e: &Expr, name: &dyn Fn(usize) -> String) -> String {
    e.for_display()
        .display_bounded(name, EXPRESSION_LIMIT)
        .to_string()
}

/// Name of a slot of a constraint expression: positions (n), velocities (n), t.
pub fn constraint_slot_name(system: &System, slot: usize) -> String {
    let n = system.n_coords();
    if slot < n {
        system.coordinate_name(slot)
    } else if slot < 2 * n {
        // `bead.x` -> `bead.vx`
        let name = system.coordinate_name(slot - n);
        match name.rsplit_once('.') {
            Some((particle, axis)) => format!("{particle}.v{axis}"),
            None => format!("{name}'"),
        }
    } else if slot == 2 * n {
        "t".into()
    } else {
        format!("slot{slot}")
    }
}

/// Name of a slot of a parametric map expression: q (n_q), qdot (n_q), t.
pub fn parametric_slot_name(coordinates: &[String], slot: usize) -> String {
    let n_q = coordinates.len();
    if slot < n_q {
        coordinates[slot].clone()
    } else if slot < 2 * n_q {
        format!("{}'", coordinates[slot - n_q])
    } else if slot == 2 * n_q {
        "t".into()
    } else {
        format!("slot{slot}")
    }
}

/// The equations `method` works with on `system`, in `bead check`'s words: for the implicit
/// form each constraint row's C, its gradient, Cdot and the bias (Cddot = J a + bias); for
/// the parametric form x(q), its Jacobian, the velocity and h (acceleration = J q'' + h).
/// At most `max_rows` rows (constraint rows or coordinates) are written; the rest are counted.
pub fn equations(system: &System, method: Method, max_rows: usize) -> String {
    let mut s = String::new();
    match method {
        Method::Implicit => {
            let set = system.constraints();
            let _ = writeln!(
                s,
                "implicit form: constraint forces J^T lambda keep C(x, t) = 0; {} constraint rows",
                set.n_rows()
            );
            let name = |slot: usize| constraint_slot_name(system, slot);
            let mut written = 0;
            for info in set.infos() {
                if written >= max_rows {
                    break;
                }
                let _ = writeln!(s, "  {}: {}", info.name, info.description);
                for row in info.rows.clone() {
                    if written >= max_rows {
                        break;
                    }
                    written += 1;
                    match set.symbolic_row(row).as_deref() {
                        Some(ExprRow {
                            value,
                            gradient,
                            velocity,
                            bias,
                        }) => {
                            let _ = writeln!(s, "    row {row}: C = {}", expression(value, &name));
                            for (k, d) in gradient {
                                let _ = writeln!(
                                    s,
                                    "      dC/d({}) = {}",
                                    name(*k),
                                    expression(d, &name)
                                );
                            }
                            let _ = writeln!(s, "      Cdot = {}", expression(velocity, &name));
                            let _ = writeln!(
                                s,
                                "      bias = {}   (Cddot = J a + bias)",
                                expression(bias, &name)
                            );
                        }
                        None => {
                            let columns: Vec<String> =
                                set.row_columns(row).iter().map(|k| name(*k)).collect();
                            let _ = writeln!(
                                s,
                                "    row {row}: a Rust constraint on {}; derivatives by dual numbers",
                                columns.join(", ")
                            );
                        }
                    }
                }
            }
            if set.n_rows() > written {
                let _ = writeln!(s, "  ... and {} more rows", set.n_rows() - written);
            }
        }
        Method::Parametric => {
            let Some(map) = system.parametric() else {
                let _ = writeln!(s, "parametric form: none");
                return s;
            };
            let coordinates = map.coordinates();
            let _ = writeln!(
                s,
                "parametric form: x = x(q, t) with q = ({}); the equations of motion M(q) q'' = Q are derived from it",
                coordinates.join(", ")
            );
            let qname = |slot: usize| parametric_slot_name(coordinates, slot);
            let rows = system.n_coords().min(max_rows);
            for k in 0..rows {
                let row = map.symbolic(k);
                let coordinate = system.coordinate_name(k);
                let _ = writeln!(s, "  {coordinate} = {}", expression(row.position, &qname));
                for (j, name) in coordinates.iter().enumerate() {
                    let d = match row.columns.iter().position(|&c| c == j) {
                        Some(e) => expression(&row.jacobian[e], &qname),
                        None => "0".to_string(),
                    };
                    let _ = writeln!(s, "    d({coordinate})/d{name} = {d}");
                }
                let _ = writeln!(s, "    velocity = {}", expression(row.velocity, &qname));
                let _ = writeln!(
                    s,
                    "    h = {}   (acceleration = J q'' + h)",
                    expression(row.bias, &qname)
                );
            }
            if system.n_coords() > rows {
                let _ = writeln!(s, "  ... and {} more coordinates", system.n_coords() - rows);
            }
        }
    }
    s
}

/// The force on particle coordinate `k` in the typeset equations: m g when gravity is the only
/// force (a constant), else the symbol F_k (a slot `force_slot + k`).
fn force_on(system: &System, k: usize, force_slot: usize) -> Expr {
    if system.forces().is_empty() {
        let dim = system.dim();
        Expr::constant(system.particles()[k / dim].mass * system.gravity()[k % dim])
    } else {
        Expr::var(force_slot + k)
    }
}

/// The multiplier of a one-row implicit system as an expression of x (n), v (n), t and the
/// forces F_k (slots 2n + 1 + k, see [`equations_mathml`]): from J M^-1 J^T lambda =
/// -(J M^-1 F + b), lambda = -(sum_k dC/dx_k F_k / m_k + b) / (sum_k (dC/dx_k)^2 / m_k).
/// `None` for other systems or a row without expressions.
pub fn single_row_multiplier(system: &System) -> Option<Expr> {
    let set = system.constraints();
    if set.n_rows() != 1 {
        return None;
    }
    let row = set.symbolic_row(0)?;
    let n = system.n_coords();
    let mass = |k: usize| system.particles()[k / system.dim()].mass;
    let mut work = row.bias.clone();
    let mut stiffness = Expr::constant(0.0);
    for (k, d) in &row.gradient {
        work = &work + &(&(d * &force_on(system, *k, 2 * n + 1)) / mass(*k));
        stiffness = &stiffness + &(&(d * d) / mass(*k));
    }
    Some(-(&work / &stiffness))
}

/// M(q) and Q(q, q', t) of a one-coordinate parametric system, M q'' = Q: with x_k(q, t),
/// J_k = dx_k/dq and h_k = xddot_k - J_k q'', M = sum_k m_k J_k^2 and
/// Q = sum_k J_k (F_k - m_k h_k) (the forces F_k in slots 3 + k, see [`equations_mathml`]).
pub fn single_coordinate_equation(system: &System) -> Option<(Expr, Expr)> {
    let map = system.parametric()?;
    if map.coordinates().len() != 1 {
        return None;
    }
    let mass = |k: usize| system.particles()[k / system.dim()].mass;
    let mut inertia = Expr::constant(0.0);
    let mut force = Expr::constant(0.0);
    for k in 0..system.n_coords() {
        let row = map.symbolic(k);
        let Some(j) = row.jacobian.first() else {
            continue;
        };
        inertia = &inertia + &(&(j * j) * mass(k));
        let net = &force_on(system, k, 3) - &(row.bias * mass(k));
        force = &force + &(j * &net);
    }
    Some((inertia, force))
}

/// A slot name as MathML: `bead.x` is x with subscript bead, `bead.vx` a dotted x, Greek
/// names their letters (`theta` θ), trailing digits a subscript (`th1` th₁), a trailing `'`
/// a dot (`theta'` θ̇).
pub fn mathml_identifier(name: &str) -> String {
    use crate::expr::mathml_escape as esc;
    let (base, dotted) = match name.strip_suffix('\'') {
        Some(b) => (b, true),
        None => (name, false),
    };
    let (particle, axis) = match base.rsplit_once('.') {
        Some((p, a)) => (Some(p), a),
        None => (None, base),
    };
    let (axis, dotted) = match (particle, axis.strip_prefix('v')) {
        (Some(_), Some(a)) if ["x", "y", "z"].contains(&a) => (a, true),
        _ => (axis, dotted),
    };
    const GREEK: [(&str, &str); 24] = [
        ("alpha", "α"),
        ("beta", "β"),
        ("gamma", "γ"),
        ("delta", "δ"),
        ("epsilon", "ε"),
        ("zeta", "ζ"),
        ("eta", "η"),
        ("theta", "θ"),
        ("kappa", "κ"),
        ("lambda", "λ"),
        ("mu", "μ"),
        ("nu", "ν"),
        ("xi", "ξ"),
        ("rho", "ρ"),
        ("sigma", "σ"),
        ("tau", "τ"),
        ("phi", "φ"),
        ("chi", "χ"),
        ("psi", "ψ"),
        ("omega", "ω"),
        ("Theta", "Θ"),
        ("Phi", "Φ"),
        ("Psi", "Ψ"),
        ("Omega", "Ω"),
    ];
    let digits = axis.len() - axis.trim_end_matches(|c: char| c.is_ascii_digit()).len();
    let (stem, index) = axis.split_at(axis.len() - digits);
    let stem = if stem.is_empty() { axis } else { stem };
    let index = if stem == axis { "" } else { index };
    let letter = GREEK
        .iter()
        .find(|(word, _)| *word == stem)
        .map_or_else(|| esc(stem), |(_, g)| g.to_string());
    let mut m = format!("<mi>{letter}</mi>");
    if dotted {
        m = format!("<mover>{m}<mo>˙</mo></mover>");
    }
    let subscript = match (particle, index) {
        (Some(p), "") => format!("<mi>{}</mi>", esc(p)),
        (Some(p), i) => format!("<mrow><mn>{i}</mn><mo>,</mo><mi>{}</mi></mrow>", esc(p)),
        (None, "") => String::new(),
        (None, i) => format!("<mn>{i}</mn>"),
    };
    if subscript.is_empty() {
        m
    } else {
        format!("<msub>{m}{subscript}</msub>")
    }
}

/// Longest typeset expression, in nodes of the written-out tree.
const MATHML_NODES: usize = 160;

/// The equations of motion `method` integrates on `system`, typeset: HTML paragraphs with
/// MathML (Core) blocks that a browser renders without anything else. The implicit form:
/// M x'' = F + J^T lambda with J M^-1 J^T lambda = -(J M^-1 F + b), each row's C, gradient
/// and b = Cddot - J x'', and for one row lambda written out. The parametric form:
/// M(q) q'' = J^T (F - m h) with M = J^T m J, each coordinate's x(q, t), J and h, and for
/// one coordinate M and Q written out. Forces are m g when gravity is the only force, else
/// the symbols F. At most `max_rows` rows or coordinates.
pub fn equations_mathml(system: &System, method: Method, max_rows: usize) -> String {
    let block = |body: &str| format!("<math display=\"block\">{body}</math>\n");
    let typeset =
        |e: &Expr, name: &dyn Fn(usize) -> String| e.for_display().mathml(name, MATHML_NODES);
    let n = system.n_coords();
    let coordinate = |k: usize| mathml_identifier(&system.coordinate_name(k));
    let force = |k: usize| format!("<msub><mi>F</mi>{}</msub>", coordinate(k));
    let gravity_only = system.forces().is_empty();
    let forces_note = if gravity_only {
        "F = m g: gravity is the only force"
    } else {
        "F: gravity and the scene's other forces on each coordinate"
    };
    let mut s = String::new();
    match method {
        Method::Implicit => {
            let set = system.constraints();
            let name = |slot: usize| {
                if slot < 2 * n + 1 {
                    mathml_identifier(&constraint_slot_name(system, slot))
                } else {
                    force(slot - 2 * n - 1)
                }
            };
            let _ = writeln!(
                s,
                "<p>Implicit form: Newton's law with constraint forces J<sup>T</sup>λ that keep every C(x, t) = 0; \
                 λ from the constraints' second derivative, with J = ∂C/∂x and b = C̈ − J ẍ ({forces_note}):</p>"
            );
            s.push_str(&block(
                "<mi>M</mi><mover><mi>x</mi><mo>¨</mo></mover><mo>=</mo><mi>F</mi><mo>+</mo>\
                 <msup><mi>J</mi><mi>T</mi></msup><mi>λ</mi><mo>,</mo><mspace width=\"1em\"/>\
                 <mi>J</mi><msup><mi>M</mi><mrow><mo>−</mo><mn>1</mn></mrow></msup><msup><mi>J</mi><mi>T</mi></msup><mi>λ</mi>\
                 <mo>=</mo><mo>−</mo><mi>J</mi><msup><mi>M</mi><mrow><mo>−</mo><mn>1</mn></mrow></msup><mi>F</mi><mo>−</mo><mi>b</mi>",
            ));
            if let Some(lambda) = single_row_multiplier(system) {
                s.push_str("<p>With one constraint row, λ written out:</p>\n");
                s.push_str(&block(&format!(
                    "<mi>λ</mi><mo>=</mo>{}",
                    typeset(&lambda, &name)
                )));
            }
            let mut written = 0;
            for info in set.infos() {
                // Past the rows shown, no more constraints are described (each made on demand).
                if written >= max_rows {
                    break;
                }
                for row in info.rows.clone() {
                    if written >= max_rows {
                        break;
                    }
                    written += 1;
                    let sub =
                        |symbol: &str| format!("<msub><mi>{symbol}</mi><mn>{row}</mn></msub>");
                    let _ = writeln!(
                        s,
                        "<p>Row {row} ({}: {}):</p>",
                        crate::expr::mathml_escape(&info.name),
                        crate::expr::mathml_escape(&info.description)
                    );
                    let symbolic = set.symbolic_row(row);
                    let Some(ExprRow {
                        value,
                        gradient,
                        bias,
                        ..
                    }) = symbolic.as_deref()
                    else {
                        s.push_str("<p>a Rust constraint: derivatives by dual numbers, no expressions to show.</p>\n");
                        continue;
                    };
                    s.push_str(&block(&format!(
                        "{}<mo>=</mo>{}<mo>=</mo><mn>0</mn>",
                        sub("C"),
                        typeset(value, &name)
                    )));
                    let mut grad = String::new();
                    for (i, (k, d)) in gradient.iter().enumerate() {
                        if i > 0 {
                            grad.push_str("<mo>,</mo><mspace width=\"1em\"/>");
                        }
                        let _ = write!(
                            grad,
                            "<mfrac><mrow><mo>∂</mo>{}</mrow><mrow><mo>∂</mo>{}</mrow></mfrac><mo>=</mo>{}",
                            sub("C"),
                            coordinate(*k),
                            typeset(d, &name)
                        );
                    }
                    s.push_str(&block(&grad));
                    s.push_str(&block(&format!(
                        "{}<mo>=</mo>{}",
                        sub("b"),
                        typeset(bias, &name)
                    )));
                }
            }
            if set.n_rows() > written {
                let _ = writeln!(s, "<p>… and {} more rows.</p>", set.n_rows() - written);
            }
        }
        Method::Parametric => {
            let Some(map) = system.parametric() else {
                s.push_str("<p>No parametric form: the scene gives no map x(q).</p>\n");
                return s;
            };
            let coordinates = map.coordinates();
            let n_q = coordinates.len();
            let name = |slot: usize| {
                if slot < 2 * n_q + 1 {
                    mathml_identifier(&parametric_slot_name(coordinates, slot))
                } else {
                    force(slot - 2 * n_q - 1)
                }
            };
            let q: Vec<String> = (0..n_q).map(&name).collect();
            let _ = writeln!(
                s,
                "<p>Parametric form: the positions x(q, t) meet the constraints by construction; \
                 Lagrange's equations in q, with J = ∂x/∂q and h = ẍ − J q̈ ({forces_note}):</p>"
            );
            s.push_str(&block(
                "<mi>M</mi><mo>(</mo><mi>q</mi><mo>)</mo><mover><mi>q</mi><mo>¨</mo></mover><mo>=</mo>\
                 <msup><mi>J</mi><mi>T</mi></msup><mo>(</mo><mi>F</mi><mo>−</mo><mi>m</mi><mi>h</mi><mo>)</mo><mo>,</mo>\
                 <mspace width=\"1em\"/><mi>M</mi><mo>(</mo><mi>q</mi><mo>)</mo><mo>=</mo><msup><mi>J</mi><mi>T</mi></msup><mi>m</mi><mi>J</mi>",
            ));
            if let Some((inertia, force_q)) = single_coordinate_equation(system) {
                let qq = &q[0];
                s.push_str("<p>With one coordinate, written out:</p>\n");
                s.push_str(&block(&format!(
                    "<mrow><mo>(</mo>{}<mo>)</mo></mrow><mover>{qq}<mo>¨</mo></mover><mo>=</mo>{}",
                    typeset(&inertia, &name),
                    typeset(&force_q, &name)
                )));
            }
            let rows = n.min(max_rows);
            for k in 0..rows {
                let row = map.symbolic(k);
                let x = coordinate(k);
                let mut line = format!("{x}<mo>=</mo>{}", typeset(row.position, &name));
                for (e, &j) in row.columns.iter().enumerate() {
                    let _ = write!(
                        line,
                        "<mo>,</mo><mspace width=\"1em\"/><mfrac><mrow><mo>∂</mo>{x}</mrow><mrow><mo>∂</mo>{}</mrow></mfrac><mo>=</mo>{}",
                        q[j],
                        typeset(&row.jacobian[e], &name)
                    );
                }
                let _ = write!(
                    line,
                    "<mo>,</mo><mspace width=\"1em\"/><msub><mi>h</mi>{x}</msub><mo>=</mo>{}",
                    typeset(row.bias, &name)
                );
                s.push_str(&block(&line));
            }
            if n > rows {
                let _ = writeln!(s, "<p>… and {} more coordinates.</p>", n - rows);
            }
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Scene;

    use crate::simulate::{Simulation, SimulationConfig};
    use std::sync::Arc;

    fn shipped(name: &str) -> Scene {
        let path = format!("{}/../../scenes/{name}.toml", env!("CARGO_MANIFEST_DIR"));
        let text = std::fs::read_to_string(&path).unwrap();
        Scene::parse(&text, &path, &[]).unwrap_or_else(|e| panic!("{e}"))
    }

    /// The typeset lambda of a one-row scene is the multiplier the implicit formulation
    /// solves for (its assembly and solve, not these expressions), at the start and later.
    #[test]
    fn the_written_out_multiplier_is_the_one_the_implicit_form_solves_for() {
        for name in ["circle", "parabola", "hump"] {
            let scene = shipped(name);
            let system = &scene.system;
            let lambda = single_row_multiplier(system).expect(name);
            let config = SimulationConfig {
                method: Method::Implicit,
                dt: 1e-3,
                ..Default::default()
            };
            let mut sim = Simulation::new(Arc::clone(system), config).unwrap();
            for _ in 0..3 {
                let expected = sim.constraint_forces().unwrap().multipliers[0];
                let (x, v) = (sim.positions().to_vec(), sim.velocities().to_vec());
                let mut force = vec![0.0; x.len()];
                system.accumulate_forces(&x, &v, &mut force);
                let slots: Vec<f64> = x
                    .iter()
                    .chain(&v)
                    .chain(&[sim.t()])
                    .chain(&force)
                    .copied()
                    .collect();
                let got = lambda.eval(&slots);
                assert!(
                    (got - expected).abs() <= 1e-12 * expected.abs().max(1.0),
                    "{name}: {got} vs {expected}"
                );
                sim.advance_to(sim.t() + 0.2).unwrap();
            }
            let m = equations_mathml(system, Method::Implicit, 8);
            assert!(
                m.contains("<mi>λ</mi><mo>=</mo>") && m.contains("<mfrac>"),
                "{m}"
            );
        }
    }

    /// The written-out M q'' = Q of a one-coordinate scene gives the acceleration the
    /// parametric formulation integrates: m (J q'' + h) - F is its constraint force.
    #[test]
    fn the_written_out_parametric_equation_is_the_one_integrated() {
        for name in ["circle", "spinning-hoop", "parabola"] {
            let scene = shipped(name);
            let system = &scene.system;
            let (inertia, force_q) = single_coordinate_equation(system).expect(name);
            let map = system.parametric().unwrap();
            let config = SimulationConfig {
                method: Method::Parametric,
                dt: 1e-3,
                ..Default::default()
            };
            let mut sim = Simulation::new(Arc::clone(system), config).unwrap();
            for _ in 0..3 {
                let reaction = sim.constraint_forces().unwrap().force;
                let (x, v) = (sim.positions().to_vec(), sim.velocities().to_vec());
                let mut force = vec![0.0; x.len()];
                system.accumulate_forces(&x, &v, &mut force);
                let slots: Vec<f64> = [sim.q()[0], sim.qdot()[0], sim.t()]
                    .iter()
                    .chain(&force)
                    .copied()
                    .collect();
                let qddot = force_q.eval(&slots) / inertia.eval(&slots);
                for k in 0..system.n_coords() {
                    let row = map.symbolic(k);
                    let j = row.jacobian.first().map_or(0.0, |e| e.eval(&slots));
                    let mass = system.particles()[k / system.dim()].mass;
                    let expected = mass * (j * qddot + row.bias.eval(&slots)) - force[k];
                    assert!(
                        (reaction[k] - expected).abs() <= 1e-9 * (1.0 + force[k].abs()),
                        "{name} coordinate {k}: {} vs {expected}",
                        reaction[k]
                    );
                }
                sim.advance_to(sim.t() + 0.2).unwrap();
            }
            let m = equations_mathml(system, Method::Parametric, 8);
            assert!(m.contains("<mover>") && m.contains("<mo>¨</mo>"), "{m}");
        }
    }

    #[test]
    fn identifiers_read_as_symbols() {
        assert_eq!(mathml_identifier("t"), "<mi>t</mi>");
        assert_eq!(mathml_identifier("theta"), "<mi>θ</mi>");
        assert_eq!(
            mathml_identifier("theta'"),
            "<mover><mi>θ</mi><mo>˙</mo></mover>"
        );
        assert_eq!(
            mathml_identifier("bead.x"),
            "<msub><mi>x</mi><mi>bead</mi></msub>"
        );
        assert_eq!(
            mathml_identifier("bead.vy"),
            "<msub><mover><mi>y</mi><mo>˙</mo></mover><mi>bead</mi></msub>"
        );
        assert_eq!(
            mathml_identifier("th1"),
            "<msub><mi>th</mi><mn>1</mn></msub>"
        );
        assert_eq!(mathml_identifier("a<b"), "<mi>a&lt;b</mi>");
    }

    /// The parabola's equations, both forms, as `bead check` prints their rows.
    #[test]
    fn the_parabola_equations_in_both_forms() {
        let text = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../scenes/parabola.toml"
        ))
        .unwrap();
        let scene = Scene::parse(&text, "parabola.toml", &[]).unwrap();
        let implicit = equations(&scene.system, Method::Implicit, 100);
        assert!(implicit.contains("row 0: C = "), "{implicit}");
        assert!(implicit.contains("dC/d(bead.x) = "), "{implicit}");
        assert!(implicit.contains("(Cddot = J a + bias)"), "{implicit}");
        let parametric = equations(&scene.system, Method::Parametric, 100);
        assert!(parametric.contains("bead.x = "), "{parametric}");
        assert!(
            parametric.contains("(acceleration = J q'' + h)"),
            "{parametric}"
        );
    }
}
