//! `baton replay --journal DIR`: a past run rebuilt from its journal — its trace and its Rerun recording —
//! without a network, agents or the chart file (the journal holds the chart's source).

use std::fs::File;
use std::io::BufWriter;
use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{anyhow, bail, Context};
use baton_proto::dist::journal::{self, Journaled, JOURNAL_FORMAT};
use baton_proto::dist::runtime::coordinator::Coordinator;
use baton_proto::pipeline::check_source;

use crate::recording::{RecordedRun, Recorder, Sink};
use crate::run::{replay_records, Records};

pub struct ReplayOptions {
    pub journal: PathBuf,
    pub rerun: Sink,
    pub trace: Option<PathBuf>,
}

pub fn replay(opts: &ReplayOptions) -> anyhow::Result<()> {
    if !opts.journal.join(crate::journal::FILE_NAME).is_file() {
        bail!("{} holds no journal ({} is missing)", opts.journal.display(), crate::journal::FILE_NAME);
    }
    let opened = crate::journal::open(&opts.journal)?;
    let path = opened.store.path().display().to_string();
    let header = opened.header.ok_or_else(|| anyhow!("the journal {path} holds no run"))?;
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
    let mut core = Coordinator::new(program, layout, header.run, header.chart.clone(), journal::token_ids(header.run));
    core.set_cycle_ms(header.cycle_ms);
    let mut core = Journaled::new(core);
    let mut out = Records::new(trace, None, recorder, header.cycle_ms);
    let replayed = replay_records(&mut core, &opened.records, &mut out)?;
    out.finish()?;
    let how = match &replayed.ended {
        None => "did not end (a coordinator resumes it with `baton run … --journal`)".to_string(),
        Some(None) => "finished".to_string(),
        Some(Some(why)) => format!("failed: {why}"),
    };
    println!(
        "run {} of chart `{}`: {} records, {} cycles, {} ms; it {how}",
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
