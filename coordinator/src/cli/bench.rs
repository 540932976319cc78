//! `baton bench`: the distributed runtime measured on loopback (and the far end of its raw Zenoh round trip).

use std::process::ExitCode;

use anyhow::bail;

use super::common::block_on;

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
    /// Tokens in flight per agent when the throughput phase is repeated at the cell's capacity (phase 5b): enough
    /// that the run without the journal is bound by the CPU, not by a token's round trip.
    #[arg(long, default_value_t = 16)]
    pub capacity_lanes_per_agent: u32,
    /// Parts of the demo chart in the recording phase.
    #[arg(long, default_value_t = 400)]
    pub parts: u32,
    /// Print the figures as JSON.
    #[arg(long)]
    pub json: bool,
    /// Only phases 1–6: latency, throughput, the journal, the demo chart.
    #[arg(long, conflicts_with_all = ["scale_only", "resume_only"])]
    pub base_only: bool,
    /// Only phases 7–10: many agents, concurrent runs, a mesh of routers, memory.
    #[arg(long, conflicts_with = "resume_only")]
    pub scale_only: bool,
    /// Only phase 11: a long journaled run, its coordinator gone, resumed from its last snapshot.
    #[arg(long, conflicts_with = "failover_only")]
    pub resume_only: bool,
    /// Only phase 12: standby coordinators on the etcd of --etcd, the active one killed --kills times; the time from
    /// each SIGKILL to the standby's first dispatch.
    #[arg(long, requires = "etcd", conflicts_with_all = ["base_only", "scale_only"])]
    pub failover_only: bool,
    /// Only phase 13: the operator console in Chromium (through chromedriver), with a 1,000-step chart and the agents
    /// of --console-agents: from a step's activation to the page showing it, the first render, and the console's
    /// memory following 16 runs.
    #[arg(long, conflicts_with_all = ["base_only", "scale_only", "resume_only", "failover_only"])]
    pub console_only: bool,
    /// The agent counts of phase 13.
    #[arg(long, value_delimiter = ',', default_value = "8,256", value_name = "N,N,…")]
    pub console_agents: Vec<u32>,
    /// Chromium, for phase 13.
    #[arg(long, default_value = "chromium", value_name = "PATH")]
    pub chromium: String,
    /// Chromium's WebDriver, for phase 13.
    #[arg(long, default_value = "chromedriver", value_name = "PATH")]
    pub chromedriver: String,
    /// The etcd of phase 12, and a prefix for its keys: etcd://HOST:PORT[,HOST:PORT…]/PREFIX.
    #[arg(long, value_name = "etcd://…/PREFIX")]
    pub etcd: Option<crate::election::Election>,
    /// Kills of phase 12.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u32).range(1..=1000))]
    pub kills: u32,
    /// The coordinators' lease in phase 12, in seconds.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u64).range(2..=60))]
    pub lease: u64,
    /// Tokens of phase 11's run.
    #[arg(long, default_value_t = 1_000_000)]
    pub resume_tokens: u64,
    /// The agent counts of phase 7, hosted in one `baton-agent` process each time.
    #[arg(long, value_delimiter = ',', default_value = "8,64,256", value_name = "N,N,…")]
    pub scale_agents: Vec<u32>,
}

/// The arguments of the hidden `baton bench-echo`.
#[derive(clap::Args)]
pub struct BenchEcho {
    /// The router to reach: the coordinator's `--listen` endpoint or the cell's router, such as
    /// tcp/127.0.0.1:7447 or tls/router.cell4.local:7447 (repeat for several).
    #[arg(long, required = true)]
    pub connect: Vec<String>,
}

impl Bench {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let Bench {
            samples,
            tokens,
            agents,
            lanes_per_agent,
            capacity_lanes_per_agent,
            parts,
            json,
            base_only,
            scale_only,
            resume_only,
            resume_tokens,
            scale_agents,
            failover_only,
            etcd,
            kills,
            lease,
            console_only,
            console_agents,
            chromium,
            chromedriver,
        } = self;
        block_on(async move {
            if [samples, tokens, agents, lanes_per_agent, capacity_lanes_per_agent, parts].contains(&0) {
                bail!(
                    "--samples, --tokens, --agents, --lanes-per-agent, --capacity-lanes-per-agent and --parts must be \
                     at least 1"
                );
            }
            if console_agents.is_empty() || console_agents.iter().any(|n| !(1..=4096).contains(n)) {
                bail!("--console-agents takes counts from 1 to 4096, such as 8,256");
            }
            if scale_agents.is_empty() || scale_agents.iter().any(|n| !(1..=4096).contains(n)) {
                bail!("--scale-agents takes counts from 1 to 4096, such as 8,64,256");
            }
            let options = crate::bench::BenchOptions {
                samples,
                tokens,
                agents,
                lanes_per_agent,
                capacity_lanes_per_agent,
                parts,
                base: !scale_only && !resume_only && !failover_only && !console_only,
                scale: !base_only && !resume_only && !failover_only && !console_only,
                scale_agents,
                resume: !base_only && !scale_only && !failover_only && !console_only,
                resume_tokens: resume_tokens.max(1),
                failover: if failover_only { etcd.map(|e| (e, kills, lease)) } else { None },
                console: console_only
                    .then(|| (crate::bench::Browser { chromium: which(&chromium), chromedriver }, console_agents)),
            };
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

/// Chromium's path: chromedriver takes the browser by its path, not by a name on `PATH`.
fn which(program: &str) -> String {
    if program.contains('/') {
        return program.to_string();
    }
    crate::demo::on_path(program).map_or_else(|| program.to_string(), |path| path.display().to_string())
}

impl BenchEcho {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        block_on(async move {
            crate::bench::echo(&self.connect).await?;
            Ok(ExitCode::SUCCESS)
        })
    }
}
