//! What every phase of `baton bench` is made of: agents started, a chart run with marks on the trace records it
//! watches, its router's configuration, and the figures taken from the marks (`Latency`, the steady rate).

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context};
use baton_proto::cluster::netconfig::NetConfig;
use serde::Serialize;
use tokio::process::{Child, Command};

use crate::demo::{agent_binary, free_port};
use crate::run::{run_with, Probe, RunOptions};
use baton_host::ZenohResult;
use baton_proto::exec::trace::TraceEvent;

/// Rounds of alternating (1) and (2).
pub(super) const ROUNDS: u32 = 3;

#[derive(Serialize, Clone, Copy)]
pub struct Latency {
    pub samples: usize,
    pub median_us: f64,
    pub p99_us: f64,
}

impl Latency {
    pub(super) fn of(mut v: Vec<Duration>) -> anyhow::Result<Latency> {
        if v.is_empty() {
            bail!("no samples");
        }
        v.sort();
        let us = |d: Duration| d.as_secs_f64() * 1e6;
        Ok(Latency {
            samples: v.len(),
            median_us: us(v[v.len() / 2]),
            p99_us: us(v[(v.len() * 99 / 100).min(v.len() - 1)]),
        })
    }
}

/// The median of a phase's rounds (NaN for none).
pub(super) fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

pub(super) type Marks = Arc<Mutex<Vec<(Instant, TraceEvent, String)>>>;

/// A probe that keeps the instants of the events the bench measures.
pub(super) fn marks(keep: &'static [TraceEvent]) -> (Marks, Probe) {
    let marks: Marks = Arc::new(Mutex::new(Vec::new()));
    let m = Arc::clone(&marks);
    let probe: Probe = Box::new(move |rec| {
        if keep.contains(&rec.event) {
            let now = Instant::now();
            if let Ok(mut v) = m.lock() {
                v.push((now, rec.event, rec.name.clone()));
            }
        }
    });
    (marks, probe)
}

/// A router listening on `listen` and linked to the routers at `connect`.
pub(super) fn router_config(listen: &str, connect: &[String]) -> anyhow::Result<zenoh::Config> {
    let net = NetConfig { connect: connect.to_vec(), ..NetConfig::router(&[listen.to_string()]) };
    zenoh::Config::from_json5(&net.json5()).zenoh()
}

pub(super) fn spawn_logged(cmd: &mut Command) -> anyhow::Result<Child> {
    // What the bench's processes say goes to `$BATON_BENCH_LOGS` when it is set, for a phase that did not finish.
    let stderr = match std::env::var_os("BATON_BENCH_LOGS") {
        Some(path) => Stdio::from(std::fs::OpenOptions::new().create(true).append(true).open(path)?),
        None => Stdio::null(),
    };
    cmd.stdout(Stdio::null()).stderr(stderr).kill_on_drop(true).spawn().context("cannot start a bench process")
}

/// Agents named `names`, each also in role `assembler` (which only the demo chart uses).
pub(super) fn spawn_agents(endpoint: &str, names: &[String]) -> anyhow::Result<Vec<Child>> {
    let bin = agent_binary()?;
    names
        .iter()
        .map(|n| spawn_logged(Command::new(&bin).args(["--connect", endpoint, "--name", n, "--role", "assembler"])))
        .collect()
}

/// The agents of a bench chart.
pub(super) enum Agents<'a> {
    /// One process each.
    Processes(&'a [String]),
    /// `count` agents named `PREFIX1` … in one process (`baton-agent --instances`).
    Hosted { prefix: &'a str, count: u32 },
}

impl Agents<'_> {
    pub(super) fn spawn(&self, endpoint: &str) -> anyhow::Result<Vec<Child>> {
        match self {
            Agents::Processes(names) => spawn_agents(endpoint, names),
            Agents::Hosted { prefix, count } => {
                let n = count.to_string();
                let args = ["--connect", endpoint, "--name", prefix, "--instances", &n];
                Ok(vec![spawn_logged(Command::new(agent_binary()?).args(args))?])
            }
        }
    }
}

/// How a bench chart runs besides its chart and agents.
#[derive(Default)]
pub(super) struct Extras {
    pub(super) journal: Option<crate::journal::Place>,
    pub(super) rerun: Option<PathBuf>,
    pub(super) sets: Vec<(String, serde_json::Value)>,
    /// The coordinator joins this router rather than embedding its own.
    pub(super) connect: Option<String>,
    /// The agents join this router rather than the coordinator's.
    pub(super) agents_at: Option<String>,
    /// Snapshots and retention of the journal, if not the defaults.
    pub(super) journal_settings: Option<crate::journal::Settings>,
}

pub(super) async fn run_chart(
    dir: &Path,
    file: &str,
    chart: String,
    agents: Agents<'_>,
    probe: Probe,
    extras: Extras,
) -> anyhow::Result<crate::run::Summary> {
    let (opts, _agents) = chart_options(dir, file, chart, &agents, extras)?;
    tokio::time::timeout(PHASE_TIMEOUT, run_with(opts, Some(probe))).await.context("the bench chart did not finish")?
}

/// Runs a chart until `stop` turns true, then drops the run where it stands — its coordinator gone, as if killed,
/// with what it handed its journal written — or until it ends.
pub(super) async fn run_chart_until(
    dir: &Path,
    file: &str,
    chart: String,
    agents: Agents<'_>,
    probe: Probe,
    extras: Extras,
    mut stop: tokio::sync::watch::Receiver<bool>,
) -> anyhow::Result<()> {
    let (opts, _agents) = chart_options(dir, file, chart, &agents, extras)?;
    let run = run_with(opts, Some(probe));
    let stopped = async {
        let _ = stop.wait_for(|s| *s).await;
    };
    tokio::time::timeout(RESUME_TIMEOUT, async {
        tokio::select! {
            ended = run => ended.map(|_| ()),
            () = stopped => Ok(()),
        }
    })
    .await
    .context("the bench chart did not finish")?
}

/// The options of a bench chart's run, with its agents started.
pub(super) fn chart_options(
    dir: &Path,
    file: &str,
    chart: String,
    agents: &Agents<'_>,
    extras: Extras,
) -> anyhow::Result<(RunOptions, Vec<Child>)> {
    let path = dir.join(file);
    if !chart.is_empty() {
        std::fs::write(&path, chart)?;
    }
    let (listen, connect) = match extras.connect {
        Some(router) => (Vec::new(), vec![router]),
        None => (vec![format!("tcp/127.0.0.1:{}", free_port()?)], Vec::new()),
    };
    let agents_at =
        extras.agents_at.clone().unwrap_or_else(|| listen.iter().chain(&connect).next().cloned().unwrap_or_default());
    let agents = agents.spawn(&agents_at)?;
    let opts = RunOptions {
        chart: path,
        pou: None,
        listen,
        connect,
        trace: None,
        summary: None,
        cycle_ms: 10,
        sets: extras.sets,
        multicast_scouting: false,
        quiet: true,
        zenoh_config: None,
        loss_policy: baton_proto::cluster::runtime::coordinator::LossPolicy::Pause,
        // A journal in etcd is written under the run's election, at its place.
        election: match &extras.journal {
            Some(crate::journal::Place::Etcd(e)) => Some((e.clone(), 2)),
            _ => None,
        },
        journal: extras.journal,
        journal_settings: extras.journal_settings.unwrap_or_default(),
        rerun: extras.rerun.map_or(crate::recording::Sink::Off, crate::recording::Sink::Save),
        watch: Vec::new(),
        wait_start: false,
        stay: false,
        abort_wait_ms: 0,
        console: None,
    };
    Ok((opts, agents))
}

/// `agents × lanes` independent loops, lane `j` dispatching a one-step segment to agent `PREFIXk` over and over
/// (k from `first + 1` to `first + agents`), `tokens` in all; the chart ends when every lane has made its share.
pub(super) fn throughput_chart(prefix: &str, first: u32, agents: u32, lanes_per_agent: u32, tokens: u32) -> String {
    let lanes = agents * lanes_per_agent;
    let per_lane = tokens.div_ceil(lanes).max(1);
    let mut chart = String::from("PROGRAM throughput\nVAR\n");
    for j in 1..=lanes {
        chart.push_str(&format!("  c{j} : DINT := 0;\n"));
    }
    chart.push_str(&format!("  n : DINT := {per_lane};\nEND_VAR\nINITIAL_STEP Start: END_STEP\n"));
    let list = |p: &str| (1..=lanes).map(|j| format!("{p}{j}")).collect::<Vec<_>>().join(", ");
    chart.push_str(&format!("TRANSITION FROM Start TO ({}) := TRUE; END_TRANSITION\n", list("H")));
    for j in 1..=lanes {
        let agent = first + (j - 1) % agents + 1;
        chart.push_str(&format!(
            "STEP H{j}: END_STEP\nTRANSITION FROM H{j} TO R{j} := c{j} < n; END_TRANSITION\nTRANSITION FROM H{j} TO D{j} := c{j} >= n; END_TRANSITION\nSTEP R{j}: {{agent := '{prefix}{agent}'}} END_STEP\nTRANSITION FROM R{j} TO B{j} := TRUE; END_TRANSITION\nSTEP B{j}: Count{j}(P); END_STEP\nTRANSITION FROM B{j} TO H{j} := TRUE; END_TRANSITION\nSTEP D{j}: END_STEP\nACTION Count{j}: IF Count{j}.Q THEN c{j} := c{j} + 1; END_IF; END_ACTION\n"
        ));
    }
    chart.push_str(&format!(
        "TRANSITION FROM ({}) TO Finished := TRUE; END_TRANSITION\nSTEP Finished: END_STEP\nEND_PROGRAM\n",
        list("D")
    ));
    chart
}

/// The returns of the first 1/`STEADY_SKIP` of a run (agents starting, caches warming) are left out of its rate.
pub(super) const STEADY_SKIP: usize = 10;

/// Of the instants tokens came back at, in order: how many came back in steady state, and in how many seconds.
pub(super) fn steady(returns: &[Instant]) -> Option<(u64, f64)> {
    let skip = returns.len() / STEADY_SKIP;
    let (first, last) = (returns.get(skip)?, returns.last()?);
    Some(((returns.len() - skip - 1) as u64, (*last - *first).as_secs_f64().max(1e-9)))
}

/// Tokens returned in steady state and the seconds they took.
pub(super) fn steady_returns(marks: &Marks) -> anyhow::Result<(u64, f64)> {
    let marks = marks.lock().map_err(|_| anyhow!("poisoned"))?;
    let returns: Vec<Instant> = marks.iter().filter(|m| m.1 == TraceEvent::Return).map(|m| m.0).collect();
    steady(&returns).ok_or_else(|| anyhow!("no token came back"))
}

/// How long phase 11's run may take (a million tokens at a few thousand per second, and its resume).
pub const RESUME_TIMEOUT: Duration = Duration::from_secs(1800);

pub(super) const PHASE_TIMEOUT: Duration = Duration::from_secs(300);

/// Phases 4 and 5: tokens returned per second in steady state by `agents` agent processes, `lanes_per_agent`
/// tokens in flight on each, with `journal` or none; and the journal's figures.
pub(super) async fn throughput(
    dir: &Path,
    agents: u32,
    lanes_per_agent: u32,
    tokens: u32,
    journal: Option<crate::journal::Place>,
) -> anyhow::Result<(u64, f64, Option<crate::journal::JournalStats>)> {
    let chart = throughput_chart("bench", 0, agents, lanes_per_agent, tokens);
    let (marks, probe) = marks(&[TraceEvent::Return]);
    let names: Vec<String> = (1..=agents).map(|k| format!("bench{k}")).collect();
    let summary = run_chart(
        dir,
        "throughput.st",
        chart,
        Agents::Processes(&names),
        probe,
        Extras { journal, ..Extras::default() },
    )
    .await?;
    let (counted, secs) = steady_returns(&marks)?;
    Ok((counted, secs, summary.journal))
}
