//! The messages Baton's processes exchange over Zenoh, and their encoding (JSON, one message per sample).
//!
//! Only these types are serialized: engine and runtime state convert to them by explicit code, so a refactor
//! cannot silently change the protocol. Every message carries the protocol version; a decoder refuses other
//! versions, oversized payloads and malformed JSON with an error, never a panic.
//!
//! The only serialized runtime types (`ToAgent`, `Report`, `VarUpdate`, `DeviceReport`, `AgentInfo`,
//! `ChartSource`, `SetRequest`/`SetReply`, `StatusReport`), JSON with a protocol version, size-limited decoding.
//! `Peers` is the coordinator's word on whose variable updates an agent may take: the coordinator's own process and
//! each writer agent's current process (sent with `Dispatch` and `Join`, and as `ToAgent::Peers` when it changes). A
//! `DeviceReport` is an agent's whole list of bound devices it cannot reach, numbered per process, sent when it changes
//! and on every `Join` (a restarted coordinator hears it again); the coordinator turns each change into a
//! `device_down`/`device_up` trace record.

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use uuid::Uuid;

use crate::exec::program::{Program, VarId};
use crate::limits::MESSAGE_BYTES_MAX;
use crate::types::Value;

/// 3: dispatches and joins carry the values of the variables the agent writes (a new process takes them) and the
/// writers it may hear variables from (`Peer`); `ToAgent::Peers` tells agents when those change. 4: operators'
/// commands (`CtlRequest`): tokens are held and released (`ToAgent::Hold`, confirmed by `AgentEventKind::Held` and
/// `Released`) and a run is aborted (`ToAgent::Abort`). 5: each agent's reports on a key of its own
/// (`keys::report`), which must name the agent the report says it is from, as variable updates and device reports
/// name theirs; `CtlRequest::to` (`move`). 6: `set` and `ctl` on keys that name their sender (`keys::set`,
/// `keys::ctl`), whose name the coordinator records as who asked; an agent's roles as liveliness tokens of their
/// own (`keys::alive_role`).
pub const PROTOCOL_VERSION: u32 = 7;

/// One run of a chart by one coordinator.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct RunId(pub Uuid);

impl RunId {
    /// As it appears in key expressions: 32 lowercase hex digits.
    pub fn key(&self) -> String {
        self.0.simple().to_string()
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct TokenId(pub Uuid);

impl std::fmt::Display for TokenId {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        std::fmt::Display::fmt(&self.0, f)
    }
}

/// The chart version: a hash of the chart's source text and POU name.
#[derive(Clone, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct ChartHash(pub String);

impl ChartHash {
    /// FNV-1a, 64 bits: enough to tell chart versions apart (this is a version stamp, not a signature).
    pub fn of(source: &str, pou: &str) -> ChartHash {
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for b in source.bytes().chain([0]).chain(pou.bytes()) {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
        ChartHash(format!("{h:016x}"))
    }
}

/// A variable's value on the wire: `{"var": 3, "value": {"bool": true}}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VarValue {
    pub var: u32,
    pub value: WireValue,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WireValue {
    Bool(bool),
    Int(i64),
    Real(f64),
    TimeMs(i64),
    Str(String),
}

impl From<Value> for WireValue {
    fn from(v: Value) -> WireValue {
        match v {
            Value::Bool(b) => WireValue::Bool(b),
            Value::Int(i) => WireValue::Int(i),
            Value::Real(r) => WireValue::Real(r),
            Value::Time(t) => WireValue::TimeMs(t),
            Value::Str(s) => WireValue::Str(s.to_string()),
        }
    }
}

impl From<WireValue> for Value {
    fn from(v: WireValue) -> Value {
        match v {
            WireValue::Bool(b) => Value::Bool(b),
            WireValue::Int(i) => Value::Int(i),
            WireValue::Real(r) => Value::Real(r),
            WireValue::TimeMs(t) => Value::Time(t),
            WireValue::Str(s) => Value::string(s),
        }
    }
}

impl VarValue {
    pub fn new(var: VarId, value: Value) -> VarValue {
        VarValue { var: var.0, value: value.into() }
    }

    /// The variable and value, if the variable exists and the value fits its type.
    pub fn resolve(&self, program: &Program) -> Option<(VarId, Value)> {
        let info = program.vars.get(self.var as usize)?;
        let value = Value::from(self.value.clone());
        info.ty.fits(&value).then_some((VarId(self.var), value))
    }
}

/// Coordinator → agent, on the agent's command key.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ToAgent {
    /// Run `segment` from step `entry`. `vars` holds the current value of every variable the agent reads or
    /// writes, as of the coordinator's variable update number `vars_seq`: a process that has not taken part in
    /// the run yet (a restarted one) takes even those it writes itself, which it would otherwise start from their
    /// initial values. `peers` are the processes whose variable updates it may take.
    Dispatch {
        run: RunId,
        chart: ChartHash,
        token: TokenId,
        epoch: u32,
        segment: u32,
        entry: u32,
        vars: Vec<VarValue>,
        vars_seq: u64,
        /// Acknowledgements owed to this agent, carried along rather than sent apart.
        acks: Vec<AckEntry>,
        /// The token may be taken away if the agent is lost (`--on-agent-loss reassign`): an agent that loses
        /// its router for a quarter of its lease cancels this token's skills (`limits::fence_after_ms`).
        fence: bool,
        peers: Peers,
        /// The token arrives held (`Hold`): its entry step becomes active only when it is released.
        #[serde(default)]
        held: bool,
        /// The run's mode (`Gate`): how the segment's transitions clear.
        #[serde(default)]
        mode: crate::exec::engine::Mode,
    },
    /// The run's mode, and a transition of this token an operator confirmed (step mode) or forced (manual mode).
    /// Numbered per token; the agent says `Gated` with the number, and the coordinator sends it again until then.
    Gate { run: RunId, token: TokenId, epoch: u32, mode: crate::exec::engine::Mode, permit: Option<u32>, seq: u64 },
    /// Hold this token (`held`), or release it: a held token's transitions do not clear, no skill of it starts,
    /// its step times stand still; its running skills finish (or are cancelled where the action says
    /// `{hold := 'cancel'}`). The agent confirms with `AgentEventKind::Held` once nothing of the token runs, and
    /// with `Released` when it goes on. Sent again until confirmed; a repeat changes nothing.
    Hold { run: RunId, token: TokenId, epoch: u32, held: bool },
    /// The run is aborted: cancel every skill of it, give its actions their final scan, forget its tokens.
    Abort { run: RunId },
    /// An operator acknowledged the supervision fault of `step` (of this token): its transitions may clear again.
    /// Sent again until the agent says `OverrunAcknowledged`.
    AckOverrun { run: RunId, token: TokenId, epoch: u32, step: u32 },
    /// This token's epoch is over (its segment was taken back): stop running it and forget it.
    Drop { run: RunId, token: TokenId, epoch: u32 },
    /// Reports applied since the last acknowledgement to this agent (at most `ACK_DELAY_MS` old, unless a
    /// dispatch carried them sooner).
    Ack { run: RunId, acks: Vec<AckEntry> },
    /// The coordinator of `run` started again from its journal: send every report it has not acknowledged
    /// now, rather than at the next resend.
    Sync { run: RunId },
    /// Take part in `run` before any token comes: the agent connects variables bound to devices on it
    /// (`cluster::bindings`), whose inputs the chart may wait for from its first cycle. `vars`, `vars_seq` and `peers` as
    /// in a dispatch.
    Join { run: RunId, chart: ChartHash, vars: Vec<VarValue>, vars_seq: u64, peers: Peers },
    /// The processes an agent may take variable updates from changed (one restarted, came or went).
    Peers { run: RunId, peers: Peers },
}

impl ToAgent {
    /// The run the message belongs to.
    pub fn run(&self) -> RunId {
        match self {
            ToAgent::Dispatch { run, .. }
            | ToAgent::Gate { run, .. }
            | ToAgent::Hold { run, .. }
            | ToAgent::Abort { run }
            | ToAgent::AckOverrun { run, .. }
            | ToAgent::Drop { run, .. }
            | ToAgent::Ack { run, .. }
            | ToAgent::Sync { run }
            | ToAgent::Join { run, .. }
            | ToAgent::Peers { run, .. } => *run,
        }
    }
}

/// Who may publish the variables an agent reads: the coordinator's process, and each agent that writes some of
/// them, with its current process and its roles. An agent takes a variable update only from the variable's one
/// writer (its agent, or an agent of its role), and only from the process named here — so a made-up writer, or a
/// made-up process of a real one, changes nothing.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Peers {
    /// Numbered by the coordinator: an older table never replaces a newer one.
    pub seq: u64,
    /// The coordinator's process, which numbers its variable updates (`VarUpdate::incarnation`).
    pub coordinator: Uuid,
    pub agents: Vec<Peer>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Peer {
    pub name: String,
    pub incarnation: Uuid,
    pub roles: Vec<String>,
}

/// Every report of this token up to `seq` is applied; with `done`, the token is finished and may be forgotten.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AckEntry {
    pub token: TokenId,
    pub epoch: u32,
    pub seq: u32,
    pub done: bool,
}

/// What happened on an agent while it held a token, `dt_ms` after the token arrived there.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AgentEvent {
    pub dt_ms: u64,
    pub kind: AgentEventKind,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AgentEventKind {
    Fire {
        transition: u32,
    },
    ActionOn {
        action: u32,
    },
    ActionOff {
        action: u32,
    },
    Fault {
        message: String,
    },
    SkillDone {
        action: u32,
    },
    SkillFault {
        action: u32,
        message: String,
    },
    /// The token is held and nothing of it runs any more (its skills finished or were cancelled).
    Held,
    /// A step of the token was active longer than its `max_ms` (`S.overrun`), and why its transitions had not
    /// cleared at that moment (`StepWhy::summary`, S7-GRAPH's CRIT_FLT).
    Overrun {
        step: u32,
        #[serde(default)]
        why: String,
    },
    /// The step's supervision fault was acknowledged here (`ToAgent::AckOverrun`).
    OverrunAcknowledged {
        step: u32,
    },
    /// `ToAgent::Gate` number `seq` applied.
    Gated {
        seq: u64,
    },
    /// A transition of the token is TRUE and waits for a confirmation (step mode), or no longer does.
    Waiting {
        transition: u32,
        waiting: bool,
    },
    /// The token was released: its transitions may clear again.
    Released,
}

/// Agent → coordinator, on the run's report key: the events of one token, numbered per token from 0.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Report {
    pub run: RunId,
    pub agent: String,
    /// The agent's process (`AgentInfo::incarnation`): an answer goes to it alone.
    pub incarnation: Uuid,
    pub token: TokenId,
    pub epoch: u32,
    pub seq: u32,
    pub events: Vec<AgentEvent>,
    /// Variables the agent writes that changed, as of its variable update number `vars_seq`.
    pub vars: Vec<VarValue>,
    pub vars_seq: u64,
    /// The token left the agent: no step of its segment is active there any more.
    pub done: bool,
}

/// Agent → coordinator, on the run's device key: the agent's bound devices it cannot reach, all of them (a report
/// replaces the one before), sent when that changes and again when the coordinator asks (`ToAgent::Join`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DeviceReport {
    pub run: RunId,
    pub agent: String,
    pub incarnation: Uuid,
    /// Numbered per process from 1: a late report never undoes a newer one.
    pub seq: u64,
    pub down: Vec<DeviceDown>,
}

/// A message an agent sent the coordinator, decoded.
#[derive(Clone, Debug, PartialEq)]
pub enum FromAgent {
    Report(Report),
    Vars(VarUpdate),
    Devices(DeviceReport),
}

impl FromAgent {
    /// What it is, for an operator's words.
    pub fn what(&self) -> &'static str {
        match self {
            FromAgent::Report(_) => "report",
            FromAgent::Vars(_) => "variable update",
            FromAgent::Devices(_) => "device report",
        }
    }

    /// Its bytes on the wire.
    pub fn encode(&self) -> Vec<u8> {
        match self {
            FromAgent::Report(r) => encode(r),
            FromAgent::Vars(u) => encode(u),
            FromAgent::Devices(d) => encode(d),
        }
    }

    /// The agent it says it is from.
    pub fn claimed(&self) -> &str {
        match self {
            FromAgent::Report(r) => &r.agent,
            FromAgent::Vars(u) => &u.from,
            FromAgent::Devices(d) => &d.agent,
        }
    }
}

/// A binding (`Layout::io` index) whose device the agent cannot reach, and why.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DeviceDown {
    pub binding: u32,
    pub message: String,
}

/// Published by whoever writes variables (the coordinator or an agent), on the run's variable keys.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VarUpdate {
    pub run: RunId,
    pub from: String,
    /// The process of `from` that numbered the update (`AgentInfo::incarnation`; nil for the coordinator, whose
    /// numbers survive its restarts): a restarted writer numbers from 1 again.
    pub incarnation: Uuid,
    pub seq: u64,
    pub vars: Vec<VarValue>,
}

/// About the bytes values take in memory, to bound what a peer can make a process hold.
fn values_weight(vars: &[VarValue]) -> usize {
    let value = |v: &WireValue| match v {
        WireValue::Str(s) => s.len(),
        _ => 8,
    };
    vars.iter().map(|vv| 16 + value(&vv.value)).sum()
}

impl VarUpdate {
    /// About the bytes it takes, to bound what is held of them.
    pub fn weight(&self) -> usize {
        64 + self.from.len() + values_weight(&self.vars)
    }
}

impl Report {
    /// About the bytes it takes, to bound what is held of them.
    pub fn weight(&self) -> usize {
        let event = |e: &AgentEvent| {
            32 + match &e.kind {
                AgentEventKind::SkillFault { message, .. } | AgentEventKind::Fault { message } => message.len(),
                _ => 0,
            }
        };
        96 + self.agent.len() + self.events.iter().map(event).sum::<usize>() + values_weight(&self.vars)
    }
}

/// An agent's answer to the info query.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AgentInfo {
    pub name: String,
    pub roles: Vec<String>,
    pub lease_ms: u64,
    /// Random per process start: tells a restarted agent (which lost its tokens) from one that was cut off.
    pub incarnation: Uuid,
    /// The tokens it holds (running, or finished with reports not yet acknowledged), so that a coordinator
    /// that started again from its journal can tell a token still out from a dispatch that never arrived.
    #[serde(default)]
    pub held: Vec<HeldToken>,
    /// Reports it sent that no acknowledgement answered yet, oldest first (at most `limits::PENDING_LISTED_MAX`):
    /// a coordinator that asks because a token has been quiet (`CoordOutput::Ask`) takes them from the answer,
    /// for when the reports themselves do not reach it (a router that lost its routes, as zenoh 1.10's do after a
    /// router restart).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub pending: Vec<Report>,
    /// The skills it has, by name (`cluster::skills`): the coordinator sends it no segment that runs another. Absent:
    /// it did not say, and is sent anything its placement allows.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub skills: Option<Vec<String>>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Serialize, Deserialize)]
pub struct HeldToken {
    pub run: RunId,
    pub token: TokenId,
    pub epoch: u32,
}

/// The coordinator's answer to the chart query: what an agent needs to run segments of this run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChartSource {
    pub hash: ChartHash,
    pub pou: String,
    pub source: String,
    /// The run's cycle period: agents cycle with it, so that the chart computes what it computes on one machine.
    pub cycle_ms: u64,
}

/// `baton set`: a request to set one input of a running chart.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SetRequest {
    pub name: String,
    pub value: serde_json::Value,
    /// Who set it, as the coordinator records it: the name the request's key gives (`keys::sender_of_request`).
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub by: String,
    /// The person a console sends it for (the user logged in to `baton console`): recorded with the sender, as
    /// `anna via console` (`keys::by_whom`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub user: Option<String>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SetReply {
    pub chart: String,
    pub ok: bool,
    pub message: String,
}

/// `baton ctl`: an operator's command to a run. `command` is a PackML command (`hold`, `unhold`, `suspend`,
/// `unsuspend`, `stop`, `abort`, `clear`, `reset`, `start`), `mode`, `confirm`, `force`, `activate`,
/// `deactivate`, `move`, `ack` or `shelve`; `target` its object (the mode, a transition, a step, an alarm id or
/// `all`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CtlRequest {
    pub command: String,
    #[serde(default)]
    pub target: Option<String>,
    /// `hold --agent NAME`: only the branches on that agent.
    #[serde(default)]
    pub agent: Option<String>,
    /// `hold --step S`: only the branch that holds step S.
    #[serde(default)]
    pub step: Option<String>,
    /// `shelve --for`: how long, in ms.
    #[serde(default)]
    pub for_ms: Option<u64>,
    /// `move FROM TO`: the step the token goes to (`target` is the step it leaves).
    #[serde(default)]
    pub to: Option<String>,
    /// Why, in the operator's words (`--reason`, or an acknowledgement's comment).
    #[serde(default)]
    pub reason: String,
    /// Who sent it, as the coordinator records it: the name the request's key gives (`keys::sender_of_request`),
    /// which a router's access control checks; what a client writes here is replaced by it.
    #[serde(default)]
    pub by: String,
    /// The person a console sends it for, as `SetRequest::user`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub user: Option<String>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CtlReply {
    pub chart: String,
    pub ok: bool,
    pub message: String,
    /// The run's state after the command, and the commands legal in it.
    pub state: crate::cluster::runtime::packml::State,
    pub available: Vec<crate::cluster::runtime::packml::Command>,
}

/// `baton status`: a running chart's situation.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StatusReport {
    pub run: RunId,
    pub chart: String,
    pub hash: ChartHash,
    /// The coordinator's clock now; the run began at `started_ms` on it (later than 0 for a run a `reset` made).
    pub t_ms: u64,
    #[serde(default)]
    pub started_ms: u64,
    /// The wall clock (Unix ms) when the coordinator read `t_ms`: a record at `t_ms = T` happened at about
    /// `unix_ms - (t_ms - T)`. 0 from a coordinator before it.
    #[serde(default)]
    pub unix_ms: u64,
    pub active_steps: Vec<StatusStep>,
    pub tokens: Vec<StatusToken>,
    pub agents: Vec<StatusAgent>,
    /// The run's PackML state, and the commands legal in it (OPC UA's AvailableTransitions). A coordinator
    /// from before run states answers without them: it was executing.
    #[serde(default = "executing")]
    pub state: crate::cluster::runtime::packml::State,
    #[serde(default)]
    pub available: Vec<crate::cluster::runtime::packml::Command>,
    /// The active list: alarms not yet back to normal and not shelved, oldest first.
    #[serde(default)]
    pub alarms: Vec<StatusAlarm>,
    /// Alarms an operator shelved, oldest first: out of the active list until their time runs out.
    #[serde(default)]
    pub shelved: Vec<StatusAlarm>,
    /// Parts of the run held while the rest goes on (`agent robot1`, `step Pick`).
    #[serde(default)]
    pub held: Vec<String>,
    /// The run's mode (`auto`, `step`, `manual`), and in step mode the transitions waiting for `confirm`.
    #[serde(default)]
    pub mode: crate::exec::engine::Mode,
    #[serde(default)]
    pub waiting: Vec<String>,
    /// Why the coordinator's own active steps wait (`baton status --why` adds the agents' from them).
    #[serde(default)]
    pub why: Vec<StepWhy>,
    /// Messages the coordinator refused so far (corrupt, of an unknown sender, stale), as the summary counts
    /// them at the end: a number that climbs says a peer is misbehaving.
    #[serde(default)]
    pub messages_dropped: u64,
    /// The chart's variables as the coordinator holds them now (constants and hidden ones left out), in the
    /// chart's order: what the console shows live beside the chart.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub values: Vec<StatusValue>,
    /// Where a viewer reads the run's Rerun recording live (`rerun+http://ADDR/proxy`), when it is served.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rerun: Option<String>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StatusValue {
    pub name: String,
    /// As IEC 61131-3 writes it (`TRUE`, `42`, `'text'`, `T#1s500ms`).
    pub value: String,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StatusAlarm {
    pub id: u64,
    pub source: String,
    pub message: String,
    pub state: crate::cluster::runtime::alarms::AlarmState,
    pub raised_ms: u64,
    /// Shelved: until when, by whom and why.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shelved_until_ms: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shelf: Option<crate::cluster::runtime::alarms::Shelf>,
}

fn executing() -> crate::cluster::runtime::packml::State {
    crate::cluster::runtime::packml::State::Execute
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StatusStep {
    pub name: String,
    pub placement: String,
    pub agent: Option<String>,
    /// The step's time (`S.T`) as the coordinator's engine counts it, in ms.
    #[serde(default)]
    pub active_ms: u64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StatusToken {
    pub token: TokenId,
    pub epoch: u32,
    /// The step its segment was entered at (where it was dispatched).
    pub entry: String,
    /// Where it is now: the active steps of its segment, as its agent reported them.
    #[serde(default)]
    pub at: Vec<String>,
    pub agent: Option<String>,
    pub since_ms: u64,
    /// Held while its agent is lost (or several processes answer to its name).
    #[serde(default)]
    pub paused: bool,
    /// Held by an operator (`baton ctl hold`), and whether its agent confirmed that nothing of it runs.
    #[serde(default)]
    pub held: bool,
    #[serde(default)]
    pub held_confirmed: bool,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StatusAgent {
    pub name: String,
    pub roles: Vec<String>,
    pub tokens: usize,
    /// Its bound devices it cannot reach.
    #[serde(default)]
    pub devices_down: Vec<StatusDevice>,
    /// The skills it announced (absent: it did not say), as `baton check --skills` reads them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub skills: Option<Vec<String>>,
}

/// A bound variable whose device its agent cannot reach: the variable keeps its last value.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StatusDevice {
    pub var: String,
    pub device: String,
    pub message: String,
}

pub use crate::exec::why::{SkillWhy, StepWhy, TransitionWhy};

/// An agent's answer to the why query (`keys::agent_why`): its active steps of each run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WhyReport {
    pub run: RunId,
    pub agent: String,
    pub steps: Vec<StepWhy>,
}

/// `{"v": 7, "t": TERM, "m": MESSAGE}`. Enums are externally tagged (`{"dispatch": {…}}`) and nothing is
/// flattened, so decoding never buffers a message to look for its tag. `t` is the coordinator's term (`encode_termed`),
/// left out where it is 0: a coordinator that stands in no election, and every message not a coordinator's.
#[derive(Serialize)]
struct EnvelopeOut<'a, T> {
    v: u32,
    #[serde(skip_serializing_if = "is_zero")]
    t: u64,
    m: &'a T,
}

fn is_zero(t: &u64) -> bool {
    *t == 0
}

#[derive(Deserialize)]
struct EnvelopeIn<T> {
    v: u32,
    #[serde(default)]
    t: u64,
    m: T,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum WireError {
    #[error("message of {0} bytes is larger than the limit of {1}")]
    TooLarge(usize, usize),
    #[error("malformed message: {0}")]
    Malformed(String),
    #[error("protocol version {0}, this build speaks {PROTOCOL_VERSION}")]
    Version(u32),
}

/// Room a message is encoded into at first: a dispatch or a report of one token takes 300–500 bytes, which
/// `serde_json::to_vec`'s 128 reached by growing twice, a copy each time.
const ENCODE_CAPACITY: usize = 512;

pub fn encode<T: Serialize>(msg: &T) -> Vec<u8> {
    encode_termed(msg, 0)
}

/// A coordinator's message, stamped with its term: the revision at which it won the run's election (0 when it
/// stands in none). An agent takes no command, and no variable update of the coordinator's, of a lower term than
/// the highest it has seen of the run — a deposed coordinator that has not noticed yet is refused.
pub fn encode_termed<T: Serialize>(msg: &T, term: u64) -> Vec<u8> {
    let mut out = Vec::with_capacity(ENCODE_CAPACITY);
    // Serializing these plain structs cannot fail: no maps with non-string keys, no foreign Serialize impls.
    serde_json::to_writer(&mut out, &EnvelopeOut { v: PROTOCOL_VERSION, t: term, m: msg })
        .expect("wire types serialize");
    out
}

pub fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, WireError> {
    decode_with_limit(bytes, MESSAGE_BYTES_MAX)
}

/// A message and the term it was stamped with (0 if none).
pub fn decode_termed<T: DeserializeOwned>(bytes: &[u8]) -> Result<(u64, T), WireError> {
    decode_envelope(bytes, MESSAGE_BYTES_MAX)
}

/// `decode` with another size limit, for the few replies that may be larger (a chart's source).
pub fn decode_with_limit<T: DeserializeOwned>(bytes: &[u8], limit: usize) -> Result<T, WireError> {
    decode_envelope(bytes, limit).map(|(_, m)| m)
}

fn decode_envelope<T: DeserializeOwned>(bytes: &[u8], limit: usize) -> Result<(u64, T), WireError> {
    if bytes.len() > limit {
        return Err(WireError::TooLarge(bytes.len(), limit));
    }
    match serde_json::from_slice::<EnvelopeIn<T>>(bytes) {
        Ok(env) if env.v == PROTOCOL_VERSION => Ok((env.t, env.m)),
        Ok(env) => Err(WireError::Version(env.v)),
        Err(e) => {
            // A message of another version may not fit this version's types: say which it was.
            #[derive(Deserialize)]
            struct Version {
                v: u32,
            }
            match serde_json::from_slice::<Version>(bytes) {
                Ok(Version { v }) if v != PROTOCOL_VERSION => Err(WireError::Version(v)),
                _ => Err(WireError::Malformed(e.to_string())),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_round_trip_and_carry_the_version() {
        let entry = AckEntry { token: TokenId(Uuid::from_u128(9)), epoch: 2, seq: 3, done: true };
        let msg = ToAgent::Ack { run: RunId(Uuid::from_u128(7)), acks: vec![entry] };
        let bytes = encode(&msg);
        assert!(std::str::from_utf8(&bytes).unwrap().contains(&format!("\"v\":{PROTOCOL_VERSION}")));
        assert_eq!(decode::<ToAgent>(&bytes), Ok(msg));
        let report = Report {
            run: RunId(Uuid::from_u128(1)),
            agent: "r1".into(),
            incarnation: Uuid::from_u128(3),
            token: TokenId(Uuid::from_u128(2)),
            epoch: 1,
            seq: 0,
            events: vec![AgentEvent { dt_ms: 5, kind: AgentEventKind::Fire { transition: 3 } }],
            vars: vec![VarValue { var: 1, value: WireValue::Bool(true) }],
            vars_seq: 4,
            done: true,
        };
        assert_eq!(decode::<Report>(&encode(&report)), Ok(report));
    }

    #[test]
    fn a_coordinators_term_rides_with_its_message_and_is_0_where_none_was_given() {
        let msg = ToAgent::Sync { run: RunId(Uuid::from_u128(7)) };
        assert_eq!(decode_termed::<ToAgent>(&encode_termed(&msg, 41)), Ok((41, msg.clone())));
        assert!(std::str::from_utf8(&encode_termed(&msg, 41)).unwrap().contains("\"t\":41"));
        // Untermed, the field is not written, and a message without it is of term 0.
        let plain = encode(&msg);
        assert!(!std::str::from_utf8(&plain).unwrap().contains("\"t\""));
        assert_eq!(decode_termed::<ToAgent>(&plain), Ok((0, msg.clone())));
        // `decode` takes a termed message as its message.
        assert_eq!(decode::<ToAgent>(&encode_termed(&msg, 3)), Ok(msg));
    }

    #[test]
    fn bad_bytes_are_errors() {
        assert!(matches!(decode::<ToAgent>(b"\xff\x00garbage"), Err(WireError::Malformed(_))));
        let unknown = format!(r#"{{"v":{PROTOCOL_VERSION},"m":{{"launch_missiles":{{}}}}}}"#);
        assert!(matches!(decode::<ToAgent>(unknown.as_bytes()), Err(WireError::Malformed(_))));
        assert_eq!(decode::<ToAgent>(br#"{"v":99,"m":{"ack":{}}}"#), Err(WireError::Version(99)));
        let big = vec![b' '; MESSAGE_BYTES_MAX + 1];
        assert_eq!(decode::<ToAgent>(&big), Err(WireError::TooLarge(MESSAGE_BYTES_MAX + 1, MESSAGE_BYTES_MAX)));
    }

    #[test]
    fn chart_hashes_tell_versions_apart() {
        assert_eq!(ChartHash::of("a", "P"), ChartHash::of("a", "P"));
        assert_ne!(ChartHash::of("a", "P"), ChartHash::of("b", "P"));
        assert_ne!(ChartHash::of("a", "P"), ChartHash::of("a", "Q"));
    }
}
