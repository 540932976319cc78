//! An agent's half of a distributed run, as a pure state machine: one `AgentRun` per run the agent takes part in.
//!
//! A dispatched token activates its entry step in the agent's engine, whose scope judges the transitions of the
//! placed steps. Each cycle's clearings and action changes are reported to the coordinator, numbered per token;
//! when no step of the token's segment is active any more, the last report says `done`. Reports are kept until
//! acknowledged and resent with backoff, so a lost message or a coordinator restart loses nothing. Skills are
//! started and stopped as their actions' Q rises and falls; their results come back as indicator variables.
//!
//! The agent's engine cycles with the run's period, on a grid that starts when a token arrives at an idle agent,
//! and only while a cycle can change something: an idle agent runs no cycle. What arrives between
//! cycles (a token, values, a skill's result) is applied at once, followed by a reaction (`Engine::react`), so a
//! segment whose exit is already TRUE hands its token back without waiting for a cycle — and no action body runs
//! more than once per cycle, whatever the traffic.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::sync::Arc;

use crate::dist::io::{IoBinding, IoDir};
use crate::dist::layout::{Layout, Placement, SegmentId, SkillBinding};
use crate::dist::wire::{
    AgentEvent, AgentEventKind, ChartHash, DeviceDown, DeviceReport, HeldToken, Peers, Report, RunId, TokenId,
    VarUpdate, VarValue,
};
use crate::exec::engine::{Engine, EventKind, Input, RemoteInput};
use crate::exec::program::{ActionId, Program, StepId, VarId};
use crate::exec::sim::fault_message;
use crate::limits::{
    CATCH_UP_CYCLES_MAX, FINISHED_TOKENS_REMEMBERED, PARKED_UPDATE_BYTES_MAX, REPORTS_UNACKED_MAX, REPORT_EVENTS_MAX,
};
use crate::types::Value;

use super::{Level, VarWrites, VarsResend, COORDINATOR};
use uuid::Uuid;

/// Processes whose refused variable updates an agent remembers having logged.
const REFUSALS_SAID_MAX: usize = 64;

/// First and largest delay before an unacknowledged report is sent again.
const RESEND_FIRST_MS: u64 = 200;
const RESEND_MAX_MS: u64 = 5_000;

#[derive(Clone, Debug, PartialEq)]
pub enum AgentOutput {
    Report(Report),
    Vars(VarUpdate),
    /// Start the skill bound to `action`; its result comes back through `handle_skill_result`.
    StartSkill {
        action: ActionId,
        name: String,
        binding: SkillBinding,
    },
    /// The action's Q fell: cancel its skill if it still runs.
    StopSkill {
        action: ActionId,
    },
    /// Send this value of an output-bound variable to its device (`Layout::io[binding]`): its first value when
    /// the agent joins the run, then every change.
    Output {
        binding: usize,
        value: Value,
    },
    /// Tell the coordinator which bound devices this agent cannot reach.
    Devices(DeviceReport),
    Log {
        level: Level,
        message: String,
    },
}

/// A dispatch, decoded: run `segment` from `entry`.
#[derive(Clone, Debug, PartialEq)]
pub struct Dispatch {
    pub token: TokenId,
    pub epoch: u32,
    pub segment: u32,
    pub entry: u32,
    pub vars: Vec<VarValue>,
    pub vars_seq: u64,
    /// The coordinator may give the token to another agent if this one is lost: fence its skills.
    pub fence: bool,
    pub peers: Peers,
}

/// A join, decoded: the run's values and writers, before any token.
#[derive(Clone, Debug, PartialEq)]
pub struct Join {
    pub vars: Vec<VarValue>,
    pub vars_seq: u64,
    pub peers: Peers,
}

struct Unacked {
    report: Report,
    sent_ms: u64,
    resend_at_ms: u64,
    backoff_ms: u64,
}

struct Holding {
    epoch: u32,
    fence: bool,
    segment: SegmentId,
    arrived_ms: u64,
    next_seq: u32,
    events: Vec<AgentEvent>,
    done: bool,
    unacked: VecDeque<Unacked>,
}

pub struct AgentRun {
    name: String,
    serves: Vec<Placement>,
    run: RunId,
    hash: ChartHash,
    program: Arc<Program>,
    layout: Arc<Layout>,
    engine: Engine,
    now_ms: u64,
    /// The run's cycle period, and when the next cycle is due (none while no cycle could change anything).
    cycle_ms: u64,
    next_cycle_ms: Option<u64>,
    /// The engine's grid is set: the first cycle planned (or the first token) set it, and every later cycle and
    /// every time the engine floors (a step's activation, a timer's start) is on it.
    grid_set: bool,
    tokens: BTreeMap<TokenId, Holding>,
    by_segment: BTreeMap<SegmentId, TokenId>,
    /// Finished or dropped tokens and their last epoch here: a dispatch of that epoch or older is a duplicate.
    finished: BTreeMap<TokenId, u32>,
    finished_order: VecDeque<TokenId>,
    /// Variables this agent may write; `pinned` marks those only it writes (placed on it by name), the others
    /// belong to a role it shares with other agents and follow whichever of them wrote last.
    owned: Vec<VarId>,
    pinned: Vec<bool>,
    published: Vec<Value>,
    /// Values changed since the last report, by variable: the next report carries them.
    unreported: BTreeMap<u32, Value>,
    vars_seq: u64,
    /// When this process's values are published again (`VARS_RESEND_FIRST_MS`), and the delay after that.
    /// When the values only this agent writes are published again (`VarsResend`).
    vars_resend: VarsResend,
    /// This agent's process: its variable updates are numbered within it.
    incarnation: Uuid,
    /// The last write applied to each variable written elsewhere.
    var_writes: VarWrites,
    /// Who may publish the variables this agent reads, as the coordinator said last (`None` before its first
    /// dispatch or join).
    peers: Option<Peers>,
    /// This process took the coordinator's values of the variables it writes itself (its first dispatch or join):
    /// from then on its own values are the run's.
    seeded: bool,
    /// Updates from a process of a known writer that the coordinator has not named yet (it restarted, and its
    /// first values overtook the news), held until it does, at most `PARKED_UPDATE_BYTES_MAX`.
    parked: VecDeque<VarUpdate>,
    parked_bytes: usize,
    /// The processes whose refused updates were logged already.
    refusals_said: VecDeque<(String, Uuid)>,
    /// Per action: the segments with a step that uses it.
    action_segments: Vec<Vec<SegmentId>>,
    running_skills: BTreeSet<ActionId>,
    /// Since this agent lost its router (for how long it had been silent then): the skills of tokens that may be
    /// taken away are stopped and none starts.
    fenced: Option<u64>,
    outbox: VecDeque<AgentOutput>,
    dropped: u64,
    /// Per binding of `Layout::io`: the value last sent to an output's device (`None`: not sent, or not ours).
    io_sent: Vec<Option<Value>>,
    /// The bindings whose device cannot be reached, and why; the number of the last `DeviceReport`.
    devices_down: BTreeMap<usize, String>,
    devices_seq: u64,
}

impl AgentRun {
    pub fn new(
        name: &str,
        roles: &[String],
        run: RunId,
        hash: ChartHash,
        program: Arc<Program>,
        layout: Arc<Layout>,
        cycle_ms: u64,
    ) -> AgentRun {
        let mut serves = vec![Placement::Agent(name.to_string())];
        serves.extend(roles.iter().map(|r| Placement::Role(r.clone())));
        let owned: Vec<VarId> =
            (0..program.vars.len()).filter(|&i| serves.contains(&layout.writer[i])).map(|i| VarId(i as u32)).collect();
        let engine = Engine::with_scope(Arc::clone(&program), layout.agent_scope(&program));
        let program_vars = program.vars.len();
        let published = owned.iter().map(|&v| engine.value(v)).collect();
        let pinned: Vec<bool> =
            owned.iter().map(|v| layout.writer[v.index()] == Placement::Agent(name.to_string())).collect();
        let mut action_segments = vec![Vec::new(); program.actions.len()];
        for (g, seg) in layout.segments.iter().enumerate() {
            for &s in &seg.steps {
                for assoc in program.associations(s) {
                    let list: &mut Vec<SegmentId> = &mut action_segments[assoc.action.index()];
                    if !list.contains(&SegmentId(g as u32)) {
                        list.push(SegmentId(g as u32));
                    }
                }
            }
        }
        let bindings = layout.io.len();
        let mut run = AgentRun {
            name: name.to_string(),
            serves,
            run,
            hash,
            program,
            layout,
            engine,
            now_ms: 0,
            cycle_ms: cycle_ms.max(1),
            next_cycle_ms: None,
            grid_set: false,
            tokens: BTreeMap::new(),
            by_segment: BTreeMap::new(),
            finished: BTreeMap::new(),
            finished_order: VecDeque::new(),
            owned,
            pinned,
            published,
            unreported: BTreeMap::new(),
            vars_seq: 0,
            vars_resend: VarsResend::default(),
            incarnation: Uuid::nil(),
            var_writes: VarWrites::new(program_vars),
            peers: None,
            seeded: false,
            parked: VecDeque::new(),
            parked_bytes: 0,
            refusals_said: VecDeque::new(),
            action_segments,
            running_skills: BTreeSet::new(),
            fenced: None,
            outbox: VecDeque::new(),
            dropped: 0,
            io_sent: vec![None; bindings],
            devices_down: BTreeMap::new(),
            devices_seq: 0,
        };
        run.send_outputs();
        run
    }

    /// The variables bound to devices on this agent, by their index in `Layout::io`.
    pub fn io_here(&self) -> impl Iterator<Item = (usize, &IoBinding)> + '_ {
        self.layout.io.iter().enumerate().filter(move |(_, b)| b.agent == self.name)
    }

    /// A sample from the device of input binding `binding`: its value, as the device gave it, is converted to the
    /// variable's type. A text where the variable is not a STRING is refused (a corrupt or foreign sample), and
    /// the variable keeps its value.
    pub fn handle_input(&mut self, now_ms: u64, binding: usize, value: Value) {
        self.catch_up(now_ms);
        let Some(b) = self.layout.io.get(binding).filter(|b| b.agent == self.name && b.dir == IoDir::Input) else {
            self.dropped += 1;
            return;
        };
        let (var, name) = (b.var, b.name.clone());
        let ty = &self.program.vars[var.index()].ty;
        if matches!(value, Value::Str(_)) && !matches!(ty, crate::types::Type::Str { .. }) {
            self.dropped += 1;
            let message =
                format!("input `{name}`: `{value}` is not a {ty}; the value stays {}", self.engine.value(var));
            self.log(Level::Warn, message);
            return;
        }
        self.write_from_device(var, value, format!("input `{name}`"));
    }

    /// Writes what a device gave (a skill's answer, a bound input) to `var`, converted to its type as `*_TO_*`
    /// converts, then reacts.
    fn write_from_device(&mut self, var: VarId, value: Value, what: String) {
        let ty = self.program.vars[var.index()].ty.clone();
        let value = crate::exec::stdlib::convert(value, &ty);
        if let Err(e) = self.engine.handle(Input::Set(var, value)) {
            self.log(Level::Warn, format!("{what}: {e}"));
        }
        self.settle();
    }

    /// Whether the device of binding `binding` (`Layout::io`, on this agent) can be reached: `Err` says why not.
    /// A change is logged and reported to the coordinator; a new reason while it stays down replaces the old one
    /// quietly (a device retried every second would flood the log). Meanwhile an input keeps its value.
    pub fn handle_device(&mut self, binding: usize, state: Result<(), String>) {
        let Some(b) = self.layout.io.get(binding).filter(|b| b.agent == self.name) else {
            self.dropped += 1;
            return;
        };
        let what = format!("{} `{}` ({})", if b.dir == IoDir::Input { "input" } else { "output" }, b.name, b.device());
        let (var, dir) = (b.var, b.dir);
        match state {
            Ok(()) => {
                if self.devices_down.remove(&binding).is_some() {
                    self.log(Level::Info, format!("{what}: reachable again"));
                    self.report_devices();
                }
            }
            Err(why) => {
                let why: String = why.chars().take(crate::limits::DEVICE_MESSAGE_CHARS_MAX).collect();
                if self.devices_down.insert(binding, why.clone()).is_none() {
                    let keeps = match dir {
                        IoDir::Input => format!("it keeps its value {}", self.engine.value(var)),
                        IoDir::Output => "its value goes to the device once it is back".to_string(),
                    };
                    self.log(Level::Warn, format!("{what}: {why}; {keeps}"));
                    self.report_devices();
                }
            }
        }
    }

    /// The coordinator asks this agent to take part in the run: it restarted, or saw this agent come back. The
    /// join carries the run's values (a new process takes even its own) and writers; the coordinator hears again
    /// which devices are down (it may have missed the report) and every value this agent writes.
    pub fn handle_join(&mut self, now_ms: u64, join: Join) {
        self.catch_up(now_ms);
        self.handle_peers_table(join.peers);
        self.take_coordinator_values(&join.vars, join.vars_seq);
        if self.io_here().next().is_some() {
            self.report_devices();
        }
        self.republish();
        self.settle();
    }

    /// The coordinator's values in a dispatch or a join: the variables this agent writes only while it has not
    /// taken part in the run yet, the others as of `vars_seq` (what another agent wrote is only relayed: that
    /// agent's own updates win).
    fn take_coordinator_values(&mut self, vars: &[VarValue], vars_seq: u64) {
        let seed = !std::mem::replace(&mut self.seeded, true);
        let coordinator = self.peers.as_ref().map_or(Uuid::nil(), |p| p.coordinator);
        for vv in vars {
            let relay =
                vv.resolve(&self.program).is_some_and(|(v, _)| self.layout.writer[v.index()] != Placement::Coordinator);
            if !self.accept_external(vv, COORDINATOR, coordinator, vars_seq, relay, seed) {
                self.dropped += 1;
            }
        }
    }

    /// Every value only this agent writes goes out again in a fresh update: a coordinator that started again from
    /// its journal, or a link that lost messages, may have missed the last ones. A role's variable is not said
    /// again: the agents of the role write it in turn, and a value said again would overwrite a newer one of
    /// another agent (the coordinator hears a role's values in reports, which are resent until acknowledged).
    fn republish(&mut self) {
        // A process that has not taken part in the run yet holds the chart's initial values, not the run's.
        if !self.seeded {
            return;
        }
        for v in self.mine() {
            self.unreported.insert(v.0, self.engine.value(v));
        }
        let read = self.mine_read();
        if read.is_empty() {
            return;
        }
        self.vars_seq += 1;
        self.publish(read);
    }

    /// The variables only this agent writes.
    fn mine(&self) -> Vec<VarId> {
        self.owned.iter().zip(&self.pinned).filter(|(_, &pinned)| pinned).map(|(&v, _)| v).collect()
    }

    /// The values of those that other agents read.
    fn mine_read(&self) -> Vec<VarValue> {
        self.mine()
            .into_iter()
            .filter(|v| self.layout.read_by_agents[v.index()])
            .map(|v| VarValue::new(v, self.engine.value(v)))
            .collect()
    }

    /// Publishes `vars` as update `vars_seq`, and plans to publish the values only this agent writes again.
    fn publish(&mut self, vars: Vec<VarValue>) {
        let update = VarUpdate {
            run: self.run,
            from: self.name.clone(),
            incarnation: self.incarnation,
            seq: self.vars_seq,
            vars,
        };
        self.outbox.push_back(AgentOutput::Vars(update));
        self.vars_resend.start(self.now_ms);
    }

    /// Publishes the values only this agent writes again, as of its last update, when that is due.
    fn resend_vars(&mut self) {
        if !self.vars_resend.due(self.now_ms) {
            return;
        }
        let read = self.mine_read();
        if !read.is_empty() {
            let update = VarUpdate {
                run: self.run,
                from: self.name.clone(),
                incarnation: self.incarnation,
                seq: self.vars_seq,
                vars: read,
            };
            self.outbox.push_back(AgentOutput::Vars(update));
        }
    }

    /// The coordinator says who may publish the variables this agent reads. A writer's new process retires its
    /// old one, whose late updates are refused; updates parked for a process now named apply.
    pub fn handle_peers(&mut self, now_ms: u64, peers: Peers) {
        self.catch_up(now_ms);
        self.handle_peers_table(peers);
        self.settle();
    }

    fn handle_peers_table(&mut self, peers: Peers) {
        if self.peers.as_ref().is_some_and(|p| p.seq >= peers.seq) {
            return;
        }
        if let Some(old) = self.peers.take() {
            for gone in old.agents {
                let same = peers.agents.iter().any(|p| p.name == gone.name && p.incarnation == gone.incarnation);
                if !same {
                    self.var_writes.retire(gone.name, gone.incarnation);
                }
            }
        }
        self.peers = Some(peers);
        let parked = std::mem::take(&mut self.parked);
        self.parked_bytes = 0;
        let mut parked: Vec<VarUpdate> = parked.into_iter().collect();
        parked.sort_by_key(|u| u.seq);
        for update in parked {
            self.take_update(&update);
        }
    }

    fn report_devices(&mut self) {
        self.devices_seq += 1;
        let down = self
            .devices_down
            .iter()
            .map(|(b, message)| DeviceDown { binding: *b as u32, message: message.clone() })
            .collect();
        self.outbox.push_back(AgentOutput::Devices(DeviceReport {
            run: self.run,
            agent: self.name.clone(),
            incarnation: self.incarnation,
            seq: self.devices_seq,
            down,
        }));
    }

    /// Queues the output-bound variables of this agent whose value changed since they were last sent.
    fn send_outputs(&mut self) {
        for i in 0..self.layout.io.len() {
            let b = &self.layout.io[i];
            if b.agent != self.name || b.dir != IoDir::Output {
                continue;
            }
            let value = self.engine.value(b.var);
            if self.io_sent[i].as_ref() != Some(&value) {
                self.io_sent[i] = Some(value.clone());
                self.outbox.push_back(AgentOutput::Output { binding: i, value });
            }
        }
    }

    /// This agent's process (`AgentInfo::incarnation`), which numbers its variable updates.
    pub fn set_incarnation(&mut self, incarnation: Uuid) {
        self.incarnation = incarnation;
    }

    pub fn hash(&self) -> &ChartHash {
        &self.hash
    }

    pub fn program(&self) -> &Arc<Program> {
        &self.program
    }

    /// The skills of the actions that run on this agent (by its name or one of its roles), with their actions.
    pub fn skills_here(&self) -> impl Iterator<Item = (ActionId, &SkillBinding)> + '_ {
        self.layout.skills.iter().enumerate().filter_map(|(i, b)| {
            let b = b.as_ref().filter(|_| self.serves.contains(&self.layout.action_placement[i]))?;
            Some((ActionId(i as u32), b))
        })
    }

    pub fn tokens_held(&self) -> usize {
        self.tokens.values().filter(|t| !t.done).count()
    }

    /// The tokens held here, running or finished with reports not yet acknowledged, in id order.
    pub fn held(&self) -> Vec<HeldToken> {
        let mut held: Vec<HeldToken> =
            self.tokens.iter().map(|(&token, t)| HeldToken { run: self.run, token, epoch: t.epoch }).collect();
        held.sort_unstable();
        held
    }

    /// How many times this agent's engine gave a step a second token (a validated chart: never).
    pub fn collisions(&self) -> u64 {
        self.engine.collisions()
    }

    /// When the oldest report not yet acknowledged was first sent.
    pub fn oldest_unacked_ms(&self) -> Option<u64> {
        self.tokens.values().filter_map(|t| t.unacked.front().map(|u| u.sent_ms)).min()
    }

    /// Messages dropped as duplicates, stale or invalid.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    pub fn poll_output(&mut self) -> Option<AgentOutput> {
        self.outbox.pop_front()
    }

    fn log(&mut self, level: Level, message: String) {
        self.outbox.push_back(AgentOutput::Log { level, message });
    }

    fn drop_msg(&mut self, message: String) {
        self.dropped += 1;
        self.log(Level::Warn, message);
    }

    fn advance(&mut self, now_ms: u64) {
        self.now_ms = self.now_ms.max(now_ms);
    }

    /// Runs the cycles due by `now_ms`, each at its grid time, before anything that arrived at `now_ms` is
    /// applied. A shell that could not keep up (the process was stopped) skips to the grid point before
    /// `now_ms` past `CATCH_UP_CYCLES_MAX` missed cycles, rather than running them back to back.
    fn catch_up(&mut self, now_ms: u64) {
        while let Some(due) = self.next_cycle_ms.filter(|&t| t <= now_ms) {
            let at =
                if now_ms - due > CATCH_UP_CYCLES_MAX * self.cycle_ms { self.engine.grid_floor(now_ms) } else { due };
            self.advance(at);
            if let Err(e) = self.engine.handle_cycle(at) {
                self.log(Level::Error, format!("cycle refused: {e}"));
            }
            self.drain_engine();
            self.next_cycle_ms = self.engine.needs_cycle().then_some(at + self.cycle_ms);
        }
        self.advance(now_ms);
    }

    /// After an input: the engine reacts at once, the next cycle is planned if one is needed, and the news
    /// is reported.
    fn settle(&mut self) {
        if let Err(e) = self.engine.react(self.now_ms) {
            self.log(Level::Error, format!("reaction refused: {e}"));
        }
        self.drain_engine();
        if self.next_cycle_ms.is_none() && self.engine.needs_cycle() {
            // The first cycle planned starts the grid here: otherwise the engine would floor times to the
            // millisecond while cycles run every cycle_ms, and a token arriving between two of them would
            // count its step's time, and start its timers, off the grid its cycles run on.
            if !self.grid_set {
                self.engine.set_grid(self.now_ms, self.cycle_ms);
                self.grid_set = true;
            }
            self.next_cycle_ms = Some(self.engine.grid_floor(self.now_ms) + self.cycle_ms);
        }
        self.report();
    }

    /// An agent with no cycle planned starts its grid when a token arrives: its first cycle runs at once. Nothing
    /// active here depends on the grid's phase then (otherwise a cycle would be planned).
    fn anchor_grid(&mut self) {
        if self.next_cycle_ms.is_some() {
            return;
        }
        self.engine.set_grid(self.now_ms, self.cycle_ms);
        self.grid_set = true;
        if let Err(e) = self.engine.handle_cycle(self.now_ms) {
            self.log(Level::Error, format!("cycle refused: {e}"));
        }
        self.drain_engine();
        self.next_cycle_ms = Some(self.now_ms + self.cycle_ms);
    }

    /// When this run next needs `handle_timeout`: its next cycle, or the next report to send again.
    pub fn poll_timeout(&self) -> Option<u64> {
        let resend = self.tokens.values().flat_map(|t| t.unacked.iter().map(|u| u.resend_at_ms)).min();
        [self.next_cycle_ms, resend, self.vars_resend.at_ms()].into_iter().flatten().min()
    }

    /// Time passed: the cycles due run, reports due are sent again.
    pub fn handle_timeout(&mut self, now_ms: u64) {
        self.catch_up(now_ms);
        self.report();
        self.resend(now_ms, false);
        self.resend_vars();
    }

    /// A token arrives. A duplicate (same token and epoch, or an older epoch) or a token already finished in
    /// that epoch changes nothing; a newer epoch of a token dropped here runs.
    pub fn handle_dispatch(&mut self, now_ms: u64, d: Dispatch) {
        self.catch_up(now_ms);
        let seen = self.tokens.get(&d.token).map(|t| t.epoch).or_else(|| self.finished.get(&d.token).copied());
        if seen.is_some_and(|epoch| epoch >= d.epoch) {
            self.dropped += 1;
            return;
        }
        if self.tokens.contains_key(&d.token) {
            // A newer epoch of a token held here: the old one is over.
            self.forget(d.token);
        }
        let Some(segment) = self.layout.segments.get(d.segment as usize) else {
            return self.drop_msg(format!("dispatch of token {} names unknown segment {}", d.token, d.segment));
        };
        let g = SegmentId(d.segment);
        let entry = StepId(d.entry);
        if !segment.steps.contains(&entry) {
            return self.drop_msg(format!("dispatch of token {} enters its segment at a step outside it", d.token));
        }
        if !self.serves.contains(&segment.placement) {
            let p = segment.placement.to_string();
            return self.drop_msg(format!(
                "token {} dropped: its segment is placed on {p}, which `{}` does not serve",
                d.token, self.name
            ));
        }
        if let Some(other) = self.by_segment.get(&g) {
            let other = *other;
            return self
                .drop_msg(format!("token {} dropped: token {other} already runs the same segment here", d.token));
        }
        self.handle_peers_table(d.peers);
        self.take_coordinator_values(&d.vars, d.vars_seq);
        self.anchor_grid();
        if let Err(e) = self.engine.handle_remote(self.now_ms, RemoteInput::Activate(entry)) {
            return self.drop_msg(format!("token {} dropped: {e}", d.token));
        }
        let held = Holding {
            epoch: d.epoch,
            fence: d.fence,
            segment: g,
            arrived_ms: self.now_ms,
            next_seq: 0,
            events: Vec::new(),
            done: false,
            unacked: VecDeque::new(),
        };
        self.tokens.insert(d.token, held);
        self.by_segment.insert(g, d.token);
        self.settle();
    }

    /// The coordinator took this token back (its segment went to another epoch): stop running it.
    pub fn handle_drop(&mut self, now_ms: u64, token: TokenId, epoch: u32) {
        self.catch_up(now_ms);
        if self.tokens.get(&token).is_some_and(|t| t.epoch == epoch) {
            self.log(Level::Warn, format!("token {token} epoch {epoch} dropped at the coordinator's request"));
            self.forget(token);
            self.settle();
        }
    }

    /// Deactivates what a token still holds here and forgets it; its actions stop in the next cycle.
    fn forget(&mut self, token: TokenId) {
        let Some(held) = self.tokens.remove(&token) else { return };
        if self.by_segment.get(&held.segment) == Some(&token) {
            self.by_segment.remove(&held.segment);
        }
        for s in self.layout.segments[held.segment.index()].steps.clone() {
            if self.engine.is_active(s) {
                let _ = self.engine.handle_remote(self.now_ms, RemoteInput::Deactivate(s));
            }
        }
        self.remember_finished(token, held.epoch);
    }

    /// Remembers a finished token, to recognise a late duplicate of its dispatch; the oldest are forgotten.
    fn remember_finished(&mut self, token: TokenId, epoch: u32) {
        if self.finished.insert(token, epoch).is_none() {
            if self.finished_order.len() >= FINISHED_TOKENS_REMEMBERED {
                if let Some(old) = self.finished_order.pop_front() {
                    self.finished.remove(&old);
                }
            }
            self.finished_order.push_back(token);
        }
    }

    /// The coordinator applied this token's reports up to `seq`.
    pub fn handle_ack(&mut self, token: TokenId, epoch: u32, seq: u32, done: bool) {
        let Some(held) = self.tokens.get_mut(&token) else { return };
        if held.epoch != epoch {
            return;
        }
        let full = held.unacked.len() >= REPORTS_UNACKED_MAX;
        while held.unacked.front().is_some_and(|u| u.report.seq <= seq) {
            held.unacked.pop_front();
        }
        if done && held.done && held.unacked.is_empty() {
            self.tokens.remove(&token);
            self.remember_finished(token, epoch);
        } else if full {
            // Room again: what waited leaves now.
            self.report();
        }
    }

    /// Variables published by the coordinator or another agent; the latest update of each writer wins. An agent
    /// applies the coordinator's rules: a value is taken only from the variable's one writer (the coordinator,
    /// its agent, or an agent of its role), and only from the process of that writer the coordinator named
    /// (`Peers`). An update of a known writer's process not named yet waits for the coordinator's word; anything
    /// else is counted and dropped.
    pub fn handle_vars(&mut self, now_ms: u64, update: &VarUpdate) {
        if update.from == self.name || update.run != self.run {
            return;
        }
        if update.from != COORDINATOR && !crate::dist::keys::is_valid_name(&update.from) {
            self.dropped += 1;
            return;
        }
        self.catch_up(now_ms);
        self.take_update(update);
        self.settle();
    }

    /// Whether `from`'s process `incarnation` is the one the coordinator named: `None` when it named none of `from`.
    fn known_process(&self, from: &str, incarnation: Uuid) -> Option<bool> {
        let peers = self.peers.as_ref()?;
        if from == COORDINATOR {
            return Some(peers.coordinator == incarnation);
        }
        peers.agents.iter().find(|p| p.name == from).map(|p| p.incarnation == incarnation)
    }

    fn take_update(&mut self, update: &VarUpdate) {
        let from = update.from.as_str();
        match self.known_process(from, update.incarnation) {
            Some(true) => {}
            // A new process of a writer the coordinator knows (or of an agent of a writing role it has not told
            // about yet): its values wait for the coordinator's word, unless the process was replaced already.
            None | Some(false)
                if from != COORDINATOR
                    && self.may_write(from)
                    && !self.var_writes.is_retired(from, update.incarnation) =>
            {
                return self.park(update.clone());
            }
            _ => {
                let why = if from == COORDINATOR {
                    "it claims to come from the coordinator, but from another process than the run's".to_string()
                } else if self.var_writes.is_retired(from, update.incarnation) {
                    format!("it comes from a process of `{from}` that a newer one replaced")
                } else {
                    format!("`{from}` writes none of the variables this agent reads")
                };
                return self.refuse(update, why);
            }
        }
        let mut foreign = 0;
        for vv in &update.vars {
            let ok = vv.resolve(&self.program).is_some_and(|(v, _)| self.writes(from, v));
            if !ok || !self.accept_external(vv, from, update.incarnation, update.seq, false, false) {
                foreign += 1;
            }
        }
        if foreign > 0 {
            self.refuse(
                update,
                format!("{foreign} of its values are of variables `{from}` does not write, or of the wrong type"),
            );
        }
    }

    /// Whether `from` may write a variable this agent reads: an agent placed by name on one, or any agent while a
    /// role writes one (the coordinator names the agents of a role as they come).
    fn may_write(&self, from: &str) -> bool {
        self.layout.writer.iter().zip(&self.layout.read_by_agents).any(|(w, &read)| {
            read && match w {
                Placement::Agent(a) => a == from,
                Placement::Role(_) => true,
                Placement::Coordinator => false,
            }
        })
    }

    /// Counts a refused update, and says so once per sending process (a peer that keeps sending is not a log
    /// flood).
    fn refuse(&mut self, update: &VarUpdate, why: String) {
        self.dropped += 1;
        let key = (update.from.clone(), update.incarnation);
        if self.refusals_said.contains(&key) {
            return;
        }
        if self.refusals_said.len() >= REFUSALS_SAID_MAX {
            self.refusals_said.pop_front();
        }
        self.refusals_said.push_back(key);
        self.log(Level::Warn, format!("variable update from `{}` refused: {why}", update.from));
    }

    /// Whether `from` is the one writer of `var`: the coordinator for its own, an agent for those placed on it or
    /// on a role the coordinator says it has.
    fn writes(&self, from: &str, var: VarId) -> bool {
        match &self.layout.writer[var.index()] {
            Placement::Coordinator => from == COORDINATOR,
            Placement::Agent(a) => a == from,
            Placement::Role(r) => self
                .peers
                .as_ref()
                .and_then(|p| p.agents.iter().find(|p| p.name == from))
                .is_some_and(|p| p.roles.iter().any(|x| x == r)),
        }
    }

    /// Holds an update until the coordinator names its process; the oldest go first past the byte bound.
    fn park(&mut self, update: VarUpdate) {
        let bytes = update.weight();
        if bytes > PARKED_UPDATE_BYTES_MAX {
            self.dropped += 1;
            return;
        }
        while self.parked_bytes + bytes > PARKED_UPDATE_BYTES_MAX {
            let Some(old) = self.parked.pop_front() else { break };
            self.parked_bytes -= old.weight();
            self.dropped += 1;
        }
        self.parked_bytes += bytes;
        self.parked.push_back(update);
    }

    /// Takes a value written elsewhere, unless this agent alone writes the variable (but for the coordinator's
    /// values given to a process that has not taken part yet: `seed`) or a newer write of it was taken already.
    /// Returns false for a value refused as invalid or misdirected.
    fn accept_external(
        &mut self,
        vv: &VarValue,
        from: &str,
        incarnation: Uuid,
        seq: u64,
        relay: bool,
        seed: bool,
    ) -> bool {
        let Some((var, value)) = vv.resolve(&self.program) else { return false };
        let i = self.owned.iter().position(|&v| v == var);
        if let Some(i) = i.filter(|&i| self.pinned[i]) {
            if !seed {
                return false;
            }
            // The run's value of a variable only this agent writes: where a new process starts from.
            self.published[i] = value.clone();
            return self.engine.handle(Input::Set(var, value)).is_ok();
        }
        if !self.var_writes.accept(var.index(), from, incarnation, seq, relay) {
            return true;
        }
        if let Some(i) = i {
            // A role's variable another agent wrote: take it as already published, not as our own change.
            self.published[i] = value.clone();
        }
        self.engine.handle(Input::Set(var, value)).is_ok()
    }

    /// Why the skills of `token` may not run now: the agent lost its router and the token may be given to
    /// another agent.
    fn fence_of(&self, token: Option<TokenId>) -> Option<String> {
        let silent_ms = self.fenced?;
        let fenced = token.and_then(|t| self.tokens.get(&t)).is_some_and(|h| h.fence);
        fenced.then(|| {
            format!(
                "the agent had no contact with its router for {silent_ms} ms, and the token may go to another agent (lease fence)"
            )
        })
    }

    /// The shell's watch on the router: `Some(silent_ms)` once the agent has not heard its router for a quarter of
    /// its lease (`limits::fence_after_ms`), `None` when it hears it again. While fenced, the skills of tokens the
    /// coordinator may give to another agent are cancelled and none starts: each is reported as a skill fault,
    /// which reaches the coordinator when the link is back (and is stale there if the token moved).
    pub fn handle_contact(&mut self, now_ms: u64, lost: Option<u64>) {
        self.catch_up(now_ms);
        match (std::mem::replace(&mut self.fenced, lost), lost) {
            (None, Some(_)) => {}
            (Some(_), None) => {
                self.log(Level::Info, "the router is back: skills start again".to_string());
                // Updates published while the link was down may be lost: every reader hears them again.
                self.republish();
                return self.settle();
            }
            _ => return,
        }
        let mut stopped: Vec<ActionId> = self.running_skills.iter().copied().collect();
        stopped.sort_unstable();
        for a in stopped {
            let token = action_token(&self.action_segments, &self.by_segment, a);
            let Some(why) = self.fence_of(token) else { continue };
            self.running_skills.remove(&a);
            self.outbox.push_back(AgentOutput::StopSkill { action: a });
            self.set_indicators(a, Some(false), Some(true));
            self.log(
                Level::Warn,
                format!("skill of action `{}` cancelled: {why}", self.program.actions[a.index()].name),
            );
            self.record(token, AgentEventKind::SkillFault { action: a.0, message: format!("cancelled: {why}") });
        }
        self.settle();
    }

    /// A skill finished: its action's indicator variables say so (first: done, second: fault).
    pub fn handle_skill_result(&mut self, now_ms: u64, action: ActionId, result: Result<(), String>) {
        self.catch_up(now_ms);
        if !self.running_skills.remove(&action) {
            return;
        }
        let ok = result.is_ok();
        self.set_indicators(action, Some(ok), Some(!ok));
        let kind = match result {
            Ok(()) => AgentEventKind::SkillDone { action: action.0 },
            Err(message) => AgentEventKind::SkillFault { action: action.0, message },
        };
        self.record(action_token(&self.action_segments, &self.by_segment, action), kind);
        self.settle();
    }

    /// A part of a running skill's answer (a feedback, the result before it is reported done): the value goes to
    /// the variable its binding's `outputs[output]` names, converted to the variable's type as `*_TO_*` does.
    /// A skill that no longer runs writes nothing: its action's Q fell, and the chart has moved on.
    pub fn handle_skill_output(&mut self, now_ms: u64, action: ActionId, output: usize, value: Value) {
        self.catch_up(now_ms);
        if !self.running_skills.contains(&action) {
            return;
        }
        let Some(var) = self.layout.skills[action.index()].as_ref().and_then(|b| b.outputs.get(output)).map(|o| o.var)
        else {
            return;
        };
        let what = format!("skill of action `{}`", self.program.actions[action.index()].name);
        self.write_from_device(var, value, what);
    }

    /// A skill stopped because its action's Q fell has ended its own way (a ROS 2 goal cancelled, a cancel
    /// method called): said in the log, since the chart no longer waits for it.
    /// `result` says how: `Ok` with what the device answered, or `Err` with why the stop failed.
    pub fn handle_skill_stopped(&mut self, action: ActionId, result: Result<String, String>) {
        let name = &self.program.actions[action.index()].name;
        let (level, message) = match result {
            Ok(how) => (Level::Info, format!("skill of action `{name}` stopped: {how}")),
            Err(why) => (Level::Warn, format!("skill of action `{name}` did not stop cleanly: {why}")),
        };
        self.log(level, message);
    }

    /// Sets the indicators of `action`'s associations on the active steps: the first to `done`, the second
    /// to `fault` (where given).
    fn set_indicators(&mut self, action: ActionId, done: Option<bool>, fault: Option<bool>) {
        let program = Arc::clone(&self.program);
        let mut sets: Vec<(VarId, bool)> = Vec::new();
        for &s in self.engine.active_steps() {
            for (assoc, inds) in program.associations(s).iter().zip(program.indicators(s)) {
                if assoc.action != action {
                    continue;
                }
                if let (Some(&v), Some(b)) = (inds.first(), done) {
                    sets.push((v, b));
                }
                if let (Some(&v), Some(b)) = (inds.get(1), fault) {
                    sets.push((v, b));
                }
            }
        }
        for (v, b) in sets {
            let _ = self.engine.handle(Input::Set(v, Value::Bool(b)));
        }
    }

    fn record(&mut self, token: Option<TokenId>, kind: AgentEventKind) {
        let Some(token) = token else { return };
        let Some(held) = self.tokens.get_mut(&token) else { return };
        let dt_ms = self.now_ms.saturating_sub(held.arrived_ms);
        held.events.push(AgentEvent { dt_ms, kind });
    }

    fn drain_engine(&mut self) {
        let program = Arc::clone(&self.program);
        while let Some(ev) = self.engine.poll_event() {
            match ev.kind {
                EventKind::Fire(t) => {
                    let token = program
                        .sources(t)
                        .first()
                        .and_then(|s| self.layout.segment_of[s.index()])
                        .and_then(|g| self.by_segment.get(&g).copied());
                    self.record(token, AgentEventKind::Fire { transition: t.0 });
                }
                EventKind::ActionOn(a) => {
                    let token = action_token(&self.action_segments, &self.by_segment, a);
                    self.record(token, AgentEventKind::ActionOn { action: a.0 });
                    if let Some(binding) = self.layout.skills[a.index()].clone() {
                        if let Some(why) = self.fence_of(token) {
                            // The token may be running elsewhere by now: nothing moves here.
                            self.set_indicators(a, Some(false), Some(true));
                            let message = format!("not started: {why}");
                            self.record(token, AgentEventKind::SkillFault { action: a.0, message });
                            continue;
                        }
                        self.running_skills.insert(a);
                        let name = program.actions[a.index()].name.clone();
                        self.outbox.push_back(AgentOutput::StartSkill { action: a, name, binding });
                    }
                }
                EventKind::ActionOff(a) => {
                    let token = action_token(&self.action_segments, &self.by_segment, a);
                    self.record(token, AgentEventKind::ActionOff { action: a.0 });
                    if self.running_skills.remove(&a) {
                        self.outbox.push_back(AgentOutput::StopSkill { action: a });
                    }
                }
                EventKind::Fault(source, fault) => {
                    let message = fault_message(&program, source, fault);
                    let token = match source {
                        crate::exec::engine::FaultSource::Transition(t) => program
                            .sources(t)
                            .first()
                            .and_then(|s| self.layout.segment_of[s.index()])
                            .and_then(|g| self.by_segment.get(&g).copied()),
                        crate::exec::engine::FaultSource::Action(a) => {
                            action_token(&self.action_segments, &self.by_segment, a)
                        }
                    };
                    self.record(token, AgentEventKind::Fault { message });
                }
                EventKind::Activate(_) | EventKind::Deactivate(_) => {}
            }
        }
    }

    /// Sends what happened since the last report: the changed variables this agent writes (published to every
    /// reader, and carried in the first report so that the coordinator sees them before the clearings they
    /// led to), then one report per token with news.
    ///
    /// A token has at most `REPORTS_UNACKED_MAX` reports out unacknowledged. Past that no report is numbered
    /// until acknowledgements make room: the events wait in order, the values coalesce (only the latest of each
    /// counts), and all of it leaves, in reports of at most `REPORT_EVENTS_MAX` events, once there is room. So
    /// whatever the coordinator has not acknowledged can always be sent again, however long it was away.
    fn report(&mut self) {
        self.send_outputs();
        let mut changed = Vec::new();
        for (i, &v) in self.owned.iter().enumerate() {
            let value = self.engine.value(v);
            if self.published[i] != value {
                self.published[i] = value.clone();
                changed.push(VarValue::new(v, value.clone()));
                self.unreported.insert(v.0, value);
            }
        }
        if !changed.is_empty() {
            self.vars_seq += 1;
            // Other agents get what their code reads; the coordinator gets everything, in the reports.
            let read: Vec<VarValue> =
                changed.iter().filter(|vv| self.layout.read_by_agents[vv.var as usize]).cloned().collect();
            if !read.is_empty() {
                self.publish(read);
            }
        }
        let mut ids: Vec<TokenId> = self.tokens.keys().copied().collect();
        ids.sort_unstable();
        for id in ids {
            let segment_active = {
                let held = &self.tokens[&id];
                self.layout.segments[held.segment.index()].steps.iter().any(|&s| self.engine.is_active(s))
            };
            let Some(held) = self.tokens.get_mut(&id) else { continue };
            while !held.done && held.unacked.len() < REPORTS_UNACKED_MAX {
                if held.events.is_empty() && segment_active && self.unreported.is_empty() {
                    break;
                }
                let events: Vec<AgentEvent> = held.events.drain(..held.events.len().min(REPORT_EVENTS_MAX)).collect();
                let done = !segment_active && held.events.is_empty();
                let vars =
                    std::mem::take(&mut self.unreported).into_iter().map(|(var, v)| VarValue::new(VarId(var), v));
                let report = Report {
                    run: self.run,
                    agent: self.name.clone(),
                    incarnation: self.incarnation,
                    token: id,
                    epoch: held.epoch,
                    seq: held.next_seq,
                    events,
                    vars: vars.collect(),
                    vars_seq: self.vars_seq,
                    done,
                };
                held.next_seq += 1;
                held.done = done;
                if done {
                    self.by_segment.remove(&held.segment);
                }
                held.unacked.push_back(Unacked {
                    report: report.clone(),
                    sent_ms: self.now_ms,
                    resend_at_ms: self.now_ms + RESEND_FIRST_MS,
                    backoff_ms: RESEND_FIRST_MS,
                });
                self.outbox.push_back(AgentOutput::Report(report));
            }
        }
    }

    /// The coordinator started again from its journal: every unacknowledged report goes now, and the delays
    /// start again from the first.
    pub fn handle_sync(&mut self, now_ms: u64) {
        // What it took from this agent before it died may not have been durable: it hears every value again.
        self.republish();
        for held in self.tokens.values_mut() {
            for u in held.unacked.iter_mut() {
                u.backoff_ms = RESEND_FIRST_MS / 2;
            }
        }
        self.resend(now_ms, true);
    }

    fn resend(&mut self, now_ms: u64, all: bool) {
        self.advance(now_ms);
        let mut again = Vec::new();
        for held in self.tokens.values_mut() {
            for u in held.unacked.iter_mut() {
                if all || u.resend_at_ms <= now_ms {
                    u.backoff_ms = (u.backoff_ms * 2).min(RESEND_MAX_MS);
                    u.resend_at_ms = now_ms + u.backoff_ms;
                    again.push(u.report.clone());
                }
            }
        }
        again.sort_by_key(|r| (r.token, r.seq));
        self.outbox.extend(again.into_iter().map(AgentOutput::Report));
    }
}

/// The token an action's event belongs to: that of the first segment using the action that has a token here.
fn action_token(
    action_segments: &[Vec<SegmentId>],
    by_segment: &BTreeMap<SegmentId, TokenId>,
    a: ActionId,
) -> Option<TokenId> {
    action_segments.get(a.index())?.iter().find_map(|g| by_segment.get(g).copied())
}
