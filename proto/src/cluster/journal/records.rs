//! The journal's records: what each is, its bytes (`encode`, `decode`), the header and pin of a run, and `apply`,
//! the one place a record becomes an input of the `Coordinator`.

use serde::{Deserialize, Serialize};
use uuid::Uuid;

use crate::cluster::layout::Layout;
use crate::cluster::runtime::coordinator::{token_ids, Coordinator, LossPolicy};
use crate::cluster::wire::{
    self, AgentInfo, ChartHash, CtlRequest, DeviceReport, FromAgent, Report, RunId, SetRequest, VarUpdate, WireError,
};
use crate::exec::program::{Program, TransitionId};

/// Bumped when records change meaning; a journal of another format is refused. 2: cycles that changed nothing
/// are not recorded, and the header holds the cycle period. 3: the header pins the compiled program
/// (`program_pin`), and refused messages are not recorded.
pub const JOURNAL_FORMAT: u32 = 3;

/// What a journal is about, written once when the run starts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JournalHeader {
    pub format: u32,
    pub run: RunId,
    /// The chart version: a journal is only ever resumed with the same chart.
    pub chart: ChartHash,
    pub pou: String,
    /// The chart's source, so that a journal can be replayed without the file.
    pub source: String,
    /// Wall-clock time of the run's time 0, in ms since the Unix epoch: a coordinator that starts again counts
    /// the time it was down.
    pub started_unix_ms: u64,
    /// The run's cycle period, which a resumed run keeps.
    pub cycle_ms: u64,
    /// What the records' numbers mean: `program_pin` of the program the run was compiled to. The chart's hash
    /// pins its text; this pins the compiler's numbering of its variables, steps, transitions, actions, segments
    /// and bindings, which another build of Baton may do otherwise.
    pub program: String,
}

/// A stamp of what a compiled program's ids mean: every variable's name and type, every step, transition (its
/// sources, targets and clearing order) and action by index, the layout's segments, writers and bindings. Two
/// compilations that number anything differently get different pins. FNV-1a, 64 bits, over a canonical text.
pub fn program_pin(program: &Program, layout: &Layout) -> String {
    use std::fmt::Write;
    let mut text = String::new();
    for (i, v) in program.vars.iter().enumerate() {
        let _ = writeln!(text, "v{i} {} {} {}", v.name, v.ty, layout.writer[i]);
    }
    for (i, s) in program.steps.iter().enumerate() {
        let _ = writeln!(text, "s{i} {} {}", s.name, layout.placement[i]);
    }
    for (i, t) in program.transitions.iter().enumerate() {
        let id = TransitionId(i as u32);
        let _ =
            writeln!(text, "t{i} {} {:?} {:?} {}", t.name, program.sources(id), program.targets(id), program.rank(id));
    }
    for (i, a) in program.actions.iter().enumerate() {
        let _ = writeln!(text, "a{i} {} {}", a.name, layout.action_placement[i]);
    }
    for (i, g) in layout.segments.iter().enumerate() {
        let _ = writeln!(text, "g{i} {} {:?}", g.placement, g.steps);
    }
    for (i, b) in layout.io.iter().enumerate() {
        let _ = writeln!(text, "io{i} {} {} {:?}", b.var.0, b.agent, b.dir);
    }
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in text.bytes() {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    format!("{h:016x}")
}

/// One input of the coordinator.
#[derive(Clone, Debug, PartialEq)]
pub enum Record {
    Cycle,
    Report(Report),
    Vars(VarUpdate),
    AgentUp(AgentInfo),
    AgentDown(String),
    /// Several processes answered to this agent name (how many).
    AgentConflict(String, u32),
    Set(SetRequest),
    /// An operator's command (`baton ctl`), accepted or refused: both are in the trace, which a replay rebuilds.
    Command(CtlRequest),
    /// An agent said which of its bound devices it cannot reach.
    Devices(DeviceReport),
    Policy(LossPolicy),
    /// A coordinator process took over from the journal here.
    Recover,
    /// The run waits in Idle for `start` (`baton run --wait-start`).
    WaitStart,
    /// The run stays at its end for `clear` and `reset` (`baton run --stay`).
    Stay,
    /// After a `reset`, the chart starts again from its initial steps as this new run (`Coordinator::new_run`);
    /// what follows is that run's.
    NewRun(RunId),
    /// The run is over (`failure` says why it failed, if it did). Nothing follows.
    End {
        failure: Option<String>,
    },
}

impl From<FromAgent> for Record {
    fn from(msg: FromAgent) -> Record {
        match msg {
            FromAgent::Report(r) => Record::Report(r),
            FromAgent::Vars(u) => Record::Vars(u),
            FromAgent::Devices(d) => Record::Devices(d),
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct Entry {
    pub t_ms: u64,
    pub record: Record,
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum JournalError {
    #[error("journal record is truncated ({0} bytes)")]
    Truncated(usize),
    #[error("journal record has unknown tag {0}")]
    UnknownTag(u8),
    #[error("journal record of tag {tag} is malformed: {why}")]
    Malformed { tag: u8, why: String },
}

pub(super) const CYCLE: u8 = 1;
pub(super) const REPORT: u8 = 2;
pub(super) const VARS: u8 = 3;
pub(super) const AGENT_UP: u8 = 4;
pub(super) const AGENT_DOWN: u8 = 5;
pub(super) const SET: u8 = 6;
pub(super) const POLICY: u8 = 7;
pub(super) const RECOVER: u8 = 8;
pub(super) const END: u8 = 9;
pub(super) const AGENT_CONFLICT: u8 = 10;
pub(super) const DEVICES: u8 = 11;
pub(super) const COMMAND: u8 = 12;
pub(super) const WAIT_START: u8 = 13;
pub(super) const STAY: u8 = 14;
pub(super) const NEW_RUN: u8 = 15;

const HEAD: usize = 9;

pub(super) fn frame(tag: u8, t_ms: u64, body: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEAD + body.len());
    out.push(tag);
    out.extend_from_slice(&t_ms.to_le_bytes());
    out.extend_from_slice(body);
    out
}

fn policy_byte(p: LossPolicy) -> u8 {
    match p {
        LossPolicy::Pause => 0,
        LossPolicy::Reassign => 1,
        LossPolicy::Fail => 2,
    }
}

/// Encodes an entry (the host's path for reports and the like is `Journaled`, which reuses the bytes).
pub fn encode(entry: &Entry) -> Vec<u8> {
    let t = entry.t_ms;
    match &entry.record {
        Record::Cycle => frame(CYCLE, t, &[]),
        Record::Report(r) => frame(REPORT, t, &wire::encode(r)),
        Record::Vars(u) => frame(VARS, t, &wire::encode(u)),
        Record::AgentUp(i) => frame(AGENT_UP, t, &wire::encode(i)),
        Record::AgentDown(name) => frame(AGENT_DOWN, t, name.as_bytes()),
        Record::AgentConflict(name, n) => {
            let mut body = n.to_le_bytes().to_vec();
            body.extend_from_slice(name.as_bytes());
            frame(AGENT_CONFLICT, t, &body)
        }
        Record::Set(s) => frame(SET, t, &wire::encode(s)),
        Record::Command(c) => frame(COMMAND, t, &wire::encode(c)),
        Record::Devices(d) => frame(DEVICES, t, &wire::encode(d)),
        Record::Policy(p) => frame(POLICY, t, &[policy_byte(*p)]),
        Record::Recover => frame(RECOVER, t, &[]),
        Record::WaitStart => frame(WAIT_START, t, &[]),
        Record::Stay => frame(STAY, t, &[]),
        Record::NewRun(run) => frame(NEW_RUN, t, run.0.as_bytes()),
        Record::End { failure } => frame(END, t, failure.as_deref().unwrap_or("").as_bytes()),
    }
}

pub fn decode(bytes: &[u8]) -> Result<Entry, JournalError> {
    if bytes.len() < HEAD {
        return Err(JournalError::Truncated(bytes.len()));
    }
    let tag = bytes[0];
    let mut t = [0u8; 8];
    t.copy_from_slice(&bytes[1..HEAD]);
    let t_ms = u64::from_le_bytes(t);
    let body = &bytes[HEAD..];
    let bad = |why: String| JournalError::Malformed { tag, why };
    let wire_err = |e: WireError| bad(e.to_string());
    let text = || std::str::from_utf8(body).map(str::to_string).map_err(|e| bad(e.to_string()));
    let record = match tag {
        CYCLE => Record::Cycle,
        REPORT => Record::Report(wire::decode(body).map_err(wire_err)?),
        VARS => Record::Vars(wire::decode(body).map_err(wire_err)?),
        AGENT_UP => Record::AgentUp(wire::decode(body).map_err(wire_err)?),
        AGENT_DOWN => Record::AgentDown(text()?),
        AGENT_CONFLICT => {
            let (n, name) = body.split_at_checked(4).ok_or_else(|| bad("truncated".to_string()))?;
            let n = u32::from_le_bytes(n.try_into().map_err(|_| bad("truncated".to_string()))?);
            let name = std::str::from_utf8(name).map_err(|e| bad(e.to_string()))?.to_string();
            Record::AgentConflict(name, n)
        }
        SET => Record::Set(wire::decode(body).map_err(wire_err)?),
        COMMAND => Record::Command(wire::decode(body).map_err(wire_err)?),
        DEVICES => Record::Devices(wire::decode(body).map_err(wire_err)?),
        POLICY => Record::Policy(match body {
            [0] => LossPolicy::Pause,
            [1] => LossPolicy::Reassign,
            [2] => LossPolicy::Fail,
            _ => return Err(bad("unknown loss policy".to_string())),
        }),
        RECOVER => Record::Recover,
        WAIT_START => Record::WaitStart,
        STAY => Record::Stay,
        NEW_RUN => Record::NewRun(RunId(
            Uuid::from_slice(body).map_err(|_| bad(format!("a run id is 16 bytes, not {}", body.len())))?,
        )),
        END => Record::End { failure: Some(text()?).filter(|s| !s.is_empty()) },
        other => return Err(JournalError::UnknownTag(other)),
    };
    Ok(Entry { t_ms, record })
}

/// Gives an entry to the coordinator: the one place where records become inputs, for a live run and a replay
/// alike. A `Set` answers whether it was taken.
pub fn apply(core: &mut Coordinator, entry: &Entry) -> Option<Result<String, String>> {
    let now = entry.t_ms;
    match &entry.record {
        Record::Cycle => {
            core.handle_cycle(now);
        }
        Record::Report(r) => core.handle_agent_message(now, FromAgent::Report(r.clone())),
        Record::Vars(u) => core.handle_agent_message(now, FromAgent::Vars(u.clone())),
        Record::AgentUp(i) => core.handle_agent_up(now, i.clone()),
        Record::AgentDown(name) => core.handle_agent_down(now, name),
        Record::AgentConflict(name, n) => core.handle_agent_conflict(now, name, *n as usize),
        Record::Set(s) => return Some(core.handle_set_by(now, &s.name, &s.value, &s.by)),
        Record::Command(c) => return Some(core.handle_command(now, c)),
        Record::Devices(d) => core.handle_agent_message(now, FromAgent::Devices(d.clone())),
        Record::Policy(p) => core.set_loss_policy(*p),
        Record::Recover => core.handle_recover(now),
        Record::WaitStart => core.handle_wait_start(),
        Record::Stay => core.handle_stay(),
        Record::NewRun(run) => {
            let next = core.new_run(now, *run, token_ids(*run));
            *core = next;
        }
        Record::End { failure } => core.handle_end(now, failure.as_deref()),
    }
    None
}
