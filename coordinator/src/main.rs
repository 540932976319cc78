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
    // Like any Unix tool, the commands that only print end quietly when the reader of their output goes away
    // (`baton check … | head`): Rust ignores SIGPIPE, which turns every later print into a panic. Not the commands
    // with sockets of their own: a peer that closes its end (an etcd member killed, a router gone) would kill
    // `baton run` with SIGPIPE on its next write, where Rust's default turns it into an error handled there.
    let offline = std::env::args_os()
        .nth(1)
        .is_some_and(|c| ["check", "sim", "export", "deploy"].contains(&c.to_str().unwrap_or("")));
    if offline {
        // SAFETY: setting a signal's disposition to its default before any thread starts has no other effect.
        unsafe {
            libc::signal(libc::SIGPIPE, libc::SIG_DFL);
        }
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
