//! The user guide's chapter "Deploying" as a test: its commands for a secured cell, as written there — read from the
//! chapter, run with `sh` in a folder of their own, the router's host and port put to a free loopback port — on a
//! real `zenohd` 1.10.2 and on the router embedded in the coordinator. The cell runs to its end (a 5 s weld among 11
//! s of motions, under `--on-agent-loss reassign`) with no fence, no alarm and no skill cancelled; the operator's
//! `set`, `hold` and `unhold` are taken and traced with her name; what the chapter shows refused is refused, with
//! its reason. And every message each process sent (`BATON_TRAFFIC`, `baton_host::traffic`) is one the generated
//! rules let through, in and out — so that a message added to Baton without its rule fails here.

use std::path::{Path, PathBuf};
use std::time::Duration;

use baton_proto::exec::trace::TraceEvent;
use baton_tests::access::{read_traffic, unmet, Rules};
use baton_tests::http::{http, Events};
use baton_tests::loopback::{bin, free_port, read_trace, repo, zenohd, TIMEOUT};
use tokio::process::{Child, Command};

baton_tests::harness_main!(tokio the_chapter_runs_on_zenohd, tokio the_chapter_runs_on_the_embedded_router);

async fn the_chapter_runs_on_zenohd() {
    cell(Variant::Zenohd).await;
}

async fn the_chapter_runs_on_the_embedded_router() {
    cell(Variant::Embedded).await;
}

#[derive(Clone, Copy, PartialEq)]
enum Variant {
    Zenohd,
    Embedded,
}

impl Variant {
    fn tag(self) -> &'static str {
        match self {
            Variant::Zenohd => "zenohd",
            Variant::Embedded => "embedded",
        }
    }
}

/// The chapter's blocks that follow a `<!-- deploying.rs: TAG -->` marker, with their tags, in order; a command's
/// continuation lines (`\`) joined.
fn chapter() -> Vec<(String, Vec<String>)> {
    let text = std::fs::read_to_string(repo("docs/book/src/deploying.md")).expect("the chapter");
    let mut blocks = Vec::new();
    let mut lines = text.lines();
    while let Some(line) = lines.next() {
        let Some(tag) = line.strip_prefix("<!-- deploying.rs: ").and_then(|t| t.strip_suffix(" -->")) else {
            continue;
        };
        let fence = lines.next().expect("a block after the marker");
        assert!(fence.starts_with("```"), "a code block follows `{line}`");
        let mut commands = Vec::new();
        let mut current = String::new();
        for l in lines.by_ref().take_while(|l| !l.starts_with("```")) {
            match l.strip_suffix('\\') {
                Some(part) => current.push_str(part),
                None => {
                    current.push_str(l);
                    commands.push(std::mem::take(&mut current).split_whitespace().collect::<Vec<_>>().join(" "));
                }
            }
        }
        blocks.push((tag.to_string(), commands));
    }
    blocks
}

/// A command of the chapter put to this machine: the router's host and port to a loopback port, the console's
/// to another.
fn here(command: &str, ports: Ports) -> String {
    command
        .replace("router.cell4.local:7447", &format!("127.0.0.1:{}", ports.router))
        .replace("0.0.0.0:7447", &format!("127.0.0.1:{}", ports.router))
        .replace("127.0.0.1:8080", &format!("127.0.0.1:{}", ports.console))
}

#[derive(Clone, Copy)]
struct Ports {
    router: u16,
    console: u16,
}

/// Who a command's process is, as the router knows it: the certificate its `--zenoh-config` names (the
/// coordinator embedding the router is the coordinator).
fn identity(command: &str) -> String {
    let arg = command.split_whitespace().skip_while(|w| *w != "--zenoh-config").nth(1).expect("--zenoh-config");
    match Path::new(arg).file_stem().and_then(|s| s.to_str()).expect("a file") {
        "coordinator-router" => "coordinator".to_string(),
        name => name.to_string(),
    }
}

/// The folder the commands run in, the programs they name on its PATH, and the processes they left running.
struct Shell {
    dir: tempfile::TempDir,
    path: String,
    running: Vec<(String, Child)>,
}

impl Shell {
    fn new(variant: Variant) -> Shell {
        let dir = tempfile::tempdir().expect("a folder");
        std::fs::create_dir_all(dir.path().join("examples")).expect("examples");
        std::fs::copy(repo("examples/secured_cell.st"), dir.path().join("examples/secured_cell.st")).expect("copy");
        let mut path: Vec<PathBuf> = vec![bin("baton").parent().expect("target").to_path_buf()];
        if variant == Variant::Zenohd {
            path.push(zenohd().parent().expect("zenohd's folder").to_path_buf());
        }
        path.extend(std::env::split_paths(&std::env::var_os("PATH").unwrap_or_default()));
        let path = std::env::join_paths(path).expect("PATH").into_string().expect("utf-8");
        Shell { dir, path, running: Vec::new() }
    }

    fn command(&self, command: &str, traffic: Option<&str>) -> Command {
        let mut cmd = Command::new("sh");
        cmd.arg("-c").arg(format!("exec {command}")).current_dir(self.dir.path()).env("PATH", &self.path);
        cmd.env_remove("BATON_TRAFFIC");
        if let Some(who) = traffic {
            cmd.env("BATON_TRAFFIC", self.dir.path().join(format!("traffic/{who}.traffic")));
        }
        cmd.kill_on_drop(true);
        cmd
    }

    /// Runs a command to its end: its exit status and what it said.
    async fn run(&self, command: &str, traffic: Option<&str>) -> (Option<i32>, String) {
        let out = self.command(command, traffic).output();
        let out = tokio::time::timeout(TIMEOUT, out).await.unwrap_or_else(|_| panic!("`{command}` did not end"));
        let out = out.expect("sh runs");
        let said = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
        (out.status.code(), said)
    }

    /// Starts a command that keeps running (`… &`), its output in `LOG.log`, and waits until it is ready: a router
    /// or a console listening on its port, a coordinator running its chart, an agent ready.
    async fn start(&mut self, command: &str, ports: Ports, traffic: Option<&str>) {
        let name = format!("process-{}", self.running.len());
        let log = std::fs::File::create(self.dir.path().join(format!("{name}.log"))).expect("a log");
        let child = self
            .command(command, traffic)
            .stdout(log.try_clone().expect("log"))
            .stderr(log)
            .spawn()
            .expect("start the command");
        self.running.push((name.clone(), child));
        let ready = tokio::time::timeout(TIMEOUT, async {
            loop {
                let said = self.log(&name);
                let up = if command.starts_with("zenohd") {
                    tokio::net::TcpStream::connect(("127.0.0.1", ports.router)).await.is_ok()
                } else if command.starts_with("baton console") {
                    tokio::net::TcpStream::connect(("127.0.0.1", ports.console)).await.is_ok()
                } else if command.starts_with("baton run") {
                    said.contains("running chart")
                } else {
                    said.contains(" ready on ")
                };
                if up {
                    return;
                }
                tokio::time::sleep(Duration::from_millis(20)).await;
            }
        })
        .await;
        assert!(ready.is_ok(), "`{command}` never came up:\n{}", self.log(&name));
    }

    fn log(&self, name: &str) -> String {
        std::fs::read_to_string(self.dir.path().join(format!("{name}.log"))).unwrap_or_default()
    }

    /// Every running process's log, for a failure's message.
    fn logs(&self) -> String {
        self.running.iter().map(|(n, _)| format!("=== {n}\n{}", self.log(n))).collect()
    }
}

async fn cell(variant: Variant) {
    let ports = Ports { router: free_port(), console: free_port() };
    let mut sh = Shell::new(variant);
    std::fs::create_dir_all(sh.dir.path().join("traffic")).expect("traffic");
    let blocks = chapter();
    let refused = blocks.iter().find(|(t, _)| t == "refused").map(|(_, c)| c.clone()).expect("the refused block");
    let mut coordinator = None;
    for (_, commands) in blocks.iter().filter(|(t, _)| t == "both" || t == variant.tag()) {
        for command in commands {
            let command = here(command, ports);
            let processes = command.starts_with("baton run")
                || command.starts_with("baton console")
                || command.starts_with("baton-agent")
                || command.starts_with("baton s")
                || command.starts_with("baton ctl");
            let who = processes.then(|| identity(&command));
            match command.strip_suffix(" &") {
                Some(background) => {
                    if background.starts_with("baton run") {
                        coordinator = Some(sh.running.len());
                    }
                    sh.start(background, ports, who.as_deref()).await;
                    // Once both robots are ready, and before the operator starts the cell: what is refused.
                    if background.contains("--name robot2") {
                        check_refused(&sh, &refused, ports).await;
                    }
                }
                None => {
                    let (code, said) = sh.run(&command, who.as_deref()).await;
                    assert_eq!(code, Some(0), "`{command}`: {said}\n{}", sh.logs());
                    // Held, the run stays for anna's console to be read.
                    if command.contains(" hold ") {
                        console_follows(&sh, ports.console).await;
                    }
                }
            }
        }
    }
    // The run goes to its end.
    let at = coordinator.expect("the chapter starts a coordinator");
    let (name, child) = &mut sh.running[at];
    let name = name.clone();
    let status = tokio::time::timeout(Duration::from_secs(120), child.wait()).await;
    let status = status.unwrap_or_else(|_| panic!("the run did not end:\n{}", sh.logs())).expect("wait");
    let log = sh.log(&name);
    assert!(status.success(), "{log}\n{}", sh.logs());
    let trace = read_trace(&sh.dir.path().join("trace.jsonl"));
    assert!(trace.iter().any(|r| r.event == TraceEvent::Activate && r.name == "Done"), "{log}");
    let bad: Vec<_> = trace
        .iter()
        .filter(|r| matches!(r.event, TraceEvent::Alarm | TraceEvent::SkillFault | TraceEvent::AgentLost))
        .collect();
    assert!(bad.is_empty(), "alarms, cancelled skills or lost agents: {bad:#?}\n{}", sh.logs());
    for (_, child) in &mut sh.running {
        let _ = child.start_kill();
    }
    let fenced: Vec<String> =
        sh.running.iter().map(|(n, _)| sh.log(n)).filter(|l| l.contains("no contact with the router")).collect();
    assert!(fenced.is_empty(), "an agent fenced itself: {fenced:#?}");
    // The weld ran its 5 s: nothing cut it short.
    let at = |e: TraceEvent, n: &str| trace.iter().find(|r| r.event == e && r.name == n).map(|r| r.t_ms);
    let weld = at(TraceEvent::Deactivate, "Weld").expect("welded") - at(TraceEvent::Activate, "Weld").expect("weld");
    assert!(weld >= 5_000, "the weld lasted {weld} ms");
    // The operator's doing, traced with the name her certificate carries.
    let by = |e: TraceEvent, n: &str| trace.iter().find(|r| r.event == e && r.name == n).and_then(|r| r.by.clone());
    assert_eq!(by(TraceEvent::Set, "go").as_deref(), Some("anna"));
    assert_eq!(by(TraceEvent::Command, "hold").as_deref(), Some("anna"));
    assert_eq!(by(TraceEvent::Command, "unhold").as_deref(), Some("anna"));
    assert!(trace.iter().any(|r| r.event == TraceEvent::State && r.name == "held"), "it was held");
    // Every message every process sent, against the rules the chapter generated.
    let file = match variant {
        Variant::Zenohd => "zenohd.json5",
        Variant::Embedded => "coordinator-router.json5",
    };
    let rules = Rules::read(&sh.dir.path().join(file));
    let traffic = read_traffic(&sh.dir.path().join("traffic"));
    let who: Vec<&str> = traffic.keys().map(String::as_str).collect();
    assert_eq!(who, ["anna", "coordinator", "robot1", "robot2"], "every process listed what it sent");
    let missing = unmet(&rules, &traffic);
    assert!(missing.is_empty(), "messages the rules of {file} do not let through:\n  {}", missing.join("\n  "));
}

/// The chapter's refusals: each `$ command` it shows, run, says each line the chapter shows after it, and fails.
async fn check_refused(sh: &Shell, block: &[String], ports: Ports) {
    let mut i = 0;
    while i < block.len() {
        let command = block[i].strip_prefix("$ ").expect("a `$ command` line");
        let expected: Vec<&String> = block[i + 1..].iter().take_while(|l| !l.starts_with("$ ")).collect();
        i += 1 + expected.len();
        let (code, said) = sh.run(&here(command, ports), None).await;
        assert_ne!(code, Some(0), "`{command}` was not refused: {said}");
        for line in expected {
            assert!(said.contains(&here(line, ports)), "`{command}` said:\n{said}\nnot:\n{line}");
        }
    }
}

/// anna's console, behind the rules, as her page reads it while the run is held: the run, its chart drawn, and her
/// hold in the run's history with her name.
async fn console_follows(sh: &Shell, port: u16) {
    let addr = format!("127.0.0.1:{port}");
    let (status, state) = http(&addr, "GET", "/api/state", None).await;
    assert_eq!(status, 200, "{state}\n{}", sh.logs());
    let state: serde_json::Value = serde_json::from_str(&state).expect("the state is JSON");
    let run =
        state["runs"][0]["run"].as_str().unwrap_or_else(|| panic!("no run on the console: {state}\n{}", sh.logs()));
    let (status, svg) = http(&addr, "GET", &format!("/api/runs/{run}/chart.svg"), None).await;
    assert_eq!(status, 200, "the chart behind the rules: {svg}\n{}", sh.logs());
    assert!(svg.contains("data-step=\"Weld\""), "{svg}");
    // The history, as the console heard it or asked the coordinator for it: read again each time it grows.
    let mut events = Events::open(&addr).await;
    let commands = loop {
        let (_, history) = http(&addr, "GET", &format!("/api/runs/{run}/history"), None).await;
        let history: Vec<serde_json::Value> = serde_json::from_str(&history).expect("a history is JSON");
        let by_anna: Vec<String> = history
            .iter()
            .filter(|e| e["event"] == "command" && e["by"] == "anna")
            .filter_map(|e| e["name"].as_str().map(str::to_string))
            .collect();
        if !by_anna.is_empty() {
            break by_anna;
        }
        while events.next().await.unwrap_or_else(|| panic!("no history of anna's on the console: {history:?}")).0
            != "history"
        {}
    };
    assert_eq!(commands, ["hold"]);
}
