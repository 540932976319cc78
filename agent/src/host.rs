//! The agent's Zenoh host: announces the agent, takes tokens, runs `AgentRun` state machines and skills, and
//! reports back. It decides nothing about charts: every rule lives in `baton_proto::cluster::runtime::agent`.
//!
//! # Rules the hosts keep
//!
//! - Agents declare their info queryable and command subscriber before their liveliness token, so a coordinator that
//!   sees the token can use them at once.
//!
//! The host's Zenoh plumbing that the coordinator shares (settings, inboxes, the outbox, the loop's waits) is
//! `baton_host`, with the rules it keeps.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::anyhow;
use baton_proto::cluster::keys;
use baton_proto::cluster::keys::is_valid_name;
use baton_proto::cluster::layout::Layout;
use baton_proto::cluster::netconfig::NetConfig;
use baton_proto::cluster::runtime::agent::{AgentOutput, AgentRun, NotTaken};
use baton_proto::cluster::runtime::Level;
use baton_proto::cluster::wire::{self, AgentInfo, ChartHash, ChartSource, HeldToken, RunId, ToAgent, VarUpdate};
use baton_proto::exec::program::{ActionId, Program};
use baton_proto::exec::trace::TraceEvent;
use baton_proto::limits::{fence_after_ms, fence_check_ms, CHART_SOURCE_BYTES_MAX};
use baton_proto::pipeline::check_source;
use tokio::sync::{mpsc, watch};
use zenoh::sample::{Locality, Sample};
use zenoh::Session;

use baton_host::{traffic, ZenohResult};

use crate::connections::Connections;
use crate::roles::{refused_role, LIVELINESS_CHECK_TIMEOUT};
use crate::skill::{SkillCall, SkillContext, SkillFuture, Skills, STOP_WAIT_MAX};
use baton_proto::types::Value;

/// Runs an agent takes part in at once; the oldest idle run is forgotten to make room.
const RUNS_MAX: usize = 64;
/// Dispatches kept while the chart of their run is fetched.
const PENDING_DISPATCHES_MAX: usize = 1024;
const CHART_FETCH_TIMEOUT: Duration = Duration::from_secs(5);
/// How long the agent waits for its router before it says that it waits.
const ROUTER_WAIT_NOTICE: Duration = Duration::from_secs(3);
/// Held tokens listed in the info reply; a coordinator sends the dispatch of any other again, which the agent
/// recognises as a duplicate.
const HELD_LISTED_MAX: usize = 4096;

#[derive(Clone, Debug)]
pub struct AgentConfig {
    pub name: String,
    pub roles: Vec<String>,
    pub connect: Vec<String>,
    pub lease_ms: u64,
    /// Print every log line, not only warnings and errors.
    pub verbose: bool,
    /// The user's own Zenoh configuration file (TLS, credentials), under Baton's settings.
    pub zenoh_config: Option<std::path::PathBuf>,
    /// Where the agent remembers, across its restarts, the highest coordinator term each run has shown it
    /// (`terms.rs`); `None`: nowhere, a restarted agent knows none.
    pub state_dir: Option<std::path::PathBuf>,
}

impl AgentConfig {
    pub fn validate(&self) -> anyhow::Result<()> {
        for n in std::iter::once(&self.name).chain(&self.roles) {
            if !is_valid_name(n) {
                anyhow::bail!("`{n}` is not a valid agent name or role: use letters, digits, `_` and `-` (at most 64)");
            }
        }
        if self.name == baton_proto::cluster::runtime::COORDINATOR {
            anyhow::bail!("`{}` is the name the coordinator publishes under: choose another agent name", self.name);
        }
        if self.lease_ms < 100 {
            anyhow::bail!("--lease-ms must be at least 100");
        }
        if self.connect.is_empty() {
            anyhow::bail!("give the router's endpoint with --connect, such as tcp/127.0.0.1:7447");
        }
        // With a TLS certificate, the agent is who its certificate says: under another name it would claim an
        // identity it cannot prove (and the router's access control, which matches the certificate, would refuse
        // it what the name needs).
        if let Some(file) = self.zenoh_config.as_deref() {
            if let Some((cert, cn)) = baton_host::certificate_identity(file) {
                if cn != self.name {
                    anyhow::bail!(
                        "the certificate {} is `{cn}`'s: this agent cannot run as `{}` with it (--name {cn}, or the \
                         certificate of `{}`)",
                        cert.display(),
                        self.name,
                        self.name
                    );
                }
            }
        }
        Ok(())
    }
}

/// A chart fetched from its coordinator, compiled: its version, program, layout and cycle period.
type Fetched = (ChartHash, Arc<Program>, Arc<Layout>, u64);

enum Event {
    Chart(RunId, Result<Fetched, String>),
    /// The watch on the router: `Some(silent_ms)` when it was silent for `fence_after_ms`, `None` when it is back.
    Contact(Option<u64>),
    /// A skill's future ended (the number tells this start of it from a later one).
    Skill(RunId, ActionId, u64, Result<(), String>),
    /// A running skill wrote a part of its answer: mapping index, value.
    SkillOutput(RunId, ActionId, u64, usize, Value),
    /// The devices of a run's bindings gave values or changed state (`crate::io::Sink` holds what).
    Devices(RunId),
}

/// A start of a skill, ready to go once the action's previous start has ended.
struct Deferred {
    serial: u64,
    skill: Arc<dyn crate::skill::Skill>,
    call: SkillCall,
    written: mpsc::UnboundedReceiver<(usize, Value)>,
    stops_itself: bool,
}

/// Starts of one action that may wait for the previous one to stop.
const DEFERRED_STARTS_MAX: usize = 16;

/// A skill started and not yet ended.
struct RunningSkill {
    serial: u64,
    stops_itself: bool,
    stop: watch::Sender<bool>,
}

struct Run {
    state: AgentRun,
    /// Where its reports go (`keys::report`), made once: a report is sent per token.
    report_key: String,
    last_used: Instant,
    /// The connections of its bound variables on this agent, closed when the run is forgotten.
    devices: crate::io::Devices,
}

struct Host {
    config: AgentConfig,
    skills: Skills,
    connections: Connections,
    session: Session,
    started: Instant,
    runs: HashMap<RunId, Run>,
    pending: HashMap<RunId, VecDeque<(ChartHash, u64, ToAgent)>>,
    running: HashMap<(RunId, ActionId), RunningSkill>,
    /// Skills told to stop that end by themselves (a goal being cancelled), by serial.
    stopping: HashMap<u64, (RunId, ActionId)>,
    /// Starts of an action's skill that wait for its previous start, still stopping, to end: a cancel must never
    /// reach the job of a step entered again.
    deferred: HashMap<(RunId, ActionId), VecDeque<Deferred>>,
    skill_serial: u64,
    events: mpsc::UnboundedSender<Event>,
    /// One publisher per key, declared on first use.
    outbox: baton_host::Outbox,
    dropped: u64,
    /// This process, as the coordinator tells it from a restarted one of the same name.
    incarnation: uuid::Uuid,
    /// Since when the router has been silent, while it is (`watch_router`): a run joined meanwhile starts fenced.
    contact_lost: Option<u64>,
    /// The deadline the main loop sleeps until: a command that needs an earlier one wakes it.
    armed: Option<Instant>,
    /// The highest term of each run, as the agent's processes before this one heard them too.
    terms: crate::terms::Terms,
}

/// A Zenoh callback that hands each sample to `handle` under the host's lock, carries out what the runs ask, and
/// wakes the main loop if a run now needs its timer earlier.
fn taking(
    shared: &Arc<baton_host::Shared<Host>>,
    handle: fn(&mut Host, Sample),
) -> impl Fn(Sample) + Send + Sync + 'static {
    let shared = Arc::clone(shared);
    move |sample| {
        shared.handle(sample, move |host, sample| {
            handle(host, sample);
            host.carry_out_all();
            baton_host::earlier(host.deadline(), host.armed)
        })
    }
}

enum SkillEvent {
    Output(usize, Value),
    Ended(Result<(), String>),
}

/// Runs one start of a skill: passes on its writes, in order and before its end, and stops it when its action
/// ends — by dropping it, or, for a skill that stops itself, by waiting (at most `STOP_WAIT_MAX`) for it to end.
async fn drive_skill(
    mut future: SkillFuture,
    ctx: SkillContext,
    mut written: mpsc::UnboundedReceiver<(usize, Value)>,
    stops_itself: bool,
    send: impl Fn(SkillEvent),
) {
    let stop = async {
        ctx.stopped().await;
        if stops_itself {
            tokio::time::sleep(STOP_WAIT_MAX).await;
        }
    };
    tokio::pin!(stop);
    loop {
        tokio::select! {
            biased;
            Some((i, v)) = written.recv() => send(SkillEvent::Output(i, v)),
            result = &mut future => {
                while let Ok((i, v)) = written.try_recv() {
                    send(SkillEvent::Output(i, v));
                }
                return send(SkillEvent::Ended(result));
            }
            () = &mut stop => {
                if stops_itself {
                    send(SkillEvent::Ended(Err(format!("it did not end within {} s of being told to stop, and was dropped", STOP_WAIT_MAX.as_secs()))));
                }
                return;
            }
        }
    }
}

/// Runs the agent until interrupted (Ctrl-C or SIGTERM), with `skills` and the protocols of `connections` (whose
/// skills it adds: `Connections::skills`).
pub async fn run(config: AgentConfig, skills: Skills, connections: Connections) -> anyhow::Result<()> {
    let mut stop = baton_host::Stop::new()?;
    run_until(config, skills, connections, async move {
        stop.recv().await;
    })
    .await
}

/// Runs the agent until `stop` completes: one of several agents in a process (`crate::many`), or an agent embedded
/// in a program that decides itself when it ends.
pub async fn run_until(
    config: AgentConfig,
    skills: Skills,
    connections: Connections,
    stop: impl std::future::Future<Output = ()>,
) -> anyhow::Result<()> {
    let skills = connections.skills(skills);
    config.validate()?;
    let net = NetConfig { lease_ms: Some(config.lease_ms), ..NetConfig::client(&config.connect, true) };
    let zconfig = baton_host::zenoh_config(&net, config.zenoh_config.as_deref())?;
    let name = config.name.clone();
    let mut stop = std::pin::pin!(stop);
    let Some(opened) = open(&config, zconfig, stop.as_mut()).await? else {
        // Nothing was joined, nothing is held: the session that may still open is never used.
        eprintln!("baton-agent `{name}`: stopped before a router answered");
        return Ok(());
    };
    let session = opened.map_err(|e| anyhow!("cannot open a Zenoh session: {e}"))?;
    let _roles = claim(&session, &name, &config.roles).await?;
    let incarnation = uuid::Uuid::new_v4();
    // Everything a coordinator may use is declared before the liveliness token announces the agent: a
    // coordinator asks for the info as soon as it sees the token, and may dispatch right after.
    let info_q = traffic::queryable(&session, keys::agent_info(&name)).await.zenoh()?;
    let why_q = traffic::queryable(&session, keys::agent_why(&name)).await.zenoh()?;
    let (tx, mut rx) = mpsc::unbounded_channel();
    let shared = baton_host::Shared::new(Host {
        config: config.clone(),
        skills,
        connections,
        session: session.clone(),
        started: Instant::now(),
        runs: HashMap::new(),
        pending: HashMap::new(),
        running: HashMap::new(),
        stopping: HashMap::new(),
        deferred: HashMap::new(),
        skill_serial: 0,
        events: tx.clone(),
        outbox: baton_host::Outbox::new(&session),
        dropped: 0,
        incarnation,
        contact_lost: None,
        armed: None,
        terms: crate::terms::Terms::open(config.state_dir.as_deref(), &name),
    });
    // Commands to this process only: a second process of the same name (which the check above refuses, but two
    // may start at the same moment) hears none of them. Both are handled in Zenoh's callback (`baton_host::shared`).
    let _cmd_sub = traffic::subscriber(&session, keys::agent_cmd(&name, incarnation))
        .allowed_origin(Locality::Remote)
        .callback(taking(&shared, Host::on_cmd))
        .await
        .zenoh()?;
    let _vars_sub = traffic::subscriber(&session, keys::vars_any_run())
        .allowed_origin(Locality::Remote)
        .callback(taking(&shared, Host::on_vars))
        .await
        .zenoh()?;
    let _alive = traffic::token(&session, keys::alive(&name))
        .await
        .map_err(|e| anyhow!("cannot declare the liveliness token: {e}"))?;
    tokio::spawn(watch_router(session.clone(), name.clone(), config.lease_ms, tx));
    let roles =
        if config.roles.is_empty() { String::new() } else { format!(" with role(s) {}", config.roles.join(", ")) };
    let skill_names = shared.lock()?.skills.names().join(", ");
    eprintln!("baton-agent `{name}`{roles} ready on {} (skills: {skill_names})", config.connect.join(", "));
    crate::trace::event(&name, TraceEvent::AgentUp, &name, Some(format!("ready on {}", config.connect.join(", "))));
    let mut deadline = shared.lock()?.settled();
    loop {
        // Asleep until a query, a skill's event or a run's next cycle or resend is due (commands come in Zenoh's
        // callback, which wakes the loop only to move the deadline earlier or to hand it messages that queued
        // up): an idle agent runs no cycle (only `watch_router` wakes it). The state is held once a wake-up, the
        // next deadline taken in the same hold: a hold makes the callbacks that come meanwhile queue their
        // messages. An info query changes nothing, so the deadline stands.
        tokio::select! {
            q = info_q.recv_async() => {
                let Ok(q) = q else { break };
                let info = wire::encode(&shared.lock()?.info(incarnation));
                if let Err(e) = traffic::reply(&q, q.key_expr().to_string(), info) {
                    eprintln!("warning: cannot answer an info query: {e}");
                }
            }
            q = why_q.recv_async() => {
                let Ok(q) = q else { break };
                // One answer per run this agent takes part in, each its own reply.
                // Cycles due ran for it (`why`): what they asked for leaves now, and the deadline moved.
                let mut host = shared.lock()?;
                let reports = host.why();
                deadline = host.settled();
                drop(host);
                for report in reports {
                    if let Err(e) = traffic::reply(&q, q.key_expr().to_string(), wire::encode(&report)) {
                        eprintln!("warning: cannot answer a why query: {e}");
                    }
                }
            }
            Some(ev) = rx.recv() => {
                let mut host = shared.lock()?;
                host.on_event(ev);
                deadline = host.settled();
            }
            () = baton_host::until(deadline) => {
                let mut host = shared.lock()?;
                host.timeout();
                deadline = host.settled();
            }
            () = shared.rearmed() => deadline = shared.lock()?.settled(),
            () = &mut stop => break,
        }
    }
    let dropped = shared.lock()?.dropped_total();
    eprintln!("baton-agent `{name}` stopping ({dropped} message(s) dropped)");
    drop((_cmd_sub, _vars_sub));
    drop(shared);
    session.close().await.zenoh()?;
    Ok(())
}

/// Opens the agent's Zenoh session, waiting for its router as long as it takes; `None` when `stop` came first.
async fn open(
    config: &AgentConfig,
    zconfig: zenoh::Config,
    mut stop: std::pin::Pin<&mut impl std::future::Future<Output = ()>>,
) -> anyhow::Result<Option<zenoh::Result<Session>>> {
    let name = &config.name;
    // The agent waits for its router as long as it takes (a robot may boot before the cell's network), but says
    // that it waits: a silent agent behind a wrong address or a cut cable is a puzzle. And it stops when asked
    // while it waits. zenoh::open holds the thread that awaits it while it retries (the runtime's only worker, for
    // one agent), so it opens on a thread of its own, and the notice and the stop are awaited here.
    let (opened_tx, opened) = tokio::sync::oneshot::channel();
    std::thread::Builder::new()
        .name(format!("open {name}"))
        .spawn(move || {
            use zenoh::Wait;
            let _ = opened_tx.send(zenoh::open(zconfig).wait());
        })
        .map_err(|e| anyhow!("cannot start a thread to open the Zenoh session: {e}"))?;
    let notice = tokio::time::sleep(ROUTER_WAIT_NOTICE);
    let mut notice = std::pin::pin!(notice);
    let mut opened = std::pin::pin!(opened);
    let mut noticed = false;
    let opened = loop {
        tokio::select! {
            opened = &mut opened => break opened.map_err(|_| anyhow!("the thread opening the Zenoh session ended"))?,
            () = &mut notice, if !noticed => {
                noticed = true;
                let said = format!("no router answers at {} yet", config.connect.join(", "));
                eprintln!("baton-agent `{name}`: {said}; still trying (Ctrl-C to stop)");
                crate::trace::event(name, TraceEvent::ContactLost, name, Some(said));
            }
            () = &mut stop => return Ok(None),
        }
    };
    Ok(Some(opened))
}

/// Announces the agent's roles and checks that its name is free: the role tokens, held while the agent runs.
async fn claim(
    session: &Session,
    name: &str,
    roles: &[String],
) -> anyhow::Result<Vec<zenoh::liveliness::LivelinessToken>> {
    // Its roles, each a liveliness token the router's access control lets only the identities deployed with that
    // role announce: refused, the agent says so and does not run (a coordinator would not give it the role's
    // steps either). Before the name check, so that the reason a process is refused is its own; the tokens of a
    // second process under a taken name give the first no role it does not claim (`announced_roles`).
    let mut tokens = Vec::with_capacity(roles.len());
    for role in roles {
        let token = traffic::token(session, keys::alive_role(name, role))
            .await
            .map_err(|e| anyhow!("cannot announce role `{role}`: {e}"))?;
        tokens.push(token);
    }
    if let Some(role) = refused_role(session, name, roles).await? {
        session.close().await.zenoh()?;
        anyhow::bail!(
            "the router does not let `{name}` serve role `{role}`: its access control lets an identity announce only \
             the roles its deployment gives it (`baton deploy acl … --agent {name}={role}`); run without --role \
             {role}, or deploy it"
        );
    }
    // A name is held by one live process: two would both run what is sent to it.
    let holders = traffic::liveliness_get(session, keys::alive(name))
        .timeout(LIVELINESS_CHECK_TIMEOUT)
        .await
        .map_err(|e| anyhow!("cannot ask the router which agents are live: {e}"))?;
    if let Ok(reply) = holders.recv_async().await {
        if reply.result().is_ok() {
            session.close().await.zenoh()?;
            anyhow::bail!(
                "an agent named `{name}` is already live on this router: stop it first, or give this one another --name"
            );
        }
    }
    Ok(tokens)
}

impl Host {
    fn now_ms(&self) -> u64 {
        self.started.elapsed().as_millis() as u64
    }

    /// Who this agent is, and the tokens it holds (a coordinator that restarted reconciles its own with them).
    /// Why the active steps of each run here wait (`baton status --why`).
    fn why(&mut self) -> Vec<baton_proto::cluster::wire::WhyReport> {
        let now = self.now_ms();
        let name = self.config.name.clone();
        self.runs
            .values_mut()
            .map(|r| {
                // The engine's state as of now: cycles due run first, as any input would have them.
                r.state.handle_timeout(now);
                baton_proto::cluster::wire::WhyReport {
                    run: r.state.run_id(),
                    agent: name.clone(),
                    steps: r.state.why(),
                }
            })
            .filter(|w| !w.steps.is_empty())
            .collect()
    }

    fn info(&self, incarnation: uuid::Uuid) -> AgentInfo {
        let mut held: Vec<HeldToken> = self.runs.values().flat_map(|r| r.state.held()).collect();
        held.sort_unstable();
        held.truncate(HELD_LISTED_MAX);
        let max = baton_proto::limits::PENDING_LISTED_MAX;
        let mut weight = 0;
        let pending: Vec<_> = self
            .runs
            .values()
            .flat_map(|r| r.state.pending_reports(max))
            .take(max)
            .take_while(|r| {
                weight += r.weight();
                weight <= baton_proto::limits::PENDING_LISTED_BYTES_MAX
            })
            .collect();
        AgentInfo {
            name: self.config.name.clone(),
            roles: self.config.roles.clone(),
            lease_ms: self.config.lease_ms,
            incarnation,
            held,
            pending,
            skills: Some(self.skills.names()),
        }
    }

    fn dropped_total(&self) -> u64 {
        self.dropped + self.runs.values().map(|r| r.state.dropped()).sum::<u64>()
    }

    fn drop_msg(&mut self, why: String) {
        self.dropped += 1;
        eprintln!("warning: dropped a message: {why}");
    }

    fn on_cmd(&mut self, sample: Sample) {
        let (term, msg): (u64, ToAgent) = match wire::decode_termed(&sample.payload().to_bytes()) {
            Ok(m) => m,
            Err(e) => return self.drop_msg(format!("on {}: {e}", sample.key_expr())),
        };
        let now = self.now_ms();
        let run = msg.run();
        if let Some(r) = self.runs.get_mut(&run) {
            if matches!(msg, ToAgent::Dispatch { .. }) {
                r.last_used = Instant::now();
            }
            let what = if matches!(msg, ToAgent::Join { .. }) { "join" } else { "dispatch" };
            // A command of a deposed coordinator's term is logged and traced by the run itself.
            let before = r.state.term().0;
            let taken = r.state.handle_message(now, term, msg);
            // A term that rose is remembered before what the message asked is carried out (after this callback).
            if r.state.term().0 > before {
                self.terms.raise(run, r.state.term().0);
            }
            if let Err(NotTaken::OtherChart) = taken {
                self.drop_msg(format!("{what} for run {} with another chart version", run.key()));
            }
            return;
        }
        match msg {
            // The first dispatch or join of a run starts the fetch of its chart; they wait for it.
            ToAgent::Dispatch { ref chart, .. } | ToAgent::Join { ref chart, .. } => {
                let chart = chart.clone();
                self.queue_for_chart(run, chart, term, msg);
            }
            // Only a run whose chart is on its way: the dispatch or join that started the fetch names them.
            ToAgent::Peers { .. } => {
                if let Some(queue) = self.pending.get_mut(&run) {
                    if queue.len() < PENDING_DISPATCHES_MAX {
                        let hash = queue.front().map(|(h, _, _)| h.clone());
                        if let Some(hash) = hash {
                            queue.push_back((hash, term, msg));
                        }
                    }
                }
            }
            // A dispatch of this run still waiting for its chart never runs.
            ToAgent::Abort { .. } => {
                self.pending.remove(&run);
            }
            // Of a run this agent does not take part in (any more): nothing to act on.
            _ => {}
        }
    }

    /// Keeps a dispatch or a join until its run's chart arrives; the first one starts the fetch.
    fn queue_for_chart(&mut self, run: RunId, hash: ChartHash, term: u64, d: ToAgent) {
        let first = !self.pending.contains_key(&run);
        if first && self.pending.len() >= RUNS_MAX {
            return self
                .drop_msg(format!("dispatch for run {} dropped: {RUNS_MAX} charts are being fetched", run.key()));
        }
        let queue = self.pending.entry(run).or_default();
        if queue.len() >= PENDING_DISPATCHES_MAX {
            return self.drop_msg(format!("too many dispatches waiting for the chart of run {}", run.key()));
        }
        queue.push_back((hash.clone(), term, d));
        if first {
            self.fetch_for(run, hash);
        }
    }

    /// Fetches the chart of `run`; dispatches that come meanwhile wait in `pending`.
    fn fetch_for(&mut self, run: RunId, hash: ChartHash) {
        if self.pending.len() >= RUNS_MAX && !self.pending.contains_key(&run) {
            return self.drop_msg(format!("run {} not joined: {RUNS_MAX} charts are being fetched", run.key()));
        }
        self.pending.entry(run).or_default();
        let session = self.session.clone();
        let tx = self.events.clone();
        tokio::spawn(async move {
            let result = fetch_chart(&session, run, &hash).await;
            let _ = tx.send(Event::Chart(run, result));
        });
    }

    fn on_vars(&mut self, sample: Sample) {
        let (term, update): (u64, VarUpdate) = match wire::decode_termed(&sample.payload().to_bytes()) {
            Ok(u) => u,
            Err(e) => return self.drop_msg(format!("on {}: {e}", sample.key_expr())),
        };
        // The key a writer publishes on names it: an update under another name's key is not that writer's.
        if keys::writer_of_vars(sample.key_expr().as_str()) != Some(update.from.as_str()) {
            return self.drop_msg(format!("on {}: an update from `{}`", sample.key_expr(), update.from));
        }
        let now = self.now_ms();
        if let Some(r) = self.runs.get_mut(&update.run) {
            let before = r.state.term().0;
            r.state.handle_vars(now, term, &update);
            if r.state.term().0 > before {
                self.terms.raise(update.run, r.state.term().0);
            }
        }
    }

    fn on_event(&mut self, ev: Event) {
        let now = self.now_ms();
        match ev {
            Event::Chart(run, Ok((hash, program, layout, cycle_ms))) => {
                let queued = self.pending.remove(&run).unwrap_or_default();
                self.make_room();
                let (name, roles) = (&self.config.name, &self.config.roles);
                let mut state = AgentRun::new(name, roles, run, hash.clone(), program, layout, cycle_ms);
                state.set_incarnation(self.incarnation);
                state.remember_term(now, self.terms.of(run));
                if let Some(silent_ms) = self.contact_lost {
                    state.handle_contact(now, Some(silent_ms));
                }
                self.check_skills(&state);
                let devices = self.start_devices(run, &state);
                let report_key = keys::report(run, &self.config.name);
                let mut r = Run { state, report_key, last_used: Instant::now(), devices };
                for (h, term, command) in queued {
                    // Queued under the chart fetched, so of this run and this version: taken. (Queued under
                    // another version, it is not this run's.)
                    if h == hash {
                        let _taken = r.state.handle_message(now, term, command);
                    }
                }
                self.terms.raise(run, r.state.term().0);
                eprintln!("joined run {} of chart `{}`", run.key(), r.state.program().name);
                self.runs.insert(run, r);
            }
            Event::Chart(run, Err(why)) => {
                let n = self.pending.remove(&run).map_or(0, |q| q.len());
                self.dropped += n as u64;
                eprintln!("error: cannot take part in run {}: {why} ({n} token(s) dropped)", run.key());
            }
            Event::Contact(lost) => {
                let holding = self.runs.values().map(|r| r.state.tokens_held()).sum::<usize>();
                let name = &self.config.name;
                match lost {
                    // Nothing held, nothing to stop: the usual end of a run whose coordinator hosted the router.
                    Some(ms) if holding == 0 => {
                        let said =
                            format!("no contact with the router for {ms} ms; no token is held here, nothing to stop");
                        eprintln!("baton-agent `{name}`: {said}; still trying");
                        crate::trace::event(name, TraceEvent::ContactLost, name, Some(said));
                    }
                    Some(ms) => {
                        let said = format!(
                            "no contact with the router for {ms} ms: the skills of the {holding} token(s) held here \
                             that may go to another agent are stopped (lease fence)"
                        );
                        eprintln!("warning: {said} at unix ms {}", baton_host::unix_ms());
                        crate::trace::event(name, TraceEvent::ContactLost, name, Some(said));
                    }
                    None => {
                        eprintln!("the router is back");
                        crate::trace::event(name, TraceEvent::ContactBack, name, None);
                    }
                }
                self.contact_lost = lost;
                for r in self.runs.values_mut() {
                    r.state.handle_contact(now, lost);
                }
            }
            Event::Skill(run, action, serial, result) => {
                if self.running.get(&(run, action)).is_some_and(|r| r.serial == serial) {
                    self.running.remove(&(run, action));
                    if let Some(r) = self.runs.get_mut(&run) {
                        let name = &r.state.program().actions[action.index()].name;
                        let (event, message) = match &result {
                            Ok(()) => (TraceEvent::SkillDone, None),
                            Err(why) => (TraceEvent::SkillFault, Some(why.clone())),
                        };
                        crate::trace::event(&self.config.name, event, name, message);
                        r.state.handle_skill_result(now, action, result);
                    }
                } else if let Some((run, action)) = self.stopping.remove(&serial) {
                    if let Some(r) = self.runs.get_mut(&run) {
                        r.state.handle_skill_stopped(action, result.map(|()| "it confirmed the stop".to_string()));
                    }
                    self.start_deferred(run, action);
                }
            }
            Event::Devices(run) => {
                if let Some(r) = self.runs.get_mut(&run) {
                    let arrived = r.devices.sink.take();
                    for (binding, state) in arrived.states {
                        r.state.handle_device(binding, state);
                    }
                    for (binding, value) in arrived.values {
                        r.state.handle_input(now, binding, value);
                    }
                }
            }
            Event::SkillOutput(run, action, serial, output, value) => {
                if self.running.get(&(run, action)).is_some_and(|r| r.serial == serial) {
                    if let Some(r) = self.runs.get_mut(&run) {
                        r.state.handle_skill_output(now, action, output, value);
                    }
                }
            }
        }
    }

    /// Connects the devices of the run's bindings on this agent.
    fn start_devices(&self, run: RunId, state: &AgentRun) -> crate::io::Devices {
        let tx = self.events.clone();
        let sink = crate::io::Sink::new(move || {
            let _ = tx.send(Event::Devices(run));
        });
        crate::io::Devices::start(&self.session, &self.connections, state.io_here(), sink)
    }

    /// Forgets the least recently used run that holds no token when the table is full.
    fn make_room(&mut self) {
        if self.runs.len() < RUNS_MAX {
            return;
        }
        let idle = self.runs.iter().filter(|(_, r)| r.state.tokens_held() == 0).min_by_key(|(_, r)| r.last_used);
        if let Some((&id, _)) = idle {
            self.runs.remove(&id);
            self.deferred.retain(|(run, _), _| *run != id);
        }
    }

    /// The earliest instant a run needs its `handle_timeout`.
    fn deadline(&self) -> Option<Instant> {
        let at = self.runs.values().filter_map(|r| r.state.poll_timeout()).min()?;
        Some(self.started + Duration::from_millis(at))
    }

    /// Time passed: every run whose cycle or resend is due gets it.
    fn timeout(&mut self) {
        let now = self.now_ms();
        for r in self.runs.values_mut() {
            if r.state.poll_timeout().is_some_and(|t| t <= now) {
                r.state.handle_timeout(now);
            }
        }
    }

    /// What the main loop's wake-up led to carried out, and the deadline it sleeps until next, armed for the
    /// callbacks to compare with.
    fn settled(&mut self) -> Option<Instant> {
        self.carry_out_all();
        self.armed = self.deadline();
        self.armed
    }

    /// Carries out what every run asks.
    fn carry_out_all(&mut self) {
        let ids: Vec<RunId> = self.runs.keys().copied().collect();
        for id in ids {
            let mut outputs = Vec::new();
            if let Some(r) = self.runs.get_mut(&id) {
                while let Some(out) = r.state.poll_output() {
                    outputs.push(out);
                }
            }
            for out in outputs {
                self.carry_out(id, out);
            }
        }
    }

    fn carry_out(&mut self, run: RunId, out: AgentOutput) {
        match out {
            AgentOutput::Report(report) => {
                let key =
                    self.runs.get(&run).map_or_else(|| keys::report(run, &self.config.name), |r| r.report_key.clone());
                self.put(&key, wire::encode(&report));
            }
            AgentOutput::Vars(update) => self.put(&keys::vars(run, &self.config.name), wire::encode(&update)),
            AgentOutput::StartSkill { action, name, binding } => {
                let tx = self.events.clone();
                self.skill_serial += 1;
                let serial = self.skill_serial;
                let (ctx, written, stop) = SkillContext::new();
                let skill = self.skills.get(&binding.skill);
                let stops_itself = skill.as_ref().is_some_and(|s| s.stops_itself());
                if let Some(old) = self.running.insert((run, action), RunningSkill { serial, stops_itself, stop }) {
                    self.stop_skill(run, action, old);
                }
                let Some(skill) = skill else {
                    let why = format!("agent `{}` {}", self.config.name, self.no_skill(&binding.skill));
                    let _ = tx.send(Event::Skill(run, action, serial, Err(why)));
                    return;
                };
                let call = SkillCall {
                    agent: self.config.name.clone(),
                    action: name,
                    params: binding.params,
                    outputs: binding.outputs.into_iter().map(|o| (o.key, o.path)).collect(),
                    session: self.session.clone(),
                    ctx,
                };
                let start = Deferred { serial, skill, call, written, stops_itself };
                if self.stopping.values().any(|&k| k == (run, action)) {
                    // The previous start is still cancelling its job: this one goes once that has ended.
                    let queue = self.deferred.entry((run, action)).or_default();
                    if queue.len() < DEFERRED_STARTS_MAX {
                        queue.push_back(start);
                    }
                    return;
                }
                self.spawn_skill(run, action, start);
            }
            AgentOutput::StopSkill { action } => {
                if let Some(old) = self.running.remove(&(run, action)) {
                    self.stop_skill(run, action, old);
                }
            }
            AgentOutput::Output { binding, value } => {
                if let Some(r) = self.runs.get(&run) {
                    r.devices.write(binding, value);
                }
            }
            AgentOutput::Devices(report) => {
                self.put(&keys::devices(run, &self.config.name), wire::encode(&report));
            }
            AgentOutput::Trace(record) => crate::trace::write(&self.config.name, record),
            AgentOutput::Log { level, message } => {
                if level >= Level::Warn || self.config.verbose {
                    let tag = match level {
                        Level::Info => "info",
                        Level::Warn => "warning",
                        Level::Error => "error",
                    };
                    eprintln!("{tag}: {message}");
                }
            }
        }
    }

    /// Says at once, when the agent joins a run, what its skills will refuse (an unknown skill, a ROS 2 type the
    /// agent does not know, a goal that does not fit its type) — rather than when the action starts.
    fn check_skills(&self, run: &AgentRun) {
        for (a, binding) in run.skills_here() {
            let action = &run.program().actions[a.index()].name;
            let problem = match self.skills.get(&binding.skill) {
                None => Some(format!("this agent {}", self.no_skill(&binding.skill))),
                Some(skill) => skill.check(&binding.params).err(),
            };
            if let Some(why) = problem {
                eprintln!("warning: action `{action}` will fault on this agent: {why}");
            }
        }
    }

    fn no_skill(&self, skill: &str) -> String {
        format!("has no skill `{skill}` (it has: {})", self.skills.names().join(", "))
    }

    /// Starts a skill's future, which `drive_skill` follows. A start whose action ended before it could go asks
    /// nothing of its device: a skill that stops itself is told it ended at once (its stop is awaited), any other
    /// is never started.
    fn spawn_skill(&mut self, run: RunId, action: ActionId, start: Deferred) {
        let Deferred { serial, skill, call, written, stops_itself } = start;
        let tx = self.events.clone();
        let ctx = call.ctx.clone();
        if ctx.is_stopped() && !stops_itself {
            return;
        }
        crate::trace::event(&self.config.name, TraceEvent::SkillStart, &call.action, None);
        tokio::spawn(drive_skill(skill.start(call), ctx, written, stops_itself, move |e| match e {
            SkillEvent::Output(i, v) => {
                let _ = tx.send(Event::SkillOutput(run, action, serial, i, v));
            }
            SkillEvent::Ended(result) => {
                let _ = tx.send(Event::Skill(run, action, serial, result));
            }
        }));
    }

    /// The action's previous start ended: the next one waiting goes now.
    fn start_deferred(&mut self, run: RunId, action: ActionId) {
        let Some(queue) = self.deferred.get_mut(&(run, action)) else { return };
        let next = queue.pop_front();
        if queue.is_empty() {
            self.deferred.remove(&(run, action));
        }
        if let Some(start) = next {
            self.spawn_skill(run, action, start);
        }
    }

    /// Tells a skill its action ended: one that stops itself is remembered until it says how it went.
    fn stop_skill(&mut self, run: RunId, action: ActionId, skill: RunningSkill) {
        let _ = skill.stop.send(true);
        if skill.stops_itself {
            self.stopping.insert(skill.serial, (run, action));
        }
    }

    /// Publishes through the outbox; a failure is logged (the state machines resend what matters).
    fn put(&mut self, key: &str, payload: Vec<u8>) {
        if let Err(e) = self.outbox.put(key, payload) {
            eprintln!("warning: {e}");
        }
    }
}

/// Watches the link to the router for the lease fence: every `fence_check_ms` the agent asks the router for its
/// own liveliness token (the router's answer comes besides the session's own). Silent for `fence_after_ms`, the
/// agent is fenced: it tells the main loop, and again when the router answers.
async fn watch_router(session: Session, name: String, lease_ms: u64, tx: mpsc::UnboundedSender<Event>) {
    let check = Duration::from_millis(fence_check_ms(lease_ms));
    let limit = Duration::from_millis(fence_after_ms(lease_ms));
    let mut last_heard = Instant::now();
    let mut fenced = false;
    let mut tick = tokio::time::interval(check);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tick.tick().await;
        let mut answers = 0;
        if let Ok(replies) = traffic::liveliness_get(&session, keys::alive(&name)).timeout(check).await {
            while let Ok(reply) = replies.recv_async().await {
                answers += usize::from(reply.result().is_ok());
            }
        }
        // One answer is this session's own token; the router's is the second.
        if answers >= 2 {
            last_heard = Instant::now();
            if std::mem::take(&mut fenced) && tx.send(Event::Contact(None)).is_err() {
                return;
            }
        } else if !fenced && last_heard.elapsed() >= limit {
            fenced = true;
            if tx.send(Event::Contact(Some(last_heard.elapsed().as_millis() as u64))).is_err() {
                return;
            }
        }
    }
}

/// Asks the coordinator of `run` for its chart and compiles it; the chart must hash to `hash`.
async fn fetch_chart(session: &Session, run: RunId, hash: &ChartHash) -> Result<Fetched, String> {
    let replies = traffic::get(session, keys::chart(run))
        .timeout(CHART_FETCH_TIMEOUT)
        .await
        .map_err(|e| format!("cannot ask for the chart: {e}"))?;
    let reply = replies.recv_async().await.map_err(|_| "the coordinator did not send the chart".to_string())?;
    let sample = reply.result().map_err(|e| format!("the chart query failed: {e:?}"))?;
    let src: ChartSource = wire::decode_with_limit(&sample.payload().to_bytes(), CHART_SOURCE_BYTES_MAX)
        .map_err(|e| format!("chart reply: {e}"))?;
    if ChartHash::of(&src.source, &src.pou) != *hash || src.hash != *hash {
        return Err("the chart received does not match the version of the token".to_string());
    }
    if !(1..=baton_proto::limits::CYCLE_MS_MAX).contains(&src.cycle_ms) {
        return Err(format!("the run's cycle period, {} ms, is not between 1 ms and an hour", src.cycle_ms));
    }
    let mut report = check_source(&src.source);
    let i = report
        .charts
        .iter()
        .position(|c| c.chart.name.name == src.pou)
        .ok_or_else(|| format!("the chart source has no POU `{}`", src.pou))?;
    let checked = report.charts.swap_remove(i);
    match (checked.program, checked.layout) {
        (Some(p), Some(l)) => Ok((hash.clone(), Arc::new(p), Arc::new(l), src.cycle_ms)),
        _ => Err(format!("chart `{}` has errors here", src.pou)),
    }
}
