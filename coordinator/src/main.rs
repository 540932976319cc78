//! `baton`: checks and simulates IEC 61131-3 sequential function charts.

mod cli;

use std::process::ExitCode;

fn main() -> ExitCode {
    cli::main()
}
