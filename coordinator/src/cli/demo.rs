//! `baton demo`: the bundled multi-robot cell on loopback.

use std::path::PathBuf;
use std::process::ExitCode;

use super::common::block_on;

/// The arguments of `baton demo`.
#[derive(clap::Args)]
pub struct Demo {
    /// Picking robots (each a `baton-agent` process); robot1 and robot2 also assemble.
    #[arg(long, default_value_t = 2)]
    pub agents: usize,
    /// Parts the cell makes before it stops (default 3; with --console, as many as an INT holds: the cell loops
    /// until Ctrl-C).
    #[arg(long)]
    pub parts: Option<u32>,
    /// Keep the chart, trace, summary and logs in this folder.
    #[arg(long, value_name = "DIR")]
    pub keep: Option<PathBuf>,
    /// Record the run for the Rerun viewer: save:PATH.rrd, connect or connect:URL, spawn, serve or serve:ADDR, or
    /// off (default save:baton-demo.rrd; with --console, served on a free loopback port for the console's timeline).
    #[arg(long, value_name = "SINK")]
    pub rerun: Option<crate::recording::Sink>,
    /// Serve the operator console while the cell runs, on ADDR (default 127.0.0.1:8080), and print its address.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = "127.0.0.1:8080")]
    pub console: Option<std::net::SocketAddr>,
}

impl Demo {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let Demo { agents, parts, keep, rerun, console } = self;
        // With the console, the cell keeps making parts for the operator to watch (the chart counts them in an INT).
        let parts = parts.unwrap_or(if console.is_some() { i16::MAX as u32 } else { 3 });
        // With the console, the recording is served for its timeline, live (a file would grow while the cell loops).
        let rerun = match rerun {
            Some(sink) => sink,
            None if console.is_some() => crate::recording::Sink::Serve {
                addr: std::net::SocketAddr::from(([127, 0, 0, 1], crate::demo::free_port()?)),
                origins: Vec::new(),
            },
            None => crate::recording::Sink::Save(PathBuf::from("baton-demo.rrd")),
        };
        block_on(crate::demo::demo(crate::demo::DemoOptions { agents, parts, keep, rerun, console }))
    }
}
