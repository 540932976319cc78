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

mod devices;
mod operator;
mod skills;
mod timers;
mod tokens;
mod variables;

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::sync::Arc;

use uuid::Uuid;

use crate::cluster::bindings::{IoBinding, IoDir};
use crate::cluster::layout::{Layout, Placement, SegmentId, SkillBinding};
use crate::cluster::wire::{
    AgentEvent, ChartHash, DeviceReport, HeldToken, Peers, Report, RunId, ToAgent, TokenId, VarUpdate, VarValue,
};
use crate::exec::engine::Engine;
use crate::exec::program::{ActionId, Program, StepId, VarId};
use crate::exec::trace::{TraceEvent, TraceRecord};
use crate::types::Value;

use super::{FinishedTokens, Level, VarWrites, VarsResend};

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
    /// A record for the agent's own trace (`baton-agent --trace`): what befell a skill or an input here. Its
    /// `t_ms` is the run's clock; the host stamps it with its own and names the agent.
    Trace(TraceRecord),
}

/// Why `AgentRun::handle_message` did not take a message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NotTaken {
    /// It is for another run.
    OtherRun,
    /// A dispatch or join made with another version of the chart than this run's.
    OtherChart,
    /// A command of a coordinator whose term is lower than the highest this run has seen.
    StaleTerm,
}

/// What a command is, for the log and the trace.
fn command_name(msg: &ToAgent) -> &'static str {
    match msg {
        ToAgent::Dispatch { .. } => "dispatch",
        ToAgent::Gate { .. } => "gate",
        ToAgent::Hold { .. } => "hold",
        ToAgent::Abort { .. } => "abort",
        ToAgent::AckOverrun { .. } => "ack_overrun",
        ToAgent::Drop { .. } => "drop",
        ToAgent::Ack { .. } => "ack",
        ToAgent::Sync { .. } => "sync",
        ToAgent::Join { .. } => "join",
        ToAgent::Peers { .. } => "peers",
    }
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
    /// The token arrives held: its entry step becomes active when it is released.
    pub held: bool,
    /// The run's mode: how its transitions clear.
    pub mode: crate::exec::engine::Mode,
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
    /// Held by an operator (`handle_hold`); what this agent last confirmed of it (`Held` or `Released`).
    held: bool,
    held_said: Option<bool>,
    /// It arrived held: its entry step, made active when it is released.
    pending_entry: Option<StepId>,
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
    finished: FinishedTokens<u32>,
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
    /// The run was aborted (`handle_abort`): nothing of it runs here again.
    aborted: bool,
    /// Skills cancelled because their token was held (`{hold := 'cancel'}`): started again on release.
    cancelled_on_hold: BTreeSet<ActionId>,
    /// The transitions said to be waiting for a confirmation (step mode), as last reported.
    waiting_said: BTreeSet<u32>,
    /// When each running skill started.
    skill_started: BTreeMap<ActionId, u64>,
    /// Skills started while their branch was held: a broken promise, counted for the simulation to find.
    started_while_held: u64,
    /// The highest coordinator term seen of this run (`wire::encode_termed`); commands and the coordinator's
    /// variable updates of a lower one are refused (`stale_terms` counts them).
    term: u64,
    stale_terms: u64,
    stale_said: BTreeSet<u64>,
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
            finished: FinishedTokens::default(),
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
            aborted: false,
            cancelled_on_hold: BTreeSet::new(),
            waiting_said: BTreeSet::new(),
            skill_started: BTreeMap::new(),
            started_while_held: 0,
            term: 0,
            stale_terms: 0,
            stale_said: BTreeSet::new(),
        };
        run.send_outputs();
        run
    }

    /// The variables bound to devices on this agent, by their index in `Layout::io`.
    pub fn io_here(&self) -> impl Iterator<Item = (usize, &IoBinding)> + '_ {
        self.layout.io.iter().enumerate().filter(move |(_, b)| b.agent == self.name)
    }

    /// This agent's process (`AgentInfo::incarnation`), which numbers its variable updates.
    pub fn set_incarnation(&mut self, incarnation: Uuid) {
        self.incarnation = incarnation;
    }

    /// The run this agent's part belongs to.
    pub fn run(&self) -> RunId {
        self.run
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

    /// Reports sent and not acknowledged yet, by token and sequence number, at most `max` (for the info answer).
    pub fn pending_reports(&self, max: usize) -> Vec<Report> {
        let mut pending: Vec<Report> =
            self.tokens.values().flat_map(|t| t.unacked.iter().map(|u| u.report.clone())).collect();
        pending.sort_by_key(|r| (r.token, r.seq));
        pending.truncate(max);
        pending
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

    /// A command of the coordinator's, decoded, with the coordinator's term it came with: the one way the agent's
    /// host and the simulated cluster alike hand one over. The acknowledgements a dispatch carries apply before
    /// the dispatch (the reports they answer are done with before the new token starts). A message of another
    /// run, a dispatch or join of another version of the chart, or a command of a lower term than the highest
    /// this run has seen (a coordinator deposed that has not noticed yet) is not taken: the caller says why it
    /// dropped the first two, and this run logs and traces the third.
    pub fn handle_message(&mut self, now_ms: u64, term: u64, msg: ToAgent) -> Result<(), NotTaken> {
        if msg.run() != self.run {
            return Err(NotTaken::OtherRun);
        }
        if !self.take_term(now_ms, term, command_name(&msg)) {
            return Err(NotTaken::StaleTerm);
        }
        match msg {
            ToAgent::Dispatch {
                chart,
                token,
                epoch,
                segment,
                entry,
                vars,
                vars_seq,
                acks,
                fence,
                peers,
                held,
                mode,
                ..
            } => {
                if chart != self.hash {
                    return Err(NotTaken::OtherChart);
                }
                for a in acks {
                    self.handle_ack(a.token, a.epoch, a.seq, a.done);
                }
                let d = Dispatch { token, epoch, segment, entry, vars, vars_seq, fence, peers, held, mode };
                self.handle_dispatch(now_ms, d);
            }
            ToAgent::Join { chart, vars, vars_seq, peers, .. } => {
                if chart != self.hash {
                    return Err(NotTaken::OtherChart);
                }
                self.handle_join(now_ms, Join { vars, vars_seq, peers });
            }
            ToAgent::Drop { token, epoch, .. } => self.handle_drop(now_ms, token, epoch),
            ToAgent::Ack { acks, .. } => {
                for a in acks {
                    self.handle_ack(a.token, a.epoch, a.seq, a.done);
                }
            }
            ToAgent::Peers { peers, .. } => self.handle_peers(now_ms, peers),
            ToAgent::Sync { .. } => self.handle_sync(now_ms),
            ToAgent::Hold { token, epoch, held, .. } => self.handle_hold(now_ms, token, epoch, held),
            ToAgent::Gate { token, epoch, mode, permit, seq, .. } => {
                self.handle_gate(now_ms, token, epoch, mode, permit, seq)
            }
            ToAgent::AckOverrun { token, epoch, step, .. } => self.handle_ack_overrun(now_ms, token, epoch, step),
            ToAgent::Abort { .. } => self.handle_abort(now_ms),
        }
        Ok(())
    }

    /// Whether a coordinator's message of `term` may be taken: of the highest term seen or a higher one, which
    /// becomes the highest. A refusal is counted, logged and traced (`stale_term`, named by what was refused).
    pub(super) fn take_term(&mut self, now_ms: u64, term: u64, what: &str) -> bool {
        if term >= self.term {
            if term > self.term {
                let message =
                    format!("coordinator term {term} (was {}): lower terms are refused from now on", self.term);
                self.log(Level::Info, format!("run {}: {message}", self.run.key()));
                self.advance(now_ms);
                self.note(TraceEvent::Term, "coordinator", None, Some(message));
            }
            self.term = term;
            return true;
        }
        self.advance(now_ms);
        self.stale_terms += 1;
        self.dropped += 1;
        let message = format!(
            "{what} of coordinator term {term} refused: this run has seen term {}, whose coordinator replaced it",
            self.term
        );
        // Said once per stale term: a deposed coordinator that keeps sending is not a log flood.
        if self.stale_said.insert(term) {
            self.log(Level::Warn, format!("run {}: {message}", self.run.key()));
        }
        self.note(TraceEvent::StaleTerm, what, None, Some(message));
        false
    }

    /// Takes `term` as the highest seen of this run before any message: the one an earlier process of this agent
    /// had heard (`baton-agent`'s state folder). Lower terms are refused from now on, and the log says so.
    pub fn remember_term(&mut self, now_ms: u64, term: u64) {
        if term > self.term {
            self.advance(now_ms);
            self.log(
                Level::Info,
                format!(
                    "run {}: coordinator term {term} remembered from before this agent's restart: lower terms are \
                     refused",
                    self.run.key()
                ),
            );
            self.term = term;
        }
    }

    /// The highest coordinator term seen of this run, and how many messages of lower ones were refused.
    pub fn term(&self) -> (u64, u64) {
        (self.term, self.stale_terms)
    }

    fn log(&mut self, level: Level, message: String) {
        self.outbox.push_back(AgentOutput::Log { level, message });
    }

    /// A record for the agent's trace: `event` of `name` (an action or a variable), of `token` if any.
    fn note(&mut self, event: TraceEvent, name: &str, token: Option<TokenId>, message: Option<String>) {
        let mut record = TraceRecord::new(self.now_ms, event, name);
        record.token = token.map(|t| t.to_string());
        record.message = message;
        self.outbox.push_back(AgentOutput::Trace(record));
    }

    fn drop_msg(&mut self, message: String) {
        self.dropped += 1;
        self.log(Level::Warn, message);
    }

    fn advance(&mut self, now_ms: u64) {
        self.now_ms = self.now_ms.max(now_ms);
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
            let why = format!("`{value}` is not a {ty}; the value stays {}", self.engine.value(var));
            self.log(Level::Warn, format!("input `{name}`: {why}"));
            let var_name = self.program.vars[var.index()].name.clone();
            self.note(TraceEvent::InputRefused, &var_name, None, Some(why));
            return;
        }
        self.write_from_device(var, value, format!("input `{name}`"));
    }
}

#[cfg(test)]
mod tests;
