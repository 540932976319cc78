//! The sections of a scenario file checked against the chart and its agents (`parse` calls them in turn): the
//! agents, the actions' simulated behaviour, the inputs, the faults and the expectations. Each reports what is
//! wrong through the `Ctx` and keeps what is right.

use std::collections::BTreeMap;
use std::ops::Range;

use toml::Spanned;

use super::raw::{RawAction, RawAgent, RawExpect, RawFault, RawInput};
use super::{
    chart_value, one_of, parse_duration, show_toml, to_json, Against, Agent, Behaviour, Ctx, Expect, ExpectKind, Fault,
    FaultKind, Input, RunState, Trigger,
};

impl Ctx<'_> {
    /// An error unless the scenario declares agent `name`.
    pub(super) fn agent_known(&mut self, against: &Against, span: &Range<usize>, name: &str) {
        if !against.agents.iter().any(|a| a == name) {
            self.error(
                span,
                format!("no agent named `{name}` in the scenario (it has: {})", against.agents.join(", ")),
            );
        }
    }

    /// The chart's name for step `name`, or an error.
    fn step_known(&mut self, against: &Against, span: &Range<usize>, name: &str) -> Option<String> {
        match against.program.steps.iter().find(|s| s.name.eq_ignore_ascii_case(name)) {
            Some(s) => Some(s.name.clone()),
            None => {
                self.error(span, super::super::cond::no_step(against.program, name));
                None
            }
        }
    }

    /// When an input, a fault or a command happens: `at` a time, or `when` a condition holds (`after` a delay).
    pub(super) fn trigger(
        &mut self,
        against: &Against,
        what: &str,
        span: &Range<usize>,
        at: &Option<Spanned<String>>,
        when: &Option<Spanned<String>>,
        after: &Option<Spanned<String>>,
    ) -> Option<Trigger> {
        match (at, when) {
            (Some(at), None) => {
                if after.is_some() {
                    self.error(span, format!("{what}: `after` goes with `when`"));
                }
                Some(Trigger::At(self.duration(at)))
            }
            (None, Some(w)) => {
                let cond = self.cond(w, against.program, &against.agents)?;
                Some(Trigger::When { cond, text: w.get_ref().clone(), after_ms: self.opt_duration(after).unwrap_or(0) })
            }
            (None, None) => {
                self.error(span, format!("{what} needs `at = \"2s\"` or `when = \"step Load active\"`"));
                None
            }
            (Some(_), Some(_)) => {
                self.error(span, format!("{what} takes `at` or `when`, not both"));
                None
            }
        }
    }

    /// `[[agents]]`.
    pub(super) fn agents(&mut self, raw: &[Spanned<RawAgent>]) -> Vec<Agent> {
        let cx = self;
        let mut agents: Vec<Agent> = Vec::new();
        for a in raw {
            let span = a.span();
            let a = a.get_ref();
            if agents.iter().any(|b| b.name == a.name) {
                cx.error(&span, format!("agent `{}` is declared twice", a.name));
                continue;
            }
            if a.name.is_empty() || !a.name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-') {
                cx.error(&span, format!("agent name `{}` must be letters, digits, `_` or `-`", a.name));
            }
            let start_ms = cx.opt_duration(&a.start).unwrap_or(0);
            agents.push(Agent {
                name: a.name.clone(),
                roles: a.roles.clone(),
                start_ms,
                skills: a.skills.as_ref().map(|s| s.iter().cloned().collect()),
            });
        }
        agents
    }

    /// `[actions.NAME]`: how the skills of the chart's actions behave in the simulation.
    pub(super) fn behaviours(
        &mut self,
        against: &Against,
        raw: &BTreeMap<String, Spanned<RawAction>>,
    ) -> BTreeMap<usize, Behaviour> {
        let cx = self;
        let mut behaviours = BTreeMap::new();
        for (name, b) in raw {
            let span = b.span();
            let Some(index) = against.program.actions.iter().position(|a| a.name.eq_ignore_ascii_case(name)) else {
                let all: Vec<&str> = against.program.actions.iter().map(|a| a.name.as_str()).collect();
                cx.error(&span, format!("the chart has no action `{name}` (it has: {})", all.join(", ")));
                continue;
            };
            let Some(binding) = against.layout.skills[index].as_ref() else {
                cx.error(
                    &span,
                    format!("action `{name}` binds no skill: only skills are simulated (its body runs as written)"),
                );
                continue;
            };
            let b = b.get_ref();
            let duration = b.duration.as_ref().and_then(|d| cx.duration_range(d));
            let mut outcomes = Vec::new();
            for o in b.outcomes.iter().flatten() {
                match o.get_ref().as_str() {
                    "done" => outcomes.push(true),
                    "fault" => outcomes.push(false),
                    other => cx.error(&o.span(), format!("an outcome is \"done\" or \"fault\", not \"{other}\"")),
                }
            }
            let mut writes = Vec::new();
            for (var, value) in &b.writes {
                let outputs = &binding.outputs;
                let Some(k) =
                    outputs.iter().position(|o| against.program.vars[o.var.index()].name.eq_ignore_ascii_case(var))
                else {
                    let mapped: Vec<&str> =
                        outputs.iter().map(|o| against.program.vars[o.var.index()].name.as_str()).collect();
                    cx.error(
                        &span,
                        format!(
                            "the skill of `{name}` maps no variable `{var}` (its mappings write: {}): a skill writes only what its action maps",
                            if mapped.is_empty() { "none".to_string() } else { mapped.join(", ") }
                        ),
                    );
                    continue;
                };
                match chart_value(value, &against.program.vars[outputs[k].var.index()].ty) {
                    Ok(v) => writes.push((k, v)),
                    Err(e) => cx.error(&span, format!("`{var}`: {e}")),
                }
            }
            behaviours
                .insert(index, Behaviour { duration, outcomes, hang: b.hang, message: b.message.clone(), writes });
        }
        behaviours
    }

    /// A skill's `duration`: one (`"2s"`) or a range (`["1s", "3s"]`), as (shortest, longest).
    fn duration_range(&mut self, d: &Spanned<toml::Value>) -> Option<(u64, u64)> {
        let cx = self;
        match d.get_ref() {
            toml::Value::String(s) => match parse_duration(s) {
                Ok(ms) => Some((ms, ms)),
                Err(e) => {
                    cx.error(&d.span(), e);
                    None
                }
            },
            toml::Value::Array(range) if range.len() == 2 => {
                let ends: Vec<Result<u64, String>> = range
                    .iter()
                    .map(|v| v.as_str().ok_or("a duration is a string: `\"2s\"`".to_string()).and_then(parse_duration))
                    .collect();
                match (&ends[0], &ends[1]) {
                    (Ok(lo), Ok(hi)) if lo <= hi => Some((*lo, *hi)),
                    (Ok(_), Ok(_)) => {
                        cx.error(&d.span(), "a duration range is [shortest, longest]");
                        None
                    }
                    (Err(e), _) | (_, Err(e)) => {
                        cx.error(&d.span(), e.clone());
                        None
                    }
                }
            }
            _ => {
                cx.error(&d.span(), "`duration` is a duration (`\"2s\"`) or a range (`[\"1s\", \"3s\"]`)");
                None
            }
        }
    }

    /// `[[inputs]]`.
    pub(super) fn inputs(&mut self, against: &Against, raw: &[Spanned<RawInput>]) -> Vec<Input> {
        let cx = self;
        let mut inputs = Vec::new();
        for i in raw {
            let span = i.span();
            let raw_input = i.get_ref();
            let Some(trigger) =
                cx.trigger(against, "an input", &span, &raw_input.at, &raw_input.when, &raw_input.after)
            else {
                continue;
            };
            let mut set = Vec::new();
            for (name, value) in &raw_input.set {
                let Some(var) = against.program.var_by_name(name) else {
                    cx.error(&span, format!("the chart has no variable `{name}`"));
                    continue;
                };
                if !against.layout.settable[var.index()] {
                    cx.error(
                        &span,
                        format!("`{name}` is written by the chart: only inputs are set, as `baton set` does"),
                    );
                    continue;
                }
                match to_json(value) {
                    Some(v) => set.push((against.program.vars[var.index()].name.clone(), v)),
                    None => cx.error(&span, format!("`{name}`: {} is not a value an input takes", show_toml(value))),
                }
            }
            if set.is_empty() && raw_input.set.is_empty() {
                cx.error(&span, "an input sets something: `set = { start = true }`");
            }
            inputs.push(Input { trigger, set });
        }
        inputs
    }

    /// `[[faults]]`.
    pub(super) fn faults(&mut self, against: &Against, raw: &[Spanned<RawFault>], journal: bool) -> Vec<Fault> {
        let cx = self;
        let mut faults = Vec::new();
        for f in raw {
            let span = f.span();
            let r = f.get_ref();
            let kind = match one_of(
                "a fault",
                &[
                    ("kill", r.kill.is_some()),
                    ("restart", r.restart.is_some()),
                    ("cut", r.cut.is_some()),
                    ("heal", r.heal.is_some()),
                    ("link", r.link.is_some()),
                    ("crash_coordinator", r.crash_coordinator == Some(true)),
                ],
            ) {
                Ok(k) => k,
                Err(e) => {
                    cx.error(&span, e);
                    continue;
                }
            };
            let agent =
                r.kill.as_ref().or(r.restart.as_ref()).or(r.cut.as_ref()).or(r.heal.as_ref()).or(r.link.as_ref());
            if let Some(a) = agent {
                cx.agent_known(against, &span, a);
            }
            let agent = agent.cloned().unwrap_or_default();
            let fault_kind = match kind {
                "kill" => FaultKind::Kill(agent),
                "restart" => FaultKind::Restart(agent),
                "cut" => FaultKind::Cut(agent, cx.opt_duration(&r.heal_after)),
                "heal" => FaultKind::Heal(agent),
                "link" => {
                    let nf = cx.net_faults(&r.delay, &r.drop, &r.duplicate, r.reorder);
                    let Some(lasting) = cx.opt_duration(&r.lasting) else {
                        cx.error(&span, "a link's faults last a while: `for = \"5s\"`");
                        continue;
                    };
                    FaultKind::Link(agent, nf, lasting)
                }
                _ => {
                    if !journal {
                        cx.error(
                            &span,
                            "the coordinator resumes from its journal: crashing it needs `journal = true` in [run]",
                        );
                    }
                    FaultKind::CrashCoordinator(cx.opt_duration(&r.down).unwrap_or(500))
                }
            };
            let Some(trigger) = cx.trigger(against, "a fault", &span, &r.at, &r.when, &r.after) else { continue };
            let jitter_ms = cx.opt_duration(&r.jitter).unwrap_or(0);
            let (line, _) = cx.at(&span);
            faults.push(Fault { kind: fault_kind, trigger, jitter_ms, line });
        }
        faults
    }

    /// `[[expect]]`.
    pub(super) fn expects(&mut self, against: &Against, raw: &[Spanned<RawExpect>]) -> Vec<Expect> {
        let cx = self;
        let mut expects = Vec::new();
        for e in raw {
            let span = e.span();
            let (line, _) = cx.at(&span);
            let r = e.get_ref();
            let kind = match one_of(
                "an expectation",
                &[
                    ("reached", r.reached.is_some()),
                    ("order", r.order.is_some()),
                    ("value", r.value.is_some()),
                    ("always", r.always.is_some()),
                    ("never", r.never.is_some()),
                    ("ends_by", r.ends_by.is_some()),
                    ("alarms", r.alarms.is_some()),
                    ("state", r.state.is_some()),
                    ("states", r.states.is_some()),
                    ("modes", r.modes.is_some()),
                    ("once_per_epoch", r.once_per_epoch.is_some()),
                ],
            ) {
                Ok(k) => k,
                Err(msg) => {
                    cx.error(&span, msg);
                    continue;
                }
            };
            let stray = |cx: &mut Ctx, key: &str, present: bool, goes: &str| {
                if present {
                    cx.error(&span, format!("`{key}` goes with {goes}, not with `{kind}`"));
                }
            };
            if kind != "reached" {
                stray(cx, "on", r.on.is_some(), "`reached`");
                stray(cx, "by", r.by.is_some(), "`reached`");
            }
            if kind != "value" {
                stray(cx, "at", r.at.is_some(), "`value`");
            }
            let Some(kind) = cx.expectation(against, r, &span, kind) else { continue };
            expects.push(Expect { kind, line });
        }
        expects
    }

    /// One expectation of `kind` (which `one_of` found in `r`), checked against the chart.
    fn expectation(&mut self, against: &Against, r: &RawExpect, span: &Range<usize>, kind: &str) -> Option<ExpectKind> {
        Some(match kind {
            "reached" => {
                let step = self.step_known(against, span, r.reached.as_deref().unwrap_or_default())?;
                if let Some(a) = &r.on {
                    self.agent_known(against, span, a);
                }
                ExpectKind::Reached { step, on: r.on.clone(), by_ms: self.opt_duration(&r.by) }
            }
            "order" => {
                let steps: Vec<Option<String>> =
                    r.order.iter().flatten().map(|s| self.step_known(against, span, s)).collect();
                if steps.len() < 2 {
                    self.error(span, "`order` names two steps or more");
                }
                ExpectKind::Order(steps.into_iter().flatten().collect())
            }
            "value" => {
                if r.value.as_ref().is_some_and(|v| v.is_empty()) {
                    self.error(span, "`value` names no variable, so it could never fail: name one or more");
                    return None;
                }
                let mut vars = Vec::new();
                for (name, v) in r.value.iter().flatten() {
                    match against.program.var_by_name(name) {
                        Some(var) if !against.program.vars[var.index()].hidden => {
                            vars.push((against.program.vars[var.index()].name.clone(), v.clone()))
                        }
                        _ => self.error(span, format!("the chart has no variable `{name}`")),
                    }
                }
                ExpectKind::Value { vars, at_ms: self.opt_duration(&r.at) }
            }
            "always" | "never" => {
                let text = r.always.as_ref().or(r.never.as_ref()).expect("one of them");
                let cond = self.cond(text, against.program, &against.agents)?;
                // A condition that reads nothing of the run holds at every moment or at none: `always` of one
                // that holds, `never` of one that does not, could never fail.
                if cond.constant() == Some(kind == "always") {
                    let what = if kind == "always" { "always holds" } else { "never holds" };
                    let message = format!(
                        "`{}` reads no step and no variable and {what}: this expectation could never fail",
                        text.get_ref()
                    );
                    self.error(&text.span(), message);
                    return None;
                }
                if kind == "always" {
                    ExpectKind::Always(cond, text.get_ref().clone())
                } else {
                    ExpectKind::Never(cond, text.get_ref().clone())
                }
            }
            "ends_by" => ExpectKind::EndsBy(self.opt_duration(&r.ends_by).unwrap_or(0)),
            "alarms" => ExpectKind::Alarms(r.alarms.clone().unwrap_or_default()),
            "state" => {
                let s = r.state.as_ref().expect("state");
                match s.get_ref().as_str() {
                    "finished" => ExpectKind::State(RunState::Finished),
                    "failed" => ExpectKind::State(RunState::Failed),
                    "running" => ExpectKind::State(RunState::Running),
                    "stopped" => ExpectKind::State(RunState::Stopped),
                    "aborted" => ExpectKind::State(RunState::Aborted),
                    other => {
                        self.error(
                            &s.span(),
                            format!("`state` is finished, failed, running, stopped or aborted, not `{other}`"),
                        );
                        return None;
                    }
                }
            }
            "states" => return self.run_states(r, span),
            "modes" => return self.modes(r, span),
            _ => {
                let name = r.once_per_epoch.as_deref().unwrap_or_default();
                match against.program.actions.iter().position(|a| a.name.eq_ignore_ascii_case(name)) {
                    Some(i) if against.layout.skills[i].is_none() => {
                        let message = format!(
                            "action `{}` starts no skill, so `once_per_epoch` could never fail: name an action bound \
                             to a skill (`{{skill := …}}`)",
                            against.program.actions[i].name
                        );
                        self.error(span, message);
                        return None;
                    }
                    Some(i) => ExpectKind::OncePerEpoch(against.program.actions[i].name.clone()),
                    None => {
                        self.error(span, format!("the chart has no action `{name}`"));
                        return None;
                    }
                }
            }
        })
    }

    /// `states = ["held", "execute"]`: the run states, in order, the run is to pass through.
    fn run_states(&mut self, r: &RawExpect, span: &Range<usize>) -> Option<ExpectKind> {
        let mut names = Vec::new();
        for s in r.states.iter().flatten() {
            let known = crate::cluster::runtime::packml::State::ALL.iter().any(|st| st.name() == s.get_ref());
            if known {
                names.push(s.get_ref().clone());
            } else {
                let all: Vec<&str> = crate::cluster::runtime::packml::State::ALL.iter().map(|s| s.name()).collect();
                self.error(&s.span(), format!("`{}` is no run state (they are: {})", s.get_ref(), all.join(", ")));
            }
        }
        if names.is_empty() {
            self.error(span, "`states` names one run state or more, such as [\"held\", \"execute\"]");
            return None;
        }
        Some(ExpectKind::States(names))
    }

    /// `modes = ["step", "auto"]`: the modes, in order, the run is to pass through.
    fn modes(&mut self, r: &RawExpect, span: &Range<usize>) -> Option<ExpectKind> {
        let mut names = Vec::new();
        for m in r.modes.iter().flatten() {
            match crate::exec::engine::Mode::from_name(m.get_ref()) {
                Some(mode) => names.push(mode.name().to_string()),
                None => self.error(&m.span(), format!("`{}` is no mode: auto, step or manual", m.get_ref())),
            }
        }
        if names.is_empty() {
            self.error(span, "`modes` names one mode or more, such as [\"step\", \"auto\"]");
            return None;
        }
        Some(ExpectKind::Modes(names))
    }
}
