//! `baton test --cluster`: a scenario on real processes on loopback, in real time. The runner embeds a Zenoh
//! router, starts `baton run` against it and one `baton-agent --simulate SCENARIO` per agent, each behind a
//! cable it can pull out (`baton_host::cable`). Inputs go in as `baton set` sends them; faults are signals (kill,
//! restart), pulled cables (cut, heal), slow cables (link delays) and a coordinator killed and started again on
//! its journal. What the runner knows of the run is what `baton run --trace` writes (with `--watch` for every
//! variable); it follows that file as it grows and judges it with the simulation's own observer
//! (`testing::run::Observer`), so a scenario means the same on both.
//!
//! Every run has its own router, ports and folder (`OUT/NAME-seedN.cluster/`: the trace, the summary, the
//! journal and each process's log, removed when the run passes), so scenarios run side by side.

use std::collections::{BTreeSet, HashMap};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context};
use baton_host::cable::Cable;
use baton_host::traffic;
use baton_proto::cluster::keys;
use baton_proto::cluster::netconfig::NetConfig;
use baton_proto::cluster::runtime::coordinator::LossPolicy;
use baton_proto::exec::program::VarId;
use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use baton_proto::front::json_value;
use baton_proto::testing::run::{fault_rng, jitter, CaseResult, Observer, Outcome};
use baton_proto::testing::scenario::{show_ms, FaultKind, NetFaults, RunState, Scenario, Trigger};
use baton_proto::testing::simulated_cluster::{Rng, LEASE_MS};
use baton_proto::types::{Type, Value};
use tokio::process::{Child, Command};
use zenoh::Session;

/// How often the runner looks at the trace and the clock.
const POLL: Duration = Duration::from_millis(5);
/// How long a killed agent's liveliness token may take to vanish before it is started again.
const GONE_WAIT: Duration = Duration::from_secs(5);
/// How long the agents that start at once may take to be live.
const LIVE_WAIT: Duration = Duration::from_secs(20);
/// How long an input waits for a chart to answer (a coordinator starting, or restarting from its journal).
const SET_WAIT: Duration = Duration::from_secs(10);

/// The programs a cluster run starts.
pub struct Binaries {
    pub baton: PathBuf,
    pub agent: PathBuf,
}

impl Binaries {
    /// This `baton`, and the `baton-agent` beside it (or on the PATH).
    pub fn find() -> anyhow::Result<Binaries> {
        Ok(Binaries {
            baton: std::env::current_exe().context("cannot locate this executable")?,
            agent: crate::demo::agent_binary()?,
        })
    }
}

/// Why `sc` cannot run on real processes, if it cannot: TCP carries everything once and in order, so losses,
/// duplicates and reordering need the simulated network.
pub fn unsupported(sc: &Scenario) -> Option<String> {
    let lossy = |n: &NetFaults| {
        let mut what = Vec::new();
        if n.drop > 0.0 {
            what.push("drop");
        }
        if n.duplicate > 0.0 {
            what.push("duplicate");
        }
        if n.reorder {
            what.push("reorder");
        }
        what
    };
    let mut why = Vec::new();
    let net = lossy(&sc.network);
    if !net.is_empty() {
        why.push(format!("[network] {}", net.join(", ")));
    }
    for f in &sc.faults {
        if let FaultKind::Link(agent, n, _) = &f.kind {
            let what = lossy(n);
            if !what.is_empty() {
                why.push(format!("line {}: {} on {agent}'s link", f.line, what.join(", ")));
            }
        }
    }
    (!why.is_empty()).then(|| {
        format!(
            "needs the simulated network: real links (TCP) cannot {} ({}); run it without --cluster",
            "drop, duplicate or reorder messages",
            why.join("; ")
        )
    })
}

/// Claims the folder of run `seed` of `sc` under `out` (its trace, summary, journal and processes' logs):
/// `NAME-seedN.cluster`, or `NAME-seedN.K.cluster` while another run holds that one (another `baton test` beside
/// this one, or another scenario file of the same name). A run holds its folder by a lock on `.lock` in it, for
/// as long as the returned file is open; a folder whose lock nobody holds is a finished run's, kept for its
/// logs, and is emptied and taken over.
pub fn claim_run_dir(out: &Path, sc: &Scenario, seed: u64) -> anyhow::Result<(PathBuf, std::fs::File)> {
    use std::os::fd::AsRawFd;
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    for k in 1..=RUN_DIRS_MAX {
        let suffix = if k == 1 { String::new() } else { format!(".{k}") };
        let dir = out.join(format!("{}-seed{seed}{suffix}.cluster", sc.file_stem()));
        match std::fs::create_dir(&dir) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {}
            Err(e) => return Err(e).with_context(|| format!("cannot create {}", dir.display())),
        }
        let lock = std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(dir.join(".lock"))
            .with_context(|| format!("cannot create {}", dir.join(".lock").display()))?;
        // SAFETY: flock on a file descriptor this function owns; it only reads the flags.
        if unsafe { libc::flock(lock.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) } != 0 {
            continue;
        }
        for entry in std::fs::read_dir(&dir).with_context(|| format!("cannot read {}", dir.display()))? {
            let entry = entry?;
            if entry.file_name() != ".lock" {
                let path = entry.path();
                let _ = if path.is_dir() { std::fs::remove_dir_all(&path) } else { std::fs::remove_file(&path) };
            }
        }
        return Ok((dir, lock));
    }
    anyhow::bail!("{RUN_DIRS_MAX} runs of `{}` seed {seed} are running under {} already", sc.name, out.display())
}

/// Folders of one (scenario, seed) that runs beside each other may take under one `--out`.
const RUN_DIRS_MAX: usize = 64;

/// Runs `sc` with `seed` on real processes and judges it; `out` holds its folder. `stop` ends it early. A
/// scenario must be one real processes can run (`unsupported` says nothing of it).
pub fn run_until(sc: &Scenario, seed: u64, stop: &AtomicBool, bins: &Binaries, out: &Path) -> Outcome {
    let rt = match tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_stack_size(baton_proto::limits::CHART_STACK_BYTES)
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => return not_run(sc, seed, format!("cannot start the runtime: {e}")),
    };
    rt.block_on(async {
        let (dir, _lock) = match claim_run_dir(out, sc, seed) {
            Ok(claimed) => claimed,
            Err(e) => return not_run(sc, seed, format!("{e:#}")),
        };
        let mut world = match World::start(sc, seed, bins, dir.clone()).await {
            Ok(w) => w,
            Err(e) => {
                let mut o = not_run(sc, seed, format!("{e:#}"));
                o.logs = Some(dir.display().to_string());
                return o;
            }
        };
        let mut outcome = world.drive(stop).await;
        world.tear_down().await;
        if outcome.passed() {
            let _ = std::fs::remove_dir_all(&dir);
            // `out` itself goes too when nothing else is in it.
            let _ = std::fs::remove_dir(out);
        } else {
            outcome.logs = Some(dir.display().to_string());
        }
        outcome
    })
}

/// A run that could not be made: every expectation unjudged, and why.
fn not_run(sc: &Scenario, seed: u64, why: String) -> Outcome {
    let cases = sc
        .expects
        .iter()
        .map(|e| CaseResult {
            line: e.line,
            title: e.title(),
            failure: Some("not judged: the scenario could not run".into()),
            at_ms: None,
        })
        .collect();
    Outcome {
        seed,
        chart_ms: 0,
        state: RunState::Running,
        cases,
        trace: Vec::new(),
        errors: vec![why],
        faults: Vec::new(),
        vars: Vec::new(),
        active: Vec::new(),
        active_at_failure: None,
        logs: None,
    }
}

/// What the runner does at a chart time.
#[derive(Clone, Debug)]
enum Act {
    StartAgent(usize),
    Input(usize),
    /// An operator's command (`[[commands]]`), sent as `baton ctl` sends it.
    Command(usize),
    Fault(usize),
    Heal(String),
    /// A link fault's time is over: back to the network's own delay.
    Undelay(String),
    CoordinatorUp,
}

/// Reads the records a trace file gained since the last look; a resumed coordinator's file starts again with
/// the records already seen, which are skipped.
struct Follower {
    path: PathBuf,
    offset: u64,
    partial: Vec<u8>,
    skip: usize,
}

impl Follower {
    fn new(path: PathBuf, skip: usize) -> Follower {
        Follower { path, offset: 0, partial: Vec::new(), skip }
    }

    fn read_new(&mut self) -> anyhow::Result<Vec<TraceRecord>> {
        use std::io::{Read, Seek, SeekFrom};
        let Ok(mut f) = std::fs::File::open(&self.path) else { return Ok(Vec::new()) };
        f.seek(SeekFrom::Start(self.offset))?;
        let mut bytes = Vec::new();
        f.read_to_end(&mut bytes)?;
        self.offset += bytes.len() as u64;
        self.partial.extend_from_slice(&bytes);
        let Some(end) = self.partial.iter().rposition(|&b| b == b'\n') else { return Ok(Vec::new()) };
        let complete: Vec<u8> = self.partial.drain(..=end).collect();
        let mut out = Vec::new();
        for line in complete.split(|&b| b == b'\n').filter(|l| !l.is_empty()) {
            let rec: TraceRecord = serde_json::from_slice(line)
                .with_context(|| format!("{}: an unreadable trace line", self.path.display()))?;
            // The replay of the journal ends where the new process says it took over: what comes after is new.
            if self.skip > 0 && rec.event != TraceEvent::Recover {
                self.skip -= 1;
                continue;
            }
            self.skip = 0;
            out.push(rec);
        }
        Ok(out)
    }
}

/// A value record's text read back as the variable's value.
fn from_shown(ty: &Type, text: &str) -> Option<Value> {
    let json = match ty {
        Type::Bool => serde_json::Value::Bool(text.eq_ignore_ascii_case("TRUE")),
        // As a REAL shows: `inf`, `-inf` and `NaN` too, which JSON has no words for.
        Type::Real { .. } => return text.parse::<f64>().ok().map(|r| ty.coerce(Value::Real(r))),
        Type::Int(_) => serde_json::from_str(text).ok()?,
        _ => serde_json::Value::String(text.to_string()),
    };
    json_value::parse(ty, &json)
}

struct World<'a> {
    sc: &'a Scenario,
    seed: u64,
    bins: &'a Binaries,
    dir: PathBuf,
    session: Session,
    router: String,
    cables: HashMap<String, Cable>,
    agents: HashMap<String, Child>,
    /// Processes started per agent name (for their log files).
    started: HashMap<String, u32>,
    coordinator: Option<Child>,
    coordinator_runs: u32,
    follower: Follower,
    /// Records read so far, over every coordinator process.
    trace: Vec<TraceRecord>,
    /// Records read but not taken in yet.
    backlog: Vec<TraceRecord>,
    values: HashMap<String, Value>,
    /// When chart time 0 was, by the runner's clock: set by the first record.
    t0: Option<Instant>,
    plan: Vec<(u64, Act)>,
    struck: Vec<(u64, String)>,
    errors: Vec<String>,
    rng: Rng,
    /// The coordinator of a run that stays was interrupted at the run's end (`at_end`).
    interrupted: bool,
}

impl<'a> World<'a> {
    async fn start(sc: &'a Scenario, seed: u64, bins: &'a Binaries, dir: PathBuf) -> anyhow::Result<World<'a>> {
        // A free port, taken by the router at once; another one if somebody took it in between.
        let mut opened = None;
        for _ in 0..5 {
            let port = crate::demo::free_port()?;
            let endpoint = format!("tcp/127.0.0.1:{port}");
            let config = baton_host::zenoh_config(&NetConfig::router(std::slice::from_ref(&endpoint)), None)?;
            if let Ok(session) = zenoh::open(config).await {
                opened = Some((session, endpoint, port));
                break;
            }
        }
        let (session, router, port) = opened.ok_or_else(|| anyhow!("cannot open a router on a loopback port"))?;
        let router_addr: SocketAddr = ([127, 0, 0, 1], port).into();
        let mut cables = HashMap::new();
        for (k, a) in sc.agents.iter().enumerate() {
            let cable = Cable::lay(router_addr, seed.wrapping_mul(31).wrapping_add(k as u64))
                .await
                .context("cannot lay an agent's cable")?;
            cable.delay(sc.network.delay_ms);
            cables.insert(a.name.clone(), cable);
        }
        let mut rng = fault_rng(seed);
        let mut plan = Vec::new();
        for (i, a) in sc.agents.iter().enumerate() {
            plan.push((a.start_ms, Act::StartAgent(i)));
        }
        for (i, f) in sc.faults.iter().enumerate() {
            if let Trigger::At(t) = f.trigger {
                plan.push((t + jitter(f, &mut rng), Act::Fault(i)));
            }
        }
        // Inputs at 0 are set before the first cycle, as the simulation sets them: `baton run --set`.
        for (i, input) in sc.inputs.iter().enumerate() {
            match input.trigger {
                Trigger::At(0) => {}
                Trigger::At(t) => plan.push((t, Act::Input(i))),
                Trigger::When { .. } => {}
            }
        }
        for (i, c) in sc.commands.iter().enumerate() {
            if let Trigger::At(t) = c.trigger {
                plan.push((t, Act::Command(i)));
            }
        }
        let follower = Follower::new(dir.join("trace.1.jsonl"), 0);
        let mut world = World {
            sc,
            seed,
            bins,
            dir,
            session,
            router,
            cables,
            agents: HashMap::new(),
            started: HashMap::new(),
            coordinator: None,
            coordinator_runs: 0,
            follower,
            trace: Vec::new(),
            backlog: Vec::new(),
            values: HashMap::new(),
            t0: None,
            plan,
            struck: Vec::new(),
            errors: Vec::new(),
            rng,
            interrupted: false,
        };
        // Chart time 0 is when the cell is there, as in the simulation: the agents that start at once are live
        // on the router before the coordinator starts its run.
        world.carry_out(None).await;
        let first: Vec<String> = sc.agents.iter().filter(|a| a.start_ms == 0).map(|a| a.name.clone()).collect();
        world.wait_live(&first).await?;
        world.start_coordinator()?;
        Ok(world)
    }

    /// Waits until every agent of `names` holds its liveliness token on the router.
    async fn wait_live(&mut self, names: &[String]) -> anyhow::Result<()> {
        let deadline = Instant::now() + LIVE_WAIT;
        loop {
            let live = self.live_agents().await.unwrap_or_default();
            let missing: Vec<&String> = names.iter().filter(|n| !live.contains(*n)).collect();
            if missing.is_empty() {
                return Ok(());
            }
            // An agent that exited says why in its log.
            for n in &missing {
                if let Some(Ok(Some(status))) = self.agents.get_mut(*n).map(|c| c.try_wait()) {
                    let log = self.dir.join(format!("agent-{n}.1.log"));
                    let text = std::fs::read_to_string(&log).unwrap_or_default();
                    anyhow::bail!("`baton-agent --name {n}` exited with {status}: {}", text.trim());
                }
            }
            if Instant::now() >= deadline {
                let names: Vec<&str> = missing.iter().map(|s| s.as_str()).collect();
                anyhow::bail!("agent(s) {} not live on the router after {LIVE_WAIT:?}", names.join(", "));
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
    }

    /// Starts `cmd` with its output in the run's folder as `log`; it dies with the runner.
    fn spawn(&self, mut cmd: Command, log: &str) -> anyhow::Result<Child> {
        let path = self.dir.join(log);
        let f = std::fs::File::create(&path).with_context(|| format!("cannot create {}", path.display()))?;
        let program = cmd.as_std().get_program().to_string_lossy().to_string();
        // Its life tied to the runner's: a runner killed outright (SIGKILL) takes its processes with it, rather
        // than leaving a coordinator and agents behind, reparented to PID 1.
        let runner = std::process::id();
        // SAFETY: between fork and exec the closure calls only async-signal-safe functions (prctl, getppid, raise).
        unsafe {
            cmd.pre_exec(move || {
                libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL);
                // The runner may have died before the line above: then nobody would tell us.
                if libc::getppid() as u32 != runner {
                    libc::raise(libc::SIGKILL);
                }
                Ok(())
            });
        }
        // A group of its own: a terminal's Ctrl-C reaches the runner, which stops the run and tears it down,
        // not the processes in the middle of it.
        cmd.process_group(0)
            .stdin(Stdio::null())
            .stdout(Stdio::from(f.try_clone()?))
            .stderr(Stdio::from(f))
            .kill_on_drop(true)
            .spawn()
            .with_context(|| format!("cannot start {program}"))
    }

    fn start_coordinator(&mut self) -> anyhow::Result<()> {
        let sc = self.sc;
        self.coordinator_runs += 1;
        let n = self.coordinator_runs;
        let policy = match sc.loss_policy {
            LossPolicy::Pause => "pause",
            LossPolicy::Reassign => "reassign",
            LossPolicy::Fail => "fail",
        };
        let mut cmd = Command::new(&self.bins.baton);
        cmd.arg("run").arg(&sc.chart_path).args(["--pou", &sc.program.name, "--connect", &self.router]);
        cmd.arg("--trace").arg(self.dir.join(format!("trace.{n}.jsonl")));
        cmd.arg("--summary").arg(self.dir.join("summary.json"));
        cmd.args(["--on-agent-loss", policy, "--cycle-ms", &sc.cycle_ms.to_string(), "--quiet"]);
        if sc.journal {
            cmd.arg("--journal").arg(self.dir.join("journal"));
        }
        if sc.stay {
            cmd.arg("--stay");
        }
        for v in sc.program.vars.iter().filter(|v| !v.hidden) {
            cmd.args(["--watch", &v.name]);
        }
        if n == 1 {
            for input in sc.inputs.iter().filter(|i| matches!(i.trigger, Trigger::At(0))) {
                for (name, value) in &input.set {
                    cmd.arg("--set").arg(format!("{name}={value}"));
                }
            }
        }
        self.coordinator = Some(self.spawn(cmd, &format!("coordinator.{n}.log"))?);
        Ok(())
    }

    fn start_agent(&mut self, name: &str) -> anyhow::Result<()> {
        let Some(agent) = self.sc.agents.iter().find(|a| a.name == name) else { return Ok(()) };
        let n = self.started.entry(name.to_string()).or_insert(0);
        *n += 1;
        let log = format!("agent-{name}.{n}.log");
        let mut cmd = Command::new(&self.bins.agent);
        cmd.args(["--connect", &self.cables[name].endpoint(), "--name", name]);
        for r in &agent.roles {
            cmd.args(["--role", r]);
        }
        cmd.args(["--lease-ms", &LEASE_MS.to_string(), "--seed", &self.seed.to_string()]);
        cmd.arg("--simulate").arg(&self.sc.path);
        let child = self.spawn(cmd, &log)?;
        self.agents.insert(name.to_string(), child);
        Ok(())
    }

    async fn kill_agent(&mut self, name: &str) {
        if let Some(mut child) = self.agents.remove(name) {
            let _ = child.kill().await;
        }
    }

    /// The agents whose liveliness token the router holds; `None` when it cannot be asked.
    async fn live_agents(&self) -> Option<BTreeSet<String>> {
        let replies =
            traffic::liveliness_get(&self.session, keys::alive_any()).timeout(Duration::from_millis(500)).await.ok()?;
        let mut live = BTreeSet::new();
        while let Ok(r) = replies.recv_async().await {
            if let Some(name) = r.result().ok().and_then(|s| keys::agent_of_alive(s.key_expr().as_str())) {
                live.insert(name.to_string());
            }
        }
        Some(live)
    }

    /// Waits until the router no longer holds `name`'s liveliness token: a process started before would refuse
    /// to run under a name still taken.
    async fn wait_gone(&self, name: &str) -> bool {
        let deadline = Instant::now() + GONE_WAIT;
        while Instant::now() < deadline {
            let Some(live) = self.live_agents().await else { return false };
            if !live.contains(name) {
                return true;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        false
    }

    /// Sets an input as `baton set` does. A chart that does not answer yet (its queryable still travelling to
    /// the router, or the coordinator restarting) is asked again for a while; a refusal is final.
    async fn set(&self, name: &str, value: &serde_json::Value) -> anyhow::Result<()> {
        let deadline = Instant::now() + SET_WAIT;
        loop {
            // The runner's router is its own, with one run on it.
            let replies = crate::client::set_on(&self.session, None, name, value.clone()).await?;
            if replies.iter().any(|r| r.ok) {
                return Ok(());
            }
            if let Some(r) = replies.first() {
                anyhow::bail!("cannot set {name} = {value}: {}", r.message);
            }
            if Instant::now() >= deadline {
                anyhow::bail!("cannot set {name} = {value}: no chart answered for {SET_WAIT:?}");
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    /// The chart time now, once the coordinator has started its run.
    fn chart_now(&self) -> Option<u64> {
        self.t0.map(|t0| t0.elapsed().as_millis() as u64)
    }

    fn value_of(&self, name: &str) -> Option<Value> {
        self.values.get(name).cloned()
    }

    fn value_by_id(&self, var: VarId) -> Value {
        let decl = &self.sc.program.vars[var.index()];
        self.values.get(&decl.name).cloned().unwrap_or_else(|| decl.ty.default_value())
    }

    /// Takes in the records read: values, steps, and at each new moment the invariants and `when` triggers.
    fn take_in(&mut self, obs: &mut Observer<'_>, records: Vec<TraceRecord>) {
        let mut i = 0;
        while i < records.len() {
            let t = records[i].t_ms;
            let j = records[i..].iter().position(|r| r.t_ms != t).map_or(records.len(), |k| i + k);
            // Values expected before this moment are those of the moment before.
            if t > 0 {
                obs.snapshot(t - 1, |n| self.value_of(n));
            }
            for r in &records[i..j] {
                if r.event == TraceEvent::Value {
                    let decl = self.sc.program.var_by_name(&r.name).map(|v| &self.sc.program.vars[v.index()]);
                    if let (Some(decl), Some(text)) = (decl, &r.value) {
                        if let Some(v) = from_shown(&decl.ty, text) {
                            self.values.insert(decl.name.clone(), v);
                        }
                    }
                }
            }
            obs.follow(&records[i..j]);
            let due = obs.judge(t, &|v| self.value_by_id(v));
            for (k, after) in due.faults {
                let at = t + after + jitter(&self.sc.faults[k], &mut self.rng);
                self.plan.push((at, Act::Fault(k)));
            }
            for (k, after) in due.inputs {
                self.plan.push((t + after, Act::Input(k)));
            }
            for (k, after) in due.commands {
                self.plan.push((t + after, Act::Command(k)));
            }
            i = j;
        }
        self.trace.extend(records);
    }

    /// Carries out what is due by chart time `now` (agents that start at 0 start before the coordinator's
    /// first record). An input waits while the coordinator is down, as in the simulation.
    async fn carry_out(&mut self, now: Option<u64>) {
        loop {
            let down = self.coordinator.is_none();
            let due = self
                .plan
                .iter()
                .enumerate()
                .filter(|(_, (t, _))| now.map_or(*t == 0, |n| *t <= n))
                .filter(|(_, (_, act))| !(down && matches!(act, Act::Input(_) | Act::Command(_))))
                .min_by_key(|(k, (t, _))| (*t, *k))
                .map(|(k, _)| k);
            let Some(k) = due else { return };
            let (t, act) = self.plan.remove(k);
            if let Err(e) = self.act(t, act).await {
                self.errors.push(format!("at {}: {e:#}", show_ms(t)));
            }
        }
    }

    async fn act(&mut self, t: u64, act: Act) -> anyhow::Result<()> {
        match act {
            Act::StartAgent(i) => {
                let name = self.sc.agents[i].name.clone();
                self.start_agent(&name)
            }
            Act::Input(i) => {
                for (name, value) in &self.sc.inputs[i].set {
                    self.set(name, value).await?;
                }
                Ok(())
            }
            Act::Command(i) => {
                // Refused or taken, the command is the run's to judge (its trace says which); only a run that
                // does not answer is the runner's error.
                let request = &self.sc.commands[i].request;
                let deadline = Instant::now() + SET_WAIT;
                loop {
                    let replies = crate::client::ctl_on(&self.session, None, request).await?;
                    if !replies.is_empty() {
                        return Ok(());
                    }
                    if Instant::now() >= deadline {
                        anyhow::bail!("cannot send `{}`: no chart answered for {SET_WAIT:?}", request.command);
                    }
                    tokio::time::sleep(Duration::from_millis(20)).await;
                }
            }
            Act::Fault(i) => {
                let f = &self.sc.faults[i];
                self.struck.push((t, f.describe()));
                match f.kind.clone() {
                    FaultKind::Kill(a) => self.kill_agent(&a).await,
                    FaultKind::Restart(a) => {
                        self.kill_agent(&a).await;
                        if !self.wait_gone(&a).await {
                            anyhow::bail!("{a} was killed, but the router still held its name after {GONE_WAIT:?}");
                        }
                        self.start_agent(&a)?;
                    }
                    FaultKind::Cut(a, heal) => {
                        self.cables[&a].cut();
                        if let Some(h) = heal {
                            self.plan.push((t + h, Act::Heal(a)));
                        }
                    }
                    FaultKind::Heal(a) => self.cables[&a].heal(),
                    FaultKind::Link(a, n, lasting) => {
                        self.cables[&a].delay(n.delay_ms);
                        self.plan.push((t + lasting, Act::Undelay(a)));
                    }
                    FaultKind::CrashCoordinator(down) => {
                        if let Some(mut c) = self.coordinator.take() {
                            let _ = c.kill().await;
                        }
                        // What it wrote is read to its end now: its successor's file replaces it.
                        let rest = self.follower.read_new()?;
                        self.backlog.extend(rest);
                        self.plan.push((t + down, Act::CoordinatorUp));
                    }
                }
                Ok(())
            }
            Act::Heal(a) => {
                self.cables[&a].heal();
                Ok(())
            }
            Act::Undelay(a) => {
                // Back to the delay of the whole network.
                self.cables[&a].delay(self.sc.network.delay_ms);
                Ok(())
            }
            Act::CoordinatorUp => {
                // Its successor writes the run again in full, from its journal, and goes on.
                let n = self.coordinator_runs + 1;
                let seen = self.trace.len() + self.backlog.len();
                self.follower = Follower::new(self.dir.join(format!("trace.{n}.jsonl")), seen);
                self.start_coordinator()
            }
        }
    }

    /// Runs the scenario to its end: the chart ends, `until` passes, or `stop` is set.
    async fn drive(&mut self, stop: &AtomicBool) -> Outcome {
        let sc = self.sc;
        let mut obs = Observer::new(sc);
        let mut stopped = false;
        let state = loop {
            if stop.load(Ordering::Relaxed) {
                stopped = true;
                break RunState::Running;
            }
            match self.follower.read_new() {
                Ok(new) => {
                    let mut records = std::mem::take(&mut self.backlog);
                    records.extend(new);
                    if self.t0.is_none() {
                        if let Some(first) = records.first() {
                            self.t0 = Some(Instant::now() - Duration::from_millis(first.t_ms));
                        }
                    }
                    self.take_in(&mut obs, records);
                }
                Err(e) => {
                    self.errors.push(format!("{e:#}"));
                    break RunState::Running;
                }
            }
            let now = self.chart_now();
            if now.is_some_and(|n| n > sc.until_ms) {
                break RunState::Running;
            }
            self.carry_out(now).await;
            if sc.stay && !self.interrupted && self.at_end().await {
                // A run that stays ends as its operator ends it, with an interrupt at its end.
                if let Some(pid) = self.coordinator.as_ref().and_then(Child::id) {
                    unsafe { libc::kill(pid as libc::pid_t, libc::SIGINT) };
                    self.interrupted = true;
                }
            }
            if let Some(c) = self.coordinator.as_mut() {
                if let Ok(Some(status)) = c.try_wait() {
                    self.coordinator = None;
                    match self.follower.read_new() {
                        Ok(rest) => self.take_in(&mut obs, rest),
                        Err(e) => self.errors.push(format!("{e:#}")),
                    }
                    if status.success() {
                        break RunState::Finished;
                    }
                    match status.code() {
                        Some(3) => break RunState::Stopped,
                        Some(4) => break RunState::Aborted,
                        _ => {}
                    }
                    let log = self.dir.join(format!("coordinator.{}.log", self.coordinator_runs));
                    let text = std::fs::read_to_string(&log).unwrap_or_default();
                    if text.contains("the run failed") {
                        break RunState::Failed;
                    }
                    let tail: Vec<&str> = text.lines().rev().take(5).collect::<Vec<_>>().into_iter().rev().collect();
                    self.errors.push(format!("`baton run` exited with {status}: {}", tail.join(" / ")));
                    break RunState::Running;
                }
            }
            tokio::time::sleep(POLL).await;
        };
        let last_t = self.trace.last().map_or(0, |r| r.t_ms);
        let chart_ms = match state {
            RunState::Running if !stopped && self.errors.is_empty() => sc.until_ms,
            _ => last_t.min(sc.until_ms),
        };
        obs.snapshot(chart_ms, |n| self.value_of(n));
        if stopped {
            self.errors.push(format!("stopped at chart time {}, before the run ended", show_ms(chart_ms)));
        }
        let (cases, active_at_failure) = obs.verdicts(&self.trace, &state, chart_ms, &|n| self.value_of(n));
        let mut vars: Vec<(String, String)> = sc
            .program
            .vars
            .iter()
            .filter(|v| !v.hidden)
            .filter_map(|v| self.values.get(&v.name).map(|x| (v.name.clone(), v.ty.show(x))))
            .collect();
        vars.sort();
        let mut faults = std::mem::take(&mut self.struck);
        faults.sort();
        Outcome {
            seed: self.seed,
            chart_ms,
            state,
            cases,
            trace: std::mem::take(&mut self.trace),
            errors: std::mem::take(&mut self.errors),
            faults,
            vars,
            active: obs.active(),
            active_at_failure,
            logs: None,
        }
    }

    /// Whether a run that stays is at its end for good: its last state is complete, stopped or aborted, no
    /// command is left to send, and the run itself is in that state (so that the trace read so far, whose moments
    /// the `when` commands were judged on, has caught up with it).
    async fn at_end(&self) -> bool {
        let Some(last) = self.trace.iter().rev().find(|r| r.event == TraceEvent::State) else { return false };
        let end = matches!(last.name.as_str(), "complete" | "stopped" | "aborted");
        if !end || self.plan.iter().any(|(_, a)| matches!(a, Act::Command(_))) {
            return false;
        }
        match crate::client::status_on(&self.session).await {
            Ok(runs) => !runs.is_empty() && runs.iter().all(|r| r.state.name() == last.name),
            Err(_) => false,
        }
    }

    /// Stops every process it started and closes the router.
    async fn tear_down(mut self) {
        let names: Vec<String> = self.agents.keys().cloned().collect();
        for n in names {
            self.kill_agent(&n).await;
        }
        if let Some(mut c) = self.coordinator.take() {
            let _ = c.kill().await;
        }
        self.cables.clear();
        let _ = self.session.close().await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The observer of real processes reads every value a trace shows, or it keeps a stale one.
    #[test]
    fn watched_values_read_back_as_they_show_infinities_and_nan_included() {
        let real = Type::Real { long: true };
        for v in [1.5, -0.0, f64::INFINITY, f64::NEG_INFINITY, f64::MAX] {
            assert_eq!(from_shown(&real, &Value::Real(v).to_string()), Some(Value::Real(v)));
        }
        let nan = from_shown(&real, &Value::Real(f64::NAN).to_string());
        assert!(matches!(nan, Some(Value::Real(r)) if r.is_nan()), "{nan:?}");
        assert_eq!(from_shown(&Type::Bool, "TRUE"), Some(Value::Bool(true)));
    }
}
