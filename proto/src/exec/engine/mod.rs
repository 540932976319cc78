//! The SFC engine: a pure, deterministic state machine that runs a `Program` one scan cycle at a time.
//!
//! A cycle at time t (IEC 61131-3 with matiec's evaluation order): inputs set before the cycle are already
//! applied; every transition leaving an active step is judged against one snapshot, in rank order, and a
//! transition cannot clear when a higher-ranked one already consumed one of its source steps; the sources of
//! cleared transitions are deactivated, then their targets activated with activation time t; finally every
//! action's Q is computed from its associations (IEC ACTION_CONTROL) and the bodies of actions whose Q is TRUE
//! run, plus one final run with Q = FALSE when Q falls.
//!
//! Between cycles, a distributed runtime applies what other engines did (`handle_remote`) and new values
//! (`handle`), then asks for a reaction (`react`): the steps that became active get their first scan (their
//! actions start), the steps that were left their last one, and the transitions whose condition reads no step
//! time and something that changed are judged at once, as the next cycle would judge them. No other action body
//! runs, so an N body runs once per cycle however many messages arrive, and a step's time counts from the cycle
//! it became active in. A chart run on one engine with no reactions behaves exactly as `baton sim`.
//!
//! The cost of a cycle depends on the active steps, their transitions and associations, and the actions with
//! stored state, never on the size of the chart: per-element scratch is indexed by id and stamped with the
//! cycle number instead of being cleared.
//!
//! `Engine`, the scan-cycle state machine: `handle(Input)`, `handle_cycle(now_ms)`, `poll_event()`;
//! `Engine::with_scope(Scope)` runs part of a chart (which transitions it judges, which are exits whose targets live
//! elsewhere, which steps' actions it runs) and `handle_remote` applies what another engine did (a token arrived; a
//! transition cleared elsewhere). Between cycles, `react` scans what became active or was left and judges the
//! transitions that read no step time and something that changed; `needs_cycle` says whether a cycle could change
//! anything; `set_grid` gives the cycle grid from which steps made active between cycles count their time (and the time
//! function blocks see, `Env::now_ms`, is that grid point in a reaction). Before judging a cycle's transitions it runs
//! the calls of those whose sources are active (a condition's user function calls), so that every condition is judged
//! against one snapshot; a transition with calls reads the clock, so it is judged in cycles only (`Reads::step_time`).
//! An action associated only as entry or exit actions (`ActionInfo::once`) runs once where its step is entered or left,
//! without a final scan, exit actions first, then entry actions, then the others (CODESYS's order). The initial steps'
//! first scan is the first cycle's: a chart's first cycle judges the transitions first, so an initial step whose
//! transition is already TRUE is left before its actions ever run (matiec's order; CODESYS runs them once first).
//!
//! # Rules the engine keeps
//!
//! - A cycle's cost depends on the active steps, their transitions and associations and the actions with stored state,
//!   never on the chart's size: per-element scratch is stamped with the cycle number, not cleared.
//!
//! - `Engine::collisions()` counts a step receiving a token while holding one. The validator's job is to make it
//!   impossible; property tests hold it to zero.

use std::collections::VecDeque;
use std::sync::Arc;

use crate::exec::eval::{self, Env, EnvMut, Fault};
use crate::exec::program::{ActionId, Program, StepId, TransitionId, VarId};
use crate::front::model::Qualifier;
use crate::limits::REACTION_ROUNDS_MAX;
use crate::types::{Type, Value};

mod actions;
mod mode;
mod operator;

pub use mode::Mode;

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Event {
    pub t_ms: u64,
    pub kind: EventKind,
}

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum EventKind {
    Fire(TransitionId),
    Deactivate(StepId),
    Activate(StepId),
    ActionOn(ActionId),
    ActionOff(ActionId),
    /// A run-time fault: the condition counted as FALSE, or the body stopped where it happened.
    Fault(FaultSource, Fault),
    /// A step was active longer than its `max_ms`: it is faulted (`S.overrun`), and its outgoing transitions
    /// wait for `acknowledge_overrun` (except those that read `S.overrun`).
    Overrun(StepId),
}

#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum FaultSource {
    Transition(TransitionId),
    Action(ActionId),
}

#[derive(Clone, Debug, PartialEq)]
pub enum Input {
    Set(VarId, Value),
}

/// What a distributed runtime tells an engine that another engine did: a token arrived (the step becomes active
/// here), or a transition that this engine does not judge cleared elsewhere (this engine mirrors it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RemoteInput {
    Activate(StepId),
    Fire(TransitionId),
    /// The token left the step without a transition: its segment was taken back (an agent was lost, or a
    /// stale token dropped).
    Deactivate(StepId),
}

/// Whether an engine judges a transition, and whether it activates the transition's targets when it clears.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum TransitionScope {
    /// Judged here; its targets become active here.
    Local,
    /// Judged here; its sources are deactivated here and its targets become active in another engine.
    Exit,
    /// Judged by another engine, which reports it as `RemoteInput::Fire`.
    Remote,
}

/// The part of a chart one engine runs. A chart that runs on one machine has `Scope::whole`; in a distributed
/// run the coordinator and each agent run complementary scopes of the same program.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Scope {
    /// Per transition.
    pub transitions: Vec<TransitionScope>,
    /// Per step: whether this engine runs the step's actions.
    pub runs_actions: Vec<bool>,
    /// Whether the initial steps start active here.
    pub initial: bool,
    /// Per action: it starts a skill whose result its indicators report, so they read FALSE from the moment its
    /// Q rises (before anything judges them), until the skill says otherwise.
    pub skill_actions: Vec<bool>,
}

impl Scope {
    pub fn whole(program: &Program) -> Scope {
        Scope {
            transitions: vec![TransitionScope::Local; program.transitions.len()],
            runs_actions: vec![true; program.steps.len()],
            initial: true,
            skill_actions: vec![false; program.actions.len()],
        }
    }
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum InputError {
    #[error("no variable with id {0}")]
    UnknownVar(u32),
    #[error("`{name}` is a CONSTANT")]
    Constant { name: String },
    #[error("`{name}` is {expected}, and {value} is not a {expected} value")]
    Type { name: String, expected: Type, value: Value },
    #[error("time went backwards: a cycle at {now_ms} ms after one at {last_ms} ms")]
    TimeWentBack { last_ms: u64, now_ms: u64 },
    #[error("no step with id {0}")]
    UnknownStep(u32),
    #[error("no transition with id {0}")]
    UnknownTransition(u32),
    #[error("step `{0}` is already active")]
    AlreadyActive(String),
    #[error("step `{0}` is not active")]
    NotActive(String),
    #[error("transition `{0}` is judged by this engine, not reported by another")]
    NotRemote(String),
    #[error("transition `{0}` cannot have cleared: not all of its source steps are active")]
    NotEnabled(String),
}

const NEVER: u64 = u64::MAX;

#[derive(Clone, Copy, serde::Serialize, serde::Deserialize)]
struct StepState {
    active: bool,
    /// Made active by another engine or by a reaction (not by a cycle of this engine).
    reactive: bool,
    /// The `gen` of its activation.
    activated_gen: u64,
    activated_ms: u64,
    /// `S.T` as it was at the last deactivation.
    t_last_ms: i64,
    activated_cycle: u64,
    /// The cycle before which a remote input activated the step: its actions run first in that cycle, and its
    /// transitions are judged from the next one, as if it had been activated by a cycle of this engine.
    remote_cycle: u64,
    /// Index into `Engine::active` while active.
    slot: u32,
    /// Held (`Engine::set_held`) since then, while active: its time stands still and no outgoing transition clears.
    held_at: Option<u64>,
    /// Its `max_ms` passed in this activation (`S.overrun`), and the fault is not acknowledged yet.
    overrun: bool,
    overrun_unacked: bool,
}

#[derive(Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
struct ActionState {
    q: bool,
    stored_s: bool,
    /// SD stored: since when, and the delay.
    stored_sd: Option<(u64, i64)>,
    stored_ds: bool,
    /// SL stored: since when, and the limit.
    stored_sl: Option<(u64, i64)>,
}

impl ActionState {
    fn live(&self) -> bool {
        self.q || self.stored_s || self.stored_sd.is_some() || self.stored_ds || self.stored_sl.is_some()
    }
}

/// What the associations of one cycle ask of one action.
#[derive(Clone, Copy, Default, serde::Serialize, serde::Deserialize)]
struct Demand {
    direct: bool,
    reset: bool,
    set_s: bool,
    set_sd: Option<i64>,
    set_ds: bool,
    set_sl: Option<i64>,
}

#[derive(serde::Serialize, serde::Deserialize)]
pub struct Engine {
    /// Not in a snapshot: `restore` is given it.
    #[serde(skip)]
    program: Arc<Program>,
    scope: Scope,
    now_ms: u64,
    /// Index of the next cycle.
    cycle: u64,
    started: bool,
    vars: Vec<Value>,
    steps: Vec<StepState>,
    active: Vec<StepId>,
    actions: Vec<ActionState>,
    /// Actions whose Q is TRUE or that hold a stored qualifier: they are judged every cycle.
    live: Vec<ActionId>,
    events: VecDeque<Event>,
    collisions: u64,
    /// The cycle grid `grid_origin_ms + k · grid_period_ms`: a step made active between cycles counts its time
    /// from the grid point before, as if it had become active in that cycle, so that its time advances in whole
    /// cycles wherever it became active (and whichever cycles actually ran).
    grid_origin_ms: u64,
    grid_period_ms: u64,
    /// Counts every change of the situation, the variables and the actions' state: a cycle that leaves it
    /// unchanged changed nothing.
    mutations: u64,
    mutations_at_cycle: u64,
    /// Orders judgements and changes, so that a reaction judges only what changed since it was last judged.
    gen: u64,
    judged_gen: Vec<u64>,
    var_gen: Vec<u64>,
    /// The last change of a step's activity or an action's Q.
    xq_gen: u64,
    /// Per transition: it may be judged in a reaction (its condition and those of the transitions ranked before
    /// it on its source steps read no step time).
    reactive_ok: Vec<bool>,
    /// Per step: while active, the engine needs cycles as time passes (a transition reading step time, or a
    /// timed qualifier).
    timed: Vec<bool>,
    timed_active: usize,
    // Scratch, reused across cycles.
    /// Transitions leaving active steps, with their ranks.
    candidates: Vec<(u32, TransitionId)>,
    consumed_stamp: Vec<u64>,
    fired: Vec<TransitionId>,
    deactivated: Vec<StepId>,
    demand: Vec<Demand>,
    demand_stamp: Vec<u64>,
    /// Per action: the cycle in which a step using it became active or was left (what a reaction controls).
    touched: Vec<u64>,
    judged: Vec<ActionId>,
    /// Per step: held by an operator (`set_held`), whenever it is active.
    held: Vec<bool>,
    /// Per action: its stored timers stand still since then, a step it is associated with being held.
    frozen_at: Vec<Option<u64>>,
    /// How transitions clear (`set_mode`): by their conditions, only once confirmed, or only when forced.
    mode: Mode,
    /// Per transition: confirmed (step mode) or forced (manual mode) to clear once.
    permits: Vec<bool>,
    /// Per transition: TRUE, and waiting for a confirmation (step mode).
    waiting: Vec<bool>,
    /// Why each step that just passed its maximum time waited then (`take_overrun_why`).
    overrun_why: Vec<(StepId, crate::exec::why::StepWhy)>,
}

impl Engine {
    /// The initial situation: every initial step active since t = 0, reported as `Activate` events at t = 0.
    pub fn new(program: Arc<Program>) -> Engine {
        let scope = Scope::whole(&program);
        Engine::with_scope(program, scope)
    }

    /// An engine that runs only `scope` of the program; with `scope.initial` FALSE it starts with no active
    /// step and waits for tokens (`RemoteInput::Activate`).
    pub fn with_scope(program: Arc<Program>, scope: Scope) -> Engine {
        assert_eq!(scope.transitions.len(), program.transitions.len(), "scope built for another program");
        assert_eq!(scope.runs_actions.len(), program.steps.len(), "scope built for another program");
        assert_eq!(scope.skill_actions.len(), program.actions.len(), "scope built for another program");
        let n_steps = program.steps.len();
        let n_actions = program.actions.len();
        let judged_here = |t: TransitionId| scope.transitions[t.index()] != TransitionScope::Remote;
        let reactive_ok = (0..program.transitions.len() as u32)
            .map(TransitionId)
            .map(|t| {
                program.sources(t).iter().all(|&s| {
                    program
                        .outgoing(s)
                        .iter()
                        .filter(|&&u| judged_here(u) && program.rank(u) <= program.rank(t))
                        .all(|&u| !program.reads(u).step_time)
                })
            })
            .collect();
        let timed = (0..n_steps as u32)
            .map(StepId)
            .map(|s| {
                let t_exit = program.outgoing(s).iter().any(|&t| judged_here(t) && program.reads(t).step_time);
                let timed_assoc = scope.runs_actions[s.index()]
                    && program.associations(s).iter().any(|a| {
                        matches!(
                            a.qualifier,
                            Qualifier::L | Qualifier::D | Qualifier::SD | Qualifier::DS | Qualifier::SL
                        )
                    });
                t_exit || timed_assoc || (scope.runs_actions[s.index()] && program.steps[s.index()].max_ms > 0)
            })
            .collect();
        let mut engine = Engine {
            vars: program.vars.iter().map(|v| v.init.clone()).collect(),
            steps: vec![
                StepState {
                    active: false,
                    reactive: false,
                    activated_gen: 0,
                    activated_ms: 0,
                    t_last_ms: 0,
                    activated_cycle: NEVER,
                    remote_cycle: NEVER,
                    slot: u32::MAX,
                    held_at: None,
                    overrun: false,
                    overrun_unacked: false,
                };
                n_steps
            ],
            active: Vec::new(),
            actions: vec![ActionState::default(); n_actions],
            live: Vec::new(),
            events: VecDeque::new(),
            collisions: 0,
            grid_origin_ms: 0,
            grid_period_ms: 1,
            mutations: 0,
            mutations_at_cycle: u64::MAX,
            gen: 0,
            judged_gen: vec![0; program.transitions.len()],
            var_gen: vec![0; program.vars.len()],
            xq_gen: 0,
            reactive_ok,
            timed,
            timed_active: 0,
            candidates: Vec::new(),
            consumed_stamp: vec![NEVER; n_steps],
            fired: Vec::new(),
            deactivated: Vec::new(),
            demand: vec![Demand::default(); n_actions],
            demand_stamp: vec![NEVER; n_actions],
            touched: vec![NEVER; n_actions],
            judged: Vec::new(),
            held: vec![false; n_steps],
            frozen_at: vec![None; n_actions],
            mode: Mode::Auto,
            permits: vec![false; program.transitions.len()],
            waiting: vec![false; program.transitions.len()],
            overrun_why: Vec::new(),
            now_ms: 0,
            cycle: 0,
            started: false,
            scope,
            program,
        };
        let initial = if engine.scope.initial { engine.program.initial_steps.clone() } else { Vec::new() };
        for s in initial {
            engine.activate(s, false);
            // The first cycle gives the initial steps their first scan, whatever reaction comes before it (an
            // agent announcing itself, a `--set` at time 0), as `baton sim` runs them.
            engine.steps[s.index()].activated_cycle = NEVER;
        }
        engine
    }

    /// An engine read back from a snapshot (`cluster::snapshot`) meets its program again. A snapshot whose sizes or
    /// ids do not fit the program is refused, so that nothing indexes past what the program has.
    pub fn attach(&mut self, program: Arc<Program>) -> Result<(), String> {
        let (n_vars, n_steps, n_actions) = (program.vars.len(), program.steps.len(), program.actions.len());
        let n_transitions = program.transitions.len();
        let sizes = [
            ("variables", self.vars.len(), n_vars),
            ("variable changes", self.var_gen.len(), n_vars),
            ("steps", self.steps.len(), n_steps),
            ("step stamps", self.consumed_stamp.len(), n_steps),
            ("held steps", self.held.len(), n_steps),
            ("timed steps", self.timed.len(), n_steps),
            ("scope steps", self.scope.runs_actions.len(), n_steps),
            ("actions", self.actions.len(), n_actions),
            ("demands", self.demand.len(), n_actions),
            ("demand stamps", self.demand_stamp.len(), n_actions),
            ("touched actions", self.touched.len(), n_actions),
            ("frozen actions", self.frozen_at.len(), n_actions),
            ("scope actions", self.scope.skill_actions.len(), n_actions),
            ("transitions", self.judged_gen.len(), n_transitions),
            ("reactive transitions", self.reactive_ok.len(), n_transitions),
            ("permits", self.permits.len(), n_transitions),
            ("waiting transitions", self.waiting.len(), n_transitions),
            ("scope transitions", self.scope.transitions.len(), n_transitions),
        ];
        if let Some((what, has, wants)) = sizes.iter().find(|(_, has, wants)| has != wants) {
            return Err(format!("it holds {has} {what} where the chart has {wants}"));
        }
        let step_ids = self.active.iter().chain(self.deactivated.iter()).map(|s| s.index());
        let step_ids = step_ids.chain(self.overrun_why.iter().map(|(s, _)| s.index()));
        if step_ids.clone().any(|s| s >= n_steps) {
            return Err("it names a step the chart does not have".into());
        }
        let action_ids = self.live.iter().chain(self.judged.iter()).map(|a| a.index());
        let transition_ids = self.fired.iter().chain(self.candidates.iter().map(|(_, t)| t)).map(|t| t.index());
        if action_ids.clone().any(|a| a >= n_actions) || transition_ids.clone().any(|t| t >= n_transitions) {
            return Err("it names an action or a transition the chart does not have".into());
        }
        let event_fits = |e: &Event| match e.kind {
            EventKind::Fire(t) | EventKind::Fault(FaultSource::Transition(t), _) => t.index() < n_transitions,
            EventKind::Activate(s) | EventKind::Deactivate(s) | EventKind::Overrun(s) => s.index() < n_steps,
            EventKind::ActionOn(a) | EventKind::ActionOff(a) | EventKind::Fault(FaultSource::Action(a), _) => {
                a.index() < n_actions
            }
        };
        let fault_fits = |e: &Event| match e.kind {
            EventKind::Fault(_, Fault::SecondToken(s)) => s.index() < n_steps,
            _ => true,
        };
        if !self.events.iter().all(|e| event_fits(e) && fault_fits(e)) {
            return Err("an event it holds names what the chart does not have".into());
        }
        if self.active.iter().enumerate().any(|(i, s)| self.steps[s.index()].slot as usize != i) {
            return Err("its active steps do not match its steps' state".into());
        }
        self.program = program;
        Ok(())
    }

    pub fn program(&self) -> &Arc<Program> {
        &self.program
    }

    /// Sets a variable before the next cycle.
    pub fn handle(&mut self, input: Input) -> Result<(), InputError> {
        let Input::Set(id, value) = input;
        let var = self.program.vars.get(id.index()).ok_or(InputError::UnknownVar(id.0))?;
        if var.constant {
            return Err(InputError::Constant { name: var.name.clone() });
        }
        // A REAL takes an integer too (a script writes 2 for 2.0).
        let fits = var.ty.fits(&value) || matches!((&var.ty, &value), (Type::Real { .. }, Value::Int(_)));
        if !fits {
            return Err(InputError::Type { name: var.name.clone(), expected: var.ty.clone(), value });
        }
        self.gen += 1;
        self.store(id, value);
        Ok(())
    }

    /// Writes a variable, noting the change (if it is one) for reactions and for `needs_cycle`.
    fn store(&mut self, id: VarId, value: Value) {
        let value = self.program.vars[id.index()].ty.coerce(value);
        if self.vars[id.index()] != value {
            self.vars[id.index()] = value;
            self.mutations += 1;
            self.var_gen[id.index()] = self.gen;
        }
    }

    /// Runs one scan cycle at `now_ms`.
    pub fn handle_cycle(&mut self, now_ms: u64) -> Result<(), InputError> {
        self.advance(now_ms)?;
        if self.mutations_at_cycle == u64::MAX {
            for i in 0..self.active.len() {
                let s = self.active[i];
                if self.steps[s.index()].activated_cycle == NEVER {
                    self.steps[s.index()].activated_cycle = self.cycle;
                }
            }
        }
        self.mutations_at_cycle = self.mutations;
        // One generation for the whole cycle: what its own actions change is judged by the next cycle, as in
        // `baton sim`, never by a reaction.
        self.gen += 1;
        self.supervise();
        self.clear_transitions(false);
        self.evolve(false);
        self.control_actions(false);
        self.deactivated.clear();
        self.cycle += 1;
        Ok(())
    }

    /// Sets the cycle grid (see `grid_floor`): the run's cycle period, from `origin_ms`.
    pub fn set_grid(&mut self, origin_ms: u64, period_ms: u64) {
        self.grid_origin_ms = origin_ms;
        self.grid_period_ms = period_ms.max(1);
    }

    /// The grid point at or before `t_ms`.
    pub fn grid_floor(&self, t_ms: u64) -> u64 {
        match t_ms.checked_sub(self.grid_origin_ms) {
            Some(d) => t_ms - d % self.grid_period_ms,
            None => t_ms,
        }
    }

    /// A reaction to what arrived since the last cycle or reaction, at `now_ms`: the first scans of steps made
    /// active (by `handle_remote` or by this reaction) and the last scans of steps left, then the transitions
    /// that read no step time and something that changed since they were last judged, judged and cleared as a
    /// cycle would, repeated while they clear (at most `REACTION_ROUNDS_MAX` times). No other action body runs.
    pub fn react(&mut self, now_ms: u64) -> Result<(), InputError> {
        self.advance(now_ms)?;
        for round in 0..REACTION_ROUNDS_MAX {
            self.gen += 1;
            self.control_actions(true);
            self.deactivated.clear();
            self.cycle += 1;
            if round + 1 == REACTION_ROUNDS_MAX {
                break;
            }
            self.gen += 1;
            self.clear_transitions(true);
            if self.fired.is_empty() {
                break;
            }
            self.gen += 1;
            self.evolve(true);
        }
        Ok(())
    }

    /// Whether a cycle could change anything: the last one (or anything since) changed something, time matters
    /// to an active step, or an action runs a body or counts time. An engine that needs no cycle stays as it is
    /// until an input comes (which a reaction handles), so skipping its cycles changes nothing.
    pub fn needs_cycle(&self) -> bool {
        let program = &self.program;
        self.mutations != self.mutations_at_cycle
            || self.timed_active > 0
            || self.live.iter().any(|a| {
                let st = &self.actions[a.index()];
                !program.actions[a.index()].body.is_empty() || st.stored_sd.is_some() || st.stored_sl.is_some()
            })
    }

    /// Applies what another engine did, at `now_ms`, at once. The actions of the steps it activates or
    /// deactivates are controlled by the next reaction (`react`) or, failing one, the next cycle, which sees
    /// them as activated or deactivated then.
    pub fn handle_remote(&mut self, now_ms: u64, input: RemoteInput) -> Result<(), InputError> {
        let program = Arc::clone(&self.program);
        match input {
            RemoteInput::Activate(s) => {
                let state = self.steps.get(s.index()).ok_or(InputError::UnknownStep(s.0))?;
                if state.active {
                    return Err(InputError::AlreadyActive(program.steps[s.index()].name.clone()));
                }
                self.advance(now_ms)?;
                self.gen += 1;
                self.activate(s, true);
                self.steps[s.index()].remote_cycle = self.cycle;
            }
            RemoteInput::Deactivate(s) => {
                let state = self.steps.get(s.index()).ok_or(InputError::UnknownStep(s.0))?;
                if !state.active {
                    return Err(InputError::NotActive(program.steps[s.index()].name.clone()));
                }
                self.advance(now_ms)?;
                self.gen += 1;
                self.deactivate(s);
            }
            RemoteInput::Fire(t) => {
                let scope = *self.scope.transitions.get(t.index()).ok_or(InputError::UnknownTransition(t.0))?;
                let name = || program.transitions[t.index()].name.clone();
                if scope != TransitionScope::Remote {
                    return Err(InputError::NotRemote(name()));
                }
                if !program.sources(t).iter().all(|s| self.steps[s.index()].active) {
                    return Err(InputError::NotEnabled(name()));
                }
                self.advance(now_ms)?;
                self.gen += 1;
                self.push(EventKind::Fire(t));
                for &s in program.sources(t) {
                    self.deactivate(s);
                }
                self.activate_targets(t, true);
                for &s in program.targets(t) {
                    self.steps[s.index()].remote_cycle = self.cycle;
                }
            }
        }
        Ok(())
    }

    fn advance(&mut self, now_ms: u64) -> Result<(), InputError> {
        if self.started && now_ms < self.now_ms {
            return Err(InputError::TimeWentBack { last_ms: self.now_ms, now_ms });
        }
        self.started = true;
        self.now_ms = now_ms;
        Ok(())
    }

    /// An engine made after t = 0 (the run a `reset` starts): its clock begins at `t_ms`, and its initial steps
    /// are active since then (their `Activate` events say so). Nothing changes once it ran.
    pub fn begin_at(&mut self, t_ms: u64) {
        if self.started {
            return;
        }
        self.now_ms = t_ms;
        for e in &mut self.events {
            e.t_ms = t_ms;
        }
        for &s in &self.active {
            self.steps[s.index()].activated_ms = t_ms;
        }
    }

    /// The time of the last cycle or remote input.
    pub fn now_ms(&self) -> u64 {
        self.now_ms
    }

    pub fn is_active(&self, s: StepId) -> bool {
        self.steps[s.index()].active
    }

    pub fn value(&self, v: VarId) -> Value {
        self.vars[v.index()].clone()
    }

    /// Whether no active step has a transition left: the chart can never evolve again.
    pub fn is_terminal(&self) -> bool {
        self.active.iter().all(|&s| self.program.outgoing(s).is_empty())
    }

    pub fn poll_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    /// The active steps, in no particular order.
    pub fn active_steps(&self) -> &[StepId] {
        &self.active
    }

    /// How many times a step received a token while it held one. A validated chart never does: a non-zero
    /// count is a bug in the validator.
    pub fn collisions(&self) -> u64 {
        self.collisions
    }

    /// Changes counted so far (events, variable values, actions' stored state): equal counts before and after
    /// a cycle mean it changed nothing.
    pub fn mutations(&self) -> u64 {
        self.mutations
    }

    fn push(&mut self, kind: EventKind) {
        self.mutations += 1;
        self.events.push_back(Event { t_ms: self.now_ms, kind });
    }

    /// Whether a reaction judges transition t now: its condition reads no step time (nor do those ranked before
    /// it), and a source became active between cycles or something it reads changed since it was last judged.
    fn reaction_judges(&self, t: TransitionId) -> bool {
        if !self.reactive_ok[t.index()] {
            return false;
        }
        let judged = self.judged_gen[t.index()];
        let reads = self.program.reads(t);
        self.program.sources(t).iter().any(|s| {
            let st = &self.steps[s.index()];
            st.reactive && st.activated_gen > judged
        }) || reads.vars.iter().any(|v| self.var_gen[v.index()] > judged)
            || (reads.steps_or_actions && self.xq_gen > judged)
    }

    /// Step (c): judge every transition leaving an active step against the same snapshot, in rank order. In a
    /// reaction, only the steps with a transition `reaction_judges` are judged, each with every transition of it
    /// that may be judged in a reaction, so that priorities hold.
    fn clear_transitions(&mut self, reaction: bool) {
        let program = Arc::clone(&self.program);
        self.candidates.clear();
        let mut deferred = false;
        for &s in &self.active {
            if self.steps[s.index()].remote_cycle == self.cycle {
                deferred = true;
                continue;
            }
            let judged_here = |t: &&TransitionId| self.scope.transitions[t.index()] != TransitionScope::Remote;
            if reaction {
                let outgoing = program.outgoing(s);
                if !outgoing.iter().filter(judged_here).any(|&t| self.reaction_judges(t)) {
                    continue;
                }
                let ok = |t: &&TransitionId| judged_here(t) && self.reactive_ok[t.index()];
                self.candidates.extend(outgoing.iter().filter(ok).map(|&t| (program.rank(t), t)));
                continue;
            }
            self.candidates.extend(program.outgoing(s).iter().filter(judged_here).map(|&t| (program.rank(t), t)));
        }
        // A step activated remotely (and not scanned by a reaction since) is judged in the next cycle, which must
        // then run: the cycle counts as a change.
        if deferred && !reaction {
            self.mutations += 1;
        }
        self.candidates.sort_unstable();
        self.candidates.dedup();
        self.fired.clear();
        let stamp = self.cycle;
        let candidates = std::mem::take(&mut self.candidates);
        // The user function calls conditions need run first, so that every condition is judged against one
        // snapshot.
        for &(_, t) in candidates.iter().filter(|_| program.has_calls()) {
            let calls = program.calls(t);
            if calls.is_empty() || !program.sources(t).iter().all(|s| self.steps[s.index()].active) {
                continue;
            }
            for call in calls {
                if let Err(fault) = eval::run(std::slice::from_ref(call), self) {
                    self.push(EventKind::Fault(FaultSource::Transition(t), fault));
                }
            }
        }
        for &(_, t) in &candidates {
            let sources = program.sources(t);
            let enabled = sources.iter().all(|s| {
                self.steps[s.index()].active
                    && self.consumed_stamp[s.index()] != stamp
                    && self.steps[s.index()].held_at.is_none()
                    && (!self.steps[s.index()].overrun_unacked || program.reads(t).overrun)
                    && self.step_t(*s) >= program.steps[s.index()].min_ms as i64
            });
            if !enabled {
                continue;
            }
            self.judged_gen[t.index()] = self.gen;
            if self.mode == Mode::Manual {
                // Conditions are not judged: only a forced transition clears, whatever its condition says.
                if std::mem::take(&mut self.permits[t.index()]) {
                    for s in sources {
                        self.consumed_stamp[s.index()] = stamp;
                    }
                    self.fired.push(t);
                }
                continue;
            }
            match eval::eval(&program.transitions[t.index()].condition, self) {
                Ok(v) if v.as_bool() && self.mode == Mode::Step && !self.permits[t.index()] => {
                    self.waiting[t.index()] = true;
                }
                Ok(v) if v.as_bool() => {
                    self.permits[t.index()] = false;
                    self.waiting[t.index()] = false;
                    for s in sources {
                        self.consumed_stamp[s.index()] = stamp;
                    }
                    self.fired.push(t);
                }
                Ok(_) => self.waiting[t.index()] = false,
                Err(fault) => self.push(EventKind::Fault(FaultSource::Transition(t), fault)),
            }
        }
        self.candidates = candidates;
    }

    /// Step (d): deactivate the sources of the cleared transitions, then activate their targets.
    fn evolve(&mut self, reaction: bool) {
        let program = Arc::clone(&self.program);
        let fired = std::mem::take(&mut self.fired);
        for &t in &fired {
            self.push(EventKind::Fire(t));
        }
        for &t in &fired {
            for &s in program.sources(t) {
                self.deactivate(s);
            }
        }
        for &t in &fired {
            if self.scope.transitions[t.index()] == TransitionScope::Local {
                self.activate_targets(t, reaction);
            }
        }
        self.fired = fired;
    }

    fn activate_targets(&mut self, t: TransitionId, reactive: bool) {
        let program = Arc::clone(&self.program);
        for &s in program.targets(t) {
            if self.steps[s.index()].active {
                // A validated chart never gets here; one whose safety could not be proven says so.
                self.collisions += 1;
                self.push(EventKind::Fault(FaultSource::Transition(t), Fault::SecondToken(s)));
            } else {
                self.activate(s, reactive);
            }
        }
    }

    /// A step made active by a cycle counts its time from now; one made active between cycles (by another
    /// engine or a reaction) counts it from the last cycle, as if it had become active in it.
    fn activate(&mut self, s: StepId, reactive: bool) {
        let slot = self.active.len() as u32;
        let since = if reactive { self.grid_floor(self.now_ms) } else { self.now_ms };
        let state = &mut self.steps[s.index()];
        state.active = true;
        state.reactive = reactive;
        state.activated_gen = self.gen;
        state.activated_ms = since;
        state.activated_cycle = self.cycle;
        state.slot = slot;
        state.held_at = self.held[s.index()].then_some(since);
        state.overrun = false;
        state.overrun_unacked = false;
        self.active.push(s);
        self.xq_gen = self.gen;
        if self.timed[s.index()] {
            self.timed_active += 1;
        }
        self.push(EventKind::Activate(s));
    }

    fn deactivate(&mut self, s: StepId) {
        let state = &mut self.steps[s.index()];
        if !state.active {
            return;
        }
        state.active = false;
        state.t_last_ms = (state.held_at.unwrap_or(self.now_ms) - state.activated_ms) as i64;
        state.held_at = None;
        state.overrun_unacked = false;
        for &t in self.program.outgoing(s) {
            self.waiting[t.index()] = false;
            self.permits[t.index()] = false;
        }
        self.xq_gen = self.gen;
        if self.timed[s.index()] {
            self.timed_active -= 1;
        }
        let slot = state.slot as usize;
        self.active.swap_remove(slot);
        if let Some(&moved) = self.active.get(slot) {
            self.steps[moved.index()].slot = slot as u32;
        }
        self.deactivated.push(s);
        self.push(EventKind::Deactivate(s));
    }
}

impl Env for Engine {
    fn var(&self, id: VarId) -> Value {
        self.vars[id.index()].clone()
    }

    fn step_x(&self, id: StepId) -> bool {
        self.steps[id.index()].active
    }

    fn step_t(&self, id: StepId) -> i64 {
        let s = &self.steps[id.index()];
        if s.active {
            (s.held_at.unwrap_or(self.now_ms) - s.activated_ms) as i64
        } else {
            s.t_last_ms
        }
    }

    fn action_q(&self, id: ActionId) -> bool {
        self.actions[id.index()].q
    }

    fn step_overrun(&self, id: StepId) -> bool {
        let s = &self.steps[id.index()];
        s.active && s.overrun
    }

    /// A reaction runs on the last cycle's time, as the steps it activates count theirs.
    fn now_ms(&self) -> i64 {
        self.grid_floor(self.now_ms) as i64
    }
}

impl EnvMut for Engine {
    fn set_var(&mut self, id: VarId, value: Value) {
        self.store(id, value);
    }
}

#[cfg(test)]
mod tests;
