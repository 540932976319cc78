//! `baton replay --journal DIR`: a past run rebuilt from its journal — its trace and its Rerun recording —
//! without a network, agents or the chart file (the journal holds the chart's source).
//!
//! It replays every segment the journal keeps, oldest first. A journal that kept all of them (`baton run
//! --journal-keep all`) gives the whole run; one compacted behind its snapshots gives the run from the oldest
//! snapshot it kept, whose coordinator it starts from. Each later segment's snapshot must stand where the records
//! before it end: a segment missing from the middle is refused, not skipped.

use std::fs::File;
use std::io::BufWriter;
use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{anyhow, bail, Context};
use baton_proto::cluster::journal::{JournalHeader, Journaled, Replayed, SnapshotMeta, JOURNAL_FORMAT};
use baton_proto::cluster::runtime::packml::State;
use baton_proto::pipeline::check_source;

use crate::recording::{RecordedRun, Recorder, Sink};
use crate::run::{replay_segments, Records};

pub struct ReplayOptions {
    pub journal: crate::journal::Place,
    pub rerun: Sink,
    pub trace: Option<PathBuf>,
    /// The variables the run watched (`baton run --watch`), traced as it traced them.
    pub watch: Vec<String>,
}

pub fn replay(opts: &ReplayOptions) -> anyhow::Result<()> {
    let (header, replayed, from, state) = rebuild(opts)?;
    let how = match &replayed.ended {
        None => "did not end (a coordinator resumes it with `baton run … --journal`)".to_string(),
        Some(failure) => crate::run::how_it_ended(state, failure.as_deref()),
    };
    let from = match from {
        None => String::new(),
        Some(meta) => format!(
            " from its snapshot at record {} ({} ms; the journal keeps the run from there: `baton run --journal-keep`)",
            meta.records, meta.last_ms
        ),
    };
    println!(
        "run {} of chart `{}`{from}: {} records, {} cycles, {} ms; it {how}",
        header.run.key(),
        header.pou,
        replayed.records,
        replayed.cycles,
        replayed.last_ms
    );
    if let Sink::Save(p) = &opts.rerun {
        println!("recording: open it with: rerun {}", p.display());
    }
    Ok(())
}

/// Replays a journal with no recording and no trace (`baton bench`): the records replayed.
pub fn replay_quietly(journal: &std::path::Path) -> anyhow::Result<u64> {
    let opts = ReplayOptions {
        journal: crate::journal::Place::Dir(journal.to_path_buf()),
        rerun: Sink::Off,
        trace: None,
        watch: Vec::new(),
    };
    rebuild(&opts).map(|(_, replayed, _, _)| replayed.records)
}

/// The run rebuilt from every segment the journal keeps into the trace and recording `opts` asks for: its header,
/// what was replayed, the snapshot it began from (if the journal no longer holds the run's start), and the state
/// it was left in.
fn rebuild(opts: &ReplayOptions) -> anyhow::Result<(JournalHeader, Replayed, Option<SnapshotMeta>, State)> {
    // Read as it stands: a replay never writes to the journal, not even to cut off a torn last commit.
    let (header, segments) = crate::journal::read_only(&opts.journal)?;
    let path = opts.journal.to_string();
    let header = header.ok_or_else(|| match &opts.journal {
        crate::journal::Place::Dir(dir) => {
            anyhow!("{} holds no journal (no {} in it)", dir.display(), crate::journal::FILE_NAME)
        }
        etcd => anyhow!("{etcd} holds no journal of a run"),
    })?;
    if header.format != JOURNAL_FORMAT {
        bail!("the journal {path} is in format {}; this baton reads format {JOURNAL_FORMAT}", header.format);
    }
    let mut report = check_source(&header.source);
    let i = report
        .charts
        .iter()
        .position(|c| c.chart.name.name == header.pou)
        .ok_or_else(|| anyhow!("the chart in the journal {path} has no POU `{}`", header.pou))?;
    let checked = report.charts.swap_remove(i);
    let (Some(program), Some(layout)) = (checked.program, checked.layout) else {
        bail!("the chart in the journal {path} does not check with this baton");
    };
    crate::run::check_pin(&header, &program, &layout, &path)?;
    let (program, layout) = (Arc::new(program), Arc::new(layout));
    let trace = match &opts.trace {
        Some(p) => Some(BufWriter::new(File::create(p).with_context(|| format!("cannot create {}", p.display()))?)),
        None => None,
    };
    let recorded = RecordedRun {
        program: Arc::clone(&program),
        layout: Arc::clone(&layout),
        run: header.run.key(),
        started_unix_ms: header.started_unix_ms,
    };
    let recorder = Recorder::start(&opts.rerun, recorded)?;
    let mut out = Records::new(trace, None, recorder, header.cycle_ms);
    // The oldest segment kept: the run's start, or a snapshot the replay starts from.
    let (mut core, from) = match segments.first().and_then(|s| s.snapshot.as_deref()) {
        None => {
            let (p, l) = (Arc::clone(&program), Arc::clone(&layout));
            (Journaled::start(p, l, header.run, header.chart.clone(), header.cycle_ms), None)
        }
        Some(bytes) => {
            let (core, meta) = Journaled::restore(Arc::clone(&program), Arc::clone(&layout), bytes)
                .map_err(|why| anyhow!("cannot replay the journal {path}: its oldest snapshot {why}"))?;
            // The recording begins with the values the snapshot holds.
            out.values(meta.last_ms, core.core());
            (core, Some(meta))
        }
    };
    core.watch(crate::run::watched(&program, &opts.watch)?);
    let replayed =
        replay_segments(&mut core, &segments, &mut out, &path).map_err(|e| anyhow!("cannot replay {e:#}"))?;
    out.finish()?;
    Ok((header, replayed, from, core.core().run_state()))
}
