//! `baton bench --failover-only --etcd etcd://…/PREFIX`: standby coordinators on a real etcd (the user's), and the
//! time from the SIGKILL of the active coordinator to the first dispatch of the standby that takes over, over a
//! chain of kills: each round kills the active coordinator, waits for its standby's first dispatch, and starts a
//! new standby for the next round.
//!
//! The coordinators are `baton run` processes of a chart that loops a short motion on one agent (a `baton-agent`
//! process), so that a dispatch is always due; they keep the run's journal in etcd (`--journal etcd://…`), under a
//! prefix of their own, and stand in its election there. The dispatches are seen on the wire by a session of the bench's router, with the
//! term each carries (`wire::decode_termed`): a failover ends at the first dispatch of a term above the killed one.
//!
//! Then the throughput of phase 5 (the same chart, agents and tokens in flight) with the journal in etcd against
//! the journal in a folder, alternating, `ROUNDS` rounds each: what a commit to etcd (a transaction through its Raft
//! log, its members' `fdatasync`s included) costs a cell against one `fdatasync` of a local file.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::anyhow;
use baton_host::traffic;
use baton_proto::cluster::keys;
use baton_proto::cluster::wire::{self, ToAgent};
use serde::Serialize;
use tokio::process::{Child, Command};

use crate::election::{candidates, Election};

use super::harness::{median, router_config, spawn_agents, spawn_logged, throughput, PHASE_TIMEOUT, ROUNDS};
use crate::journal::Place;

#[derive(Serialize, Clone)]
pub struct Failover {
    pub kills: u32,
    pub lease_s: u64,
    /// From the SIGKILL to the standby's first dispatch, in ms: median, max, and each.
    pub median_ms: f64,
    pub max_ms: f64,
    pub samples_ms: Vec<f64>,
    /// Tokens returned per second with the journal in a folder and in etcd (medians of `ROUNDS` rounds each), the
    /// tokens in flight, and a commit's time and records per commit with etcd.
    pub throughput_file_tokens_per_s: f64,
    pub throughput_etcd_tokens_per_s: f64,
    pub throughput_in_flight: u32,
    pub etcd_commit_us: f64,
    pub file_commit_us: f64,
    pub etcd_records_per_commit: f64,
}

/// Phase 5's shape for the throughput with each journal: agents, tokens in flight per agent, tokens.
pub struct Shape {
    pub agents: u32,
    pub lanes_per_agent: u32,
    pub tokens: u32,
}

const CHART: &str = "PROGRAM failover\nVAR moved : BOOL; END_VAR\nINITIAL_STEP Start: END_STEP\n\
    TRANSITION FROM Start TO Move := TRUE; END_TRANSITION\n\
    STEP Move: {agent := 'f1'} Go(N, moved); END_STEP\nTRANSITION FROM Move TO Start := moved; END_TRANSITION\n\
    ACTION Go: {skill := 'motion', ms := 20} END_ACTION\nEND_PROGRAM\n";

pub async fn failover(dir: &Path, etcd: &Election, kills: u32, lease_s: u64, shape: Shape) -> anyhow::Result<Failover> {
    let (median_ms, max_ms, samples) = kill_rounds(dir, etcd, kills, lease_s).await?;
    let mut file = (Vec::new(), Vec::new(), Vec::new());
    let mut in_etcd = (Vec::new(), Vec::new(), Vec::new());
    for round in 1..=ROUNDS {
        for journal in ["a folder", "etcd"] {
            eprintln!(
                "  throughput with the journal in {journal}, round {round}/{ROUNDS}: {} agents, {} tokens in flight, \
                 {} tokens",
                shape.agents,
                shape.agents * shape.lanes_per_agent,
                shape.tokens
            );
            let (place, into) = if journal == "etcd" {
                let prefix = format!("{}/bench-{}", etcd.prefix, uuid::Uuid::new_v4());
                (Place::Etcd(Election { prefix, ..etcd.clone() }), &mut in_etcd)
            } else {
                let _ = std::fs::remove_dir_all(dir.join("throughput-journal"));
                (Place::Dir(dir.join("throughput-journal")), &mut file)
            };
            let (n, secs, stats) =
                throughput(dir, shape.agents, shape.lanes_per_agent, shape.tokens, Some(place)).await?;
            let stats = stats.ok_or_else(|| anyhow!("a journaled run without its journal's figures"))?;
            into.0.push(n as f64 / secs);
            into.1.push(stats.commit_us);
            into.2.push(stats.records as f64 / stats.commits.max(1) as f64);
        }
    }
    Ok(Failover {
        kills,
        lease_s,
        median_ms,
        max_ms,
        samples_ms: samples,
        throughput_file_tokens_per_s: median(file.0),
        throughput_etcd_tokens_per_s: median(in_etcd.0),
        throughput_in_flight: shape.agents * shape.lanes_per_agent,
        etcd_commit_us: median(in_etcd.1),
        file_commit_us: median(file.1),
        etcd_records_per_commit: median(in_etcd.2),
    })
}

/// The kills: the median and max from a SIGKILL to the standby's first dispatch, in ms, and each.
async fn kill_rounds(dir: &Path, etcd: &Election, kills: u32, lease_s: u64) -> anyhow::Result<(f64, f64, Vec<f64>)> {
    let endpoint = format!("tcp/127.0.0.1:{}", crate::demo::free_port()?);
    let router = zenoh::open(router_config(&endpoint, &[])?).await.map_err(|e| anyhow!("router: {e}"))?;
    let chart = dir.join("failover.st");
    std::fs::write(&chart, CHART)?;
    let election = Election { prefix: format!("{}/bench-{}", etcd.prefix, uuid::Uuid::new_v4()), ..etcd.clone() };
    let shown = election.to_string();
    let (tx, mut dispatches) = tokio::sync::mpsc::unbounded_channel::<(Instant, u64)>();
    let _seen = traffic::subscriber(&router, keys::agent_cmd_any("*"))
        .callback(move |sample| {
            if let Ok((term, ToAgent::Dispatch { .. })) = wire::decode_termed::<ToAgent>(&sample.payload().to_bytes()) {
                let _ = tx.send((Instant::now(), term));
            }
        })
        .await
        .map_err(|e| anyhow!("subscriber: {e}"))?;
    let start = || -> anyhow::Result<Child> {
        let exe = std::env::current_exe()?;
        let lease = lease_s.to_string();
        spawn_logged(Command::new(exe).arg("run").arg(&chart).args(["--connect", &endpoint, "--quiet"]).args([
            "--journal",
            &shown,
            "--lease",
            &lease,
        ]))
    };
    let _agent = spawn_agents(&endpoint, &["f1".to_string()])?;
    let mut active = start()?;
    let mut samples = Vec::new();
    tokio::time::timeout(PHASE_TIMEOUT, async {
        let mut term = standing(&election, 1).await?[0].term;
        for round in 0..kills {
            let standby = start()?;
            standing(&election, 2).await?;
            // A dispatch of the active coordinator after the standby stands: the run goes on as it should.
            while dispatches.recv().await.ok_or_else(|| anyhow!("the subscriber closed"))?.1 != term {}
            active.start_kill()?;
            let killed = Instant::now();
            active.wait().await?;
            let (at, new) = loop {
                let (at, t) = dispatches.recv().await.ok_or_else(|| anyhow!("the subscriber closed"))?;
                if t > term {
                    break (at, t);
                }
            };
            samples.push((at - killed).as_secs_f64() * 1e3);
            eprintln!(
                "  kill {}: the standby dispatched {:.0} ms after it (term {term} → {new})",
                round + 1,
                samples[samples.len() - 1]
            );
            (active, term) = (standby, new);
        }
        anyhow::Ok(())
    })
    .await
    .map_err(|_| anyhow!("the failover phase did not finish within {PHASE_TIMEOUT:?}"))??;
    let _ = active.start_kill();
    let max_ms = samples.iter().copied().fold(f64::NAN, f64::max);
    Ok((median(samples.clone()), max_ms, samples))
}

/// Waits until `n` coordinators stand in the election (the active one first); returns them.
async fn standing(election: &Election, n: usize) -> anyhow::Result<Vec<crate::election::Candidate>> {
    loop {
        let now = candidates(election).await?;
        if now.len() >= n {
            return Ok(now);
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}
