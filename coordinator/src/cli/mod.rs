//! The `baton` command line: one file per command (as mini-redis does), each an argument struct with its `run`.
//! What a command does lives in its own module (`crate::run`, `crate::testing`, …); here it is only parsed and
//! called.

mod bench;
mod check;
mod ctl;
mod demo;
mod deploy;
mod export;
mod replay;
mod run;
mod set;
mod sim;
mod status;
mod test;

use std::io::Write;
use std::path::Path;
use std::process::ExitCode;

use anyhow::Context;
use baton_proto::front::diag::LineIndex;
use baton_proto::pipeline::Report;
use clap::{Parser, Subcommand};

/// Exit status of `baton check` and `baton sim` when the chart has errors.
const EXIT_INVALID: u8 = 1;
/// Exit status for usage and I/O errors (clap uses it too).
const EXIT_USAGE: u8 = 2;
/// Exit status of `baton run` when an operator stopped the run (`baton ctl stop`, an interrupt).
const EXIT_STOPPED: u8 = 3;
/// Exit status of `baton run` when an operator aborted the run (`baton ctl abort`, a second interrupt).
const EXIT_ABORTED: u8 = 4;
/// Exit status of `baton run` when SIGTERM took the process away from a journaled run, which its journal resumes
/// (`deploy/systemd/baton-run@.service` counts it a clean stop).
const EXIT_LEFT: u8 = 5;

#[derive(Parser)]
#[command(name = "baton", version, about = "Sequential function charts (IEC 61131-3), checked and run")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Check a chart: syntax, names, types, safety and reachability. Exit 0 when valid, 1 on errors.
    Check(check::Check),
    /// Run a chart on virtual time and print its events as JSON Lines.
    Sim(sim::Sim),
    /// Write a valid chart file out in another format: `--plcopen`, PLCopen TC6 v2.01 XML with positions, for
    /// Beremiz, OpenPLC Editor and other IEC 61131-3 tools. Every chart of the file, or the one `--pou` names.
    Export(export::Export),
    /// Coordinate a chart across agents over Zenoh; exit 0 when it reaches a terminal situation, 3 when an
    /// operator stopped it (an interrupt stops it too), 4 when one aborted it (a second interrupt).
    Run(run::Run),
    /// Rebuild a past run from its journal: its Rerun recording and its trace (no network, no agents).
    Replay(replay::Replay),
    /// Set an input of a chart running behind a router: baton set --connect EP [--run ID] NAME=VALUE. With several
    /// runs behind the router, --run says which (nothing is set otherwise).
    Set(set::Set),
    /// Run scenario files (*.test.toml) of your charts on a simulated cell, on virtual time: exit 0 when every
    /// expectation holds, 1 when one fails, 2 when a scenario could not run, 3 on a malformed scenario file
    Test(test::Test),
    /// Run the bundled multi-robot cell: a router, a coordinator and simulated robots on loopback.
    Demo(demo::Demo),
    /// Measure the distributed runtime on loopback: Zenoh and token round trips, convergence, throughput.
    Bench(bench::Bench),
    /// The far end of the bench's raw Zenoh round trip.
    #[command(hide = true)]
    BenchEcho(bench::BenchEcho),
    /// Print the active steps, tokens in flight and live agents of the charts running behind a router.
    Status(status::Status),
    /// Operate a running chart: hold, unhold, suspend, unsuspend, stop, abort; ack or shelve an alarm.
    /// baton ctl --connect EP [--run ID] COMMAND [TARGET …] [--agent NAME] [--step S] [--reason TEXT]
    Ctl(ctl::Ctl),
    /// Prepare a cell's deployment: `certs` makes a CA and a certificate per process (the name as its common
    /// name); `acl` writes the router's access control from the chart's placement and the identities.
    #[command(subcommand)]
    Deploy(deploy::Deploy),
}

pub fn main() -> ExitCode {
    // Zenoh's own log, when `RUST_LOG` asks for it (`RUST_LOG=zenoh=debug`): what its sessions, links, routing and a
    // router's access control do.
    zenoh::try_init_log_from_env();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Check(c) => c.run(),
        Command::Sim(c) => c.run(),
        Command::Export(c) => c.run(),
        Command::Run(c) => c.run(),
        Command::Replay(c) => c.run(),
        Command::Set(c) => c.run(),
        Command::Test(c) => c.run(),
        Command::Demo(c) => c.run(),
        Command::Bench(c) => c.run(),
        Command::BenchEcho(c) => c.run(),
        Command::Status(c) => c.run(),
        Command::Ctl(c) => c.run(),
        Command::Deploy(c) => c.run(),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(EXIT_USAGE)
        }
    }
}

/// Where a one-shot client (`set`, `status`, `ctl`) reaches a cell: its router, and the Zenoh configuration a
/// secured one asks for.
#[derive(clap::Args)]
pub struct Reach {
    /// The router to reach: the coordinator's `--listen` endpoint or the cell's router, such as
    /// tcp/127.0.0.1:7447 or tls/router.cell4.local:7447 (repeat for several).
    #[arg(long, value_name = "ENDPOINT", required = true)]
    pub connect: Vec<String>,
    /// A Zenoh configuration file (TLS, credentials…).
    #[arg(long, value_name = "FILE")]
    pub zenoh_config: Option<std::path::PathBuf>,
}

/// Zenoh needs the multi-thread runtime (its blocking calls panic inside a current-thread one).
fn block_on(fut: impl std::future::Future<Output = anyhow::Result<ExitCode>>) -> anyhow::Result<ExitCode> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .thread_stack_size(baton_proto::limits::CHART_STACK_BYTES)
        .enable_all()
        .build()
        .context("cannot start the runtime")?;
    runtime.block_on(fut)
}

fn print_diagnostics(path: &Path, src: &str, report: &Report, keep: impl Fn(u32) -> bool) {
    let index = LineIndex::new(src);
    let shown = path.display().to_string();
    let mut err = std::io::stderr().lock();
    for d in report.diagnostics.iter().filter(|d| keep(d.span.start)) {
        let _ = write!(err, "{}", index.render(&shown, d));
    }
}
