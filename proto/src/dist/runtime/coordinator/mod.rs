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

mod control;
mod devices;
mod membership;
mod reports;
mod timers;
mod tokens;
mod variables;

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
use membership::*;
use tokens::*;

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

    fn alarm(&mut self, message: String) {
        let mut rec = TraceRecord::new(self.now_ms, TraceEvent::Alarm, &self.program.name);
        rec.message = Some(message.clone());
        self.trace(rec);
        self.log(Level::Error, message);
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
