//! Running many cases and reporting every failure at once (a defect usually fails many
//! cases; the list says which).

use std::panic::{catch_unwind, AssertUnwindSafe};

/// Run `check` on every case; panic at the end listing every case that failed, with its
/// message. `label` names a case.
pub fn each<T>(what: &str, cases: &[T], label: impl Fn(&T) -> String, check: impl Fn(&T)) {
    let mut failures = Vec::new();
    for case in cases {
        if let Err(e) = catch_unwind(AssertUnwindSafe(|| check(case))) {
            let message = e
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| e.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_default();
            failures.push(format!("{}: {message}", label(case)));
        }
    }
    assert!(
        failures.is_empty(),
        "{what}: {} of {} cases failed:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n")
    );
}
