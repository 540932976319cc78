//! The `baton` command line: one file per command (as mini-redis does), each an argument struct with its `run`.
//! What a command does lives in its own module (`crate::run`, `crate::testing`, …); here it is only parsed and
//! called.

mod bench;
mod check;
mod common;
mod console;
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

use std::process::ExitCode;

use clap::{Parser, Subcommand};

use common::EXIT_USAGE;

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
    Run(Box<run::Run>),
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
    /// The operator console in a browser: each run's chart with its active steps, its state and legal commands,
    /// its alarms and agents. baton console --connect EP [--listen 127.0.0.1:8080]
    Console(console::Console),
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
        Command::Console(c) => c.run(),
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
