//! Whether a journal may be resumed by this chart and this build, and the wall clock a run starts on.

use anyhow::bail;
use baton_proto::dist::journal::{self, JournalHeader, Record, JOURNAL_FORMAT};
use baton_proto::dist::layout::Layout;
use baton_proto::dist::wire::ChartHash;
use baton_proto::exec::program::Program;

use crate::chart_file::Loaded;

pub(crate) fn unix_ms() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_millis() as u64)
}

/// A journal is resumed only by the same chart version, only in a format this build reads, and only if its
/// run did not end.
pub(crate) fn check_resumable(
    header: &JournalHeader,
    records: &[Vec<u8>],
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
    if let Some(last) = records.last() {
        if let Ok(journal::Entry { record: Record::End { failure }, .. }) = journal::decode(last) {
            let how = match failure {
                Some(why) => format!("failed: {why}"),
                None => "finished".to_string(),
            };
            bail!(
                "the run {} in the journal {path} is over (it {how}); give another --journal folder for a new run",
                header.run.key()
            );
        }
    }
    Ok(())
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
