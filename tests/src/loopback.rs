//! Loopback cluster tests' kit: real `baton` and `baton-agent` processes on 127.0.0.1 with a free port,
//! multicast scouting off, every wait on an event under a timeout, every process killed when the cluster is
//! dropped.

use std::path::{Path, PathBuf};
use std::process::{ExitStatus, Stdio};
use std::time::Duration;

use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, ChildStderr, Command};

/// Long enough for a debug build on a loaded 2-core CI machine; a healthy test finishes far earlier.
pub const TIMEOUT: Duration = Duration::from_secs(60);

/// The workspace's binaries, built by `cargo test --workspace` next to the test executable's folder.
pub fn bin(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("test executable");
    // target/<profile>/deps/<test> → target/<profile>/<name>
    let dir = exe.parent().and_then(Path::parent).expect("target dir");
    let path = dir.join(format!("{name}{}", std::env::consts::EXE_SUFFIX));
    assert!(
        path.is_file(),
        "{} is missing: run `cargo test --workspace` (or `cargo build --workspace`) first",
        path.display()
    );
    path
}

pub fn free_port() -> u16 {
    let l = std::net::TcpListener::bind("127.0.0.1:0").expect("bind a loopback port");
    l.local_addr().expect("local address").port()
}

pub fn repo(path: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join(path)
}

/// `zenohd` 1.10.2: `$ZENOHD`, or where `.ci/run` installs it — outside the clone, in the machine's cache of pinned
/// tools (`$BATON_TOOLS`, `~/.cache/baton-tools` by default), so that every clone on the machine shares it — or
/// `target/zenohd`; the test is ignored without it (and fails under CI).
pub fn zenohd() -> PathBuf {
    zenohd_candidates().into_iter().find(|p| p.is_file()).unwrap_or_else(|| {
        crate::harness::missing(&format!(
            "no zenohd at {}: `.ci/run` installs it (`cargo install zenohd@1.10.2 --locked --root \\
             ~/.cache/baton-tools/zenohd-1.10.2`)",
            zenohd_candidates().iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(" or ")
        ))
    })
}

fn zenohd_candidates() -> Vec<PathBuf> {
    let tools = std::env::var_os("BATON_TOOLS")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache/baton-tools")));
    std::env::var_os("ZENOHD")
        .map(PathBuf::from)
        .into_iter()
        .chain(tools.map(|t| t.join("zenohd-1.10.2/bin/zenohd")))
        .chain([repo("target/zenohd/bin/zenohd")])
        .collect()
}

/// Starts `zenohd` with `config`, its output appended to `log`; returns once it accepts connections on `port`. It
/// runs in the repository's folder, as `deploy/`'s READMEs run it (`deploy/acl` names its dictionary from there).
pub async fn start_zenohd(config: &Path, port: u16, log: &Path) -> Child {
    let out = std::fs::OpenOptions::new().create(true).append(true).open(log).expect("zenohd's log");
    let child = Command::new(zenohd())
        .current_dir(repo(""))
        .env("RUST_LOG", "warn")
        .arg("-c")
        .arg(config)
        .stdout(out.try_clone().expect("zenohd's log"))
        .stderr(out)
        .kill_on_drop(true)
        .spawn()
        .expect("start zenohd");
    let up = tokio::time::timeout(TIMEOUT, async {
        while tokio::net::TcpStream::connect(("127.0.0.1", port)).await.is_err() {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await;
    assert!(up.is_ok(), "zenohd never listened on {port}: {}", std::fs::read_to_string(log).unwrap_or_default());
    child
}

pub struct Cluster {
    pub endpoint: String,
    pub dir: tempfile::TempDir,
    agents: Vec<(String, Child)>,
    /// A router of the test's own, when the coordinator joins rather than embeds one (`Cluster::with_router`).
    router: Option<zenoh::Session>,
}

/// A coordinator process, with its stderr readable line by line.
pub struct Coordinator {
    pub child: Child,
    /// Its log, read as it comes by a task of its own (so that a coordinator never waits on a full pipe), and
    /// how far the waits have read it.
    log: Log,
    read: usize,
    pub trace: PathBuf,
    pub summary: PathBuf,
    /// The trace's records when the process started: a resumed run's trace holds its earlier ones.
    trace_before: usize,
}

/// A child's log lines as they come, and a wake-up for each.
#[derive(Clone, Default)]
struct Log {
    lines: std::sync::Arc<std::sync::Mutex<Vec<String>>>,
    more: std::sync::Arc<tokio::sync::Notify>,
    ended: std::sync::Arc<std::sync::atomic::AtomicBool>,
}

impl Log {
    /// Reads `stderr` to its end in a task of its own.
    fn follow(stderr: ChildStderr) -> Log {
        let log = Log::default();
        let out = log.clone();
        tokio::spawn(async move {
            let mut lines = BufReader::new(stderr).lines();
            while let Ok(Some(line)) = lines.next_line().await {
                out.lines.lock().expect("log").push(line);
                out.more.notify_waiters();
            }
            out.ended.store(true, std::sync::atomic::Ordering::SeqCst);
            out.more.notify_waiters();
        });
        log
    }

    fn since(&self, from: usize) -> Vec<String> {
        self.lines.lock().expect("log").get(from..).map(<[String]>::to_vec).unwrap_or_default()
    }
}

impl Default for Cluster {
    fn default() -> Self {
        Self::new()
    }
}

impl Cluster {
    pub fn new() -> Cluster {
        Cluster {
            endpoint: format!("tcp/127.0.0.1:{}", free_port()),
            dir: tempfile::tempdir().expect("temp dir"),
            agents: Vec::new(),
            router: None,
        }
    }

    /// A cluster whose router lives in the test process, so that it outlives a coordinator that is killed.
    /// Coordinators then join it (`coordinator_joining`).
    pub async fn with_router() -> Cluster {
        let mut cluster = Cluster::new();
        let net = baton_proto::cluster::netconfig::NetConfig::router(std::slice::from_ref(&cluster.endpoint));
        let config = zenoh::Config::from_json5(&net.json5()).expect("router config");
        cluster.router = Some(zenoh::open(config).await.expect("start the test's router"));
        cluster
    }

    /// A Zenoh session of the test's own on the cluster's router, to watch the protocol.
    pub async fn watch(&self) -> zenoh::Session {
        let net = baton_proto::cluster::netconfig::NetConfig::client(std::slice::from_ref(&self.endpoint), true);
        zenoh::open(zenoh::Config::from_json5(&net.json5()).expect("config")).await.expect("session")
    }

    /// Starts `baton-agent --name NAME --role …` joining the cluster's router.
    pub fn agent(&mut self, name: &str, roles: &[&str], extra: &[&str]) {
        let endpoint = self.endpoint.clone();
        self.agent_via(Command::new(bin("baton-agent")), &endpoint, name, roles, extra);
    }

    /// Starts an agent that joins the router through `endpoint` (a `baton_host::cable::Cable`'s, say).
    pub fn agent_at(&mut self, endpoint: &str, name: &str, roles: &[&str], extra: &[&str]) {
        self.agent_via(Command::new(bin("baton-agent")), endpoint, name, roles, extra);
    }

    /// The router's TCP address (of `endpoint`, `tcp/127.0.0.1:PORT`).
    pub fn router_addr(&self) -> std::net::SocketAddr {
        self.endpoint.trim_start_matches("tcp/").parse().expect("a tcp endpoint")
    }

    /// Starts an agent inside a network namespace, joining the router at `endpoint`.
    pub fn agent_in(
        &mut self,
        netns: &crate::netns::Netns,
        endpoint: &str,
        name: &str,
        roles: &[&str],
        extra: &[&str],
    ) {
        let mut cmd = Command::new("ip");
        cmd.args(["netns", "exec", netns.name()]).arg(bin("baton-agent"));
        self.agent_via(cmd, endpoint, name, roles, extra);
    }

    fn agent_via(&mut self, mut cmd: Command, endpoint: &str, name: &str, roles: &[&str], extra: &[&str]) {
        let log = std::fs::File::create(self.dir.path().join(format!("{name}.log"))).expect("agent log");
        let trace = self.agent_trace_path(name, self.agents.iter().filter(|(n, _)| n == name).count());
        cmd.args(["--connect", endpoint, "--name", name]).arg("--trace").arg(trace);
        // The agent's state (the terms it remembers) in the cluster's folder, never the user's home: an agent of
        // the same name started again finds it there.
        cmd.env("XDG_STATE_HOME", self.dir.path().join("state"));
        for r in roles {
            cmd.args(["--role", r]);
        }
        cmd.args(extra).stdout(Stdio::null()).stderr(log).kill_on_drop(true);
        self.agents.push((name.to_string(), cmd.spawn().expect("start baton-agent")));
    }

    /// SIGKILLs the agent's process (the most recent one of that name) and waits for it to be gone.
    pub async fn kill_agent(&mut self, name: &str) {
        let (_, child) = self.agents.iter_mut().rev().find(|(n, _)| n == name).expect("agent started");
        child.start_kill().expect("kill the agent");
        tokio::time::timeout(TIMEOUT, child.wait()).await.expect("agent died in time").expect("wait");
    }

    /// Waits (under the timeout) for the agent's process (the most recent one of that name) to end by itself.
    pub async fn wait_agent(&mut self, name: &str) -> ExitStatus {
        let (_, child) = self.agents.iter_mut().rev().find(|(n, _)| n == name).expect("agent started");
        tokio::time::timeout(TIMEOUT, child.wait())
            .await
            .unwrap_or_else(|_| panic!("agent `{name}` did not end"))
            .expect("wait")
    }

    /// Sends a signal (`STOP`, `CONT`…) to the agent's process, as `kill -SIG` does.
    pub fn signal_agent(&self, name: &str, signal: &str) {
        let (_, child) = self.agents.iter().rev().find(|(n, _)| n == name).expect("agent started");
        let pid = child.id().expect("agent running").to_string();
        let status =
            std::process::Command::new("kill").args([&format!("-{signal}"), &pid]).status().expect("kill runs");
        assert!(status.success(), "kill -{signal} {pid}");
    }

    /// The trace of the `nth` process started under `name` (from 0): each has its own.
    fn agent_trace_path(&self, name: &str, nth: usize) -> PathBuf {
        self.dir.path().join(format!("{name}-{nth}.trace.jsonl"))
    }

    /// The trace of the agent's most recent process (`baton-agent --trace`), as far as it is written.
    pub fn agent_trace(&self, name: &str) -> Vec<TraceRecord> {
        let started = self.agents.iter().filter(|(n, _)| n == name).count();
        assert!(started > 0, "agent `{name}` was never started");
        read_trace_so_far(&self.agent_trace_path(name, started - 1))
    }

    /// Waits until the trace of the agent's most recent process has a record that `matches` (`what` says it, for
    /// the failure message); returns that trace so far. Woken by the file system each time its folder changes.
    pub async fn wait_for_agent_trace(
        &self,
        name: &str,
        what: &str,
        matches: impl Fn(&TraceRecord) -> bool,
    ) -> Vec<TraceRecord> {
        let (_watcher, mut changed) = watch(self.dir.path());
        let found = tokio::time::timeout(TIMEOUT, async {
            loop {
                let trace = self.agent_trace(name);
                if trace.iter().any(&matches) || changed.recv().await.is_none() {
                    return trace;
                }
            }
        })
        .await;
        match found {
            Ok(trace) if trace.iter().any(&matches) => trace,
            _ => panic!(
                "agent `{name}`'s trace never showed {what}; its trace:\n{:#?}\nits log:\n{}",
                self.agent_trace(name),
                self.agent_log(name)
            ),
        }
    }

    pub fn agent_log(&self, name: &str) -> String {
        std::fs::read_to_string(self.dir.path().join(format!("{name}.log"))).unwrap_or_default()
    }

    /// Starts `baton run CHART --listen EP --trace … --summary …` (the coordinator embeds the router).
    pub fn coordinator(&self, chart: &Path, extra: &[&str]) -> Coordinator {
        self.start_coordinator(chart, "--listen", extra)
    }

    /// Starts `baton run CHART --connect EP …`: the coordinator joins the test's router (`with_router`).
    pub fn coordinator_joining(&self, chart: &Path, extra: &[&str]) -> Coordinator {
        assert!(self.router.is_some(), "make the cluster with Cluster::with_router");
        self.start_coordinator(chart, "--connect", extra)
    }

    /// Starts `baton run CHART --connect EP …` joining a router the test started itself (a `zenohd`).
    pub fn coordinator_connecting(&self, chart: &Path, extra: &[&str]) -> Coordinator {
        self.start_coordinator(chart, "--connect", extra)
    }

    /// Another coordinator joining the test's router, whose trace and summary files are named after `name`: two
    /// runs behind one router.
    pub fn coordinator_joining_as(&self, name: &str, chart: &Path, extra: &[&str]) -> Coordinator {
        assert!(self.router.is_some(), "make the cluster with Cluster::with_router");
        self.start_coordinator_as(name, chart, "--connect", extra)
    }

    fn start_coordinator(&self, chart: &Path, how: &str, extra: &[&str]) -> Coordinator {
        self.start_coordinator_as("", chart, how, extra)
    }

    fn start_coordinator_as(&self, name: &str, chart: &Path, how: &str, extra: &[&str]) -> Coordinator {
        let trace = self.dir.path().join(format!("trace{name}.jsonl"));
        let summary = self.dir.path().join(format!("summary{name}.json"));
        let trace_before = fresh_trace(&trace, extra);
        let child = Command::new(bin("baton"))
            .arg("run")
            .arg(chart)
            .args([how, &self.endpoint])
            .arg("--trace")
            .arg(&trace)
            .arg("--summary")
            .arg(&summary)
            .args(extra)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .kill_on_drop(true)
            .spawn()
            .expect("start baton run");
        Coordinator::following(child, trace, summary, trace_before)
    }

    /// The run's status as `baton status --json EXTRA…` prints it (its first line: the run behind the router), once
    /// a run answers; `None` while none does.
    pub async fn status_json(&self, extra: &[&str]) -> Option<serde_json::Value> {
        let mut args = vec!["status", "--connect", &self.endpoint, "--json"];
        args.extend(extra);
        let out = self.baton(&args).await;
        let first = out.stdout.split(|b| *b == b'\n').next().unwrap_or_default();
        serde_json::from_slice::<serde_json::Value>(first).ok().filter(|s| s["run"].is_string())
    }

    /// Runs `baton ARGS…` to completion, under the timeout.
    pub async fn baton(&self, args: &[&str]) -> std::process::Output {
        let out = Command::new(bin("baton")).args(args).kill_on_drop(true).output();
        tokio::time::timeout(TIMEOUT, out).await.expect("baton finished in time").expect("baton runs")
    }
}

impl Coordinator {
    /// A coordinator started with its log piped (`stderr`), its trace written to `trace` (which held
    /// `trace_before` records before it started: `fresh_trace`'s count) and its summary to `summary`.
    pub fn following(mut child: Child, trace: PathBuf, summary: PathBuf, trace_before: usize) -> Coordinator {
        let log = Log::follow(child.stderr.take().expect("the coordinator's log is piped"));
        Coordinator { child, log, read: 0, trace, summary, trace_before }
    }

    /// SIGKILLs the coordinator and waits for it to be gone.
    pub async fn kill(mut self) {
        self.child.start_kill().expect("kill the coordinator");
        tokio::time::timeout(TIMEOUT, self.child.wait()).await.expect("coordinator died in time").expect("wait");
    }

    /// What the coordinator logged that no wait read yet, for a failure message.
    pub async fn unread_log(&mut self) -> String {
        let lines = self.log.since(self.read);
        self.read += lines.len();
        lines.join("\n")
    }

    /// Waits until this process is serving its run: its first trace record (the chart's initial steps, or the
    /// run waiting for its start), or, resuming a run whose trace had records, its `recover` record. Returns the
    /// trace so far.
    pub async fn wait_ready(&mut self) -> Vec<TraceRecord> {
        let resumed = self.trace_before > 0;
        self.wait_for_trace("to serve its run", |r| !resumed || r.event == TraceEvent::Recover).await
    }

    /// Waits until the trace has a record this process wrote that `matches` (`what` says it, for the failure
    /// message); returns the trace so far. Woken by the file system each time the trace changes.
    pub async fn wait_for_trace(&mut self, what: &str, matches: impl Fn(&TraceRecord) -> bool) -> Vec<TraceRecord> {
        let before = self.trace_before;
        self.wait_for_trace_from(before, what, matches).await
    }

    /// How many whole records the trace holds now: a mark for `wait_for_trace_after`, taken before the deed
    /// whose record is awaited.
    pub fn trace_mark(&self) -> usize {
        read_trace_so_far(&self.trace).len().max(self.trace_before)
    }

    /// As `wait_for_trace`, for a record written after `mark` (`trace_mark`).
    pub async fn wait_for_trace_after(
        &mut self,
        mark: usize,
        what: &str,
        matches: impl Fn(&TraceRecord) -> bool,
    ) -> Vec<TraceRecord> {
        self.wait_for_trace_from(mark, what, matches).await
    }

    async fn wait_for_trace_from(
        &mut self,
        before: usize,
        what: &str,
        matches: impl Fn(&TraceRecord) -> bool,
    ) -> Vec<TraceRecord> {
        let (_watcher, mut changed) = watch(self.trace.parent().expect("the trace's folder"));
        let found = tokio::time::timeout(TIMEOUT, async {
            loop {
                let trace = read_trace_so_far(&self.trace);
                // A resumed run's trace is cut back to its snapshot and replayed: what it adds is after the
                // records it had, or, cut shorter, any `recover` record.
                let fresh = |i: usize, r: &TraceRecord| i >= before || r.event == TraceEvent::Recover;
                if trace.iter().enumerate().any(|(i, r)| fresh(i, r) && matches(r)) {
                    return Some(trace);
                }
                if self.log.ended.load(std::sync::atomic::Ordering::SeqCst) {
                    return None;
                }
                tokio::select! {
                    _ = changed.recv() => {}
                    () = self.log.more.notified() => {}
                }
            }
        })
        .await;
        match found {
            Ok(Some(trace)) => trace,
            _ => panic!(
                "the coordinator's trace never showed it {what} (its process: {:?}); its trace:\n{:#?}\nits log:\n{}",
                self.child.try_wait(),
                read_trace_so_far(&self.trace),
                self.log.since(0).join("\n")
            ),
        }
    }

    /// Waits for the coordinator to exit, draining its log; returns its status and the whole log.
    pub async fn finish(mut self) -> (ExitStatus, String, Vec<TraceRecord>, serde_json::Value) {
        let done = tokio::time::timeout(TIMEOUT, async {
            let status = self.child.wait().await;
            while !self.log.ended.load(std::sync::atomic::Ordering::SeqCst) {
                let more = self.log.more.notified();
                if self.log.ended.load(std::sync::atomic::Ordering::SeqCst) {
                    break;
                }
                more.await;
            }
            status
        })
        .await;
        let log = self.log.since(0).join("\n");
        let status = match done {
            Ok(s) => s.expect("wait for baton run"),
            Err(_) => panic!("the coordinator did not finish within {TIMEOUT:?}; its log:\n{log}"),
        };
        let trace = read_trace(&self.trace);
        let summary = std::fs::read_to_string(&self.summary)
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok())
            .unwrap_or(serde_json::Value::Null);
        (status, log, trace, summary)
    }
}

/// Before a coordinator with `args` starts: unless it resumes a journal (`--journal` of a folder with something in
/// it), its run starts a trace of its own, so the one an earlier process left at `trace` goes first — the waits on
/// the trace (`Coordinator::wait_for_trace`) then see this run's records only. Returns the records the trace holds
/// as the process starts (counted before it can write one).
pub fn fresh_trace(trace: &Path, args: &[&str]) -> usize {
    let journal = args.iter().position(|a| *a == "--journal").and_then(|i| args.get(i + 1));
    let resumes = journal.is_some_and(|j| std::fs::read_dir(j).is_ok_and(|mut d| d.next().is_some()));
    if !resumes {
        let _ = std::fs::remove_file(trace);
    }
    read_trace(trace).len()
}

/// A wake-up each time something in `dir` changes (a file written, made or removed), while the watcher lives.
pub fn watch(dir: &Path) -> (notify::RecommendedWatcher, tokio::sync::mpsc::UnboundedReceiver<()>) {
    let (tx, changed) = tokio::sync::mpsc::unbounded_channel();
    let mut watcher = notify::recommended_watcher(move |_: notify::Result<notify::Event>| {
        let _ = tx.send(());
    })
    .expect("a file watcher");
    notify::Watcher::watch(&mut watcher, dir, notify::RecursiveMode::NonRecursive).expect("watch the folder");
    (watcher, changed)
}

/// Waits until `ready` gives a value, asking it again each time the file system says something in `dir` changed,
/// under the timeout; `what` names what was waited for, if it never came.
pub async fn when_changed<T>(dir: &Path, what: &str, mut ready: impl FnMut() -> Option<T>) -> T {
    let (_watcher, mut changed) = watch(dir);
    let found = tokio::time::timeout(TIMEOUT, async {
        loop {
            if let Some(value) = ready() {
                return Some(value);
            }
            changed.recv().await?;
        }
    })
    .await;
    found.ok().flatten().unwrap_or_else(|| panic!("{what} never came"))
}

/// The trace's whole lines so far (a line being written is left for later).
pub fn read_trace_so_far(path: &Path) -> Vec<TraceRecord> {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let whole = text.rfind('\n').map_or("", |end| &text[..end]);
    whole.lines().filter_map(|l| serde_json::from_str(l).ok()).collect()
}

pub fn read_trace(path: &Path) -> Vec<TraceRecord> {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    text.lines().map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("bad trace line {l}: {e}"))).collect()
}

/// The records of one event, as (t_ms, name, agent).
pub fn events(trace: &[TraceRecord], event: TraceEvent) -> Vec<(u64, String, Option<String>)> {
    trace.iter().filter(|r| r.event == event).map(|r| (r.t_ms, r.name.clone(), r.agent.clone())).collect()
}

/// Where and in which epoch each token entering `step` was dispatched, in order, as (agent, epoch).
pub fn dispatches(trace: &[TraceRecord], step: &str) -> Vec<(String, Option<u32>)> {
    trace
        .iter()
        .filter(|r| r.event == TraceEvent::Dispatch && r.name == step)
        .map(|r| (r.agent.clone().unwrap_or_default(), r.epoch))
        .collect()
}

/// The invariants of `crate::invariants::check` on a finished run's trace of `chart` (its first POU), with every
/// token back.
pub fn check_trace_invariants(trace: &[TraceRecord], chart: &Path) {
    check_trace_invariants_with_tokens_out(trace, chart, 0);
}

/// The same for a run that ended with `out` tokens still out (a run that failed).
pub fn check_trace_invariants_with_tokens_out(trace: &[TraceRecord], chart: &Path, out: usize) {
    let source = std::fs::read_to_string(chart).unwrap_or_else(|e| panic!("{}: {e}", chart.display()));
    let report = baton_proto::pipeline::check_source(&source);
    let program = report.charts.first().and_then(|c| c.program.as_ref()).expect("a valid chart");
    if let Err(why) = crate::invariants::check(trace, program, out == 0) {
        panic!("trace of {}: {why}", chart.display());
    }
    assert_eq!(crate::invariants::tokens_out(trace), out, "tokens out at the end of the trace of {}", chart.display());
}

/// The id of step `name` in the first chart of `chart`, as dispatches carry it.
pub fn step_id(chart: &Path, name: &str) -> u32 {
    let src = std::fs::read_to_string(chart).unwrap_or_else(|e| panic!("{}: {e}", chart.display()));
    let report = baton_proto::pipeline::check_source(&src);
    let program = report.charts[0].program.as_ref().expect("a valid chart");
    program.steps.iter().position(|s| s.name == name).expect("step") as u32
}

pub type Samples = zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>;

/// The status of a run behind `session`'s router, asked as `baton status` asks it: of `key` (`keys::status(run)`),
/// or of any run (`keys::status_any_run()`), the first to answer.
pub async fn status_of(session: &zenoh::Session, key: String) -> baton_proto::cluster::wire::StatusReport {
    use baton_proto::cluster::wire;
    let replies = session.get(key).timeout(TIMEOUT).await.expect("status query");
    let reply = replies.recv_async().await.expect("a status reply");
    wire::decode(&reply.result().expect("ok").payload().to_bytes()).expect("a status")
}

/// Where commands reach the one process of agent `name` now: its command key, found as a coordinator finds it
/// (the incarnation its info answers with).
pub async fn cmd_key_of(session: &zenoh::Session, name: &str) -> String {
    use baton_proto::cluster::{keys, wire};
    let info = session.get(keys::agent_info(name)).timeout(TIMEOUT).await.expect("info query");
    let info = info.recv_async().await.unwrap_or_else(|_| panic!("{name} answers"));
    let info: wire::AgentInfo = wire::decode(&info.result().expect("ok").payload().to_bytes()).expect("info");
    keys::agent_cmd(name, info.incarnation)
}

/// Waits, on a subscriber of the agents' command keys, for the dispatch entering step `entry` in `epoch`;
/// returns the agent it went to and the token.
pub async fn next_dispatch(cmds: &Samples, entry: u32, epoch: u32) -> (String, baton_proto::cluster::wire::TokenId) {
    next_dispatch_within(cmds, entry, epoch)
        .await
        .unwrap_or_else(|| panic!("step {entry} was not dispatched in epoch {epoch} within {TIMEOUT:?}"))
}

/// `next_dispatch`, or `None` after `TIMEOUT`, so that the caller can say what the processes logged.
pub async fn next_dispatch_within(
    cmds: &Samples,
    entry: u32,
    epoch: u32,
) -> Option<(String, baton_proto::cluster::wire::TokenId)> {
    use baton_proto::cluster::wire::{self, ToAgent};
    let found = tokio::time::timeout(TIMEOUT, async {
        while let Ok(sample) = cmds.recv_async().await {
            if let Ok(ToAgent::Dispatch { entry: e, epoch: n, token, .. }) = wire::decode(&sample.payload().to_bytes())
            {
                if (e, n) == (entry, epoch) {
                    let agent = sample.key_expr().as_str().split('/').nth(2).map(str::to_string);
                    return agent.map(|a| (a, token));
                }
            }
        }
        None
    })
    .await;
    found.ok().flatten()
}

/// `baton deploy certs --ca PKI ARGS…` (names and `--san`s), which must succeed.
pub fn deploy_certs(pki: &Path, args: &[&str]) {
    let out = std::process::Command::new(bin("baton"))
        .args(["deploy", "certs", "--ca"])
        .arg(pki)
        .args(args)
        .output()
        .expect("baton deploy certs runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

/// The Zenoh configuration file of process `name` of the CA in `pki`, written in `dir` from the deployment's own
/// templates (`deploy/tls/router.json5` for one that listens, `client.json5` for one that connects), their paths
/// and names put to the test's.
pub fn tls_config(dir: &Path, pki: &Path, name: &str, listen: bool) -> PathBuf {
    let (template, example) = if listen { ("router.json5", "router") } else { ("client.json5", "robot1") };
    let text = std::fs::read_to_string(repo(&format!("deploy/tls/{template}")))
        .expect("the template")
        .replace(&format!("/etc/baton/pki/{example}."), &format!("/etc/baton/pki/{name}."))
        .replace("/etc/baton/pki/", &format!("{}/", pki.display()));
    let path = dir.join(format!("{name}-{}.json5", if listen { "router" } else { "client" }));
    std::fs::write(&path, text).expect("write the configuration");
    path
}

/// Who a client without a certificate or a user name sends commands as, as the book says: `user@host` (the login
/// name, the machine's host name), made a key's word by `keys::sender_name`.
pub fn who_sends() -> String {
    let user = std::env::var("USER").or_else(|_| std::env::var("LOGNAME")).unwrap_or_else(|_| "unknown".into());
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
    baton_proto::cluster::keys::sender_name(&format!("{user}@{}", host.trim()))
}
