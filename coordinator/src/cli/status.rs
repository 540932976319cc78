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
    /// Also say which coordinator of the run's election is active, since when and at which term, and which stand
    /// by (as `baton run --election` names it).
    #[arg(long, value_name = "etcd://…/PREFIX")]
    pub election: Option<crate::election::Election>,
}

impl Status {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let Status { reach, json, why, election } = self;
        block_on(async move {
            let coordinators = match &election {
                Some(e) => Some(crate::election::candidates(e).await?),
                None => None,
            };
            crate::client::status(&reach.connect, reach.zenoh_config.as_deref(), json, why, coordinators).await?;
            Ok(ExitCode::SUCCESS)
        })
    }
}
