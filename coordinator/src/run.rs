//! `baton run`: the coordinator's Zenoh shell. It turns samples into inputs of the pure `Coordinator`, runs its
//! cycles, publishes what it asks for, writes the trace and answers the chart, status and set queries. It
//! decides nothing about charts: every rule lives in `baton_proto::dist::runtime::coordinator`.
//!
//! With `--journal DIR`, every input is recorded (`baton_proto::dist::journal::Journaled`) and what the coordinator
//! asks for is held back until the records that led to it are durable (`crate::journal`, group commit). A
//! journal of a run that did not end is resumed: replayed, then reconciled with the agents.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context};
use baton_proto::dist::journal::{self, JournalHeader, Journaled, Record, JOURNAL_FORMAT};
use baton_proto::dist::keys;
use baton_proto::dist::layout::Layout;
use baton_proto::dist::netconfig::NetConfig;
use baton_proto::dist::runtime::coordinator::{CoordOutput, Coordinator, LossPolicy};
use baton_proto::dist::runtime::Level;
use baton_proto::dist::wire::{self, AgentInfo, ChartHash, ChartSource, RunId, SetReply, SetRequest};
use baton_proto::exec::program::{Program, VarId};
use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use baton_proto::limits::{CATCH_UP_CYCLES_MAX, RECEIVE_QUEUE_MAX};
use baton_proto::pipeline::check_source;
use baton_proto::types::Value;
use serde::Serialize;
use tokio::sync::mpsc;
use zenoh::handlers::FifoChannel;
use zenoh::pubsub::Publisher;
use zenoh::qos::CongestionControl;
use zenoh::query::Query;
use zenoh::sample::{Sample, SampleKind};
use zenoh::Session;

const INFO_QUERY_TIMEOUT: Duration = Duration::from_secs(3);
const INFO_QUERY_ATTEMPTS: u32 = 5;
/// Replies to one info query taken into account: two already mean a conflict.
const INFO_REPLIES_MAX: usize = 16;
/// How often a name that several processes answer to is asked again.
const CONFLICT_RECHECK: Duration = Duration::from_secs(2);

pub struct RunOptions {
    pub chart: PathBuf,
    pub pou: Option<String>,
    pub listen: Vec<String>,
    pub connect: Vec<String>,
    pub trace: Option<PathBuf>,
    pub summary: Option<PathBuf>,
    pub cycle_ms: u64,
    pub sets: Vec<(String, serde_json::Value)>,
    pub multicast_scouting: bool,
    pub quiet: bool,
    /// The user's own Zenoh configuration (TLS, credentials), under Baton's settings.
    pub zenoh_config: Option<PathBuf>,
    pub loss_policy: LossPolicy,
    /// Record every input in this folder before acting on it; resume the run found there.
    pub journal: Option<PathBuf>,
    /// Where the run's Rerun recording goes.
    pub rerun: crate::recording::Sink,
    /// Variables whose value the trace records: once after the first cycle and after every change.
    pub watch: Vec<String>,
}

/// What `baton run` prints at the end, and writes with `--summary FILE`.
#[derive(Serialize)]
pub struct Summary {
    pub chart: String,
    pub run: String,
    pub duration_ms: u64,
    pub tokens_dispatched: u64,
    pub tokens_returned: u64,
    pub messages_dropped: u64,
    /// Per step: how many times it was active and for how long in all.
    pub steps: BTreeMap<String, StepTime>,
    /// Final values of the chart's variables.
    pub vars: BTreeMap<String, String>,
    /// With `--journal`: records written and transactions committed by this process.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub journal: Option<crate::journal::JournalStats>,
}

#[derive(Serialize, Default, Clone, Copy)]
pub struct StepTime {
    pub activations: u64,
    pub active_ms: u64,
}

/// A compiled chart ready to coordinate.
pub struct Loaded {
    pub source: String,
    pub pou: String,
    pub program: Arc<Program>,
    pub layout: Arc<Layout>,
}

/// Reads and checks the chart; every problem is printed, as `baton check` would.
pub fn load(chart: &std::path::Path, pou: Option<&str>) -> anyhow::Result<Loaded> {
    let source = crate::cli::read_chart(chart)?.text;
    let report = check_source(&source);
    let index = baton_proto::front::diag::LineIndex::new(&source);
    for d in &report.diagnostics {
        eprint!("{}", index.render(&chart.display().to_string(), d));
    }
    let chosen = crate::cli::pick(&report, pou)?;
    let (Some(program), Some(layout)) = (&chosen.program, &chosen.layout) else {
        bail!("chart `{}` has errors; nothing was run", chosen.chart.name.name);
    };
    Ok(Loaded {
        pou: chosen.chart.name.name.clone(),
        program: Arc::new(program.clone()),
        layout: Arc::new(layout.clone()),
        source,
    })
}

/// Who answered to an agent's name.
enum Identity {
    One(AgentInfo),
    /// Several processes answered to this name (how many).
    Several(String, u32),
    /// Nobody that makes sense, and why.
    Unknown(String, String),
}

struct Shell {
    session: Session,
    core: Journaled,
    started: Instant,
    /// The run's time when this process started: 0, or where a resumed run stood (downtime included).
    base_ms: u64,
    journal: Option<crate::journal::Writer>,
    /// What the coordinator asked for, per journal batch, until that batch is durable.
    held: VecDeque<(u64, Vec<CoordOutput>)>,
    /// Answers to `baton set`, likewise: a client is told a value was taken only once it is durable.
    held_replies: VecDeque<(u64, Query, Vec<u8>)>,
    quiet: bool,
    /// One publisher per key, declared on first use.
    publishers: HashMap<String, Publisher<'static>>,
    vars_key: String,
    decode_drops: u64,
    out: Records,
    /// The run's cycle period, and the grid time of the last cycle this process ran.
    cycle_ms: u64,
    last_cycle_ms: Option<u64>,
    /// Agents whose liveliness token is there: those are asked again until they say who they are.
    live: std::collections::HashSet<String>,
}

/// What woke the coordinator's main loop.
enum Wake {
    Report(Sample),
    Vars(Sample),
    Devices(Sample),
    Alive(Sample),
    Identity(Identity),
    Chart(Query),
    Status(Query),
    Set(Query),
    Durable,
    Timer,
    Stop,
    Closed,
}

/// Where trace records go: the bench's probe, the recording, the summary's step times and the trace file.
pub struct Records {
    /// The run's cycle period: a record's cycle (the recording's `cycle` timeline) is its grid index.
    cycle_ms: u64,
    pub trace: Option<BufWriter<File>>,
    trace_error: bool,
    steps: BTreeMap<String, (StepTime, Option<u64>)>,
    probe: Option<Probe>,
    pub recorder: Option<crate::recording::Recorder>,
    /// `--watch`: each variable with the value the trace last recorded.
    watched: Vec<(VarId, Option<Value>)>,
}

impl Records {
    pub fn new(
        trace: Option<BufWriter<File>>,
        probe: Option<Probe>,
        recorder: Option<crate::recording::Recorder>,
        cycle_ms: u64,
    ) -> Records {
        Records {
            cycle_ms: cycle_ms.max(1),
            trace,
            trace_error: false,
            steps: BTreeMap::new(),
            probe,
            recorder,
            watched: Vec::new(),
        }
    }

    /// Records the values of `vars` too (`--watch`), as `baton sim --watch` does.
    pub fn watch(&mut self, vars: Vec<VarId>) {
        self.watched = vars.into_iter().map(|v| (v, None)).collect();
    }

    /// `value` records of the watched variables that changed since the trace last said: they go with the
    /// outputs of the input that changed them, so that they are written only once it is durable.
    pub fn watched_changes(&mut self, t_ms: u64, core: &Coordinator) -> Vec<TraceRecord> {
        let mut out = Vec::new();
        for (var, last) in &mut self.watched {
            let value = core.value(*var);
            if last.as_ref() != Some(&value) {
                let decl = &core.program().vars[var.index()];
                let mut record = TraceRecord::new(t_ms, TraceEvent::Value, &decl.name);
                record.value = Some(decl.ty.show(&value));
                *last = Some(value);
                out.push(record);
            }
        }
        out
    }

    pub fn record(&mut self, rec: TraceRecord) {
        let cycle = rec.t_ms / self.cycle_ms;
        if let Some(probe) = &mut self.probe {
            probe(&rec);
        }
        if let Some(r) = &mut self.recorder {
            r.trace(cycle, &rec);
        }
        match rec.event {
            TraceEvent::Activate => {
                let e = self.steps.entry(rec.name.clone()).or_default();
                e.0.activations += 1;
                e.1 = Some(rec.t_ms);
            }
            TraceEvent::Deactivate => {
                if let Some((time, since)) = self.steps.get_mut(&rec.name) {
                    if let Some(t0) = since.take() {
                        time.active_ms += rec.t_ms.saturating_sub(t0);
                    }
                }
            }
            _ => {}
        }
        if let Some(w) = &mut self.trace {
            let written = serde_json::to_writer(&mut *w, &rec)
                .map_err(std::io::Error::other)
                .and_then(|()| w.write_all(b"\n"))
                .and_then(|()| w.flush());
            if let Err(e) = written {
                if !self.trace_error {
                    eprintln!("error: cannot write the trace: {e}");
                    self.trace_error = true;
                }
            }
        }
    }

    /// The variables' values at `t_ms`, after an input, for the recording.
    pub fn values(&mut self, t_ms: u64, core: &Coordinator) {
        let cycle = t_ms / self.cycle_ms;
        if let Some(r) = self.recorder.as_mut() {
            r.values(cycle, t_ms, |v| core.value(v));
        }
    }

    /// Ends the recording and flushes the trace.
    pub fn finish(&mut self) -> anyhow::Result<()> {
        if let Some(r) = self.recorder.take() {
            let dropped = r.finish();
            if dropped > 0 {
                eprintln!("warning: the recording lacks {dropped} record(s): the Rerun sink could not keep up");
            }
        }
        if let Some(t) = &mut self.trace {
            t.flush().context("cannot write the trace")?;
        }
        Ok(())
    }
}

/// Rebuilds a run from its journal's records into `core`: the trace (and recording) of the past go to `out`,
/// nothing is sent.
pub fn replay_records(
    core: &mut Journaled,
    records: &[Vec<u8>],
    out: &mut Records,
) -> anyhow::Result<journal::Replayed> {
    let mut replayed = journal::Replayed::default();
    for (i, bytes) in records.iter().enumerate() {
        let entry = journal::decode(bytes).map_err(|e| anyhow!("the journal's record {i} cannot be read: {e}"))?;
        core.apply_replayed(&entry, &mut replayed);
        while let Some(output) = core.poll_output() {
            if let CoordOutput::Trace(rec) = output {
                out.record(rec);
            }
        }
        // After every input, as the live run does.
        out.values(entry.t_ms, core.core());
        for rec in out.watched_changes(entry.t_ms, core.core()) {
            out.record(rec);
        }
    }
    Ok(replayed)
}

/// Sees every trace record as it is made, for `baton bench`'s clocks.
pub type Probe = Box<dyn FnMut(&TraceRecord) + Send>;

pub async fn run(opts: RunOptions) -> anyhow::Result<Summary> {
    run_with(opts, None).await
}

pub async fn run_with(opts: RunOptions, probe: Option<Probe>) -> anyhow::Result<Summary> {
    let loaded = load(&opts.chart, opts.pou.as_deref())?;
    if opts.listen.is_empty() == opts.connect.is_empty() {
        bail!("give either --listen ENDPOINT (embed a router) or --connect ENDPOINT (join one)");
    }
    let hash = ChartHash::of(&loaded.source, &loaded.pou);
    let mut watch = Vec::with_capacity(opts.watch.len());
    for name in &opts.watch {
        match loaded.program.var_by_name(name) {
            Some(v) => watch.push(v),
            None => bail!("--watch {name}: chart `{}` has no variable `{name}`", loaded.program.name),
        }
    }
    // The journal first: a refused one costs nothing, not even a Zenoh session.
    let mut resume: Option<(JournalHeader, Vec<Vec<u8>>)> = None;
    let mut writer = None;
    let (run, started_unix_ms) = match &opts.journal {
        None => (RunId(uuid::Uuid::new_v4()), unix_ms()),
        Some(dir) => {
            let mut opened = crate::journal::open(dir)?;
            let path = opened.store.path().display().to_string();
            let run = match opened.header.take() {
                None => {
                    let header = JournalHeader {
                        format: JOURNAL_FORMAT,
                        run: RunId(uuid::Uuid::new_v4()),
                        chart: hash.clone(),
                        pou: loaded.pou.clone(),
                        source: loaded.source.clone(),
                        started_unix_ms: unix_ms(),
                        cycle_ms: opts.cycle_ms,
                        program: journal::program_pin(&loaded.program, &loaded.layout),
                    };
                    opened.store.write_header(&header)?;
                    (header.run, header.started_unix_ms)
                }
                Some(header) => {
                    check_resumable(&header, &opened.records, &loaded, &hash, &opts.chart, &path)?;
                    let at = (header.run, header.started_unix_ms);
                    resume = Some((header, std::mem::take(&mut opened.records)));
                    at
                }
            };
            writer = Some(opened.store.start_writer());
            run
        }
    };
    let net =
        if opts.listen.is_empty() { NetConfig::client(&opts.connect, true) } else { NetConfig::router(&opts.listen) };
    let net = NetConfig { multicast_scouting: opts.multicast_scouting, ..net };
    let zconfig = crate::zconf::load(&net, opts.zenoh_config.as_deref())?;
    let session = zenoh::open(zconfig).await.map_err(|e| anyhow!("cannot open a Zenoh session: {e}"))?;
    // A resumed run keeps the period it started with.
    let cycle_ms = match &resume {
        Some((header, _)) => {
            if header.cycle_ms != opts.cycle_ms {
                eprintln!(
                    "warning: --cycle-ms {} ignored: the run resumes with the period it started with, {} ms",
                    opts.cycle_ms, header.cycle_ms
                );
            }
            header.cycle_ms
        }
        None => opts.cycle_ms,
    }
    .max(1);
    let chart_reply = wire::encode(&ChartSource {
        hash: hash.clone(),
        pou: loaded.pou.clone(),
        source: loaded.source.clone(),
        cycle_ms,
    });
    let mut core =
        Coordinator::new(Arc::clone(&loaded.program), Arc::clone(&loaded.layout), run, hash, journal::token_ids(run));
    core.set_cycle_ms(cycle_ms);
    let zerr = |e: zenoh::Error| anyhow!("{e}");
    let inbox = || FifoChannel::new(RECEIVE_QUEUE_MAX);
    let report_sub = session.declare_subscriber(keys::report(run)).with(inbox()).await.map_err(zerr)?;
    let vars_sub = session.declare_subscriber(keys::vars(run, "*")).with(inbox()).await.map_err(zerr)?;
    let devices_sub = session.declare_subscriber(keys::devices(run, "*")).with(inbox()).await.map_err(zerr)?;
    let alive_sub = session.liveliness().declare_subscriber(keys::alive_any()).history(true).await.map_err(zerr)?;
    let chart_q = session.declare_queryable(keys::chart(run)).await.map_err(zerr)?;
    let status_q = session.declare_queryable(keys::status(run)).await.map_err(zerr)?;
    let set_q = session.declare_queryable(keys::set(run)).await.map_err(zerr)?;
    let trace = match &opts.trace {
        Some(p) => Some(BufWriter::new(File::create(p).with_context(|| format!("cannot create {}", p.display()))?)),
        None => None,
    };
    let where_ = if opts.listen.is_empty() {
        format!("joined {}", opts.connect.join(", "))
    } else {
        format!("router on {}", opts.listen.join(", "))
    };
    let mut durable_rx = writer.as_ref().map(crate::journal::Writer::watcher);
    let recorder = crate::recording::Recorder::start(
        &opts.rerun,
        crate::recording::RecordedRun {
            program: Arc::clone(&loaded.program),
            layout: Arc::clone(&loaded.layout),
            run: run.key(),
            started_unix_ms,
        },
    )?;
    let mut shell = Shell {
        session: session.clone(),
        core: Journaled::new(core),
        started: Instant::now(),
        base_ms: 0,
        journal: writer,
        held: VecDeque::new(),
        held_replies: VecDeque::new(),
        quiet: opts.quiet,
        publishers: HashMap::new(),
        vars_key: keys::vars(run, baton_proto::dist::runtime::COORDINATOR),
        decode_drops: 0,
        out: Records::new(trace, probe, recorder, cycle_ms),
        cycle_ms,
        last_cycle_ms: None,
        live: std::collections::HashSet::new(),
    };
    shell.out.watch(watch);
    match resume {
        Some((header, records)) => {
            // The past, replayed: its trace is written again (the file then holds the whole run), nothing is
            // sent, and the run's clock goes on from wall-clock time, downtime included.
            let replayed = replay_records(&mut shell.core, &records, &mut shell.out)?;
            let wall = unix_ms().saturating_sub(header.started_unix_ms);
            shell.base_ms = replayed.last_ms.max(wall);
            if !opts.sets.is_empty() {
                eprintln!("warning: --set ignored: the run resumes from its journal with the values it had");
            }
            let now = shell.now_ms();
            shell.core.set_loss_policy(now, opts.loss_policy);
            shell.core.recover(now);
            if !opts.quiet {
                eprintln!(
                    "baton: resuming run {} of chart `{}` from its journal ({} records, {} token(s) out; {where_})",
                    run.key(),
                    loaded.pou,
                    replayed.records,
                    shell.core.core().tokens_in_flight()
                );
            }
        }
        None => {
            shell.core.set_loss_policy(0, opts.loss_policy);
            for (name, value) in &opts.sets {
                shell.core.set(0, name, value).map_err(|e| anyhow!("--set {name}: {e}"))?;
            }
            if !opts.quiet {
                eprintln!("baton: running chart `{}` as run {} ({where_})", loaded.pou, run.key());
            }
        }
    }
    let (tx, mut rx) = mpsc::unbounded_channel::<Identity>();
    // Signal streams made once: polling them each turn of the loop costs nothing.
    let mut sigterm = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
    let mut sigint = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::interrupt())?;
    let mut interrupted = false;
    shell.due_cycles().await?;
    while !shell.core.core().is_terminal() && shell.core.core().failure().is_none() {
        // Asleep until a message comes or the next cycle is due: an idle run does not wake.
        let deadline = shell.next_cycle().map(|t| shell.instant_of(t));
        let timer = async move {
            match deadline {
                Some(at) => tokio::time::sleep_until(at.into()).await,
                None => std::future::pending().await,
            }
        };
        let wake = tokio::select! {
            s = report_sub.recv_async() => s.map_or(Wake::Closed, Wake::Report),
            s = vars_sub.recv_async() => s.map_or(Wake::Closed, Wake::Vars),
            s = devices_sub.recv_async() => s.map_or(Wake::Closed, Wake::Devices),
            s = alive_sub.recv_async() => s.map_or(Wake::Closed, Wake::Alive),
            Some(ev) = rx.recv() => Wake::Identity(ev),
            q = chart_q.recv_async() => q.map_or(Wake::Closed, Wake::Chart),
            q = status_q.recv_async() => q.map_or(Wake::Closed, Wake::Status),
            q = set_q.recv_async() => q.map_or(Wake::Closed, Wake::Set),
            // A journal batch became durable: what it led to may go now.
            _ = async { durable_rx.as_mut().expect("journal").changed().await }, if durable_rx.is_some() => Wake::Durable,
            () = timer => Wake::Timer,
            _ = sigint.recv() => Wake::Stop,
            _ = sigterm.recv() => Wake::Stop,
        };
        // Cycles due run first, at their grid times, so that what arrived now comes after them.
        shell.due_cycles().await?;
        match wake {
            Wake::Report(s) => {
                shell.on_report(&s);
                while let Ok(Some(s)) = report_sub.try_recv() {
                    shell.on_report(&s);
                }
            }
            Wake::Vars(s) => shell.on_vars(&s),
            Wake::Devices(s) => shell.on_devices(&s),
            Wake::Alive(s) => shell.on_alive(&s, &tx),
            Wake::Identity(ev) => shell.on_identity(ev, &tx),
            Wake::Chart(q) => reply(&q, keys::chart(run), chart_reply.clone()).await,
            Wake::Status(q) => {
                // The run's clock now, not the time of its last input: an idle run's time goes on.
                let mut status = shell.core.core().status();
                status.t_ms = shell.now_ms();
                reply(&q, keys::status(run), wire::encode(&status)).await
            }
            Wake::Set(q) => {
                let answer = wire::encode(&shell.on_set(&q));
                match &shell.journal {
                    // Its record goes in the batch written just below; the answer waits for it.
                    Some(j) => shell.held_replies.push_back((j.sent() + 1, q, answer)),
                    None => reply(&q, keys::set(run), answer).await,
                }
            }
            Wake::Durable => shell.release().await?,
            Wake::Timer => {}
            Wake::Stop => {
                interrupted = true;
                break;
            }
            Wake::Closed => break,
        }
        shell.commit(Vec::new()).await?;
    }
    if !interrupted {
        let now = shell.now_ms();
        shell.core.end(now);
        shell.commit(Vec::new()).await?;
    }
    // Whatever was taken in is made durable and carried out before the process leaves.
    if let Some(w) = &mut shell.journal {
        w.sync().await?;
    }
    shell.release().await?;
    if let Some(w) = &mut shell.journal {
        w.close();
    }
    shell.out.finish()?;
    let failure = shell.core.core().failure().map(str::to_string);
    let summary = shell.summary(&loaded);
    drop(shell);
    session.close().await.map_err(zerr)?;
    if interrupted {
        if let Some(dir) = &opts.journal {
            eprintln!("baton: the run is kept in its journal; `baton run … --journal {}` resumes it", dir.display());
        }
        bail!("interrupted before the chart reached a terminal situation");
    }
    if let Some(why) = &failure {
        bail!("the run failed: {why}");
    }
    if let Some(p) = &opts.summary {
        let text = serde_json::to_string_pretty(&summary)?;
        std::fs::write(p, text).with_context(|| format!("cannot write {}", p.display()))?;
    }
    Ok(summary)
}

fn unix_ms() -> u64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_millis() as u64)
}

/// A journal is resumed only by the same chart version, only in a format this build reads, and only if its
/// run did not end.
fn check_resumable(
    header: &JournalHeader,
    records: &[Vec<u8>],
    loaded: &Loaded,
    hash: &ChartHash,
    chart: &std::path::Path,
    path: &str,
) -> anyhow::Result<()> {
    let pou = loaded.pou.as_str();
    if !(1..=baton_proto::limits::CYCLE_MS_MAX).contains(&header.cycle_ms) {
        bail!("the journal {path} holds a cycle period of {} ms, which no run has: it is damaged", header.cycle_ms);
    }
    if header.format != JOURNAL_FORMAT {
        bail!(
            "the journal {path} is in format {}, and this baton reads format {JOURNAL_FORMAT}; \
             give another --journal folder",
            header.format
        );
    }
    if header.chart != *hash || header.pou != pou {
        bail!(
            "the journal {path} belongs to a run of chart `{}` version {}, and {} is chart `{pou}` version {}: \
             a run only resumes with the chart it started with. Run that version again to resume it, or give \
             another --journal folder for a new run",
            header.pou,
            header.chart.0,
            chart.display(),
            hash.0
        );
    }
    check_pin(header, &loaded.program, &loaded.layout, path)?;
    if let Some(last) = records.last() {
        if let Ok(journal::Entry { record: Record::End { failure }, .. }) = journal::decode(last) {
            let how = match failure {
                Some(why) => format!("failed: {why}"),
                None => "finished".to_string(),
            };
            bail!(
                "the run {} in the journal {path} is over (it {how}); give another --journal folder for a new run",
                header.run.key()
            );
        }
    }
    Ok(())
}

/// A journal's records mean something only for the program it pins: a build of Baton that compiles the same chart
/// to other numbers would apply them to other variables and transitions.
pub fn check_pin(header: &JournalHeader, program: &Program, layout: &Layout, path: &str) -> anyhow::Result<()> {
    let pin = journal::program_pin(program, layout);
    if header.program != pin {
        bail!(
            "the journal {path} was written by a baton that compiled chart `{}` to other numbers (program {}; this \
             baton compiles it to program {pin}): its records would name other variables and transitions here. \
             Resume it with the baton that started it, or give another --journal folder for a new run",
            header.pou,
            header.program
        );
    }
    Ok(())
}

/// Answers on the queryable's own key, which names the run: a client that asked all runs (`baton/run/*/status`)
/// gets one reply per run, where replies on the query's key would be consolidated into one.
async fn reply(q: &Query, key: String, payload: Vec<u8>) {
    if let Err(e) = q.reply(key, payload).await {
        eprintln!("warning: cannot answer a query on {}: {e}", q.key_expr());
    }
}

impl Shell {
    fn now_ms(&self) -> u64 {
        self.base_ms + self.started.elapsed().as_millis() as u64
    }

    fn on_report(&mut self, s: &Sample) {
        let now = self.now_ms();
        if let Err(e) = self.core.report(now, &s.payload().to_bytes()) {
            self.decode_drop(s, e);
        }
        self.out.values(now, self.core.core());
    }

    fn on_vars(&mut self, s: &Sample) {
        let now = self.now_ms();
        if let Err(e) = self.core.vars(now, &s.payload().to_bytes()) {
            self.decode_drop(s, e);
        }
        self.out.values(now, self.core.core());
    }

    fn on_devices(&mut self, s: &Sample) {
        let now = self.now_ms();
        if let Err(e) = self.core.devices(now, &s.payload().to_bytes()) {
            self.decode_drop(s, e);
        }
    }

    fn decode_drop(&mut self, s: &Sample, e: wire::WireError) {
        self.decode_drops += 1;
        eprintln!("warning: dropped a message on {}: {e}", s.key_expr());
    }

    /// A live agent is asked for its roles before the coordinator counts on it.
    fn on_alive(&mut self, s: &Sample, tx: &mpsc::UnboundedSender<Identity>) {
        let Some(name) = keys::agent_of_alive(s.key_expr().as_str()).map(str::to_string) else { return };
        match s.kind() {
            SampleKind::Put => {
                if self.live.len() < baton_proto::limits::AGENTS_MAX {
                    self.live.insert(name.clone());
                }
                identify(self.session.clone(), name, tx.clone(), Duration::ZERO);
            }
            SampleKind::Delete => {
                self.live.remove(&name);
                let now = self.now_ms();
                self.core.agent_down(now, &name);
            }
        }
    }

    fn on_identity(&mut self, ev: Identity, tx: &mpsc::UnboundedSender<Identity>) {
        let now = self.now_ms();
        match ev {
            Identity::One(info) => self.core.agent_up(now, info),
            Identity::Several(name, n) => {
                self.core.agent_conflict(now, &name, n);
                // Asked again until one process answers alone (or none does).
                if self.live.contains(&name) {
                    identify(self.session.clone(), name, tx.clone(), CONFLICT_RECHECK);
                }
            }
            Identity::Unknown(name, why) => {
                // Its liveliness token is there, so it is asked again (a link that comes back, a process that was
                // stopped): as long as it is not known, nothing is dispatched to it.
                if self.live.contains(&name) {
                    eprintln!("warning: agent `{name}` is live but did not say who it is: {why}; asking again");
                    identify(self.session.clone(), name, tx.clone(), CONFLICT_RECHECK);
                }
            }
        }
    }

    fn on_set(&mut self, q: &Query) -> SetReply {
        let chart = self.core.core().program().name.clone();
        let request: Result<SetRequest, _> = match q.payload() {
            Some(p) => wire::decode(&p.to_bytes()),
            None => return SetReply { chart, ok: false, message: "the request carries no value".into() },
        };
        let now = self.now_ms();
        match request {
            Ok(r) => match self.core.set(now, &r.name, &r.value) {
                Ok(message) => SetReply { chart, ok: true, message },
                Err(message) => SetReply { chart, ok: false, message },
            },
            Err(e) => SetReply { chart, ok: false, message: format!("malformed request: {e}") },
        }
    }

    /// The grid time of the next cycle, if the coordinator needs one.
    fn next_cycle(&self) -> Option<u64> {
        self.core.core().next_cycle_ms(self.last_cycle_ms)
    }

    fn instant_of(&self, t_ms: u64) -> Instant {
        self.started + Duration::from_millis(t_ms.saturating_sub(self.base_ms))
    }

    /// Runs the cycles that are due, each at its grid time (one that fell far behind skips to the present), and
    /// has what they asked for carried out — at once, or once its journal batch is durable.
    async fn due_cycles(&mut self) -> anyhow::Result<()> {
        let now = self.now_ms();
        while let Some(due) = self.next_cycle().filter(|&t| t <= now) {
            let at = if now - due > CATCH_UP_CYCLES_MAX * self.cycle_ms { now - now % self.cycle_ms } else { due };
            self.last_cycle_ms = Some(at);
            self.core.cycle(at);
            self.commit(Vec::new()).await?;
        }
        Ok(())
    }

    async fn commit(&mut self, mut outputs: Vec<CoordOutput>) -> anyhow::Result<()> {
        while let Some(out) = self.core.poll_output() {
            outputs.push(out);
        }
        let records = self.core.take_records();
        // The recording's values after every input, as a replay of the journal sees them.
        let now = self.core.core().now_ms();
        self.out.values(now, self.core.core());
        outputs.extend(self.out.watched_changes(now, self.core.core()).into_iter().map(CoordOutput::Trace));
        let Some(journal) = &mut self.journal else {
            return self.carry_out(outputs).await;
        };
        if !records.is_empty() {
            let batch = journal.write(records)?;
            self.held.push_back((batch, outputs));
        } else if !outputs.is_empty() {
            // Nothing new to record: these follow the last batch.
            self.held.push_back((journal.sent(), outputs));
        }
        self.release().await
    }

    /// Carries out what waited for journal batches that are now durable, in order.
    async fn release(&mut self) -> anyhow::Result<()> {
        let durable = match &self.journal {
            Some(j) => j.durable()?,
            None => u64::MAX,
        };
        while self.held.front().is_some_and(|(batch, _)| *batch <= durable) {
            let Some((_, outputs)) = self.held.pop_front() else { break };
            self.carry_out(outputs).await?;
        }
        while self.held_replies.front().is_some_and(|(batch, _, _)| *batch <= durable) {
            let Some((_, q, answer)) = self.held_replies.pop_front() else { break };
            reply(&q, keys::set(self.core.core().run()), answer).await;
        }
        Ok(())
    }

    async fn carry_out(&mut self, outputs: Vec<CoordOutput>) -> anyhow::Result<()> {
        // Messages leave before the trace is written: a token's round trip does not wait for the disk.
        let mut local = Vec::new();
        for out in outputs {
            match out {
                CoordOutput::Send { agent, incarnation, msg } => {
                    self.send(keys::agent_cmd(&agent, incarnation), wire::encode(&msg)).await?
                }
                CoordOutput::Vars(update) => self.send(self.vars_key.clone(), wire::encode(&update)).await?,
                other => local.push(other),
            }
        }
        for out in local {
            match out {
                CoordOutput::Send { .. } | CoordOutput::Vars(_) => {}
                CoordOutput::Trace(rec) => self.out.record(rec),
                CoordOutput::Log { level, message } => {
                    let tag = match level {
                        Level::Info => "info",
                        Level::Warn => "warning",
                        Level::Error => "error",
                    };
                    if level > Level::Info || !self.quiet {
                        eprintln!("{tag}: {message}");
                    }
                }
            }
        }
        Ok(())
    }

    /// Publishes in the main loop, without a hop to another task (a hop cost a third of a token's round trip).
    /// This cannot deadlock with an agent doing the same: a put waits only while the link's queue is full, and
    /// each side's Zenoh reader hands samples to an inbox of `RECEIVE_QUEUE_MAX` without waiting for the main
    /// loop, so both sides would need that many messages unread at once.
    async fn send(&mut self, key: String, payload: Vec<u8>) -> anyhow::Result<()> {
        if !self.publishers.contains_key(&key) {
            let p = self
                .session
                .declare_publisher(key.clone())
                .congestion_control(CongestionControl::Block)
                .express(true)
                .await
                .map_err(|e| anyhow!("cannot publish on {key}: {e}"))?;
            self.publishers.insert(key.clone(), p);
        }
        if let Some(p) = self.publishers.get(&key) {
            if let Err(e) = p.put(payload).await {
                eprintln!("warning: cannot publish on {key}: {e}");
            }
        }
        Ok(())
    }

    fn summary(&self, loaded: &Loaded) -> Summary {
        let now = self.now_ms();
        let stats = self.core.core().stats();
        let steps = self
            .out
            .steps
            .iter()
            .map(|(name, (t, since))| {
                let mut t = *t;
                if let Some(t0) = since {
                    t.active_ms += now.saturating_sub(*t0);
                }
                (name.clone(), t)
            })
            .collect();
        let vars = loaded
            .program
            .vars
            .iter()
            .enumerate()
            .filter(|(_, v)| !v.constant && !v.hidden)
            .map(|(i, v)| {
                (v.name.clone(), self.core.core().value(baton_proto::exec::program::VarId(i as u32)).to_string())
            })
            .collect();
        Summary {
            chart: loaded.pou.clone(),
            run: self.core.core().run().key(),
            duration_ms: now,
            tokens_dispatched: stats.dispatched,
            tokens_returned: stats.returned,
            messages_dropped: stats.dropped + self.decode_drops,
            steps,
            vars,
            journal: self.journal.as_ref().map(crate::journal::Writer::stats),
        }
    }
}

/// After `delay`, asks agent `name` who it is and tells the main loop: one process (`AgentUp`), several
/// (`AgentConflict`), or none that makes sense.
fn identify(session: Session, name: String, tx: mpsc::UnboundedSender<Identity>, delay: Duration) {
    tokio::spawn(async move {
        tokio::time::sleep(delay).await;
        let ev = match ask_info(&session, &name).await {
            Ok(mut infos) if infos.len() == 1 => match infos.pop() {
                Some(info) if info.name == name => Identity::One(info),
                Some(info) => Identity::Unknown(name, format!("it calls itself `{}`", info.name)),
                None => Identity::Unknown(name, "no answer".to_string()),
            },
            Ok(infos) => Identity::Several(name, infos.len() as u32),
            Err(why) => Identity::Unknown(name, why),
        };
        let _ = tx.send(ev);
    });
}

/// Asks a live agent who it is, a few times: its answer may trail its liveliness token through a router. Every
/// process answering to the name replies; they are told apart by their incarnation.
async fn ask_info(session: &Session, name: &str) -> Result<Vec<AgentInfo>, String> {
    let mut last = String::new();
    for attempt in 0..INFO_QUERY_ATTEMPTS {
        match ask_info_once(session, name).await {
            Ok(infos) if !infos.is_empty() => return Ok(infos),
            Ok(_) => last = "no answer to the info query".to_string(),
            Err(why) => last = why,
        }
        tokio::time::sleep(Duration::from_millis(100 << attempt)).await;
    }
    Err(last)
}

async fn ask_info_once(session: &Session, name: &str) -> Result<Vec<AgentInfo>, String> {
    let replies = session
        .get(keys::agent_info(name))
        // Every reply, not one per key: two processes of one name answer on the same key.
        .consolidation(zenoh::query::ConsolidationMode::None)
        .timeout(INFO_QUERY_TIMEOUT)
        .await
        .map_err(|e| e.to_string())?;
    let mut infos: Vec<AgentInfo> = Vec::new();
    let mut last = String::new();
    while let Ok(reply) = replies.recv_async().await {
        let info = match reply.result() {
            Ok(sample) => wire::decode::<AgentInfo>(&sample.payload().to_bytes()).map_err(|e| e.to_string()),
            Err(e) => Err(format!("{e:?}")),
        };
        match info {
            Ok(info) if !infos.iter().any(|i| i.incarnation == info.incarnation) => infos.push(info),
            Ok(_) => {}
            Err(why) => last = why,
        }
        if infos.len() >= INFO_REPLIES_MAX {
            break;
        }
    }
    if infos.is_empty() && !last.is_empty() {
        return Err(last);
    }
    Ok(infos)
}

impl Summary {
    pub fn print(&self) {
        println!("chart `{}` finished in {} ms", self.chart, self.duration_ms);
        println!(
            "tokens: {} dispatched, {} returned; {} message(s) dropped",
            self.tokens_dispatched, self.tokens_returned, self.messages_dropped
        );
        println!("{:<24} {:>11} {:>14}", "step", "activations", "active ms");
        for (name, t) in &self.steps {
            println!("{name:<24} {:>11} {:>14}", t.activations, t.active_ms);
        }
        let vars: Vec<String> = self.vars.iter().map(|(k, v)| format!("{k} = {v}")).collect();
        println!("variables: {}", vars.join(", "));
        if let Some(j) = &self.journal {
            println!("journal: {} records in {} commits", j.records, j.commits);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn options(chart: PathBuf, journal: PathBuf) -> RunOptions {
        RunOptions {
            chart,
            pou: None,
            listen: vec!["tcp/127.0.0.1:0".into()],
            connect: Vec::new(),
            trace: None,
            summary: None,
            cycle_ms: 10,
            sets: Vec::new(),
            multicast_scouting: false,
            quiet: true,
            zenoh_config: None,
            loss_policy: LossPolicy::Pause,
            journal: Some(journal),
            rerun: crate::recording::Sink::Off,
            watch: Vec::new(),
        }
    }

    /// The same chart text, compiled by a baton that numbers its program otherwise (simulated by a journal whose
    /// pin is not this build's): resuming it would apply the records to other variables, so it is refused.
    #[tokio::test(flavor = "multi_thread", worker_threads = 1)]
    async fn a_journal_of_another_compilation_is_not_resumed() {
        let dir = tempfile::tempdir().expect("temp dir");
        let chart = dir.path().join("wait.st");
        let source = "PROGRAM wait\nVAR go : BOOL; END_VAR\nINITIAL_STEP A: END_STEP\n\
                      TRANSITION FROM A TO B := go; END_TRANSITION\nSTEP B: END_STEP\nEND_PROGRAM\n";
        std::fs::write(&chart, source).expect("write the chart");
        let loaded = load(&chart, None).expect("a valid chart");
        let pin = journal::program_pin(&loaded.program, &loaded.layout);
        let other = format!("{}{}", if pin.starts_with('0') { '1' } else { '0' }, &pin[1..]);
        let header = JournalHeader {
            format: JOURNAL_FORMAT,
            run: RunId(uuid::Uuid::from_u128(3)),
            chart: ChartHash::of(source, "wait"),
            pou: "wait".into(),
            source: source.into(),
            started_unix_ms: 1,
            cycle_ms: 10,
            program: other.clone(),
        };
        let journal_dir = dir.path().join("journal");
        let mut opened = crate::journal::open(&journal_dir).expect("a new journal");
        opened.store.write_header(&header).expect("header");
        drop(opened);
        let err = run(options(chart, journal_dir.clone())).await.err().expect("refused").to_string();
        assert!(err.contains("compiled chart `wait` to other numbers") && err.contains(&other), "{err}");
        assert!(err.contains(&pin), "the message names both programs: {err}");
        // baton replay refuses it as well.
        let replay =
            crate::replay::ReplayOptions { journal: journal_dir, rerun: crate::recording::Sink::Off, trace: None };
        let err = crate::replay::replay(&replay).expect_err("refused").to_string();
        assert!(err.contains("to other numbers"), "{err}");
    }
}
