//! `baton bench`: the distributed runtime measured on loopback (and the far end of its raw Zenoh round trip).

use std::process::ExitCode;

use anyhow::bail;

use super::block_on;

/// The arguments of `baton bench`.
#[derive(clap::Args)]
pub struct Bench {
    /// Round trips and convergences measured.
    #[arg(long, default_value_t = 2000)]
    pub samples: u32,
    /// Tokens in the throughput phase.
    #[arg(long, default_value_t = 40_000)]
    pub tokens: u32,
    /// Agents (processes) in the throughput phase.
    #[arg(long, default_value_t = 8)]
    pub agents: u32,
    /// Tokens in flight per agent in the throughput phase.
    #[arg(long, default_value_t = 4)]
    pub lanes_per_agent: u32,
    /// Parts of the demo chart in the recording phase.
    #[arg(long, default_value_t = 400)]
    pub parts: u32,
    /// Print the figures as JSON.
    #[arg(long)]
    pub json: bool,
}

/// The arguments of the hidden `baton bench-echo`.
#[derive(clap::Args)]
pub struct BenchEcho {
    #[arg(long, required = true)]
    pub connect: Vec<String>,
}

impl Bench {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let Bench { samples, tokens, agents, lanes_per_agent, parts, json } = self;
        block_on(async move {
            if samples == 0 || tokens == 0 || agents == 0 || lanes_per_agent == 0 || parts == 0 {
                bail!("--samples, --tokens, --agents, --lanes-per-agent and --parts must be at least 1");
            }
            let options = crate::bench::BenchOptions { samples, tokens, agents, lanes_per_agent, parts };
            let report = crate::bench::bench(options).await?;
            if json {
                println!("{}", serde_json::to_string_pretty(&report)?);
            } else {
                report.print();
            }
            Ok(ExitCode::SUCCESS)
        })
    }
}

impl BenchEcho {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        block_on(async move {
            crate::bench::echo(&self.connect).await?;
            Ok(ExitCode::SUCCESS)
        })
    }
}
