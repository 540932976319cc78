//! Phase 13, `baton bench --console-only`: the operator console as an operator's browser sees it. A router, a
//! coordinator running a ring of 1,000 steps each active 60 ms, 8 or 256 idle agents listed in every status, and a
//! `baton console` process; Chromium, driven through chromedriver (W3C WebDriver), opens the page with a watcher of
//! the bench's own, added before the page's script runs, that notes by the wall clock when the chart is first
//! drawn and when each step is first drawn lit. The latency is from the step's `activate` record on the coordinator
//! (taken in this process, on the same wall clock) to that moment. Then the console's resident memory while it
//! follows 16 runs behind one router, each run's chart drawn and its history read.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Stdio;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use anyhow::{anyhow, bail, Context};
use baton_host::ZenohResult;
use baton_proto::exec::trace::TraceEvent;
use serde::Serialize;
use serde_json::{json, Value};
use tokio::process::{Child, Command};

use super::harness::{marks, router_config, run_chart_until, spawn_logged, Agents, Extras, Marks};
use crate::demo::free_port;

/// Steps of the ring the page shows.
const STEPS: usize = 1_000;
/// Steps whose latency is measured at each agent count.
const MEASURED: usize = 150;
/// Runs the console follows in the memory measure.
const RUNS: usize = 16;
/// How long the page and the console get for each thing the bench waits on.
const WAIT: Duration = Duration::from_secs(120);

/// What phase 13 measured.
#[derive(Serialize)]
pub struct ConsoleReport {
    pub steps: usize,
    /// Per agent count.
    pub latency: Vec<ConsolePoint>,
    /// The console's resident set while it follows `runs` runs.
    pub memory_mib: f64,
    pub runs: usize,
}

#[derive(Serialize)]
pub struct ConsolePoint {
    pub agents: u32,
    /// From a step's `activate` on the coordinator to the page's DOM showing it lit.
    pub event_to_dom_median_ms: f64,
    pub event_to_dom_p99_ms: f64,
    pub samples: usize,
    /// From the start of the page's navigation to the chart's steps all in its DOM.
    pub first_render_ms: f64,
}

/// Where Chromium and its WebDriver are.
pub struct Browser {
    pub chromium: String,
    pub chromedriver: String,
}

pub async fn console(dir: &Path, browser: &Browser, agent_counts: &[u32]) -> anyhow::Result<ConsoleReport> {
    let mut latency = Vec::new();
    for &agents in agent_counts {
        eprintln!("13 the console in Chromium: a {STEPS}-step ring, {agents} agents, {MEASURED} steps measured");
        latency.push(point(dir, browser, agents).await?);
    }
    eprintln!("13 the console's memory, following {RUNS} runs behind one router");
    let memory_mib = memory(dir).await?;
    Ok(ConsoleReport { steps: STEPS, latency, memory_mib, runs: RUNS })
}

impl ConsoleReport {
    pub(super) fn print(&self) {
        println!("(13) the operator console in Chromium, a {}-step chart:", self.steps);
        println!(
            "{:>8} {:>14} {:>14} {:>8} {:>14}",
            "agents", "event→DOM p50", "event→DOM p99", "samples", "first render"
        );
        for p in &self.latency {
            println!(
                "{:>8} {:>11.0} ms {:>11.0} ms {:>8} {:>11.0} ms",
                p.agents, p.event_to_dom_median_ms, p.event_to_dom_p99_ms, p.samples, p.first_render_ms
            );
        }
        println!("     goals: p99 < 100 ms, first render < 1 s");
        println!(
            "     the console following {} runs behind one router: {:.1} MiB resident",
            self.runs, self.memory_mib
        );
    }
}

/// A ring of `steps` steps on the coordinator, each left after 60 ms.
fn ring(steps: usize) -> String {
    let mut s = String::from("PROGRAM ring\nINITIAL_STEP S0: END_STEP\n");
    for k in 0..steps {
        if k > 0 {
            s.push_str(&format!("STEP S{k}: END_STEP\n"));
        }
        let next = (k + 1) % steps;
        s.push_str(&format!("TRANSITION FROM S{k} TO S{next} := S{k}.T >= T#60ms; END_TRANSITION\n"));
    }
    s.push_str("END_PROGRAM\n");
    s
}

fn unix_ms(at: SystemTime) -> f64 {
    at.duration_since(UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64() * 1e3)
}

/// The latency at one agent count.
async fn point(dir: &Path, browser: &Browser, agents: u32) -> anyhow::Result<ConsolePoint> {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port()?);
    let _router = zenoh::open(router_config(&endpoint, &[])?).await.zenoh()?;
    let (marks, probe) = marks(&[TraceEvent::Activate]);
    // The marks' instants on the wall clock, which the page's `Date.now()` reads too.
    let (zero, zero_wall) = (Instant::now(), SystemTime::now());
    let (stop, stopped) = tokio::sync::watch::channel(false);
    let extras = Extras { connect: Some(endpoint.clone()), ..Extras::default() };
    let file = format!("ring-{agents}.st");
    let run = run_chart_until(
        dir,
        &file,
        ring(STEPS),
        Agents::Hosted { prefix: "idle", count: agents },
        probe,
        extras,
        stopped,
    );
    let measured = async {
        let (_console, addr) = start_console(&endpoint).await?;
        listed(&addr, |runs| {
            runs.first().and_then(|r| r["agents"].as_array()).is_some_and(|a| a.len() == agents as usize)
        })
        .await
        .context("the console did not list every agent")?;
        let page = watch_page(browser, &format!("http://{addr}/")).await;
        stop.send_replace(true);
        page
    };
    let (ran, page) = tokio::join!(run, measured);
    ran?;
    let page = page?;
    let activated = activations(&marks, zero, zero_wall)?;
    let rendered_at = page["rendered_at"].as_f64().ok_or_else(|| anyhow!("the page was never drawn"))?;
    let seen = page["seen"].as_object().ok_or_else(|| anyhow!("the page saw no step"))?;
    // The first `MEASURED` steps the page saw lit: it goes on seeing steps between the check that it has seen enough
    // and the reading of what it saw (more of them the busier the machine).
    let mut first: Vec<(&str, f64)> =
        seen.iter().filter_map(|(step, at)| Some((step.as_str(), at.as_f64()?))).collect();
    first.sort_by(|a, b| a.1.total_cmp(&b.1));
    first.truncate(MEASURED);
    // Only steps activated once the page showed the chart: those it found lit when it opened are no latency.
    let mut settled: Vec<f64> = first
        .iter()
        .filter_map(|&(step, at)| {
            let on = *activated.get(step)?;
            (on >= rendered_at).then_some(at - on)
        })
        .collect();
    if settled.len() < MEASURED / 2 {
        bail!("only {} steps measured", settled.len());
    }
    settled.sort_by(f64::total_cmp);
    let at = |p: f64| settled[((settled.len() - 1) as f64 * p).round() as usize];
    Ok(ConsolePoint {
        agents,
        event_to_dom_median_ms: at(0.5),
        event_to_dom_p99_ms: at(0.99),
        samples: settled.len(),
        first_render_ms: page["first_render_ms"].as_f64().unwrap_or_default(),
    })
}

/// Each step's first activation, in Unix ms.
fn activations(marks: &Marks, zero: Instant, zero_wall: SystemTime) -> anyhow::Result<BTreeMap<String, f64>> {
    let marks = marks.lock().map_err(|_| anyhow!("poisoned"))?;
    let mut first = BTreeMap::new();
    for (at, _, step) in marks.iter() {
        let wall = zero_wall + at.saturating_duration_since(zero);
        first.entry(step.clone()).or_insert_with(|| unix_ms(wall));
    }
    Ok(first)
}

/// `baton console` for the cell behind `endpoint`, as an operator starts it: its process and its address.
async fn start_console(endpoint: &str) -> anyhow::Result<(Child, String)> {
    let addr = format!("127.0.0.1:{}", free_port()?);
    let exe = std::env::current_exe().context("this program's path")?;
    let child = spawn_logged(Command::new(exe).args(["console", "--connect", endpoint, "--listen", &addr]))?;
    Ok((child, addr))
}

/// Waits until the console's state lists runs that `enough` accepts (polled: the console's own pace).
async fn listed(addr: &str, enough: impl Fn(&[Value]) -> bool) -> anyhow::Result<Vec<Value>> {
    let url = format!("http://{addr}/api/state");
    let deadline = Instant::now() + WAIT;
    loop {
        let state = http(&url, "GET", None).await.unwrap_or_default();
        if let Some(runs) = state["runs"].as_array().filter(|runs| enough(runs)) {
            return Ok(runs.clone());
        }
        if Instant::now() > deadline {
            bail!("{url} said {state}");
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
}

/// A request to the console or to chromedriver (a JSON body, a JSON answer), off the runtime's threads.
async fn http(url: &str, method: &str, body: Option<Value>) -> anyhow::Result<Value> {
    let (url, method) = (url.to_string(), method.to_string());
    tokio::task::spawn_blocking(move || {
        let agent: ureq::Agent =
            ureq::Agent::config_builder().timeout_global(Some(WAIT)).http_status_as_error(false).build().into();
        let mut answer = match (method.as_str(), body) {
            ("GET", _) => agent.get(&url).call(),
            ("DELETE", _) => agent.delete(&url).call(),
            (_, body) => agent
                .post(&url)
                .header("Content-Type", "application/json")
                .send(body.unwrap_or_else(|| json!({})).to_string()),
        }
        .with_context(|| format!("{method} {url}"))?;
        let status = answer.status();
        let text = answer.body_mut().read_to_string().with_context(|| format!("{method} {url}"))?;
        let value: Value = serde_json::from_str(&text).with_context(|| format!("{method} {url}: {text}"))?;
        if !status.is_success() {
            bail!("{method} {url}: {status} {}", value["value"]["message"].as_str().unwrap_or(&text));
        }
        Ok(value)
    })
    .await?
}

/// Notes, by the wall clock, when the chart holds its steps (and, from the navigation's start, how long that took)
/// and when each step is first shown lit.
const WATCH: &str = r##"
window.__seen = {};
window.__firstRender = null;
new MutationObserver(() => {
    const steps = document.querySelectorAll("#chart svg g.step");
    if (window.__firstRender === null && steps.length >= STEPS) {
        window.__firstRender = performance.now();
        window.__renderedAt = Date.now();
    }
    const now = Date.now();
    for (const g of document.querySelectorAll("#chart svg g.step.active")) {
        if (!(g.dataset.step in window.__seen)) window.__seen[g.dataset.step] = now;
    }
}).observe(document, { subtree: true, childList: true, attributes: true, attributeFilter: ["class"] });
"##;

/// Opens `url` in headless Chromium with the watcher, and returns what it noted once `MEASURED` steps were seen
/// lit: `{first_render_ms, rendered_at, seen: {step: unix_ms}}`.
async fn watch_page(browser: &Browser, url: &str) -> anyhow::Result<Value> {
    let port = free_port()?;
    let mut driver = Command::new(&browser.chromedriver);
    driver.arg(format!("--port={port}")).stdout(Stdio::null()).stderr(Stdio::null()).kill_on_drop(true);
    let _driver = driver.spawn().with_context(|| format!("cannot start {} (chromedriver)", browser.chromedriver))?;
    let base = format!("http://127.0.0.1:{port}");
    let deadline = Instant::now() + WAIT;
    while !http(&format!("{base}/status"), "GET", None).await.is_ok_and(|s| s["value"]["ready"] == true) {
        if Instant::now() > deadline {
            bail!("{} did not become ready", browser.chromedriver);
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let args = ["--headless", "--no-sandbox", "--disable-gpu", "--window-size=1400,1000", "--no-first-run"];
    let capabilities = json!({"capabilities": {"alwaysMatch": {
        "browserName": "chrome",
        "goog:chromeOptions": {"binary": browser.chromium, "args": args},
    }}});
    let session = http(&format!("{base}/session"), "POST", Some(capabilities)).await?;
    let id = session["value"]["sessionId"].as_str().ok_or_else(|| anyhow!("no session: {session}"))?;
    let session = format!("{base}/session/{id}");
    let watched = async {
        let watch = WATCH.replace("STEPS", &STEPS.to_string());
        let cdp = json!({"cmd": "Page.addScriptToEvaluateOnNewDocument", "params": {"source": watch}});
        http(&format!("{session}/goog/cdp/execute"), "POST", Some(cdp)).await?;
        http(&format!("{session}/url"), "POST", Some(json!({ "url": url }))).await?;
        let script = |s: &str| {
            let body = json!({"script": s, "args": []});
            let url = format!("{session}/execute/sync");
            async move { http(&url, "POST", Some(body)).await.map(|v| v["value"].clone()) }
        };
        let count = format!("return window.__firstRender !== null && Object.keys(window.__seen).length >= {MEASURED}");
        let deadline = Instant::now() + WAIT;
        while script(&count).await? != true {
            if Instant::now() > deadline {
                bail!("the page showed fewer than {MEASURED} steps lit in {} s", WAIT.as_secs());
            }
            tokio::time::sleep(Duration::from_millis(200)).await;
        }
        script("return {first_render_ms: window.__firstRender, rendered_at: window.__renderedAt, seen: window.__seen}")
            .await
    };
    let page = watched.await;
    let _ = http(&session, "DELETE", None).await;
    page
}

/// The console's resident memory while it follows `RUNS` runs behind one router, in MiB.
async fn memory(dir: &Path) -> anyhow::Result<f64> {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port()?);
    let _router = zenoh::open(router_config(&endpoint, &[])?).await.zenoh()?;
    let (stop, stopped) = tokio::sync::watch::channel(false);
    let mut runs = tokio::task::JoinSet::new();
    for r in 0..RUNS {
        let (dir, extras, stopped) =
            (dir.to_path_buf(), Extras { connect: Some(endpoint.clone()), ..Extras::default() }, stopped.clone());
        runs.spawn(async move {
            let (_, probe) = marks(&[]);
            run_chart_until(&dir, &format!("memory-{r}.st"), ring(100), Agents::Processes(&[]), probe, extras, stopped)
                .await
        });
    }
    let measured = async {
        let (console, addr) = start_console(&endpoint).await?;
        let listed = listed(&addr, |runs| runs.len() == RUNS).await.context("the console did not list every run")?;
        // Each run's chart drawn and its history read, as pages showing each would have them.
        for run in &listed {
            let id = run["run"].as_str().ok_or_else(|| anyhow!("a run without an id"))?;
            for part in ["chart.svg", "history"] {
                let url = format!("http://{addr}/api/runs/{id}/{part}");
                let got = tokio::task::spawn_blocking(move || ureq::get(&url).call().map(|_| ()));
                got.await?.context("the console's answer")?;
            }
        }
        let pid = console.id().ok_or_else(|| anyhow!("the console is gone"))?;
        let status = std::fs::read_to_string(format!("/proc/{pid}/status")).context("/proc")?;
        let kb: f64 = status
            .lines()
            .find_map(|l| l.strip_prefix("VmRSS:"))
            .and_then(|v| v.split_whitespace().next())
            .and_then(|v| v.parse().ok())
            .ok_or_else(|| anyhow!("no VmRSS in /proc/{pid}/status"))?;
        Ok::<f64, anyhow::Error>(kb / 1024.0)
    };
    let mib = measured.await;
    stop.send_replace(true);
    while let Some(run) = runs.join_next().await {
        run??;
    }
    mib
}
