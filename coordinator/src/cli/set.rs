//! `baton set`: an input of a running chart set from outside.

use std::path::PathBuf;
use std::process::ExitCode;

use super::{block_on, EXIT_INVALID};

/// The arguments of `baton set`.
#[derive(clap::Args)]
pub struct Set {
    /// The router to reach: the coordinator's `--listen` endpoint or the cell's router, such as
    /// tcp/127.0.0.1:7447 or tls/router.cell4.local:7447 (repeat for several).
    #[arg(long, value_name = "ENDPOINT", required = true)]
    pub connect: Vec<String>,
    /// The run, by its id as `baton status` lists it (or the start of it).
    #[arg(long, value_name = "ID")]
    pub run: Option<String>,
    /// The input and its value, as the chart's type reads it: `go=true`, `speed=2.5`, `mode=2`.
    #[arg(value_name = "NAME=VALUE", value_parser = crate::client::parse_assignment)]
    pub assignment: (String, serde_json::Value),
    /// A Zenoh configuration file (TLS, credentials…).
    #[arg(long, value_name = "FILE")]
    pub zenoh_config: Option<PathBuf>,
}

impl Set {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let Set { connect, run, assignment: (name, value), zenoh_config } = self;
        block_on(async move {
            let taken = crate::client::set(&connect, zenoh_config.as_deref(), run.as_deref(), &name, value).await?;
            Ok(if taken { ExitCode::SUCCESS } else { ExitCode::from(EXIT_INVALID) })
        })
    }
}
