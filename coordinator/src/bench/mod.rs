//! `baton bench`: the distributed runtime measured on loopback, in one run — the raw Zenoh round trip between
//! two processes, a token's round trip through Baton, convergence latency, and throughput with 8 agents, with
//! the journal off and on (`--journal`: every input durable before the coordinator acts on it).
//!
//! Every phase runs real processes (`baton-agent`s, and a `baton bench-echo` for the raw round trip) against a
//! coordinator and router in this process; times are taken with `Instant` where the events happen.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context};
use baton_proto::cluster::netconfig::NetConfig;
use serde::Serialize;
use tokio::process::Command;
use zenoh::qos::CongestionControl;

use crate::demo::free_port;

mod console;
mod failover;
mod harness;
mod resume;
mod scale;
use baton_host::{traffic, ZenohResult};
use baton_proto::exec::trace::TraceEvent;
use baton_proto::testing::bench_charts;
use harness::{
    marks, median, router_config, run_chart, spawn_logged, steady_returns, Agents, Extras, Latency, PHASE_TIMEOUT,
    ROUNDS,
};

const PING_KEY: &str = "baton/bench/ping";
const PONG_KEY: &str = "baton/bench/pong";
const ECHO_ALIVE_KEY: &str = "baton/bench/echo";
pub struct BenchOptions {
    /// Round trips measured in phases 1 and 2, and convergences in phase 3.
    pub samples: u32,
    /// Tokens in the throughput phase.
    pub tokens: u32,
    pub agents: u32,
    /// Tokens circulating at once per agent in the throughput phase.
    pub lanes_per_agent: u32,
    /// The same at the cell's capacity (phase 5b).
    pub capacity_lanes_per_agent: u32,
    /// Parts the demo chart makes in the recording phase.
    pub parts: u32,
    /// Run phases 1–6 (latency, throughput, journal, demo chart).
    pub base: bool,
    /// Run phases 7–10 (agents on one coordinator, concurrent runs, a mesh of routers, memory).
    pub scale: bool,
    /// The agent counts of phase 7.
    pub scale_agents: Vec<u32>,
    /// Run phase 11 (a journaled run of `resume_tokens` tokens, resumed).
    pub resume: bool,
    pub resume_tokens: u64,
    /// Run phase 12 (standby coordinators on this etcd: kills, and the lease in seconds).
    pub failover: Option<(crate::election::Election, u32, u64)>,
    /// Run phase 13 (the operator console in this browser, at these agent counts).
    pub console: Option<(console::Browser, Vec<u32>)>,
}

pub use console::Browser;

#[derive(Serialize)]
pub struct BenchReport {
    #[serde(flatten)]
    pub base: Option<BaseReport>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scale: Option<ScaleReport>,
    /// (11)
    #[serde(skip_serializing_if = "Option::is_none")]
    pub resume: Option<resume::Resume>,
    /// (12)
    #[serde(skip_serializing_if = "Option::is_none")]
    pub failover: Option<failover::Failover>,
    /// (13)
    #[serde(skip_serializing_if = "Option::is_none")]
    pub console: Option<console::ConsoleReport>,
}

/// Phases 7–10.
#[derive(Serialize)]
pub struct ScaleReport {
    /// (7) per agent count.
    pub agents: Vec<scale::ScalePoint>,
    /// The largest count's throughput over the smallest's (target ≥ 0.8).
    pub throughput_ratio: f64,
    /// (8)
    pub concurrent_runs: scale::ConcurrentRuns,
    /// (9)
    pub mesh: scale::MeshRoundTrip,
    /// (10) with the largest agent count.
    pub memory_per_token_bytes: f64,
    pub memory_tokens: u32,
}

/// Phases 1–6.
#[derive(Serialize)]
pub struct BaseReport {
    pub zenoh_round_trip: Latency,
    pub token_round_trip: Latency,
    pub token_to_zenoh_ratio: f64,
    pub convergence: Latency,
    /// Median of the rounds without a journal.
    pub throughput_tokens_per_s: f64,
    /// Median of the rounds with `--journal` (group commit to an append-only file, fdatasync per commit).
    pub throughput_journal_tokens_per_s: f64,
    pub throughput_journal_ratio: f64,
    /// Group commit at work: journal records per durable transaction.
    pub throughput_journal_records_per_commit: f64,
    /// A commit's write and `fdatasync`, on average: what a token's round trip waits for at least with the journal.
    pub throughput_journal_commit_us: f64,
    /// What a batch led to was sent this long after the batch was handed to the writer, on average
    /// (`JournalStats::held_us`): what the journal adds to a round trip.
    pub throughput_journal_held_us: f64,
    pub throughput_agents: u32,
    pub throughput_tokens: u64,
    pub throughput_in_flight: u32,
    /// (5b) (4) and (5) again with `capacity_in_flight` tokens in flight, where the run without the journal is
    /// bound by the CPU rather than by a round trip: what the journal costs the cell's capacity, where (5) shows
    /// what its commits add to each round trip.
    pub capacity_in_flight: u32,
    pub capacity_tokens_per_s: f64,
    pub capacity_journal_tokens_per_s: f64,
    pub capacity_journal_ratio: f64,
    /// (6) the demo chart without a recording, and with `--rerun save:…`.
    pub demo_tokens_per_s: f64,
    pub demo_recorded_tokens_per_s: f64,
    pub demo_recorded_ratio: f64,
    pub demo_parts: u32,
    pub demo_recording_bytes: u64,
}

pub async fn bench(opts: BenchOptions) -> anyhow::Result<BenchReport> {
    let dir = tempfile::tempdir()?;
    let base = if opts.base { Some(base(dir.path(), &opts).await?) } else { None };
    let scale = if opts.scale { Some(scale(dir.path(), &opts).await?) } else { None };
    let resume = if opts.resume {
        eprintln!("11/11 a run of {} tokens with --journal, its coordinator gone, resumed", opts.resume_tokens);
        Some(resume::resume(dir.path(), opts.resume_tokens).await?)
    } else {
        None
    };
    let failover = match &opts.failover {
        Some((etcd, kills, lease_s)) => {
            eprintln!("12 standby coordinators on etcd: {kills} kills of the active one, a lease of {lease_s} s");
            let shape =
                failover::Shape { agents: opts.agents, lanes_per_agent: opts.lanes_per_agent, tokens: opts.tokens };
            Some(failover::failover(dir.path(), etcd, *kills, *lease_s, shape).await?)
        }
        None => None,
    };
    let console = match &opts.console {
        Some((browser, agents)) => Some(console::console(dir.path(), browser, agents).await?),
        None => None,
    };
    Ok(BenchReport { base, scale, resume, failover, console })
}

/// In-flight tokens of phase 7 at every agent count (one per agent at the largest).
const SCALE_IN_FLIGHT: u32 = 256;
const CONCURRENT_RUNS: u32 = 16;
/// Tokens parked for phase 10 (a chart lists at most 1,024 branches in one divergence).
const PARKED_TOKENS: u32 = 1024;

async fn scale(dir: &Path, opts: &BenchOptions) -> anyhow::Result<ScaleReport> {
    let mut points = Vec::new();
    let in_flight = opts.scale_agents.iter().copied().max().unwrap_or(1).max(SCALE_IN_FLIGHT);
    for &n in &opts.scale_agents {
        eprintln!("7/10 {n} agents in one process: round trips one at a time, then {in_flight} tokens in flight");
        points.push(scale::scale_point(dir, n, opts.samples, opts.tokens, in_flight).await?);
    }
    let (Some(first), Some(last)) = (points.first(), points.last()) else { bail!("no agent count to measure") };
    let throughput_ratio = last.throughput_tokens_per_s / first.throughput_tokens_per_s;
    eprintln!("8/10 {CONCURRENT_RUNS} runs at once behind one router, 2 agents each");
    let concurrent_runs =
        scale::concurrent_runs(dir, CONCURRENT_RUNS, 2, (opts.tokens / CONCURRENT_RUNS).max(100)).await?;
    eprintln!("9/10 token round trip across a mesh of three routers");
    let mesh = scale::mesh_round_trip(dir, opts.samples).await?;
    let largest = opts.scale_agents.iter().copied().max().unwrap_or(1);
    eprintln!("10/10 coordinator memory: {PARKED_TOKENS} tokens parked on {largest} agents");
    let memory_per_token_bytes = scale::memory_per_token(dir, largest, PARKED_TOKENS).await?;
    Ok(ScaleReport {
        agents: points,
        throughput_ratio,
        concurrent_runs,
        mesh,
        memory_per_token_bytes,
        memory_tokens: PARKED_TOKENS,
    })
}

async fn base(dir: &Path, opts: &BenchOptions) -> anyhow::Result<BaseReport> {
    // (1) and (2) alternate in rounds, so that both see the same machine: loopback latency on a shared VM
    // drifts by more than the difference being measured.
    let per_round = opts.samples.div_ceil(ROUNDS).max(1);
    let (mut raw, mut token) = (Vec::new(), Vec::new());
    for round in 1..=ROUNDS {
        eprintln!("1/5 raw Zenoh round trip, round {round}/{ROUNDS}, {per_round} samples");
        raw.extend(raw_round_trip(per_round).await?);
        eprintln!("2/5 token round trip through Baton, round {round}/{ROUNDS}, {per_round} samples");
        token.extend(token_round_trip(dir, per_round).await?);
    }
    let (zenoh_round_trip, token_round_trip) = (Latency::of(raw)?, Latency::of(token)?);
    eprintln!("3/5 convergence latency, 3 branches, {} samples", opts.samples.min(2000));
    let convergence = convergence(dir, opts.samples.min(2000)).await?;
    let at_32 = journal_rounds(dir, opts, "4/5", opts.lanes_per_agent).await?;
    let at_capacity = journal_rounds(dir, opts, "5b/5", opts.capacity_lanes_per_agent).await?;
    // (6) The demo chart recorded to a file against not recorded, alternating as well.
    let (mut plain, mut recorded, mut rrd_bytes) = (Vec::new(), Vec::new(), 0);
    for round in 1..=ROUNDS {
        for record in [false, true] {
            let with = if record { "--rerun save" } else { "--rerun off" };
            eprintln!("5/5 demo chart, {with}, round {round}/{ROUNDS}: {} parts, motions of 0 ms", opts.parts);
            let rrd = record.then(|| dir.join(format!("demo-{round}.rrd")));
            let (n, secs) = demo_throughput(dir, opts.parts, rrd.clone()).await?;
            if let Some(path) = rrd {
                rrd_bytes = std::fs::metadata(&path).map_or(0, |m| m.len());
                recorded.push(n as f64 / secs);
            } else {
                plain.push(n as f64 / secs);
            }
        }
    }
    let (plain, recorded) = (median(plain), median(recorded));
    Ok(BaseReport {
        demo_tokens_per_s: plain,
        demo_recorded_tokens_per_s: recorded,
        demo_recorded_ratio: recorded / plain,
        demo_parts: opts.parts,
        demo_recording_bytes: rrd_bytes,
        token_to_zenoh_ratio: token_round_trip.median_us / zenoh_round_trip.median_us,
        zenoh_round_trip,
        token_round_trip,
        convergence,
        throughput_tokens_per_s: at_32.off,
        throughput_journal_tokens_per_s: at_32.on,
        throughput_journal_ratio: at_32.on / at_32.off,
        throughput_journal_records_per_commit: at_32.records_per_commit,
        throughput_journal_commit_us: at_32.commit_us,
        throughput_journal_held_us: at_32.held_us,
        throughput_agents: opts.agents,
        throughput_tokens: at_32.tokens,
        throughput_in_flight: at_32.in_flight,
        capacity_in_flight: at_capacity.in_flight,
        capacity_tokens_per_s: at_capacity.off,
        capacity_journal_tokens_per_s: at_capacity.on,
        capacity_journal_ratio: at_capacity.on / at_capacity.off,
    })
}

/// Phases 4 and 5 (or 5b) at one number of tokens in flight: each figure the median of its rounds.
struct JournalRounds {
    in_flight: u32,
    tokens: u64,
    off: f64,
    on: f64,
    records_per_commit: f64,
    commit_us: f64,
    held_us: f64,
}

/// The throughput chart without and with `--journal`, alternating in rounds as (1) and (2) do, for the same reason.
async fn journal_rounds(
    dir: &Path,
    opts: &BenchOptions,
    phase: &str,
    lanes_per_agent: u32,
) -> anyhow::Result<JournalRounds> {
    let in_flight = opts.agents * lanes_per_agent;
    let (mut off, mut on, mut records_per_commit, mut commit_us, mut held_us) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut tokens = 0;
    for round in 1..=ROUNDS {
        for journal in [false, true] {
            let with = if journal { "journal on" } else { "journal off" };
            eprintln!(
                "{phase} throughput, {with}, round {round}/{ROUNDS}: {} agents, {in_flight} tokens in flight, {} tokens",
                opts.agents, opts.tokens
            );
            let journal = journal.then(|| crate::journal::Place::Dir(dir.join(format!("journal-{phase}-{round}"))));
            let journaled = journal.is_some();
            let (n, secs, stats) = harness::throughput(dir, opts.agents, lanes_per_agent, opts.tokens, journal).await?;
            tokens = n;
            if let Some(j) = stats {
                records_per_commit.push(j.records as f64 / j.commits.max(1) as f64);
                commit_us.push(j.commit_us);
                held_us.push(j.held_us);
            }
            if journaled { &mut on } else { &mut off }.push(n as f64 / secs);
        }
    }
    Ok(JournalRounds {
        in_flight,
        tokens,
        off: median(off),
        on: median(on),
        records_per_commit: median(records_per_commit),
        commit_us: median(commit_us),
        held_us: median(held_us),
    })
}

impl BenchReport {
    pub fn print(&self) {
        if let Some(base) = &self.base {
            base.print();
        }
        if let Some(scale) = &self.scale {
            scale.print();
        }
        if let Some(f) = &self.failover {
            println!(
                "(12) failover, from the SIGKILL of the active coordinator to its standby's first dispatch, over {} \
                 kills with a lease of {} s, the journal in etcd: median {:.0} ms, max {:.0} ms",
                f.kills, f.lease_s, f.median_ms, f.max_ms
            );
            println!(
                "(12) throughput at {} tokens in flight with the journal in etcd: {:.0} tokens/s ({:.0} µs a commit, \
                 {:.1} records each); in a folder: {:.0} tokens/s ({:.0} µs a commit)",
                f.throughput_in_flight,
                f.throughput_etcd_tokens_per_s,
                f.etcd_commit_us,
                f.etcd_records_per_commit,
                f.throughput_file_tokens_per_s,
                f.file_commit_us
            );
        }
        if let Some(c) = &self.console {
            c.print();
        }
        if let Some(r) = &self.resume {
            println!(
                "(11) a run of {} tokens with --journal ({:.0} tokens/s; {} records in {} segments, {:.0} MB): \
                 the journal resumed in {:.0} ms from its last snapshot ({} records replayed; target < 1 s), \
                 `baton run` recovered {:.0} ms after its start (a Zenoh session opened too); the whole journal \
                 replays in {:.0} ms ({:.0} records/s: at worst, {} records after the last snapshot, {:.0} ms)",
                r.tokens,
                r.tokens_per_s,
                r.records,
                r.segments,
                r.journal_bytes as f64 / 1e6,
                r.resume_journal_ms,
                r.resume_replayed_records,
                r.resume_ms,
                r.full_replay_ms,
                r.replay_records_per_s,
                crate::journal::SNAPSHOT_EVERY,
                r.worst_case_resume_ms
            );
        }
    }
}

impl ScaleReport {
    fn print(&self) {
        println!("(7) agents on one coordinator (hosted in one process); dispatch → return one token at a time:");
        println!(
            "{:>8} {:>12} {:>12} {:>14} {:>10} {:>14}",
            "agents", "median", "p99", "tokens/s", "in flight", "memory/agent"
        );
        for p in &self.agents {
            println!(
                "{:>8} {:>9.1} µs {:>9.1} µs {:>14.0} {:>10} {:>11.1} kB",
                p.agents,
                p.dispatch_to_return.median_us,
                p.dispatch_to_return.p99_us,
                p.throughput_tokens_per_s,
                p.in_flight,
                p.memory_per_agent_bytes / 1e3
            );
        }
        println!(
            "    throughput, most agents over fewest: {:.2} (target ≥ 0.8; p99 target < 5 ms)",
            self.throughput_ratio
        );
        let c = &self.concurrent_runs;
        println!(
            "(8) {} runs behind one router ({} agents each): {:.0} tokens/s in all; runs between {:.0} and {:.0} tokens/s",
            c.runs, c.agents_per_run, c.total_tokens_per_s, c.slowest_run_tokens_per_s, c.fastest_run_tokens_per_s
        );
        let m = &self.mesh;
        println!(
            "(9) round trip, agent on the coordinator's router: {:.1} µs median, {:.1} µs p99; two routers away on a mesh of three: {:.1} µs, {:.1} µs; ratio of medians {:.2} (target ≤ 2)",
            m.one_router.median_us, m.one_router.p99_us, m.three_routers.median_us, m.three_routers.p99_us, m.ratio
        );
        println!(
            "(10) coordinator memory per token in flight: {:.1} kB ({} tokens parked)",
            self.memory_per_token_bytes / 1e3,
            self.memory_tokens
        );
    }
}

impl BaseReport {
    fn print(&self) {
        let row = |name: &str, l: &Latency| {
            println!("{name:<42} {:>9.1} µs {:>9.1} µs {:>8}", l.median_us, l.p99_us, l.samples);
        };
        println!("{:<42} {:>12} {:>12} {:>8}", "measure", "median", "p99", "samples");
        row("(1) raw Zenoh round trip, 2 processes", &self.zenoh_round_trip);
        row("(2) token round trip through Baton", &self.token_round_trip);
        row("(3) convergence: last return → successor", &self.convergence);
        println!("ratio (2)/(1), medians: {:.2} (target < 1.5)", self.token_to_zenoh_ratio);
        println!(
            "(4) throughput: {:.0} tokens/s ({} tokens, {} agents, {} in flight; target ≥ 5000)",
            self.throughput_tokens_per_s, self.throughput_tokens, self.throughput_agents, self.throughput_in_flight
        );
        println!(
            "(5) throughput with --journal: {:.0} tokens/s, {:.2} of (4) ({:.1} records per commit, a commit's write \
             and fdatasync {:.0} µs, what it led to sent {:.0} µs after its batch was handed to the writer; a round trip of (4) takes {:.0} µs)",
            self.throughput_journal_tokens_per_s,
            self.throughput_journal_ratio,
            self.throughput_journal_records_per_commit,
            self.throughput_journal_commit_us,
            self.throughput_journal_held_us,
            self.throughput_in_flight as f64 / self.throughput_tokens_per_s * 1e6
        );
        println!(
            "(5b) at capacity, {} in flight: {:.0} tokens/s; with --journal {:.0} tokens/s, {:.2} of it",
            self.capacity_in_flight,
            self.capacity_tokens_per_s,
            self.capacity_journal_tokens_per_s,
            self.capacity_journal_ratio
        );
        println!(
            "(6) demo chart: {:.0} tokens/s; with --rerun save: {:.0} tokens/s, {:.2} of it (target ≥ 0.9; {} parts, {:.1} MB recorded)",
            self.demo_tokens_per_s,
            self.demo_recorded_tokens_per_s,
            self.demo_recorded_ratio,
            self.demo_parts,
            self.demo_recording_bytes as f64 / 1e6
        );
    }
}

/// Phase 1: put → the echo process's subscriber → put back → our subscriber, 64-byte payloads.
async fn raw_round_trip(samples: u32) -> anyhow::Result<Vec<Duration>> {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port()?);
    let session = zenoh::open(router_config(&endpoint, &[])?).await.zenoh()?;
    let alive = traffic::liveliness_subscriber(&session, ECHO_ALIVE_KEY.into()).await.zenoh()?;
    let pong = traffic::subscriber(&session, PONG_KEY.into()).await.zenoh()?;
    let ping = traffic::publisher(&session, PING_KEY.into())
        .congestion_control(CongestionControl::Block)
        .express(true)
        .await
        .zenoh()?;
    let _echo = spawn_logged(Command::new(std::env::current_exe()?).args(["bench-echo", "--connect", &endpoint]))?;
    tokio::time::timeout(PHASE_TIMEOUT, alive.recv_async())
        .await
        .context("the echo process did not come up")?
        .zenoh()?;
    let mut rtts = Vec::with_capacity(samples as usize);
    let warmup = 200;
    for i in 0..samples + warmup {
        let mut payload = vec![0u8; 64];
        payload[..4].copy_from_slice(&i.to_le_bytes());
        let t0 = Instant::now();
        ping.put(payload).await.zenoh()?;
        loop {
            let s = tokio::time::timeout(PHASE_TIMEOUT, pong.recv_async()).await.context("no pong")?.zenoh()?;
            let bytes = s.payload().to_bytes();
            if bytes.len() >= 4 && bytes[..4] == i.to_le_bytes() {
                break;
            }
        }
        if i >= warmup {
            rtts.push(t0.elapsed());
        }
    }
    session.close().await.zenoh()?;
    Ok(rtts)
}

/// `baton bench-echo`: puts every ping back as a pong.
pub async fn echo(connect: &[String]) -> anyhow::Result<()> {
    let net = NetConfig::client(connect, false);
    let config = zenoh::Config::from_json5(&net.json5()).zenoh()?;
    let session = zenoh::open(config).await.zenoh()?;
    let pings = traffic::subscriber(&session, PING_KEY.into()).await.zenoh()?;
    let pong = traffic::publisher(&session, PONG_KEY.into())
        .congestion_control(CongestionControl::Block)
        .express(true)
        .await
        .zenoh()?;
    let _alive = traffic::token(&session, ECHO_ALIVE_KEY.into()).await.zenoh()?;
    while let Ok(s) = pings.recv_async().await {
        pong.put(s.payload().clone()).await.zenoh()?;
    }
    Ok(())
}

/// Phase 2: a one-step segment whose exit is TRUE at once, dispatched `samples` times (plus a warm-up), from
/// its dispatch to the activation of the next step on the coordinator.
async fn token_round_trip(dir: &Path, samples: u32) -> anyhow::Result<Vec<Duration>> {
    let warmup = 200;
    let chart = bench_charts::token_round_trip(u64::from(samples + warmup));
    let (marks, probe) = marks(&[TraceEvent::Dispatch, TraceEvent::Activate]);
    run_chart(dir, "token_rtt.st", chart, Agents::Processes(&["bench1".to_string()]), probe, Extras::default()).await?;
    let marks = marks.lock().map_err(|_| anyhow!("poisoned"))?;
    let mut rtts = Vec::new();
    let mut sent: Option<Instant> = None;
    for (t, event, name) in marks.iter() {
        match (event, name.as_str()) {
            (TraceEvent::Dispatch, "Remote") => sent = Some(*t),
            (TraceEvent::Activate, "Back") => {
                if let Some(t0) = sent.take() {
                    rtts.push(*t - t0);
                }
            }
            _ => {}
        }
    }
    Ok(rtts.split_off((warmup as usize).min(rtts.len())))
}

/// Phase 3: three branches on three agents; from the coordinator's taking the last branch's return to the
/// activation of the convergence's successor.
async fn convergence(dir: &Path, samples: u32) -> anyhow::Result<Latency> {
    let warmup = 100;
    let mut chart = bench_charts::counted_loop_header("convergence", u64::from(samples + warmup));
    chart.push_str("TRANSITION Go FROM Home TO (R1, R2, R3) := i < n; END_TRANSITION\n");
    for k in 1..=3 {
        chart.push_str(&format!(
            "STEP R{k}: {{agent := 'bench{k}'}} END_STEP\nTRANSITION FROM R{k} TO W{k} := TRUE; END_TRANSITION\nSTEP W{k}: END_STEP\n"
        ));
    }
    chart.push_str(concat!(
        "TRANSITION FROM (W1, W2, W3) TO Join := TRUE; END_TRANSITION\n",
        "STEP Join: Count(P); END_STEP\n",
        "TRANSITION FROM Join TO Home := TRUE; END_TRANSITION\nEND_PROGRAM\n",
    ));
    let (marks, probe) = marks(&[TraceEvent::Return, TraceEvent::Activate]);
    let agents: Vec<String> = (1..=3).map(|k| format!("bench{k}")).collect();
    run_chart(dir, "convergence.st", chart, Agents::Processes(&agents), probe, Extras::default()).await?;
    let marks = marks.lock().map_err(|_| anyhow!("poisoned"))?;
    let mut lat = Vec::new();
    let mut last_return: Option<Instant> = None;
    for (t, event, name) in marks.iter() {
        match (event, name.as_str()) {
            (TraceEvent::Return, _) => last_return = Some(*t),
            (TraceEvent::Activate, "Join") => {
                if let Some(t0) = last_return.take() {
                    lat.push(*t - t0);
                }
            }
            _ => {}
        }
    }
    Latency::of(lat.split_off((warmup as usize).min(lat.len())))
}

/// Phase 6: the demo's cell chart (two robots) with its motions taking no time and no inspection faults, `parts`
/// parts, recorded to a file or not; tokens returned per second in steady state, and the recording's size.
async fn demo_throughput(dir: &Path, parts: u32, record: Option<PathBuf>) -> anyhow::Result<(u64, f64)> {
    let chart = crate::demo_chart::cell_chart(2);
    let chart = instant_motions(&chart);
    let (marks, probe) = marks(&[TraceEvent::Return]);
    let names: Vec<String> = (1..=2).map(|k| format!("robot{k}")).collect();
    let extras =
        Extras { rerun: record, sets: vec![("parts".to_string(), serde_json::json!(parts))], ..Extras::default() };
    run_chart(dir, "cell.st", chart, Agents::Processes(&names), probe, extras).await?;
    steady_returns(&marks)
}

/// The cell chart with every motion instantaneous and inspection never failing, so that the chart's own
/// traffic, not simulated robot time, sets the pace.
fn instant_motions(chart: &str) -> String {
    let mut out = String::with_capacity(chart.len());
    for line in chart.lines() {
        if line.starts_with("ACTION") && line.contains("skill := 'motion'") {
            let name = line.split_whitespace().nth(1).unwrap_or("Motion:");
            out.push_str(&format!("ACTION {name} {{skill := 'motion', ms := 0}} END_ACTION"));
        } else {
            out.push_str(line);
        }
        out.push('\n');
    }
    out
}
