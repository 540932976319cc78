//! The coordinator's journal, as records: every input its state machine takes, with the time it took it, in
//! order. The coordinator is deterministic — the same inputs at the same times give the same situation, the same
//! tokens (their ids come from the run id and a counter) and the same trace — so replaying the records rebuilds
//! the run exactly: activations, dispatches, returns, epochs and the values it owns.
//!
//! `Journaled` wraps a `Coordinator` so that nothing reaches it without a record: the shell takes the records
//! (`take_records`), makes them durable, and only then carries out what the coordinator asked for. Storage is
//! the shell's business (`baton-coordinator` keeps records in an embedded database); this module only encodes,
//! decodes and applies them.
//!
//! A record is `[tag: u8][t_ms: u64, little endian][body]`. Bodies of reports, variable updates and agent
//! announcements are the wire messages as they arrived, so journaling them costs a copy, not an encoding.
//!
//! The coordinator's journal as records — every input of `Coordinator` with its time (`Record`: cycle,
//! report, variable update, device report, agent up/down, set, loss policy, recover, end) — their binary framing,
//! `apply` (the one place records become inputs), `Journaled` (a `Coordinator` whose inputs are all recorded first, and
//! `replay`), the journal header (with `program_pin`, a hash of what the records' variable, step, transition, action
//! and segment numbers mean, so a journal is resumed or replayed only by the compilation that wrote it), and
//! `token_ids` (token ids from the run id and a counter, so that a replay makes the same tokens). Storage is the
//! shell's.

use serde::{Deserialize, Serialize};
use uuid::Uuid;

use crate::dist::layout::Layout;
pub use crate::dist::runtime::coordinator::{token_ids, TokenIds};
use crate::dist::runtime::coordinator::{Coordinator, LossPolicy};
use crate::dist::wire::{
    self, AgentInfo, ChartHash, CtlRequest, DeviceReport, Report, RunId, SetRequest, VarUpdate, WireError,
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

const CYCLE: u8 = 1;
const REPORT: u8 = 2;
const VARS: u8 = 3;
const AGENT_UP: u8 = 4;
const AGENT_DOWN: u8 = 5;
const SET: u8 = 6;
const POLICY: u8 = 7;
const RECOVER: u8 = 8;
const END: u8 = 9;
const AGENT_CONFLICT: u8 = 10;
const DEVICES: u8 = 11;
const COMMAND: u8 = 12;
const WAIT_START: u8 = 13;
const STAY: u8 = 14;
const NEW_RUN: u8 = 15;

const HEAD: usize = 9;

fn frame(tag: u8, t_ms: u64, body: &[u8]) -> Vec<u8> {
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

/// Encodes an entry (the shell's path for reports and the like is `Journaled`, which reuses the bytes).
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
        Record::Report(r) => core.handle_report(now, r.clone()),
        Record::Vars(u) => core.handle_vars(now, u.clone()),
        Record::AgentUp(i) => core.handle_agent_up(now, i.clone()),
        Record::AgentDown(name) => core.handle_agent_down(now, name),
        Record::AgentConflict(name, n) => core.handle_agent_conflict(now, name, *n as usize),
        Record::Set(s) => return Some(core.handle_set(now, &s.name, &s.value)),
        Record::Command(c) => return Some(core.handle_command(now, c)),
        Record::Devices(d) => core.handle_devices(now, d.clone()),
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

/// A coordinator whose every input is recorded first.
pub struct Journaled {
    core: Coordinator,
    records: Vec<Vec<u8>>,
    /// The time of the last cycle that changed nothing, if no record followed it yet.
    quiet_ms: Option<u64>,
    /// Records made (or replayed) since the run's first, trace records taken, and the last record's time: what a
    /// snapshot says of where it stands.
    counted: u64,
    traced: u64,
    last_ms: u64,
}

/// Bumped when the coordinator's state changes shape; a snapshot is also restored only by the Baton version that
/// wrote it (`SnapshotMeta::baton`), since its fields are the coordinator's own.
pub const SNAPSHOT_FORMAT: u32 = 1;

/// Where a journal's snapshot stands in its run, besides the coordinator's state.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SnapshotMeta {
    /// `SNAPSHOT_FORMAT` and the version of Baton that wrote it.
    pub format: u32,
    pub baton: String,
    /// The journal records before it, counted from the run's first: a resume replays those after it.
    pub records: u64,
    /// The trace records the run had made: a resumed run's trace file keeps these and the replay writes the rest.
    pub trace_records: u64,
    /// The time of the last record before it.
    pub last_ms: u64,
    /// The shell's own (`baton run`: the summary's step times), opaque here.
    #[serde(default)]
    pub shell: serde_json::Value,
}

/// A snapshot's bytes: the length of its `SnapshotMeta` (u32, little-endian), the meta as JSON, the coordinator's
/// state (`Coordinator::snapshot`).
fn encode_snapshot(meta: &SnapshotMeta, core: &[u8]) -> Vec<u8> {
    let meta = serde_json::to_vec(meta).expect("a snapshot's meta serializes");
    let mut out = Vec::with_capacity(4 + meta.len() + core.len());
    out.extend_from_slice(&(meta.len() as u32).to_le_bytes());
    out.extend_from_slice(&meta);
    out.extend_from_slice(core);
    out
}

/// What a snapshot says of where it stands, without restoring it.
pub fn snapshot_meta(bytes: &[u8]) -> Result<SnapshotMeta, String> {
    split_snapshot(bytes).map(|(meta, _)| meta)
}

fn split_snapshot(bytes: &[u8]) -> Result<(SnapshotMeta, &[u8]), String> {
    let (len, rest) = bytes.split_at_checked(4).ok_or("is truncated")?;
    let len = u32::from_le_bytes(len.try_into().map_err(|_| "is truncated")?) as usize;
    let (meta, core) = rest.split_at_checked(len).ok_or("is truncated")?;
    let meta = serde_json::from_slice(meta).map_err(|e| format!("has a malformed head: {e}"))?;
    Ok((meta, core))
}

impl Journaled {
    pub fn new(core: Coordinator) -> Journaled {
        Journaled { core, records: Vec::new(), quiet_ms: None, counted: 0, traced: 0, last_ms: 0 }
    }

    /// Run `run` of a chart at its start, on the cycle period `cycle_ms`, its tokens numbered from the run id
    /// (`token_ids`): what a new run, a replay from the start and a resume without a snapshot all begin with.
    pub fn start(
        program: std::sync::Arc<Program>,
        layout: std::sync::Arc<Layout>,
        run: RunId,
        hash: ChartHash,
        cycle_ms: u64,
    ) -> Journaled {
        let mut core = Coordinator::new(program, layout, run, hash, token_ids(run));
        core.set_cycle_ms(cycle_ms);
        Journaled::new(core)
    }

    /// A snapshot of the coordinator after every record made so far, with `shell`'s data; `None` while it has
    /// outputs not yet taken (their trace records would be counted nowhere). A cycle that changed nothing and
    /// was not recorded yet is recorded first, so that the snapshot follows the last record exactly: take the
    /// records after this call, and write them before the snapshot.
    pub fn snapshot(&mut self, shell: serde_json::Value) -> Option<Vec<u8>> {
        if self.core.has_output() {
            return None;
        }
        if let Some(t_ms) = self.quiet_ms.take() {
            self.push(encode(&Entry { t_ms, record: Record::Cycle }), t_ms);
        }
        let meta = SnapshotMeta {
            format: SNAPSHOT_FORMAT,
            baton: env!("CARGO_PKG_VERSION").to_string(),
            records: self.counted,
            trace_records: self.traced,
            last_ms: self.last_ms,
            shell,
        };
        Some(encode_snapshot(&meta, &self.core.snapshot()))
    }

    /// The coordinator a snapshot holds, and where it stands; the records after it are replayed next.
    pub fn restore(
        program: std::sync::Arc<Program>,
        layout: std::sync::Arc<Layout>,
        bytes: &[u8],
    ) -> Result<(Journaled, SnapshotMeta), String> {
        let (meta, core) = split_snapshot(bytes)?;
        if meta.format != SNAPSHOT_FORMAT || meta.baton != env!("CARGO_PKG_VERSION") {
            return Err(format!(
                "was written by Baton {} (snapshot format {}), and this is Baton {} (format {SNAPSHOT_FORMAT}): \
                 resume it with the Baton that wrote it",
                meta.baton,
                meta.format,
                env!("CARGO_PKG_VERSION")
            ));
        }
        let core = Coordinator::restore(program, layout, core).map_err(|e| e.to_string())?;
        let mut j = Journaled::new(core);
        (j.counted, j.traced, j.last_ms) = (meta.records, meta.trace_records, meta.last_ms);
        Ok((j, meta))
    }

    /// Records made or replayed since the run's first.
    pub fn records_counted(&self) -> u64 {
        self.counted
    }

    fn push(&mut self, bytes: Vec<u8>, t_ms: u64) {
        self.records.push(bytes);
        self.counted += 1;
        self.last_ms = self.last_ms.max(t_ms);
    }

    /// The coordinator, to read from; inputs go through the methods below.
    pub fn core(&self) -> &Coordinator {
        &self.core
    }

    /// What the coordinator asks for, once the records taken so far are durable.
    pub fn poll_output(&mut self) -> Option<crate::dist::runtime::coordinator::CoordOutput> {
        let out = self.core.poll_output();
        if let Some(crate::dist::runtime::coordinator::CoordOutput::Trace(_)) = &out {
            self.traced += 1;
        }
        out
    }

    /// The records made since the last call, oldest first.
    pub fn take_records(&mut self) -> Vec<Vec<u8>> {
        std::mem::take(&mut self.records)
    }

    pub fn has_records(&self) -> bool {
        !self.records.is_empty()
    }

    /// Whether the coordinator asked for something not yet taken.
    pub fn has_output(&self) -> bool {
        self.core.has_output()
    }

    fn feed(&mut self, bytes: Vec<u8>, entry: Entry) -> Option<Result<String, String>> {
        // The cycles that changed nothing since the last record moved the clock on: the last of them is recorded
        // before this input, so that a replay reaches it at the same time (on the same situation, it changes
        // nothing there either).
        if let Some(t_ms) = self.quiet_ms.take() {
            self.push(encode(&Entry { t_ms, record: Record::Cycle }), t_ms);
        }
        self.push(bytes, entry.t_ms);
        apply(&mut self.core, &entry)
    }

    fn input(&mut self, t_ms: u64, record: Record) -> Option<Result<String, String>> {
        let entry = Entry { t_ms, record };
        self.feed(encode(&entry), entry)
    }

    /// A cycle is recorded if it changed something. A cycle that changed nothing leaves the coordinator as it
    /// was but for its clock, so of a series of them only the last is recorded, and only when another record
    /// follows: an idle run writes nothing.
    pub fn cycle(&mut self, now_ms: u64) {
        if self.core.handle_cycle(now_ms) {
            self.quiet_ms = None;
            self.push(encode(&Entry { t_ms: now_ms, record: Record::Cycle }), now_ms);
        } else {
            self.quiet_ms = Some(now_ms);
        }
    }

    /// A message as it arrived on the wire, recorded first if the coordinator takes it (`record`: the bytes to
    /// record), then applied. One it refuses (of another run or another process, stale, a duplicate, a value it
    /// does not take) changes nothing a replay needs: it is applied (counted, logged, answered) but not recorded,
    /// so that what a peer sends costs no disk unless the coordinator acts on it.
    fn arrived(&mut self, now_ms: u64, record: Option<Vec<u8>>, applied: Record) {
        let entry = Entry { t_ms: now_ms, record: applied };
        match record {
            Some(bytes) => {
                self.feed(bytes, entry);
            }
            None => {
                apply(&mut self.core, &entry);
            }
        }
    }

    /// A report as it arrived from `sender` (the agent its key names): one that claims another agent is dropped.
    pub fn report(&mut self, now_ms: u64, sender: &str, bytes: &[u8]) -> Result<(), WireError> {
        let report: Report = wire::decode(bytes)?;
        if report.agent != sender {
            self.core.refuse_misaddressed(now_ms, "report", sender, &report.agent);
            return Ok(());
        }
        let record = self.core.admit_report(&report).then(|| frame(REPORT, now_ms, bytes));
        self.arrived(now_ms, record, Record::Report(report));
        Ok(())
    }

    /// A variable update: only its values that apply are recorded (the bytes as they came when all do).
    pub fn vars(&mut self, now_ms: u64, sender: &str, bytes: &[u8]) -> Result<(), WireError> {
        let update: VarUpdate = wire::decode(bytes)?;
        if update.from != sender {
            self.core.refuse_misaddressed(now_ms, "variable update", sender, &update.from);
            return Ok(());
        }
        let record = self.core.admit_vars(&update).map(|kept| {
            if kept.len() == update.vars.len() {
                frame(VARS, now_ms, bytes)
            } else {
                frame(VARS, now_ms, &wire::encode(&VarUpdate { vars: kept, ..update.clone() }))
            }
        });
        self.arrived(now_ms, record, Record::Vars(update));
        Ok(())
    }

    /// A device report: recorded as it applies (messages cut, each binding once).
    pub fn devices(&mut self, now_ms: u64, sender: &str, bytes: &[u8]) -> Result<(), WireError> {
        let report: DeviceReport = wire::decode(bytes)?;
        if report.agent != sender {
            self.core.refuse_misaddressed(now_ms, "device report", sender, &report.agent);
            return Ok(());
        }
        let Some(kept) = self.core.admit_devices(&report) else {
            self.arrived(now_ms, None, Record::Devices(report));
            return Ok(());
        };
        let record = frame(DEVICES, now_ms, &wire::encode(&kept));
        self.arrived(now_ms, Some(record), Record::Devices(kept));
        Ok(())
    }

    pub fn agent_up(&mut self, now_ms: u64, info: AgentInfo) {
        self.input(now_ms, Record::AgentUp(info));
    }

    pub fn agent_down(&mut self, now_ms: u64, name: &str) {
        self.input(now_ms, Record::AgentDown(name.to_string()));
    }

    pub fn agent_conflict(&mut self, now_ms: u64, name: &str, processes: u32) {
        self.input(now_ms, Record::AgentConflict(name.to_string(), processes));
    }

    /// `baton set`: recorded only if it applies.
    pub fn set(&mut self, now_ms: u64, name: &str, value: &serde_json::Value) -> Result<String, String> {
        self.core.check_set(name, value)?;
        let request = SetRequest { name: name.to_string(), value: value.clone() };
        self.input(now_ms, Record::Set(request)).unwrap_or_else(|| Err("not applied".to_string()))
    }

    /// An operator's command: recorded whether it is taken or refused (the refusal is in the trace too).
    pub fn command(&mut self, now_ms: u64, request: CtlRequest) -> Result<String, String> {
        self.input(now_ms, Record::Command(request)).unwrap_or_else(|| Err("not applied".to_string()))
    }

    pub fn set_loss_policy(&mut self, now_ms: u64, policy: LossPolicy) {
        self.input(now_ms, Record::Policy(policy));
    }

    pub fn recover(&mut self, now_ms: u64) {
        self.input(now_ms, Record::Recover);
    }

    /// The run waits in Idle for an operator's `start`.
    pub fn wait_start(&mut self, now_ms: u64) {
        self.input(now_ms, Record::WaitStart);
    }

    /// The run stays at its end for `clear` and `reset`.
    pub fn stay(&mut self, now_ms: u64) {
        self.input(now_ms, Record::Stay);
    }

    /// After a `reset` (`Coordinator::wants_new_run`): the chart starts again as run `run`.
    pub fn new_run(&mut self, now_ms: u64, run: RunId) {
        self.input(now_ms, Record::NewRun(run));
    }

    /// The last record of a run that ended.
    pub fn end(&mut self, now_ms: u64) {
        let failure = self.core.failure().map(str::to_string);
        self.input(now_ms, Record::End { failure });
    }

    /// Rebuilds a coordinator from its journal's records, oldest first; its outputs are what the run did then
    /// (the trace of the past), left for the caller to take. Returns the time of the last record and whether
    /// the run had ended.
    pub fn replay<'a>(
        &mut self,
        records: impl IntoIterator<Item = &'a [u8]>,
    ) -> Result<Replayed, (usize, JournalError)> {
        let mut out = Replayed::default();
        for (i, bytes) in records.into_iter().enumerate() {
            let entry = decode(bytes).map_err(|e| (i, e))?;
            self.apply_replayed(&entry, &mut out);
        }
        Ok(out)
    }

    /// Applies one record read back from the journal (it is not recorded again), and counts it in `out`.
    pub fn apply_replayed(&mut self, entry: &Entry, out: &mut Replayed) {
        self.counted += 1;
        self.last_ms = self.last_ms.max(entry.t_ms);
        out.records += 1;
        out.last_ms = out.last_ms.max(entry.t_ms);
        match &entry.record {
            Record::End { failure } => out.ended = Some(failure.clone()),
            Record::Cycle => out.cycles += 1,
            _ => {}
        }
        apply(&mut self.core, entry);
    }
}

#[derive(Clone, Debug, Default, PartialEq)]
pub struct Replayed {
    pub records: u64,
    /// Cycle records among them (cycles that changed nothing were not recorded).
    pub cycles: u64,
    pub last_ms: u64,
    /// `Some(failure)` if the journal's run ended (with `failure` if it failed).
    pub ended: Option<Option<String>>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_round_trip_and_garbage_is_an_error() {
        let run = RunId(Uuid::from_u128(5));
        let entries = [
            Entry { t_ms: 0, record: Record::Policy(LossPolicy::Reassign) },
            Entry { t_ms: 7, record: Record::Cycle },
            Entry { t_ms: 9, record: Record::AgentDown("r1".into()) },
            Entry { t_ms: 10, record: Record::AgentConflict("r1".into(), 2) },
            Entry {
                t_ms: 11,
                record: Record::Set(SetRequest { name: "go".into(), value: serde_json::Value::Bool(true) }),
            },
            Entry {
                t_ms: 12,
                record: Record::Vars(VarUpdate {
                    run,
                    from: "r2".into(),
                    incarnation: Uuid::from_u128(9),
                    seq: 3,
                    vars: Vec::new(),
                }),
            },
            Entry { t_ms: 13, record: Record::Recover },
            Entry { t_ms: 13, record: Record::Stay },
            Entry { t_ms: 13, record: Record::NewRun(RunId(Uuid::from_u128(0x1234_5678_9abc))) },
            Entry {
                t_ms: 14,
                record: Record::Devices(DeviceReport {
                    run,
                    agent: "cell1".into(),
                    incarnation: Uuid::from_u128(9),
                    seq: 2,
                    down: vec![wire::DeviceDown { binding: 1, message: "no answer".into() }],
                }),
            },
            Entry { t_ms: u64::MAX, record: Record::End { failure: Some("agent `r1` was lost".into()) } },
            Entry { t_ms: 20, record: Record::End { failure: None } },
        ];
        for e in &entries {
            assert_eq!(decode(&encode(e)).as_ref(), Ok(e));
        }
        assert_eq!(decode(&[1, 2, 3]), Err(JournalError::Truncated(3)));
        assert_eq!(decode(&[200, 0, 0, 0, 0, 0, 0, 0, 0]), Err(JournalError::UnknownTag(200)));
        assert!(matches!(decode(&frame(REPORT, 1, b"{not json")), Err(JournalError::Malformed { tag: REPORT, .. })));
        assert!(matches!(decode(&frame(POLICY, 1, &[9])), Err(JournalError::Malformed { .. })));
        assert!(matches!(decode(&frame(NEW_RUN, 1, &[1, 2, 3])), Err(JournalError::Malformed { .. })));
    }

    #[test]
    fn token_ids_are_distinct_and_repeat_for_the_same_run() {
        let run = RunId(Uuid::from_u128(0xfeed));
        let mut a = token_ids(run);
        let mut b = token_ids(run);
        let first: Vec<wire::TokenId> = (0..1000).map(|_| a.next_id()).collect();
        let again: Vec<wire::TokenId> = (0..1000).map(|_| b.next_id()).collect();
        assert_eq!(first, again);
        let distinct: std::collections::BTreeSet<_> = first.iter().collect();
        assert_eq!(distinct.len(), first.len());
        let mut other = token_ids(RunId(Uuid::from_u128(0xbeef)));
        assert_ne!(other.next_id(), first[0]);
    }

    /// A coordinator of a chart with a step on r1 that writes `n` and waits for input `go`, with r1 up.
    fn journaled() -> (Journaled, RunId) {
        let (program, layout) = crate::testing::simulated_cluster::compile(
            "PROGRAM p\nVAR go : BOOL; n : DINT; note : STRING[8]; END_VAR\nINITIAL_STEP A: END_STEP\n\
             TRANSITION FROM A TO B := TRUE; END_TRANSITION\nSTEP B: {agent := 'r1'} Count(N); END_STEP\n\
             TRANSITION FROM B TO C := go; END_TRANSITION\nSTEP C: END_STEP\n\
             ACTION Count: n := n + 1; note := 'x'; END_ACTION\nEND_PROGRAM\n",
        );
        let run = RunId(Uuid::from_u128(7));
        let core = Coordinator::new(program, layout, run, ChartHash("h".into()), token_ids(run));
        let mut j = Journaled::new(core);
        let info = AgentInfo {
            name: "r1".into(),
            roles: Vec::new(),
            lease_ms: 1000,
            incarnation: Uuid::from_u128(1),
            held: Vec::new(),
            pending: Vec::new(),
        };
        j.agent_up(0, info);
        j.cycle(0);
        j.take_records();
        (j, run)
    }

    fn value(j: &Journaled, name: &str, v: crate::types::Value) -> wire::VarValue {
        wire::VarValue::new(j.core().program().var_by_name(name).expect("a variable"), v)
    }

    /// A snapshot says where it stands (records, trace records, time) and restores the coordinator it was taken
    /// of; one taken with outputs not yet taken is not made; one of another Baton version or format is refused.
    #[test]
    fn a_snapshot_restores_where_it_stands_and_only_for_the_baton_that_wrote_it() {
        let (mut j, _) = journaled();
        j.set(20, "go", &serde_json::json!(true)).expect("go");
        assert!(j.snapshot(serde_json::Value::Null).is_none(), "outputs not yet taken");
        let traced = std::iter::from_fn(|| j.poll_output())
            .filter(|o| matches!(o, crate::dist::runtime::coordinator::CoordOutput::Trace(_)))
            .count() as u64;
        j.cycle(30);
        while j.poll_output().is_some() {}
        j.take_records();
        let bytes = j.snapshot(serde_json::json!({"shell": 1})).expect("nothing pending");
        // The cycle at 30 changed nothing and was not recorded yet: the snapshot records it first, so that it
        // follows the last record exactly.
        let quiet: Vec<Entry> = j.take_records().iter().map(|r| decode(r).expect("a record")).collect();
        assert_eq!(quiet, [Entry { t_ms: 30, record: Record::Cycle }]);
        let records = j.records_counted();
        let (program, layout) = (std::sync::Arc::clone(j.core().program()), std::sync::Arc::clone(j.core().layout()));
        let (again, meta) = Journaled::restore(std::sync::Arc::clone(&program), std::sync::Arc::clone(&layout), &bytes)
            .expect("restores");
        assert_eq!((meta.records, meta.last_ms, meta.shell), (records, 30, serde_json::json!({"shell": 1})));
        assert!(
            meta.trace_records >= traced && traced > 0,
            "{} trace records, {traced} taken before",
            meta.trace_records
        );
        assert_eq!(again.core().snapshot(), j.core().snapshot(), "the same coordinator");
        // Another version's snapshot: its meta rewritten, the state as it was.
        let (old, state) = split_snapshot(&bytes).expect("a snapshot");
        let older = encode_snapshot(&SnapshotMeta { baton: "0.0.1".into(), ..old }, state);
        let err = Journaled::restore(program, layout, &older).err().expect("refused");
        assert!(
            err.contains("was written by Baton 0.0.1") && err.contains("resume it with the Baton that wrote it"),
            "{err}"
        );
    }

    /// A run that stays, completes, is reset and runs again: its journal, replayed into a new coordinator, makes
    /// the same trace and ends in the same run, state and situation.
    #[test]
    fn a_reset_is_replayed_into_the_same_runs_and_trace() {
        use crate::dist::runtime::coordinator::CoordOutput;
        use crate::dist::runtime::packml::State;
        let (program, layout) = crate::testing::simulated_cluster::compile(
            "PROGRAM p\nVAR go : BOOL; n : DINT; END_VAR\nINITIAL_STEP A: Count(N); END_STEP\n\
             TRANSITION FROM A TO B := go; END_TRANSITION\nSTEP B: END_STEP\n\
             ACTION Count: n := n + 1; END_ACTION\nEND_PROGRAM\n",
        );
        let first = RunId(Uuid::from_u128(7));
        let fresh = || {
            let (p, l) = (std::sync::Arc::clone(&program), std::sync::Arc::clone(&layout));
            Coordinator::new(p, l, first, ChartHash("h".into()), token_ids(first))
        };
        let trace = |j: &mut Journaled| {
            std::iter::from_fn(|| j.poll_output())
                .filter_map(|o| match o {
                    CoordOutput::Trace(t) => Some(t),
                    _ => None,
                })
                .collect::<Vec<_>>()
        };
        let ctl = |command: &str| CtlRequest {
            command: command.into(),
            reason: "shift change".into(),
            by: "op".into(),
            ..Default::default()
        };
        let mut live = Journaled::new(fresh());
        live.stay(0);
        live.set(0, "go", &serde_json::json!(true)).expect("go");
        for t in [10, 20, 30] {
            live.cycle(t);
        }
        assert_eq!(live.core().run_state(), State::Complete);
        live.command(40, ctl("reset")).expect("reset");
        let second = RunId(Uuid::from_u128(8));
        assert!(live.core().wants_new_run());
        live.new_run(40, second);
        live.command(50, ctl("start")).expect("start");
        for t in [60, 70] {
            live.cycle(t);
        }
        let n = program.var_by_name("n").expect("n");
        let counted = live.core().value(n);
        let live_trace = trace(&mut live);
        assert!(live_trace
            .iter()
            .any(|r| r.event == crate::exec::trace::TraceEvent::NewRun && r.message == Some(second.key())));
        let records = live.take_records();
        let mut again = Journaled::new(fresh());
        again.replay(records.iter().map(Vec::as_slice)).expect("the records decode");
        assert_eq!(trace(&mut again), live_trace);
        assert_eq!((again.core().run(), again.core().run_state()), (second, State::Execute));
        assert_eq!(again.core().value(n), counted);
    }

    #[test]
    fn what_the_coordinator_refuses_is_not_journaled() {
        use crate::types::Value;
        let (mut j, run) = journaled();
        let update = |from: &str, incarnation: u128, seq: u64, vars: Vec<wire::VarValue>| VarUpdate {
            run,
            from: from.into(),
            incarnation: Uuid::from_u128(incarnation),
            seq,
            vars,
        };
        // A megabyte from an agent the coordinator does not know, 50 times; one from r1's replaced or made-up
        // process; one of another run; a value r1 does not write; a string longer than its variable: nothing
        // to record.
        let big = value(&j, "note", Value::Str(std::sync::Arc::new("x".repeat(1_000_000))));
        for seq in 0..50 {
            j.vars(10, "ghost", &wire::encode(&update("ghost", 9, seq, vec![big.clone()]))).expect("decodes");
        }
        j.vars(11, "r1", &wire::encode(&update("r1", 2, 1, vec![value(&j, "n", Value::Int(5))]))).expect("decodes");
        let mut other = update("r1", 1, 1, vec![value(&j, "n", Value::Int(5))]);
        other.run = RunId(Uuid::from_u128(8));
        j.vars(12, "r1", &wire::encode(&other)).expect("decodes");
        j.vars(13, "r1", &wire::encode(&update("r1", 1, 1, vec![value(&j, "go", Value::Bool(true))])))
            .expect("decodes");
        j.vars(14, "r1", &wire::encode(&update("r1", 1, 1, vec![big.clone()]))).expect("decodes");
        assert!(j.take_records().is_empty(), "refused updates were journaled");
        assert_eq!(j.core().value(j.core().program().var_by_name("go").expect("go")), Value::Bool(false));
        // A set the coordinator refuses is not journaled either; one it takes is.
        assert!(j.set(15, "n", &serde_json::json!(3)).is_err());
        assert!(j.set(15, "nothing", &serde_json::json!(3)).is_err());
        assert!(j.take_records().is_empty());
        assert!(j.set(16, "go", &serde_json::json!(false)).is_ok());
        assert_eq!(j.take_records().len(), 1);
        // An update that mixes what r1 writes with what it does not: only r1's own value is recorded, once.
        let mixed = update(
            "r1",
            1,
            2,
            vec![value(&j, "n", Value::Int(7)), value(&j, "go", Value::Bool(true)), value(&j, "n", Value::Int(8))],
        );
        j.vars(17, "r1", &wire::encode(&mixed)).expect("decodes");
        let records = j.take_records();
        assert_eq!(records.len(), 1);
        let Ok(Entry { record: Record::Vars(kept), .. }) = decode(&records[0]) else { panic!("a Vars record") };
        assert_eq!(kept.vars, vec![value(&j, "n", Value::Int(7))]);
        // The same update again is old news: not recorded.
        j.vars(18, "r1", &wire::encode(&mixed)).expect("decodes");
        assert!(j.take_records().is_empty());
        // r2 publishing on its own key an update that says it is r1's: dropped, not recorded, nothing taken.
        let claimed = update("r1", 1, 3, vec![value(&j, "n", Value::Int(9))]);
        j.vars(19, "r2", &wire::encode(&claimed)).expect("decodes");
        assert!(j.take_records().is_empty());
        assert_eq!(j.core().value(j.core().program().var_by_name("n").expect("n")), Value::Int(7));
    }

    #[test]
    fn reports_held_ahead_of_a_gap_are_bounded_by_bytes_and_duplicates_are_not_journaled() {
        use crate::dist::wire::{AgentEvent, AgentEventKind, ToAgent};
        use crate::limits::REPORTS_AHEAD_BYTES_MAX;
        let (mut j, run) = journaled();
        let mut token = None;
        while let Some(out) = j.poll_output() {
            if let crate::dist::runtime::coordinator::CoordOutput::Send {
                msg: ToAgent::Dispatch { token: t, .. },
                ..
            } = out
            {
                token = Some(t);
            }
        }
        let token = token.expect("B was dispatched to r1");
        let report = |seq: u32, message: String| Report {
            run,
            agent: "r1".into(),
            incarnation: Uuid::from_u128(1),
            token,
            epoch: 1,
            seq,
            events: vec![AgentEvent { dt_ms: 1, kind: AgentEventKind::Fault { message } }],
            vars: Vec::new(),
            vars_seq: 0,
            done: false,
        };
        // Reports ahead of the missing seq 0, each 100 KB: those within REPORTS_AHEAD_BYTES_MAX are held (and
        // recorded, since they will apply), the rest are dropped unrecorded (the agent sends them again).
        let mut recorded = 0;
        for seq in 1..100 {
            j.report(20, "r1", &wire::encode(&report(seq, "f".repeat(100_000)))).expect("decodes");
            recorded += j.take_records().len();
        }
        assert!(recorded > 0 && recorded * 100_000 <= REPORTS_AHEAD_BYTES_MAX, "{recorded} held");
        // The same one ahead again, and one from another process: not recorded.
        j.report(21, "r1", &wire::encode(&report(1, "f".into()))).expect("decodes");
        let mut forged = report(0, "f".into());
        forged.incarnation = Uuid::from_u128(2);
        j.report(21, "r1", &wire::encode(&forged)).expect("decodes");
        assert!(j.take_records().is_empty());
        // On r2's key, saying it is r1's: dropped before anything looks at it.
        j.report(21, "r2", &wire::encode(&report(0, "f".into()))).expect("decodes");
        assert!(j.take_records().is_empty());
        // The one it waits for applies, and so do those held.
        j.report(22, "r1", &wire::encode(&report(0, "f".into()))).expect("decodes");
        assert_eq!(j.take_records().len(), 1);
        // Now old: acknowledged again, not recorded.
        j.report(23, "r1", &wire::encode(&report(0, "f".into()))).expect("decodes");
        assert!(j.take_records().is_empty());
    }

    #[test]
    fn the_program_pin_changes_with_what_the_numbers_mean() {
        let pin = |src: &str| {
            let (program, layout) = crate::testing::simulated_cluster::compile(src);
            program_pin(&program, &layout)
        };
        let chart = |vars: &str, placed: &str| {
            format!(
                "PROGRAM p\nVAR {vars} END_VAR\nINITIAL_STEP A: END_STEP\nTRANSITION FROM A TO B := go; \
                 END_TRANSITION\nSTEP B: {placed} END_STEP\nEND_PROGRAM\n"
            )
        };
        let base = chart("go : BOOL; n : INT;", "");
        assert_eq!(pin(&base), pin(&base), "the same compilation, the same pin");
        // Variables numbered the other way round, a type changed, a step placed elsewhere: each moves the pin.
        for other in [
            chart("n : INT; go : BOOL;", ""),
            chart("go : BOOL; n : DINT;", ""),
            chart("go : BOOL; n : INT;", "{agent := 'r1'}"),
        ] {
            assert_ne!(pin(&base), pin(&other), "{other}");
        }
    }
}
