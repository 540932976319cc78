//! Where a run's trace records go — the bench's probe, the recording, the summary's step times, the trace file —
//! and how a journal's records are replayed into them.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Write};

use anyhow::{anyhow, Context};
use baton_proto::cluster::journal::{self, Journaled};
use baton_proto::cluster::runtime::coordinator::{CoordOutput, Coordinator};
use baton_proto::exec::trace::{TraceEvent, TraceRecord};

use super::summary::StepTime;

/// Sees every trace record as it is made, for `baton bench`'s clocks.
pub type Probe = Box<dyn FnMut(&TraceRecord) + Send>;

/// Where trace records go: the bench's probe, the recording, the summary's step times and the trace file.
pub struct Records {
    /// The run's cycle period: a record's cycle (the recording's `cycle` timeline) is its grid index.
    cycle_ms: u64,
    pub trace: Option<BufWriter<File>>,
    trace_error: bool,
    pub(super) steps: BTreeMap<String, (StepTime, Option<u64>)>,
    probe: Option<Probe>,
    pub recorder: Option<crate::recording::Recorder>,
    /// The live trace and history for consoles (none offline).
    pub feed: Option<super::feed::Feed>,
}

impl Records {
    pub fn new(
        trace: Option<BufWriter<File>>,
        probe: Option<Probe>,
        recorder: Option<crate::recording::Recorder>,
        cycle_ms: u64,
    ) -> Records {
        Records {
            cycle_ms: cycle_ms.max(1),
            trace,
            trace_error: false,
            steps: BTreeMap::new(),
            probe,
            recorder,
            feed: None,
        }
    }

    pub fn record(&mut self, rec: TraceRecord) {
        let cycle = rec.t_ms / self.cycle_ms;
        if let Some(probe) = &mut self.probe {
            probe(&rec);
        }
        if let Some(r) = &mut self.recorder {
            r.trace(cycle, &rec);
        }
        if let Some(f) = &self.feed {
            f.record(&rec);
        }
        match rec.event {
            TraceEvent::Activate => {
                let e = self.steps.entry(rec.name.clone()).or_default();
                e.0.activations += 1;
                e.1 = Some(rec.t_ms);
            }
            TraceEvent::Deactivate => {
                if let Some((time, since)) = self.steps.get_mut(&rec.name) {
                    if let Some(t0) = since.take() {
                        time.active_ms += rec.t_ms.saturating_sub(t0);
                    }
                }
            }
            _ => {}
        }
        if let Some(w) = &mut self.trace {
            let written = serde_json::to_writer(&mut *w, &rec)
                .map_err(std::io::Error::other)
                .and_then(|()| w.write_all(b"\n"))
                .and_then(|()| w.flush());
            if let Err(e) = written {
                if !self.trace_error {
                    eprintln!("error: cannot write the trace: {e}");
                    self.trace_error = true;
                }
            }
        }
    }

    /// The variables' values at `t_ms`, after an input, for the recording.
    pub fn values(&mut self, t_ms: u64, core: &Coordinator) {
        let cycle = t_ms / self.cycle_ms;
        if let Some(r) = self.recorder.as_mut() {
            r.values(cycle, t_ms, |v| core.value(v));
        }
    }

    /// Ends the recording and flushes the trace.
    pub fn finish(&mut self) -> anyhow::Result<()> {
        if let Some(r) = self.recorder.take() {
            let dropped = r.finish();
            if dropped > 0 {
                eprintln!("warning: the recording lacks {dropped} record(s): the Rerun sink could not keep up");
            }
        }
        if let Some(t) = &mut self.trace {
            t.flush().context("cannot write the trace")?;
        }
        Ok(())
    }
}

/// Rebuilds a run from its journal's records into `core`: the trace (and recording) of the past go to `out`,
/// nothing is sent.
pub fn replay_records(
    core: &mut Journaled,
    records: &[Vec<u8>],
    out: &mut Records,
) -> anyhow::Result<journal::Replayed> {
    let mut replayed = journal::Replayed::default();
    for (i, bytes) in records.iter().enumerate() {
        let entry = journal::decode(bytes).map_err(|e| anyhow!("the journal's record {i} cannot be read: {e}"))?;
        core.apply_replayed(&entry, &mut replayed);
        while let Some(output) = core.poll_output() {
            if let CoordOutput::Trace(rec) = output {
                out.record(rec);
            }
        }
        // After every input, as the live run does.
        out.values(entry.t_ms, core.core());
    }
    Ok(replayed)
}
