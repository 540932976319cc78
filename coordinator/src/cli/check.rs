//! `baton check`: syntax, names, types, safety and reachability, as text or as one JSON object.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use baton_proto::cluster::skills::Catalogue;
use baton_proto::front::diag::LineIndex;
use baton_proto::front::source;
use baton_proto::pipeline::{check_source, Report};

use crate::chart_file::read_chart;

use super::common::{print_diagnostics, EXIT_INVALID, EXIT_USAGE};

/// The arguments of `baton check`.
#[derive(clap::Args)]
pub struct Check {
    /// The chart file: IEC 61131-3 textual SFC (`.st`) or PLCopen TC6 XML (`.xml`), as a PLC tool exports it.
    pub chart: PathBuf,
    /// Print one JSON object (the charts' steps, transitions and actions, and every diagnostic) instead.
    #[arg(long)]
    pub json: bool,
    /// Skills the cell's agents have besides the built-in ones, as `baton-agent --list-skills` prints them (TOML,
    /// or JSON for a `.json` file): a skill name neither built in nor listed is warned of (repeatable).
    #[arg(long = "skills", value_name = "FILE")]
    pub skills: Vec<PathBuf>,
    /// Ask the agents live behind this router which skills they have, and know those too (repeatable).
    #[arg(long, value_name = "ENDPOINT")]
    pub connect: Vec<String>,
    /// With --connect: a Zenoh configuration file (a secured router's CA and your certificate).
    #[arg(long, value_name = "FILE", requires = "connect")]
    pub zenoh_config: Option<PathBuf>,
}

impl Check {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let mut known = Catalogue::builtin();
        for file in &self.skills {
            let text =
                std::fs::read_to_string(file).map_err(|e| anyhow::anyhow!("cannot read {}: {e}", file.display()))?;
            let json = file.extension().is_some_and(|e| e.eq_ignore_ascii_case("json"));
            let read = Catalogue::parse(&text, json).map_err(|e| anyhow::anyhow!("{}: {e}", file.display()))?;
            known.merge(read);
        }
        if !self.connect.is_empty() {
            let runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build()?;
            let (agents, live) =
                runtime.block_on(crate::client::live_skills(&self.connect, self.zenoh_config.as_deref()))?;
            if agents.is_empty() {
                eprintln!(
                    "warning: no agent is live behind {}: only the built-in skills are known",
                    self.connect.join(", ")
                );
            } else {
                let names: Vec<&str> = live.names().collect();
                eprintln!("skills of the live agents ({}): {}", agents.join(", "), names.join(", "));
            }
            // What a file or the built-ins say of a skill (its parameters) stands; the agents add the names.
            let new: Vec<_> = live.skills.into_iter().filter(|s| known.get(&s.name).is_none()).collect();
            known.skills.extend(new);
        }
        if self.json {
            check_json(&self.chart, &known)
        } else {
            check(&self.chart, &known)
        }
    }
}

/// `check_source`, and what the skills `known` say of the charts' skill bindings (`cluster::skills::check`).
fn checked(src: &str, known: &Catalogue) -> Report {
    let mut report = check_source(src);
    let more: Vec<_> = report
        .charts
        .iter()
        .filter_map(|c| Some(baton_proto::cluster::skills::check(c.program.as_ref()?, c.layout.as_ref()?, known)))
        .flatten()
        .collect();
    report.diagnostics.extend(more);
    report.diagnostics.sort_by_key(|d| d.span.start);
    report
}

fn check(path: &Path, known: &Catalogue) -> anyhow::Result<ExitCode> {
    let src = read_chart(path)?.text;
    let report = checked(&src, known);
    print_diagnostics(path, &src, &report, |_| true);
    let errors = report.error_count();
    let warnings = report.diagnostics.len() - errors;
    if errors > 0 {
        eprintln!("{}: {errors} error(s), {warnings} warning(s)", path.display());
        return Ok(ExitCode::from(EXIT_INVALID));
    }
    for c in &report.charts {
        if let Some(p) = &c.program {
            println!(
                "{}: chart `{}` is valid: {} steps, {} transitions, {} actions, {} warning(s)",
                path.display(),
                p.name,
                p.steps.len(),
                p.transitions.len(),
                p.actions.len(),
                warnings
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// `baton check --json`: the charts of the file and every diagnostic, as one JSON object; the exit status is
/// `baton check`'s.
fn check_json(path: &Path, known: &Catalogue) -> anyhow::Result<ExitCode> {
    let file = path.display().to_string();
    // Always one JSON object, whatever happened: a file that cannot be read is an error diagnostic of its own.
    let read = std::fs::metadata(path)
        .map_err(anyhow::Error::from)
        .and_then(|m| source::check_size(m.len()).map_err(anyhow::Error::from))
        .and_then(|()| std::fs::read(path).map_err(anyhow::Error::from))
        .and_then(|bytes| source::decode(&bytes).map_err(anyhow::Error::from));
    let decoded = match read {
        Ok(d) => d,
        Err(e) => {
            let message = format!("cannot read {file}: {e}");
            let diagnostic =
                serde_json::json!({ "severity": "error", "file": file, "line": 0, "col": 0, "message": message });
            println!("{}", serde_json::json!({ "charts": [], "diagnostics": [diagnostic] }));
            return Ok(ExitCode::from(EXIT_USAGE));
        }
    };
    let src = decoded.text;
    let report = checked(&src, known);
    let index = LineIndex::new(&src);
    let names = |ids: &[baton_proto::front::model::Ident]| ids.iter().map(|i| i.name.clone()).collect::<Vec<_>>();
    let charts: Vec<serde_json::Value> = report
        .charts
        .iter()
        .map(|c| {
            let chart = &c.chart;
            serde_json::json!({
                "pou": chart.name.name,
                "steps": chart.steps.iter().map(|s| s.name.name.clone()).collect::<Vec<_>>(),
                "initial_steps": chart.steps.iter().filter(|s| s.initial).map(|s| s.name.name.clone()).collect::<Vec<_>>(),
                "transitions": chart.transitions.iter().map(|t| serde_json::json!({
                    "name": t.name.as_ref().map(|n| n.name.clone()),
                    "from": names(&t.from),
                    "to": names(&t.to),
                })).collect::<Vec<_>>(),
                "actions": chart.actions.iter().map(|a| a.name.name.clone()).collect::<Vec<_>>(),
            })
        })
        .collect();
    let note = decoded.note.map(|n| {
        serde_json::json!({ "severity": "warning", "file": file, "line": n.line, "col": n.col, "message": n.message })
    });
    let diagnostics: Vec<serde_json::Value> = note
        .into_iter()
        .chain(report.diagnostics.iter().map(|d| {
            let (line, col) = index.line_col(d.span.start);
            let severity = if d.is_error() { "error" } else { "warning" };
            serde_json::json!({ "severity": severity, "file": file, "line": line, "col": col, "message": d.message })
        }))
        .collect();
    println!("{}", serde_json::json!({ "charts": charts, "diagnostics": diagnostics }));
    Ok(if report.error_count() > 0 { ExitCode::from(EXIT_INVALID) } else { ExitCode::SUCCESS })
}
