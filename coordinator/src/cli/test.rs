//! `baton test`: users' scenario files run on a simulated cell (or, with `--cluster`, on real processes).

use std::path::PathBuf;
use std::process::ExitCode;

/// The arguments of `baton test`.
#[derive(clap::Args)]
pub struct Test {
    /// Scenario files, or folders to search for *.test.toml (default: the current folder).
    pub paths: Vec<PathBuf>,
    /// Run N schedules per scenario, seeds from its own `seed` on (durations, message order and delays, fault
    /// timing); a failure prints the command that replays its seed.
    #[arg(long, value_name = "N")]
    pub seeds: Option<u64>,
    /// Run exactly this seed: the replay of a failure.
    #[arg(long, value_name = "SEED", conflicts_with = "seeds")]
    pub seed: Option<u64>,
    /// Write a JUnit XML report here (one testsuite per file, one testcase per expectation).
    #[arg(long, value_name = "FILE")]
    pub junit: Option<PathBuf>,
    /// Where the traces and Rerun recordings of failing runs go (and, with --cluster, their processes' logs).
    #[arg(long, value_name = "DIR", default_value = "baton-test-failures")]
    pub out: PathBuf,
    /// Runs at once (default: the machine's cores).
    #[arg(long, value_name = "N")]
    pub jobs: Option<usize>,
    /// Print only failures and the total.
    #[arg(long, short)]
    pub quiet: bool,
    /// Print which steps, transitions and branches the scenarios exercised, and which steps faults struck.
    #[arg(long)]
    pub coverage: bool,
    /// Stop after this much wall time (`10min`, `90s`): what ran is reported and the JUnit file written;
    /// exit status 2. An interrupt (SIGINT, SIGTERM) does the same, with exit status 130.
    #[arg(long, value_name = "DURATION", value_parser = parse_wall_time)]
    pub timeout: Option<std::time::Duration>,
    /// Run on real processes on loopback, in real time: an embedded router, `baton run` and a
    /// `baton-agent --simulate` per agent; faults by signals, cut cables and a coordinator restarted on its
    /// journal.
    #[arg(long)]
    pub cluster: bool,
    /// Keep the trace and Rerun recording of every run under --out, not only of failing runs.
    #[arg(long)]
    pub keep: bool,
}

impl Test {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let Test { paths, seeds, seed, junit, out, jobs, quiet, coverage, timeout, cluster, keep } = self;
        let jobs = jobs.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
        crate::testing::test(&crate::testing::TestOptions {
            paths,
            seeds,
            seed,
            junit,
            out,
            jobs,
            quiet,
            coverage,
            timeout,
            cluster,
            keep,
        })
    }
}

fn parse_wall_time(s: &str) -> Result<std::time::Duration, String> {
    baton_proto::testing::scenario::parse_duration(s).map(std::time::Duration::from_millis)
}
