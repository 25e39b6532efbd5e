//! Wall-clock time for the sessions' budgets (how long a tick may step a panel, how long the
//! view's preview run may take). Natively it is [`std::time::Instant`]; inside a browser
//! (wasm32, where `Instant::now` is not available) the embedder supplies the page's clock
//! (`performance.now()`) once with [`set_source`]. Budgets only pace the work: they never
//! change a result.

use std::sync::OnceLock;
use std::time::Duration;

/// The embedder's clock: seconds since any fixed origin.
static SOURCE: OnceLock<fn() -> f64> = OnceLock::new();

/// Use `now` (seconds since a fixed origin, non-decreasing) as the clock; the first call
/// wins. Needed on wasm32, where without it every budget reads zero elapsed time (work is
/// then bounded by its step counts alone).
pub fn set_source(now: fn() -> f64) {
    let _ = SOURCE.set(now);
}

/// Seconds since a fixed origin.
fn now() -> f64 {
    if let Some(source) = SOURCE.get() {
        return source();
    }
    native_now()
}

#[cfg(not(target_arch = "wasm32"))]
fn native_now() -> f64 {
    static ORIGIN: OnceLock<std::time::Instant> = OnceLock::new();
    ORIGIN
        .get_or_init(std::time::Instant::now)
        .elapsed()
        .as_secs_f64()
}

#[cfg(target_arch = "wasm32")]
fn native_now() -> f64 {
    0.0
}

/// A running stopwatch.
#[derive(Clone, Copy, Debug)]
pub struct Stopwatch {
    start: f64,
}

impl Stopwatch {
    /// Started now.
    pub fn start() -> Stopwatch {
        Stopwatch { start: now() }
    }

    /// Time since [`Stopwatch::start`].
    pub fn elapsed(&self) -> Duration {
        Duration::from_secs_f64((now() - self.start).max(0.0))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stopwatch_measures_the_time_slept() {
        let watch = Stopwatch::start();
        std::thread::sleep(Duration::from_millis(20));
        let elapsed = watch.elapsed();
        assert!(elapsed >= Duration::from_millis(20), "{elapsed:?}");
    }
}
