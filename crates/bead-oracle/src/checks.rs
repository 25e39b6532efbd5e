//! (a) The error at every recorded time against the reference, bounded by the method's
//! order: [`convergence`] (fixed-step integrators: halve dt and the error falls by 2^p
//! within 20%, at every recorded time, unless it is at round-off) and [`within`] (dopri5:
//! every row within a bound of its tolerance).

use crate::matrix::DOPRI_BOUND;
use crate::rows::{error, error_vector, norm, Row};
use crate::run::Spec;
use crate::systems::System;

/// The relative error below which a run is at round-off (plus the reference's own floor).
pub const ROUND_OFF: f64 = 2e-12;

/// What [`convergence`] measured.
#[derive(Clone, Copy, Debug)]
pub struct Convergence {
    /// The largest error of any row at dt and at dt / 2.
    pub coarse: f64,
    pub fine: f64,
    /// coarse / fine, against 2^p.
    pub ratio: f64,
}

/// (a) for a fixed-step integrator of order p: `coarse` recorded every step of dt, `fine`
/// every step of dt / 2 over the same times. The largest error of any row falls by 2^p
/// within 20% (unless the fine run is at round-off), and at every time of the coarse run
/// its error vector is 2^p times the fine run's to within 20% of the coarse run's largest
/// error: a single wrong row (stale, mislabelled, from another state) breaks that.
pub fn convergence(
    system: &System,
    order: u32,
    coarse: &[Row],
    fine: &[Row],
    what: &str,
) -> Convergence {
    assert!(coarse.len() >= 2, "{what}: {} rows", coarse.len());
    assert_eq!(
        2 * coarse.len() - 1,
        fine.len(),
        "{what}: the fine run has twice the rows"
    );
    let factor = 2f64.powi(order as i32);
    let floor = ROUND_OFF + system.reference_floor();
    let errors_c: Vec<Vec<f64>> = coarse.iter().map(|r| error_vector(system, r)).collect();
    let errors_f: Vec<Vec<f64>> = fine.iter().map(|r| error_vector(system, r)).collect();
    let e_c = errors_c.iter().fold(0.0, |m: f64, e| m.max(norm(e)));
    let e_f = errors_f.iter().fold(0.0, |m: f64, e| m.max(norm(e)));
    let ratio = e_c / e_f;
    let measured = Convergence {
        coarse: e_c,
        fine: e_f,
        ratio,
    };
    if e_f > 4.0 * floor {
        assert!(
            (ratio / factor - 1.0).abs() <= 0.2,
            "{what}: halving dt took the largest error from {e_c:.3e} to {e_f:.3e}, a ratio of \
             {ratio:.3} where order {order} gives {factor} (within 20%)"
        );
    } else {
        assert!(
            e_c <= 4.0 * factor * floor,
            "{what}: the fine run is at round-off ({e_f:.3e}) but the coarse one is not ({e_c:.3e})"
        );
    }
    for (k, (row, e)) in coarse.iter().zip(&errors_c).enumerate() {
        let partner = &fine[2 * k];
        assert_eq!(
            row.t.to_bits(),
            partner.t.to_bits(),
            "{what}: row {k} at t = {} but the fine run's at t = {}",
            row.t,
            partner.t
        );
        let deviation: Vec<f64> = e
            .iter()
            .zip(&errors_f[2 * k])
            .map(|(a, b)| a - factor * b)
            .collect();
        let allowed = 0.2 * factor * e_f + (1.0 + factor) * floor;
        assert!(
            norm(&deviation) <= allowed,
            "{what}: at t = {} the error is {:?} at dt and {:?} at dt/2: not {factor} times \
             (off by {:.3e}, allowed {allowed:.3e})",
            row.t,
            e,
            errors_f[2 * k],
            norm(&deviation)
        );
    }
    measured
}

/// (a) for rows whose error has a stated bound (dopri5's tolerance, a run with retries):
/// every row within `bound` (relative, as [`error`] measures). Returns the largest error.
pub fn within(system: &System, rows: &[Row], bound: f64, what: &str) -> f64 {
    let floor = ROUND_OFF + system.reference_floor();
    let mut largest: f64 = 0.0;
    for row in rows {
        let e = error(system, row);
        assert!(
            e <= bound + floor,
            "{what}: at t = {} the error is {e:.3e}, above the bound {bound:.3e}: x = {:?}, \
             exact {:?}",
            row.t,
            row.x,
            system.exact_state(row.t).0
        );
        largest = largest.max(e);
    }
    largest
}

/// (a) for rows a front end printed for `spec`, against the reference: a fixed-step run
/// converges with the library's run at dt / 2 ([`convergence`]; with a stop condition the
/// rows up to it, then the crossing's state and time); dopri5's rows are within
/// [`crate::matrix::DOPRI_BOUND`] times its tolerance, and so is its event time (s).
pub fn against_reference(spec: &Spec, rows: &[Row], what: &str) {
    let system = spec.system;
    if spec.integrator.is_adaptive() {
        let rtol = spec.rtol.expect("dopri5 runs state their rtol");
        within(system, rows, DOPRI_BOUND * rtol, what);
        if spec.stop_when.is_some() {
            let te = rows.last().expect("rows").t;
            let exact = spec.event_time();
            assert!(
                (te - exact).abs() <= 10.0 * DOPRI_BOUND * rtol,
                "{what}: the event at t = {te}, exactly {exact}"
            );
        }
        return;
    }
    let fine = spec.halved().run();
    assert!(fine.result.is_ok(), "{what}: the run at dt/2 failed");
    let order = spec.integrator.order();
    if spec.stop_when.is_none() {
        convergence(system, order, rows, &fine.rows, what);
        return;
    }
    let (event_c, grid_c) = rows.split_last().expect("rows");
    let (event_f, grid_f) = fine.rows.split_last().expect("rows");
    // The grids up to the earlier crossing (the fine run may cross a step sooner).
    let n_c = grid_c.len().min(grid_f.len().div_ceil(2));
    let measured = convergence(system, order, &grid_c[..n_c], &grid_f[..2 * n_c - 1], what);
    // The crossing's state: its error at dt and at dt / 2, as at every row.
    let factor = 2f64.powi(order as i32);
    let floor = ROUND_OFF + system.reference_floor();
    let (e_c, e_f) = (error_vector(system, event_c), error_vector(system, event_f));
    let deviation: Vec<f64> = e_c.iter().zip(&e_f).map(|(a, b)| a - factor * b).collect();
    let allowed = 0.2 * factor * measured.fine.max(norm(&e_f)) + (1.0 + factor) * floor;
    assert!(
        norm(&deviation) <= allowed,
        "{what}: at the crossing (t = {} and {}) the error is {e_c:?} at dt and {e_f:?} at dt/2",
        event_c.t,
        event_f.t
    );
    // Its time: the crossing moves by (error of g) / (rate of g), so within the state's
    // error times the system's time scale length / speed, with a factor 100 for crossings
    // slower than the system's speed (the time's own error term can vanish, so its ratio
    // at dt and dt / 2 is not asserted). A crossing a step late is off by dt.
    let exact = spec.event_time();
    let scale = system.length / system.speed;
    for (row, largest) in [(event_c, measured.coarse), (event_f, measured.fine)] {
        let bound = 100.0 * largest.max(floor) * scale + 1e-10 * spec.dt;
        assert!(
            (row.t - exact).abs() <= bound,
            "{what}: the crossing at t = {}, exactly {exact}: off by {:.3e}, allowed {bound:.3e}",
            row.t,
            row.t - exact
        );
    }
}
