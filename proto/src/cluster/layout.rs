//! Where each part of a chart runs in a distributed run: step placement from `{agent := …}` and
//! `{role := …}` pragmas, segments (the runs of steps that travel as one token), waiting steps, the one writer
//! of each variable, skill bindings, and the engine scopes of the coordinator and of the agents.
//!
//! Rules, checked here so that a chart that passes `baton check` runs the same on one machine or many:
//! - a segment is a maximal run of steps placed the same way, linked by transitions with one source and one
//!   target; simultaneous divergences and convergences are always judged by the coordinator;
//! - a placed step that feeds a simultaneous convergence is a *waiting step*: its token returns as soon as it
//!   is active, so it may hold no actions;
//! - an action runs in one place, each variable has one writer, and a transition judged on an agent reads only
//!   steps of its own placement.
//!
//! Placement pragmas, segments (union-find over one-source one-target transitions of equal placement),
//! waiting steps, each variable's one writer, skill bindings (with their structured parameters read and their output
//! mappings, whose variables the action's agent writes); the coordinator's and agents' scopes. Its refusals are `baton
//! check` diagnostics.

use std::collections::BTreeMap;
use std::fmt;

use crate::cluster::keys::is_valid_name;
use crate::exec::engine::{Scope, TransitionScope};
use crate::exec::program::{walk_body, ActionId, CExpr, CStmt, Program, StepId, TransitionId, VarId};
use crate::front::diag::{Diagnostic, Span};
use crate::front::literal::FieldPath;
use crate::front::model::{Chart, Pragma};
use crate::front::pragma::Param;

#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Placement {
    Coordinator,
    /// Pinned to the agent with this name.
    Agent(String),
    /// Any live agent that has this role.
    Role(String),
}

impl fmt::Display for Placement {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Placement::Coordinator => write!(f, "the coordinator"),
            Placement::Agent(a) => write!(f, "agent `{a}`"),
            Placement::Role(r) => write!(f, "role `{r}`"),
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize)]
pub struct SegmentId(pub u32);

impl SegmentId {
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

#[derive(Clone, Debug)]
pub struct Segment {
    pub placement: Placement,
    /// In id order; the first is the name the segment is known by.
    pub steps: Vec<StepId>,
}

/// `ACTION Pick: {skill := 'motion', ms := 800} END_ACTION`: the action starts skill `motion` on its agent.
#[derive(Clone, Debug, PartialEq)]
pub struct SkillBinding {
    pub skill: String,
    /// The pragma's keys other than `skill`, lowercased (mappings included, as written).
    pub params: BTreeMap<String, Param>,
    /// Where the parts of the skill's answer go: `result := 'sequence[4] => last'` and the like (see
    /// `OUTPUT_KEYS`). These variables are written by the agent that runs the action, and by nothing else.
    pub outputs: Vec<SkillOutput>,
    /// The binding's pragma in the source, where `baton check` points at it.
    pub span: Span,
}

/// One part of a skill's answer written to a chart variable.
#[derive(Clone, Debug, PartialEq)]
pub struct SkillOutput {
    /// The parameter that maps it: `result`, `feedback`, `response` or `outputs`.
    pub key: String,
    /// The part of the answer: `sequence[4]`.
    pub path: FieldPath,
    pub var: VarId,
}

/// The skill parameters that map parts of a skill's answer to variables, as `'path => variable, …'`: the
/// result of a ROS 2 action and its latest feedback, the response of a service, the output arguments of an
/// OPC UA method.
pub const OUTPUT_KEYS: [&str; 4] = ["result", "feedback", "response", "outputs"];

/// The skill parameters that hold a structured literal (a goal, a request, arguments): read at check time.
pub const LITERAL_KEYS: [&str; 3] = ["goal", "request", "args"];

#[derive(Clone, Debug, Default)]
pub struct Layout {
    /// Per step.
    pub placement: Vec<Placement>,
    /// Per step: the segment of a placed step; `None` for coordinator steps and waiting steps.
    pub segment_of: Vec<Option<SegmentId>>,
    pub segments: Vec<Segment>,
    /// Per step: a placed step that feeds a simultaneous convergence; the coordinator holds it.
    pub waiting: Vec<bool>,
    /// Per variable: who writes it. Variables nobody writes belong to the coordinator and are inputs.
    pub writer: Vec<Placement>,
    /// Per variable: no action writes it, so a client may set it (`baton set`).
    pub settable: Vec<bool>,
    /// Per action.
    pub skills: Vec<Option<SkillBinding>>,
    /// Per segment: the actions bound to skills that its steps run — what an agent must offer to be sent it.
    pub segment_skills: Vec<Vec<ActionId>>,
    /// Per action: where it runs (the placement of the steps that use it).
    pub action_placement: Vec<Placement>,
    /// Per variable: read by code that runs on agents, or bound to a device (an input's agent publishes it, an
    /// output's agent must hear it), so its writer publishes it.
    pub read_by_agents: Vec<bool>,
    /// The variables bound to device signals (`cluster::bindings`), and the agent that connects each.
    pub io: Vec<crate::cluster::bindings::IoBinding>,
}

impl Layout {
    /// The coordinator judges every transition that does not leave a placed, non-waiting step, and mirrors the
    /// others as agents report them.
    pub fn coordinator_scope(&self, program: &Program) -> Scope {
        let transitions = (0..program.transitions.len())
            .map(|t| match self.agent_judges(program, TransitionId(t as u32)) {
                Some(_) => TransitionScope::Remote,
                None => TransitionScope::Local,
            })
            .collect();
        let runs_actions = self.placement.iter().map(|p| *p == Placement::Coordinator).collect();
        // The coordinator runs no skills.
        let skill_actions = vec![false; program.actions.len()];
        Scope { transitions, runs_actions, initial: true, skill_actions }
    }

    /// An agent judges the transitions leaving its segments' steps; those that stay inside a segment are local,
    /// the others hand the token back. It starts with no active step.
    pub fn agent_scope(&self, program: &Program) -> Scope {
        let transitions = (0..program.transitions.len())
            .map(|t| {
                let t = TransitionId(t as u32);
                match self.agent_judges(program, t) {
                    Some(g) if self.is_internal(program, t, g) => TransitionScope::Local,
                    Some(_) => TransitionScope::Exit,
                    None => TransitionScope::Remote,
                }
            })
            .collect();
        let runs_actions = self.segment_of.iter().map(Option::is_some).collect();
        let skill_actions = self.skills.iter().map(Option::is_some).collect();
        Scope { transitions, runs_actions, initial: false, skill_actions }
    }

    /// The segment whose agent judges `t`: that of its single source, when the source is in a segment.
    pub fn agent_judges(&self, program: &Program, t: TransitionId) -> Option<SegmentId> {
        match program.sources(t) {
            [s] => self.segment_of[s.index()],
            _ => None,
        }
    }

    /// A transition with one source and one target in the same segment.
    pub fn is_internal(&self, program: &Program, t: TransitionId, g: SegmentId) -> bool {
        matches!((program.sources(t), program.targets(t)), ([_], [target]) if self.segment_of[target.index()] == Some(g))
    }

    /// The variables written where `placement` runs.
    pub fn written_by<'a>(&'a self, placement: &'a Placement) -> impl Iterator<Item = VarId> + 'a {
        self.writer.iter().enumerate().filter(move |(_, w)| *w == placement).map(|(i, _)| VarId(i as u32))
    }
}

/// Lays out a compiled chart. `chart` is the chart `program` was compiled from without errors, so step and
/// declared action ids follow its declaration order.
pub fn layout(chart: &Chart, program: &Program, diags: &mut Vec<Diagnostic>) -> Layout {
    let n_steps = program.steps.len();
    let step_span = |s: StepId| chart.steps.get(s.index()).map_or(chart.name.span, |st| st.name.span);
    let placement: Vec<Placement> = (0..n_steps).map(|i| step_placement(&program.steps[i].pragmas, diags)).collect();
    let mut waiting = vec![false; n_steps];
    for t in 0..program.transitions.len() {
        let sources = program.sources(TransitionId(t as u32));
        if sources.len() > 1 {
            for s in sources {
                waiting[s.index()] = placement[s.index()] != Placement::Coordinator;
            }
        }
    }
    for (i, &w) in waiting.iter().enumerate() {
        if w && !program.associations(StepId(i as u32)).is_empty() {
            diags.push(Diagnostic::error(step_span(StepId(i as u32)), format!(
                "step `{}` is placed on {} and feeds a simultaneous convergence, so its token returns to the coordinator as soon as it is active and its actions could not run: end the branch with an empty waiting step",
                program.steps[i].name, placement[i]
            )));
        }
    }
    let (segment_of, segments) = segments(program, &placement, &waiting);
    check_entries(program, &segment_of, diags, &step_span);
    let action_placement = action_placements(program, &placement, diags, &step_span);
    let skills = skill_bindings(program, &action_placement, diags, chart);
    let judged_at = |t: usize| match program.sources(TransitionId(t as u32)) {
        [s] if segment_of[s.index()].is_some() => placement[s.index()].clone(),
        _ => Placement::Coordinator,
    };
    let transition_placement: Vec<Placement> = (0..program.transitions.len()).map(judged_at).collect();
    let io = crate::cluster::bindings::io_bindings(chart, program, diags);
    let (writer, settable) = writers(chart, program, &action_placement, &transition_placement, &skills, &io, diags);
    check_remote_reads(chart, program, &placement, &segment_of, &action_placement, diags);
    let mut read_by_agents = read_by_agents(program, &segment_of, &action_placement);
    for b in &io {
        read_by_agents[b.var.index()] = true;
    }
    let segment_skills = segments.iter().map(|seg| skills_run_by(program, &seg.steps, &skills)).collect();
    Layout {
        placement,
        segment_of,
        segments,
        waiting,
        writer,
        settable,
        skills,
        segment_skills,
        action_placement,
        read_by_agents,
        io,
    }
}

/// The actions bound to skills that `steps` run, each once, in id order.
fn skills_run_by(program: &Program, steps: &[StepId], skills: &[Option<SkillBinding>]) -> Vec<ActionId> {
    let mut out: Vec<ActionId> = steps
        .iter()
        .flat_map(|&s| program.associations(s).iter().map(|a| a.action))
        .filter(|a| skills[a.index()].is_some())
        .collect();
    out.sort_unstable();
    out.dedup();
    out
}

/// The keys a step's pragma may hold.
/// A step's keys: its placement, and its supervision (`min_ms` and `max_ms`, which `compile` reads).
const STEP_KEYS: [&str; 4] = ["agent", "role", "min_ms", "max_ms"];

/// A pragma Baton may read, as pairs: `None` (after reporting it) when it names Baton's `keys` but cannot be read,
/// or when it only names near misses of them (a warning: it may be another tool's), or is another tool's.
fn baton_pairs(
    pragma: &Pragma,
    keys: &[&str],
    what: &str,
    diags: &mut Vec<Diagnostic>,
) -> Option<Vec<(String, Param)>> {
    let named = match crate::front::pragma::read(&pragma.text) {
        crate::front::pragma::Pragma::Foreign => return None,
        crate::front::pragma::Pragma::Pairs(pairs) => {
            if pairs.iter().any(|(k, _)| keys.contains(&k.as_str())) {
                return Some(pairs);
            }
            pairs.into_iter().map(|(k, _)| k).collect::<Vec<_>>()
        }
        crate::front::pragma::Pragma::Malformed { keys: named, why } => {
            if let Some(k) = named.iter().find(|k| keys.contains(&k.as_str())) {
                diags.push(Diagnostic::error(
                    pragma.span,
                    format!("this {what} pragma with `{k}` cannot be read: {why}"),
                ));
                return None;
            }
            named
        }
    };
    for key in named {
        if let Some(meant) = crate::front::pragma::near_miss(&key, keys) {
            diags.push(Diagnostic::warning(
                pragma.span,
                format!(
                    "`{key}` is not a key Baton reads on {} {what}: did you mean `{meant}`? (if it is another tool's, ignore this)",
                    if what.starts_with('a') { "an" } else { "a" }
                ),
            ));
        }
    }
    None
}

fn step_placement(pragmas: &[Pragma], diags: &mut Vec<Diagnostic>) -> Placement {
    let mut found: Option<Placement> = None;
    for pragma in pragmas {
        let Some(pairs) = baton_pairs(pragma, &STEP_KEYS, "step", diags) else { continue };
        for (key, value) in pairs {
            let err = |m: String| Diagnostic::error(pragma.span, m);
            if key == "min_ms" || key == "max_ms" {
                continue;
            }
            if !STEP_KEYS.contains(&key.as_str()) {
                let hint = crate::front::pragma::near_miss(&key, &STEP_KEYS)
                    .map_or(String::new(), |k| format!(" (did you mean `{k}`?)"));
                diags.push(err(format!(
                    "unknown key `{key}` in a step's placement{hint}: a step takes `agent := 'name'`, `role := 'name'`, `min_ms := T#200ms` or `max_ms := T#5s`"
                )));
                continue;
            }
            let name = match value.as_str() {
                Some(n) if is_valid_name(n) => n.to_string(),
                _ => {
                    diags.push(err(format!(
                        "`{key}` needs a quoted name of letters, digits, `_` or `-`, such as '{key}1'"
                    )));
                    continue;
                }
            };
            let placed = if key == "agent" { Placement::Agent(name) } else { Placement::Role(name) };
            if let Some(previous) = &found {
                diags.push(err(format!("the step is already placed on {previous}: a step has one placement")));
                continue;
            }
            found = Some(placed);
        }
    }
    found.unwrap_or(Placement::Coordinator)
}

/// Union-find over placed, non-waiting steps joined by one-source, one-target transitions of the same placement.
fn segments(program: &Program, placement: &[Placement], waiting: &[bool]) -> (Vec<Option<SegmentId>>, Vec<Segment>) {
    let n = placement.len();
    let mut parent: Vec<usize> = (0..n).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let placed = |s: StepId| placement[s.index()] != Placement::Coordinator && !waiting[s.index()];
    for t in 0..program.transitions.len() {
        let t = TransitionId(t as u32);
        if let ([a], [b]) = (program.sources(t), program.targets(t)) {
            if placed(*a) && placed(*b) && placement[a.index()] == placement[b.index()] {
                let (ra, rb) = (root(&mut parent, a.index()), root(&mut parent, b.index()));
                parent[ra.max(rb)] = ra.min(rb);
            }
        }
    }
    let mut segment_of = vec![None; n];
    let mut segments: Vec<Segment> = Vec::new();
    let mut by_root: BTreeMap<usize, SegmentId> = BTreeMap::new();
    for i in 0..n {
        if !placed(StepId(i as u32)) {
            continue;
        }
        let r = root(&mut parent, i);
        let id = *by_root.entry(r).or_insert_with(|| {
            segments.push(Segment { placement: placement[i].clone(), steps: Vec::new() });
            SegmentId(segments.len() as u32 - 1)
        });
        segments[id.index()].steps.push(StepId(i as u32));
        segment_of[i] = Some(id);
    }
    (segment_of, segments)
}

/// A token enters a segment at one step: a transition that is not inside a segment may activate at most one of
/// its steps, and may not lead back into the segment it leaves.
fn check_entries(
    program: &Program,
    segment_of: &[Option<SegmentId>],
    diags: &mut Vec<Diagnostic>,
    step_span: &dyn Fn(StepId) -> Span,
) {
    for t in 0..program.transitions.len() {
        let t = TransitionId(t as u32);
        let from = match program.sources(t) {
            [s] => segment_of[s.index()],
            _ => None,
        };
        let internal = matches!(program.targets(t), [target] if from.is_some() && segment_of[target.index()] == from);
        if internal {
            continue;
        }
        let mut seen: Vec<SegmentId> = Vec::new();
        for &target in program.targets(t) {
            let Some(g) = segment_of[target.index()] else { continue };
            let name = &program.transitions[t.index()].name;
            if seen.contains(&g) || Some(g) == from {
                diags.push(Diagnostic::error(step_span(target), format!(
                    "transition `{name}` enters the segment of step `{}` twice or from inside it: a segment travels as one token, entered at one step",
                    program.steps[target.index()].name
                )));
            }
            seen.push(g);
        }
    }
}

fn action_placements(
    program: &Program,
    placement: &[Placement],
    diags: &mut Vec<Diagnostic>,
    step_span: &dyn Fn(StepId) -> Span,
) -> Vec<Placement> {
    let mut used: Vec<Option<(Placement, StepId)>> = vec![None; program.actions.len()];
    for s in 0..program.steps.len() {
        let s = StepId(s as u32);
        for assoc in program.associations(s) {
            let here = &placement[s.index()];
            match &used[assoc.action.index()] {
                None => used[assoc.action.index()] = Some((here.clone(), s)),
                Some((there, first)) if there != here => diags.push(Diagnostic::error(step_span(s), format!(
                    "action `{}` runs on {here} for step `{}` but on {there} for step `{}`: an action runs in one place",
                    program.actions[assoc.action.index()].name, program.steps[s.index()].name, program.steps[first.index()].name
                ))),
                Some(_) => {}
            }
        }
    }
    used.into_iter().map(|u| u.map_or(Placement::Coordinator, |(p, _)| p)).collect()
}

fn skill_bindings(
    program: &Program,
    action_placement: &[Placement],
    diags: &mut Vec<Diagnostic>,
    chart: &Chart,
) -> Vec<Option<SkillBinding>> {
    let mut out = Vec::with_capacity(program.actions.len());
    let runs = associated(program);
    for (i, action) in program.actions.iter().enumerate() {
        let mut binding: Option<SkillBinding> = None;
        for pragma in &action.pragmas {
            let Some(pairs) = baton_pairs(pragma, &["skill"], "action", diags) else { continue };
            let Some((_, skill)) = pairs.iter().find(|(k, _)| k == "skill") else { continue };
            let Some(skill) = skill.as_str().filter(|s| is_valid_name(s)).map(str::to_string) else {
                diags.push(Diagnostic::error(pragma.span, "`skill` needs a quoted skill name, such as 'motion'"));
                continue;
            };
            if binding.is_some() {
                diags.push(Diagnostic::error(
                    pragma.span,
                    format!("action `{}` is bound to a skill twice", action.name),
                ));
                continue;
            }
            if !runs[i] {
                let message = format!(
                    "action `{}` is bound to skill `{skill}`, but no step of the chart runs it: an action that a \
                     nested chart controls cannot drive a skill",
                    action.name
                );
                diags.push(Diagnostic::error(pragma.span, message));
            } else if action_placement[i] == Placement::Coordinator {
                let span = chart.actions.get(i).map_or(pragma.span, |a| a.name.span);
                diags.push(Diagnostic::warning(span, format!(
                    "action `{}` is bound to skill `{skill}` but runs on the coordinator, which runs no skills: place its steps on an agent",
                    action.name
                )));
            }
            let params: BTreeMap<String, Param> = pairs.into_iter().filter(|(k, _)| k != "skill").collect();
            // What a hold does to the running skill: let it finish (a robot completes its motion), or cancel it.
            if let Some(hold) = params.get("hold") {
                if !hold.as_str().is_some_and(|h| h.eq_ignore_ascii_case("finish") || h.eq_ignore_ascii_case("cancel"))
                {
                    diags.push(Diagnostic::error(
                        pragma.span,
                        format!("`hold` of action `{}` is 'finish' (the default) or 'cancel'", action.name),
                    ));
                }
            }
            let outputs = skill_outputs(program, &params, pragma.span, diags);
            binding = Some(SkillBinding { skill, params, outputs, span: pragma.span });
        }
        out.push(binding);
    }
    out
}

/// Reads a binding's structured parameters and its output mappings, reporting what cannot be read.
fn skill_outputs(
    program: &Program,
    params: &BTreeMap<String, Param>,
    span: Span,
    diags: &mut Vec<Diagnostic>,
) -> Vec<SkillOutput> {
    for key in LITERAL_KEYS {
        match params.get(key) {
            Some(Param::Str(text)) => {
                if let Err(why) = crate::front::literal::parse(text) {
                    diags.push(Diagnostic::error(span, format!("`{key}` cannot be read: {why}")));
                }
            }
            Some(Param::Value(_)) => diags.push(Diagnostic::error(
                span,
                format!("`{key}` is written as a quoted literal, such as '(order := 5)' or '[3, 4]'"),
            )),
            None => {}
        }
    }
    let mut out = Vec::new();
    for key in OUTPUT_KEYS {
        let Some(param) = params.get(key) else { continue };
        let Some(text) = param.as_str() else {
            diags.push(Diagnostic::error(
                span,
                format!("`{key}` maps parts of the answer to variables: write it as '<part> => <variable>, …'"),
            ));
            continue;
        };
        let mapping = match crate::front::literal::parse_mapping(text) {
            Ok(m) => m,
            Err(why) => {
                diags.push(Diagnostic::error(span, format!("`{key}` cannot be read: {why}")));
                continue;
            }
        };
        for (path, name) in mapping {
            match program.var_by_name(&name).map(|v| v.index()) {
                None => diags.push(Diagnostic::error(
                    span,
                    format!("`{key}` writes `{name}`, which is not a variable of the chart"),
                )),
                Some(i) if program.vars[i].constant => {
                    diags.push(Diagnostic::error(span, format!("`{key}` writes `{name}`, which is a constant")))
                }
                Some(i) => out.push(SkillOutput { key: key.to_string(), path, var: VarId(i as u32) }),
            }
        }
    }
    out
}

/// Which actions a step of the chart is associated with (the others run only inside a nested chart's body,
/// where they are that chart's action's writes, or never).
fn associated(program: &Program) -> Vec<bool> {
    let mut out = vec![false; program.actions.len()];
    for s in 0..program.steps.len() {
        for a in program.associations(StepId(s as u32)) {
            out[a.action.index()] = true;
        }
    }
    out
}

fn assigned(body: &[CStmt], out: &mut Vec<VarId>) {
    walk_body(body, &mut |v| out.push(v), &mut |_| {});
}

/// Each variable has one writer: the place that runs every action writing it (by assignment, as a boolean
/// action, or as an indicator driven by a skill).
fn writers(
    chart: &Chart,
    program: &Program,
    action_placement: &[Placement],
    transition_placement: &[Placement],
    skills: &[Option<SkillBinding>],
    io: &[crate::cluster::bindings::IoBinding],
    diags: &mut Vec<Diagnostic>,
) -> (Vec<Placement>, Vec<bool>) {
    let n = program.vars.len();
    let mut writes: Vec<Vec<(Placement, String)>> = vec![Vec::new(); n];
    let mut note = |v: VarId, p: &Placement, by: String| {
        if !writes[v.index()].iter().any(|(q, _)| q == p) {
            writes[v.index()].push((p.clone(), by));
        }
    };
    let runs = associated(program);
    for (i, action) in program.actions.iter().enumerate().filter(|(i, _)| runs[*i]) {
        let mut vars = Vec::new();
        assigned(&action.body, &mut vars);
        vars.extend(action.bool_var);
        for v in vars {
            note(v, &action_placement[i], format!("action `{}`", action.name));
        }
    }
    // A condition's user function calls run where the condition is judged: on the agent of the step it leaves
    // when that step is placed, on the coordinator otherwise (their frames are scratch, written anywhere).
    for (i, t) in program.transitions.iter().enumerate() {
        let calls = program.calls(TransitionId(i as u32));
        if calls.is_empty() {
            continue;
        }
        let place = &transition_placement[i];
        let mut vars = Vec::new();
        assigned(calls, &mut vars);
        for v in vars {
            note(v, place, format!("the function calls of transition `{}`", t.name));
        }
    }
    for (i, binding) in skills.iter().enumerate() {
        for out in binding.iter().flat_map(|b| &b.outputs) {
            note(
                out.var,
                &action_placement[i],
                format!("the `{}` of skill action `{}`", out.key, program.actions[i].name),
            );
        }
    }
    for s in 0..program.steps.len() {
        let s = StepId(s as u32);
        for (assoc, inds) in program.associations(s).iter().zip(program.indicators(s)) {
            for &v in inds {
                let by = format!(
                    "the indicator of `{}` in step `{}`",
                    program.actions[assoc.action.index()].name,
                    program.steps[s.index()].name
                );
                note(v, &action_placement[assoc.action.index()], by);
            }
        }
    }
    // A bound input's one writer is its device, through its agent: nothing in the chart may write it too.
    for b in io.iter().filter(|b| b.dir == crate::cluster::bindings::IoDir::Input) {
        let others = &mut writes[b.var.index()];
        if !others.is_empty() {
            let by: Vec<String> = others.iter().map(|(p, by)| format!("{by} on {p}")).collect();
            diags.push(Diagnostic::error(
                b.span,
                format!(
                    "`{}` is bound as an input on `{}`, and {} writes it too: a bound input is written by its device alone",
                    b.name,
                    b.agent,
                    by.join(", ")
                ),
            ));
            others.clear();
        }
        others.push((Placement::Agent(b.agent.clone()), format!("the input binding on `{}`", b.agent)));
    }
    let mut writer = Vec::with_capacity(n);
    let mut settable = Vec::with_capacity(n);
    for (i, w) in writes.iter().enumerate() {
        // Scratch (a function's frame, a call's result, VAR_TEMP): written and read within one call.
        let scratch = program.vars[i].hidden && program.vars[i].section == crate::front::model::VarSection::Temp;
        if w.len() > 1 && !scratch {
            let span = chart
                .vars
                .iter()
                .find(|d| d.name.name.eq_ignore_ascii_case(&program.vars[i].name))
                .map_or(chart.name.span, |d| d.name.span);
            let places: Vec<String> = w.iter().map(|(p, by)| format!("{by} on {p}")).collect();
            diags.push(Diagnostic::error(
                span,
                format!(
                    "variable `{}` has more than one writer ({}): each variable is written in one place",
                    program.vars[i].name,
                    places.join(", ")
                ),
            ));
        }
        writer.push(w.first().map_or(Placement::Coordinator, |(p, _)| p.clone()));
        settable.push(w.is_empty() && !program.vars[i].constant);
    }
    (writer, settable)
}

/// What a piece of code reads.
#[derive(Default)]
struct Refs {
    steps: Vec<StepId>,
    actions: Vec<ActionId>,
    vars: Vec<VarId>,
}

impl Refs {
    fn expr(&mut self, e: &CExpr) {
        match e {
            CExpr::Const(_) => {}
            CExpr::Var(v) => self.vars.push(*v),
            CExpr::StepX(s) | CExpr::StepT(s) | CExpr::StepOverrun(s) => self.steps.push(*s),
            CExpr::ActionQ(a) => self.actions.push(*a),
            CExpr::NestedT(v) => self.vars.extend(v.iter()),
            CExpr::Not(x) | CExpr::Neg(x, _) => self.expr(x),
            CExpr::Logic(_, a, b) | CExpr::Cmp(_, a, b) => {
                self.expr(a);
                self.expr(b);
            }
            CExpr::Arith { lhs, rhs, .. } => {
                self.expr(lhs);
                self.expr(rhs);
            }
            CExpr::Call(c) => c.args.iter().for_each(|a| self.expr(a)),
            CExpr::Index(ix) => {
                self.vars.extend((0..ix.len).map(|i| VarId(ix.base.0 + i)));
                ix.indices.iter().for_each(|e| self.expr(e));
            }
        }
    }

    fn body(&mut self, body: &[CStmt]) {
        walk_body(body, &mut |_| {}, &mut |e| self.expr(e));
    }
}

/// The variables that code running on agents reads: conditions of the transitions they judge, bodies of the
/// actions they run, durations of their associations. Only these need to travel to agents.
fn read_by_agents(program: &Program, segment_of: &[Option<SegmentId>], action_placement: &[Placement]) -> Vec<bool> {
    let mut refs = Refs::default();
    for t in 0..program.transitions.len() {
        if let [s] = program.sources(TransitionId(t as u32)) {
            if segment_of[s.index()].is_some() {
                refs.expr(&program.transitions[t].condition);
                refs.body(program.calls(TransitionId(t as u32)));
            }
        }
    }
    for (i, action) in program.actions.iter().enumerate() {
        if action_placement[i] != Placement::Coordinator {
            refs.body(&action.body);
        }
    }
    for (s, g) in segment_of.iter().enumerate() {
        if g.is_none() {
            continue;
        }
        for assoc in program.associations(StepId(s as u32)) {
            if let Some(crate::exec::program::DurationSrc::Var(v)) = assoc.duration {
                refs.vars.push(v);
            }
        }
    }
    let mut read = vec![false; program.vars.len()];
    for v in refs.vars {
        read[v.index()] = true;
    }
    read
}

/// An agent knows only the steps and actions it runs: code judged or run there may read `S.X`, `S.T` and
/// `A.Q` only of its own placement's steps and actions.
fn check_remote_reads(
    chart: &Chart,
    program: &Program,
    placement: &[Placement],
    segment_of: &[Option<SegmentId>],
    action_placement: &[Placement],
    diags: &mut Vec<Diagnostic>,
) {
    let mut check = |what: String, here: &Placement, span: Span, steps: &[StepId], actions: &[ActionId]| {
        for s in steps {
            if segment_of[s.index()].is_none() || placement[s.index()] != *here {
                diags.push(Diagnostic::error(span, format!(
                    "{what} runs on {here} but reads step `{}`, which it cannot see there: an agent sees only the steps of its own placement",
                    program.steps[s.index()].name
                )));
                return;
            }
        }
        for a in actions {
            if action_placement[a.index()] != *here {
                diags.push(Diagnostic::error(
                    span,
                    format!(
                        "{what} runs on {here} but reads action `{}`, which runs on {}",
                        program.actions[a.index()].name,
                        action_placement[a.index()]
                    ),
                ));
                return;
            }
        }
    };
    for t in 0..program.transitions.len() {
        let tid = TransitionId(t as u32);
        let [s] = program.sources(tid) else { continue };
        if segment_of[s.index()].is_none() {
            continue;
        }
        let mut refs = Refs::default();
        refs.expr(&program.transitions[t].condition);
        let span = chart.transitions.get(t).map_or(chart.name.span, |tr| tr.span);
        check(
            format!("transition `{}`", program.transitions[t].name),
            &placement[s.index()],
            span,
            &refs.steps,
            &refs.actions,
        );
    }
    for (i, action) in program.actions.iter().enumerate() {
        if action_placement[i] == Placement::Coordinator {
            continue;
        }
        let mut refs = Refs::default();
        refs.body(&action.body);
        let span = chart.actions.get(i).map_or(chart.name.span, |a| a.name.span);
        check(format!("action `{}`", action.name), &action_placement[i], span, &refs.steps, &refs.actions);
    }
}
