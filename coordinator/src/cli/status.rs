//! `baton status`: the charts running behind a router, their active steps, tokens and agents.

use std::process::ExitCode;

use super::common::block_on;

/// The arguments of `baton status`.
#[derive(clap::Args)]
pub struct Status {
    #[command(flatten)]
    pub reach: super::common::Reach,
    /// One JSON object per running chart.
    #[arg(long)]
    pub json: bool,
    /// Why each active step waits: its transitions' FALSE parts with their values, a convergence's missing
    /// branches, a skill still running, a hold, a fault, a minimum time — asked of the agents for their steps.
    #[arg(long)]
    pub why: bool,
}

impl Status {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let Status { reach, json, why } = self;
        block_on(async move {
            crate::client::status(&reach.connect, reach.zenoh_config.as_deref(), json, why).await?;
            Ok(ExitCode::SUCCESS)
        })
    }
}
