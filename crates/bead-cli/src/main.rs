//! `bead`: the command-line tool. Glue only: flags are parsed in [`args`], resolved against
//! the scene in [`plan`], run by [`commands`] through the library, and reported by [`report`].

mod args;
mod commands;
mod numbers;
mod outputs;
mod plan;
mod report;
mod report_args;

use std::io::{self, Write};
use std::process::ExitCode;

use clap::Parser;

/// mimalloc rather than the system's allocator: a sweep sets up and drops thousands of
/// simulations, each some hundred small buffers, which glibc's malloc frees and coalesces
/// at ~16% of a sweep's instructions (see DESIGN.md, dependency choices).
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> ExitCode {
    // Usage errors exit with code 2 here, with clap's message.
    let cli = args::Cli::parse();
    if cli.no_jit {
        bead::expr::set_jit_enabled(false);
    }
    let result = commands::dispatch(cli.command);
    if let (true, Err(error)) = (commands::progress::interrupted(), &result) {
        // Ctrl-C ended a run: it stopped at its last good state, its files written, and
        // the error says where; 128 + SIGINT, as a shell reports a process it interrupted.
        // (A command whose runs had all finished when the signal came completes: exit 0.)
        let _ = writeln!(io::stderr(), "error: {}", commands::terminal(&chain(error)));
        return ExitCode::from(130);
    }
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            if error
                .downcast_ref::<io::Error>()
                .is_some_and(|e| e.kind() == io::ErrorKind::BrokenPipe)
            {
                // stdout was closed early (`bead check ... | head`): not an error.
                return ExitCode::SUCCESS;
            }
            let _ = writeln!(
                io::stderr(),
                "error: {}",
                commands::terminal(&chain(&error))
            );
            if error.downcast_ref::<commands::Usage>().is_some() {
                // Flags that contradict each other, found after parsing: like clap's own.
                return ExitCode::from(2);
            }
            ExitCode::FAILURE
        }
    }
}

/// The error and its causes, `: `-separated, each cause once: a cause whose text the message
/// already contains (an error that prints its source and also returns it from `source()`)
/// is not repeated, so an OS error never reads `(os error 2): ... (os error 2)`.
fn chain(error: &anyhow::Error) -> String {
    let mut text = error.to_string();
    for cause in error.chain().skip(1) {
        let cause = cause.to_string();
        if !text.contains(&cause) {
            text.push_str(": ");
            text.push_str(&cause);
        }
    }
    text
}

#[cfg(test)]
mod tests {
    use super::chain;
    use anyhow::Context;

    #[derive(Debug)]
    struct Loud(std::io::Error);
    impl std::fmt::Display for Loud {
        fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            write!(f, "cannot write `x`: {}", self.0)
        }
    }
    impl std::error::Error for Loud {
        fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
            Some(&self.0)
        }
    }

    #[test]
    fn each_cause_is_printed_once() {
        let os = || std::io::Error::from_raw_os_error(2);
        let e = anyhow::Error::new(Loud(os()));
        assert_eq!(chain(&e), format!("cannot write `x`: {}", os()));
        let e = Err::<(), _>(os()).context("cannot open `y`").unwrap_err();
        assert_eq!(chain(&e), format!("cannot open `y`: {}", os()));
    }
}
