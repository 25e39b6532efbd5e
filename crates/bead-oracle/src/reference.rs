//! The references made by `tests/oracle/make_references.py`: q, q', q'' on a uniform grid
//! (NAME.csv) and the settings, errors and event times they were made with (NAME.json).
//! Between grid points the quintic Hermite interpolant of (q, q', q'') gives q and its
//! derivative q'; on a grid point the tabulated values themselves.

use std::path::PathBuf;

use serde_json::Value;

/// One system's reference.
#[derive(Clone, Debug)]
pub struct Reference {
    pub name: String,
    /// NAME.json as written by the script.
    pub settings: Value,
    /// Grid step (s).
    pub step: f64,
    /// Coordinates per row.
    pub k: usize,
    /// Rows of t, q (k), q' (k), q'' (k).
    rows: Vec<Vec<f64>>,
    /// The stated error of q and q' (closed form or solver) plus that of the interpolant.
    pub error: f64,
}

/// `tests/oracle/` of the repository.
pub fn directory() -> PathBuf {
    crate::root().join("tests/oracle")
}

impl Reference {
    /// Load tests/oracle/references/NAME.{json,csv}.
    pub fn load(name: &str) -> Reference {
        let dir = directory().join("references");
        let json = std::fs::read_to_string(dir.join(format!("{name}.json")))
            .unwrap_or_else(|e| panic!("reference {name}.json: {e}"));
        let settings: Value = serde_json::from_str(&json).expect("reference JSON");
        let csv = std::fs::read_to_string(dir.join(format!("{name}.csv")))
            .unwrap_or_else(|e| panic!("reference {name}.csv: {e}"));
        let mut lines = csv.lines();
        let header: Vec<&str> = lines.next().expect("header").split(',').collect();
        let k = (header.len() - 1) / 3;
        let rows: Vec<Vec<f64>> = lines
            .map(|l| {
                l.split(',')
                    .map(|v| v.parse::<f64>().expect("a number"))
                    .collect()
            })
            .collect();
        let number = |key: &str| settings[key].as_f64().unwrap_or_else(|| panic!("{key}"));
        let step = number("grid_step");
        let error = number("reference_error") + number("interpolation_error");
        Reference {
            name: name.to_string(),
            step,
            k,
            rows,
            error,
            settings,
        }
    }

    /// The last tabulated time.
    pub fn duration(&self) -> f64 {
        self.rows.last().expect("rows")[0]
    }

    /// (q, q') at t, 0 <= t <= the duration.
    pub fn at(&self, t: f64) -> (Vec<f64>, Vec<f64>) {
        let k = self.k;
        let last = self.rows.len() - 1;
        assert!(
            (-1e-12..=self.duration() + 1e-12).contains(&t),
            "t = {t} is outside the reference {} (0 .. {})",
            self.name,
            self.duration()
        );
        let position = (t / self.step).clamp(0.0, last as f64);
        let i = (position.floor() as usize).min(last.saturating_sub(1));
        let s = position - i as f64;
        let on = |row: &Vec<f64>| (row[1..=k].to_vec(), row[k + 1..=2 * k].to_vec());
        if s.abs() < 1e-9 {
            return on(&self.rows[i]);
        }
        if (s - 1.0).abs() < 1e-9 {
            return on(&self.rows[i + 1]);
        }
        let (a, b) = (&self.rows[i], &self.rows[i + 1]);
        let h = b[0] - a[0];
        let s = (t - a[0]) / h;
        let mut q = vec![0.0; k];
        let mut qdot = vec![0.0; k];
        for j in 0..k {
            let ends = [
                a[1 + j],
                a[1 + k + j],
                a[1 + 2 * k + j],
                b[1 + j],
                b[1 + k + j],
                b[1 + 2 * k + j],
            ];
            q[j] = hermite(h, ends, s);
            qdot[j] = hermite_slope(h, ends, s);
        }
        (q, qdot)
    }

    /// The params of NAME.json, evaluated (`pi/3` and the like are read as the script does).
    pub fn param(&self, name: &str) -> f64 {
        match &self.settings["params"][name] {
            Value::Number(n) => n.as_f64().expect("a number"),
            Value::String(s) => match s.as_str() {
                "pi/3" => std::f64::consts::PI / 3.0,
                "pi/2" => std::f64::consts::FRAC_PI_2,
                "3*pi/4" => 3.0 * std::f64::consts::FRAC_PI_4,
                other => panic!("parameter {name} = {other}: not a form this reader knows"),
            },
            other => panic!("parameter {name}: {other}"),
        }
    }

    /// The events of NAME.json: (implicit form's stop_when, parametric form's, time).
    pub fn events(&self) -> Vec<(String, String, f64)> {
        self.settings["events"]
            .as_array()
            .expect("events")
            .iter()
            .map(|e| {
                (
                    e["implicit"].as_str().expect("implicit").to_string(),
                    e["parametric"].as_str().expect("parametric").to_string(),
                    e["t"].as_f64().expect("t"),
                )
            })
            .collect()
    }
}

/// The quintic Hermite interpolant at s h of [y0, y0', y0'', y1, y1', y1''] (the script's
/// `hermite`).
fn hermite(h: f64, e: [f64; 6], s: f64) -> f64 {
    let s2 = s * s;
    let s3 = s2 * s;
    let h00 = 1.0 - 10.0 * s3 + 15.0 * s3 * s - 6.0 * s3 * s2;
    let h10 = s - 6.0 * s3 + 8.0 * s3 * s - 3.0 * s3 * s2;
    let h20 = (s2 - 3.0 * s3 + 3.0 * s3 * s - s3 * s2) / 2.0;
    let h01 = 10.0 * s3 - 15.0 * s3 * s + 6.0 * s3 * s2;
    let h11 = -4.0 * s3 + 7.0 * s3 * s - 3.0 * s3 * s2;
    let h21 = (s3 - 2.0 * s3 * s + s3 * s2) / 2.0;
    h00 * e[0]
        + h10 * h * e[1]
        + h20 * h * h * e[2]
        + h01 * e[3]
        + h11 * h * e[4]
        + h21 * h * h * e[5]
}

/// d/dt of [`hermite`].
fn hermite_slope(h: f64, e: [f64; 6], s: f64) -> f64 {
    let s2 = s * s;
    let s3 = s2 * s;
    let s4 = s3 * s;
    let h00 = -30.0 * s2 + 60.0 * s3 - 30.0 * s4;
    let h10 = 1.0 - 18.0 * s2 + 32.0 * s3 - 15.0 * s4;
    let h20 = (2.0 * s - 9.0 * s2 + 12.0 * s3 - 5.0 * s4) / 2.0;
    let h01 = 30.0 * s2 - 60.0 * s3 + 30.0 * s4;
    let h11 = -12.0 * s2 + 28.0 * s3 - 15.0 * s4;
    let h21 = (3.0 * s2 - 8.0 * s3 + 5.0 * s4) / 2.0;
    (h00 * e[0] + h01 * e[3]) / h + h10 * e[1] + h20 * h * e[2] + h11 * e[4] + h21 * h * e[5]
}
