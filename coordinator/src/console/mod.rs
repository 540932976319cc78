//! `baton console`: the operator console, a web page served by a Zenoh client of the cell (as `baton ctl` is one).
//! The page shows each run behind the router — its chart drawn in IEC 61131-3 notation (`back::svg`) with the active
//! steps lit and the agent holding each, its PackML state and the commands legal in it as buttons, its alarms and
//! agents — and sends an operator's commands through the same query `baton ctl` sends. Everything the page needs is
//! in this binary: no CDN, nothing fetched at run time, so it works on a plant network without internet.
//!
//! The page follows the cell by server-sent events (`GET /api/events`): the console asks the runs for their status
//! as soon as a run publishes a trace record (`keys::trace`), and every `STATUS_EVERY` besides, and sends the page
//! what changed (a `state` event); `GET /api/state` is the same once. A `history` event says the runs' history
//! grew (`history.rs`): the page asks `GET /api/runs/{run}/history?after=N` for what is new.
//! `GET /api/runs/{run}/chart.svg` is a run's chart, drawn once per chart version; `GET /api/runs/{run}/why` why
//! each active step waits (as `baton status --why`); `POST /api/runs/{run}/ctl`
//! takes a `CtlRequest` as JSON and answers with the coordinator's `CtlReply` (a refusal says why and what is
//! legal now). `GET /api/runs/{run}/nested/{action}` draws an action written in SFC as a chart of its own. The
//! page's timeline is Rerun's web viewer (`timeline.rs`, under `/rerun/`), reading a run's recording where its
//! coordinator serves it (the status's `rerun`) or a finished one of `--recordings` (`recordings.rs`).

mod auth;
mod history;
mod recordings;
mod timeline;
mod tls;
pub mod users;

use std::collections::BTreeMap;
use std::convert::Infallible;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use axum::extract::{Path as UrlPath, State};
use axum::http::{header, StatusCode};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::Extension;
use axum::{Json, Router};
use baton_host::traffic;
use baton_proto::cluster::keys;
use baton_proto::cluster::wire::{self, ChartSource, CtlRequest, RunId, StatusReport};
use baton_proto::exec::trace::TraceRecord;
use baton_proto::limits::CHART_SOURCE_BYTES_MAX;
use tokio_stream::wrappers::WatchStream;
use tokio_stream::StreamExt;
use zenoh::Session;

/// How often the console asks the runs behind its router for their status when none of them said anything: runs
/// that appear or end, agents whose tokens move.
const STATUS_EVERY: Duration = Duration::from_millis(500);
/// How long a run has to send its chart.
const CHART_TIMEOUT: Duration = Duration::from_secs(5);

/// The page: its markup, style and script in one file.
const PAGE: &str = include_str!("page.html");

/// What the page is told each time it changes: the runs behind the router, and whether the router answers.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
struct Snapshot {
    /// The console hears its router (a `false` makes the page mark everything stale).
    connected: bool,
    runs: Vec<StatusReport>,
    /// Agents a run listed and no longer does, kept on screen, greyed, with since when (rmf-web keeps a robot that
    /// disconnects on the map as stale rather than dropping it).
    lost_agents: Vec<LostAgent>,
    /// With `--election`: the run's coordinators as etcd has them, the active one first (empty: nobody stands;
    /// `null`: etcd did not answer).
    #[serde(skip_serializing_if = "Option::is_none")]
    coordinators: Option<Option<Vec<crate::election::Candidate>>>,
}

#[derive(Clone, Debug, PartialEq, serde::Serialize)]
struct LostAgent {
    run: RunId,
    name: String,
    /// When the console last saw it listed, in Unix milliseconds.
    since_unix_ms: u64,
}

/// Which agents each run listed: live, or lost since when (Unix ms).
#[derive(Default)]
struct Agents {
    seen: BTreeMap<(RunId, String), Option<u64>>,
}

impl Agents {
    /// Takes the runs' lists as they are now; returns the agents lost, oldest loss first.
    fn update(&mut self, runs: &[StatusReport], now_unix_ms: u64) -> Vec<LostAgent> {
        let live: std::collections::BTreeSet<(RunId, String)> =
            runs.iter().flat_map(|r| r.agents.iter().map(move |a| (r.run, a.name.clone()))).collect();
        // A run that no longer answers takes its agents with it.
        self.seen.retain(|(run, _), _| runs.iter().any(|r| r.run == *run));
        for (key, lost) in self.seen.iter_mut() {
            if live.contains(key) {
                *lost = None;
            } else if lost.is_none() {
                *lost = Some(now_unix_ms);
            }
        }
        for key in live {
            self.seen.entry(key).or_insert(None);
        }
        let mut lost: Vec<LostAgent> = self
            .seen
            .iter()
            .filter_map(|((run, name), lost)| {
                lost.map(|since| LostAgent { run: *run, name: name.clone(), since_unix_ms: since })
            })
            .collect();
        lost.sort_by_key(|l| l.since_unix_ms);
        lost
    }
}

/// How long the console keeps showing what it last heard of its router and of a run that fell silent:
/// zenoh-link-tls 1.10.2 drops a TLS session now and then and takes it back within milliseconds
/// (`tests/tests/zenoh_tls_race.rs`), which is no loss to show an operator.
const SILENCE_GRACE: Duration = Duration::from_millis(1500);

/// The runs as last heard, and when the router was: what the page is shown through a short silence.
#[derive(Default)]
struct Heard {
    router: Option<Instant>,
    runs: BTreeMap<RunId, (StatusReport, Instant)>,
}

impl Heard {
    /// Takes what was heard at `now` — the runs' status, if the router was there to ask and answered — and returns
    /// whether the router counts as there, and the runs to show, each as last heard. Without the router the runs
    /// stay as they were (the page marks them stale); with it, a run silent past the grace has ended.
    fn update(&mut self, answered: Option<Vec<StatusReport>>, now: Instant) -> (bool, Vec<StatusReport>) {
        if let Some(runs) = answered {
            self.router = Some(now);
            for r in runs {
                self.runs.insert(r.run, (r, now));
            }
            self.runs.retain(|_, (_, at)| now.duration_since(*at) < SILENCE_GRACE);
        }
        let connected = self.router.is_some_and(|at| now.duration_since(at) < SILENCE_GRACE);
        let mut runs: Vec<StatusReport> = self.runs.values().map(|(r, _)| r.clone()).collect();
        runs.sort_by(|a, b| (a.chart.as_str(), a.run).cmp(&(b.chart.as_str(), b.run)));
        (connected, runs)
    }
}

struct Console {
    session: Session,
    /// Who the console sends commands as: the identity it authenticates with, as `baton ctl` does.
    sender: String,
    latest: tokio::sync::watch::Sender<String>,
    /// A run published a trace record: time to ask for the status again.
    poke: tokio::sync::Notify,
    histories: Mutex<history::Histories>,
    /// The number of the newest history entry, for the pages' `history` events.
    history_seq: tokio::sync::watch::Sender<u64>,
    /// Each chart version's drawing and inputs, made once.
    charts: Mutex<BTreeMap<String, Arc<ChartView>>>,
    /// Who may do what, and the console's own trace.
    auth: Arc<auth::Auth>,
    /// Where finished runs' recordings are (`--recordings`).
    recordings: Option<PathBuf>,
    /// The run's election on etcd (`--election`).
    election: Option<crate::election::Election>,
}

/// What the page shows of a chart version: its drawing, and the inputs an operator may set (`baton set`'s: the
/// variables no action writes).
struct ChartView {
    svg: String,
    inputs: Vec<InputVar>,
    /// The chart's actions written in SFC, each drawn as a chart of its own, by name.
    nested: BTreeMap<String, String>,
    /// The bodies of its macro steps (a PLCopen chart's), each drawn as a chart of its own, by name: the chart
    /// shows each macro step as one step.
    macros: BTreeMap<String, String>,
}

#[derive(Clone, Debug, serde::Serialize)]
struct InputVar {
    name: String,
    #[serde(rename = "type")]
    ty: String,
}

/// Who may reach a console and how: HTTPS with a certificate and its key, the users who log in, and the console's
/// own trace (logins and refusals). None of it is needed on loopback.
#[derive(Clone, Debug, Default)]
pub struct Access {
    pub tls: Option<(PathBuf, PathBuf)>,
    pub users: Option<PathBuf>,
    pub trace: Option<PathBuf>,
    /// Finished runs' recordings (`.rrd`), which the page opens in its timeline.
    pub recordings: Option<PathBuf>,
    /// The run's election on etcd, whose coordinators the page names (`--election`).
    pub election: Option<crate::election::Election>,
}

/// The console's listening socket on `listen`: bound before anything else starts, so that a port taken is said at
/// once. Beyond loopback it needs TLS and users.
pub async fn bind(listen: SocketAddr, access: &Access) -> anyhow::Result<tokio::net::TcpListener> {
    if !listen.ip().is_loopback() && (access.tls.is_none() || access.users.is_none()) {
        anyhow::bail!(
            "--listen {listen}: beyond loopback the console needs TLS and users: --tls-cert FILE --tls-key FILE \
             (baton deploy certs) and --users FILE (baton deploy users); or listen on 127.0.0.1 and reach it \
             through an SSH tunnel (ssh -L 8080:127.0.0.1:8080 HOST)"
        );
    }
    tokio::net::TcpListener::bind(listen).await.with_context(|| format!("cannot listen on {listen} for the console"))
}

/// A console of a run or a demo: on loopback, where nobody logs in.
pub async fn bind_local(listen: SocketAddr) -> anyhow::Result<tokio::net::TcpListener> {
    bind(listen, &Access::default()).await
}

/// Serves the console on `listener` for the cell behind `connect`, until interrupted or told to `stop`; says where
/// on stdout. Its Zenoh session is closed before it returns.
pub async fn serve(
    listener: tokio::net::TcpListener,
    connect: &[String],
    file: Option<&std::path::Path>,
    access: Access,
    stop: tokio::sync::watch::Receiver<bool>,
) -> anyhow::Result<()> {
    let users = access.users.as_deref().map(users::Users::load).transpose()?;
    let acceptor = access.tls.as_ref().map(|(cert, key)| tls::acceptor(cert, key)).transpose()?;
    let auth = Arc::new(auth::Auth::new(users, acceptor.is_some(), access.trace.as_deref())?);
    let session = crate::client::open(connect, file).await?;
    let (latest, _) = tokio::sync::watch::channel(String::new());
    let (history_seq, _) = tokio::sync::watch::channel(0);
    let console = Arc::new(Console {
        session,
        sender: crate::client::sender(file),
        latest,
        poke: tokio::sync::Notify::new(),
        histories: Mutex::default(),
        history_seq,
        charts: Mutex::new(BTreeMap::new()),
        auth,
        recordings: access.recordings.clone(),
        election: access.election.clone(),
    });
    let _trace = listen_to_traces(&console).await?;
    // Ended with the server: left running, it would poll its timer while a run's runtime shuts down (a panic).
    let following = tokio::spawn(follow(Arc::clone(&console)));
    // Everything but the page and logging in needs a session where users log in.
    let guarded = Router::new()
        .route("/api/state", get(state))
        .route("/api/events", get(events))
        .route("/api/runs/{run}/chart.svg", get(chart))
        .route("/api/runs/{run}/nested/{action}", get(nested))
        .route("/api/runs/{run}/macro/{name}", get(macro_body))
        .route("/api/runs/{run}/ctl", post(ctl))
        .route("/api/runs/{run}/why", get(why))
        .route("/api/runs/{run}/inputs", get(inputs))
        .route("/api/runs/{run}/set", post(set))
        .route("/api/runs/{run}/history", get(history_after))
        .route("/api/recordings", get(recording_list))
        .route("/recordings/{name}", get(recording_file))
        .route(timeline::VIEWER_PAGE, get(timeline::page))
        .route(timeline::VIEWER_JS, get(timeline::script))
        .route(timeline::VIEWER_WASM, get(timeline::wasm))
        .route_layer(axum::middleware::from_fn_with_state(Arc::clone(&console.auth), auth::require));
    // Logging in and out sees only who may do what.
    let logins = Router::new()
        .route("/api/login", post(auth::login))
        .route("/api/logout", post(auth::logout))
        .route("/api/me", get(auth::me))
        .with_state(Arc::clone(&console.auth));
    let app = Router::new().route("/", get(page)).merge(guarded).with_state(Arc::clone(&console)).merge(logins);
    let bound = listener.local_addr().context("the address listened on")?;
    let scheme = if acceptor.is_some() { "https" } else { "http" };
    println!("baton console on {scheme}://{bound}/ for {}", connect.join(", "));
    let mut told = stop.clone();
    let server = async {
        match acceptor {
            Some(acceptor) => until_stopped(tls::TlsListener::new(listener, acceptor)?, app, stop).await,
            None => until_stopped(listener, app, stop).await,
        }
    };
    // Told to stop, the requests under way get `STOP_GRACE` to be answered (a command's reply on its way); a
    // page's event stream would hold a graceful end open forever, so past it the server goes.
    let served = tokio::select! {
        served = server => served,
        _ = async {
            let _ = told.wait_for(|stop| *stop).await;
            tokio::time::sleep(STOP_GRACE).await;
        } => Ok(()),
    };
    following.abort();
    let _ = following.await;
    // Closed here, not at the process's exit: a run's embedded router must not be torn down under it.
    let _ = console.session.close().await;
    served
}

async fn until_stopped<L>(listener: L, app: Router, mut stop: tokio::sync::watch::Receiver<bool>) -> anyhow::Result<()>
where
    L: axum::serve::Listener,
    L::Addr: std::fmt::Debug,
{
    axum::serve(listener, app)
        .with_graceful_shutdown(async move {
            tokio::select! {
                _ = tokio::signal::ctrl_c() => {}
                _ = stop.wait_for(|stop| *stop) => {}
            }
        })
        .await
        .context("the console's server")
}

/// A console serving in the background of a run or a demo.
pub struct Background {
    stop: tokio::sync::watch::Sender<bool>,
    task: tokio::task::JoinHandle<()>,
}

impl Background {
    /// Stops the console and waits until its session is closed: before the run's own session, whose embedded
    /// router the console is a client of, so that the router is never torn down under it.
    pub async fn stop(self) {
        self.stop.send_replace(true);
        let _ = tokio::time::timeout(STOP_GRACE * 4, self.task).await;
    }
}

/// How long a console told to stop gives the requests under way.
const STOP_GRACE: Duration = Duration::from_millis(500);

/// Serves the console in the background of a run or a demo, for the cell behind `endpoints`; a console that
/// stops says why and leaves the run alone.
pub fn spawn(
    listener: tokio::net::TcpListener,
    endpoints: Vec<String>,
    file: Option<std::path::PathBuf>,
) -> Background {
    let (stop, told) = tokio::sync::watch::channel(false);
    let task = tokio::spawn(async move {
        if let Err(e) = serve(listener, &endpoints, file.as_deref(), Access::default(), told).await {
            eprintln!("error: the console stopped: {e:#}");
        }
    });
    Background { stop, task }
}

/// Where a console in the process of a run or a demo reaches its cell: the router it joined, or the one it
/// embeds, on loopback where it listens on every address.
pub fn endpoints_of(listen: &[String], connect: &[String]) -> Vec<String> {
    if !connect.is_empty() {
        return connect.to_vec();
    }
    listen.iter().map(|e| e.replace("/0.0.0.0:", "/127.0.0.1:").replace("/[::]:", "/[::1]:")).collect()
}

/// Asks the runs for their status every `STATUS_EVERY`, and publishes what the page is told when it changed.
async fn follow(console: Arc<Console>) {
    let mut tick = tokio::time::interval(STATUS_EVERY);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut last = Snapshot { connected: false, runs: Vec::new(), lost_agents: Vec::new(), coordinators: None };
    let mut election = console.election.clone().map(crate::election::Follower::new);
    let mut agents = Agents::default();
    let mut heard = Heard::default();
    let mut first = true;
    loop {
        tokio::select! {
            _ = tick.tick() => {}
            _ = console.poke.notified() => {}
        }
        let answered = match console.session.info().routers_zid().await.next() {
            Some(_) => crate::client::status_on(&console.session).await.ok(),
            None => None,
        };
        let asked = answered.is_some();
        if !asked {
            if let Ok(mut histories) = console.histories.lock() {
                histories.ask_again();
            }
        }
        let (connected, runs) = heard.update(answered, Instant::now());
        let now = baton_host::unix_ms();
        // Without an answer nothing new is known of the agents: their list stays as it was.
        let lost_agents = if asked { agents.update(&runs, now) } else { last.lost_agents.clone() };
        ask_histories(&console, &runs, now);
        let coordinators = match &mut election {
            Some(follower) => Some(follower.read().await.ok()),
            None => None,
        };
        let snapshot = Snapshot { connected, runs, lost_agents, coordinators };
        let mut still = snapshot.clone();
        // A run's clocks alone moving is no change to tell the page of (it counts the steps' times on itself).
        for r in &mut still.runs {
            (r.t_ms, r.unix_ms) = (0, 0);
            r.active_steps.iter_mut().for_each(|s| s.active_ms = 0);
        }
        if still != last || first {
            (last, first) = (still, false);
            console.latest.send_replace(serde_json::to_string(&snapshot).unwrap_or_default());
        }
    }
}

async fn page() -> impl IntoResponse {
    ([(header::CONTENT_TYPE, "text/html; charset=utf-8"), (header::CACHE_CONTROL, "no-cache")], PAGE)
}

async fn state(State(console): State<Arc<Console>>) -> impl IntoResponse {
    let text = console.latest.borrow().clone();
    ([(header::CONTENT_TYPE, "application/json")], text)
}

/// Server-sent events: a `state` event now (once there is one) and each time it changes; a `history` event (the
/// newest entry's number) each time a run's history grows.
async fn events(
    State(console): State<Arc<Console>>,
) -> Sse<impl tokio_stream::Stream<Item = Result<Event, Infallible>>> {
    let states = WatchStream::new(console.latest.subscribe())
        .filter(|text| !text.is_empty())
        .map(|text| Ok(Event::default().event("state").data(text)));
    let histories = WatchStream::new(console.history_seq.subscribe())
        .map(|seq| Ok(Event::default().event("history").data(seq.to_string())));
    Sse::new(states.merge(histories)).keep_alive(KeepAlive::default())
}

/// Hears every run's trace records: history is kept, and any record has the status asked for again.
async fn listen_to_traces(console: &Arc<Console>) -> anyhow::Result<zenoh::pubsub::Subscriber<()>> {
    use baton_host::ZenohResult;
    let weak = Arc::downgrade(console);
    traffic::subscriber(&console.session, keys::trace_any_run())
        .callback(move |sample| {
            let Some(console) = weak.upgrade() else { return };
            let run = keys::run_of_trace(sample.key_expr().as_str()).and_then(|r| uuid::Uuid::parse_str(r).ok());
            let record = wire::decode::<baton_proto::exec::trace::TraceRecord>(&sample.payload().to_bytes());
            if let (Some(run), Ok(record)) = (run, record) {
                let now = baton_host::unix_ms();
                console.keep_history(RunId(run), vec![record], |_| now);
            }
            console.poke.notify_one();
        })
        .await
        .zenoh()
}

impl Console {
    fn keep_history(&self, run: RunId, records: Vec<TraceRecord>, unix_ms: impl Fn(&TraceRecord) -> u64) {
        let Ok(mut histories) = self.histories.lock() else { return };
        if histories.add(run, records, unix_ms) {
            self.history_seq.send_replace(histories.last_seq());
        }
    }
}

/// Asks each run the console had not heard of before for the history its coordinator kept, in the background;
/// forgets runs gone. `now` is when `runs` answered, on the console's clock.
fn ask_histories(console: &Arc<Console>, runs: &[StatusReport], now: u64) {
    let Ok(mut histories) = console.histories.lock() else { return };
    histories.forget_beyond(&runs.iter().map(|r| r.run).collect());
    for report in runs.iter().filter(|r| histories.first_sight(r.run)) {
        let (console, run, t_ms) = (Arc::clone(console), report.run, report.t_ms);
        tokio::spawn(async move {
            match ask_history(&console.session, run).await {
                // The run's clock read `t_ms` at `now`.
                Ok(records) => console.keep_history(run, records, |r| now.saturating_sub(t_ms.saturating_sub(r.t_ms))),
                Err(why) => {
                    eprintln!("warning: the console has no history of run {} before now: {why}", run.key());
                    // Asked again at the next look.
                    if let Ok(mut histories) = console.histories.lock() {
                        histories.ask_again();
                    }
                }
            }
        });
    }
}

async fn ask_history(session: &Session, run: RunId) -> Result<Vec<TraceRecord>, String> {
    let replies = traffic::get(session, keys::history(run)).timeout(CHART_TIMEOUT).await.map_err(|e| e.to_string())?;
    let reply = replies.recv_async().await.map_err(|_| "its coordinator did not answer".to_string())?;
    let sample = reply.result().map_err(|e| format!("refused: {e:?}"))?;
    history::decode_answer(&sample.payload().to_bytes())
}

#[derive(serde::Deserialize)]
struct After {
    #[serde(default)]
    after: u64,
}

/// Run `run`'s history entries numbered after `?after=N` (all without it), oldest first.
async fn history_after(
    State(console): State<Arc<Console>>,
    UrlPath(run): UrlPath<String>,
    axum::extract::Query(after): axum::extract::Query<After>,
) -> Response {
    let run = match run_id(&run) {
        Ok(r) => r,
        Err(refused) => return refused.into_response(),
    };
    match console.histories.lock() {
        Ok(histories) => Json(histories.after(run, after.after)).into_response(),
        Err(_) => (StatusCode::INTERNAL_SERVER_ERROR, "poisoned").into_response(),
    }
}

/// A run's id as the URL writes it: 32 hex digits (as `baton status` prints it) or the hyphenated form; else a
/// 400 answer saying so.
fn run_id(text: &str) -> Result<RunId, (StatusCode, String)> {
    uuid::Uuid::parse_str(text).map(RunId).map_err(|_| (StatusCode::BAD_REQUEST, format!("`{text}` is not a run id")))
}

/// The run's chart drawn (`baton export --svg` of the chart the run coordinates).
async fn chart(State(console): State<Arc<Console>>, UrlPath(run): UrlPath<String>) -> Response {
    drawing(&console, &run, |view| Some(&view.svg), String::new).await
}

/// The chart of run `run`'s action `action`, an action written in SFC, drawn as a chart of its own.
async fn nested(State(console): State<Arc<Console>>, UrlPath((run, action)): UrlPath<(String, String)>) -> Response {
    let missing = || format!("`{action}` is no action of this chart written in SFC");
    drawing(&console, &run, |view| view.nested.get(&action), missing).await
}

/// The body of run `run`'s macro step `name`, drawn as a chart of its own.
async fn macro_body(State(console): State<Arc<Console>>, UrlPath((run, name)): UrlPath<(String, String)>) -> Response {
    let missing = || format!("`{name}` is no macro step of this chart");
    drawing(&console, &run, |view| view.macros.get(&name), missing).await
}

/// One of the drawings of run `run`'s chart, as `pick` finds it in the chart's view: an SVG answer, or 404 with
/// `missing` where there is none.
async fn drawing(
    console: &Console,
    run: &str,
    pick: impl FnOnce(&ChartView) -> Option<&String>,
    missing: impl FnOnce() -> String,
) -> Response {
    let run = match run_id(run) {
        Ok(r) => r,
        Err(refused) => return refused.into_response(),
    };
    match chart_view(console, run).await {
        Ok(view) => match pick(&view) {
            Some(svg) => ([(header::CONTENT_TYPE, "image/svg+xml")], svg.clone()).into_response(),
            None => (StatusCode::NOT_FOUND, missing()).into_response(),
        },
        Err(why) => (StatusCode::BAD_GATEWAY, why).into_response(),
    }
}

/// The finished runs' recordings of `--recordings`.
async fn recording_list(State(console): State<Arc<Console>>) -> Response {
    recordings::list(console.recordings.clone()).await
}

async fn recording_file(State(console): State<Arc<Console>>, UrlPath(name): UrlPath<String>) -> Response {
    recordings::file(console.recordings.as_deref(), &name).await
}

/// The inputs of run `run`'s chart an operator may set, with their types.
async fn inputs(State(console): State<Arc<Console>>, UrlPath(run): UrlPath<String>) -> Response {
    let run = match run_id(&run) {
        Ok(r) => r,
        Err(refused) => return refused.into_response(),
    };
    match chart_view(&console, run).await {
        Ok(view) => Json(view.inputs.clone()).into_response(),
        Err(why) => (StatusCode::BAD_GATEWAY, why).into_response(),
    }
}

/// `{"name": NAME, "value": JSON}`: sets an input of run `run` as `baton set` does, under the console's identity.
#[derive(serde::Deserialize)]
struct SetBody {
    name: String,
    value: serde_json::Value,
}

async fn set(
    State(console): State<Arc<Console>>,
    Extension(who): Extension<auth::Who>,
    UrlPath(run): UrlPath<String>,
    Json(body): Json<SetBody>,
) -> Response {
    let run = match run_id(&run) {
        Ok(r) => r,
        Err(refused) => return refused.into_response(),
    };
    if let Err(forbidden) = console.allowed(&who, users::Role::Operator, "set") {
        return forbidden.into_response();
    }
    let by = (console.sender.as_str(), who.user.as_deref());
    reply_of(run, crate::client::set_as(&console.session, Some(run), &body.name, body.value, by).await)
}

impl Console {
    /// Whether `who` may do `what`, which needs `needed`; else the 403 answer, the refusal traced.
    fn allowed(&self, who: &auth::Who, needed: users::Role, what: &str) -> Result<(), (StatusCode, String)> {
        if who.role >= needed {
            return Ok(());
        }
        let user = who.user.as_deref().unwrap_or("this page");
        let why = format!("{user} is {}: `{what}` needs {}", who.role.name(), needed.name());
        let by = keys::by_whom(&self.sender, who.user.as_deref());
        self.auth.trace(baton_proto::exec::trace::TraceEvent::CommandRefused, what, Some(by), why.clone());
        Err((StatusCode::FORBIDDEN, why))
    }
}

/// The run's answer to a query sent to it alone, as JSON; 502 when it did not answer or the query failed.
fn reply_of<T: serde::Serialize>(run: RunId, replies: anyhow::Result<Vec<T>>) -> Response {
    match replies {
        Ok(replies) => match replies.into_iter().next() {
            Some(reply) => Json(reply).into_response(),
            None => (StatusCode::BAD_GATEWAY, format!("run {} did not answer", run.key())).into_response(),
        },
        Err(e) => (StatusCode::BAD_GATEWAY, format!("{e:#}")).into_response(),
    }
}

/// Run `run`'s answer with its chart. A query that ends with no answer at all is asked again, for up to
/// `CHART_TIMEOUT`: a session that zenoh-link-tls drops is back within milliseconds (`SILENCE_GRACE`).
async fn ask_chart(session: &Session, run: RunId) -> Result<zenoh::query::Reply, String> {
    let began = Instant::now();
    loop {
        let replies = traffic::get(session, keys::chart(run))
            .timeout(CHART_TIMEOUT)
            .await
            .map_err(|e| format!("cannot ask run {} for its chart: {e}", run.key()))?;
        if let Ok(reply) = replies.recv_async().await {
            return Ok(reply);
        }
        if began.elapsed() >= CHART_TIMEOUT {
            return Err(format!("run {} did not send its chart", run.key()));
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// Asks run `run` for its chart and draws it, or takes what was made of that chart version before.
async fn chart_view(console: &Console, run: RunId) -> Result<Arc<ChartView>, String> {
    let reply = ask_chart(&console.session, run).await?;
    let sample = reply.result().map_err(|e| format!("run {} refused its chart: {e:?}", run.key()))?;
    let src: ChartSource = wire::decode_with_limit(&sample.payload().to_bytes(), CHART_SOURCE_BYTES_MAX)
        .map_err(|e| format!("run {}'s chart: {e}", run.key()))?;
    if let Some(view) = console.charts.lock().map_err(|_| "poisoned".to_string())?.get(&src.hash.0) {
        return Ok(Arc::clone(view));
    }
    let report = baton_proto::pipeline::check_source(&src.source);
    let checked = report.charts.iter().find(|c| c.chart.name.name == src.pou);
    let Some((chart, Some(program), Some(layout))) = checked.map(|c| (&c.chart, c.program.as_ref(), c.layout.as_ref()))
    else {
        return Err(format!("run {}'s chart `{}` does not compile here", run.key(), src.pou));
    };
    let inputs = program
        .vars
        .iter()
        .zip(&layout.settable)
        .filter(|(v, &settable)| settable && !v.hidden && !v.constant)
        .map(|(v, _)| InputVar { name: v.name.clone(), ty: v.ty.to_string() })
        .collect();
    let nested = chart
        .actions
        .iter()
        .filter(|a| a.sfc.is_some())
        .filter_map(|a| {
            let (inner, program) = baton_proto::back::svg::nested(chart, &report.library, &report.types, &a.name.name)?;
            Some((a.name.name.clone(), baton_proto::back::svg::chart(&inner, &program)))
        })
        .collect();
    let svg = baton_proto::back::svg::collapsed(chart, &report.library, &report.types, None).map_or_else(
        || baton_proto::back::svg::chart(chart, program),
        |(drawn, p)| baton_proto::back::svg::chart(&drawn, &p),
    );
    let macros = chart
        .macros
        .iter()
        .filter_map(|m| {
            let name = m.name.name.as_str();
            let (body, program) = baton_proto::back::svg::collapsed(chart, &report.library, &report.types, Some(name))?;
            Some((name.to_string(), baton_proto::back::svg::chart(&body, &program)))
        })
        .collect();
    let view = Arc::new(ChartView { svg, inputs, nested, macros });
    console.charts.lock().map_err(|_| "poisoned".to_string())?.insert(src.hash.0, Arc::clone(&view));
    Ok(view)
}

/// Why each active step of run `run` waits, as `baton status --why` says it: the coordinator's own steps and, asked
/// of them, the agents'.
async fn why(State(console): State<Arc<Console>>, UrlPath(run): UrlPath<String>) -> Response {
    let run = match run_id(&run) {
        Ok(r) => r,
        Err(refused) => return refused.into_response(),
    };
    let asked = async {
        let mut reports = crate::client::status_on(&console.session).await?;
        reports.retain(|r| r.run == run);
        crate::client::add_agents_why(&console.session, &mut reports).await?;
        anyhow::Ok(reports)
    };
    match asked.await {
        Ok(reports) => match reports.into_iter().next() {
            Some(report) => {
                // Each step's reasons, and the one line `baton status --why` prints of them.
                let steps: Vec<serde_json::Value> = report
                    .why
                    .iter()
                    .map(|w| {
                        let mut v = serde_json::to_value(w).unwrap_or_default();
                        v["summary"] = serde_json::Value::String(w.summary());
                        v
                    })
                    .collect();
                Json(steps).into_response()
            }
            None => (StatusCode::NOT_FOUND, format!("run {} does not answer", run.key())).into_response(),
        },
        Err(e) => (StatusCode::BAD_GATEWAY, format!("{e:#}")).into_response(),
    }
}

/// An operator's command to run `run`, sent as `baton ctl` sends it, under the console's identity and for the user
/// logged in — if their role allows it (`users::needed`), else 403.
async fn ctl(
    State(console): State<Arc<Console>>,
    Extension(who): Extension<auth::Who>,
    UrlPath(run): UrlPath<String>,
    Json(mut request): Json<CtlRequest>,
) -> Response {
    let run = match run_id(&run) {
        Ok(r) => r,
        Err(refused) => return refused.into_response(),
    };
    if let Err(forbidden) = console.allowed(&who, users::needed(&request), &request.command.to_ascii_lowercase()) {
        return forbidden.into_response();
    }
    request.by.clone_from(&console.sender);
    request.user.clone_from(&who.user);
    reply_of(run, crate::client::ctl_on(&console.session, Some(run), &request).await)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn report(run: u128) -> StatusReport {
        let text = format!(
            r#"{{"run": "{}", "chart": "c", "hash": "h", "t_ms": 0, "active_steps": [], "tokens": [], "agents": []}}"#,
            uuid::Uuid::from_u128(run)
        );
        serde_json::from_str(&text).expect("a status report")
    }

    #[test]
    fn a_short_silence_shows_what_was_heard_and_a_long_one_says_so() {
        let mut heard = Heard::default();
        let t0 = Instant::now();
        let (connected, runs) = heard.update(Some(vec![report(1), report(2)]), t0);
        assert!(connected && runs.len() == 2);
        // The router gone for a moment: as it was.
        let (connected, runs) = heard.update(None, t0 + SILENCE_GRACE / 2);
        assert!(connected && runs.len() == 2);
        // Run 2 silent for a moment while the router answers: still shown; past the grace, it has ended.
        assert_eq!(heard.update(Some(vec![report(1)]), t0 + SILENCE_GRACE / 2).1.len(), 2);
        let (_, runs) = heard.update(Some(vec![report(1)]), t0 + SILENCE_GRACE * 2);
        assert_eq!(runs.iter().map(|r| r.run.0.as_u128()).collect::<Vec<_>>(), [1]);
        // The router gone past the grace: not connected, and the runs stay as last heard, to be shown stale.
        let (connected, runs) = heard.update(None, t0 + SILENCE_GRACE * 4);
        assert!(!connected && runs.len() == 1);
    }
}
