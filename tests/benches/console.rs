//! The operator console's speed, as an operator's browser sees it (Debian's Chromium through chromedriver,
//! `tests/scripts/console_bench.py`): on a cell on loopback — a router, a coordinator running a ring of 1,000 steps
//! each active 60 ms, and 8 or 256 idle agents listed in every status — how long from a step's `activate` record
//! on the coordinator (its trace, put on the wall clock by what `baton status` says its clock read when) to the
//! page's DOM showing the step lit, median and p99 over 150 steps; the page's first render of the 1,000-step chart;
//! and the console's memory (resident set) following 16 runs behind one router. Run with
//! `cargo build --release --workspace && cargo bench -p baton-tests --bench console` (it runs the release
//! binaries); `docs/book/src/benchmarks.md` has the figures.

use std::collections::BTreeMap;
use std::time::Duration;

use baton_proto::exec::trace::TraceEvent;
use baton_tests::http::{console, http, require_browser};
use baton_tests::loopback::{repo, Cluster, TIMEOUT};
use tokio::process::Command;

const STEPS: usize = 1_000;
const MEASURED: usize = 150;

/// A ring of `steps` steps on the coordinator, each left after 60 ms.
fn ring(steps: usize) -> String {
    let mut s = String::from("PROGRAM ring\nINITIAL_STEP S0: END_STEP\n");
    for k in 0..steps {
        let next = (k + 1) % steps;
        if k > 0 {
            s.push_str(&format!("STEP S{k}: END_STEP\n"));
        }
        s.push_str(&format!("TRANSITION FROM S{k} TO S{next} := S{k}.T >= T#60ms; END_TRANSITION\n"));
    }
    s.push_str("END_PROGRAM\n");
    s
}

fn percentile(sorted: &[i64], p: f64) -> i64 {
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// Event-to-DOM latency with `agents` idle agents: (median ms, p99 ms, first render ms).
async fn latency(agents: u32) -> (i64, i64, f64) {
    let mut cluster = Cluster::with_router().await;
    let chart = cluster.dir.path().join("ring.st");
    std::fs::write(&chart, ring(STEPS)).expect("write the chart");
    cluster.agent("idle", &[], &["--instances", &agents.to_string()]);
    let mut coordinator = cluster.coordinator_joining(&chart, &[]);
    coordinator.wait_ready().await;
    let (_console, addr) = console(&cluster.endpoint, &[]).await;
    // Every agent listed before the page opens.
    let all_listed = tokio::time::timeout(TIMEOUT * 4, async {
        loop {
            let (_, state) = http(&addr, "GET", "/api/state", None).await;
            let state: serde_json::Value = serde_json::from_str(&state).unwrap_or_default();
            if state["runs"][0]["agents"].as_array().is_some_and(|a| a.len() == agents as usize) {
                return;
            }
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    });
    all_listed.await.expect("every agent listed in time");
    let out = Command::new("python3")
        .arg(repo("tests/scripts/console_bench.py"))
        .args([&format!("http://{addr}/"), &STEPS.to_string(), &MEASURED.to_string()])
        .kill_on_drop(true)
        .output();
    let out = tokio::time::timeout(TIMEOUT * 8, out).await.expect("the browser in time").expect("python3 runs");
    let said = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(out.status.success(), "{said}\n{}", String::from_utf8_lossy(&out.stderr));
    let page: serde_json::Value = serde_json::from_str(said.trim()).expect("JSON");
    // The coordinator's clock on the wall clock.
    let status = cluster.baton(&["status", "--connect", &cluster.endpoint, "--json"]).await;
    let status: serde_json::Value = serde_json::from_slice(&status.stdout).expect("status JSON");
    let zero = status["unix_ms"].as_i64().expect("unix_ms") - status["t_ms"].as_i64().expect("t_ms");
    let trace = coordinator.wait_for_trace("the steps", |_| true).await;
    let mut activated: BTreeMap<&str, i64> = BTreeMap::new();
    for r in trace.iter().filter(|r| r.event == TraceEvent::Activate) {
        activated.entry(r.name.as_str()).or_insert(zero + r.t_ms as i64);
    }
    let seen = page["seen"].as_object().expect("seen");
    // Only steps activated once the page showed the chart: those it found lit when it opened are no latency.
    let rendered_at = page["rendered_at"].as_i64().expect("rendered_at");
    let mut settled: Vec<i64> = seen
        .iter()
        .filter_map(|(step, at)| {
            let on = *activated.get(step.as_str())?;
            (on >= rendered_at).then(|| at.as_i64().map(|at| at - on)).flatten()
        })
        .collect();
    settled.sort_unstable();
    assert!(settled.len() >= MEASURED / 2, "too few steps measured: {settled:?}");
    coordinator.kill().await;
    (percentile(&settled, 0.5), percentile(&settled, 0.99), page["first_render_ms"].as_f64().unwrap_or_default())
}

/// The console's resident memory following 16 runs behind one router, in MiB.
async fn memory_with_runs(runs: usize) -> f64 {
    let cluster = Cluster::with_router().await;
    let chart = cluster.dir.path().join("ring.st");
    std::fs::write(&chart, ring(100)).expect("write the chart");
    let mut coordinators = Vec::new();
    for _ in 0..runs {
        let mut c = cluster.coordinator_joining(&chart, &[]);
        c.wait_ready().await;
        coordinators.push(c);
    }
    let (console, addr) = console(&cluster.endpoint, &[]).await;
    let listed = tokio::time::timeout(TIMEOUT * 2, async {
        loop {
            let (_, state) = http(&addr, "GET", "/api/state", None).await;
            let state: serde_json::Value = serde_json::from_str(&state).unwrap_or_default();
            if state["runs"].as_array().is_some_and(|r| r.len() == runs) {
                return;
            }
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
    });
    listed.await.expect("every run listed in time");
    // Each run's chart drawn and its history read, as pages showing each would have them.
    let (_, state) = http(&addr, "GET", "/api/state", None).await;
    let state: serde_json::Value = serde_json::from_str(&state).expect("JSON");
    for run in state["runs"].as_array().expect("runs") {
        let id = run["run"].as_str().expect("an id");
        assert_eq!(http(&addr, "GET", &format!("/api/runs/{id}/chart.svg"), None).await.0, 200);
        assert_eq!(http(&addr, "GET", &format!("/api/runs/{id}/history"), None).await.0, 200);
    }
    let pid = console.id().expect("the console's pid");
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("/proc");
    let kb: f64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.split_whitespace().next())
        .and_then(|v| v.parse().ok())
        .expect("VmRSS");
    for c in coordinators {
        c.kill().await;
    }
    kb / 1024.0
}

fn main() {
    require_browser();
    let runtime = tokio::runtime::Runtime::new().expect("a runtime");
    runtime.block_on(async {
        for agents in [8, 256] {
            let (median, p99, first) = latency(agents).await;
            println!(
                "console, {STEPS}-step chart, {agents} agents: event to DOM median {median} ms, p99 {p99} ms; first \
                 render {first:.0} ms"
            );
        }
        let mib = memory_with_runs(16).await;
        println!("console following 16 runs behind one router: {mib:.1} MiB resident");
    });
}
