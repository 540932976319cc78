//! A scenario file (`*.test.toml`): the chart under test, the simulated cell (agents, what their skills do),
//! inputs, faults and expectations. Reading one checks it whole against its chart: every step, action, agent and
//! variable it names exists, every time is a duration, every condition parses — and each mistake is said at its
//! `FILE:LINE:COL`. A scenario that reads is one that can run.
//!
//! The format, key by key, is in the user guide (`docs/book/src/testing.md`) and in `docs/baton-test.schema.json`.

use std::collections::{BTreeMap, BTreeSet};
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use toml::Spanned;

use crate::cluster::layout::Layout;
use crate::cluster::runtime::coordinator::LossPolicy;
use crate::cluster::wire::ChartHash;
use crate::exec::program::Program;
use crate::front::diag::LineIndex;
use crate::pipeline::check_source;

use super::cond::Cond;
use raw::RawScenario;

mod commands;
mod raw;
mod sections;

/// How long a scenario may run in chart time unless it says (`until`).
pub const UNTIL_DEFAULT_MS: u64 = 600_000;
/// The longest chart time a scenario may ask for: a week.
pub const UNTIL_MAX_MS: u64 = 7 * 24 * 3_600_000;

/// A mistake in a scenario file, at a place of it.
#[derive(Clone, Debug, PartialEq)]
pub struct ScenarioError {
    pub line: usize,
    pub col: usize,
    pub message: String,
}

/// Why a scenario cannot be read (exit status 3) or cannot run (exit status 2).
#[derive(Clone, Debug, PartialEq)]
pub enum LoadError {
    /// The file is not a valid scenario: `FILE:LINE:COL: message` each.
    Malformed(Vec<ScenarioError>),
    /// The scenario reads, but what it names cannot be had: its chart is missing or has errors.
    CannotRun(String),
}

// ---- the scenario, checked ---------------------------------------------------------------------------

/// When something happens: at a chart time, or the first time a condition holds (then `after` later).
#[derive(Clone, Debug)]
pub enum Trigger {
    At(u64),
    When { cond: Cond, text: String, after_ms: u64 },
}

#[derive(Clone, Debug)]
pub struct Input {
    pub trigger: Trigger,
    pub set: Vec<(String, serde_json::Value)>,
}

/// What the simulated network does to messages.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NetFaults {
    pub delay_ms: u64,
    pub drop: f64,
    pub duplicate: f64,
    pub reorder: bool,
}

#[derive(Clone, Debug)]
pub enum FaultKind {
    Kill(String),
    Restart(String),
    /// Cut off (a partition), healed `heal_after_ms` later if given.
    Cut(String, Option<u64>),
    Heal(String),
    /// The agent's link suffers `faults` for `for_ms`.
    Link(String, NetFaults, u64),
    /// The coordinator dies and starts again from its journal `down_ms` later.
    CrashCoordinator(u64),
}

#[derive(Clone, Debug)]
pub struct Fault {
    pub kind: FaultKind,
    pub trigger: Trigger,
    /// Each seed moves the fault by up to this much, later.
    pub jitter_ms: u64,
    pub line: usize,
}

impl Fault {
    /// `kill robot1`, `crash the coordinator`…
    pub fn describe(&self) -> String {
        match &self.kind {
            FaultKind::Kill(a) => format!("kill {a}"),
            FaultKind::Restart(a) => format!("restart {a}"),
            FaultKind::Cut(a, None) => format!("cut {a} off"),
            FaultKind::Cut(a, Some(ms)) => format!("cut {a} off for {}", show_ms(*ms)),
            FaultKind::Heal(a) => format!("heal {a}"),
            FaultKind::Link(a, f, ms) => {
                let mut parts = Vec::new();
                if f.drop > 0.0 {
                    parts.push(format!("drop {}", f.drop));
                }
                if f.duplicate > 0.0 {
                    parts.push(format!("duplicate {}", f.duplicate));
                }
                if f.delay_ms > 0 {
                    parts.push(format!("delay up to {}", show_ms(f.delay_ms)));
                }
                if f.reorder {
                    parts.push("reorder".into());
                }
                format!("{} on {a}'s link for {}", parts.join(", "), show_ms(*ms))
            }
            FaultKind::CrashCoordinator(down) => format!("crash the coordinator, back after {}", show_ms(*down)),
        }
    }
}

/// What an action's skill does in the simulated cell.
#[derive(Clone, Debug, Default)]
pub struct Behaviour {
    /// Fixed (`lo == hi`) or drawn from the seed within `lo..=hi`; `None`: the `motion` skill's `ms` parameter.
    pub duration: Option<(u64, u64)>,
    /// Outcome of its first, second… run (`true` done, `false` fault); the last repeats. Empty: the `motion`
    /// skill's `fault_rate` decides.
    pub outcomes: Vec<bool>,
    pub hang: bool,
    pub message: Option<String>,
    /// Values written to the skill's mapped output variables before it ends: (index in its binding, value).
    pub writes: Vec<(usize, crate::types::Value)>,
}

#[derive(Clone, Debug)]
pub struct Agent {
    pub name: String,
    pub roles: Vec<String>,
    pub start_ms: u64,
    /// The skills it provides; `None`: all.
    pub skills: Option<BTreeSet<String>>,
}

#[derive(Clone, Debug, PartialEq)]
pub enum RunState {
    Finished,
    Failed,
    Running,
    /// An operator's `stop` ended it.
    Stopped,
    /// An operator's `abort` ended it.
    Aborted,
}

/// An operator's command the scenario sends (`[[commands]]`), as `baton ctl` would.
#[derive(Clone, Debug)]
pub struct Command {
    pub trigger: Trigger,
    pub request: crate::cluster::wire::CtlRequest,
    pub line: usize,
}

/// The commands `[[commands]]` may send.
pub const COMMANDS: [&str; 18] = [
    "start",
    "clear",
    "reset",
    "hold",
    "unhold",
    "suspend",
    "unsuspend",
    "stop",
    "abort",
    "mode",
    "confirm",
    "force",
    "activate",
    "deactivate",
    "move",
    "ack",
    "shelve",
    "unshelve",
];

#[derive(Clone, Debug)]
pub enum ExpectKind {
    Reached {
        step: String,
        on: Option<String>,
        by_ms: Option<u64>,
    },
    Order(Vec<String>),
    Value {
        vars: Vec<(String, toml::Value)>,
        at_ms: Option<u64>,
    },
    Always(Cond, String),
    Never(Cond, String),
    EndsBy(u64),
    Alarms(Vec<String>),
    State(RunState),
    /// The run passes through these PackML states, in this order (others may come between).
    States(Vec<String>),
    /// The run's mode changes to these, in this order.
    Modes(Vec<String>),
    OncePerEpoch(String),
}

#[derive(Clone, Debug)]
pub struct Expect {
    pub kind: ExpectKind,
    pub line: usize,
}

impl Expect {
    /// One line naming what is expected: the test case's name.
    pub fn title(&self) -> String {
        match &self.kind {
            ExpectKind::Reached { step, on, by_ms } => {
                let on = on.as_ref().map_or(String::new(), |a| format!(" on {a}"));
                let by = by_ms.map_or(String::new(), |t| format!(" by {}", show_ms(t)));
                format!("step {step} is reached{on}{by}")
            }
            ExpectKind::Order(steps) => format!("steps pass in order: {}", steps.join(", ")),
            ExpectKind::Value { vars, at_ms } => {
                let vs: Vec<String> = vars.iter().map(|(n, v)| format!("{n} = {}", show_toml(v))).collect();
                let when = at_ms.map_or("at the end".to_string(), |t| format!("at {}", show_ms(t)));
                format!("{} {when}", vs.join(", "))
            }
            ExpectKind::Always(_, text) => format!("always {text}"),
            ExpectKind::Never(_, text) => format!("never {text}"),
            ExpectKind::EndsBy(t) => format!("the chart ends by {}", show_ms(*t)),
            ExpectKind::Alarms(a) if a.is_empty() => "no alarm is raised".to_string(),
            ExpectKind::Alarms(a) => format!("alarms raised: {}", a.join("; ")),
            ExpectKind::State(s) => format!("the run ends {}", format!("{s:?}").to_lowercase()),
            ExpectKind::States(s) => format!("the run passes through the states {}", s.join(", ")),
            ExpectKind::Modes(m) => format!("the run's mode changes to {}", m.join(", ")),
            ExpectKind::OncePerEpoch(a) => format!("the skill of {a} never runs twice in an epoch"),
        }
    }
}

/// A scenario read and checked against its chart, ready to run with any seed.
pub struct Scenario {
    pub path: PathBuf,
    pub name: String,
    pub chart_path: PathBuf,
    pub program: Arc<Program>,
    pub layout: Arc<Layout>,
    pub hash: ChartHash,
    pub until_ms: u64,
    pub seed: u64,
    pub loss_policy: LossPolicy,
    pub journal: bool,
    /// The run stays at its end for `clear` and `reset` (`baton run --stay`): the scenario ends once the run is
    /// at an end (complete, stopped, aborted) with no command left to send.
    pub stay: bool,
    pub cycle_ms: u64,
    pub network: NetFaults,
    pub agents: Vec<Agent>,
    /// By action index.
    pub behaviours: BTreeMap<usize, Behaviour>,
    pub inputs: Vec<Input>,
    pub faults: Vec<Fault>,
    pub commands: Vec<Command>,
    pub expects: Vec<Expect>,
}

impl Scenario {
    /// Its name as a file name: letters, digits and `-` kept, everything else `_`.
    pub fn file_stem(&self) -> String {
        self.name.replace(|c: char| !c.is_ascii_alphanumeric() && c != '-', "_")
    }
}

pub fn show_ms(ms: u64) -> String {
    if ms == 0 {
        "0s".into()
    } else if ms.is_multiple_of(60_000) {
        format!("{}min", ms / 60_000)
    } else if ms.is_multiple_of(1000) {
        format!("{}s", ms / 1000)
    } else if ms >= 1000 {
        format!("{}s", ms as f64 / 1000.0)
    } else {
        format!("{ms}ms")
    }
}

/// A chart time as a scenario writes it: `250ms`, `2s`, `1.5s`, `10min`, `1h`, or IEC's `T#2s`.
pub fn parse_duration(text: &str) -> Result<u64, String> {
    let t = text.trim();
    let t = t.strip_prefix("T#").or_else(|| t.strip_prefix("t#")).unwrap_or(t);
    let split = t.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let n: f64 =
        number.parse().map_err(|_| format!("`{text}` is not a duration (write `250ms`, `2s`, `1.5s`, `10min`)"))?;
    let scale = match unit.trim() {
        "ms" => 1.0,
        "s" => 1000.0,
        "m" | "min" => 60_000.0,
        "h" => 3_600_000.0,
        _ => return Err(format!("`{text}` is not a duration: its unit must be ms, s, min or h")),
    };
    let ms = n * scale;
    if !(0.0..=UNTIL_MAX_MS as f64).contains(&ms) {
        return Err(format!("`{text}` is longer than a week"));
    }
    Ok(ms.round() as u64)
}

/// What a scenario's sections are checked against: the chart, and the names of the scenario's agents.
pub(super) struct Against<'a> {
    pub(super) program: &'a Program,
    pub(super) layout: &'a Layout,
    pub(super) agents: Vec<String>,
}

pub(super) struct Ctx<'a> {
    lines: LineIndex<'a>,
    errors: Vec<ScenarioError>,
}

impl Ctx<'_> {
    pub(super) fn at(&self, span: &Range<usize>) -> (usize, usize) {
        self.lines.line_col(span.start as u32)
    }

    pub(super) fn error(&mut self, span: &Range<usize>, message: impl Into<String>) {
        let (line, col) = self.at(span);
        self.errors.push(ScenarioError { line, col, message: message.into() });
    }

    fn duration(&mut self, s: &Spanned<String>) -> u64 {
        match parse_duration(s.get_ref()) {
            Ok(ms) => ms,
            Err(e) => {
                self.error(&s.span(), e);
                0
            }
        }
    }

    pub(super) fn opt_duration(&mut self, s: &Option<Spanned<String>>) -> Option<u64> {
        s.as_ref().map(|s| self.duration(s))
    }

    fn cond(&mut self, s: &Spanned<String>, program: &Program, agents: &[String]) -> Option<Cond> {
        match Cond::parse(s.get_ref(), program, agents) {
            Ok(c) => Some(c),
            Err(e) => {
                self.error(&s.span(), e);
                None
            }
        }
    }

    /// The faults of `[network]`, or of a `link` fault: the same four keys.
    fn net_faults(
        &mut self,
        delay: &Option<Spanned<String>>,
        drop: &Option<Spanned<f64>>,
        duplicate: &Option<Spanned<f64>>,
        reorder: Option<bool>,
    ) -> NetFaults {
        NetFaults {
            delay_ms: self.opt_duration(delay).unwrap_or(0),
            drop: self.probability(drop),
            duplicate: self.probability(duplicate),
            reorder: reorder.unwrap_or(false),
        }
    }

    fn probability(&mut self, p: &Option<Spanned<f64>>) -> f64 {
        match p {
            Some(p) if !(0.0..=1.0).contains(p.get_ref()) => {
                self.error(&p.span(), format!("a probability is from 0 to 1, not {}", p.get_ref()));
                0.0
            }
            Some(p) => *p.get_ref(),
            None => 0.0,
        }
    }
}

/// A TOML value as the scenario wrote it.
pub fn show_toml(v: &toml::Value) -> String {
    match v {
        toml::Value::String(s) => format!("{s:?}"),
        toml::Value::Integer(i) => i.to_string(),
        toml::Value::Float(f) => f.to_string(),
        toml::Value::Boolean(b) => b.to_string(),
        toml::Value::Datetime(d) => format!("{d:?}"),
        toml::Value::Array(a) => format!("[{}]", a.iter().map(show_toml).collect::<Vec<_>>().join(", ")),
        toml::Value::Table(_) => "a table".to_string(),
    }
}

/// A TOML value as `baton set` takes it.
fn to_json(v: &toml::Value) -> Option<serde_json::Value> {
    Some(match v {
        toml::Value::Boolean(b) => serde_json::Value::Bool(*b),
        toml::Value::Integer(i) => serde_json::json!(i),
        toml::Value::Float(f) => serde_json::json!(f),
        toml::Value::String(s) => serde_json::Value::String(s.clone()),
        _ => return None,
    })
}

/// A TOML value as a value of a chart variable of type `ty`: a TIME is written as a duration (`"2s"`).
pub fn chart_value(v: &toml::Value, ty: &crate::types::Type) -> Result<crate::types::Value, String> {
    use crate::types::{Type, Value};
    let value = match v {
        toml::Value::Boolean(b) => Value::Bool(*b),
        toml::Value::Integer(i) => Value::Int(*i),
        toml::Value::Float(f) => Value::Real(*f),
        toml::Value::String(s) if matches!(ty, Type::Time) => Value::Time(parse_duration(s)? as i64),
        toml::Value::String(s) => Value::string(s.as_str()),
        other => return Err(format!("{} is not a value a chart variable takes", show_toml(other))),
    };
    let value = ty.coerce(value);
    if ty.fits(&value) {
        Ok(value)
    } else {
        Err(format!("{} is not a value of the variable's type", show_toml(v)))
    }
}

fn one_of<'a>(what: &str, present: &[(&'a str, bool)]) -> Result<&'a str, String> {
    let set: Vec<&str> = present.iter().filter(|(_, p)| *p).map(|(k, _)| *k).collect();
    let keys: Vec<&str> = present.iter().map(|(k, _)| *k).collect();
    match set[..] {
        [one] => Ok(one),
        [] => Err(format!("{what} needs one of: {}", keys.join(", "))),
        _ => Err(format!("{what} takes one of {}, not several ({})", keys.join(", "), set.join(", "))),
    }
}

/// How a host reads a file for the loader: proto never touches one itself.
pub type ReadFile<'r> = &'r dyn Fn(&Path) -> std::io::Result<String>;

/// Reads (with `read`) and checks the scenario at `path`.
pub fn load(path: &Path, read: ReadFile) -> Result<Scenario, LoadError> {
    let text = read(path).map_err(|e| LoadError::CannotRun(format!("cannot read {}: {e}", path.display())))?;
    parse(path, &text, read)
}

/// The scenario's chart, read relative to it (so that a folder of both can go anywhere), checked, and the one it
/// names (`pou`) picked: its path, program, layout and hash.
fn chart(
    cx: &mut Ctx,
    path: &Path,
    raw: &RawScenario,
    read: ReadFile,
) -> Result<(PathBuf, Arc<Program>, Arc<Layout>, ChartHash), LoadError> {
    let base = path.parent().unwrap_or(Path::new("."));
    let chart_path = base.join(raw.chart.get_ref());
    let source = match read(&chart_path) {
        Ok(s) => s,
        Err(e) => {
            let (line, col) = cx.at(&raw.chart.span());
            return Err(LoadError::CannotRun(format!(
                "{}:{line}:{col}: cannot read the chart {}: {e}",
                path.display(),
                chart_path.display()
            )));
        }
    };
    let mut report = check_source(&source);
    let index = LineIndex::new(&source);
    let errors: Vec<String> = report
        .diagnostics
        .iter()
        .filter(|d| d.is_error())
        .map(|d| index.render(&chart_path.display().to_string(), d))
        .collect();
    let names: Vec<String> = report.charts.iter().map(|c| c.chart.name.name.clone()).collect();
    let pick = match &raw.pou {
        Some(p) => match names.iter().position(|n| n.eq_ignore_ascii_case(p.get_ref())) {
            Some(i) => i,
            None => {
                cx.error(
                    &p.span(),
                    format!(
                        "no chart named `{}` in {} (it has: {})",
                        p.get_ref(),
                        chart_path.display(),
                        names.join(", ")
                    ),
                );
                return Err(LoadError::Malformed(std::mem::take(&mut cx.errors)));
            }
        },
        None if names.len() == 1 => 0,
        None if names.is_empty() => {
            return Err(LoadError::CannotRun(format!("{} has no chart:\n{}", chart_path.display(), errors.join("\n"))))
        }
        None => {
            cx.error(
                &raw.chart.span(),
                format!("{} holds several charts ({}): choose one with `pou`", chart_path.display(), names.join(", ")),
            );
            return Err(LoadError::Malformed(std::mem::take(&mut cx.errors)));
        }
    };
    let checked = report.charts.remove(pick);
    let (Some(program), Some(layout)) = (checked.program, checked.layout) else {
        return Err(LoadError::CannotRun(format!(
            "the chart {} has errors (see `baton check`):\n{}",
            chart_path.display(),
            errors.join("\n")
        )));
    };
    let program = Arc::new(program);
    let layout = Arc::new(layout);
    let hash = ChartHash::of(&source, &program.name);
    Ok((chart_path, program, layout, hash))
}

/// Checks the scenario `text`, read from `path`; its chart, relative to it, is read with `read`.
pub fn parse(path: &Path, text: &str, read: ReadFile) -> Result<Scenario, LoadError> {
    let mut cx = Ctx { lines: LineIndex::new(text), errors: Vec::new() };
    let raw: RawScenario = match toml::from_str(text) {
        Ok(r) => r,
        Err(e) => {
            let span = e.span().unwrap_or(0..0);
            cx.error(&span, e.message().trim().to_string());
            return Err(LoadError::Malformed(cx.errors));
        }
    };
    let (chart_path, program, layout, hash) = chart(&mut cx, path, &raw, read)?;

    let until_ms = match &raw.until {
        Some(u) => cx.duration(u).max(1),
        None => UNTIL_DEFAULT_MS,
    };
    let loss_policy = match raw.run.on_agent_loss.as_ref().map(|s| (s.get_ref().as_str(), s.span())) {
        None | Some(("pause", _)) => LossPolicy::Pause,
        Some(("reassign", _)) => LossPolicy::Reassign,
        Some(("fail", _)) => LossPolicy::Fail,
        Some((other, span)) => {
            cx.error(&span, format!("`on_agent_loss` is pause, reassign or fail, not `{other}`"));
            LossPolicy::Pause
        }
    };
    let cycle_ms = match &raw.run.cycle_ms {
        Some(c) if !(1..=60_000).contains(c.get_ref()) => {
            cx.error(&c.span(), format!("`cycle_ms` is from 1 to 60000, not {}", c.get_ref()));
            crate::testing::simulated_cluster::CYCLE_MS
        }
        Some(c) => *c.get_ref(),
        None => crate::testing::simulated_cluster::CYCLE_MS,
    };
    let journal = raw.run.journal.unwrap_or(true);
    let stay = raw.run.stay.unwrap_or(false);
    let n = &raw.network;
    let network = cx.net_faults(&n.delay, &n.drop, &n.duplicate, n.reorder);

    let agents = cx.agents(&raw.agents);
    let agent_names: Vec<String> = agents.iter().map(|a| a.name.clone()).collect();
    let scenario_span = 0..0;
    if agents.is_empty() && layout.placement.iter().any(|p| *p != crate::cluster::layout::Placement::Coordinator) {
        // Nothing to run the distributed steps on: said once, at the top.
        cx.error(&scenario_span, "the chart places steps on agents, and the scenario declares none: add `[[agents]]`");
    }
    let against = Against { program: &program, layout: &layout, agents: agent_names };

    let behaviours = cx.behaviours(&against, &raw.actions);
    // A skill the chart binds must be built in or simulated here, or a misspelt name would pass and wait on a robot.
    let listed = |skill: &str| agents.iter().any(|a| a.skills.as_ref().is_some_and(|s| s.contains(skill)));
    let simulated = |i: usize, skill: &str| behaviours.contains_key(&i) || listed(skill);
    for message in crate::cluster::skills::not_built_in(&program, &layout, simulated) {
        cx.error(&raw.chart.span(), message);
    }

    let inputs = cx.inputs(&against, &raw.inputs);
    let faults = cx.faults(&against, &raw.faults, journal);
    let commands = cx.commands(&against, &raw.commands, stay);

    let expects = cx.expects(&against, &raw.expect);
    if expects.is_empty() && cx.errors.is_empty() {
        cx.error(&(0..0), "the scenario expects nothing: add `[[expect]]` tables");
    }
    if !cx.errors.is_empty() {
        cx.errors.sort_by_key(|e| (e.line, e.col));
        return Err(LoadError::Malformed(cx.errors));
    }
    let name = raw.name.unwrap_or_else(|| {
        let file = path.file_name().map(|f| f.to_string_lossy().to_string()).unwrap_or_default();
        file.split(".test.").next().unwrap_or(&file).to_string()
    });
    Ok(Scenario {
        path: path.to_path_buf(),
        name,
        chart_path,
        program,
        layout,
        hash,
        until_ms,
        seed: raw.seed.unwrap_or(1),
        loss_policy,
        journal,
        stay,
        cycle_ms,
        network,
        agents,
        behaviours,
        inputs,
        faults,
        commands,
        expects,
    })
}
