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
    /// Parts the cell makes before it stops.
    #[arg(long, default_value_t = 3)]
    pub parts: u32,
    /// Keep the chart, trace, summary and logs in this folder.
    #[arg(long, value_name = "DIR")]
    pub keep: Option<PathBuf>,
    /// Record the run for the Rerun viewer: save:PATH.rrd, connect or connect:URL, spawn, or off.
    #[arg(long, value_name = "SINK", default_value = "save:baton-demo.rrd")]
    pub rerun: crate::recording::Sink,
}

impl Demo {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let Demo { agents, parts, keep, rerun } = self;
        block_on(crate::demo::demo(crate::demo::DemoOptions { agents, parts, keep, rerun }))
    }
}
