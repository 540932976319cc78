//! `--rerun off | save:PATH.rrd | connect[:URL] | spawn | serve[:ADDR]`: a run's timeline in Rerun.
//!
//! The coordinator's host hands every trace record and every change of a variable to a `Recorder`, which
//! passes them through a bounded queue to a thread of its own that logs them: the coordinator's cycle never
//! waits for Rerun. When the queue is full (a slow sink), records are dropped and counted, and the run says so.
//!
//! Entity paths (documented in the user guide, `docs/book/src/rerun.md`):
//! - `sfc/graph` — the chart: steps as nodes, transitions as edges, laid out once; node colours follow the
//!   steps (active here, active on an agent, waiting at a convergence, faulted, inactive).
//! - `sfc/steps/<step>` — each step's state over time: `active` (on the coordinator), `on <agent>`,
//!   `waiting` (a branch's last step, at a convergence), `no agent yet`, `faulted`, or `inactive`.
//! - `agents/<name>` — `online`, `busy: <step> (<token>)`, or `lost`.
//! - `tokens/<id>` — dispatch, progress, return, reassignment and rejection of each token, as text with levels.
//! - `vars/<name>` — numeric and boolean variables as time series.
//! - `log` — alarms and warnings: agents lost, stale epochs rejected, skill faults, run-time faults.
//!
//! Two timelines: `wall` (Unix time) and `cycle` (the coordinator's cycle number).
//!
//! # Rules the recording keeps
//!
//! - Recording never paces the coordinator: the host only clones records into a bounded channel (`try_send`; a full
//!   channel drops and counts); the Rerun SDK runs on the `baton-rerun` thread. The recording is derived from the trace
//!   and variable values alone, so a replayed journal yields the same recording as the live run. Anything logged
//!   `static` in Rerun hides every timed value of the same component, so only what never changes (graph nodes and
//!   edges, state colours, series styles) is static.

use std::collections::{BTreeMap, HashMap};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::Arc;
use std::time::Duration;

use anyhow::anyhow;
use baton_proto::cluster::layout::{Layout, Placement};
use baton_proto::exec::program::{Program, StepId, TransitionId, VarId, VarInfo};
use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use baton_proto::types::{quote_string, Type, Value};
use rerun::blueprint::components::PanelState;
use rerun::blueprint::{
    Blueprint, BlueprintPanel, GraphView, Horizontal, SelectionPanel, StateTimelineView, TextLogView, TimePanel,
    TimeSeriesView, Vertical,
};
use rerun::components::{AggregationPolicy, InterpolationMode};
use rerun::{
    Color, GraphEdges, GraphNodes, RecordingStream, Scalars, SeriesLines, StateChange, StateConfiguration, TextLog,
};

/// Records the queue holds before the recorder drops; far more than a burst of the busiest chart.
const QUEUE_MAX: usize = 65_536;

/// How long the end of a run waits for a viewer to take the rest of its recording.
const LIVE_CLOSE_WAIT: Duration = Duration::from_secs(10);

/// How long `connect` tries to reach the viewer before the run starts.
const CONNECT_CHECK_WAIT: Duration = Duration::from_secs(2);

/// The Rerun viewer's default gRPC proxy.
pub const DEFAULT_VIEWER_URL: &str = "rerun+http://127.0.0.1:9876/proxy";

/// Whether a viewer listens at `url` (`rerun+http://HOST:PORT/proxy`): the SDK would otherwise buffer the
/// recording for a viewer that is not there, and a run would record nothing without a word.
pub fn reachable(url: &str) -> anyhow::Result<()> {
    let authority = url
        .split_once("://")
        .map(|(_, rest)| rest.split('/').next().unwrap_or(rest))
        .ok_or_else(|| anyhow!("`{url}` is not a Rerun viewer URL (rerun+http://HOST:PORT/proxy)"))?;
    let addrs: Vec<SocketAddr> = authority
        .to_socket_addrs()
        .map_err(|e| anyhow!("`{url}` is not a Rerun viewer URL (rerun+http://HOST:PORT/proxy): {e}"))?
        .collect();
    let mut last = None;
    for addr in &addrs {
        match TcpStream::connect_timeout(addr, CONNECT_CHECK_WAIT) {
            Ok(_) => return Ok(()),
            Err(e) => last = Some(e),
        }
    }
    let why = last.map_or_else(|| "no address".to_string(), |e| e.to_string());
    Err(anyhow!(
        "no Rerun viewer at {url} ({why}): start one with `rerun`, or record with --rerun spawn or save:PATH.rrd"
    ))
}

/// Where a recording goes.
#[derive(Clone, Debug, PartialEq)]
pub enum Sink {
    Off,
    Save(PathBuf),
    /// A running viewer's gRPC proxy (default `rerun+http://127.0.0.1:9876/proxy`).
    Connect(Option<String>),
    /// Start a viewer (the `rerun` command must be on the PATH) and stream to it.
    Spawn,
    /// Serve the recording on ADDR (Rerun's gRPC server, which keeps it for viewers that come later): the
    /// operator console's page shows it live. A browser page may read it only from the origins allowed (Rerun
    /// allows loopback pages; `--rerun-origin` adds a console's).
    Serve {
        addr: SocketAddr,
        origins: Vec<String>,
    },
}

/// Where `--rerun serve` listens unless told.
pub const DEFAULT_SERVE_ADDR: &str = "127.0.0.1:9876";

impl std::str::FromStr for Sink {
    type Err = String;

    fn from_str(s: &str) -> Result<Sink, String> {
        match s {
            "off" => Ok(Sink::Off),
            "spawn" => Ok(Sink::Spawn),
            "connect" => Ok(Sink::Connect(None)),
            "serve" => format!("serve:{DEFAULT_SERVE_ADDR}").parse(),
            _ => {
                if let Some(path) = s.strip_prefix("save:") {
                    if path.is_empty() {
                        return Err("give a file: save:PATH.rrd".into());
                    }
                    Ok(Sink::Save(PathBuf::from(path)))
                } else if let Some(url) = s.strip_prefix("connect:") {
                    Ok(Sink::Connect(Some(url.to_string())))
                } else if let Some(addr) = s.strip_prefix("serve:") {
                    let addr =
                        addr.parse().map_err(|_| format!("`{addr}` is not an address to serve on (HOST:PORT)"))?;
                    Ok(Sink::Serve { addr, origins: Vec::new() })
                } else {
                    Err(format!(
                        "`{s}` is not a Rerun sink: use off, save:PATH.rrd, connect[:URL], spawn or serve[:ADDR]"
                    ))
                }
            }
        }
    }
}

/// Rerun's gRPC server on `addr`, which keeps the recording (up to a quarter of the memory, as Rerun's own
/// `serve_grpc`) for viewers that connect later. Rerun's server would only log that it cannot bind, and the run
/// would record for nobody: the address is tried first, so that a taken port is the user's error at once.
fn serve(
    builder: rerun::RecordingStreamBuilder,
    addr: SocketAddr,
    origins: &[String],
) -> anyhow::Result<RecordingStream> {
    drop(
        std::net::TcpListener::bind(addr).map_err(|e| {
            anyhow!("cannot serve the recording on {addr}: {e} (choose another with --rerun serve:ADDR)")
        })?,
    );
    let options = rerun::ServerOptions {
        memory_limit: rerun::MemoryLimit::from_fraction_of_total(0.25),
        cors_allowed_origins: origins.to_vec(),
        ..Default::default()
    };
    builder
        .serve_grpc_opts(addr.ip().to_string(), addr.port(), options)
        .map_err(|e| anyhow!("cannot serve the recording on {addr}: {e}"))
}

/// What a recording is of.
pub struct RecordedRun {
    pub program: Arc<Program>,
    pub layout: Arc<Layout>,
    /// The run id: the recording id, so that a recording rebuilt from the journal is the same recording.
    pub run: String,
    /// Wall-clock time of the run's time 0, in ms since the Unix epoch.
    pub started_unix_ms: u64,
}

enum Item {
    Trace(u64, TraceRecord),
    Values(u64, u64, Vec<(VarId, Value)>),
}

pub struct Recorder {
    tx: Option<SyncSender<Item>>,
    dropped: Arc<AtomicU64>,
    thread: Option<std::thread::JoinHandle<()>>,
    /// Signalled by the logging thread when the recording is flushed and closed.
    done: Receiver<()>,
    /// A viewer (connect, spawn, serve), not a file.
    live: bool,
    /// Where viewers read the recording (`serve`): `rerun+http://ADDR/proxy`.
    served: Option<String>,
    /// The last value sent of each recorded variable.
    last: Vec<Option<Value>>,
    program: Arc<Program>,
}

impl Recorder {
    /// Opens the sink (an error here is the user's to fix: a file that cannot be created, a bad URL) and starts
    /// the logging thread. `None` for `Sink::Off`.
    pub fn start(sink: &Sink, run: RecordedRun) -> anyhow::Result<Option<Recorder>> {
        let builder = rerun::RecordingStreamBuilder::new("baton").recording_id(run.run.clone());
        // A file carries the layout as the default (a layout the user arranged stays theirs); a live viewer is
        // told to show it at once, since it may already have made up a layout of its own from the first data.
        let builder = match sink {
            Sink::Save(_) => builder.with_default_blueprint(blueprint()),
            _ => builder.with_blueprint(blueprint()),
        };
        let stream = match sink {
            Sink::Off => return Ok(None),
            Sink::Save(path) => builder.save(path).map_err(|e| anyhow!("cannot record to {}: {e}", path.display()))?,
            Sink::Connect(url) => {
                let url = url.clone().unwrap_or_else(|| DEFAULT_VIEWER_URL.to_string());
                reachable(&url)?;
                builder
                    .connect_grpc_opts(url.clone())
                    .map_err(|e| anyhow!("cannot connect to a viewer at {url}: {e}"))?
            }
            Sink::Spawn => {
                builder.spawn().map_err(|e| anyhow!("cannot start the Rerun viewer (is `rerun` on the PATH?): {e}"))?
            }
            Sink::Serve { addr, origins } => serve(builder, *addr, origins)?,
        };
        let (tx, rx) = sync_channel(QUEUE_MAX);
        let (done_tx, done) = sync_channel(1);
        let program = Arc::clone(&run.program);
        let thread = std::thread::Builder::new()
            .name("baton-rerun".into())
            .spawn(move || {
                let mut logger = Logger::new(stream, run);
                logger.static_parts();
                logger.run(&rx);
                drop(logger);
                let _ = done_tx.send(());
            })
            .map_err(|e| anyhow!("cannot start the recording thread: {e}"))?;
        let last = vec![None; program.vars.len()];
        let live = !matches!(sink, Sink::Save(_));
        let served = match sink {
            Sink::Serve { addr, .. } => Some(format!("rerun+http://{addr}/proxy")),
            _ => None,
        };
        Ok(Some(Recorder {
            served,
            tx: Some(tx),
            dropped: Arc::new(AtomicU64::new(0)),
            thread: Some(thread),
            done,
            live,
            last,
            program,
        }))
    }

    /// Where a viewer reads this run's recording live, when it is served.
    pub fn served(&self) -> Option<&str> {
        self.served.as_deref()
    }

    fn send(&mut self, item: Item) {
        let Some(tx) = &self.tx else { return };
        match tx.try_send(item) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => {
                if self.dropped.fetch_add(1, Ordering::Relaxed) == 0 {
                    eprintln!("warning: the Rerun sink is falling behind: records are dropped from the recording");
                }
            }
            Err(TrySendError::Disconnected(_)) => self.tx = None,
        }
    }

    /// A trace record made in cycle `cycle`.
    pub fn trace(&mut self, cycle: u64, rec: &TraceRecord) {
        self.send(Item::Trace(cycle, rec.clone()));
    }

    /// The numeric and boolean variables as they stand after cycle `cycle`; only changes are recorded.
    pub fn values(&mut self, cycle: u64, t_ms: u64, value_of: impl Fn(VarId) -> Value) {
        let mut changed = Vec::new();
        for (i, info) in self.program.vars.iter().enumerate() {
            if !recorded(info) {
                continue;
            }
            let v = value_of(VarId(i as u32));
            if self.last[i].as_ref() != Some(&v) {
                self.last[i] = Some(v.clone());
                changed.push((VarId(i as u32), v));
            }
        }
        if !changed.is_empty() {
            self.send(Item::Values(cycle, t_ms, changed));
        }
    }

    /// Ends the recording: everything queued is logged and the sink flushed (a file gets its footer). Returns
    /// how many records were dropped.
    pub fn finish(mut self) -> u64 {
        self.close();
        self.dropped.load(Ordering::Relaxed)
    }

    /// A file is always finished (the disk takes it). A viewer that went away, or stopped reading, would hold
    /// the Rerun SDK's flush forever: after `LIVE_CLOSE_WAIT` the run goes on without it, and says so.
    fn close(&mut self) {
        self.tx = None;
        let Some(t) = self.thread.take() else { return };
        if self.live {
            match self.done.recv_timeout(LIVE_CLOSE_WAIT) {
                Ok(()) | Err(RecvTimeoutError::Disconnected) => {}
                Err(RecvTimeoutError::Timeout) => {
                    eprintln!(
                        "warning: the Rerun viewer did not take the end of the recording within {} s; left behind",
                        LIVE_CLOSE_WAIT.as_secs()
                    );
                    return;
                }
            }
        }
        let _ = t.join();
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        self.close();
    }
}

/// The layout sent with every recording: the chart over the variables, beside the step and agent timelines
/// and the log; the side panels folded away so that the views have the room, the time panel on `wall`.
fn blueprint() -> Blueprint {
    Blueprint::new(
        Horizontal::new([
            Vertical::new([
                GraphView::new("chart").with_origin("sfc/graph").into(),
                TimeSeriesView::new("variables").with_origin("vars").into(),
            ])
            .with_row_shares([3.0, 1.0])
            .into(),
            Vertical::new([
                StateTimelineView::new("steps").with_origin("sfc/steps").into(),
                StateTimelineView::new("agents").with_origin("agents").into(),
                TextLogView::new("log").with_origin("/").with_contents(["/log", "/tokens/**", "/vars/**"]).into(),
            ])
            .with_row_shares([5.0, 1.5, 3.0])
            .into(),
        ])
        .with_column_shares([2.0, 3.0]),
    )
    .with_blueprint_panel(BlueprintPanel::from_state(PanelState::Collapsed))
    .with_selection_panel(SelectionPanel::from_state(PanelState::Collapsed))
    .with_time_panel(TimePanel::new().with_state(PanelState::Collapsed).with_timeline("wall"))
}

#[derive(Clone, Copy, PartialEq)]
enum StepState {
    Inactive,
    Active,
    OnAgent,
    Waiting,
    Faulted,
    /// Held by an operator: nothing of it clears or starts.
    Held,
}

impl StepState {
    fn color(self) -> Color {
        match self {
            StepState::Inactive => Color::from_rgb(110, 110, 110),
            StepState::Active => Color::from_rgb(60, 180, 75),
            StepState::OnAgent => Color::from_rgb(70, 130, 230),
            StepState::Waiting => Color::from_rgb(245, 165, 35),
            StepState::Faulted => Color::from_rgb(220, 50, 50),
            StepState::Held => Color::from_rgb(150, 90, 200),
        }
    }
}

struct Logger {
    rec: RecordingStream,
    run: RecordedRun,
    steps: HashMap<String, StepId>,
    state: Vec<StepState>,
    graph_dirty: bool,
    /// The steps' states when the run was held, to show again when it goes on.
    before_hold: Option<Vec<StepState>>,
    /// Per step: it is a source of a simultaneous convergence.
    converging: Vec<bool>,
    /// Per agent: the tokens it holds, as token → step.
    agents: BTreeMap<String, BTreeMap<String, String>>,
    cycle: u64,
}

impl Logger {
    fn new(rec: RecordingStream, run: RecordedRun) -> Logger {
        let steps = run.program.steps.iter().enumerate().map(|(i, s)| (s.name.clone(), StepId(i as u32))).collect();
        let state = vec![StepState::Inactive; run.program.steps.len()];
        let mut converging = vec![false; run.program.steps.len()];
        for t in 0..run.program.transitions.len() {
            let sources = run.program.sources(TransitionId(t as u32));
            if sources.len() > 1 {
                for s in sources {
                    converging[s.index()] = true;
                }
            }
        }
        Logger {
            rec,
            run,
            steps,
            state,
            converging,
            graph_dirty: false,
            before_hold: None,
            agents: BTreeMap::new(),
            cycle: 0,
        }
    }

    fn ok(&self, r: rerun::RecordingStreamResult<()>) {
        if let Err(e) = r {
            eprintln!("warning: cannot log to Rerun: {e}");
        }
    }

    /// The chart's graph (laid out once), and the colours of each state.
    fn static_parts(&mut self) {
        let program = Arc::clone(&self.run.program);
        let names: Vec<String> = program.steps.iter().map(|s| s.name.clone()).collect();
        let step_positions = layered_layout(&program);
        // SFC notation: each transition is a node of its own between its steps, labelled with its condition; a
        // simultaneous divergence or convergence (several targets or sources) is marked `‖`, a selection is a step
        // with several transitions below it.
        let (mut ids, mut labels, mut positions, mut radii) =
            (names.clone(), names.clone(), step_positions.clone(), Vec::new());
        radii.resize(names.len(), 12.0f32);
        let mut edges = Vec::new();
        for t in 0..program.transitions.len() {
            let t = TransitionId(t as u32);
            let (sources, targets) = (program.sources(t), program.targets(t));
            let id = format!("t{}", t.0);
            let condition = baton_proto::exec::why::show(&program, &program.transitions[t.index()].condition);
            let simultaneous = sources.len() > 1 || targets.len() > 1;
            labels.push(if simultaneous { format!("‖ {condition}") } else { condition });
            let at = |steps: &[StepId]| {
                let n = steps.len().max(1) as f32;
                steps.iter().fold([0.0f32, 0.0], |acc, s| {
                    let p = step_positions[s.index()];
                    [acc[0] + p[0] / n, acc[1] + p[1] / n]
                })
            };
            let (from, to) = (at(sources), at(targets));
            positions.push([(from[0] + to[0]) / 2.0, (from[1] + to[1]) / 2.0]);
            radii.push(4.0);
            for &s in sources {
                edges.push((program.steps[s.index()].name.clone(), id.clone()));
            }
            for &d in targets {
                edges.push((id.clone(), program.steps[d.index()].name.clone()));
            }
            ids.push(id);
        }
        // Static: the nodes, their labels, sizes and places. Not their colours: static data hides every temporal
        // value of the same component, so the colours are logged on the timelines, from the start.
        let nodes = GraphNodes::new(ids).with_labels(labels).with_positions(positions).with_radii(radii);
        self.ok(self.rec.log_static("sfc/graph", &nodes));
        self.at(0);
        self.graph_dirty = true;
        self.flush_graph();
        self.ok(self.rec.log_static("sfc/graph", &GraphEdges::new(edges).with_directed_edges()));
        let steps_config = StateConfiguration::new()
            .with_values(["active", "waiting", "no agent yet", "faulted", "held", "inactive"])
            .with_colors([
                StepState::Active.color(),
                StepState::Waiting.color(),
                StepState::Waiting.color(),
                StepState::Faulted.color(),
                StepState::Held.color(),
                StepState::Inactive.color(),
            ]);
        for name in &names {
            self.ok(self.rec.log_static(format!("sfc/steps/{name}"), &steps_config));
        }
        // A variable holds its value until the next change: steps, not slopes. Where many changes fall on one
        // pixel, the lowest and highest are both drawn, so a pulse of one cycle still shows.
        let series = SeriesLines::new()
            .with_interpolation_mode(InterpolationMode::StepAfter)
            .with_aggregation_policy(AggregationPolicy::MinMax);
        for info in program.vars.iter().filter(|v| recorded(v)) {
            self.ok(self.rec.log_static(format!("vars/{}", info.name), &series));
        }
    }

    fn run(&mut self, rx: &Receiver<Item>) {
        while let Ok(item) = rx.recv() {
            let cycle = match &item {
                Item::Trace(c, _) | Item::Values(c, _, _) => *c,
            };
            if cycle != self.cycle {
                self.flush_graph();
                self.cycle = cycle;
            }
            match item {
                Item::Trace(_, rec) => self.trace(&rec),
                Item::Values(_, t_ms, values) => self.values(t_ms, &values),
            }
        }
        self.flush_graph();
        if let Err(e) = self.rec.flush_blocking() {
            eprintln!("warning: the Rerun recording could not be flushed: {e}");
        }
    }

    fn at(&self, t_ms: u64) {
        self.rec.set_time_sequence("cycle", self.cycle as i64);
        let wall = (self.run.started_unix_ms + t_ms) as f64 / 1000.0;
        self.rec.set_timestamp_secs_since_epoch("wall", wall);
    }

    fn flush_graph(&mut self) {
        if !self.graph_dirty {
            return;
        }
        self.graph_dirty = false;
        let transitions = self.run.program.transitions.len();
        let colors: Vec<Color> = self
            .state
            .iter()
            .map(|s| s.color())
            .chain(std::iter::repeat_n(Color::from_rgb(200, 200, 200), transitions))
            .collect();
        self.ok(self.rec.log("sfc/graph", &GraphNodes::update_fields().with_colors(colors)));
    }

    fn step_state(&mut self, name: &str, state: StepState, label: &str) {
        let Some(&s) = self.steps.get(name) else { return };
        self.state[s.index()] = state;
        self.graph_dirty = true;
        self.ok(self.rec.log(format!("sfc/steps/{name}"), &StateChange::single(label)));
    }

    /// An entry on the token's own path; the text names the token too, since the log view's path column is
    /// narrow.
    fn token_log(&self, rec: &TraceRecord, level: &str, text: String) {
        if let Some(token) = &rec.token {
            self.log_on_token(token, level, text);
        }
    }

    fn log_on_token(&self, token: &str, level: &str, text: String) {
        let text = format!("[{}] {text}", short(token));
        self.ok(self.rec.log(format!("tokens/{token}"), &TextLog::new(text).with_level(level)));
    }

    /// An entry on the token behind something an agent did (agents' records name the agent, not the token):
    /// the agent's token whose segment holds `step`; for a skill (no step), the agent's token if it holds one.
    fn progress_log(&self, agent: &str, step: Option<&str>, level: &str, text: String) {
        let Some(held) = self.agents.get(agent) else { return };
        let layout = &self.run.layout;
        let segment = |name: &str| self.steps.get(name).and_then(|s| layout.segment_of[s.index()]);
        let token = match step {
            Some(step) => {
                segment(step).and_then(|g| held.iter().find(|(_, entry)| segment(entry) == Some(g)).map(|(t, _)| t))
            }
            None if held.len() == 1 => held.keys().next(),
            None => None,
        };
        if let Some(token) = token {
            self.log_on_token(token, level, text);
        }
    }

    fn log(&self, level: &str, text: String) {
        self.ok(self.rec.log("log", &TextLog::new(text).with_level(level)));
    }

    fn agent_state(&self, agent: &str) {
        let state = match self.agents.get(agent) {
            None => return,
            Some(tokens) if tokens.is_empty() => "online".to_string(),
            Some(tokens) => {
                let held: Vec<String> = tokens.iter().map(|(t, step)| format!("{step} ({})", short(t))).collect();
                format!("busy: {}", held.join(", "))
            }
        };
        self.ok(self.rec.log(format!("agents/{agent}"), &StateChange::single(state)));
    }

    fn trace(&mut self, rec: &TraceRecord) {
        self.at(rec.t_ms);
        let agent = rec.agent.as_deref();
        let epoch = rec.epoch.map(|e| format!(", epoch {e}")).unwrap_or_default();
        let message = rec.message.as_deref().unwrap_or("");
        match rec.event {
            TraceEvent::Activate => self.activated(rec),
            TraceEvent::Deactivate => self.step_state(&rec.name, StepState::Inactive, "inactive"),
            TraceEvent::Dispatch | TraceEvent::Resume => self.dispatched(rec),
            TraceEvent::Return => self.returned(rec),
            TraceEvent::Wait => self.token_log(rec, "WARN", format!("waits for an agent: step {}{epoch}", rec.name)),
            TraceEvent::Withdraw => {
                self.token_log(rec, "WARN", format!("taken back by the operator: step {}{epoch}", rec.name))
            }
            TraceEvent::RejectStale => {
                let a = agent.unwrap_or("?");
                let text = format!("stale report from {a} rejected (step {}{epoch}); told to drop it", rec.name);
                self.token_log(rec, "WARN", text.clone());
                self.log("WARN", text);
                if let (Some(held), Some(t)) = (self.agents.get_mut(a), &rec.token) {
                    held.remove(t);
                }
            }
            TraceEvent::AgentUp => {
                self.agents.entry(rec.name.clone()).or_default();
                self.agent_state(&rec.name);
            }
            TraceEvent::AgentLost => {
                self.agents.entry(rec.name.clone()).or_default();
                self.ok(self.rec.log(format!("agents/{}", rec.name), &StateChange::single("lost")));
                self.log("WARN", format!("agent {} lost", rec.name));
            }
            TraceEvent::Alarm => {
                let id = rec.id.map(|i| format!(" #{i}")).unwrap_or_default();
                self.log("ERROR", format!("alarm{id} ({}): {message}", rec.name));
                // A supervision alarm names its step: the chart view marks it faulted.
                if self.steps.contains_key(&rec.name) {
                    self.step_state(&rec.name, StepState::Faulted, "faulted");
                }
            }
            TraceEvent::Ack | TraceEvent::Shelve | TraceEvent::Unshelve | TraceEvent::AlarmClear => {
                let id = rec.id.map(|i| format!(" #{i}")).unwrap_or_default();
                let by = rec.by.as_deref().unwrap_or("?");
                let text = match rec.event {
                    TraceEvent::Ack if message.is_empty() => format!("alarm{id} acknowledged by {by}"),
                    TraceEvent::Ack => format!("alarm{id} acknowledged by {by}: {message}"),
                    TraceEvent::Shelve => format!("alarm{id} shelved by {by} ({message})"),
                    TraceEvent::Unshelve => format!("alarm{id} ({}) back in the active list: {message}", rec.name),
                    _ => format!("alarm{id} ({}) back to normal", rec.name),
                };
                self.log("INFO", text);
            }
            TraceEvent::Command | TraceEvent::CommandRefused => {
                let by = rec.by.as_deref().unwrap_or("?");
                let part = rec.agent.as_deref().map(|a| format!(" --agent {a}")).unwrap_or_default();
                let (level, text) = match rec.event {
                    TraceEvent::Command if message.is_empty() => {
                        ("INFO", format!("command {}{part} by {by}", rec.name))
                    }
                    TraceEvent::Command => ("INFO", format!("command {}{part} by {by}: {message}", rec.name)),
                    _ => ("WARN", format!("command {}{part} by {by} refused: {message}", rec.name)),
                };
                self.log(level, text);
            }
            TraceEvent::Mode => self.log("INFO", format!("mode: {}", rec.name)),
            TraceEvent::DeviceDown | TraceEvent::DeviceUp => {
                let a = agent.unwrap_or("?");
                let (level, text) = match rec.event {
                    TraceEvent::DeviceDown => {
                        ("WARN", format!("device of `{}` on {a} down: {message}; it keeps its value", rec.name))
                    }
                    _ => ("INFO", format!("device of `{}` on {a} back: {message}", rec.name)),
                };
                self.progress_log(a, None, level, text.clone());
                self.log(level, text);
            }
            TraceEvent::Recover => self.log("WARN", format!("coordinator restarted: {message}")),
            TraceEvent::Deposed => self.log("WARN", format!("coordinator stopped acting: {message}")),
            TraceEvent::State => self.run_state(&rec.name),
            TraceEvent::SkillFault | TraceEvent::Fault => {
                let on = agent.map(|a| format!(" on {a}")).unwrap_or_default();
                let level = if rec.event == TraceEvent::Fault { "ERROR" } else { "WARN" };
                let text = format!("{}{on}: {} {message}", rec.event.to_string().replace('_', " "), rec.name);
                if let Some(a) = agent {
                    self.progress_log(a, None, level, text.clone());
                }
                self.log(level, text);
                self.fault_steps(&rec.name, rec.event == TraceEvent::Fault);
            }
            TraceEvent::Set => self.log("INFO", format!("set {} := {message}", rec.name)),
            TraceEvent::Told => {
                let text = format!("{} is back and was told: {message}", rec.name);
                self.progress_log(&rec.name, None, "WARN", text.clone());
                self.log("WARN", text);
            }
            TraceEvent::NewRun => {
                // The chart starts again from its initial steps: no step is held or faulted any more.
                self.before_hold = None;
                for s in self.state.iter_mut() {
                    *s = StepState::Inactive;
                }
                self.graph_dirty = true;
                self.log("INFO", format!("reset: chart {} starts again as run {message}", rec.name));
            }
            TraceEvent::SkillDone => {
                if let Some(a) = agent {
                    self.progress_log(a, None, "INFO", format!("skill {} done on {a}", rec.name));
                }
            }
            _ => {}
        }
    }

    /// A step became active: where it runs (on an agent, waiting at a convergence or for an agent, here).
    fn activated(&mut self, rec: &TraceRecord) {
        let agent = rec.agent.as_deref();
        // The last step of a simultaneous branch waits at the convergence for the others. A placed step
        // whose token has no agent yet waits for one (its dispatch says where it went).
        let s = self.steps.get(&rec.name).copied();
        let waiting = s.is_some_and(|s| self.converging[s.index()]);
        let placed = s.is_some_and(|s| self.run.layout.placement[s.index()] != Placement::Coordinator);
        if let Some(a) = agent {
            self.progress_log(a, Some(&rec.name), "INFO", format!("at step {} on {a}", rec.name));
        }
        match agent {
            _ if waiting => self.step_state(&rec.name, StepState::Waiting, "waiting"),
            Some(a) => self.step_state(&rec.name, StepState::OnAgent, &format!("on {a}")),
            None if placed => self.step_state(&rec.name, StepState::Waiting, "no agent yet"),
            None => self.step_state(&rec.name, StepState::Active, "active"),
        }
    }

    /// A token went to an agent (or resumed there): its log, and what the agent holds.
    fn dispatched(&mut self, rec: &TraceRecord) {
        let agent = rec.agent.as_deref();
        let epoch = rec.epoch.map(|e| format!(", epoch {e}")).unwrap_or_default();
        let message = rec.message.as_deref().unwrap_or("");
        let a = agent.unwrap_or("?");
        let extra = if message.is_empty() { String::new() } else { format!(": {message}") };
        // A dispatch in a later epoch restarts the segment: reassigned, or its agent restarted.
        let (level, what) = match (rec.event, rec.epoch) {
            (TraceEvent::Dispatch, Some(e)) if e > 1 => ("WARN", "dispatched again, the segment restarting,"),
            (TraceEvent::Dispatch, _) => ("INFO", "dispatched"),
            _ => ("INFO", "resumed"),
        };
        self.token_log(rec, level, format!("{what} to {a}: step {}{epoch}{extra}", rec.name));
        if let (Some(a), Some(t)) = (agent, &rec.token) {
            self.agents.entry(a.to_string()).or_default().insert(t.clone(), rec.name.clone());
            self.agent_state(a);
            if self.steps.get(&rec.name).is_some_and(|&s| self.state[s.index()] != StepState::Inactive) {
                self.step_state(&rec.name, StepState::OnAgent, &format!("on {a}"));
            }
        }
    }

    /// The run's PackML state changed.
    fn run_state(&mut self, name: &str) {
        self.log("INFO", format!("run state: {name}"));
        // Held (or suspended, or stopped), every active step is marked so; back to executing, as it was.
        let held = matches!(name, "held" | "suspended");
        if held && self.before_hold.is_none() {
            self.before_hold = Some(self.state.clone());
            for s in self.state.iter_mut().filter(|s| !matches!(s, StepState::Inactive | StepState::Faulted)) {
                *s = StepState::Held;
            }
            self.graph_dirty = true;
        } else if !held {
            if let Some(before) = self.before_hold.take() {
                // What changed while held (a step left, a fault) stands; the rest is as it was.
                for (now, was) in self.state.iter_mut().zip(before) {
                    if *now == StepState::Held {
                        *now = was;
                    }
                }
                self.graph_dirty = true;
            }
        }
    }

    /// A token came back from its agent.
    fn returned(&mut self, rec: &TraceRecord) {
        let agent = rec.agent.as_deref();
        let epoch = rec.epoch.map(|e| format!(", epoch {e}")).unwrap_or_default();
        self.token_log(rec, "INFO", format!("returned from {}: step {}{epoch}", agent.unwrap_or("?"), rec.name));
        if let (Some(a), Some(t)) = (agent, &rec.token) {
            if let Some(held) = self.agents.get_mut(a) {
                held.remove(t);
            }
            self.agent_state(a);
        }
    }

    /// Marks faulted the active steps that use action `name` (for a skill fault), or every active step whose
    /// action or transition faulted (for a run-time fault, named by the chart).
    fn fault_steps(&mut self, name: &str, chart_fault: bool) {
        let program = Arc::clone(&self.run.program);
        let hit: Vec<String> = (0..program.steps.len())
            .filter(|&i| self.state[i] != StepState::Inactive)
            .filter(|&i| {
                !chart_fault
                    && program
                        .associations(StepId(i as u32))
                        .iter()
                        .any(|a| program.actions[a.action.index()].name == name)
            })
            .map(|i| program.steps[i].name.clone())
            .collect();
        for step in hit {
            self.step_state(&step, StepState::Faulted, "faulted");
        }
    }

    fn values(&mut self, t_ms: u64, values: &[(VarId, Value)]) {
        self.at(t_ms);
        let program = Arc::clone(&self.run.program);
        for (v, value) in values {
            let name = &program.vars[v.index()].name;
            let x = match value {
                Value::Bool(b) => f64::from(u8::from(*b)),
                // A string has no number to plot: its changes are lines of the log view.
                Value::Str(s) => {
                    self.ok(self
                        .rec
                        .log(format!("vars/{name}"), &TextLog::new(format!("{name} := {}", quote_string(s)))));
                    continue;
                }
                other => other.as_f64(),
            };
            self.ok(self.rec.log(format!("vars/{name}"), &Scalars::single(x)));
        }
    }
}

/// Variables recorded as series: those that can change and have a number to plot.
fn recorded(info: &VarInfo) -> bool {
    !info.constant && !info.hidden && !matches!(info.ty, Type::Unsupported(_))
}

/// The first 8 hex digits of a token id, enough to tell tokens apart on a timeline.
fn short(token: &str) -> &str {
    token.get(..8).unwrap_or(token)
}

/// Steps in layers by their distance from the initial steps (following transitions), spread across each
/// layer; steps not reached that way go below.
fn layered_layout(program: &Program) -> Vec<[f32; 2]> {
    let n = program.steps.len();
    let mut depth: Vec<Option<usize>> = vec![None; n];
    let mut queue = std::collections::VecDeque::new();
    for &s in &program.initial_steps {
        depth[s.index()] = Some(0);
        queue.push_back(s);
    }
    while let Some(s) = queue.pop_front() {
        let d = depth[s.index()].unwrap_or(0);
        for &t in program.outgoing(s) {
            for &next in program.targets(t) {
                if depth[next.index()].is_none() {
                    depth[next.index()] = Some(d + 1);
                    queue.push_back(next);
                }
            }
        }
    }
    let deepest = depth.iter().flatten().max().copied().unwrap_or(0);
    let mut per_layer: BTreeMap<usize, usize> = BTreeMap::new();
    let mut out = Vec::with_capacity(n);
    for d in depth {
        let layer = d.unwrap_or(deepest + 1);
        let slot = per_layer.entry(layer).or_default();
        out.push([*slot as f32 * 160.0, layer as f32 * 90.0]);
        *slot += 1;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn connect_needs_a_listening_viewer_and_says_so() {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
        let port = listener.local_addr().expect("addr").port();
        let url = format!("rerun+http://127.0.0.1:{port}/proxy");
        reachable(&url).expect("a listener is reachable");
        drop(listener);
        let err = reachable(&url).expect_err("nobody listens").to_string();
        assert!(err.contains("no Rerun viewer at") && err.contains("start one with `rerun`"), "{err}");
        let err = reachable("127.0.0.1:9876").expect_err("not a URL").to_string();
        assert!(err.contains("not a Rerun viewer URL"), "{err}");
    }

    #[test]
    fn sinks_parse_and_bad_ones_say_what_is_allowed() {
        assert_eq!("off".parse(), Ok(Sink::Off));
        assert_eq!("spawn".parse(), Ok(Sink::Spawn));
        assert_eq!("connect".parse(), Ok(Sink::Connect(None)));
        assert_eq!(
            "connect:rerun+http://127.0.0.1:9000/proxy".parse(),
            Ok(Sink::Connect(Some("rerun+http://127.0.0.1:9000/proxy".into())))
        );
        assert_eq!("save:run.rrd".parse(), Ok(Sink::Save(PathBuf::from("run.rrd"))));
        assert!("save:".parse::<Sink>().is_err());
        assert!("file.rrd".parse::<Sink>().unwrap_err().contains("save:PATH.rrd"));
        let served = |addr: &str| Ok(Sink::Serve { addr: addr.parse().expect("an address"), origins: Vec::new() });
        assert_eq!("serve".parse(), served("127.0.0.1:9876"));
        assert_eq!("serve:0.0.0.0:9000".parse(), served("0.0.0.0:9000"));
        assert!("serve:somewhere".parse::<Sink>().unwrap_err().contains("HOST:PORT"));
    }

    #[test]
    fn a_taken_port_is_said_before_the_run_starts() {
        let taken = std::net::TcpListener::bind("127.0.0.1:0").expect("a port");
        let addr = taken.local_addr().expect("its address");
        let builder = rerun::RecordingStreamBuilder::new("baton");
        let Err(err) = serve(builder, addr, &[]) else { panic!("a taken port was taken") };
        assert!(err.to_string().contains(&format!("cannot serve the recording on {addr}")), "{err}");
    }
}
