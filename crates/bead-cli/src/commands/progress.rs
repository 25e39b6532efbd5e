//! A progress bar for long runs: on stderr, only when stderr is a terminal, and only once a
//! run has taken more than a second (short runs print nothing); and Ctrl-C (SIGINT, SIGTERM,
//! SIGHUP) during a run, which ends it at its last good state, its trace, summary and report
//! written as for a failed run (exit code 130). A second one ends the process at once.
//! `bead sweep` stops at the next member handed over in order instead, its CSV holding the
//! rows up to that member.

use std::io::IsTerminal;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Once;
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

/// Set by the first Ctrl-C (or SIGTERM, SIGHUP) after a run has started.
static INTERRUPTED: AtomicBool = AtomicBool::new(false);

/// Whether a run of this process was interrupted (then `main` exits with code 130).
pub fn interrupted() -> bool {
    INTERRUPTED.load(Ordering::Relaxed)
}

/// From the first run on, a signal that would end the process sets [`INTERRUPTED`] instead,
/// which every run's [`Bar`] reports to the run (and `bead sweep` reads between members); a
/// second one exits at once. Commands that start no run (the viewer's server) keep the
/// default: the signal ends them.
pub fn catch_interrupts() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // Without a handler (one already set, or none allowed) a signal ends the process
        // as it did.
        let _ = ctrlc::set_handler(|| {
            if INTERRUPTED.swap(true, Ordering::SeqCst) {
                std::process::exit(130);
            }
        });
    });
}

impl Bar {
    pub fn new(label: String) -> Self {
        catch_interrupts();
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

    fn interrupted(&mut self) -> bool {
        interrupted()
    }
}

impl Drop for Bar {
    fn drop(&mut self) {
        self.finish();
    }
}
