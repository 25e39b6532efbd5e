//! `bead`: the command-line tool. Glue only: flags are parsed in [`args`], resolved against
//! the scene in [`plan`], run by [`commands`] through the library, and reported by [`report`].

mod args;
mod commands;
mod numbers;
mod plan;
mod report;
mod report_args;

use std::io::{self, Write};
use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    // Usage errors exit with code 2 here, with clap's message.
    let cli = args::Cli::parse();
    match commands::dispatch(cli.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            if error
                .downcast_ref::<io::Error>()
                .is_some_and(|e| e.kind() == io::ErrorKind::BrokenPipe)
            {
                // stdout was closed early (`bead check ... | head`): not an error.
                return ExitCode::SUCCESS;
            }
            let _ = writeln!(io::stderr(), "error: {error:#}");
            ExitCode::FAILURE
        }
    }
}
