//! `baton`: checks, simulates and coordinates IEC 61131-3 sequential function charts.
//!
//! # Where things are
//!
//! ARCHITECTURE.md's code map (`coordinator/`) is the one map of this crate; each module's documentation says what
//! it does.

mod bench;
mod chart_file;
mod cli;
mod client;
mod console;
mod demo;
mod demo_chart;
mod deploy;
mod election;
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
