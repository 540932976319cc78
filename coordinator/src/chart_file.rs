//! A chart file as every command reads it: decoded as its tool wrote it, checked, and one chart picked from
//! it (`--pou`).

use std::path::Path;
use std::sync::Arc;

use anyhow::{bail, Context};
use baton_proto::cluster::layout::Layout;
use baton_proto::exec::program::Program;
use baton_proto::front::source::{self, Decoded};
use baton_proto::pipeline::{check_source, CheckedChart, Report};

pub(crate) fn read(path: &Path) -> anyhow::Result<String> {
    std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))
}

/// A chart file's text, decoded as its tool wrote it (`front::source`): its size is checked before it is read,
/// and how it was read, when not as UTF-8, is said as a warning at its place.
pub fn read_chart(path: &Path) -> anyhow::Result<Decoded> {
    let len = std::fs::metadata(path).with_context(|| format!("cannot read {}", path.display()))?.len();
    source::check_size(len).with_context(|| format!("cannot read {}", path.display()))?;
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let decoded = source::decode(&bytes).with_context(|| format!("cannot read {}", path.display()))?;
    if let Some(note) = &decoded.note {
        eprintln!("{}:{}:{}: warning: {}", path.display(), note.line, note.col, note.message);
    }
    Ok(decoded)
}

pub fn pick<'r>(report: &'r Report, pou: Option<&str>) -> anyhow::Result<&'r CheckedChart> {
    let names = || report.charts.iter().map(|c| c.chart.name.name.as_str()).collect::<Vec<_>>().join(", ");
    match pou {
        Some(name) => report
            .charts
            .iter()
            .find(|c| c.chart.name.name.eq_ignore_ascii_case(name))
            .with_context(|| format!("no chart named `{name}` in this file (it has: {})", names())),
        None => match &report.charts[..] {
            [one] => Ok(one),
            [] => bail!("no sequential function chart in this file"),
            _ => bail!("this file holds several charts ({}): choose one with --pou NAME", names()),
        },
    }
}

/// A compiled chart ready to coordinate.
pub struct Loaded {
    pub source: String,
    pub pou: String,
    pub program: Arc<Program>,
    pub layout: Arc<Layout>,
}

/// Reads and checks the chart; every problem is printed, as `baton check` would.
pub fn load(chart: &std::path::Path, pou: Option<&str>) -> anyhow::Result<Loaded> {
    let source = read_chart(chart)?.text;
    let report = check_source(&source);
    let index = baton_proto::front::diag::LineIndex::new(&source);
    for d in &report.diagnostics {
        eprint!("{}", index.render(&chart.display().to_string(), d));
    }
    let chosen = pick(&report, pou)?;
    let (Some(program), Some(layout)) = (&chosen.program, &chosen.layout) else {
        bail!("chart `{}` has errors; nothing was run", chosen.chart.name.name);
    };
    Ok(Loaded {
        pou: chosen.chart.name.name.clone(),
        program: Arc::new(program.clone()),
        layout: Arc::new(layout.clone()),
        source,
    })
}
