//! `baton`: checks, simulates and coordinates IEC 61131-3 sequential function charts.

mod bench;
mod cli;
mod client;
mod demo;
mod demo_chart;
mod journal;
mod recording;
mod replay;
mod run;
mod zconf;

use std::process::ExitCode;

fn main() -> ExitCode {
    cli::main()
}
