//! `baton status`: the charts running behind a router, their active steps, tokens and agents.

use std::path::PathBuf;
use std::process::ExitCode;

use super::block_on;

/// The arguments of `baton status`.
#[derive(clap::Args)]
pub struct Status {
    /// The router to reach: the coordinator's `--listen` endpoint or the cell's router, such as
    /// tcp/127.0.0.1:7447 or tls/router.cell4.local:7447 (repeat for several).
    #[arg(long, value_name = "ENDPOINT", required = true)]
    pub connect: Vec<String>,
    /// One JSON object per running chart.
    #[arg(long)]
    pub json: bool,
    /// Why each active step waits: its transitions' FALSE parts with their values, a convergence's missing
    /// branches, a skill still running, a hold, a fault, a minimum time — asked of the agents for their steps.
    #[arg(long)]
    pub why: bool,
    /// A Zenoh configuration file (TLS, credentials…).
    #[arg(long, value_name = "FILE")]
    pub zenoh_config: Option<PathBuf>,
}

impl Status {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let Status { connect, json, why, zenoh_config } = self;
        block_on(async move {
            crate::client::status(&connect, zenoh_config.as_deref(), json, why).await?;
            Ok(ExitCode::SUCCESS)
        })
    }
}
