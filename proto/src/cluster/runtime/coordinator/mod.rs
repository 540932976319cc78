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
//! Cycles run on the run's grid (`k · cycle_ms`), one at a time, whatever the traffic: the host asks
//! `poll_timeout` when the next one is needed and runs it at its grid time. What arrives in between is applied at
//! once and followed by a reaction (`Engine::react`), so a token's return or an input is acted on without
//! waiting for the next cycle, and without running any action body an extra time.

mod control;
mod devices;
mod inbound;
mod membership;
mod modes;
mod operate;
mod reports;
mod restart;
mod snapshot;
mod state;
mod supervision;
mod timers;
mod tokens;
mod variables;

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::sync::Arc;

use crate::cluster::layout::{Layout, Placement};
use crate::cluster::wire::{AckEntry, ChartHash, FromAgent, Peers, RunId, ToAgent, TokenId, VarUpdate};
use crate::exec::engine::Engine;
use crate::exec::program::{Program, TransitionId, VarId};
use crate::exec::trace::{TraceEvent, TraceRecord};
use crate::types::Value;

use super::alarms::{AlarmChange, Alarms};
use super::packml::State;
use super::{FinishedTokens, Level, VarWrites, VarsResend};
use state::{AgentState, PartialHolds, Supervised, TokenState};

pub use state::{token_ids, TokenIds};

/// First and largest delay before a dispatch that no report answered is sent again (the agent drops the
/// duplicate if it has the token).
const DISPATCH_RESEND_FIRST_MS: u64 = 500;

const DISPATCH_RESEND_MAX_MS: u64 = 5_000;

/// First and largest delay before the agent of a token that reported once and then went quiet is asked for the
/// reports it has not had acknowledged (`CoordOutput::Ask`). A token whose motion runs long is quiet too: the
/// answer then lists nothing, at one question per agent per `ASK_MAX_MS` at most.
const ASK_FIRST_MS: u64 = 1_000;

const ASK_MAX_MS: u64 = 8_000;

/// What the coordinator takes of a message (`Coordinator::admit`).
#[derive(Clone, Debug, PartialEq)]
pub enum Admitted {
    /// Nothing: it claims to be from another agent than its sender. Dropped and counted, never journaled.
    Refused,
    /// Applied, and nothing of it is journaled (a duplicate acknowledged again, a stale update).
    Unrecorded,
    /// Applied and journaled as it came.
    Whole,
    /// Journaled as this part of it, which is what applies (the values of an update that apply, a device report's
    /// messages cut).
    Part(FromAgent),
}

/// What the coordinator asks its host to do.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum CoordOutput {
    /// A command for one process (`incarnation`) of `agent`.
    Send {
        agent: String,
        incarnation: uuid::Uuid,
        msg: ToAgent,
    },
    Vars(VarUpdate),
    /// Ask process `incarnation` of `agent` for its info (`AgentInfo::pending`: the reports it sent that no
    /// acknowledgement answered) and give what it lists to `Journaled::report` as if the reports had arrived: a
    /// token of it has been quiet (`ASK_FIRST_MS`). A router that lost its routes drops puts and still carries
    /// queries.
    Ask {
        agent: String,
        incarnation: uuid::Uuid,
    },
    Trace(TraceRecord),
    Log {
        level: Level,
        message: String,
    },
}

/// What the coordinator does with the tokens of an agent that is lost (`baton run --on-agent-loss`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
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

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct CoordStats {
    pub dispatched: u64,
    pub returned: u64,
    /// Dispatches sent again because no report answered them.
    pub resent: u64,
    /// Agents asked for their unacknowledged reports because a token of theirs was quiet.
    pub asked: u64,
    /// Reports and updates that were malformed, stale, duplicated or from the wrong agent.
    pub dropped: u64,
}

#[derive(serde::Serialize, serde::Deserialize)]
pub struct Coordinator {
    run: RunId,
    hash: ChartHash,
    /// Not in a snapshot: `restore` is given them.
    #[serde(skip)]
    program: Arc<Program>,
    #[serde(skip)]
    layout: Arc<Layout>,
    engine: Engine,
    now_ms: u64,
    agents: BTreeMap<String, AgentState>,
    tokens: BTreeMap<TokenId, TokenState>,
    by_segment: Vec<Option<TokenId>>,
    /// Tokens no live agent can take yet, oldest first.
    waiting: Vec<TokenId>,
    /// Finished tokens and their last report, to answer a late duplicate with the same acknowledgement; a snapshot
    /// lists them in id order, as it did when they were in an ordered map.
    #[serde(serialize_with = "in_id_order")]
    finished: FinishedTokens<(u32, u32, String)>,
    finished_order: VecDeque<TokenId>,
    owned: Vec<VarId>,
    published: Vec<Option<Value>>,
    vars_seq: u64,
    /// When the owned values are published again (`VarsResend`).
    vars_resend: VarsResend,
    /// The last write applied to each variable an agent writes.
    var_writes: VarWrites,
    new_token: TokenIds,
    round_robin: usize,
    outbox: VecDeque<CoordOutput>,
    /// Acknowledgements owed, per agent: sent together at the end of the cycle.
    acks: BTreeMap<String, Vec<AckEntry>>,
    /// When the oldest owed acknowledgement was made.
    acks_since_ms: u64,
    policy: LossPolicy,
    /// Why the run must end, under `LossPolicy::Fail`.
    failure: Option<String>,
    /// The run's PackML state (`packml`): Execute from the start, Completing then Complete at its end.
    run_state: State,
    /// Alarms raised and not yet back to normal.
    alarms: Alarms,
    /// Parts of the run held while the rest goes on (`hold --agent`, `hold --step`).
    partial: PartialHolds,
    /// Supervision alarms (`max_ms`) by id, with their step.
    supervised: BTreeMap<super::alarms::AlarmId, Supervised>,
    /// The alarm of each device an agent cannot reach, by agent and binding: its cause is gone when it is reached.
    device_alarms: BTreeMap<(String, u32), super::alarms::AlarmId>,
    /// The alarm of each skill an agent lacks for what its placement would send it, by agent and skill
    /// (`membership::check_skills_of`).
    #[serde(default)]
    skill_alarms: BTreeMap<(String, String), super::alarms::AlarmId>,
    /// The transitions agents said wait for a confirmation (step mode).
    agent_waiting: BTreeSet<TransitionId>,
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
    /// The run stays at its end for `clear` and `reset` (`baton run --stay`).
    stays: bool,
    /// When this run began on the coordinator's clock: 0, or the moment a `reset` made it.
    #[serde(default)]
    started_ms: u64,
    /// Agents that held tokens of a run when it was aborted and could not be told: the run they were not told of,
    /// and the alarms raised for their abandoned tokens (`restart::tell_of_end`).
    untold: BTreeMap<String, (RunId, Vec<super::alarms::AlarmId>)>,
}

/// A map serialized with its entries in key order, as a `BTreeMap` of the same entries is: a snapshot's bytes do not
/// depend on the hasher's seed.
fn in_id_order<S: serde::Serializer, V: serde::Serialize>(
    map: &FinishedTokens<V>,
    serializer: S,
) -> Result<S::Ok, S::Error> {
    let mut entries: Vec<(&TokenId, &V)> = map.iter().collect();
    entries.sort_unstable_by_key(|(id, _)| **id);
    serializer.collect_map(entries)
}

impl Coordinator {
    /// `new_token` gives each token its id (`token_ids`: the run id and a counter, so a replay makes the same).
    pub fn new(
        program: Arc<Program>,
        layout: Arc<Layout>,
        run: RunId,
        hash: ChartHash,
        new_token: TokenIds,
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
            finished: FinishedTokens::default(),
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
            run_state: State::Execute,
            alarms: Alarms::default(),
            partial: PartialHolds::default(),
            supervised: BTreeMap::new(),
            device_alarms: BTreeMap::new(),
            skill_alarms: BTreeMap::new(),
            agent_waiting: BTreeSet::new(),
            recovered_ms: None,
            cycle_ms: 1,
            stats: CoordStats::default(),
            writer_names,
            writer_roles,
            peers: Peers { seq: 0, coordinator: uuid::Uuid::nil(), agents: Vec::new() },
            stays: false,
            started_ms: 0,
            untold: BTreeMap::new(),
        }
    }

    pub fn program(&self) -> &Arc<Program> {
        &self.program
    }

    pub fn layout(&self) -> &Arc<Layout> {
        &self.layout
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

    /// The run is over for whatever reason: terminal, failed, stopped or aborted.
    pub fn is_over(&self) -> bool {
        self.is_terminal() || self.failure.is_some() || self.is_ended_by_operator()
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

    /// Something needs a person: a new occurrence in the run's alarm list (`alarms`), traced with its id and its
    /// `source` (an agent's name), and logged.
    fn alarm(&mut self, source: &str, message: String) -> Option<super::alarms::AlarmId> {
        self.alarm_at(self.now_ms, source, message)
    }

    fn alarm_at(&mut self, t_ms: u64, source: &str, message: String) -> Option<super::alarms::AlarmId> {
        let mut rec = TraceRecord::new(t_ms, TraceEvent::Alarm, source);
        let mut raised = None;
        if let Some(AlarmChange::Raised { id, .. }) = self.alarms.raise(self.now_ms, source, &message, false) {
            rec.id = Some(id.0);
            raised = Some(id);
        }
        rec.message = Some(message.clone());
        self.trace(rec);
        self.log(Level::Error, message);
        raised
    }

    /// Something that happened and is over at once (a skill's fault, a run-time fault) still needs a person: an
    /// alarm whose cause is gone as it is raised, standing until acknowledged. One like it that is standing and not
    /// acknowledged yet is not raised again (a fault every cycle is one alarm, not a flood).
    fn event_alarm(&mut self, t_ms: u64, source: &str, message: String) {
        let standing = self.alarms.standing().any(|a| a.ack.is_none() && a.source == source && a.message == message);
        if standing {
            return;
        }
        if let Some(id) = self.alarm_at(t_ms, source, message) {
            let changes = self.alarms.cause_gone(id);
            self.alarm_changes(changes);
        }
    }

    /// The run's standing alarms.
    pub fn alarms(&self) -> &Alarms {
        &self.alarms
    }
}

#[cfg(test)]
mod tests;
