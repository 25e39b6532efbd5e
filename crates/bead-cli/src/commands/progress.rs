//! A progress bar for long runs: on stderr, only when stderr is a terminal, and only once a
//! run has taken more than a second (short runs print nothing).

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use bead::simulate::Progress;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// Shown after this much wall time.
const DELAY: Duration = Duration::from_secs(1);

/// A [`Progress`] drawing an indicatif bar on stderr (see the module documentation).
pub struct Bar {
    label: String,
    start: Instant,
    terminal: bool,
    bar: Option<ProgressBar>,
}

impl Bar {
    pub fn new(label: String) -> Self {
        Bar {
            label,
            start: Instant::now(),
            terminal: std::io::stderr().is_terminal(),
            bar: None,
        }
    }

    /// Remove the bar (if it was shown).
    pub fn finish(&mut self) {
        if let Some(bar) = self.bar.take() {
            bar.finish_and_clear();
        }
    }
}

impl Progress for Bar {
    fn advance(&mut self, step: u64, total: u64) {
        if !self.terminal {
            return;
        }
        if self.bar.is_none() && self.start.elapsed() >= DELAY && step < total {
            let bar = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr())
                .with_elapsed(self.start.elapsed());
            if let Ok(style) = ProgressStyle::with_template(
                "{prefix} [{bar:30}] {pos}/{len} steps, {elapsed} elapsed, eta {eta}",
            ) {
                bar.set_style(style.progress_chars("=> "));
            }
            bar.set_prefix(self.label.clone());
            self.bar = Some(bar);
        }
        if let Some(bar) = &self.bar {
            bar.set_position(step);
        }
    }
}

impl Drop for Bar {
    fn drop(&mut self) {
        self.finish();
    }
}
