//! `baton sim`: a chart on virtual time, its events printed as JSON Lines.

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;

use anyhow::Context;
use baton_proto::exec::sim::{parse_inputs, simulate_watching};
use baton_proto::exec::trace::Output;
use baton_proto::pipeline::check_source;

use crate::chart_file::{pick, read, read_chart};

use super::common::{print_diagnostics, EXIT_INVALID};

/// The arguments of `baton sim`.
#[derive(clap::Args)]
pub struct Sim {
    /// The chart file: IEC 61131-3 textual SFC (`.st`) or PLCopen TC6 XML (`.xml`), as a PLC tool exports it.
    pub chart: PathBuf,
    /// Input script, JSON Lines: {"t_ms": 100, "set": {"start": true}}.
    #[arg(long)]
    pub inputs: Option<PathBuf>,
    /// Time between two scan cycles.
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..=baton_proto::limits::CYCLE_MS_MAX))]
    pub cycle_ms: u64,
    /// Time of the last cycle.
    #[arg(long, default_value_t = 1000)]
    pub until_ms: u64,
    /// Which chart to run when the file holds several PROGRAMs or FUNCTION_BLOCKs with SFC bodies.
    #[arg(long)]
    pub pou: Option<String>,
    /// Trace this variable's value (`t1.ET` for a block's output): a `value` record after the first cycle
    /// and after every cycle that changed it. Repeat for more.
    #[arg(long, value_name = "VARIABLE")]
    pub watch: Vec<String>,
}

impl Sim {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        sim(&self.chart, self.inputs.as_deref(), self.cycle_ms, self.until_ms, self.pou.as_deref(), &self.watch)
    }
}

fn sim(
    path: &Path,
    inputs: Option<&Path>,
    cycle_ms: u64,
    until_ms: u64,
    pou: Option<&str>,
    watch: &[String],
) -> anyhow::Result<ExitCode> {
    let src = read_chart(path)?.text;
    let report = check_source(&src);
    if report.charts.is_empty() {
        print_diagnostics(path, &src, &report, |_| true);
        return Ok(ExitCode::from(EXIT_INVALID));
    }
    let chosen = pick(&report, pou)?;
    let span = chosen.chart.span;
    let inside = |at: u32| span.start <= at && at <= span.end;
    print_diagnostics(path, &src, &report, inside);
    let Some(program) = &chosen.program else {
        eprintln!("{}: chart `{}` has errors; nothing was run", path.display(), chosen.chart.name.name);
        return Ok(ExitCode::from(EXIT_INVALID));
    };
    let program = Arc::new(program.clone());
    let records = match inputs {
        Some(p) => {
            let text = read(p)?;
            parse_inputs(&text, &program).with_context(|| format!("bad input script {}", p.display()))?
        }
        None => Vec::new(),
    };
    let mut watched = Vec::with_capacity(watch.len());
    for name in watch {
        match program.var_by_name(name) {
            Some(v) => watched.push(v),
            None => anyhow::bail!("--watch {name}: chart `{}` has no variable `{name}`", program.name),
        }
    }
    let mut out = BufWriter::new(std::io::stdout().lock());
    let mut write_error = None;
    let layout = chosen.layout.clone();
    let end = simulate_watching(Arc::clone(&program), &records, cycle_ms, until_ms, &watched, |output| match output {
        Output::Trace(record) => {
            if write_error.is_none() {
                let line = serde_json::to_string(&record).map_err(std::io::Error::other);
                if let Err(e) = line.and_then(|l| writeln!(out, "{l}")) {
                    write_error = Some(e);
                }
            }
        }
        Output::Fault { t_ms, message } => eprintln!("warning: t_ms={t_ms}: {message}"),
    })?;
    if let Some(layout) = &layout {
        for line in waiting_on_skills(&program, layout, &end, until_ms) {
            eprintln!("{line}");
        }
    }
    match write_error.map_or_else(|| out.flush(), Err) {
        // A closed pipe (`baton sim … | head`) is the reader's choice, not an error.
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(ExitCode::SUCCESS),
        Err(e) => Err(e).context("cannot write the trace"),
        Ok(()) => Ok(ExitCode::SUCCESS),
    }
}

/// `baton sim` runs one engine and no skill: a step whose action is a skill waits for ever for what that skill
/// would have written. Said at the end, for each such step still active, with how to drive it: an input script
/// that sets the indicator (or output) the step waits for, or `baton test`, whose simulated cell runs skills.
fn waiting_on_skills(
    program: &baton_proto::exec::program::Program,
    layout: &baton_proto::cluster::layout::Layout,
    active: &[baton_proto::exec::program::StepId],
    until_ms: u64,
) -> Vec<String> {
    let mut lines = Vec::new();
    for &s in active {
        let indicators = program.indicators(s);
        for (i, assoc) in program.associations(s).iter().enumerate() {
            let Some(binding) = layout.skills.get(assoc.action.index()).and_then(Option::as_ref) else { continue };
            let action = &program.actions[assoc.action.index()].name;
            let drive: Vec<&str> =
                indicators.get(i).into_iter().flatten().map(|v| program.vars[v.index()].name.as_str()).collect();
            let how = match drive.as_slice() {
                [] => String::new(),
                names => format!(
                    "; to go on here, set {} in an --inputs script, as the skill would (`{{\"t_ms\": 500, \"set\": \
                     {{\"{}\": true}}}}`)",
                    names.iter().map(|n| format!("`{n}`")).collect::<Vec<_>>().join(", "),
                    names[0]
                ),
            };
            lines.push(format!(
                "note: step `{}` waits at {until_ms} ms on action `{action}`, the skill `{}`: `baton sim` runs no \
                 skills{how}; `baton test` runs them simulated (durations, outcomes)",
                program.steps[s.index()].name,
                binding.skill
            ));
        }
    }
    lines
}
