//! `baton bench`'s scale phases: many agents on one coordinator (hosted in one `baton-agent --instances N`
//! process), many runs behind one router, a mesh of three routers, and the coordinator's memory per agent and per
//! token in flight.

use std::collections::HashMap;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail};
use baton_host::ZenohResult;
use baton_proto::exec::trace::TraceEvent;
use serde::Serialize;

use crate::demo::free_port;
use crate::run::Probe;

use super::harness::{
    marks, router_config, run_chart, steady, steady_returns, throughput_chart, Agents, Extras, Latency, Marks,
    STEADY_SKIP,
};

/// The figures of one agent count.
#[derive(Serialize, Clone)]
pub struct ScalePoint {
    pub agents: u32,
    /// One token at a time, to each agent in turn: from its dispatch to its return, on the coordinator.
    pub dispatch_to_return: Latency,
    /// `in_flight` tokens circulating, spread over every agent.
    pub throughput_tokens_per_s: f64,
    pub in_flight: u32,
    /// The coordinator process's resident memory per agent joined (its embedded router's share included).
    pub memory_per_agent_bytes: f64,
}

#[derive(Serialize, Clone)]
pub struct ConcurrentRuns {
    pub runs: u32,
    pub agents_per_run: u32,
    /// Every run's returns over the time all of them ran.
    pub total_tokens_per_s: f64,
    /// The slowest run's own rate, and the fastest's.
    pub slowest_run_tokens_per_s: f64,
    pub fastest_run_tokens_per_s: f64,
}

#[derive(Serialize, Clone)]
pub struct MeshRoundTrip {
    /// The agent on the coordinator's router.
    pub one_router: Latency,
    /// The agent two routers away from the coordinator's, on a mesh of three.
    pub three_routers: Latency,
    pub ratio: f64,
}

/// The resident memory of this process, in bytes (Linux).
fn rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// A probe that keeps the marks of `keep`, and the process's memory as each agent comes up and once the chart
/// reaches its step `Finished`: what the agents cost after each took part in the run.
fn marks_and_memory(keep: &'static [TraceEvent]) -> (Marks, Arc<Mutex<Vec<u64>>>, Probe) {
    let (marks, mut inner) = marks(keep);
    let memory = Arc::new(Mutex::new(Vec::new()));
    let m = Arc::clone(&memory);
    let probe: Probe = Box::new(move |rec| {
        let at_end = rec.event == TraceEvent::Activate && rec.name == "Finished";
        if rec.event == TraceEvent::AgentUp || at_end {
            if let (Some(rss), Ok(mut v)) = (rss_bytes(), m.lock()) {
                v.push(rss);
            }
        }
        inner(rec);
    });
    (marks, memory, probe)
}

/// From each dispatch of a step to that step's next return, the first `warmup` left out.
fn round_trips(marks: &Marks, warmup: usize) -> anyhow::Result<Vec<Duration>> {
    let marks = marks.lock().map_err(|_| anyhow!("poisoned"))?;
    let mut sent: HashMap<&str, Instant> = HashMap::new();
    let mut lat = Vec::new();
    for (t, event, name) in marks.iter() {
        match event {
            TraceEvent::Dispatch => {
                sent.insert(name.as_str(), *t);
            }
            TraceEvent::Return => {
                if let Some(t0) = sent.remove(name.as_str()) {
                    lat.push(*t - t0);
                }
            }
            _ => {}
        }
    }
    Ok(lat.split_off(warmup.min(lat.len())))
}

/// One token at a time, the `i`-th to agent `PREFIX(i mod agents + 1)`: `samples` round trips spread evenly over
/// every agent.
fn round_robin_chart(prefix: &str, agents: u32, samples: u32) -> String {
    let mut chart = format!(
        "PROGRAM round_robin\nVAR\n  n : DINT := {samples};\n  i : DINT := 0;\nEND_VAR\nINITIAL_STEP Home: END_STEP\n\
         TRANSITION Stop FROM Home TO Finished := i >= n; END_TRANSITION\nSTEP Finished: END_STEP\n\
         STEP Back: Count(P); END_STEP\nTRANSITION FROM Back TO Home := TRUE; END_TRANSITION\n\
         ACTION Count: IF Count.Q THEN i := i + 1; END_IF; END_ACTION\n"
    );
    for k in 1..=agents {
        chart.push_str(&format!(
            "TRANSITION FROM Home TO R{k} := i < n AND i MOD {agents} = {}; END_TRANSITION\n\
             STEP R{k}: {{agent := '{prefix}{k}'}} END_STEP\nTRANSITION FROM R{k} TO Back := TRUE; END_TRANSITION\n",
            k - 1
        ));
    }
    chart.push_str("END_PROGRAM\n");
    chart
}

/// `agents` agents in one process on one coordinator: the round trip of one token at a time (and the memory each
/// agent costs the coordinator), then throughput with `in_flight` tokens circulating.
pub async fn scale_point(
    dir: &Path,
    agents: u32,
    samples: u32,
    tokens: u32,
    in_flight: u32,
) -> anyhow::Result<ScalePoint> {
    let warmup = agents.max(100);
    let chart = round_robin_chart("bench", agents, samples + warmup);
    let (rtt_marks, memory, probe) = marks_and_memory(&[TraceEvent::Dispatch, TraceEvent::Return]);
    let hosted = Agents::Hosted { prefix: "bench", count: agents };
    run_chart(dir, &format!("round_robin_{agents}.st"), chart, hosted, probe, Extras::default()).await?;
    let dispatch_to_return = Latency::of(round_trips(&rtt_marks, warmup as usize)?)?;
    let memory = memory.lock().map_err(|_| anyhow!("poisoned"))?.clone();
    // From the first agent up to the end, over the agents after the first.
    let memory_per_agent_bytes = match (memory.first(), memory.last()) {
        (Some(first), Some(last)) if agents > 1 => (*last as f64 - *first as f64) / f64::from(agents - 1),
        _ => f64::NAN,
    };
    let lanes_per_agent = (in_flight / agents).max(1);
    let chart = throughput_chart("bench", 0, agents, lanes_per_agent, tokens);
    let (marks, probe) = marks(&[TraceEvent::Return]);
    let hosted = Agents::Hosted { prefix: "bench", count: agents };
    run_chart(dir, &format!("throughput_{agents}.st"), chart, hosted, probe, Extras::default()).await?;
    let (n, secs) = steady_returns(&marks)?;
    Ok(ScalePoint {
        agents,
        dispatch_to_return,
        throughput_tokens_per_s: n as f64 / secs,
        in_flight: agents * lanes_per_agent,
        memory_per_agent_bytes,
    })
}

/// The coordinator's memory per token in flight: `tokens` branches parked on `agents` agents in motions of
/// `PARK_MS`, the memory before the first dispatch against the memory once every token is out.
pub async fn memory_per_token(dir: &Path, agents: u32, tokens: u32) -> anyhow::Result<f64> {
    const PARK_MS: u32 = 4000;
    let mut chart = String::from("PROGRAM parked\nVAR\n");
    for j in 1..=tokens {
        chart.push_str(&format!("  d{j} : BOOL;\n"));
    }
    chart.push_str("END_VAR\nINITIAL_STEP Start: END_STEP\n");
    let list = |p: &str| (1..=tokens).map(|j| format!("{p}{j}")).collect::<Vec<_>>().join(", ");
    chart.push_str(&format!("TRANSITION FROM Start TO ({}) := TRUE; END_TRANSITION\n", list("P")));
    for j in 1..=tokens {
        let agent = (j - 1) % agents + 1;
        chart.push_str(&format!(
            "STEP P{j}: {{agent := 'bench{agent}'}} Park{j}(N, d{j}); END_STEP\nTRANSITION FROM P{j} TO W{j} := d{j}; END_TRANSITION\nSTEP W{j}: END_STEP\n\
             ACTION Park{j}: {{skill := 'motion', ms := {PARK_MS}}} END_ACTION\n"
        ));
    }
    chart.push_str(&format!(
        "TRANSITION FROM ({}) TO Finished := TRUE; END_TRANSITION\nSTEP Finished: END_STEP\nEND_PROGRAM\n",
        list("W")
    ));
    // Memory at the first dispatch (every agent up, nothing out) and at the first return (every token out,
    // acknowledged, its motion running).
    let samples: Arc<Mutex<Vec<(TraceEvent, u64)>>> = Arc::new(Mutex::new(Vec::new()));
    let s = Arc::clone(&samples);
    let probe: Probe = Box::new(move |rec| {
        if matches!(rec.event, TraceEvent::Dispatch | TraceEvent::Return) {
            if let Ok(mut v) = s.lock() {
                let seen = v.iter().any(|(e, _)| *e == rec.event);
                if !seen {
                    v.push((rec.event, rss_bytes().unwrap_or(0)));
                }
            }
        }
    });
    let hosted = Agents::Hosted { prefix: "bench", count: agents };
    run_chart(dir, "parked.st", chart, hosted, probe, Extras::default()).await?;
    let samples = samples.lock().map_err(|_| anyhow!("poisoned"))?;
    let at = |e: TraceEvent| samples.iter().find(|(x, _)| *x == e).map(|(_, m)| *m as f64);
    match (at(TraceEvent::Dispatch), at(TraceEvent::Return)) {
        (Some(before), Some(out)) => Ok((out - before) / tokens as f64),
        _ => bail!("the parked chart neither dispatched nor returned"),
    }
}

/// `runs` coordinators at once behind one router of their own, each with `agents_per_run` agents (all hosted in
/// one process) and `tokens` tokens.
pub async fn concurrent_runs(
    dir: &Path,
    runs: u32,
    agents_per_run: u32,
    tokens: u32,
) -> anyhow::Result<ConcurrentRuns> {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port()?);
    let _router = zenoh::open(router_config(&endpoint, &[])?).await.zenoh()?;
    let _agents = Agents::Hosted { prefix: "c", count: runs * agents_per_run }.spawn(&endpoint)?;
    let mut all = tokio::task::JoinSet::new();
    for r in 0..runs {
        let dir = dir.to_path_buf();
        let endpoint = endpoint.clone();
        all.spawn(async move {
            // Run r's agents are c(r·k+1) … c(r·k+k).
            let chart = throughput_chart("c", r * agents_per_run, agents_per_run, 4, tokens);
            let (marks, probe) = marks(&[TraceEvent::Return]);
            let extras = Extras { connect: Some(endpoint), ..Extras::default() };
            run_chart(&dir, &format!("run{r}.st"), chart, Agents::Processes(&[]), probe, extras).await?;
            let marks = marks.lock().map_err(|_| anyhow!("poisoned"))?;
            Ok::<Vec<Instant>, anyhow::Error>(marks.iter().map(|m| m.0).collect())
        });
    }
    let mut returns = Vec::new();
    while let Some(run) = all.join_next().await {
        returns.push(run??);
    }
    let rates: Vec<f64> = returns.iter().map(|v| steady(v).map_or(0.0, |(n, secs)| n as f64 / secs)).collect();
    // The window in which every run was running: from the latest first return to the earliest last one.
    let start = returns.iter().filter_map(|v: &Vec<Instant>| v.get(v.len() / STEADY_SKIP)).max().copied();
    let end = returns.iter().filter_map(|v| v.last()).min().copied();
    let (Some(start), Some(end)) = (start, end) else { bail!("a run returned nothing") };
    let window = end.saturating_duration_since(start).max(Duration::from_micros(1));
    let within = returns.iter().flatten().filter(|t| **t >= start && **t <= end).count();
    Ok(ConcurrentRuns {
        runs,
        agents_per_run,
        total_tokens_per_s: within as f64 / window.as_secs_f64(),
        slowest_run_tokens_per_s: rates.iter().copied().fold(f64::INFINITY, f64::min),
        fastest_run_tokens_per_s: rates.iter().copied().fold(0.0, f64::max),
    })
}

/// The token round trip with the agent on the coordinator's router, and with it two routers away on a mesh of
/// three (each router linked to those started before it), alternating.
pub async fn mesh_round_trip(dir: &Path, samples: u32) -> anyhow::Result<MeshRoundTrip> {
    let (mut one, mut three) = (Vec::new(), Vec::new());
    let rounds = super::harness::ROUNDS;
    let per_round = samples.div_ceil(rounds).max(1);
    for round in 1..=rounds {
        eprintln!("   mesh round trip, round {round}/{rounds}: one router");
        one.extend(mesh_samples(dir, per_round, false).await?);
        eprintln!("   mesh round trip, round {round}/{rounds}: three routers");
        three.extend(mesh_samples(dir, per_round, true).await?);
    }
    let (one_router, three_routers) = (Latency::of(one)?, Latency::of(three)?);
    Ok(MeshRoundTrip { ratio: three_routers.median_us / one_router.median_us, one_router, three_routers })
}

async fn mesh_samples(dir: &Path, samples: u32, mesh: bool) -> anyhow::Result<Vec<Duration>> {
    let warmup = 200;
    let ports = [free_port()?, free_port()?, free_port()?];
    let at = |i: usize| format!("tcp/127.0.0.1:{}", ports[i]);
    let r0 = zenoh::open(router_config(&at(0), &[])?).await.zenoh()?;
    let mut routers = vec![r0];
    if mesh {
        routers.push(zenoh::open(router_config(&at(1), &[at(0)])?).await.zenoh()?);
        routers.push(zenoh::open(router_config(&at(2), &[at(0), at(1)])?).await.zenoh()?);
    }
    let chart = round_robin_chart("bench", 1, samples + warmup);
    let (marks, probe) = marks(&[TraceEvent::Dispatch, TraceEvent::Return]);
    let agents_at = if mesh { at(2) } else { at(0) };
    let extras = Extras { connect: Some(at(0)), agents_at: Some(agents_at), ..Extras::default() };
    run_chart(dir, "mesh.st", chart, Agents::Hosted { prefix: "bench", count: 1 }, probe, extras).await?;
    for r in routers {
        r.close().await.zenoh()?;
    }
    round_trips(&marks, warmup as usize)
}
