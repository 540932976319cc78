//! `baton bench`'s phase 11: a run of a million tokens with `--journal`, its coordinator gone mid-run, and the
//! time `baton run` takes to resume it — from the journal's last snapshot — against the time a replay of the
//! whole journal takes (what a resume cost before snapshots).

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use anyhow::{anyhow, bail, Context};
use baton_proto::exec::trace::TraceEvent;
use serde::Serialize;

use crate::run::Probe;

use super::harness::{chart_options, run_chart_until, throughput_chart, Agents, Extras};

#[derive(Serialize, Clone)]
pub struct Resume {
    /// Tokens the run had returned when its coordinator went.
    pub tokens: u64,
    /// The journal's rate while it ran (tokens returned per second, from the first to the last).
    pub tokens_per_s: f64,
    /// Journal records, and the segments and bytes the journal kept (`--journal-keep all`).
    pub records: u64,
    pub segments: u64,
    pub journal_bytes: u64,
    /// From `baton run`'s start to the resumed coordinator's `recover` record: the journal opened, the last
    /// snapshot restored and the records after it replayed, and a Zenoh session opened.
    pub resume_ms: f64,
    /// The journal's part of it alone (`run::resume_offline`): opened, snapshot restored, records replayed.
    pub resume_journal_ms: f64,
    /// Journal records and trace records the resume replayed (those after the snapshot).
    pub resume_replayed_records: u64,
    pub resume_replayed_trace_records: u64,
    /// Every record from the run's start replayed (`baton replay` without a recording), and its rate: a resume
    /// replays at most `--snapshot-every` records, so its worst case is that many at this rate.
    pub full_replay_ms: f64,
    pub replay_records_per_s: f64,
    pub worst_case_resume_ms: f64,
}

/// Agents and tokens in flight while the run makes its tokens: the bench's throughput setting.
const AGENTS: u32 = 8;
const LANES_PER_AGENT: u32 = 4;

/// A probe that counts returns (and says when `stop_at` came back) and marks the first `recover`, with the trace
/// records before it.
fn counter(stop_at: u64) -> (Arc<Mutex<Counted>>, tokio::sync::watch::Receiver<bool>, Probe) {
    let counted = Arc::new(Mutex::new(Counted::default()));
    let (tx, rx) = tokio::sync::watch::channel(false);
    let c = Arc::clone(&counted);
    let probe: Probe = Box::new(move |rec| {
        let Ok(mut c) = c.lock() else { return };
        match rec.event {
            TraceEvent::Return => {
                c.returns += 1;
                let now = Instant::now();
                c.first.get_or_insert(now);
                c.last = Some(now);
                if c.returns == stop_at {
                    let _ = tx.send(true);
                }
            }
            TraceEvent::Recover if c.recovered.is_none() => {
                c.recovered = Some((Instant::now(), c.records));
                let _ = tx.send(true);
            }
            _ => {}
        }
        c.records += 1;
    });
    (counted, rx, probe)
}

#[derive(Default)]
struct Counted {
    returns: u64,
    records: u64,
    first: Option<Instant>,
    last: Option<Instant>,
    recovered: Option<(Instant, u64)>,
}

pub async fn resume(dir: &Path, tokens: u64) -> anyhow::Result<Resume> {
    let journal = dir.join("resume-journal");
    let _ = std::fs::remove_dir_all(&journal);
    // Lanes that never finish: the run is left when `tokens` came back, as if its coordinator died.
    let chart = throughput_chart("resume", 0, AGENTS, LANES_PER_AGENT, i32::MAX as u32);
    let settings = crate::journal::Settings { keep: crate::journal::Keep::All, ..Default::default() };
    let agents = || Agents::Hosted { prefix: "resume", count: AGENTS };
    let extras = || Extras {
        journal: Some(crate::journal::Place::Dir(journal.clone())),
        journal_settings: Some(settings),
        ..Extras::default()
    };
    let (counted, stop, probe) = counter(tokens);
    run_chart_until(dir, "resume.st", chart.clone(), agents(), probe, extras(), stop).await?;
    let (returned, tokens_per_s) = {
        let c = counted.lock().map_err(|_| anyhow!("poisoned"))?;
        let secs = match (c.first, c.last) {
            (Some(a), Some(b)) => (b - a).as_secs_f64().max(1e-9),
            _ => bail!("no token came back"),
        };
        (c.returns, c.returns as f64 / secs)
    };
    let (segments, journal_bytes) = journal_size(&journal)?;
    // The resume, until the coordinator has replayed and says it recovered.
    let (counted, stop, probe) = counter(u64::MAX);
    let started = Instant::now();
    run_chart_until(dir, "resume.st", chart, agents(), probe, extras(), stop).await?;
    let (recovered, replayed) =
        counted.lock().map_err(|_| anyhow!("poisoned"))?.recovered.ok_or_else(|| anyhow!("the run did not resume"))?;
    let resume_ms = (recovered - started).as_secs_f64() * 1e3;
    let (opts, _) = chart_options(dir, "resume.st", String::new(), &Agents::Processes(&[]), extras())?;
    let started = Instant::now();
    let resume_replayed_records = crate::run::resume_offline(&opts)?;
    let resume_journal_ms = started.elapsed().as_secs_f64() * 1e3;
    // What a resume cost before snapshots: every record from the start.
    let started = Instant::now();
    let records = crate::replay::replay_quietly(&journal)?;
    let full_replay_ms = started.elapsed().as_secs_f64() * 1e3;
    let replay_records_per_s = records as f64 / (full_replay_ms / 1e3).max(1e-9);
    let worst_case_resume_ms = crate::journal::SNAPSHOT_EVERY as f64 / replay_records_per_s * 1e3;
    std::fs::remove_dir_all(&journal).context("cannot remove the bench's journal")?;
    Ok(Resume {
        tokens: returned,
        tokens_per_s,
        records,
        segments,
        journal_bytes,
        resume_ms,
        resume_journal_ms,
        resume_replayed_records,
        resume_replayed_trace_records: replayed,
        full_replay_ms,
        replay_records_per_s,
        worst_case_resume_ms,
    })
}

/// The segments of a journal folder and their bytes.
fn journal_size(dir: &Path) -> anyhow::Result<(u64, u64)> {
    let (mut n, mut bytes) = (0, 0);
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        if entry.file_name().to_str().is_some_and(|n| n.starts_with("journal") && n.ends_with(".log")) {
            n += 1;
            bytes += entry.metadata()?.len();
        }
    }
    Ok((n, bytes))
}
