//! `baton replay`: a past run rebuilt from its journal.

use std::path::PathBuf;
use std::process::ExitCode;

/// The arguments of `baton replay`.
#[derive(clap::Args)]
pub struct Replay {
    /// The folder, or etcd://HOST:PORT[,…]/PREFIX, given to `baton run --journal`.
    #[arg(long, value_name = "DIR|etcd://…/PREFIX")]
    pub journal: crate::journal::Place,
    /// Where the recording goes: save:PATH.rrd, connect or connect:URL, spawn, or off.
    #[arg(long, value_name = "SINK", default_value = "off")]
    pub rerun: crate::recording::Sink,
    /// Write the run's trace as JSON Lines.
    #[arg(long, value_name = "FILE")]
    pub trace: Option<PathBuf>,
    /// Trace this variable's value as `baton run --watch` did (give the run's own): the trace is then the one the
    /// run wrote. Repeat for more.
    #[arg(long, value_name = "VARIABLE")]
    pub watch: Vec<String>,
}

impl Replay {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let Replay { journal, rerun, trace, watch } = self;
        let opts = crate::replay::ReplayOptions { journal, rerun, trace, watch };
        crate::replay::replay(&opts).map(|()| ExitCode::SUCCESS)
    }
}
