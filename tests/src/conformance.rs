//! Conformance cases as data, in `tests/conformance/`: a trace case is a folder in `traces/` with `chart.st` (or
//! `chart.xml`), an optional `inputs.jsonl`, an optional `sim.json` (`{"cycle_ms": 10, "until_ms": 1000}`) and
//! `expected.jsonl`, what `baton sim` prints; a diagnostics case is a `NAME.st` (or `NAME.xml`) in `diagnostics/`
//! beside `NAME.expected`, the exact text `baton check` prints. `check` is the only code that drives them, so a
//! refactor touches one place. `UPDATE_EXPECT=1` rewrites the expectations instead; review the diff.
//!
//! ("Scenario" is the word for users' `*.test.toml` files, which `baton test` runs.)

use std::fs;
use std::path::Path;
use std::sync::Arc;

use baton_proto::exec::sim::{parse_inputs, simulate_watching};
use baton_proto::exec::trace::Output;
use baton_proto::front::diag::LineIndex;
use baton_proto::pipeline::check_source;

fn read(path: &Path) -> Result<String, String> {
    fs::read_to_string(path).map_err(|e| format!("cannot read {}: {e}", path.display()))
}

fn updating() -> bool {
    std::env::var_os("UPDATE_EXPECT").is_some()
}

/// Checks one conformance case: a folder (a trace case) or a `.st` or `.xml` file (a diagnostics case).
pub fn check(path: &Path) -> Result<(), String> {
    if path.is_dir() {
        compare(&path.join("expected.jsonl"), &run_simulation(path)?)
    } else {
        compare(&path.with_extension("expected"), &render_check(path)?)
    }
}

/// Checks the diagnostics `baton check` gives a file kept elsewhere (the shared corpus) against our expectation.
/// Only the header lines are kept, so that no text of the third-party file is copied into ours.
pub fn check_diagnostics_against(path: &Path, expected_path: &Path) -> Result<(), String> {
    let headers: String = render_check(path)?
        .lines()
        .filter(|l| !l.starts_with(' ') && !l.contains(" | "))
        .map(|l| format!("{l}\n"))
        .collect();
    compare(expected_path, &headers)
}

fn compare(expected_path: &Path, actual: &str) -> Result<(), String> {
    if updating() {
        return fs::write(expected_path, actual).map_err(|e| format!("cannot write {}: {e}", expected_path.display()));
    }
    let expected = read(expected_path)?;
    if expected == actual {
        return Ok(());
    }
    let first_diff = expected.lines().zip(actual.lines()).position(|(e, a)| e != a);
    let line = first_diff.unwrap_or_else(|| expected.lines().count().min(actual.lines().count()));
    Err(format!(
        "{} differs from line {}:\n  expected: {}\n  actual:   {}\n(run with UPDATE_EXPECT=1 to accept the new output, then review the diff)",
        expected_path.display(),
        line + 1,
        expected.lines().nth(line).unwrap_or("<end>"),
        actual.lines().nth(line).unwrap_or("<end>")
    ))
}

/// What `baton check` prints for a file: every diagnostic, rendered, and the summary.
pub fn render_check(path: &Path) -> Result<String, String> {
    let src = read(path)?;
    let report = check_source(&src);
    let index = LineIndex::new(&src);
    let name = path.file_name().map_or_else(String::new, |n| n.to_string_lossy().into_owned());
    let mut out = String::new();
    for d in &report.diagnostics {
        out.push_str(&index.render(&name, d));
    }
    let errors = report.error_count();
    out.push_str(&format!("errors: {errors}, warnings: {}\n", report.diagnostics.len() - errors));
    Ok(out)
}

#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct SimSettings {
    #[serde(default = "default_cycle")]
    cycle_ms: u64,
    #[serde(default = "default_until")]
    until_ms: u64,
    /// Variables traced as `value` records, as `baton sim --watch` does.
    #[serde(default)]
    watch: Vec<String>,
}

fn default_cycle() -> u64 {
    10
}

fn default_until() -> u64 {
    1000
}

/// The trace `baton sim` prints for a scenario folder, faults included as `{"fault": …}` lines.
pub fn run_simulation(dir: &Path) -> Result<String, String> {
    // A scenario's chart is textual SFC (`chart.st`) or PLCopen XML (`chart.xml`).
    let file = if dir.join("chart.xml").exists() { "chart.xml" } else { "chart.st" };
    let src = read(&dir.join(file))?;
    let report = check_source(&src);
    let index = LineIndex::new(&src);
    let errors: String = report.diagnostics.iter().filter(|d| d.is_error()).map(|d| index.render(file, d)).collect();
    let program = match &report.charts[..] {
        [one] => one.program.clone().ok_or_else(|| format!("{}: chart has errors:\n{errors}", dir.display()))?,
        _ => return Err(format!("{}: expected exactly one chart", dir.display())),
    };
    let settings: SimSettings = match fs::read_to_string(dir.join("sim.json")) {
        Ok(text) => serde_json::from_str(&text).map_err(|e| format!("{}/sim.json: {e}", dir.display()))?,
        Err(_) => SimSettings { cycle_ms: default_cycle(), until_ms: default_until(), watch: Vec::new() },
    };
    let inputs = match fs::read_to_string(dir.join("inputs.jsonl")) {
        Ok(text) => parse_inputs(&text, &program).map_err(|e| format!("{}/inputs.jsonl: {e}", dir.display()))?,
        Err(_) => Vec::new(),
    };
    let mut watch = Vec::with_capacity(settings.watch.len());
    for name in &settings.watch {
        watch.push(
            program.var_by_name(name).ok_or_else(|| format!("{}/sim.json: no variable `{name}`", dir.display()))?,
        );
    }
    let mut out = String::new();
    simulate_watching(Arc::new(program), &inputs, settings.cycle_ms, settings.until_ms, &watch, |o| match o {
        Output::Trace(record) => {
            out.push_str(&serde_json::to_string(&record).unwrap_or_default());
            out.push('\n');
        }
        Output::Fault { t_ms, message } => {
            out.push_str(&serde_json::json!({ "t_ms": t_ms, "fault": message }).to_string());
            out.push('\n');
        }
    })
    .map_err(|e| e.to_string())?;
    Ok(out)
}
