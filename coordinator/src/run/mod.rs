//! `baton run`: the coordinator's Zenoh host. It turns samples into inputs of the pure `Coordinator`, runs its
//! cycles, publishes what it asks for, writes the trace and answers the chart, status and set queries. It
//! decides nothing about charts: every rule lives in `baton_proto::cluster::runtime::coordinator`.
//!
//! With `--journal DIR`, every input is recorded (`baton_proto::cluster::journal::Journaled`) and what the coordinator
//! asks for is held back until the records that led to it are durable (`crate::journal`, group commit). A
//! journal of a run that did not end is resumed: replayed, then reconciled with the agents.

pub(crate) mod feed;
mod host;
mod records;
mod resume;
mod summary;

use std::collections::VecDeque;
use std::fs::File;
use std::io::BufWriter;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{anyhow, bail, Context};
use baton_host::ZenohResult;
use baton_proto::cluster::journal::{self, JournalHeader, Journaled, JOURNAL_FORMAT};
use baton_proto::cluster::keys;
use baton_proto::cluster::netconfig::NetConfig;
use baton_proto::cluster::runtime::coordinator::LossPolicy;
use baton_proto::cluster::wire::{self, ChartHash, ChartSource, RunId};
use baton_proto::exec::program::VarId;
use tokio::sync::{mpsc, watch};

use crate::chart_file::{load, Loaded};

use baton_host::unix_ms;
use host::{releasing, reply, Callbacks, Host, Identity, Inboxes, Wake};
use resume::{check_resumable, end_of, resume_segments, trace_lines};

pub use records::{Probe, Records};
pub use resume::{check_pin, how_it_ended, replay_segments};
pub use summary::Summary;

#[derive(Clone)]
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
    /// Record every input in this folder (or in etcd) before acting on it; resume the run found there.
    pub journal: Option<crate::journal::Place>,
    /// When the journal gets a snapshot, and how many of its segments are kept.
    pub journal_settings: crate::journal::Settings,
    /// Where the run's Rerun recording goes.
    pub rerun: crate::recording::Sink,
    /// Variables whose value the trace records: once after the first cycle and after every change.
    pub watch: Vec<String>,
    /// Wait in Idle, the chart not started, for an operator's `baton ctl start`.
    pub wait_start: bool,
    /// Stay at the run's end for `clear` and `reset` (`--stay`).
    pub stay: bool,
    /// After an abort, how long to wait for agents that could not be told of it.
    pub abort_wait_ms: u64,
    /// Serve the operator console on this loopback address (`--console`).
    pub console: Option<std::net::SocketAddr>,
    /// Stand in this election on etcd, with a lease of this many seconds, and coordinate only while winning it.
    pub election: Option<(crate::election::Election, u64)>,
}

pub async fn run(opts: RunOptions) -> anyhow::Result<Summary> {
    run_with(opts, None).await
}

pub async fn run_with(opts: RunOptions, probe: Option<Probe>) -> anyhow::Result<Summary> {
    let loaded = load(&opts.chart, opts.pou.as_deref())?;
    if opts.listen.is_empty() == opts.connect.is_empty() {
        bail!("give either --listen ENDPOINT (embed a router) or --connect ENDPOINT (join one)");
    }
    let hash = ChartHash::of(&loaded.source, &loaded.pou);
    let watch = watched(&loaded.program, &opts.watch)?;
    // The console's port next: taken, the run does not start.
    let console = match opts.console {
        Some(addr) => Some(crate::console::bind_local(addr).await?),
        None => None,
    };
    // A standby waits here, before it touches the journal, until it wins.
    let won = elected(&opts).await?;
    // The journal first: a refused one costs nothing, not even a Zenoh session.
    let Opened { run, started_unix_ms, resume, store } = open_journal(&opts, &loaded, &hash, won.as_ref())?;
    let net =
        if opts.listen.is_empty() { NetConfig::client(&opts.connect, true) } else { NetConfig::router(&opts.listen) };
    let net = NetConfig { multicast_scouting: opts.multicast_scouting, ..net };
    let zconfig = baton_host::zenoh_config(&net, opts.zenoh_config.as_deref())?;
    let session = zenoh::open(zconfig).await.map_err(|e| anyhow!("cannot open a Zenoh session: {e}"))?;
    // Once the election is lost, nothing the journal made durable is sent any more.
    let deliver = match &won {
        Some(won) => host::deliver_while(host::deliver_through(&session), Arc::clone(&won.acting)),
        None => host::deliver_through(&session),
    };
    let writer = store.map(|store| store.start_writer(Some(deliver)));
    let console = console.map(|listener| {
        let endpoints = crate::console::endpoints_of(&opts.listen, &opts.connect);
        crate::console::spawn(listener, endpoints, opts.zenoh_config.clone())
    });
    // A resumed run keeps the period it started with.
    let cycle_ms = match &resume {
        Some(Resume { header, .. }) => {
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
    // A run resumed from a snapshot is the coordinator the snapshot holds; any other starts from the chart.
    let fresh =
        || Journaled::start(Arc::clone(&loaded.program), Arc::clone(&loaded.layout), run, hash.clone(), cycle_ms);
    let (resume, core, meta) = match resume {
        Some(Resume { header, snapshot: Some((core, meta)), segments }) => {
            (Some(Resume { header, snapshot: Some(meta.clone()), segments }), core, Some(meta))
        }
        Some(Resume { header, snapshot: None, segments }) => {
            (Some(Resume { header, snapshot: None, segments }), fresh(), None)
        }
        None => (None, fresh(), None),
    };
    let trace = match &opts.trace {
        Some(p) => Some(open_trace(p, meta.as_ref().map(|m| m.trace_records))?),
        None => None,
    };
    let where_ = if opts.listen.is_empty() {
        format!("joined {}", opts.connect.join(", "))
    } else {
        format!("router on {}", opts.listen.join(", "))
    };
    let recorder = crate::recording::Recorder::start(
        &opts.rerun,
        crate::recording::RecordedRun {
            program: Arc::clone(&loaded.program),
            layout: Arc::clone(&loaded.layout),
            run: run.key(),
            started_unix_ms,
        },
    )?;
    let mut out = Records::new(trace, probe, recorder, cycle_ms);
    out.feed = Some(feed::Feed::declare(&session, run).await?);
    let mut host = Host {
        session: session.clone(),
        core,
        started: Instant::now(),
        base_ms: 0,
        journal: writer,
        snapshot_every: opts.journal_settings.snapshot_every,
        snapshot_due: opts.journal_settings.snapshot_every,
        held: VecDeque::new(),
        held_replies: VecDeque::new(),
        quiet: opts.quiet,
        term: won.as_ref().map_or(0, |w| w.term),
        outbox: baton_host::Outbox::new(&session),
        vars_key: keys::vars(run, baton_proto::cluster::runtime::COORDINATOR),
        cmd_keys: host::CmdKeys::default(),
        decode_drops: 0,
        out,
        cycle_ms,
        last_cycle_ms: None,
        live: std::collections::HashSet::new(),
        answers: None,
        asking: std::collections::HashSet::new(),
        armed: None,
        failed: None,
    };
    host.core.watch(watch);
    begin(&mut host, resume, &opts, &loaded, run, &where_)?;
    let shared = baton_host::Shared::new(host);
    let lost = won.as_ref().map(|w| w.lost.clone());
    let ended = serve(&shared, &session, chart_reply, opts.abort_wait_ms, lost).await?;
    let summary = wind_down(shared.take()?, session, console, &opts, &loaded, ended).await;
    // Over, or left by a SIGTERM: a standby need not wait for the lease to end. (Deposed: it is not ours to give.)
    if let (Some(won), false) = (won, ended == Ended::Deposed) {
        won.resign().await;
    }
    summary
}

/// With `--election`: waits, standing by, until this coordinator wins the run's election.
async fn elected(opts: &RunOptions) -> anyhow::Result<Option<crate::election::Won>> {
    let Some((election, lease_s)) = &opts.election else { return Ok(None) };
    let candidate = format!("{} (pid {})", crate::client::who(), std::process::id());
    let won = crate::election::win(election, *lease_s, &candidate, opts.quiet).await?;
    if !opts.quiet {
        eprintln!("baton: won the election on etcd: coordinating at term {}", won.term);
    }
    Ok(Some(won))
}

/// The variables `--watch` names, each a variable of `program`.
pub fn watched(program: &baton_proto::exec::program::Program, names: &[String]) -> anyhow::Result<Vec<VarId>> {
    let var = |name: &String| {
        program
            .var_by_name(name)
            .ok_or_else(|| anyhow!("--watch {name}: chart `{}` has no variable `{name}`", program.name))
    };
    names.iter().map(var).collect()
}

/// What `baton run` does with a journal before it serves — open it, restore its last snapshot, replay the records
/// after it — without a network, for `baton bench`: the records replayed. (The journal is left as it was.)
pub fn resume_offline(opts: &RunOptions) -> anyhow::Result<u64> {
    let loaded = load(&opts.chart, opts.pou.as_deref())?;
    let hash = ChartHash::of(&loaded.source, &loaded.pou);
    let Opened { resume: Some(Resume { header, snapshot, segments }), .. } = open_journal(opts, &loaded, &hash, None)?
    else {
        bail!("no run to resume");
    };
    let mut core = match snapshot {
        Some((core, _)) => core,
        None => Journaled::start(loaded.program, loaded.layout, header.run, hash, header.cycle_ms),
    };
    let mut out = Records::new(None, None, None, header.cycle_ms);
    Ok(replay_segments(&mut core, &segments, &mut out, "")?.records)
}

/// Starts the run afresh (with `--set`'s values), or resumes it: the past replayed from the journal (its trace
/// written again, so that the file holds the whole run), nothing sent, the clock going on from wall-clock time.
fn begin(
    host: &mut Host,
    resume: Option<Resume<journal::SnapshotMeta>>,
    opts: &RunOptions,
    loaded: &Loaded,
    run: RunId,
    where_: &str,
) -> anyhow::Result<()> {
    match resume {
        Some(Resume { header, snapshot, segments }) => {
            // The past, replayed from the snapshot on (the coordinator is the snapshot's already): its trace is
            // written again after the records the trace file kept, nothing is sent, and the run's clock goes on
            // from wall-clock time, downtime included.
            let from = match &snapshot {
                Some(meta) => {
                    host.out.steps = serde_json::from_value(meta.host.clone()).unwrap_or_default();
                    format!("its snapshot at record {} and ", meta.records)
                }
                None => String::new(),
            };
            host.snapshot_due = host.core.records_counted() + host.snapshot_every;
            let path = opts.journal.as_ref().map_or(String::new(), ToString::to_string);
            let replayed = replay_segments(&mut host.core, &segments, &mut host.out, &path)?;
            let wall = unix_ms().saturating_sub(header.started_unix_ms);
            let last_ms = snapshot.as_ref().map_or(0, |m| m.last_ms);
            host.base_ms = replayed.last_ms.max(last_ms).max(wall);
            if !opts.sets.is_empty() {
                eprintln!("warning: --set ignored: the run resumes from its journal with the values it had");
            }
            let now = host.now_ms();
            host.core.set_loss_policy(now, opts.loss_policy);
            host.core.recover(now);
            if !opts.quiet {
                eprintln!(
                    "baton: resuming run {} of chart `{}` from its journal ({from}{} records, {} token(s) out; \
                     {where_})",
                    run.key(),
                    loaded.pou,
                    replayed.records,
                    host.core.core().tokens_in_flight()
                );
            }
        }
        None => {
            host.core.set_loss_policy(0, opts.loss_policy);
            if opts.stay {
                host.core.stay(0);
            }
            if opts.wait_start {
                host.core.wait_start(0);
            }
            for (name, value) in &opts.sets {
                host.core.set(0, name, value).map_err(|e| anyhow!("--set {name}: {e}"))?;
            }
            if !opts.quiet {
                eprintln!("baton: running chart `{}` as run {} ({where_})", loaded.pou, run.key());
            }
        }
    }
    Ok(())
}

/// A run's identity and where its journal stands: a new run's header written, or a resumable one's records.
struct Opened {
    run: RunId,
    started_unix_ms: u64,
    resume: Option<Resume<(Journaled, journal::SnapshotMeta)>>,
    store: Option<crate::journal::Store>,
}

/// A run to resume: its header, the snapshot it resumes from (`S`: restored, then what it said), and the segments
/// to replay (from that snapshot's on).
struct Resume<S> {
    header: JournalHeader,
    snapshot: Option<S>,
    segments: Vec<crate::journal::Segment>,
}

/// The trace file: a new one, or — for a run resumed from a snapshot — the one the run wrote, cut back to the
/// `kept` records made before the snapshot (the replay of the records after it writes the rest again). So the
/// file holds the whole run, as the live run wrote it, when it still holds what was written before the snapshot.
fn open_trace(path: &std::path::Path, kept: Option<u64>) -> anyhow::Result<BufWriter<File>> {
    let cannot = || format!("cannot open the trace {}", path.display());
    let Some(kept) = kept else {
        return Ok(BufWriter::new(File::create(path).with_context(cannot)?));
    };
    let mut file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(path)
        .with_context(cannot)?;
    let mut bytes = Vec::new();
    std::io::Read::read_to_end(&mut file, &mut bytes).with_context(cannot)?;
    let ends = bytes.iter().enumerate().filter(|(_, b)| **b == b'\n').map(|(i, _)| i + 1);
    let (lines, end) = ends.take(kept as usize).fold((0u64, 0usize), |(n, _), at| (n + 1, at));
    if lines < kept {
        eprintln!(
            "warning: the trace {} holds {lines} of the {kept} records the run made before its journal's snapshot: \
             the records after the snapshot follow them (with `--journal-keep all`, `baton replay` rebuilds it whole)",
            path.display()
        );
    }
    file.set_len(end as u64).with_context(cannot)?;
    std::io::Seek::seek(&mut file, std::io::SeekFrom::Start(end as u64)).with_context(cannot)?;
    Ok(BufWriter::new(file))
}

/// Opens `--journal`, if given: a new journal gets its header, an old one is checked and its records read. One in
/// etcd is written under the fence of the election `won`.
fn open_journal(
    opts: &RunOptions,
    loaded: &Loaded,
    hash: &ChartHash,
    won: Option<&crate::election::Won>,
) -> anyhow::Result<Opened> {
    let Some(place) = &opts.journal else {
        return Ok(Opened { run: RunId(uuid::Uuid::new_v4()), started_unix_ms: unix_ms(), resume: None, store: None });
    };
    let mut opened = crate::journal::open(place, won.map(crate::election::Won::fence))?;
    opened.store.keep(opts.journal_settings.keep);
    let path = opened.store.shown();
    let (run, started_unix_ms, resume) = match opened.header.take() {
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
            (header.run, header.started_unix_ms, None)
        }
        Some(header) => {
            check_resumable(&header, loaded, hash, &opts.chart, &path)?;
            let (run, started) = (header.run, header.started_unix_ms);
            let ended = end_of(&opened.records);
            let last = crate::journal::Segment {
                number: opened.store.number(),
                snapshot: opened.snapshot.take(),
                records: std::mem::take(&mut opened.records),
            };
            let segments = resume_segments(&opened.store, last, opts.trace.as_deref().map(trace_lines))?;
            let snapshot = match segments.first().and_then(|s| s.snapshot.as_deref()) {
                Some(bytes) => {
                    let (program, layout) = (Arc::clone(&loaded.program), Arc::clone(&loaded.layout));
                    let restored = Journaled::restore(program, layout, bytes)
                        .map_err(|why| anyhow!("cannot resume from the journal {path}: its snapshot {why}"))?;
                    Some(restored)
                }
                None => None,
            };
            if let Some(failure) = ended {
                // Over: replayed (with nothing written) to say how — completed, stopped, aborted or failed.
                let mut core = match segments.first().and_then(|s| s.snapshot.as_deref()) {
                    Some(bytes) => {
                        Journaled::restore(Arc::clone(&loaded.program), Arc::clone(&loaded.layout), bytes)
                            .map_err(|why| anyhow!("cannot read the journal {path}: its snapshot {why}"))?
                            .0
                    }
                    None => Journaled::start(
                        Arc::clone(&loaded.program),
                        Arc::clone(&loaded.layout),
                        run,
                        hash.clone(),
                        header.cycle_ms,
                    ),
                };
                let mut out = Records::new(None, None, None, header.cycle_ms);
                replay_segments(&mut core, &segments, &mut out, &path)?;
                return Err(RunOver(format!(
                    "the run {} in the journal {path} is over (it {})",
                    header.run.key(),
                    how_it_ended(core.core().run_state(), failure.as_deref())
                ))
                .into());
            }
            (run, started, Some(Resume { header, snapshot, segments }))
        }
    };
    Ok(Opened { run, started_unix_ms, resume, store: Some(opened.store) })
}

/// The journal's run is over: `baton run` refuses to start on it — unless it stood in an election, where a standby
/// that wins after the run ended has nothing to take over, and leaves.
#[derive(Debug)]
pub struct RunOver(pub String);

impl std::fmt::Display for RunOver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}; give another --journal folder for a new run", self.0)
    }
}

impl std::error::Error for RunOver {}

/// How the main loop ended.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Ended {
    /// The chart reached a terminal situation, failed, was stopped or aborted.
    Ran,
    /// Zenoh closed an inbox: the run is left as it stands (its journal resumes it).
    Closed,
    /// SIGTERM with a journal: the process goes away (a service stopped or restarted, a reboot) and leaves the run
    /// as it stands, for the coordinator that starts on its journal next — as after a crash, the agents keep their
    /// tokens, and nothing is ended.
    Left,
    /// The coordinator's election was lost (or about to be): it stops acting at once, sends nothing more, and
    /// leaves the run to the standby that wins.
    Deposed,
}

/// Why the election was lost, once it is; never without one.
async fn deposed(lost: &mut Option<watch::Receiver<Option<String>>>) -> String {
    let Some(lost) = lost else { return std::future::pending().await };
    match lost.wait_for(Option::is_some).await {
        Ok(why) => why.clone().unwrap_or_default(),
        Err(_) => "the election's watch ended".to_string(),
    }
}

/// Who an interrupt comes from, in the trace: the user and host of this process.
fn signal_sender(signal: &str) -> String {
    format!("{} ({signal})", crate::client::who())
}

/// Whether the main loop goes on: until the run is over — unless it stays at its end (`--stay`), or an abort left
/// agents that could not be told, which are waited for until `tell_until` (set here when that wait begins).
fn keeps_serving(host: &Host, tell_until: &mut Option<Instant>, abort_wait_ms: u64) -> bool {
    let core = host.core.core();
    if !core.is_over() || (core.stays() && core.failure().is_none()) {
        return true;
    }
    let untold: Vec<&str> = core.untold_agents().collect();
    if untold.is_empty() {
        return false;
    }
    let until = *tell_until.get_or_insert_with(|| {
        if !host.quiet {
            eprintln!(
                "baton: the run is {}; waiting up to {abort_wait_ms} ms to tell {} of it (interrupt to leave now)",
                core.run_state().name(),
                untold.join(", ")
            );
        }
        Instant::now() + std::time::Duration::from_millis(abort_wait_ms)
    });
    if Instant::now() < until {
        return true;
    }
    eprintln!(
        "baton: warning: {} never heard of the end of the run: what they still run of it goes on",
        untold.join(", ")
    );
    false
}

/// The main loop: asleep until a query comes, a callback has something for it, or the next cycle is due. A run's
/// messages from agents are handled in Zenoh's callbacks (`Callbacks`), under the same lock.
async fn serve(
    shared: &Arc<baton_host::Shared<Host>>,
    session: &zenoh::Session,
    chart_reply: Vec<u8>,
    abort_wait_ms: u64,
    mut lost: Option<watch::Receiver<Option<String>>>,
) -> anyhow::Result<Ended> {
    // A resumed journal may have gone on to a later run than its header's (a `reset`).
    let mut run = shared.lock()?.core.core().run();
    let mut inboxes = Inboxes::declare(session, run).await?;
    let (tx, mut rx) = mpsc::unbounded_channel::<Identity>();
    {
        let mut host = shared.lock()?;
        host.vars_key = keys::vars(run, baton_proto::cluster::runtime::COORDINATOR);
        host.answers = Some(tx.clone());
        host.due_cycles()?;
        if let Some(journal) = &host.journal {
            journal.on_durable(releasing(shared));
        }
        // What beginning the run made (a run waiting for its start: its `idle` state and the journal's record of
        // it) is written now, not with whatever happens next.
        host.commit(Vec::new())?;
    }
    let mut callbacks = Callbacks::declare(session, run, shared).await?;
    let mut stop = baton_host::Stop::new()?;
    let mut interrupts = 0;
    let mut tell_until = None;
    let mut deadline = match next_wake(&mut *shared.lock()?, &mut tell_until, abort_wait_ms)? {
        Some(deadline) => deadline,
        None => return Ok(Ended::Ran),
    };
    loop {
        let wake = tokio::select! {
            s = inboxes.alive.recv_async() => s.map_or(Wake::Closed, Wake::Alive),
            Some(ev) = rx.recv() => Wake::Identity(ev),
            q = inboxes.chart.recv_async() => q.map_or(Wake::Closed, Wake::Chart),
            q = inboxes.status.recv_async() => q.map_or(Wake::Closed, Wake::Status),
            q = inboxes.set.recv_async() => q.map_or(Wake::Closed, Wake::Set),
            q = inboxes.ctl.recv_async() => q.map_or(Wake::Closed, Wake::Ctl),
            () = baton_host::until(deadline) => Wake::Timer,
            () = shared.rearmed() => Wake::Look,
            signal = stop.recv() => Wake::Stop(signal),
            why = deposed(&mut lost) => {
                shared.lock()?.stopped_acting(&why);
                return Ok(Ended::Deposed);
            }
        };
        // Taken under the lock, with no wait in it, and the next deadline with it (one hold a wake-up: a hold
        // makes the callbacks that come meanwhile queue their messages); a reset's new inboxes are declared after.
        let (reset, wake_at) = {
            let mut host = shared.lock()?;
            // Cycles due run first, at their grid times, so that what arrived now comes after them.
            host.due_cycles()?;
            match wake {
                Wake::Alive(s) => host.on_alive(&s, &tx),
                Wake::Identity(ev) => host.on_identity(ev, &tx),
                Wake::Chart(q) => reply(&q, keys::chart(run), chart_reply.clone()),
                Wake::Status(q) => {
                    // The run's clock now, not the time of its last input: an idle run's time goes on.
                    let mut status = host.core.core().status();
                    status.t_ms = host.now_ms();
                    status.unix_ms = baton_host::unix_ms();
                    status.rerun = host.out.recorder.as_ref().and_then(|r| r.served()).map(str::to_string);
                    status.messages_dropped += host.decode_drops;
                    reply(&q, keys::status(run), wire::encode(&status))
                }
                Wake::Set(q) => host.on_set_query(q, run),
                Wake::Ctl(q) => host.on_ctl_query(q, run),
                Wake::Timer | Wake::Look => {}
                Wake::Stop(baton_host::Signal::Terminate) if host.journal.is_some() => {
                    if !host.quiet {
                        eprintln!("baton: SIGTERM: leaving the run as it stands, for its journal to resume");
                    }
                    return Ok(Ended::Left);
                }
                Wake::Stop(_) if host.core.core().is_over() => {
                    // At the end of a run that stays, or waiting for agents to tell: the process leaves.
                    return Ok(Ended::Ran);
                }
                Wake::Stop(signal) => {
                    interrupts += 1;
                    interrupted(&mut host, signal, interrupts);
                }
                Wake::Closed => return Ok(Ended::Closed),
            }
            host.commit(Vec::new())?;
            let reset = host.new_run_if_reset()?;
            (reset, next_wake(&mut host, &mut tell_until, abort_wait_ms)?)
        };
        if let Some(next) = reset {
            inboxes = Inboxes::declare(session, next).await?;
            callbacks = Callbacks::declare(session, next, shared).await?;
            run = next;
            interrupts = 0;
        }
        match wake_at {
            Some(at) => deadline = at,
            None => break,
        }
    }
    drop(callbacks);
    Ok(Ended::Ran)
}

/// When the main loop must wake next if nothing comes (`None` inside: never, an idle run), armed for the
/// callbacks to compare with; `None` once the run is no longer served. A callback's failure ends the loop with it.
fn next_wake(
    host: &mut Host,
    tell_until: &mut Option<Instant>,
    abort_wait_ms: u64,
) -> anyhow::Result<Option<Option<Instant>>> {
    if let Some(e) = host.failed.take() {
        return Err(e);
    }
    if !keeps_serving(host, tell_until, abort_wait_ms) {
        return Ok(None);
    }
    let deadline = host.next_cycle().map(|t| host.instant_of(t)).into_iter().chain(*tell_until).min();
    host.armed = deadline;
    Ok(Some(deadline))
}

/// An interrupt: the first stops the run (what runs finishes, nothing new starts), the next aborts it. So does
/// SIGTERM without a journal: no coordinator could take the run up again.
fn interrupted(host: &mut Host, signal: baton_host::Signal, interrupts: u32) {
    let command = if interrupts == 1 { "stop" } else { "abort" };
    let request = baton_proto::cluster::wire::CtlRequest {
        command: command.into(),
        target: None,
        agent: None,
        step: None,
        for_ms: None,
        to: None,
        reason: "interrupted".into(),
        by: signal_sender(match signal {
            baton_host::Signal::Interrupt => "SIGINT",
            baton_host::Signal::Terminate => "SIGTERM",
        }),
        user: None,
    };
    if !host.quiet {
        let what = if interrupts == 1 {
            "stopping: running skills finish, nothing new starts (interrupt again to abort)"
        } else {
            "aborting: running skills are cancelled"
        };
        eprintln!("baton: interrupted, {what}");
    }
    if let Err(why) = host.command(request) {
        eprintln!("baton: {command} refused: {why}");
    }
}

/// Ends the run (unless interrupted), makes durable and carries out whatever was taken in, and says how it went.
async fn wind_down(
    mut host: Host,
    session: zenoh::Session,
    console: Option<crate::console::Background>,
    opts: &RunOptions,
    loaded: &Loaded,
    ended: Ended,
) -> anyhow::Result<Summary> {
    if ended == Ended::Ran {
        // The run's end is its journal's last record: no snapshot after it.
        host.snapshot_every = 0;
        let now = host.now_ms();
        host.core.end(now);
        host.commit(Vec::new())?;
    }
    // Whatever was taken in is made durable and carried out before the process leaves — unless another coordinator
    // may be acting already.
    let mut ended = ended;
    if ended != Ended::Deposed {
        if let Some(w) = &mut host.journal {
            match w.sync().await {
                // etcd refused the last commits: another coordinator holds the election, and goes on from it.
                Err(e) if e.is::<crate::journal::Fenced>() => {
                    host.stopped_acting(&e.to_string());
                    ended = Ended::Deposed;
                }
                synced => synced?,
            }
        }
    }
    if ended != Ended::Deposed {
        host.release()?;
    }
    if let Some(w) = &mut host.journal {
        w.close();
    }
    host.out.finish()?;
    let failure = host.core.core().failure().map(str::to_string);
    let mut summary = host.summary(loaded);
    summary.left = matches!(ended, Ended::Left | Ended::Deposed);
    summary.deposed = ended == Ended::Deposed;
    let tokens_out = host.core.core().tokens_in_flight();
    drop(host);
    // The console is a client of this session's router: it goes first, once the replies released above had
    // their moment to reach it.
    if let Some(console) = console {
        console.stop().await;
    }
    session.close().await.zenoh()?;
    if ended != Ended::Ran {
        if let Some(dir) = &opts.journal {
            eprintln!(
                "baton: run {} is kept in its journal ({} token(s) out, their agents keep them); `baton run {} … \
                 --journal {}` resumes it",
                summary.run,
                tokens_out,
                opts.chart.display(),
                dir
            );
        }
    }
    if ended == Ended::Closed {
        bail!("the Zenoh session closed before the chart reached a terminal situation");
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
            journal: Some(crate::journal::Place::Dir(journal)),
            journal_settings: Default::default(),
            rerun: crate::recording::Sink::Off,
            watch: Vec::new(),
            wait_start: false,
            stay: false,
            abort_wait_ms: 0,
            console: None,
            election: None,
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
        let place = crate::journal::Place::Dir(journal_dir.clone());
        let mut opened = crate::journal::open(&place, None).expect("a new journal");
        opened.store.write_header(&header).expect("header");
        drop(opened);
        let err = run(options(chart, journal_dir.clone())).await.err().expect("refused").to_string();
        assert!(err.contains("compiled chart `wait` to other numbers") && err.contains(&other), "{err}");
        assert!(err.contains(&pin), "the message names both programs: {err}");
        // baton replay refuses it as well.
        let replay = crate::replay::ReplayOptions {
            journal: place,
            rerun: crate::recording::Sink::Off,
            trace: None,
            watch: Vec::new(),
        };
        let err = crate::replay::replay(&replay).expect_err("refused").to_string();
        assert!(err.contains("to other numbers"), "{err}");
    }
}
