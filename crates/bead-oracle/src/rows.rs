//! One recorded state as every front end prints it (a trace row, a summary's final state, a
//! viewer frame), and the checks of one row or a run of rows against the oracle.

use bead::simulate::Sample;

use crate::systems::System;

/// One recorded state. `q`, `qdot` are the parametric form's coordinates (empty for the
/// implicit form, whose coordinates are the particles').
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    pub t: f64,
    pub x: Vec<f64>,
    pub v: Vec<f64>,
    pub energy: f64,
    pub constraint_error: f64,
    pub work: Option<f64>,
    pub q: Vec<f64>,
    pub qdot: Vec<f64>,
}

impl Row {
    /// A sample of `simulate::run`; `parametric` keeps q, q' (else they are the particles').
    pub fn of_sample(sample: &Sample, parametric: bool) -> Row {
        Row {
            t: sample.t,
            x: sample.x.to_vec(),
            v: sample.xdot.to_vec(),
            energy: sample.energy,
            constraint_error: sample.constraint_error,
            work: sample.work,
            q: if parametric {
                sample.q.to_vec()
            } else {
                Vec::new()
            },
            qdot: if parametric {
                sample.qdot.to_vec()
            } else {
                Vec::new()
            },
        }
    }

    /// A row of a CSV trace (`bead run --trace`) with the given header, numbers read
    /// exactly (Rust's parse is correctly rounded).
    pub fn of_csv(header: &[String], line: &str, dim: usize) -> Row {
        let values: Vec<f64> = line
            .split(',')
            .map(|v| {
                v.parse()
                    .unwrap_or_else(|_| panic!("`{v}` is not a number: {line}"))
            })
            .collect();
        assert_eq!(values.len(), header.len(), "{line}");
        let column = |name: &str| header.iter().position(|h| h == name);
        let energy = column("energy").expect("energy column");
        let particles = (energy - 1) / (2 * dim);
        let mut x = Vec::new();
        let mut v = Vec::new();
        for p in 0..particles {
            let base = 1 + p * 2 * dim;
            x.extend_from_slice(&values[base..base + dim]);
            v.extend_from_slice(&values[base + dim..base + 2 * dim]);
        }
        let mut q = Vec::new();
        let mut qdot = Vec::new();
        for (i, h) in header.iter().enumerate() {
            if h.starts_with("q.") {
                q.push(values[i]);
                qdot.push(values[i + 1]);
            }
        }
        Row {
            t: values[0],
            x,
            v,
            energy: values[energy],
            constraint_error: values[energy + 1],
            work: column("work").map(|i| values[i]),
            q,
            qdot,
        }
    }

    /// All rows of a CSV trace's text.
    pub fn parse_trace(text: &str, dim: usize) -> Vec<Row> {
        let mut lines = text.lines();
        let header: Vec<String> = lines
            .next()
            .expect("a header")
            .split(',')
            .map(str::to_string)
            .collect();
        lines.map(|l| Row::of_csv(&header, l, dim)).collect()
    }

    /// Bit for bit the same numbers (NaN never equals).
    pub fn same_bits(&self, other: &Row) -> bool {
        let bits = |a: &[f64], b: &[f64]| {
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
        };
        self.t.to_bits() == other.t.to_bits()
            && bits(&self.x, &other.x)
            && bits(&self.v, &other.v)
            && self.energy.to_bits() == other.energy.to_bits()
            && self.constraint_error.to_bits() == other.constraint_error.to_bits()
            && self.work.map(f64::to_bits) == other.work.map(f64::to_bits)
            && bits(&self.q, &other.q)
            && bits(&self.qdot, &other.qdot)
    }
}

/// The signed error of a row's particle state against the exact one at the row's t, each
/// position over the system's length scale and each velocity over its speed scale, and for
/// a driven system the error of the work W over the energy scale (W exact: T + V at t
/// minus T + V at 0, since E - W is conserved).
pub fn error_vector(system: &System, row: &Row) -> Vec<f64> {
    let (x, v) = system.exact_state(row.t);
    let mut e: Vec<f64> = row
        .x
        .iter()
        .zip(&x)
        .map(|(a, b)| (a - b) / system.length)
        .chain(row.v.iter().zip(&v).map(|(a, b)| (a - b) / system.speed))
        .collect();
    if let (true, Some(w)) = (system.driven, row.work) {
        let (x0, v0) = system.exact_state(0.0);
        let work = system.energy(&x, &v) - system.energy(&x0, &v0);
        e.push((w - work) / system.energy_scale());
    }
    e
}

/// max |error_vector|.
pub fn error(system: &System, row: &Row) -> f64 {
    norm(&error_vector(system, row))
}

pub fn norm(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |m: f64, e| m.max(e.abs()))
}

/// (b) The numbers of one row belong to one state: for the parametric form x = x(q, t) and
/// v = J q' + dx/dt at the row's own t; T + V of the row's x and v is its energy; max |C(x,
/// t)| is its constraint error; a driven system's row carries the work W (and an undriven
/// one none). `what` names the row in messages.
pub fn check_consistent(system: &System, row: &Row, parametric: bool, what: &str) {
    let scale_e = system
        .energy(&system.exact_state(0.0).0, &system.exact_state(0.0).1)
        .abs()
        + system.masses.iter().sum::<f64>() * system.speed * system.speed;
    let e = system.energy(&row.x, &row.v);
    assert!(
        (e - row.energy).abs() <= 1e-13 * scale_e,
        "{what}: energy {} but T + V of the row's x and v is {e} (t = {})",
        row.energy,
        row.t
    );
    let c = (system.constraints)(&row.x, row.t);
    let c = norm(&c);
    let c_tolerance = 1e-14 * system.length * system.length * 4.0 + 1e-9 * c;
    assert!(
        (c - row.constraint_error).abs() <= c_tolerance,
        "{what}: constraint_error {} but max |C(x, t)| of the row is {c} (t = {})",
        row.constraint_error,
        row.t
    );
    assert_eq!(
        row.work.is_some(),
        system.driven,
        "{what}: work column present: {:?}",
        row.work
    );
    if parametric {
        assert_eq!(row.q.len(), system.coordinates.len(), "{what}: q");
        let x = (system.map)(&row.q, row.t);
        let v = (system.velocity)(&row.q, &row.qdot, row.t);
        for (a, b) in row.x.iter().zip(&x) {
            assert!(
                (a - b).abs() <= 1e-14 * system.length * 8.0,
                "{what}: x = {:?} but x(q, t) = {x:?} for q = {:?} at t = {}",
                row.x,
                row.q,
                row.t
            );
        }
        for (a, b) in row.v.iter().zip(&v) {
            assert!(
                (a - b).abs() <= 1e-14 * system.speed * 8.0,
                "{what}: v = {:?} but J q' + dx/dt = {v:?} for q = {:?}, q' = {:?} at t = {}",
                row.v,
                row.q,
                row.qdot,
                row.t
            );
        }
    } else {
        assert!(
            row.q.is_empty() || row.q == row.x,
            "{what}: implicit q is x"
        );
    }
}

/// The spinning hoop's Jacobi integral E - w L_z of a row (conserved exactly: the hoop turns
/// at a constant rate about z), or None for the other systems.
pub fn jacobi(system: &System, row: &Row) -> Option<f64> {
    (system.name == "spinning-hoop").then(|| {
        let (x, v) = (&row.x, &row.v);
        let lz = system.masses[0] * (x[0] * v[1] - x[1] * v[0]);
        system.energy(x, v) - crate::systems::HOOP_W * lz
    })
}
