//! `baton demo`: a router, a coordinator and simulated robots as separate processes on loopback, running the
//! bundled cell chart, with live progress and a summary.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader, IsTerminal};
use std::path::{Path, PathBuf};
use std::process::{ExitCode, Stdio};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context};
use baton_proto::cluster::netconfig::NetConfig;
use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use indicatif::{ProgressBar, ProgressStyle};
use tokio::process::{Child, Command};

use crate::demo_chart::cell_chart;
use baton_host::ZenohResult;

/// The demo gives up after this long: the default cell finishes in a few seconds.
const DEMO_TIMEOUT: Duration = Duration::from_secs(300);

pub struct DemoOptions {
    pub agents: usize,
    pub parts: u32,
    /// Keep the run's files (chart, trace, summary, agent logs) here instead of a temporary folder.
    pub keep: Option<PathBuf>,
    /// Where the recording goes (`baton-demo.rrd` in the current folder unless told; served with the console).
    pub rerun: crate::recording::Sink,
    /// Serve the operator console on this loopback address while the cell runs.
    pub console: Option<std::net::SocketAddr>,
}

/// `baton-agent`, next to this executable (as cargo builds them) or on the PATH.
pub fn agent_binary() -> anyhow::Result<PathBuf> {
    let exe = std::env::current_exe().context("cannot locate this executable")?;
    let beside = exe.with_file_name(format!("baton-agent{}", std::env::consts::EXE_SUFFIX));
    if beside.is_file() {
        return Ok(beside);
    }
    on_path("baton-agent").ok_or_else(|| {
        anyhow!(
            "`baton-agent` is neither beside {} nor on the PATH: build both with `cargo build --release`",
            exe.display()
        )
    })
}

/// A free TCP port on 127.0.0.1: bound, read, released.
pub fn free_port() -> anyhow::Result<u16> {
    let l = std::net::TcpListener::bind("127.0.0.1:0").context("cannot bind a loopback port")?;
    Ok(l.local_addr()?.port())
}

pub async fn demo(opts: DemoOptions) -> anyhow::Result<ExitCode> {
    if opts.agents == 0 || opts.agents > 64 {
        bail!("--agents must be between 1 and 64");
    }
    if opts.parts == 0 {
        bail!("--parts must be at least 1");
    }
    let agent_bin = agent_binary()?;
    let exe = std::env::current_exe()?;
    let tmp;
    let dir: &Path = match &opts.keep {
        Some(d) => {
            std::fs::create_dir_all(d).with_context(|| format!("cannot create {}", d.display()))?;
            d
        }
        None => {
            tmp = tempfile::tempdir().context("cannot create a temporary folder")?;
            tmp.path()
        }
    };
    // The console's port first: taken, the demo does not start.
    let console = if let Some(addr) = opts.console { Some(crate::console::bind_local(addr).await?) } else { None };
    let chart = dir.join("cell.st");
    std::fs::write(&chart, cell_chart(opts.agents))?;
    let trace = dir.join("trace.jsonl");
    let summary = dir.join("summary.json");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port()?);

    // The router: this process.
    let net = NetConfig::router(std::slice::from_ref(&endpoint));
    let config = zenoh::Config::from_json5(&net.json5()).zenoh()?;
    let router = zenoh::open(config).await.map_err(|e| anyhow!("cannot start the router on {endpoint}: {e}"))?;
    println!("baton demo: router on {endpoint}, {} robot(s), {} part(s)", opts.agents, opts.parts);
    let console = console.map(|listener| crate::console::spawn(listener, vec![endpoint.clone()], None));

    let mut agents = start_robots(&agent_bin, &endpoint, dir, opts.agents)?;
    let coord_log = dir.join("coordinator.log");
    let (rerun, rerun_arg) = rerun_sink(&opts)?;
    let mut coordinator = Command::new(&exe)
        .arg("run")
        .arg(&chart)
        .args(["--connect", &endpoint, "--quiet", "--set", &format!("parts={}", opts.parts)])
        .arg("--trace")
        .arg(&trace)
        .arg("--summary")
        .arg(&summary)
        .args(["--rerun", &rerun_arg])
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&coord_log)?)
        .kill_on_drop(true)
        .spawn()
        .context("cannot start the coordinator")?;

    let started = Instant::now();
    let mut progress = Progress::new(opts.parts as u64, &trace);
    let mut ticker = tokio::time::interval(Duration::from_millis(100));
    // SIGTERM reaches only this process: the coordinator and the agents are stopped here (they are killed on
    // drop), not left behind.
    let mut sigterm = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
    let status = loop {
        tokio::select! {
            st = coordinator.wait() => break st?,
            _ = ticker.tick() => {
                progress.poll();
                if started.elapsed() > DEMO_TIMEOUT {
                    let _ = coordinator.kill().await;
                    progress.finish();
                    bail!("the demo did not finish in {} s; logs are in {}", DEMO_TIMEOUT.as_secs(), dir.display());
                }
            }
            _ = tokio::signal::ctrl_c() => {
                // A terminal's Ctrl-C reaches the coordinator too: it stops its run and closes its recording.
                if tokio::time::timeout(Duration::from_secs(5), coordinator.wait()).await.is_err() {
                    let _ = coordinator.kill().await;
                }
                progress.finish();
                bail!("interrupted");
            }
            _ = sigterm.recv() => {
                let _ = coordinator.kill().await;
                progress.finish();
                bail!("terminated");
            }
        }
    };
    progress.poll();
    progress.finish();
    for a in &mut agents {
        let _ = a.kill().await;
    }
    // The console is a client of this router: it goes first.
    if let Some(console) = console {
        console.stop().await;
    }
    router.close().await.zenoh()?;
    report_end(&opts, status, &coord_log, &summary, &progress, started.elapsed(), &rerun, dir)
}

/// How the demo's run ended, told to the user: by an operator, failed (with the coordinator's log), or its summary
/// and where its files and recording are.
#[allow(clippy::too_many_arguments)]
fn report_end(
    opts: &DemoOptions,
    status: std::process::ExitStatus,
    coord_log: &Path,
    summary: &Path,
    progress: &Progress,
    elapsed: Duration,
    rerun: &crate::recording::Sink,
    dir: &Path,
) -> anyhow::Result<ExitCode> {
    // An operator's `baton ctl stop` or `abort` ends the run as asked: its summary says how far it got.
    let by_operator = matches!(status.code(), Some(3 | 4));
    if by_operator {
        let how = if status.code() == Some(3) { "stopped" } else { "aborted" };
        println!("baton demo: the run was {how} by an operator (baton ctl)");
    }
    if !status.success() && !by_operator {
        let log = std::fs::read_to_string(coord_log).unwrap_or_default();
        eprintln!("{log}");
        bail!("the coordinator failed ({status}); its log is above");
    }
    let text = std::fs::read_to_string(summary).context("the coordinator wrote no summary")?;
    let s: serde_json::Value = serde_json::from_str(&text)?;
    print_summary(&s, progress, elapsed);
    if opts.keep.is_some() {
        println!("files (chart, trace, summary, logs): {}", dir.display());
    }
    if let crate::recording::Sink::Save(p) = rerun {
        let shown = opts.rerun_path_as_given().unwrap_or(p);
        println!("recording: {} — open it with: rerun {}", p.display(), shown.display());
        if on_path("rerun").is_none() {
            println!("(the Rerun viewer is not on the PATH: pip install rerun-sdk==0.36.3, or cargo install rerun-cli --version 0.36.3 --locked)");
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// The demo's robots: `count` agents on `endpoint`, the first two with the assembler role, each logging to the folder.
fn start_robots(agent_bin: &Path, endpoint: &str, dir: &Path, count: usize) -> anyhow::Result<Vec<Child>> {
    let mut agents: Vec<Child> = Vec::new();
    for k in 1..=count {
        let name = format!("robot{k}");
        let log = std::fs::File::create(dir.join(format!("{name}.log")))?;
        let mut cmd = Command::new(agent_bin);
        cmd.args(["--connect", endpoint, "--name", &name, "--lease-ms", "2000"]);
        // Two robots share the assembler role (one if the cell has one): the coordinator picks the less busy.
        if k <= 2 {
            cmd.args(["--role", "assembler"]);
        }
        cmd.stdout(Stdio::null()).stderr(log).kill_on_drop(true);
        agents.push(cmd.spawn().with_context(|| format!("cannot start {}", agent_bin.display()))?);
    }
    Ok(agents)
}

/// Where the coordinator records the run, and its `--rerun` argument.
fn rerun_sink(opts: &DemoOptions) -> anyhow::Result<(crate::recording::Sink, String)> {
    // The coordinator runs in this folder's child process: a relative recording path is made absolute here.
    let rerun = match &opts.rerun {
        crate::recording::Sink::Save(p) => crate::recording::Sink::Save(std::path::absolute(p)?),
        other => other.clone(),
    };
    if let crate::recording::Sink::Connect(url) = &rerun {
        crate::recording::reachable(url.as_deref().unwrap_or(crate::recording::DEFAULT_VIEWER_URL))?;
    }
    let rerun_arg = match &rerun {
        crate::recording::Sink::Off => "off".to_string(),
        crate::recording::Sink::Save(p) => format!("save:{}", p.display()),
        crate::recording::Sink::Connect(None) => "connect".to_string(),
        crate::recording::Sink::Connect(Some(url)) => format!("connect:{url}"),
        crate::recording::Sink::Spawn => "spawn".to_string(),
        // The console the demo serves is on loopback, which Rerun's server allows.
        crate::recording::Sink::Serve { addr, .. } => format!("serve:{addr}"),
    };
    Ok((rerun, rerun_arg))
}

/// Follows the trace file as the coordinator writes it.
struct Progress {
    bar: ProgressBar,
    path: PathBuf,
    offset: u64,
    partial: String,
    active: BTreeMap<String, Option<String>>,
    parts_done: u64,
    pub dispatched: u64,
    pub per_agent: BTreeMap<String, u64>,
    tty: bool,
}

impl Progress {
    fn new(parts: u64, path: &Path) -> Progress {
        let tty = std::io::stderr().is_terminal();
        let bar = if tty { ProgressBar::new(parts) } else { ProgressBar::hidden() };
        let style = ProgressStyle::with_template("{elapsed:>4} [{bar:30}] {pos}/{len} parts  {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> ");
        bar.set_style(style);
        Progress {
            bar,
            path: path.to_path_buf(),
            offset: 0,
            partial: String::new(),
            active: BTreeMap::new(),
            parts_done: 0,
            dispatched: 0,
            per_agent: BTreeMap::new(),
            tty,
        }
    }

    fn poll(&mut self) {
        let Ok(mut f) = std::fs::File::open(&self.path) else { return };
        use std::io::{Seek, SeekFrom};
        if f.seek(SeekFrom::Start(self.offset)).is_err() {
            return;
        }
        let mut reader = BufReader::new(f);
        loop {
            let mut line = String::new();
            match reader.read_line(&mut line) {
                Ok(0) | Err(_) => break,
                Ok(n) => {
                    self.offset += n as u64;
                    if !line.ends_with('\n') {
                        self.partial.push_str(&line);
                        continue;
                    }
                    let full = std::mem::take(&mut self.partial) + &line;
                    if let Ok(rec) = serde_json::from_str::<TraceRecord>(&full) {
                        self.on_record(rec);
                    }
                }
            }
        }
        let now: Vec<String> = self
            .active
            .iter()
            .map(|(s, a)| match a {
                Some(a) => format!("{s}@{a}"),
                None => s.clone(),
            })
            .collect();
        self.bar.set_message(now.join(" "));
    }

    fn on_record(&mut self, rec: TraceRecord) {
        match rec.event {
            TraceEvent::Activate => {
                self.active.insert(rec.name.clone(), rec.agent.clone());
                if rec.name == "Count" {
                    self.parts_done += 1;
                    self.bar.set_position(self.parts_done);
                    if !self.tty {
                        println!("{:>6} ms  part {} done", rec.t_ms, self.parts_done);
                    }
                }
            }
            TraceEvent::Deactivate => {
                self.active.remove(&rec.name);
            }
            TraceEvent::Dispatch => {
                self.dispatched += 1;
                if let Some(a) = rec.agent {
                    *self.per_agent.entry(a).or_default() += 1;
                }
            }
            TraceEvent::SkillFault if !self.tty => {
                println!("{:>6} ms  {} failed on {}: rework", rec.t_ms, rec.name, rec.agent.unwrap_or_default());
            }
            _ => {}
        }
    }

    fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

fn print_summary(s: &serde_json::Value, progress: &Progress, elapsed: Duration) {
    let var = |name: &str| s["vars"][name].as_str().unwrap_or("?").to_string();
    println!("parts done: {} (reworks: {})", var("done"), var("reworks"));
    println!("chart time: {} ms (demo, with start-up: {:.1} s)", s["duration_ms"], elapsed.as_secs_f64());
    let per_agent: Vec<String> = progress.per_agent.iter().map(|(a, n)| format!("{a} {n}")).collect();
    println!(
        "tokens dispatched: {} ({}); returned: {}; messages dropped: {}",
        s["tokens_dispatched"],
        per_agent.join(", "),
        s["tokens_returned"],
        s["messages_dropped"]
    );
    println!("{:<12} {:>11} {:>12} {:>10}", "step", "activations", "active ms", "ms each");
    if let Some(steps) = s["steps"].as_object() {
        for (name, t) in steps {
            let n = t["activations"].as_u64().unwrap_or(0);
            let ms = t["active_ms"].as_u64().unwrap_or(0);
            let each = ms.checked_div(n).unwrap_or(0);
            println!("{name:<12} {n:>11} {ms:>12} {each:>10}");
        }
    }
}

impl DemoOptions {
    /// The recording's path as the user gave it (relative paths read better in the printed command).
    fn rerun_path_as_given(&self) -> Option<&Path> {
        match &self.rerun {
            crate::recording::Sink::Save(p) => Some(p.as_path()),
            _ => None,
        }
    }
}

/// The executable `name` in the first of the PATH's folders that has it.
pub(crate) fn on_path(name: &str) -> Option<PathBuf> {
    let paths = std::env::var_os("PATH")?;
    std::env::split_paths(&paths).map(|dir| dir.join(name)).find(|c| c.is_file())
}
