//! `Journaled`: a `Coordinator` whose every input is recorded first, the `--watch` values it traces after each
//! record, and its snapshots (`SnapshotMeta` and the coordinator's state).

use serde::{Deserialize, Serialize};

use crate::cluster::layout::Layout;
use crate::cluster::runtime::coordinator::{token_ids, Admitted, CoordOutput, Coordinator, LossPolicy};
use crate::cluster::wire::{self, AgentInfo, ChartHash, CtlRequest, FromAgent, RunId, SetRequest, WireError};
use crate::exec::program::{Program, VarId};
use crate::exec::trace::{TraceEvent, TraceRecord};
use crate::types::Value;

use super::records::{apply, decode, encode, frame, Entry, JournalError, Record, DEVICES, REPORT, VARS};

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
    /// `--watch`: what the trace says of these variables (`watch`).
    watch: Watch,
}

/// The variables whose `value` records the trace gets, as `baton sim --watch` gives them: once after the first
/// cycle, then after each record that changes them — made after each record as its replay makes them, so that a
/// live run, a resumed one and a replay trace the same, and counted with the coordinator's own trace records.
#[derive(Default)]
struct Watch {
    /// Each variable with the value the trace last recorded.
    vars: Vec<(VarId, Option<Value>)>,
    /// The first cycle was recorded: values are traced from there on.
    started: bool,
    /// The values a snapshot held, by name, for `watch` to take up.
    restored: Vec<(String, Value)>,
    /// The coordinator's outputs and the `value` records after them, in the order they were made.
    queue: std::collections::VecDeque<CoordOutput>,
}

/// Bumped when the coordinator's state changes shape; a snapshot is also restored only by the Baton version that
/// wrote it (`SnapshotMeta::baton`), since its fields are the coordinator's own.
/// 2: an agent's `gone_at_ms` (its grace after its token went); the `--watch` values in the meta.
pub const SNAPSHOT_FORMAT: u32 = 2;

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
    /// The host's own (`baton run`: the summary's step times), opaque here. Named `shell` in the journal's
    /// format since its first version.
    #[serde(default, rename = "shell")]
    pub host: serde_json::Value,
    /// The watched variables' values as the trace last recorded them, once the first cycle was recorded.
    #[serde(default)]
    pub watched: Option<Vec<(String, Value)>>,
}

/// A snapshot's bytes: the length of its `SnapshotMeta` (u32, little-endian), the meta as JSON, the coordinator's
/// state (`Coordinator::snapshot`).
pub(super) fn encode_snapshot(meta: &SnapshotMeta, core: &[u8]) -> Vec<u8> {
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

pub(super) fn split_snapshot(bytes: &[u8]) -> Result<(SnapshotMeta, &[u8]), String> {
    let (len, rest) = bytes.split_at_checked(4).ok_or("is truncated")?;
    let len = u32::from_le_bytes(len.try_into().map_err(|_| "is truncated")?) as usize;
    let (meta, core) = rest.split_at_checked(len).ok_or("is truncated")?;
    let meta = serde_json::from_slice(meta).map_err(|e| format!("has a malformed head: {e}"))?;
    Ok((meta, core))
}

impl Journaled {
    pub fn new(core: Coordinator) -> Journaled {
        Journaled {
            core,
            records: Vec::new(),
            quiet_ms: None,
            counted: 0,
            traced: 0,
            last_ms: 0,
            watch: Watch::default(),
        }
    }

    /// Traces the values of `vars` too (`--watch`): after the first cycle and after every change. A coordinator
    /// restored from a snapshot goes on from the values its trace last recorded.
    pub fn watch(&mut self, vars: Vec<VarId>) {
        let program = std::sync::Arc::clone(self.core.program());
        let last = |v: VarId| {
            let name = &program.vars[v.index()].name;
            self.watch.restored.iter().find(|(n, _)| n == name).map(|(_, value)| value.clone())
        };
        self.watch.vars = vars.into_iter().map(|v| (v, last(v))).collect();
    }

    /// After a record is made and applied (as a replay applies it): the watched variables it changed, in the
    /// trace after what the coordinator made of it.
    fn after_record(&mut self, t_ms: u64, cycle: bool) {
        self.watch.started |= cycle;
        if !self.watch.started || self.watch.vars.is_empty() {
            return;
        }
        while let Some(out) = self.core.poll_output() {
            self.watch.queue.push_back(out);
        }
        let program = self.core.program();
        for (var, last) in &mut self.watch.vars {
            let value = self.core.value(*var);
            if last.as_ref() != Some(&value) {
                let decl = &program.vars[var.index()];
                let mut record = TraceRecord::new(t_ms, TraceEvent::Value, &decl.name);
                record.value = Some(decl.ty.show(&value));
                *last = Some(value);
                self.watch.queue.push_back(CoordOutput::Trace(record));
            }
        }
    }

    /// The last of the cycles that changed nothing since the last record, recorded (before the next record, or a
    /// snapshot): a replay reaches it at the same time, and changes nothing there either.
    fn record_quiet_cycle(&mut self) {
        if let Some(t_ms) = self.quiet_ms.take() {
            self.push(encode(&Entry { t_ms, record: Record::Cycle }), t_ms);
            self.after_record(t_ms, true);
        }
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

    /// A snapshot of the coordinator after every record made so far, with `host`'s data; `None` while it has
    /// outputs not yet taken (their trace records would be counted nowhere). A cycle that changed nothing and
    /// was not recorded yet is recorded first, so that the snapshot follows the last record exactly: take the
    /// records after this call, and write them before the snapshot.
    pub fn snapshot(&mut self, host: serde_json::Value) -> Option<Vec<u8>> {
        self.record_quiet_cycle();
        if self.has_output() {
            return None;
        }
        let watched = self.watch.started.then(|| {
            let program = self.core.program();
            let traced = self.watch.vars.iter().filter_map(|(v, last)| Some((v, last.clone()?)));
            traced.map(|(v, value)| (program.vars[v.index()].name.clone(), value)).collect()
        });
        let meta = SnapshotMeta {
            format: SNAPSHOT_FORMAT,
            baton: env!("CARGO_PKG_VERSION").to_string(),
            records: self.counted,
            trace_records: self.traced,
            last_ms: self.last_ms,
            host,
            watched,
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
        j.watch.started = meta.watched.is_some();
        j.watch.restored = meta.watched.clone().unwrap_or_default();
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
    pub fn poll_output(&mut self) -> Option<CoordOutput> {
        let out = self.watch.queue.pop_front().or_else(|| self.core.poll_output());
        if let Some(CoordOutput::Trace(_)) = &out {
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
        !self.watch.queue.is_empty() || self.core.has_output()
    }

    fn feed(&mut self, bytes: Vec<u8>, entry: Entry) -> Option<Result<String, String>> {
        // The cycles that changed nothing since the last record moved the clock on: the last of them is recorded
        // before this input.
        self.record_quiet_cycle();
        self.push(bytes, entry.t_ms);
        let result = apply(&mut self.core, &entry);
        self.after_record(entry.t_ms, matches!(entry.record, Record::Cycle));
        result
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
            self.after_record(now_ms, true);
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

    /// A report as it arrived from `sender` (the agent its key names).
    pub fn report(&mut self, now_ms: u64, sender: &str, bytes: &[u8]) -> Result<(), WireError> {
        self.take_from_agent(now_ms, sender, bytes, FromAgent::Report(wire::decode(bytes)?));
        Ok(())
    }

    /// A variable update as it arrived from `sender`.
    pub fn vars(&mut self, now_ms: u64, sender: &str, bytes: &[u8]) -> Result<(), WireError> {
        self.take_from_agent(now_ms, sender, bytes, FromAgent::Vars(wire::decode(bytes)?));
        Ok(())
    }

    /// A device report as it arrived from `sender`.
    pub fn devices(&mut self, now_ms: u64, sender: &str, bytes: &[u8]) -> Result<(), WireError> {
        self.take_from_agent(now_ms, sender, bytes, FromAgent::Devices(wire::decode(bytes)?));
        Ok(())
    }

    /// What an agent sent, decoded from `bytes`: the coordinator judges it (`Coordinator::admit`), what it admits
    /// is recorded (the bytes as they came when it is whole), and then applied.
    fn take_from_agent(&mut self, now_ms: u64, sender: &str, bytes: &[u8], msg: FromAgent) {
        let tag = match msg {
            FromAgent::Report(_) => REPORT,
            FromAgent::Vars(_) => VARS,
            FromAgent::Devices(_) => DEVICES,
        };
        let (record, applied) = match self.core.admit(now_ms, sender, &msg) {
            Admitted::Refused => return,
            Admitted::Unrecorded => (None, msg),
            Admitted::Whole => (Some(frame(tag, now_ms, bytes)), msg),
            // A device report applies as it is kept; an update's values that do not apply are refused as the
            // whole is applied.
            Admitted::Part(kept) => {
                let bytes = frame(tag, now_ms, &kept.encode());
                (Some(bytes), if matches!(kept, FromAgent::Devices(_)) { kept } else { msg })
            }
        };
        self.arrived(now_ms, record, Record::from(applied));
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
        self.set_by(now_ms, SetRequest { name: name.to_string(), value: value.clone(), by: String::new(), user: None })
    }

    /// `baton set` of `request.by`: recorded only if it applies.
    pub fn set_by(&mut self, now_ms: u64, request: SetRequest) -> Result<String, String> {
        self.core.check_set(&request.name, &request.value)?;
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
        self.after_record(entry.t_ms, matches!(entry.record, Record::Cycle));
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
