//! `baton`: checks and simulates IEC 61131-3 sequential function charts.

mod cli;
mod demo_chart;

use std::process::ExitCode;

fn main() -> ExitCode {
    cli::main()
}
