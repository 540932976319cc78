//! `baton`: checks, simulates and coordinates IEC 61131-3 sequential function charts.
//!
//! # Where things are
//!
//! The command line (`cli/`, clap, one file per command); `chart_file.rs`, a chart file read, decoded and picked;
//! `run/`, the coordinator's Zenoh shell (samples in, `Coordinator` outputs out, trace file, summary, the
//! chart/status/set queryables); `client.rs` (`baton set`, `baton status`); `demo.rs` and `demo_chart.rs` (`baton demo`
//! and its cell chart, of which `examples/cell.st` is the two-robot rendering); `bench/` (`baton bench`); `baton-shell`'s `zenoh_config`
//! (Baton's Zenoh settings over the user's `--zenoh-config` file); `journal.rs` (`--journal DIR`: the records appended to one file,
//! a writer thread with group commit, `Writer::durable` telling the shell which batches it may act on); `recording.rs`
//! (`--rerun SINK`: `Recorder`, which the shell hands trace records and changed variable values, and the `baton-rerun`
//! thread's `Logger`, which turns them into Rerun entities, plus the default blueprint); `replay.rs` (`baton replay`: a
//! journal replayed into a fresh `Coordinator`, with no network, into the same `Records` as a live run); `testing/`
//! (`baton test`: `mod.rs` — scenario files found and read, (scenario, seed) runs on a pool of threads, the report —
//! per failure the events around it, the active steps, the variables, the faults, the failing run's trace and `.rrd` —
//! the JUnit file and the exit status; `real_processes.rs`, `--cluster`: per run an embedded router, `baton-agent
//! --simulate` processes that must be live before `baton run` starts, the trace followed as it grows (a restarted
//! coordinator's replayed past skipped up to its `recover`) into `testing::run::Observer`, and the faults as signals,
//! pulled cables and a journal restart; `cable.rs`, an agent's cable to the router — a loopback TCP relay that can be
//! cut without closing anything, healed, or delayed in order); a run's folder is claimed with a lock (`claim_run_dir`),
//! so two scenarios of one name never share one, and every child process dies with the runner (`PR_SET_PDEATHSIG`).
//! `baton set --run ID` addresses one run, and refuses to guess when several answer. `--watch` values are the
//! journaled coordinator's own trace records (`Journaled::watch`), made after each record as its replay makes them, so
//! that they too wait for the journal and a resumed run traces them as the live one did. `run/records.rs`'s `Records` is the one place trace records go: the bench's probe, the recording, the
//! summary's step times and the trace file; `replay_records` feeds a journal's records to a coordinator and its outputs
//! to `Records`, for a resumed run and for `baton replay` alike.

mod bench;
mod chart_file;
mod cli;
mod client;
mod demo;
mod demo_chart;
mod deploy;
mod journal;
mod recording;
mod replay;
mod run;
mod testing;

use std::process::ExitCode;

fn main() -> ExitCode {
    // Like any Unix tool, end quietly when the reader of our output goes away (`baton check … | head`): Rust
    // ignores SIGPIPE, which turns every later print into a panic.
    // SAFETY: setting a signal's disposition to its default before any thread starts has no other effect.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    // Everything runs on a thread of the stack a chart may need (`limits::CHART_STACK_BYTES`): whatever `baton
    // check` accepts, `baton run`, `sim` and `test` hold.
    let stack = baton_proto::limits::CHART_STACK_BYTES;
    let main = std::thread::Builder::new().name("baton".into()).stack_size(stack).spawn(cli::main);
    match main.map(std::thread::JoinHandle::join) {
        Ok(Ok(code)) => code,
        Ok(Err(_)) => ExitCode::from(101),
        Err(e) => {
            eprintln!("error: cannot start baton's thread: {e}");
            ExitCode::from(1)
        }
    }
}
