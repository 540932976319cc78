//! `baton set`: an input of a running chart set from outside.

use std::process::ExitCode;

use super::common::{block_on, EXIT_INVALID};

/// The arguments of `baton set`.
#[derive(clap::Args)]
pub struct Set {
    #[command(flatten)]
    pub reach: super::common::Reach,
    /// The run, by its id as `baton status` lists it (or the start of it).
    #[arg(long, value_name = "ID")]
    pub run: Option<String>,
    /// The input and its value, as the chart's type reads it: `go=true`, `speed=2.5`, `mode=2`.
    #[arg(value_name = "NAME=VALUE", value_parser = crate::client::parse_assignment)]
    pub assignment: (String, serde_json::Value),
}

impl Set {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let Set { reach, run, assignment: (name, value) } = self;
        block_on(async move {
            let file = reach.zenoh_config.as_deref();
            let taken = crate::client::set(&reach.connect, file, run.as_deref(), &name, value).await?;
            Ok(if taken { ExitCode::SUCCESS } else { ExitCode::from(EXIT_INVALID) })
        })
    }
}
