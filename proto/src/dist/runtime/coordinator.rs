//! The coordinator's half of a distributed run, as a pure state machine.
//!
//! It runs the whole chart in one engine whose scope leaves the transitions of placed steps to agents. When a
//! transition activates the first step of a segment, it creates a token and dispatches it to a live agent that
//! matches the segment's placement (or keeps it waiting until one appears). Agents report the transitions
//! they clear; the coordinator mirrors them in its engine, in order, once per report sequence number, so a
//! duplicated or reordered report changes nothing. A simultaneous convergence is an ordinary transition of the
//! coordinator's engine: it clears when every source step is active here (each input arrived) and its
//! condition is TRUE.
//!
//! Cycles run on the run's grid (`k · cycle_ms`), one at a time, whatever the traffic: the shell asks
//! `poll_timeout` when the next one is needed and runs it at its grid time. What arrives in between is applied at
//! once and followed by a reaction (`Engine::react`), so a token's return or an input is acted on without
//! waiting for the next cycle, and without running any action body an extra time.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::sync::Arc;

use crate::dist::layout::{Layout, Placement, SegmentId};
use crate::dist::wire::{
    AckEntry, AgentEventKind, AgentInfo, ChartHash, DeviceReport, Peer, Peers, Report, RunId, StatusAgent,
    StatusDevice, StatusReport, StatusStep, StatusToken, ToAgent, TokenId, VarUpdate, VarValue,
};
use crate::exec::engine::{Engine, Event, EventKind, Input, RemoteInput};
use crate::exec::program::{Program, StepId, TransitionId, VarId};
use crate::exec::sim::{output_of, parse_value, SimOutput};
use crate::exec::trace::{TraceEvent, TraceRecord};
use crate::limits::{
    ACK_DELAY_MS, AGENTS_MAX, FINISHED_TOKENS_REMEMBERED, REPORTS_AHEAD_BYTES_MAX, REPORTS_AHEAD_MAX,
    STALE_EPOCHS_TRACED,
};
use crate::types::Value;

use super::{Level, VarWrites, VarsResend, COORDINATOR};

/// First and largest delay before a dispatch that no report answered is sent again (the agent drops the
/// duplicate if it has the token).
const DISPATCH_RESEND_FIRST_MS: u64 = 500;
const DISPATCH_RESEND_MAX_MS: u64 = 5_000;

/// What the coordinator asks its shell to do.
#[derive(Clone, Debug, PartialEq)]
pub enum CoordOutput {
    /// A command for one process (`incarnation`) of `agent`.
    Send {
        agent: String,
        incarnation: uuid::Uuid,
        msg: ToAgent,
    },
    Vars(VarUpdate),
    Trace(TraceRecord),
    Log {
        level: Level,
        message: String,
    },
}

/// What the coordinator does with the tokens of an agent that is lost (`baton run --on-agent-loss`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LossPolicy {
    /// Hold the segment and raise an alarm; the token resumes when the agent comes back. The default,
    /// because running a motion again can be unsafe.
    #[default]
    Pause,
    /// A new epoch: the segment restarts from its first step on another live agent of its placement.
    Reassign,
    /// End the run, saying why.
    Fail,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CoordStats {
    pub dispatched: u64,
    pub returned: u64,
    /// Dispatches sent again because no report answered them.
    pub resent: u64,
    /// Reports and updates that were malformed, stale, duplicated or from the wrong agent.
    pub dropped: u64,
}

/// What a report from an agent would do (`Coordinator::classify_report`).
enum ReportFate {
    OtherRun,
    /// A duplicate of a finished token's last report: acknowledged again.
    FinishedAgain(AckEntry),
    UnknownToken,
    /// Of an older epoch; `first` of its epoch to come.
    Stale {
        first: bool,
    },
    /// Of an epoch never dispatched.
    FutureEpoch,
    NotHolder,
    OtherProcess,
    /// Applied already: acknowledged again.
    Old,
    /// Ahead of a missing one: held if there is `room`.
    Ahead {
        room: bool,
    },
    /// The one the token waits for.
    Next,
}

struct AgentState {
    roles: Vec<String>,
    alive: bool,
    tokens: usize,
    incarnation: uuid::Uuid,
    /// This coordinator started again from its journal and has not heard from the agent since.
    recovering: bool,
    /// How long the agent may stay silent before it counts as lost (its own setting).
    lease_ms: u64,
    /// More than one process answers to the name: nothing is dispatched to it until one answers alone.
    conflict: bool,
    /// Its bound devices it cannot reach (`Layout::io` index → why), as of its device report `devices_seq`.
    devices_down: BTreeMap<u32, String>,
    devices_seq: u64,
    /// Its current process was sent a dispatch or a join: it takes part in the run, and hears when the writers
    /// it may take values from change (`ToAgent::Peers`).
    joined: bool,
}

impl AgentState {
    /// An agent first heard of: not live until it announces itself.
    fn new(incarnation: uuid::Uuid, lease_ms: u64) -> AgentState {
        AgentState {
            roles: Vec::new(),
            alive: false,
            tokens: 0,
            incarnation,
            recovering: false,
            lease_ms,
            conflict: false,
            devices_down: BTreeMap::new(),
            devices_seq: 0,
            joined: false,
        }
    }
}

struct TokenState {
    segment: SegmentId,
    entry: StepId,
    epoch: u32,
    agent: Option<String>,
    next_seq: u32,
    ahead: BTreeMap<u32, Report>,
    /// What the reports held ahead weigh (`Report::weight`), bounded by `REPORTS_AHEAD_BYTES_MAX`.
    ahead_bytes: usize,
    /// The older epochs whose reports were traced as stale (`reject_stale`, once each): later ones are only
    /// answered with a `Drop`.
    stale_traced: Vec<u32>,
    dispatched_ms: u64,
    /// Its agent was lost under `LossPolicy::Pause`.
    paused: bool,
    /// False from a restart from the journal until the agent says it holds the token (or reports on it).
    confirmed: bool,
    /// When the dispatch is sent again if no report came, and the delay after that.
    resend_at_ms: u64,
    resend_backoff_ms: u64,
    /// The process of its agent it was given to: a token goes back in the same epoch only to that process.
    incarnation: uuid::Uuid,
    /// Its agent was lost under `LossPolicy::Reassign`: when the token goes to another agent, unless the lost one
    /// comes back first. Not before the agent has stopped its skills (`limits::fence_margin_ms`).
    reassign_at_ms: Option<u64>,
}

pub struct Coordinator {
    run: RunId,
    hash: ChartHash,
    program: Arc<Program>,
    layout: Arc<Layout>,
    engine: Engine,
    now_ms: u64,
    agents: BTreeMap<String, AgentState>,
    tokens: BTreeMap<TokenId, TokenState>,
    by_segment: Vec<Option<TokenId>>,
    /// Tokens no live agent can take yet, oldest first.
    waiting: Vec<TokenId>,
    /// Finished tokens and their last report, to answer a late duplicate with the same acknowledgement.
    finished: BTreeMap<TokenId, (u32, u32, String)>,
    finished_order: VecDeque<TokenId>,
    owned: Vec<VarId>,
    published: Vec<Option<Value>>,
    vars_seq: u64,
    /// When the owned values are published again (`VarsResend`).
    vars_resend: VarsResend,
    /// The last write applied to each variable an agent writes.
    var_writes: VarWrites,
    new_token: Box<dyn FnMut() -> TokenId + Send>,
    round_robin: usize,
    outbox: VecDeque<CoordOutput>,
    /// Acknowledgements owed, per agent: sent together at the end of the cycle.
    acks: BTreeMap<String, Vec<AckEntry>>,
    /// When the oldest owed acknowledgement was made.
    acks_since_ms: u64,
    policy: LossPolicy,
    /// Why the run must end, under `LossPolicy::Fail`.
    failure: Option<String>,
    /// When this coordinator last started again from its journal.
    recovered_ms: Option<u64>,
    /// The run's cycle period (`set_cycle_ms`).
    cycle_ms: u64,
    stats: CoordStats,
    /// The agents whose variable updates other agents may take: those placed by name on a variable agents read,
    /// and those with a role that writes one.
    writer_names: BTreeSet<String>,
    writer_roles: BTreeSet<String>,
    /// The writers agents were told of last (`ToAgent::Peers`).
    peers: Peers,
}

impl Coordinator {
    /// `new_token` gives each token its id: random in a real run, counted in a simulation.
    pub fn new(
        program: Arc<Program>,
        layout: Arc<Layout>,
        run: RunId,
        hash: ChartHash,
        new_token: Box<dyn FnMut() -> TokenId + Send>,
    ) -> Coordinator {
        let engine = Engine::with_scope(Arc::clone(&program), layout.coordinator_scope(&program));
        let program_vars = program.vars.len();
        // Only what agents read travels: the coordinator's own counters and flags stay home.
        let owned: Vec<VarId> =
            layout.written_by(&Placement::Coordinator).filter(|v| layout.read_by_agents[v.index()]).collect();
        let (mut writer_names, mut writer_roles) = (BTreeSet::new(), BTreeSet::new());
        for (w, _) in layout.writer.iter().zip(&layout.read_by_agents).filter(|(_, read)| **read) {
            match w {
                Placement::Agent(a) => writer_names.insert(a.clone()),
                Placement::Role(r) => writer_roles.insert(r.clone()),
                Placement::Coordinator => false,
            };
        }
        Coordinator {
            run,
            hash,
            by_segment: vec![None; layout.segments.len()],
            published: vec![None; owned.len()],
            owned,
            program,
            layout,
            engine,
            now_ms: 0,
            agents: BTreeMap::new(),
            tokens: BTreeMap::new(),
            waiting: Vec::new(),
            finished: BTreeMap::new(),
            finished_order: VecDeque::new(),
            vars_seq: 0,
            vars_resend: VarsResend::default(),
            var_writes: VarWrites::new(program_vars),
            new_token,
            round_robin: 0,
            outbox: VecDeque::new(),
            acks: BTreeMap::new(),
            acks_since_ms: 0,
            policy: LossPolicy::default(),
            failure: None,
            recovered_ms: None,
            cycle_ms: 1,
            stats: CoordStats::default(),
            writer_names,
            writer_roles,
            peers: Peers { seq: 0, coordinator: uuid::Uuid::nil(), agents: Vec::new() },
        }
    }

    pub fn program(&self) -> &Arc<Program> {
        &self.program
    }

    pub fn run(&self) -> RunId {
        self.run
    }

    pub fn stats(&self) -> CoordStats {
        self.stats
    }

    pub fn set_loss_policy(&mut self, policy: LossPolicy) {
        self.policy = policy;
    }

    /// Set when the run must end with an error (an agent lost under `LossPolicy::Fail`).
    pub fn failure(&self) -> Option<&str> {
        self.failure.as_deref()
    }

    pub fn poll_output(&mut self) -> Option<CoordOutput> {
        self.outbox.pop_front()
    }

    pub fn has_output(&self) -> bool {
        !self.outbox.is_empty()
    }

    /// The run is over: no active step has a transition left and no token is out.
    pub fn is_terminal(&self) -> bool {
        self.tokens.is_empty() && self.engine.is_terminal()
    }

    /// A variable's current value here.
    pub fn value(&self, v: VarId) -> Value {
        self.engine.value(v)
    }

    /// The time of the last input or cycle.
    pub fn now_ms(&self) -> u64 {
        self.now_ms
    }

    /// The epoch a finished token ended in, while it is remembered.
    pub fn finished_epoch(&self, token: TokenId) -> Option<u32> {
        self.finished.get(&token).map(|(epoch, _, _)| *epoch)
    }

    /// How many times the coordinator's engine gave a step a second token (a validated chart: never).
    pub fn collisions(&self) -> u64 {
        self.engine.collisions()
    }

    pub fn tokens_in_flight(&self) -> usize {
        self.tokens.len()
    }

    fn advance(&mut self, now_ms: u64) {
        self.now_ms = self.now_ms.max(now_ms);
    }

    fn log(&mut self, level: Level, message: String) {
        self.outbox.push_back(CoordOutput::Log { level, message });
    }

    fn drop_msg(&mut self, message: String) {
        self.stats.dropped += 1;
        self.log(Level::Warn, message);
    }

    fn trace(&mut self, rec: TraceRecord) {
        self.outbox.push_back(CoordOutput::Trace(rec));
    }

    /// The run's cycle period: the grid the shell runs cycles on, and from which steps made active between
    /// cycles count their time.
    pub fn set_cycle_ms(&mut self, cycle_ms: u64) {
        self.cycle_ms = cycle_ms.max(1);
        self.engine.set_grid(0, self.cycle_ms);
    }

    /// Runs one cycle at `now_ms` (a grid time), then what is due: dispatches sent again, agents given up,
    /// acknowledgements, changed variables. Returns whether it changed anything: a cycle that did not needs no
    /// record in a journal (the next input carries the time on).
    pub fn handle_cycle(&mut self, now_ms: u64) -> bool {
        self.advance(now_ms);
        let (mutations, outputs, recovering) = (self.engine.mutations(), self.outbox.len(), self.recovered_ms);
        if let Err(e) = self.engine.handle_cycle(self.now_ms) {
            self.log(Level::Error, format!("cycle refused: {e}"));
        }
        self.drain_engine();
        self.resend_dispatches();
        self.reassign_due();
        self.give_up_on_silent_agents();
        self.publish_vars();
        self.resend_vars();
        self.flush_acks(true);
        self.engine.mutations() != mutations || self.outbox.len() != outputs || self.recovered_ms != recovering
    }

    /// After an input: the engine reacts to it (first scans of steps that became active, transitions that read
    /// what changed), and what that changed leaves at once.
    fn settle(&mut self) {
        if let Err(e) = self.engine.react(self.now_ms) {
            self.log(Level::Error, format!("reaction refused: {e}"));
        }
        self.drain_engine();
        self.publish_vars();
        self.flush_acks(false);
    }

    /// The grid time of the next cycle, for a shell whose last cycle ran at `last_cycle_ms`: never two in one
    /// period, never before what the coordinator waits for (`poll_timeout`), none when nothing needs one.
    pub fn next_cycle_ms(&self, last_cycle_ms: Option<u64>) -> Option<u64> {
        let wanted = self.poll_timeout()?;
        let mut after = last_cycle_ms.map_or(0, |t| t + self.cycle_ms);
        if last_cycle_ms.is_some_and(|t| self.now_ms > t) {
            // An input since the last cycle was reacted to at once, standing for the cycle at its grid point (the
            // steps it made active count their time from there): the next cycle comes after that point, or a
            // step made active exactly on it would be scanned twice there.
            after = after.max(self.now_ms - self.now_ms % self.cycle_ms + self.cycle_ms);
        }
        Some(wanted.max(after).div_ceil(self.cycle_ms) * self.cycle_ms)
    }

    /// When the next cycle is needed: at once (the next grid time) when the engine needs one, else at the
    /// earliest deadline (a dispatch to send again, acknowledgements to send, an agent to give up on), or never.
    pub fn poll_timeout(&self) -> Option<u64> {
        if self.engine.needs_cycle() {
            return Some(self.now_ms);
        }
        let resend = self
            .tokens
            .values()
            .filter(|t| t.next_seq == 0 && !t.paused && t.confirmed && t.agent.is_some())
            .map(|t| t.resend_at_ms)
            .min();
        let acks = (!self.acks.is_empty()).then_some(self.acks_since_ms + ACK_DELAY_MS);
        let give_up = self.recovered_ms.and_then(|since| {
            self.agents.values().filter(|a| a.recovering && a.alive).map(|a| since.saturating_add(a.lease_ms)).min()
        });
        let reassign = self.tokens.values().filter_map(|t| t.reassign_at_ms).min();
        [resend, acks, give_up, reassign, self.vars_resend.at_ms()].into_iter().flatten().min()
    }

    /// After a restart from the journal, an agent that has not come back within its lease is lost, as if its
    /// liveliness token had gone: its tokens are paused, reassigned or fail the run.
    fn give_up_on_silent_agents(&mut self) {
        let Some(since) = self.recovered_ms else { return };
        let now = self.now_ms;
        let silent: Vec<String> = self
            .agents
            .iter()
            .filter(|(_, a)| a.recovering && a.alive && now >= since.saturating_add(a.lease_ms))
            .map(|(n, _)| n.clone())
            .collect();
        for name in silent {
            self.log(Level::Warn, format!("agent `{name}` did not come back within its lease after the restart"));
            self.handle_agent_down(now, &name);
        }
        if self.agents.values().all(|a| !a.recovering || !a.alive) {
            self.recovered_ms = None;
        }
    }

    /// A dispatch lost on the way (a link that broke and came back within the agent's lease) would leave its
    /// segment waiting for ever: a dispatch that no report answered goes again, with doubling delays. The agent
    /// drops the copy if the first one arrived.
    fn resend_dispatches(&mut self) {
        let now = self.now_ms;
        let mut due: Vec<TokenId> = self
            .tokens
            .iter()
            .filter(|(_, t)| t.next_seq == 0 && !t.paused && t.confirmed && t.resend_at_ms <= now)
            .filter(|(_, t)| t.agent.as_ref().and_then(|a| self.agents.get(a)).is_some_and(|a| a.alive))
            .map(|(id, _)| *id)
            .collect();
        due.sort_unstable();
        for id in due {
            self.publish_vars();
            let Some((agent, msg)) = self.dispatch_msg(id) else { continue };
            if let Some(t) = self.tokens.get_mut(&id) {
                t.resend_backoff_ms = (t.resend_backoff_ms * 2).min(DISPATCH_RESEND_MAX_MS);
                t.resend_at_ms = now + t.resend_backoff_ms;
            }
            self.stats.resent += 1;
            self.log(Level::Info, format!("token {id} sent again to `{agent}`: no report on it yet"));
            self.send(agent, msg);
        }
    }

    /// Acknowledgements ride on the dispatches about to leave to the same agent; in a cycle (`due`), the rest
    /// leave together once they are `ACK_DELAY_MS` old, or at once when the run is over.
    fn flush_acks(&mut self, due: bool) {
        if self.acks.is_empty() {
            return;
        }
        for out in self.outbox.iter_mut() {
            if let CoordOutput::Send { agent, msg: ToAgent::Dispatch { acks, .. }, .. } = out {
                if let Some(owed) = self.acks.remove(agent.as_str()) {
                    acks.extend(owed);
                }
            }
        }
        if self.acks.is_empty() {
            return;
        }
        if (due && self.now_ms >= self.acks_since_ms + ACK_DELAY_MS) || self.is_terminal() {
            for (agent, acks) in std::mem::take(&mut self.acks) {
                self.send(agent, ToAgent::Ack { run: self.run, acks });
            }
        }
    }

    /// A command for `agent`'s current process; none for an agent this coordinator does not know. A dispatch or
    /// a join makes the process one that takes part in the run.
    fn send(&mut self, agent: String, msg: ToAgent) {
        if let Some(a) = self.agents.get_mut(&agent) {
            a.joined |= matches!(msg, ToAgent::Dispatch { .. } | ToAgent::Join { .. });
            let incarnation = a.incarnation;
            self.outbox.push_back(CoordOutput::Send { agent, incarnation, msg });
        }
    }

    fn ack(&mut self, agent: String, entry: AckEntry) {
        if self.acks.is_empty() {
            self.acks_since_ms = self.now_ms;
        }
        self.acks.entry(agent).or_default().push(entry);
    }

    fn publish_vars(&mut self) {
        let mut changed = Vec::new();
        for (i, &v) in self.owned.iter().enumerate() {
            let value = self.engine.value(v);
            if self.published[i].as_ref() != Some(&value) {
                self.published[i] = Some(value.clone());
                changed.push(VarValue::new(v, value));
            }
        }
        if !changed.is_empty() {
            self.vars_seq += 1;
            let update = VarUpdate {
                run: self.run,
                from: COORDINATOR.to_string(),
                incarnation: uuid::Uuid::nil(),
                seq: self.vars_seq,
                vars: changed,
            };
            self.outbox.push_back(CoordOutput::Vars(update));
            self.vars_resend.start(self.now_ms);
        }
    }

    /// Publishes every owned value again, as of the last update, when that is due (`VARS_RESEND_FIRST_MS`).
    fn resend_vars(&mut self) {
        if !self.vars_resend.due(self.now_ms) {
            return;
        }
        let vars = self.owned.iter().map(|&v| VarValue::new(v, self.engine.value(v))).collect();
        let update = VarUpdate {
            run: self.run,
            from: COORDINATOR.to_string(),
            incarnation: uuid::Uuid::nil(),
            seq: self.vars_seq,
            vars,
        };
        self.outbox.push_back(CoordOutput::Vars(update));
    }

    /// The agent that holds the token of a placed step's segment, if it is out.
    fn holder(&self, s: StepId) -> Option<&str> {
        self.segment_holder(self.layout.segment_of[s.index()]?)
    }

    fn segment_holder(&self, g: SegmentId) -> Option<&str> {
        self.tokens.get(&self.by_segment[g.index()]?)?.agent.as_deref()
    }

    fn drain_engine(&mut self) {
        while let Some(ev) = self.engine.poll_event() {
            self.on_engine_event(ev);
        }
    }

    fn on_engine_event(&mut self, ev: Event) {
        let program = Arc::clone(&self.program);
        let mut created = None;
        if let EventKind::Activate(s) = ev.kind {
            if let Some(g) = self.layout.segment_of[s.index()] {
                if self.by_segment[g.index()].is_none() {
                    created = Some(self.new_token(g, s));
                }
            }
        }
        let by = match ev.kind {
            EventKind::Activate(s) | EventKind::Deactivate(s) => self.holder(s),
            EventKind::Fire(t) => self.layout.agent_judges(&program, t).and_then(|g| self.segment_holder(g)),
            _ => None,
        };
        let agent = by.map(str::to_string);
        let mut rec = match output_of(&program, ev) {
            SimOutput::Trace(rec) => rec,
            SimOutput::Fault { t_ms, message } => {
                self.log(Level::Error, message.clone());
                let mut rec = TraceRecord::new(t_ms, TraceEvent::Fault, &program.name);
                rec.message = Some(message);
                rec
            }
        };
        rec.agent = agent;
        self.trace(rec);
        if let Some(id) = created {
            self.emit_dispatch_or_wait(id);
        }
    }

    fn new_token(&mut self, g: SegmentId, entry: StepId) -> TokenId {
        let id = (self.new_token)();
        let tok = TokenState {
            segment: g,
            entry,
            epoch: 1,
            agent: None,
            next_seq: 0,
            ahead: BTreeMap::new(),
            ahead_bytes: 0,
            stale_traced: Vec::new(),
            dispatched_ms: self.now_ms,
            paused: false,
            confirmed: true,
            resend_at_ms: 0,
            resend_backoff_ms: 0,
            incarnation: uuid::Uuid::nil(),
            reassign_at_ms: None,
        };
        self.tokens.insert(id, tok);
        self.by_segment[g.index()] = Some(id);
        if let Some(agent) = self.choose_agent(&self.layout.segments[g.index()].placement.clone()) {
            self.assign(id, agent);
        }
        id
    }

    fn choose_agent(&mut self, placement: &Placement) -> Option<String> {
        match placement {
            Placement::Coordinator => None,
            Placement::Agent(name) => self.agents.get(name).filter(|a| a.alive && !a.conflict).map(|_| name.clone()),
            Placement::Role(role) => {
                let able: Vec<(&String, usize)> = self
                    .agents
                    .iter()
                    .filter(|(_, a)| a.alive && !a.conflict && a.roles.iter().any(|r| r == role))
                    .map(|(n, a)| (n, a.tokens))
                    .collect();
                let least = able.iter().map(|(_, n)| *n).min()?;
                let tied: Vec<&String> = able.iter().filter(|(_, n)| *n == least).map(|(name, _)| *name).collect();
                let pick = tied[self.round_robin % tied.len()].clone();
                self.round_robin = self.round_robin.wrapping_add(1);
                Some(pick)
            }
        }
    }

    fn assign(&mut self, id: TokenId, agent: String) {
        let incarnation = self.agents.get_mut(&agent).map(|a| {
            a.tokens += 1;
            a.incarnation
        });
        if let Some(tok) = self.tokens.get_mut(&id) {
            tok.agent = Some(agent);
            tok.incarnation = incarnation.unwrap_or_default();
        }
    }

    /// Sends a token to its agent, or says why it waits.
    fn emit_dispatch_or_wait(&mut self, id: TokenId) {
        self.send_token(id, TraceEvent::Dispatch);
    }

    /// Sends a token to its agent, traced as `event` (`dispatch`, or `resume` when a paused token goes back to
    /// its agent in the same epoch), or says why it waits.
    fn send_token(&mut self, id: TokenId, event: TraceEvent) {
        let Some(tok) = self.tokens.get(&id) else { return };
        let entry_name = self.program.steps[tok.entry.index()].name.clone();
        let placement = self.layout.segments[tok.segment.index()].placement.clone();
        let epoch = tok.epoch;
        if tok.agent.is_none() {
            if !self.waiting.contains(&id) {
                self.waiting.push(id);
                let mut rec = TraceRecord::new(self.now_ms, TraceEvent::Wait, &entry_name);
                rec.token = Some(id.to_string());
                rec.epoch = Some(epoch);
                self.trace(rec);
                let why = match &placement {
                    Placement::Agent(a) => format!("no live agent named `{a}`"),
                    Placement::Role(r) => format!("no live agent with role `{r}`"),
                    Placement::Coordinator => "it is placed on the coordinator".to_string(),
                };
                self.log(Level::Warn, format!("token for step `{entry_name}` waits: {why}"));
            }
            return;
        }
        // What changed since the last update is published first, so that the dispatch's values carry an update
        // number of their own: an agent takes a value only from an update newer than the last it applied, and
        // would otherwise keep what it had for a variable that changed since (a P action then reads it stale).
        self.publish_vars();
        let Some((agent, msg)) = self.dispatch_msg(id) else { return };
        if let Some(tok) = self.tokens.get_mut(&id) {
            tok.dispatched_ms = self.now_ms;
            tok.resend_at_ms = self.now_ms + DISPATCH_RESEND_FIRST_MS;
            tok.resend_backoff_ms = DISPATCH_RESEND_FIRST_MS;
        }
        if event == TraceEvent::Dispatch {
            self.stats.dispatched += 1;
        }
        let mut rec = TraceRecord::new(self.now_ms, event, &entry_name);
        rec.agent = Some(agent.clone());
        rec.token = Some(id.to_string());
        rec.epoch = Some(epoch);
        self.trace(rec);
        self.send(agent, msg);
    }

    /// The dispatch of a token to its agent, as it stands now (callers publish the variables first, so that
    /// `vars_seq` numbers these values).
    fn dispatch_msg(&self, id: TokenId) -> Option<(String, ToAgent)> {
        let tok = self.tokens.get(&id)?;
        let agent = tok.agent.clone()?;
        let vars = self.values_for(&agent);
        let msg = ToAgent::Dispatch {
            run: self.run,
            chart: self.hash.clone(),
            token: id,
            epoch: tok.epoch,
            segment: tok.segment.0,
            entry: tok.entry.0,
            vars,
            vars_seq: self.vars_seq,
            acks: Vec::new(),
            fence: self.policy == LossPolicy::Reassign,
            peers: self.peers.clone(),
        };
        Some((agent, msg))
    }

    /// What a dispatch or a join gives `agent`: the value of every variable code on agents reads, and of every
    /// variable `agent` writes. A process that has not taken part in the run yet (a restarted one) starts from
    /// these even for its own, or it would compute on the chart's initial values.
    fn values_for(&self, agent: &str) -> Vec<VarValue> {
        (0..self.program.vars.len())
            .filter(|&i| self.layout.read_by_agents[i] || self.serves(agent, &self.layout.writer[i]))
            .map(|i| VarValue::new(VarId(i as u32), self.engine.value(VarId(i as u32))))
            .collect()
    }

    /// A join for `agent`'s current process: the run's values and writers, before any token.
    fn join_msg(&self, agent: &str) -> ToAgent {
        ToAgent::Join {
            run: self.run,
            chart: self.hash.clone(),
            vars: self.values_for(agent),
            vars_seq: self.vars_seq,
            peers: self.peers.clone(),
        }
    }

    /// The writers agents may take variable updates from, as the agents tracked now say; when that changed, every
    /// agent taking part in the run hears the new table.
    fn refresh_peers(&mut self) {
        let agents: Vec<Peer> = self
            .agents
            .iter()
            .filter(|(name, a)| {
                self.writer_names.contains(*name) || a.roles.iter().any(|r| self.writer_roles.contains(r))
            })
            .map(|(name, a)| Peer { name: name.clone(), incarnation: a.incarnation, roles: a.roles.clone() })
            .collect();
        if agents == self.peers.agents {
            return;
        }
        self.peers.seq += 1;
        self.peers.agents = agents;
        let joined: Vec<String> =
            self.agents.iter().filter(|(_, a)| a.joined && a.alive && !a.conflict).map(|(n, _)| n.clone()).collect();
        for name in joined {
            let msg = ToAgent::Peers { run: self.run, peers: self.peers.clone() };
            self.send(name, msg);
        }
    }

    /// This coordinator started again from its journal (replayed up to here): nothing it knew about the agents
    /// still holds until each says so. Their tokens stay theirs, unconfirmed: an agent that comes back with the
    /// token keeps it (and is asked for its unacknowledged reports), one that lacks it gets the dispatch again in
    /// the same epoch, and a restarted one runs the segment again in a new epoch. Variables are published again.
    pub fn handle_recover(&mut self, now_ms: u64) {
        self.advance(now_ms);
        for a in self.agents.values_mut() {
            a.recovering = true;
        }
        self.recovered_ms = Some(self.now_ms);
        for t in self.tokens.values_mut() {
            if t.agent.is_some() {
                t.confirmed = false;
            }
        }
        self.acks.clear();
        self.published.iter_mut().for_each(|p| *p = None);
        let out = self.tokens.len();
        let message = format!("started again from the journal with {out} token(s) out");
        let mut rec = TraceRecord::new(self.now_ms, TraceEvent::Recover, &self.program.name);
        rec.message = Some(message.clone());
        self.trace(rec);
        self.log(Level::Info, message);
    }

    /// An agent announced itself (or came back). Tokens waiting for it leave now.
    pub fn handle_agent_up(&mut self, now_ms: u64, info: AgentInfo) {
        self.advance(now_ms);
        let valid = |n: &str| crate::dist::keys::is_valid_name(n) && n != COORDINATOR;
        if !valid(&info.name) || !info.roles.iter().all(|r| crate::dist::keys::is_valid_name(r)) {
            self.drop_msg(format!("agent announcement with an invalid name or role ignored: {:?}", info.name));
            return;
        }
        if !self.agents.contains_key(&info.name) && self.agents.len() >= AGENTS_MAX {
            self.drop_msg(format!("agent `{}` ignored: already tracking {AGENTS_MAX} agents", info.name));
            return;
        }
        let name = info.name.clone();
        let entry = self.agents.entry(name.clone()).or_insert_with(|| AgentState::new(info.incarnation, info.lease_ms));
        let was_alive = entry.alive;
        let recovering = std::mem::take(&mut entry.recovering);
        let restarted = entry.incarnation != info.incarnation;
        let old_incarnation = entry.incarnation;
        let was_conflict = std::mem::take(&mut entry.conflict);
        entry.roles = info.roles.clone();
        entry.lease_ms = info.lease_ms;
        entry.alive = true;
        entry.incarnation = info.incarnation;
        if restarted {
            // The new process numbers its device reports from 1; what it cannot reach it says when it joins. It
            // knows nothing of the run yet.
            entry.devices_seq = 0;
            entry.joined = false;
        }
        if was_conflict {
            self.log(Level::Info, format!("agent `{name}` answers alone again"));
        }
        if restarted {
            // Its numbers start again: what the old process still sends is late.
            self.var_writes.retire(name.clone(), old_incarnation);
        }
        self.refresh_peers();
        if !was_alive {
            let mut rec = TraceRecord::new(self.now_ms, TraceEvent::AgentUp, &name);
            rec.agent = Some(name.clone());
            self.trace(rec);
            let roles =
                if info.roles.is_empty() { String::new() } else { format!(" (roles: {})", info.roles.join(", ")) };
            self.log(Level::Info, format!("agent `{name}` is live{roles}"));
        }
        // This agent's paused tokens (it was lost) and unconfirmed ones (this coordinator restarted): if it is the
        // same process and holds the token, it keeps it and sends its unacknowledged reports now; if it lacks
        // it, the dispatch goes again in the same epoch; if it restarted, the segment's progress died with the
        // old process and it runs again from its first step, in a new epoch.
        let mut settle: Vec<TokenId> = self
            .tokens
            .iter()
            // A new process of the agent lost whatever the old one held, even if this coordinator never saw the
            // old one go (a restart faster than the liveliness token's deletion).
            .filter(|(_, t)| t.paused || !t.confirmed || t.incarnation != info.incarnation)
            .filter(|(_, t)| t.agent.as_deref() == Some(name.as_str()))
            .map(|(id, _)| *id)
            .collect();
        settle.sort_unstable();
        let run = self.run;
        // A coordinator that started again asks every agent for its unacknowledged reports and its values: what it
        // took before it died may not have been durable.
        let mut sync = recovering;
        for id in settle {
            let Some(tok) = self.tokens.get_mut(&id) else { continue };
            let entry = self.program.steps[tok.entry.index()].name.clone();
            // Compared with the process the token went to, not the last one announced: under `fail` the token stays
            // with the process that lost it, and nothing of it ever goes to the new one.
            if tok.incarnation != info.incarnation {
                if self.policy == LossPolicy::Fail {
                    let why = format!("agent `{name}` restarted while holding the token of step `{entry}`");
                    self.alarm(why.clone());
                    self.failure.get_or_insert(why);
                    continue;
                }
                self.alarm(format!(
                    "agent `{name}` came back restarted: the segment of step `{entry}` runs again from its first step"
                ));
                self.restart_on(id, Some(name.clone()));
                continue;
            }
            tok.paused = false;
            tok.reassign_at_ms = None;
            tok.confirmed = true;
            let epoch = tok.epoch;
            if info.held.iter().any(|h| h.run == run && h.token == id && h.epoch == epoch) {
                sync = true;
                let mut rec = TraceRecord::new(self.now_ms, TraceEvent::Resume, &entry);
                rec.agent = Some(name.clone());
                rec.token = Some(id.to_string());
                rec.epoch = Some(epoch);
                rec.message = Some("still held by the agent".to_string());
                self.trace(rec);
            } else {
                self.send_token(id, TraceEvent::Resume);
            }
        }
        if sync {
            self.send(name.clone(), ToAgent::Sync { run });
        }
        // An agent that connects bound variables takes part in the run from the start, tokens or not.
        if (!was_alive || restarted) && self.layout.io.iter().any(|b| b.agent == name) {
            let msg = self.join_msg(&name);
            self.send(name.clone(), msg);
        }
        // What the agent still holds of an older epoch (its segment moved on while it was away) or of a token
        // that is over: it must not run it a moment longer.
        let mut stale: Vec<(TokenId, u32)> = info
            .held
            .iter()
            .filter(|h| h.run == run)
            .filter(|h| match self.tokens.get(&h.token) {
                Some(t) => t.epoch != h.epoch || t.agent.as_deref() != Some(name.as_str()),
                None => {
                    !self.finished.get(&h.token).is_some_and(|(epoch, _, agent)| *epoch == h.epoch && *agent == name)
                }
            })
            .map(|h| (h.token, h.epoch))
            .collect();
        stale.sort_unstable();
        for (token, epoch) in stale {
            self.send(name.clone(), ToAgent::Drop { run, token, epoch });
        }
        let waiting = std::mem::take(&mut self.waiting);
        for id in waiting {
            let Some(tok) = self.tokens.get(&id) else { continue };
            let placement = self.layout.segments[tok.segment.index()].placement.clone();
            match self.choose_agent(&placement) {
                Some(agent) => {
                    self.assign(id, agent);
                    self.emit_dispatch_or_wait(id);
                }
                None => self.waiting.push(id),
            }
        }
        self.settle();
    }

    /// More than one process answered to agent `name` (a copied service file, an old process that lingers):
    /// each would run what is sent to the name, so nothing is dispatched to it, its tokens are held, and an
    /// alarm says so, until one process answers alone (`handle_agent_up`).
    pub fn handle_agent_conflict(&mut self, now_ms: u64, name: &str, processes: usize) {
        self.advance(now_ms);
        if !crate::dist::keys::is_valid_name(name) {
            return self.drop_msg(format!("agent conflict with an invalid name ignored: {name:?}"));
        }
        if !self.agents.contains_key(name) && self.agents.len() >= AGENTS_MAX {
            return self.drop_msg(format!("agent `{name}` ignored: already tracking {AGENTS_MAX} agents"));
        }
        let agent = self.agents.entry(name.to_string()).or_insert_with(|| AgentState::new(uuid::Uuid::nil(), 0));
        if std::mem::replace(&mut agent.conflict, true) {
            return;
        }
        for t in self.tokens.values_mut().filter(|t| t.agent.as_deref() == Some(name)) {
            t.paused = true;
        }
        self.refresh_peers();
        self.alarm(format!(
            "{processes} processes answer as agent `{name}`: nothing is sent to `{name}`, and its tokens are held, until one of them stops"
        ));
        self.settle();
    }

    /// An agent's liveliness token is gone (killed: at once; hung or cut off: after its lease). Its tokens are
    /// paused, reassigned or fail the run, as the loss policy says.
    pub fn handle_agent_down(&mut self, now_ms: u64, name: &str) {
        self.advance(now_ms);
        let Some(agent) = self.agents.get_mut(name) else { return };
        if !agent.alive {
            return;
        }
        agent.alive = false;
        let lease_ms = agent.lease_ms;
        let mut rec = TraceRecord::new(self.now_ms, TraceEvent::AgentLost, name);
        rec.agent = Some(name.to_string());
        self.trace(rec);
        let mut held: Vec<TokenId> =
            self.tokens.iter().filter(|(_, t)| t.agent.as_deref() == Some(name)).map(|(id, _)| *id).collect();
        held.sort_unstable();
        if held.is_empty() {
            self.log(Level::Info, format!("agent `{name}` is gone; it held no token"));
        }
        for id in held {
            let entry =
                self.tokens.get(&id).map(|t| self.program.steps[t.entry.index()].name.clone()).unwrap_or_default();
            match self.policy {
                LossPolicy::Pause => {
                    if let Some(t) = self.tokens.get_mut(&id) {
                        t.paused = true;
                    }
                    self.alarm(format!(
                        "agent `{name}` lost holding the token of step `{entry}`: paused until it comes back"
                    ));
                }
                LossPolicy::Reassign => {
                    // The agent stops the segment's skills once it has lost its router for long enough; only then
                    // may another agent start it.
                    let margin = crate::limits::fence_margin_ms(lease_ms);
                    if let Some(t) = self.tokens.get_mut(&id) {
                        t.paused = true;
                        t.reassign_at_ms = Some(self.now_ms + margin);
                    }
                    self.alarm(format!(
                        "agent `{name}` lost holding the token of step `{entry}`: reassigned, from its first step, in {margin} ms unless it comes back"
                    ));
                }
                LossPolicy::Fail => {
                    let why = format!("agent `{name}` was lost holding the token of step `{entry}`");
                    self.alarm(why.clone());
                    self.failure.get_or_insert(why);
                }
            }
        }
        self.forget_if_gone(name);
        self.settle();
    }

    /// An agent that is gone and holds no token is forgotten: if it comes back, it is a new one. So the agents
    /// tracked are the live ones and the lost ones with a token, however many names come and go.
    fn forget_if_gone(&mut self, name: &str) {
        let gone = self.agents.get(name).is_some_and(|a| !a.alive);
        if gone && !self.tokens.values().any(|t| t.agent.as_deref() == Some(name)) {
            self.agents.remove(name);
            self.acks.remove(name);
            self.refresh_peers();
        }
    }

    fn alarm(&mut self, message: String) {
        let mut rec = TraceRecord::new(self.now_ms, TraceEvent::Alarm, &self.program.name);
        rec.message = Some(message.clone());
        self.trace(rec);
        self.log(Level::Error, message);
    }

    /// Takes a token back from its agent: a new epoch, the segment's steps back to its first step in the mirror,
    /// and a dispatch to a live agent of the placement (or a wait for one).
    fn reassign(&mut self, id: TokenId) {
        self.restart_on(id, None);
    }

    /// Tokens of lost agents whose fence margin is over go to other agents.
    fn reassign_due(&mut self) {
        let now = self.now_ms;
        let mut due: Vec<TokenId> = self
            .tokens
            .iter()
            .filter(|(_, t)| t.reassign_at_ms.is_some_and(|at| at <= now))
            .map(|(id, _)| *id)
            .collect();
        due.sort_unstable();
        for id in due {
            self.reassign(id);
        }
    }

    /// A new epoch from the segment's first step, on `agent` or on whichever live agent the placement picks.
    fn restart_on(&mut self, id: TokenId, agent: Option<String>) {
        let Some(tok) = self.tokens.get_mut(&id) else { return };
        tok.epoch += 1;
        tok.next_seq = 0;
        tok.ahead.clear();
        tok.ahead_bytes = 0;
        tok.paused = false;
        tok.reassign_at_ms = None;
        tok.confirmed = true;
        let (segment, entry, old) = (tok.segment, tok.entry, tok.agent.take());
        if let Some(a) = old.and_then(|a| self.agents.get_mut(&a)) {
            a.tokens = a.tokens.saturating_sub(1);
        }
        let now = self.now_ms;
        for s in self.layout.segments[segment.index()].steps.clone() {
            if self.engine.is_active(s) && s != entry {
                let _ = self.engine.handle_remote(now, RemoteInput::Deactivate(s));
            }
        }
        if !self.engine.is_active(entry) {
            let _ = self.engine.handle_remote(now, RemoteInput::Activate(entry));
        }
        self.drain_engine();
        let placement = self.layout.segments[segment.index()].placement.clone();
        if let Some(agent) = agent.or_else(|| self.choose_agent(&placement)) {
            self.assign(id, agent);
        }
        self.emit_dispatch_or_wait(id);
    }

    /// What a report would do here; `handle_report` does it, and the journal records only those that change
    /// what a replay must rebuild (`admit_report`).
    fn classify_report(&self, report: &Report) -> ReportFate {
        if report.run != self.run {
            return ReportFate::OtherRun;
        }
        let Some(tok) = self.tokens.get(&report.token) else {
            return match self.finished.get(&report.token) {
                Some((epoch, seq, agent)) if report.epoch == *epoch && report.agent == *agent => {
                    ReportFate::FinishedAgain(AckEntry { token: report.token, epoch: *epoch, seq: *seq, done: true })
                }
                _ => ReportFate::UnknownToken,
            };
        };
        if report.epoch != tok.epoch {
            return match report.epoch < tok.epoch {
                true => ReportFate::Stale { first: !tok.stale_traced.contains(&report.epoch) },
                false => ReportFate::FutureEpoch,
            };
        }
        if tok.agent.as_deref() != Some(report.agent.as_str()) {
            return ReportFate::NotHolder;
        }
        if self.agents.get(&report.agent).map(|a| a.incarnation) != Some(report.incarnation) {
            return ReportFate::OtherProcess;
        }
        if report.seq < tok.next_seq {
            return ReportFate::Old;
        }
        if report.seq > tok.next_seq {
            let room = tok.ahead.len() < REPORTS_AHEAD_MAX
                && tok.ahead_bytes + report.weight() <= REPORTS_AHEAD_BYTES_MAX
                && !tok.ahead.contains_key(&report.seq);
            return ReportFate::Ahead { room };
        }
        ReportFate::Next
    }

    /// Whether a report changes what the coordinator knows (it applies, waits ahead of a gap, or is the first
    /// stale one of its epoch, which the trace shows): only those are journaled. The others are answered, counted
    /// and dropped, and change nothing a replay needs — so a peer's garbage costs no disk.
    pub fn admit_report(&self, report: &Report) -> bool {
        matches!(
            self.classify_report(report),
            ReportFate::Next | ReportFate::Ahead { room: true } | ReportFate::Stale { first: true }
        )
    }

    /// A report from an agent, decoded. Reports of a token apply once each, in sequence order.
    pub fn handle_report(&mut self, now_ms: u64, report: Report) {
        self.advance(now_ms);
        match self.classify_report(&report) {
            ReportFate::OtherRun => self.drop_msg(format!("report from `{}` for another run dropped", report.agent)),
            ReportFate::FinishedAgain(entry) => {
                // A duplicate of a finished token's report: acknowledge again, apply nothing.
                self.stats.dropped += 1;
                self.ack(report.agent, entry);
            }
            ReportFate::UnknownToken => {
                self.drop_msg(format!("report from `{}` for unknown token {} dropped", report.agent, report.token))
            }
            ReportFate::Stale { first } => self.stale_report(report, first),
            ReportFate::FutureEpoch => self.drop_msg(format!(
                "report from `{}` for token {} dropped: epoch {} was never dispatched",
                report.agent, report.token, report.epoch
            )),
            ReportFate::NotHolder => self.drop_msg(format!(
                "report for token {} dropped: it came from `{}`, which does not hold it",
                report.token, report.agent
            )),
            ReportFate::OtherProcess => self.drop_msg(format!(
                "report for token {} dropped: it came from another process than `{}`'s current one",
                report.token, report.agent
            )),
            ReportFate::Old => {
                let Some(tok) = self.tokens.get(&report.token) else { return };
                let entry = AckEntry { token: report.token, epoch: tok.epoch, seq: tok.next_seq - 1, done: false };
                self.stats.dropped += 1;
                self.ack(report.agent, entry);
            }
            ReportFate::Ahead { room: false } => self.stats.dropped += 1,
            ReportFate::Ahead { room: true } => {
                let Some(tok) = self.tokens.get_mut(&report.token) else { return };
                tok.ahead_bytes += report.weight();
                tok.ahead.insert(report.seq, report);
            }
            ReportFate::Next => self.next_report(report),
        }
    }

    /// A report of an older epoch (its segment was taken back): the agent is told to drop it, and the trace
    /// says so once per epoch.
    fn stale_report(&mut self, report: Report, first: bool) {
        let Some(tok) = self.tokens.get_mut(&report.token) else { return };
        let epoch = tok.epoch;
        if first {
            if tok.stale_traced.len() >= STALE_EPOCHS_TRACED {
                tok.stale_traced.remove(0);
            }
            tok.stale_traced.push(report.epoch);
            let entry = self.program.steps[tok.entry.index()].name.clone();
            let mut rec = TraceRecord::new(self.now_ms, TraceEvent::RejectStale, &entry);
            rec.agent = Some(report.agent.clone());
            rec.token = Some(report.token.to_string());
            rec.epoch = Some(report.epoch);
            self.trace(rec);
        }
        let msg = ToAgent::Drop { run: self.run, token: report.token, epoch: report.epoch };
        let (agent, incarnation) = (report.agent.clone(), report.incarnation);
        self.outbox.push_back(CoordOutput::Send { agent, incarnation, msg });
        self.drop_msg(format!(
            "report from `{}` for token {} rejected: epoch {} is stale (current {epoch}); told to drop it",
            report.agent, report.token, report.epoch
        ));
    }

    /// The report the token waited for: it applies, and so do those held ahead that follow it.
    fn next_report(&mut self, report: Report) {
        let Some(tok) = self.tokens.get_mut(&report.token) else { return };
        // A report on the token is as good as the agent saying it holds it.
        tok.confirmed = true;
        let id = report.token;
        let mut next = Some(report);
        while let Some(r) = next {
            let done = r.done;
            self.apply_report(r);
            if done {
                break;
            }
            next = self.tokens.get_mut(&id).and_then(|t| {
                let seq = t.next_seq;
                let r = t.ahead.remove(&seq)?;
                t.ahead_bytes = t.ahead_bytes.saturating_sub(r.weight());
                Some(r)
            });
        }
        self.settle();
    }

    fn apply_report(&mut self, r: Report) {
        let Some(tok) = self.tokens.get(&r.token) else { return };
        let (segment, dispatched_ms, epoch) = (tok.segment, tok.dispatched_ms, tok.epoch);
        let placement = self.layout.segments[segment.index()].placement.clone();
        let program = Arc::clone(&self.program);
        self.apply_agent_vars(&r.agent, r.incarnation, r.vars_seq, &r.vars);
        // Never before the coordinator's last grid point: a report that comes late (lost and sent again, an agent
        // cut off for a while) cannot make the coordinator's own steps active in cycles that have passed without
        // them, or their actions would run fewer cycles than their step times say.
        let mut floor = self.engine.now_ms().max(self.now_ms - self.now_ms % self.cycle_ms);
        for ev in &r.events {
            // Agent times are offsets from the token's arrival; they are mapped onto this clock, never before
            // what the coordinator already recorded and never after now.
            let t_ms = dispatched_ms.saturating_add(ev.dt_ms).clamp(floor, self.now_ms.max(floor));
            floor = t_ms;
            // Which run of its segment it happened in: a test can tell a segment run twice in one epoch.
            let rec = |event: TraceEvent, name: &str, message: Option<String>| {
                let mut rec = TraceRecord::new(t_ms, event, name);
                rec.agent = Some(r.agent.clone());
                rec.token = Some(r.token.to_string());
                rec.epoch = Some(epoch);
                rec.message = message;
                rec
            };
            match &ev.kind {
                AgentEventKind::Fire { transition } => {
                    let t = TransitionId(*transition);
                    let ok = (*transition as usize) < program.transitions.len()
                        && self.layout.agent_judges(&program, t) == Some(segment);
                    if !ok {
                        self.drop_msg(format!(
                            "`{}` reported transition {transition}, which is not its to clear",
                            r.agent
                        ));
                        continue;
                    }
                    if let Err(e) = self.engine.handle_remote(t_ms, RemoteInput::Fire(t)) {
                        self.drop_msg(format!("`{}` reported a clearing this coordinator cannot mirror: {e}", r.agent));
                        continue;
                    }
                    self.drain_engine();
                }
                AgentEventKind::ActionOn { action } | AgentEventKind::ActionOff { action } => {
                    let Some(info) = program.actions.get(*action as usize) else {
                        self.drop_msg(format!("`{}` reported unknown action {action}", r.agent));
                        continue;
                    };
                    if self.layout.action_placement[*action as usize] != placement {
                        self.drop_msg(format!(
                            "`{}` reported action `{}`, which does not run there",
                            r.agent, info.name
                        ));
                        continue;
                    }
                    let on = matches!(ev.kind, AgentEventKind::ActionOn { .. });
                    let rec = rec(if on { TraceEvent::ActionOn } else { TraceEvent::ActionOff }, &info.name, None);
                    self.trace(rec);
                }
                AgentEventKind::SkillDone { action } => {
                    let Some(info) = program.actions.get(*action as usize) else { continue };
                    let rec = rec(TraceEvent::SkillDone, &info.name, None);
                    self.trace(rec);
                }
                AgentEventKind::SkillFault { action, message } => {
                    let Some(info) = program.actions.get(*action as usize) else { continue };
                    let rec = rec(TraceEvent::SkillFault, &info.name, Some(message.clone()));
                    self.log(
                        Level::Warn,
                        format!("skill of action `{}` on `{}` failed: {message}", info.name, r.agent),
                    );
                    self.trace(rec);
                }
                AgentEventKind::Fault { message } => {
                    let rec = rec(TraceEvent::Fault, &program.name, Some(message.clone()));
                    self.log(Level::Error, format!("on `{}`: {message}", r.agent));
                    self.trace(rec);
                }
            }
        }
        let agent = r.agent.clone();
        self.ack(agent.clone(), AckEntry { token: r.token, epoch, seq: r.seq, done: r.done });
        if let Some(tok) = self.tokens.get_mut(&r.token) {
            tok.next_seq = r.seq + 1;
        }
        if r.done {
            self.finish(r.token, epoch, r.seq, agent);
        }
    }

    fn finish(&mut self, id: TokenId, epoch: u32, seq: u32, agent: String) {
        let Some(tok) = self.tokens.remove(&id) else { return };
        self.by_segment[tok.segment.index()] = None;
        if let Some(a) = self.agents.get_mut(&agent) {
            a.tokens = a.tokens.saturating_sub(1);
        }
        self.forget_if_gone(&agent);
        let still =
            self.layout.segments[tok.segment.index()].steps.iter().find(|&&s| self.engine.is_active(s)).copied();
        if let Some(s) = still {
            let name = self.program.steps[s.index()].name.clone();
            self.log(
                Level::Error,
                format!("token {id} came back from `{agent}` while its step `{name}` is still active"),
            );
        }
        self.stats.returned += 1;
        let mut rec = TraceRecord::new(self.now_ms, TraceEvent::Return, &self.program.steps[tok.entry.index()].name);
        rec.agent = Some(agent.clone());
        rec.token = Some(id.to_string());
        rec.epoch = Some(epoch);
        self.trace(rec);
        if self.finished_order.len() >= FINISHED_TOKENS_REMEMBERED {
            if let Some(old) = self.finished_order.pop_front() {
                self.finished.remove(&old);
            }
        }
        self.finished.insert(id, (epoch, seq, agent));
        self.finished_order.push_back(id);
    }

    fn serves(&self, agent: &str, placement: &Placement) -> bool {
        match placement {
            Placement::Coordinator => false,
            Placement::Agent(a) => a == agent,
            Placement::Role(r) => self.agents.get(agent).is_some_and(|s| s.roles.iter().any(|x| x == r)),
        }
    }

    /// Values from `agent`'s process `incarnation`, as of its update `seq`: each applies unless a newer write of
    /// the variable was applied already.
    fn apply_agent_vars(&mut self, agent: &str, incarnation: uuid::Uuid, seq: u64, vars: &[VarValue]) -> bool {
        let mut applied = false;
        let mut refused: BTreeSet<u32> = BTreeSet::new();
        for vv in vars {
            let Some((var, value)) = vv.resolve(&self.program) else {
                refused.insert(vv.var);
                continue;
            };
            if !self.serves(agent, &self.layout.writer[var.index()]) {
                refused.insert(vv.var);
                continue;
            }
            if !self.var_writes.accept(var.index(), agent, incarnation, seq, false) {
                continue;
            }
            applied = true;
            if let Err(e) = self.engine.handle(Input::Set(var, value)) {
                self.log(Level::Warn, format!("value from `{agent}` refused: {e}"));
            }
        }
        if !refused.is_empty() {
            self.drop_msg(format!(
                "`{agent}` sent {} variable value(s) it does not write, or of the wrong type",
                refused.len()
            ));
        }
        applied
    }

    /// The part of an agent's variable update that would apply: its values of variables it writes, that fit
    /// their types and are newer than those applied, each variable once (its first value, as `handle_vars` takes
    /// it). `None` when nothing would: then nothing is journaled, whatever the update weighs.
    pub fn admit_vars(&self, update: &VarUpdate) -> Option<Vec<VarValue>> {
        if update.from == COORDINATOR || update.run != self.run {
            return None;
        }
        let agent = self.agents.get(&update.from)?;
        if agent.incarnation != update.incarnation {
            return None;
        }
        let mut seen = BTreeSet::new();
        let kept: Vec<VarValue> = update
            .vars
            .iter()
            .filter(|vv| {
                vv.resolve(&self.program).is_some_and(|(var, _)| {
                    self.serves(&update.from, &self.layout.writer[var.index()])
                        && self.var_writes.would_accept(var.index(), &update.from, update.incarnation, update.seq)
                        && seen.insert(var)
                })
            })
            .cloned()
            .collect();
        (!kept.is_empty()).then_some(kept)
    }

    /// A device report as it would apply (its messages cut to `DEVICE_MESSAGE_CHARS_MAX`, each binding once, as
    /// `handle_devices` keeps them); `None` when it would not apply, and then it is not journaled.
    pub fn admit_devices(&self, report: &DeviceReport) -> Option<DeviceReport> {
        if report.run != self.run {
            return None;
        }
        let agent = self.agents.get(&report.agent)?;
        if agent.incarnation != report.incarnation || !agent.alive || report.seq <= agent.devices_seq {
            return None;
        }
        let mut down: BTreeMap<u32, String> = BTreeMap::new();
        for d in &report.down {
            let ours = self.layout.io.get(d.binding as usize).is_some_and(|b| b.agent == report.agent);
            if !ours {
                return None;
            }
            down.insert(d.binding, d.message.chars().take(crate::limits::DEVICE_MESSAGE_CHARS_MAX).collect());
        }
        let down = down.into_iter().map(|(binding, message)| crate::dist::wire::DeviceDown { binding, message });
        Some(DeviceReport { down: down.collect(), ..report.clone() })
    }

    /// A variable update published by an agent (also sent to agents that read it).
    pub fn handle_vars(&mut self, now_ms: u64, update: VarUpdate) {
        self.advance(now_ms);
        if update.from == COORDINATOR {
            return;
        }
        if update.run != self.run {
            return self.drop_msg(format!("variable update from `{}` for another run dropped", update.from));
        }
        let Some(agent) = self.agents.get(&update.from) else {
            return self.drop_msg(format!("variable update from unknown agent `{}` dropped", update.from));
        };
        if agent.incarnation != update.incarnation {
            return self.drop_msg(format!(
                "variable update from `{}` dropped: it comes from another process than the agent's current one",
                update.from
            ));
        }
        // An update that changes nothing (every value older than one applied) is not journaled: it must not move
        // the engine either, or a replay would differ.
        if self.apply_agent_vars(&update.from, update.incarnation, update.seq, &update.vars) {
            self.settle();
        }
    }

    /// Which of its bound devices an agent cannot reach. Each change is a trace record, `device_down` or
    /// `device_up`, named after the variable, and a log line; the variable keeps its value meanwhile.
    pub fn handle_devices(&mut self, now_ms: u64, report: DeviceReport) {
        self.advance(now_ms);
        if report.run != self.run {
            return self.drop_msg(format!("device report from `{}` for another run dropped", report.agent));
        }
        let Some(agent) = self.agents.get(&report.agent) else {
            return self.drop_msg(format!("device report from unknown agent `{}` dropped", report.agent));
        };
        if agent.incarnation != report.incarnation || !agent.alive {
            return self.drop_msg(format!(
                "device report from `{}` dropped: it comes from another process than the agent's current one",
                report.agent
            ));
        }
        if report.seq <= agent.devices_seq {
            return;
        }
        let mut down = BTreeMap::new();
        for d in report.down {
            let ours = self.layout.io.get(d.binding as usize).is_some_and(|b| b.agent == report.agent);
            if !ours {
                return self.drop_msg(format!(
                    "device report from `{}` dropped: binding {} is not one of its own",
                    report.agent, d.binding
                ));
            }
            down.insert(d.binding, d.message.chars().take(crate::limits::DEVICE_MESSAGE_CHARS_MAX).collect());
        }
        let Some(agent) = self.agents.get_mut(&report.agent) else { return };
        agent.devices_seq = report.seq;
        let before = std::mem::replace(&mut agent.devices_down, down.clone());
        let name = report.agent;
        for (b, why) in &down {
            if !before.contains_key(b) {
                let binding = &self.layout.io[*b as usize];
                let mut rec = TraceRecord::new(self.now_ms, TraceEvent::DeviceDown, &binding.name);
                rec.agent = Some(name.clone());
                rec.message = Some(format!("{}: {why}", binding.device()));
                let text = format!(
                    "agent `{name}` cannot reach the device of `{}` ({}): {why}; `{}` keeps its value {}",
                    binding.name,
                    binding.device(),
                    binding.name,
                    self.engine.value(binding.var)
                );
                self.trace(rec);
                self.log(Level::Warn, text);
            }
        }
        for b in before.keys().filter(|b| !down.contains_key(b)) {
            let binding = &self.layout.io[*b as usize];
            let mut rec = TraceRecord::new(self.now_ms, TraceEvent::DeviceUp, &binding.name);
            rec.agent = Some(name.clone());
            rec.message = Some(binding.device());
            let text = format!("agent `{name}` reaches the device of `{}` again ({})", binding.name, binding.device());
            self.trace(rec);
            self.log(Level::Info, text);
        }
    }

    /// `baton set NAME=VALUE`: sets an input (a variable no action writes) before the next cycle.
    pub fn handle_set(&mut self, now_ms: u64, name: &str, value: &serde_json::Value) -> Result<String, String> {
        self.advance(now_ms);
        let (var, v) = self.check_set(name, value)?;
        let program = Arc::clone(&self.program);
        let info = &program.vars[var.index()];
        let shown = info.ty.show(&v);
        self.engine.handle(Input::Set(var, v)).map_err(|e| e.to_string())?;
        let mut rec = TraceRecord::new(self.now_ms, TraceEvent::Set, &info.name);
        rec.message = Some(shown.clone());
        self.trace(rec);
        self.settle();
        Ok(format!("{} := {shown}", info.name))
    }

    /// Whether `baton set NAME=VALUE` would apply; why not, if not (then it is not journaled).
    pub fn check_set(&self, name: &str, value: &serde_json::Value) -> Result<(VarId, Value), String> {
        let var = self
            .program
            .var_by_name(name)
            .ok_or_else(|| format!("chart `{}` has no variable `{name}`", self.program.name))?;
        let info = &self.program.vars[var.index()];
        if !self.layout.settable[var.index()] {
            let why = if info.constant {
                "it is a CONSTANT".to_string()
            } else {
                format!("the chart writes it on {}", self.layout.writer[var.index()])
            };
            return Err(format!("`{}` cannot be set: {why}", info.name));
        }
        let v = parse_value(&info.ty, value)
            .ok_or_else(|| format!("`{}` is {}, and {value} is not a {} value", info.name, info.ty, info.ty))?;
        Ok((var, v))
    }

    pub fn status(&self) -> StatusReport {
        let mut active_steps: Vec<StatusStep> = self
            .engine
            .active_steps()
            .iter()
            .map(|&s| StatusStep {
                name: self.program.steps[s.index()].name.clone(),
                placement: self.layout.placement[s.index()].to_string(),
                agent: self.holder(s).map(str::to_string),
            })
            .collect();
        active_steps.sort_by(|a, b| a.name.cmp(&b.name));
        let mut tokens: Vec<StatusToken> = self
            .tokens
            .iter()
            .map(|(id, t)| StatusToken {
                token: *id,
                epoch: t.epoch,
                entry: self.program.steps[t.entry.index()].name.clone(),
                agent: t.agent.clone(),
                since_ms: t.dispatched_ms,
                paused: t.paused,
            })
            .collect();
        tokens.sort_by_key(|t| (t.since_ms, t.token));
        let agents = self
            .agents
            .iter()
            .filter(|(_, a)| a.alive)
            .map(|(name, a)| StatusAgent {
                name: name.clone(),
                roles: a.roles.clone(),
                tokens: a.tokens,
                devices_down: a
                    .devices_down
                    .iter()
                    .map(|(b, why)| {
                        let binding = &self.layout.io[*b as usize];
                        StatusDevice { var: binding.name.clone(), device: binding.device(), message: why.clone() }
                    })
                    .collect(),
            })
            .collect();
        StatusReport {
            run: self.run,
            chart: self.program.name.clone(),
            hash: self.hash.clone(),
            t_ms: self.now_ms,
            active_steps,
            tokens,
            agents,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::limits::AGENTS_MAX;

    const RUN: RunId = RunId(uuid::Uuid::from_u128(7));

    fn coordinator_of(program: &Arc<Program>, layout: &Arc<Layout>) -> Coordinator {
        let (program, layout) = (Arc::clone(program), Arc::clone(layout));
        Coordinator::new(program, layout, RUN, ChartHash("h".into()), crate::dist::journal::token_ids(RUN))
    }

    fn coordinator() -> Coordinator {
        let (program, layout) = crate::testing::simulated_cluster::compile(
            "PROGRAM p\nINITIAL_STEP A: END_STEP\nTRANSITION FROM A TO B := TRUE; END_TRANSITION\n\
             STEP B: {role := 'worker'} END_STEP\nEND_PROGRAM\n",
        );
        coordinator_of(&program, &layout)
    }

    fn info(name: &str, n: u128) -> AgentInfo {
        AgentInfo {
            name: name.into(),
            roles: Vec::new(),
            lease_ms: 1000,
            incarnation: uuid::Uuid::from_u128(n),
            held: Vec::new(),
        }
    }

    #[test]
    fn agents_that_are_gone_and_hold_nothing_are_forgotten() {
        let mut c = coordinator();
        // Far more names than the coordinator tracks come and go, as on a cell whose agents restart under new
        // names for months.
        for i in 0..(2 * AGENTS_MAX) {
            let name = format!("a{i}");
            c.handle_agent_up(i as u64, info(&name, i as u128));
            c.handle_agent_down(i as u64, &name);
        }
        assert!(c.agents.is_empty(), "{} agents remembered", c.agents.len());
        c.handle_agent_up(10_000, info("newcomer", 1));
        assert_eq!(c.status().agents.len(), 1, "a new agent is still taken");
    }

    #[test]
    fn a_device_that_cannot_be_reached_is_traced_once_each_way_and_a_rogue_report_changes_nothing() {
        use crate::dist::runtime::agent::{AgentOutput, AgentRun};
        let source = "PROGRAM p\nVAR\n  door : BOOL; {input := 'opcua', agent := 'cell1', endpoint := \
                      'opc.tcp://10.0.0.5:4840', node := 'ns=2;s=Door'}\n  lamp : BOOL; {output := 'zenoh', \
                      agent := 'cell2', key := 'cell2/lamp'}\nEND_VAR\nINITIAL_STEP A: END_STEP\n\
                      TRANSITION FROM A TO B := door; END_TRANSITION\nSTEP B: END_STEP\nEND_PROGRAM\n";
        let (program, layout) = crate::testing::simulated_cluster::compile(source);
        let mut c = coordinator_of(&program, &layout);
        let mut agent = AgentRun::new("cell1", &[], RUN, ChartHash("h".into()), program, layout, 10);
        agent.set_incarnation(uuid::Uuid::from_u128(1));
        c.handle_agent_up(0, info("cell1", 1));
        c.handle_agent_up(0, info("cell2", 2));
        let reports = |a: &mut AgentRun| {
            let mut out = Vec::new();
            while let Some(o) = a.poll_output() {
                if let AgentOutput::Devices(d) = o {
                    out.push(d);
                }
            }
            out
        };
        let traced = |c: &mut Coordinator| {
            let mut out = Vec::new();
            while let Some(o) = c.poll_output() {
                if let CoordOutput::Trace(t) = o {
                    if matches!(t.event, TraceEvent::DeviceUp | TraceEvent::DeviceDown) {
                        out.push((t.event, t.name, t.message.unwrap_or_default()));
                    }
                }
            }
            out
        };
        traced(&mut c);
        agent.handle_device(0, Err("cannot reach opc.tcp://10.0.0.5:4840: BadTimeout".into()));
        // Tried again and failing for another reason: no second report.
        agent.handle_device(0, Err("cannot reach opc.tcp://10.0.0.5:4840: BadConnectionRejected".into()));
        let down = reports(&mut agent);
        assert_eq!(down.len(), 1);
        c.handle_devices(10, down[0].clone());
        let t = traced(&mut c);
        assert_eq!(t.len(), 1, "{t:?}");
        assert_eq!((t[0].0, t[0].1.as_str()), (TraceEvent::DeviceDown, "door"));
        assert!(t[0].2.contains("OPC UA node ns=2;s=Door") && t[0].2.contains("BadTimeout"), "{}", t[0].2);
        assert_eq!(c.status().agents[0].devices_down[0].var, "door");
        // The same report again (a Join answered), a late one, another process's, and one about a binding of
        // another agent: nothing is traced.
        c.handle_devices(11, down[0].clone());
        let join = crate::dist::runtime::agent::Join { vars: Vec::new(), vars_seq: 0, peers: Peers::default() };
        agent.handle_join(0, join);
        let again = reports(&mut agent);
        c.handle_devices(12, again[0].clone());
        let mut stale = again[0].clone();
        stale.seq = 1;
        stale.down.clear();
        c.handle_devices(13, stale);
        let mut other = again[0].clone();
        other.seq = 99;
        other.incarnation = uuid::Uuid::from_u128(5);
        other.down.clear();
        c.handle_devices(14, other);
        let mut rogue = again[0].clone();
        rogue.seq = 100;
        rogue.down[0].binding = 1;
        c.handle_devices(15, rogue);
        assert!(traced(&mut c).is_empty());
        assert_eq!(c.status().agents[0].devices_down.len(), 1);
        agent.handle_device(0, Ok(()));
        for r in reports(&mut agent) {
            c.handle_devices(20, r);
        }
        assert_eq!(
            traced(&mut c),
            vec![(TraceEvent::DeviceUp, "door".into(), "OPC UA node ns=2;s=Door on opc.tcp://10.0.0.5:4840".into())]
        );
        assert!(c.status().agents[0].devices_down.is_empty());
    }
}
