//! `baton export --plcopen | --svg`: valid charts written out as PLCopen TC6 v2.01 XML, with positions, or one
//! chart drawn in IEC 61131-3 notation as SVG, at the same positions (`back::diagram`).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use baton_proto::pipeline::{check_source, CheckedChart, Report};

use crate::chart_file::{pick, read_chart};

use super::common::{print_diagnostics, EXIT_INVALID};

/// The arguments of `baton export`.
#[derive(clap::Args)]
pub struct Export {
    /// The chart file: IEC 61131-3 textual SFC (`.st`) or PLCopen TC6 XML (`.xml`), as a PLC tool exports it.
    pub chart: PathBuf,
    /// PLCopen TC6 v2.01 XML: every chart of the file (or the one --pou names).
    #[arg(long, required_unless_present = "svg", conflicts_with = "svg")]
    pub plcopen: bool,
    /// The chart drawn in IEC 61131-3 notation as an SVG picture (one chart: --pou picks it in a file of several).
    #[arg(long)]
    pub svg: bool,
    /// Which chart to use when the file holds several PROGRAMs or FUNCTION_BLOCKs with SFC bodies.
    #[arg(long)]
    pub pou: Option<String>,
    /// Write here instead of to stdout.
    #[arg(long, short = 'o', value_name = "FILE")]
    pub output: Option<PathBuf>,
}

impl Export {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        if self.svg {
            return export_svg(&self.chart, self.pou.as_deref(), self.output.as_deref());
        }
        export(&self.chart, self.pou.as_deref(), self.output.as_deref())
    }
}

/// The file's charts checked, their diagnostics printed; `None`, having said that nothing was `done`, when the
/// file has errors or no chart.
fn checked(path: &Path, done: &str) -> anyhow::Result<Option<Report>> {
    let src = read_chart(path)?.text;
    let report = check_source(&src);
    print_diagnostics(path, &src, &report, |_| true);
    if report.error_count() > 0 || report.charts.is_empty() {
        eprintln!("{}: nothing was {done}: the file has errors or no chart", path.display());
        return Ok(None);
    }
    Ok(Some(report))
}

/// `baton export --svg`: one chart of the file, drawn; a chart with errors draws nothing.
fn export_svg(path: &Path, pou: Option<&str>, output: Option<&Path>) -> anyhow::Result<ExitCode> {
    let Some(report) = checked(path, "drawn")? else { return Ok(ExitCode::from(EXIT_INVALID)) };
    let chosen = pick(&report, pou)?;
    let Some(program) = chosen.program.as_ref() else {
        eprintln!("{}: nothing was drawn: chart `{}` did not compile", path.display(), chosen.chart.name.name);
        return Ok(ExitCode::from(EXIT_INVALID));
    };
    write_out(output, &baton_proto::back::svg::chart(&chosen.chart, program))?;
    Ok(ExitCode::SUCCESS)
}

/// `text` to `output`, or to stdout (a closed pipe, as `| head` makes, is no error).
fn write_out(output: Option<&Path>, text: &str) -> anyhow::Result<()> {
    match output {
        Some(file) => std::fs::write(file, text).with_context(|| format!("cannot write {}", file.display()))?,
        None => {
            let mut out = std::io::stdout().lock();
            match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
                Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {}
                other => other.context("cannot write the export")?,
            }
        }
    }
    Ok(())
}

/// `baton export --plcopen`: the file's charts as PLCopen XML; a chart with errors exports nothing.
fn export(path: &Path, pou: Option<&str>, output: Option<&Path>) -> anyhow::Result<ExitCode> {
    let Some(report) = checked(path, "exported")? else { return Ok(ExitCode::from(EXIT_INVALID)) };
    let chosen: Vec<&CheckedChart> = match pou {
        Some(_) => vec![pick(&report, pou)?],
        None => report.charts.iter().collect(),
    };
    let charts: Vec<_> = chosen.iter().filter_map(|c| Some((&c.chart, c.program.as_ref()?))).collect();
    let project = path.file_stem().map_or_else(|| "baton".to_string(), |s| s.to_string_lossy().into_owned());
    let xml = baton_proto::back::plcopen::export(&charts, &report.library, &report.types, &project, &utc_now());
    write_out(output, &xml)?;
    Ok(ExitCode::SUCCESS)
}

/// The current UTC time as an `xsd:dateTime` (`2026-12-01T12:34:56`).
fn utc_now() -> String {
    let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs()) as i64;
    let (days, rest) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let (year, month, day) = baton_proto::types::civil_from_days(days);
    format!("{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}", rest / 3600, rest % 3600 / 60, rest % 60)
}
