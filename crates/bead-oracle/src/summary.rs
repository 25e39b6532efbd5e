//! A run's summary (`bead run --json`, `Scene.run().summary`, the library's `Summary`) against
//! the run's own rows: the final state is the last row's, bit for bit, at the time asked for.

use serde_json::Value;

use crate::rows::Row;
use crate::run::Spec;

/// The numbers of `value`, exactly.
fn numbers(value: &Value) -> Vec<f64> {
    value
        .as_array()
        .unwrap_or_else(|| panic!("not an array: {value}"))
        .iter()
        .map(|v| v.as_f64().unwrap_or_else(|| panic!("not a number: {v}")))
        .collect()
}

fn same(a: f64, b: f64) -> bool {
    a.to_bits() == b.to_bits()
}

/// The time a run of `spec` must end at when no event stops it: its duration (or steps dt).
pub fn end_time(spec: &Spec) -> f64 {
    spec.duration
        .unwrap_or_else(|| spec.steps.expect("duration or steps") as f64 * spec.dt)
}

/// (c) and the end time: `summary` (parsed JSON) describes the last of `rows`, bit for bit,
/// and the run ended where asked: at the stop condition's crossing (`stop_time`) or at
/// the duration. `particles` names the particles in order.
pub fn check_summary(spec: &Spec, summary: &Value, rows: &[Row], particles: &[&str], what: &str) {
    let last = rows.last().expect("rows");
    let first = &rows[0];
    let t_final = summary["t_final"].as_f64().expect("t_final");
    assert!(
        same(t_final, last.t),
        "{what}: t_final {t_final} but the last row is at {}",
        last.t
    );
    match summary["stop_time"].as_f64() {
        Some(stop) => assert!(same(stop, t_final), "{what}: stop_time {stop}"),
        None => {
            let end = end_time(spec);
            assert!(
                (t_final - end).abs() <= 4.0 * f64::EPSILON * end,
                "{what}: the run ended at t = {t_final}, asked for {end}"
            );
        }
    }
    assert_eq!(summary["completed"], Value::Bool(true), "{what}: completed");
    let dim = spec.system.dim;
    for (p, name) in particles.iter().enumerate() {
        let state = &summary["particles"][name];
        let position = numbers(&state["position"]);
        let velocity = numbers(&state["velocity"]);
        let (x, v) = (
            &last.x[p * dim..(p + 1) * dim],
            &last.v[p * dim..(p + 1) * dim],
        );
        assert!(
            position.iter().zip(x).all(|(a, b)| same(*a, *b)) && position.len() == dim,
            "{what}: final position of {name} {position:?}, last row {x:?} (t = {})",
            last.t
        );
        assert!(
            velocity.iter().zip(v).all(|(a, b)| same(*a, *b)) && velocity.len() == dim,
            "{what}: final velocity of {name} {velocity:?}, last row {v:?}"
        );
    }
    let figure = |key: &str| {
        summary[key]
            .as_f64()
            .unwrap_or_else(|| panic!("{what}: {key}"))
    };
    assert!(
        same(figure("energy_final"), last.energy),
        "{what}: energy_final"
    );
    assert!(
        same(figure("energy_initial"), first.energy),
        "{what}: energy_initial"
    );
    assert!(
        same(figure("constraint_error_final"), last.constraint_error),
        "{what}: constraint_error_final"
    );
    let work = summary.get("work_final").and_then(Value::as_f64);
    assert_eq!(
        work.map(f64::to_bits),
        last.work.map(f64::to_bits),
        "{what}: work_final {work:?}, last row {:?}",
        last.work
    );
    if !last.q.is_empty() {
        for (k, name) in spec.system.coordinates.iter().enumerate() {
            let pair = numbers(&summary["coordinates"][name]);
            assert!(
                same(pair[0], last.q[k]) && same(pair[1], last.qdot[k]),
                "{what}: final {name} {pair:?}, last row {} {}",
                last.q[k],
                last.qdot[k]
            );
        }
    }
}
