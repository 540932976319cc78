//! Runs a scenario on the simulated cell (`crate::testing::simulated_cluster`): the real coordinator and agent state
//! machines and the real engine, on virtual time, from one seed — then judges every expectation.
//!
//! The seed decides everything random: durations within their ranges, `fault_rate`, the network's losses,
//! duplicates, delays and order, and how late each fault with a `jitter` strikes. The same scenario and seed
//! give the same run, so a failure found among many seeds is replayed by its seed alone.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};

use super::cond::View;
use super::scenario::{chart_value, show_ms, Behaviour, ExpectKind, FaultKind, NetFaults, RunState, Scenario, Trigger};
use crate::exec::program::VarId;
use crate::exec::trace::{TraceEvent, TraceRecord};
use crate::testing::simulated_cluster::{self, Fate, Faults, Rng, SimAgentSpec, SimCluster, SimSkill, SkillStart};
use crate::types::Value;

/// The verdict on one expectation.
#[derive(Clone, Debug)]
pub struct CaseResult {
    pub line: usize,
    pub title: String,
    /// Why it does not hold; `None` when it does.
    pub failure: Option<String>,
    /// When it was seen failing, if at a moment (an invariant broken, a value at a time).
    pub at_ms: Option<u64>,
}

/// Steps active at a moment, and where: (step, agent; `None` on the coordinator).
pub type ActiveSteps = Vec<(String, Option<String>)>;

/// One run of a scenario.
pub struct Outcome {
    pub seed: u64,
    /// The chart time the run reached.
    pub chart_ms: u64,
    pub state: RunState,
    pub cases: Vec<CaseResult>,
    pub trace: Vec<TraceRecord>,
    /// What the simulation could not do as the scenario asked (an input refused…): the scenario could not run.
    pub errors: Vec<String>,
    /// Faults as they struck: (chart time, what).
    pub faults: Vec<(u64, String)>,
    /// The variables at the end, as their types show them.
    pub vars: Vec<(String, String)>,
    /// Steps active at the end, and where.
    pub active: ActiveSteps,
    /// The first failure's moment: the steps active then, and where.
    pub active_at_failure: Option<(u64, ActiveSteps)>,
    /// Where a run of real processes (`baton test --cluster`) left their logs, when it failed.
    pub logs: Option<String>,
}

impl Outcome {
    pub fn passed(&self) -> bool {
        self.errors.is_empty() && self.cases.iter().all(|c| c.failure.is_none())
    }

    /// The trace as lines a user reads, around `t_ms` (`before` records up to it, then a few after).
    pub fn timeline_around(&self, t_ms: u64, before: usize) -> Vec<String> {
        let upto = self.trace.iter().position(|r| r.t_ms > t_ms).unwrap_or(self.trace.len());
        let from = upto.saturating_sub(before);
        let to = (upto + 3).min(self.trace.len());
        self.trace[from..to].iter().map(describe_record).collect()
    }
}

/// `  12.34s  activate Assemble on robot2 (token …, epoch 2): message`.
pub fn describe_record(r: &TraceRecord) -> String {
    let mut line = format!("{:>9}  {} {}", format!("{:.3}s", r.t_ms as f64 / 1000.0), r.event, r.name);
    if let Some(a) = &r.agent {
        line.push_str(&format!(" on {a}"));
    }
    if let Some(e) = r.epoch {
        line.push_str(&format!(" (epoch {e})"));
    }
    if let Some(v) = &r.value {
        line.push_str(&format!(" = {v}"));
    }
    if let Some(m) = &r.message {
        line.push_str(&format!(": {m}"));
    }
    line
}

/// Keeps `active` (step → the agent it runs on, `None` on the coordinator) up to date with a trace record of
/// step `step`.
pub fn follow_steps(active: &mut BTreeMap<usize, Option<String>>, step: usize, r: &TraceRecord) {
    match r.event {
        TraceEvent::Activate => {
            active.insert(step, r.agent.clone());
        }
        TraceEvent::Deactivate => {
            active.remove(&step);
        }
        // A step waiting for an agent is active already; it now runs there.
        TraceEvent::Dispatch if active.contains_key(&step) => {
            active.insert(step, r.agent.clone());
        }
        _ => {}
    }
}

/// The run as conditions see it: the steps active anywhere, and the coordinator's variables.
struct Now<'a> {
    active: &'a BTreeMap<usize, Option<String>>,
    value: &'a dyn Fn(VarId) -> Value,
    state: crate::cluster::runtime::packml::State,
}

impl View for Now<'_> {
    fn step(&self, index: usize) -> Option<Option<&str>> {
        self.active.get(&index).map(|a| a.as_deref())
    }

    fn value(&self, var: VarId) -> Value {
        (self.value)(var)
    }

    fn state(&self) -> Option<crate::cluster::runtime::packml::State> {
        Some(self.state)
    }
}

/// What the observer found due at a moment: `when` faults and inputs whose condition came true, each with its
/// `after` delay (by index in the scenario).
#[derive(Default)]
pub struct Due {
    pub faults: Vec<(usize, u64)>,
    pub inputs: Vec<(usize, u64)>,
    pub commands: Vec<(usize, u64)>,
}

/// Watches a run as it goes, wherever it runs (the simulated cell, or real processes): the steps active and
/// where, from the trace; when each `always`/`never` first broke; the values expected at a time; and which
/// `when` triggers fired. Then judges every expectation.
pub struct Observer<'a> {
    sc: &'a Scenario,
    steps: BTreeMap<String, usize>,
    active: BTreeMap<usize, Option<String>>,
    /// Invariants: expectation index → when first broken.
    broken: BTreeMap<usize, u64>,
    snapshots: BTreeMap<usize, Vec<(String, Value)>>,
    active_at_failure: Option<(u64, ActiveSteps)>,
    fault_fired: Vec<bool>,
    input_fired: Vec<bool>,
    command_fired: Vec<bool>,
    /// The run's PackML state, as its last `state` record said (Execute before any).
    state: crate::cluster::runtime::packml::State,
}

impl<'a> Observer<'a> {
    /// Faults and inputs at a fixed time count as fired: the runner schedules them from the start.
    pub fn new(sc: &'a Scenario) -> Observer<'a> {
        Observer {
            sc,
            steps: sc.program.steps.iter().enumerate().map(|(i, s)| (s.name.clone(), i)).collect(),
            active: BTreeMap::new(),
            broken: BTreeMap::new(),
            snapshots: BTreeMap::new(),
            active_at_failure: None,
            fault_fired: sc.faults.iter().map(|f| matches!(f.trigger, Trigger::At(_))).collect(),
            input_fired: sc.inputs.iter().map(|i| matches!(i.trigger, Trigger::At(_))).collect(),
            command_fired: sc.commands.iter().map(|c| matches!(c.trigger, Trigger::At(_))).collect(),
            state: crate::cluster::runtime::packml::State::Execute,
        }
    }

    /// Follows the steps through new trace records (an agent's steps come with its reports).
    pub fn follow(&mut self, records: &[TraceRecord]) {
        use crate::cluster::runtime::packml::State;
        for r in records {
            match r.event {
                TraceEvent::State => {
                    if let Some(s) = State::ALL.into_iter().find(|s| s.name() == r.name) {
                        self.state = s;
                    }
                    continue;
                }
                // `reset`: the chart starts again, nothing of the old run is active.
                TraceEvent::NewRun => {
                    self.active.clear();
                    continue;
                }
                _ => {}
            }
            if let Some(&i) = self.steps.get(&r.name) {
                follow_steps(&mut self.active, i, r);
            }
        }
    }

    /// Takes the values expected at a time `<= t` not taken yet, with `value` as they are now.
    pub fn snapshot(&mut self, t: u64, value: impl Fn(&str) -> Option<Value>) {
        for (k, e) in self.sc.expects.iter().enumerate() {
            if let ExpectKind::Value { vars, at_ms: Some(at) } = &e.kind {
                if *at <= t && !self.snapshots.contains_key(&k) {
                    let vals = vars.iter().map(|(n, _)| (n.clone(), value(n).unwrap_or(Value::Bool(false)))).collect();
                    self.snapshots.insert(k, vals);
                }
            }
        }
    }

    /// The next time a value is expected at, not taken yet.
    pub fn next_snapshot(&self) -> Option<u64> {
        self.sc
            .expects
            .iter()
            .enumerate()
            .filter_map(|(k, e)| match &e.kind {
                ExpectKind::Value { at_ms: Some(at), .. } if !self.snapshots.contains_key(&k) => Some(*at),
                _ => None,
            })
            .min()
    }

    /// Judges the moment `t` (after everything that happened at it): invariants, and `when` triggers, each of
    /// which fires once.
    pub fn judge(&mut self, t: u64, value: &dyn Fn(VarId) -> Value) -> Due {
        let view = Now { active: &self.active, value, state: self.state };
        let mut due = Due::default();
        for (k, e) in self.sc.expects.iter().enumerate() {
            let holds = match &e.kind {
                ExpectKind::Always(c, _) => c.holds(&view),
                ExpectKind::Never(c, _) => !c.holds(&view),
                _ => true,
            };
            if !holds && !self.broken.contains_key(&k) {
                self.broken.insert(k, t);
                if self.active_at_failure.is_none() {
                    self.active_at_failure = Some((t, show_active(self.sc, &self.active)));
                }
            }
        }
        for (i, f) in self.sc.faults.iter().enumerate() {
            if let (false, Trigger::When { cond, after_ms, .. }) = (self.fault_fired[i], &f.trigger) {
                if cond.holds(&view) {
                    self.fault_fired[i] = true;
                    due.faults.push((i, *after_ms));
                }
            }
        }
        for (i, input) in self.sc.inputs.iter().enumerate() {
            if let (false, Trigger::When { cond, after_ms, .. }) = (self.input_fired[i], &input.trigger) {
                if cond.holds(&view) {
                    self.input_fired[i] = true;
                    due.inputs.push((i, *after_ms));
                }
            }
        }
        for (i, c) in self.sc.commands.iter().enumerate() {
            if let (false, Trigger::When { cond, after_ms, .. }) = (self.command_fired[i], &c.trigger) {
                if cond.holds(&view) {
                    self.command_fired[i] = true;
                    due.commands.push((i, *after_ms));
                }
            }
        }
        due
    }

    /// The steps active now, and where.
    pub fn active(&self) -> ActiveSteps {
        show_active(self.sc, &self.active)
    }

    /// Judges every expectation of a run that reached `chart_ms` in `state`, with `trace` its records and
    /// `final_value` its variables at the end. Returns the verdicts and the first failure's moment.
    pub fn verdicts(
        &self,
        trace: &[TraceRecord],
        state: &RunState,
        chart_ms: u64,
        final_value: &dyn Fn(&str) -> Option<Value>,
    ) -> (Vec<CaseResult>, Option<(u64, ActiveSteps)>) {
        let cases = self
            .sc
            .expects
            .iter()
            .enumerate()
            .map(|(k, e)| self.verdict(k, e, trace, state, chart_ms, final_value))
            .collect();
        (cases, self.active_at_failure.clone())
    }

    fn verdict(
        &self,
        k: usize,
        e: &super::scenario::Expect,
        trace: &[TraceRecord],
        state: &RunState,
        chart_ms: u64,
        final_value: &dyn Fn(&str) -> Option<Value>,
    ) -> CaseResult {
        let sc = self.sc;
        let mut at_ms = None;
        let failure = match &e.kind {
            ExpectKind::Reached { step, on, by_ms } => {
                let (failure, at) = reached(e, trace, step, on.as_deref(), *by_ms);
                at_ms = at;
                failure
            }
            ExpectKind::Order(order) => {
                let mut next = 0;
                let mut last_t = 0;
                for r in trace.iter().filter(|r| r.event == TraceEvent::Activate) {
                    if next < order.len() && r.name == order[next] {
                        next += 1;
                        last_t = r.t_ms;
                    }
                }
                if next == order.len() {
                    None
                } else {
                    at_ms = Some(last_t);
                    let passed = if next == 0 { "none of them".to_string() } else { order[..next].join(", ") };
                    Some(format!(
                        "expected the steps in order {}; passed {passed}, then never {} (at {} or later)",
                        order.join(" → "),
                        order[next],
                        show_ms(last_t)
                    ))
                }
            }
            ExpectKind::Value { vars, at_ms: when } => {
                let mut wrong = Vec::new();
                for (name, expected) in vars {
                    let var = sc.program.var_by_name(name).expect("checked");
                    let ty = &sc.program.vars[var.index()].ty;
                    let actual = match when {
                        Some(_) => self
                            .snapshots
                            .get(&k)
                            .and_then(|s| s.iter().find(|(n, _)| n == name))
                            .map(|(_, v)| v.clone()),
                        None => final_value(name),
                    };
                    let Some(actual) = actual else {
                        wrong.push(format!("{name}: the run ended before {}", show_ms(when.unwrap_or(0))));
                        continue;
                    };
                    match chart_value(expected, ty) {
                        Ok(exp) if values_equal(&actual, &exp) => {}
                        Ok(exp) => wrong.push(format!("{name} = {} (expected {})", ty.show(&actual), ty.show(&exp))),
                        Err(err) => wrong.push(format!("{name}: {err}")),
                    }
                }
                at_ms = *when;
                (!wrong.is_empty()).then(|| {
                    let moment = when.map_or("at the end".to_string(), |t| format!("at {}", show_ms(t)));
                    format!("{moment}: {}", wrong.join(", "))
                })
            }
            ExpectKind::Always(_, text) | ExpectKind::Never(_, text) => self.broken.get(&k).map(|t| {
                at_ms = Some(*t);
                let was = if matches!(e.kind, ExpectKind::Always(..)) { "FALSE" } else { "TRUE" };
                format!("`{text}` was {was} at {}", show_ms(*t))
            }),
            ExpectKind::EndsBy(by) => match state {
                RunState::Finished if chart_ms <= *by => None,
                RunState::Finished => Some(format!("the chart ended at {}, after {}", show_ms(chart_ms), show_ms(*by))),
                RunState::Failed => Some(format!("the run failed at {}", show_ms(chart_ms))),
                RunState::Running => Some(format!("the chart had not ended by {}", show_ms(chart_ms))),
                RunState::Stopped | RunState::Aborted => {
                    Some(format!("the run was {} at {}", format!("{state:?}").to_lowercase(), show_ms(chart_ms)))
                }
            },
            ExpectKind::Alarms(expected) => alarms_failure(expected, trace),
            ExpectKind::State(expected) => (expected != state).then(|| {
                format!(
                    "expected the run to end {}; it {}",
                    format!("{expected:?}").to_lowercase(),
                    match state {
                        RunState::Finished => format!("finished at {}", show_ms(chart_ms)),
                        RunState::Failed => format!("failed at {}", show_ms(chart_ms)),
                        RunState::Running => format!("was still running at {}", show_ms(chart_ms)),
                        RunState::Stopped => format!("was stopped at {}", show_ms(chart_ms)),
                        RunState::Aborted => format!("was aborted at {}", show_ms(chart_ms)),
                    }
                )
            }),
            ExpectKind::States(expected) | ExpectKind::Modes(expected) => {
                let event = if matches!(e.kind, ExpectKind::States(_)) { TraceEvent::State } else { TraceEvent::Mode };
                let seen: Vec<&str> = trace.iter().filter(|r| r.event == event).map(|r| r.name.as_str()).collect();
                let mut rest = seen.iter();
                let missing = expected.iter().find(|want| !rest.any(|s| s == want));
                missing.map(|m| {
                    let seen = if seen.is_empty() { "none".to_string() } else { seen.join(", ") };
                    let what = if event == TraceEvent::State { "states" } else { "modes" };
                    format!("never reached `{m}` in that order; the {what} the run passed: {seen}")
                })
            }
            ExpectKind::OncePerEpoch(action) => runs_twice(trace, action).map(|(t, why)| {
                at_ms = Some(t);
                why
            }),
        };
        CaseResult { line: e.line, title: e.title(), failure, at_ms }
    }
}

fn show_active(sc: &Scenario, active: &BTreeMap<usize, Option<String>>) -> ActiveSteps {
    let mut v: ActiveSteps = active.iter().map(|(i, a)| (sc.program.steps[*i].name.clone(), a.clone())).collect();
    v.sort();
    v
}

/// How late a fault with a `jitter` strikes, drawn from the faults' own stream.
pub fn jitter(f: &super::scenario::Fault, rng: &mut Rng) -> u64 {
    if f.jitter_ms > 0 {
        rng.next_u64() % (f.jitter_ms + 1)
    } else {
        0
    }
}

/// The stream faults' jitters draw from, for `seed`.
pub fn fault_rng(seed: u64) -> Rng {
    Rng::new(seed, 0xD1B5_4A32_D192_ED03)
}

fn net(n: NetFaults) -> Faults {
    Faults { duplicate: n.duplicate, reorder: n.reorder, delay_ms_max: n.delay_ms, loss: n.drop }
}

/// Makes a fault happen at `t`.
fn strike(sim: &mut SimCluster, kind: &FaultKind, t: u64) {
    match kind {
        FaultKind::Kill(a) => sim.fate_at(t, a, Fate::Kill),
        FaultKind::Restart(a) => sim.fate_at(t, a, Fate::Restart),
        FaultKind::Cut(a, heal) => {
            sim.fate_at(t, a, Fate::Cut);
            if let Some(h) = heal {
                sim.fate_at(t + h, a, Fate::Heal);
            }
        }
        FaultKind::Heal(a) => sim.fate_at(t, a, Fate::Heal),
        FaultKind::Link(a, f, lasting) => sim.link_faults_at(t, t + lasting, a, net(*f)),
        FaultKind::CrashCoordinator(down) => sim.crash_coordinator_at(t, *down),
    }
}

/// What the simulated skills do: the scenario's behaviour for their action, else the `motion` parameters. The
/// simulated cell uses it, and so does `baton-agent --simulate`, in real time.
pub fn skill_model(sc: &Scenario) -> crate::testing::simulated_cluster::SkillModel {
    let behaviours: BTreeMap<String, Behaviour> =
        sc.behaviours.iter().map(|(i, b)| (sc.program.actions[*i].name.clone(), b.clone())).collect();
    let provides: BTreeMap<String, Option<std::collections::BTreeSet<String>>> =
        sc.agents.iter().map(|a| (a.name.clone(), a.skills.clone())).collect();
    let mut runs: BTreeMap<String, usize> = BTreeMap::new();
    Box::new(move |s: SkillStart<'_>| {
        if let Some(Some(skills)) = provides.get(s.agent) {
            if !skills.contains(&s.binding.skill) {
                let have: Vec<&str> = skills.iter().map(String::as_str).collect();
                return SimSkill::Finish {
                    after_ms: 0,
                    result: Err(format!("unknown skill `{}` (this agent has: {})", s.binding.skill, have.join(", "))),
                    writes: Vec::new(),
                };
            }
        }
        let n = runs.entry(s.action.to_string()).or_insert(0);
        let nth = *n;
        *n += 1;
        // What the scenario does not say, the `motion` parameters decide, as in `baton run`'s demo.
        let Some(b) = behaviours.get(s.action) else { return simulated_cluster::motion(s.binding, s.random) };
        if b.hang {
            return SimSkill::Hang;
        }
        let after_ms = match b.duration {
            Some((lo, hi)) => lo + s.random % (hi - lo + 1),
            None => simulated_cluster::motion_ms(s.binding),
        };
        let message = || b.message.clone().unwrap_or_else(|| "simulated fault".to_string());
        let result = match b.outcomes.as_slice() {
            [] => simulated_cluster::motion_result(s.binding, s.random).map_err(|_| message()),
            o if o[nth.min(o.len() - 1)] => Ok(()),
            _ => Err(message()),
        };
        SimSkill::Finish { after_ms, result, writes: b.writes.clone() }
    })
}

fn values_equal(actual: &Value, expected: &Value) -> bool {
    match (actual, expected) {
        // Infinities equal themselves, and a NaN expected is a NaN found (`value = { r = nan }`).
        (Value::Real(a), Value::Real(b)) if !a.is_finite() || !b.is_finite() => a == b || (a.is_nan() && b.is_nan()),
        (Value::Real(a), Value::Real(b)) => (a - b).abs() <= 1e-6 * a.abs().max(b.abs()).max(1.0),
        (a, b) => a == b,
    }
}

/// Runs `sc` with `seed` and judges it.
pub fn run(sc: &Scenario, seed: u64) -> Outcome {
    run_until(sc, seed, &AtomicBool::new(false))
}

/// Runs `sc` with `seed` and judges it, unless `stop` is set meanwhile (an interrupt, a time limit): the run
/// then ends where it is, with an error that says so.
pub fn run_until(sc: &Scenario, seed: u64, stop: &AtomicBool) -> Outcome {
    let agents: Vec<SimAgentSpec> = sc
        .agents
        .iter()
        .map(|a| SimAgentSpec {
            name: a.name.clone(),
            roles: a.roles.clone(),
            start_ms: a.start_ms,
            skills: a.skills.as_ref().map(|s| s.iter().cloned().collect()),
        })
        .collect();
    let mut sim = SimCluster::with_program(
        sc.program.clone(),
        sc.layout.clone(),
        sc.hash.clone(),
        &agents,
        net(sc.network),
        seed,
        sc.cycle_ms,
    );
    sim.set_loss_policy(sc.loss_policy);
    if sc.stay {
        sim.set_stay();
    }
    sim.set_skill_model(skill_model(sc));
    let mut rng = fault_rng(seed);
    let mut struck: Vec<(u64, String)> = Vec::new();
    for f in &sc.faults {
        if let Trigger::At(t) = f.trigger {
            let at = t + jitter(f, &mut rng);
            strike(&mut sim, &f.kind, at);
            struck.push((at, f.describe()));
        }
    }
    for input in &sc.inputs {
        if let Trigger::At(t) = input.trigger {
            for (name, v) in &input.set {
                sim.set_at(t, name, v.clone());
            }
        }
    }
    for c in &sc.commands {
        if let Trigger::At(t) = c.trigger {
            sim.command_at(t, c.request.clone());
        }
    }
    let mut obs = Observer::new(sc);
    let mut seen = 0usize;
    let mut stopped = false;
    let ended = loop {
        if sim.now_ms > sc.until_ms {
            break None;
        }
        if stop.load(Ordering::Relaxed) {
            stopped = true;
            break None;
        }
        let t = sim.now_ms;
        let over = sim.tick();
        obs.follow(&sim.trace[seen.min(sim.trace.len())..]);
        seen = sim.trace.len();
        obs.snapshot(t, |n| sim.value(n));
        // Only moments when something happened are ticked (idle time is skipped below): judge each.
        let due = obs.judge(t, &|v| sim.coordinator.core().value(v));
        for (i, after) in due.faults {
            let f = &sc.faults[i];
            let at = sim.now_ms + after + jitter(f, &mut rng);
            strike(&mut sim, &f.kind, at);
            struck.push((at, f.describe()));
        }
        for (i, after) in due.inputs {
            for (name, v) in &sc.inputs[i].set {
                sim.set_at(sim.now_ms + after, name, v.clone());
            }
        }
        for (i, after) in due.commands {
            sim.command_at(sim.now_ms + after, sc.commands[i].request.clone());
        }
        // A run that stays at its end goes on while an operator's command is still to come.
        if let Some(finished) = over.filter(|_| !(sc.stay && sim.commands_pending())) {
            break Some(finished);
        }
        // Jump over idle time, but not past a moment a value is expected at, nor the end.
        let limit = obs.next_snapshot().unwrap_or(u64::MAX).min(sc.until_ms + 1);
        sim.skip_idle(limit);
    };
    let by_operator = match sim.coordinator.core().run_state() {
        crate::cluster::runtime::packml::State::Stopped => Some(RunState::Stopped),
        crate::cluster::runtime::packml::State::Aborted => Some(RunState::Aborted),
        _ => None,
    };
    let state = match ended {
        Some(true) if by_operator.is_some() => by_operator.unwrap_or(RunState::Finished),
        Some(true) => RunState::Finished,
        Some(false) => RunState::Failed,
        None => RunState::Running,
    };
    let chart_ms = sim.now_ms.min(sc.until_ms);
    let mut errors = sim.errors.clone();
    if stopped {
        errors.push(format!("stopped at chart time {}, before the run ended", show_ms(sim.now_ms)));
    }
    errors.extend(sim.violations.iter().map(|v| format!("the runtime broke its promise: {v}")));
    let trace = sim.trace.clone();
    struck.sort();
    struck.retain(|(t, _)| *t <= chart_ms);
    let (cases, active_at_failure) = obs.verdicts(&trace, &state, chart_ms, &|name| sim.value(name));
    let mut vars: Vec<(String, String)> = sc
        .program
        .vars
        .iter()
        .filter(|v| !v.hidden)
        .filter_map(|v| sim.shown(&v.name).map(|s| (v.name.clone(), s)))
        .collect();
    vars.sort();
    let active = obs.active();
    Outcome { seed, chart_ms, state, cases, trace, errors, faults: struck, vars, active, active_at_failure, logs: None }
}

fn quoted(items: &[&String]) -> String {
    items.iter().map(|s| format!("`{s}`")).collect::<Vec<_>>().join(", ")
}

/// `reached`: where the step ran — where it was activated, or dispatched to once an agent could take it — against
/// where and by when it was expected; the failure, and when the step was first reached.
fn reached(
    e: &super::scenario::Expect,
    trace: &[TraceRecord],
    step: &str,
    on: Option<&str>,
    by_ms: Option<u64>,
) -> (Option<String>, Option<u64>) {
    // Where a step ran: where it was activated, or dispatched to once an agent could take it.
    let hits: Vec<&TraceRecord> = trace
        .iter()
        .filter(|r| {
            r.name == step
                && (r.event == TraceEvent::Activate || (r.event == TraceEvent::Dispatch && r.agent.is_some()))
        })
        .collect();
    let fits = |r: &&TraceRecord| on.is_none_or(|a| r.agent.as_deref() == Some(a)) && by_ms.is_none_or(|t| r.t_ms <= t);
    if hits.iter().any(fits) {
        (None, None)
    } else if let Some(first) = hits.first() {
        let mut wheres: Vec<String> = hits
            .iter()
            .map(|r| format!("at {} on {}", show_ms(r.t_ms), r.agent.as_deref().unwrap_or("the coordinator")))
            .collect();
        wheres.dedup();
        wheres.truncate(5);
        (Some(format!("expected {}; it was reached {}", e.title(), wheres.join(", "))), Some(first.t_ms))
    } else {
        (Some(format!("expected {}; it was never active", e.title())), None)
    }
}

/// `alarms`: every alarm expected raised (a part of its message), and none other.
fn alarms_failure(expected: &[String], trace: &[TraceRecord]) -> Option<String> {
    let alarms: Vec<String> =
        trace.iter().filter(|r| r.event == TraceEvent::Alarm).map(|r| r.message.clone().unwrap_or_default()).collect();
    let missing: Vec<&String> = expected.iter().filter(|x| !alarms.iter().any(|a| a.contains(x.as_str()))).collect();
    let extra: Vec<&String> = alarms.iter().filter(|a| !expected.iter().any(|x| a.contains(x.as_str()))).collect();
    match (missing.is_empty(), extra.is_empty()) {
        (true, true) => None,
        _ => {
            let mut parts = Vec::new();
            if !missing.is_empty() {
                parts.push(format!("never raised: {}", quoted(&missing)));
            }
            if !extra.is_empty() {
                parts.push(format!("raised but not expected: {}", quoted(&extra)));
            }
            Some(parts.join("; "))
        }
    }
}

/// The first time the skill of `action` ran twice in one run of its segment (one token's epoch): on two agents,
/// or twice at once on one. `None` when it never did.
pub fn runs_twice(trace: &[TraceRecord], action: &str) -> Option<(u64, String)> {
    let mut on: BTreeMap<(String, u32), Vec<String>> = BTreeMap::new();
    let mut running: BTreeMap<(String, u32, String), bool> = BTreeMap::new();
    for r in trace.iter().filter(|r| r.name == action) {
        let (Some(tok), Some(ep), Some(agent)) = (&r.token, r.epoch, &r.agent) else { continue };
        match r.event {
            TraceEvent::ActionOn => {
                let agents = on.entry((tok.clone(), ep)).or_default();
                if !agents.contains(agent) {
                    agents.push(agent.clone());
                }
                let twice = std::mem::replace(running.entry((tok.clone(), ep, agent.clone())).or_default(), true);
                if agents.len() > 1 || twice {
                    let where_ = if twice {
                        format!("twice at once on {agent}")
                    } else {
                        format!("on {}", agents.join(" and "))
                    };
                    let why = format!(
                        "the skill of {action} ran {where_} in epoch {ep} of token {tok}, at {}",
                        show_ms(r.t_ms)
                    );
                    return Some((r.t_ms, why));
                }
            }
            TraceEvent::ActionOff => {
                running.insert((tok.clone(), ep, agent.clone()), false);
            }
            _ => {}
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rec(t: u64, event: TraceEvent, agent: &str, epoch: u32) -> TraceRecord {
        let mut r = TraceRecord::new(t, event, "Weld");
        r.agent = Some(agent.into());
        r.token = Some("t1".into());
        r.epoch = Some(epoch);
        r
    }

    #[test]
    fn a_skill_run_twice_in_an_epoch_is_found() {
        // A segment run again in a new epoch, on another agent, is what `reassign` does: fine.
        let fine = [
            rec(0, TraceEvent::ActionOn, "a", 1),
            rec(5, TraceEvent::ActionOn, "b", 2),
            rec(9, TraceEvent::ActionOff, "b", 2),
        ];
        assert_eq!(runs_twice(&fine, "Weld"), None);
        // A loop in the segment runs the skill again after it ended: fine too.
        let again = [
            rec(0, TraceEvent::ActionOn, "a", 1),
            rec(3, TraceEvent::ActionOff, "a", 1),
            rec(4, TraceEvent::ActionOn, "a", 1),
        ];
        assert_eq!(runs_twice(&again, "Weld"), None);
        let two_agents = [rec(0, TraceEvent::ActionOn, "a", 1), rec(7, TraceEvent::ActionOn, "b", 1)];
        let (t, why) = runs_twice(&two_agents, "Weld").expect("found");
        assert_eq!(t, 7);
        assert!(why.contains("ran on a and b in epoch 1 of token t1"), "{why}");
        let at_once = [rec(0, TraceEvent::ActionOn, "a", 1), rec(2, TraceEvent::ActionOn, "a", 1)];
        assert!(runs_twice(&at_once, "Weld").expect("found").1.contains("twice at once on a"));
    }
}
