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
                    match set.symbolic_row(row) {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::Scene;

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
