//! Whether a journal may be resumed by this chart and this build, and the wall clock a run starts on.

use anyhow::{anyhow, bail};
use baton_proto::cluster::journal::{self, JournalHeader, Journaled, Record, Replayed, JOURNAL_FORMAT};
use baton_proto::cluster::layout::Layout;
use baton_proto::cluster::wire::ChartHash;
use baton_proto::exec::program::Program;

use crate::chart_file::Loaded;

/// A journal is resumed only by the same chart version and only in a format this build reads (whether its run
/// ended is `end_of`'s to say).
pub(crate) fn check_resumable(
    header: &JournalHeader,
    loaded: &Loaded,
    hash: &ChartHash,
    chart: &std::path::Path,
    path: &str,
) -> anyhow::Result<()> {
    let pou = loaded.pou.as_str();
    if !(1..=baton_proto::limits::CYCLE_MS_MAX).contains(&header.cycle_ms) {
        bail!("the journal {path} holds a cycle period of {} ms, which no run has: it is damaged", header.cycle_ms);
    }
    if header.format != JOURNAL_FORMAT {
        bail!(
            "the journal {path} is in format {}, and this baton reads format {JOURNAL_FORMAT}; \
             give another --journal folder",
            header.format
        );
    }
    if header.chart != *hash || header.pou != pou {
        bail!(
            "the journal {path} belongs to a run of chart `{}` version {}, and {} is chart `{pou}` version {}: \
             a run only resumes with the chart it started with. Run that version again to resume it, or give \
             another --journal folder for a new run",
            header.pou,
            header.chart.0,
            chart.display(),
            hash.0
        );
    }
    check_pin(header, &loaded.program, &loaded.layout, path)?;
    Ok(())
}

/// How a journal's run ended, if its last record is its end: the failure, if it failed.
pub(crate) fn end_of(records: &[Vec<u8>]) -> Option<Option<String>> {
    match journal::decode(records.last()?) {
        Ok(journal::Entry { record: Record::End { failure }, .. }) => Some(failure),
        _ => None,
    }
}

/// How a run ended, in words: `state` its PackML state at the end, `failure` why it failed.
pub fn how_it_ended(state: baton_proto::cluster::runtime::packml::State, failure: Option<&str>) -> String {
    use baton_proto::cluster::runtime::packml::State;
    match (failure, state) {
        (Some(why), _) => format!("failed: {why}"),
        (None, State::Complete) => "completed".to_string(),
        (None, State::Stopped) => "was stopped".to_string(),
        (None, State::Aborted) => "was aborted".to_string(),
        (None, other) => format!("ended in state {}", other.name()),
    }
}

/// A journal's records mean something only for the program it pins: a build of Baton that compiles the same chart
/// to other numbers would apply them to other variables and transitions.
pub fn check_pin(header: &JournalHeader, program: &Program, layout: &Layout, path: &str) -> anyhow::Result<()> {
    let pin = journal::program_pin(program, layout);
    if header.program != pin {
        bail!(
            "the journal {path} was written by a baton that compiled chart `{}` to other numbers (program {}; this \
             baton compiles it to program {pin}): its records would name other variables and transitions here. \
             Resume it with the baton that started it, or give another --journal folder for a new run",
            header.pou,
            header.program
        );
    }
    Ok(())
}

/// Replays `segments` (oldest first) into `core`, which stands where the first begins (the run's start, or the
/// first's snapshot restored). Each later segment's snapshot must stand where the records before it end: a segment
/// missing from the middle is refused, not skipped.
pub fn replay_segments(
    core: &mut Journaled,
    segments: &[crate::journal::Segment],
    out: &mut super::records::Records,
    path: &str,
) -> anyhow::Result<Replayed> {
    let mut replayed = Replayed::default();
    for (i, segment) in segments.iter().enumerate() {
        if let (true, Some(bytes)) = (i > 0, &segment.snapshot) {
            let meta = journal::snapshot_meta(bytes)
                .map_err(|why| anyhow!("the journal {path}: segment {}'s snapshot {why}", segment.number))?;
            if meta.records != core.records_counted() {
                bail!(
                    "the journal {path}: segment {} begins after record {}, and the segments before it end after \
                     record {}: a segment is missing or damaged",
                    segment.number,
                    meta.records,
                    core.records_counted()
                );
            }
        }
        let part = super::records::replay_records(core, &segment.records, out)?;
        replayed.records += part.records;
        replayed.cycles += part.cycles;
        replayed.last_ms = replayed.last_ms.max(part.last_ms);
        replayed.ended = part.ended.or(replayed.ended);
    }
    Ok(replayed)
}

/// The segments a resume replays: the last one (from its snapshot), or — when the trace file lacks trace records
/// made before that snapshot (the process died after the snapshot was durable and before it wrote them) — from
/// the newest kept snapshot the file does hold, so that the replay writes the missing records again. `trace_lines`:
/// the whole records the trace file holds, if the run writes one.
pub(crate) fn resume_segments(
    store: &crate::journal::Store,
    last: crate::journal::Segment,
    trace_lines: Option<u64>,
) -> anyhow::Result<Vec<crate::journal::Segment>> {
    let traced = |s: &crate::journal::Segment| match &s.snapshot {
        None => Ok(0),
        Some(bytes) => journal::snapshot_meta(bytes).map(|m| m.trace_records).map_err(|why| anyhow!("{why}")),
    };
    let Some(lines) = trace_lines else { return Ok(vec![last]) };
    if traced(&last)? <= lines {
        return Ok(vec![last]);
    }
    let mut all = store.segments()?;
    let mut from = None;
    for (i, s) in all.iter().enumerate().rev() {
        if traced(s)? <= lines {
            from = Some(i);
            break;
        }
    }
    match from {
        Some(i) => Ok(all.split_off(i)),
        None => {
            eprintln!(
                "warning: the trace file holds {lines} records, fewer than the journal's oldest kept snapshot \
                 follows: the records in between are missing from it"
            );
            Ok(vec![last])
        }
    }
}

/// How many whole records (lines) a trace file holds; none if it is missing.
pub(crate) fn trace_lines(path: &std::path::Path) -> u64 {
    std::fs::read(path).map_or(0, |bytes| bytes.iter().filter(|b| **b == b'\n').count() as u64)
}
