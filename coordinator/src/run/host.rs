//! The coordinator's Zenoh host: samples and queries in, the pure `Coordinator`'s inputs out, its outputs held
//! until the journal has what led to them, then published; agents that go live are asked who they are.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::anyhow;
use baton_host::{traffic, Shared, ZenohResult};
use baton_proto::cluster::journal::Journaled;
use baton_proto::cluster::keys;
use baton_proto::cluster::runtime::coordinator::CoordOutput;
use baton_proto::cluster::runtime::Level;
use baton_proto::cluster::wire::{self, AgentInfo, CtlReply, CtlRequest, RunId, SetReply, SetRequest};
use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use baton_proto::limits::CATCH_UP_CYCLES_MAX;
use tokio::sync::mpsc;
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::Subscriber;
use zenoh::query::Query;
use zenoh::query::Queryable;
use zenoh::sample::{Locality, Sample, SampleKind};
use zenoh::Session;

use super::records::Records;
use super::summary::Summary;
use crate::chart_file::Loaded;
use crate::journal::{OnDurable, Outgoing};

pub(crate) const INFO_QUERY_TIMEOUT: Duration = Duration::from_secs(3);

pub(crate) const INFO_QUERY_ATTEMPTS: u32 = 5;

/// Replies to one info query taken into account: two already mean a conflict.
pub(crate) const INFO_REPLIES_MAX: usize = 16;

/// How often a name that several processes answer to is asked again.
pub(crate) const CONFLICT_RECHECK: Duration = Duration::from_secs(2);

/// Who answered to an agent's name.
pub(crate) enum Identity {
    One(AgentInfo),
    /// Several processes answered to this name (how many).
    Several(String, u32),
    /// Nobody that makes sense, and why.
    Unknown(String, String),
    /// What an agent asked because a token of it was quiet (`CoordOutput::Ask`) listed as sent and not
    /// acknowledged (nothing if it did not answer).
    Pending(String, Vec<baton_proto::cluster::wire::Report>),
}

/// How the journal's writer sends what a durable batch led to: through an outbox of its own on the run's session,
/// from its thread, without waiting for the main loop's turn. A key that cannot be declared stops the journal and
/// the run (as it ends the run in `Host::send`); a put that fails is a warning (the state machines resend what
/// matters).
pub(crate) fn deliver_through(session: &Session) -> crate::journal::Deliver {
    let mut outbox = baton_host::Outbox::new(session);
    Box::new(move |messages| {
        for Outgoing { key, payload } in messages {
            weigh(outbox.put(&key, payload))?;
        }
        Ok(())
    })
}

/// `deliver`, while `acting`: once a coordinator stopped acting (its election lost), what its journal still makes
/// durable is sent to nobody — a standby that won goes on from the same records.
pub(crate) fn deliver_while(
    mut deliver: crate::journal::Deliver,
    acting: std::sync::Arc<std::sync::atomic::AtomicBool>,
) -> crate::journal::Deliver {
    Box::new(move |messages| if acting.load(std::sync::atomic::Ordering::SeqCst) { deliver(messages) } else { Ok(()) })
}

/// What a put that did not go means for the run: a key that cannot be declared ends it (the reason returned), a
/// failed put is a warning (the state machines resend what matters).
fn weigh(sent: Result<(), baton_host::Unsent>) -> Result<(), String> {
    match sent {
        Err(baton_host::Unsent::Declare(why)) => Err(why),
        Err(baton_host::Unsent::Put(why)) => {
            eprintln!("warning: {why}");
            Ok(())
        }
        Ok(()) => Ok(()),
    }
}

/// Command keys kept (`CmdKeys`); all are forgotten when more are needed, as the outbox forgets its publishers.
const CMD_KEYS_MAX: usize = baton_host::PUBLISHERS_MAX;

/// Each agent process's command key (`keys::agent_cmd`), made once rather than for every dispatch: by the process's
/// incarnation, with the agent's name it was made for (a process that announces another's incarnation gets its own).
#[derive(Default)]
pub(crate) struct CmdKeys(HashMap<uuid::Uuid, (String, String)>);

impl CmdKeys {
    fn of(&mut self, agent: &str, incarnation: uuid::Uuid) -> String {
        if let Some((name, key)) = self.0.get(&incarnation) {
            if name == agent {
                return key.clone();
            }
        }
        if self.0.len() >= CMD_KEYS_MAX {
            self.0.clear();
        }
        let key = keys::agent_cmd(agent, incarnation);
        self.0.insert(incarnation, (agent.to_string(), key.clone()));
        key
    }
}

/// The message an output of the coordinator puts on the wire, with its key (`vars_key` for variable updates),
/// stamped with the coordinator's `term`; `None` for an output that stays in this process.
fn message(vars_key: &str, cmd_keys: &mut CmdKeys, term: u64, out: &CoordOutput) -> Option<Outgoing> {
    match out {
        CoordOutput::Send { agent, incarnation, msg } => {
            Some(Outgoing { key: cmd_keys.of(agent, *incarnation), payload: wire::encode_termed(msg, term) })
        }
        CoordOutput::Vars(update) => {
            Some(Outgoing { key: vars_key.to_string(), payload: wire::encode_termed(update, term) })
        }
        _ => None,
    }
}

pub(crate) struct Host {
    pub(crate) session: Session,
    pub(crate) core: Journaled,
    pub(crate) started: Instant,
    /// The run's time when this process started: 0, or where a resumed run stood (downtime included).
    pub(crate) base_ms: u64,
    pub(crate) journal: Option<crate::journal::Writer>,
    /// A snapshot after this many records since the last (0: none), and the record count it is due at.
    pub(crate) snapshot_every: u64,
    pub(crate) snapshot_due: u64,
    /// What the coordinator asked for that stays in this process (trace records, logs, questions), per journal
    /// batch, until that batch is durable; the batch's messages go with it to the journal's writer.
    pub(crate) held: VecDeque<(u64, Vec<CoordOutput>)>,
    /// Answers to `baton set` and `baton ctl`, likewise (with the key they answer on): a client is told a value
    /// or a command was taken only once it is durable. Each waits for the batch its request went into, which the
    /// next `commit` gives it (`None` until then); a request that recorded nothing waits only for the batches
    /// before it, at most `HELD_REPLIES_MAX` of them.
    pub(crate) held_replies: VecDeque<(Option<u64>, Query, String, Vec<u8>)>,
    pub(crate) quiet: bool,
    /// The coordinator's term, on every command and variable update it sends (`wire::encode_termed`): the
    /// revision at which it won the run's election, 0 for a coordinator that stands in none.
    pub(crate) term: u64,
    /// One publisher per key, declared on first use.
    pub(crate) outbox: baton_host::Outbox,
    pub(crate) vars_key: String,
    pub(crate) cmd_keys: CmdKeys,
    pub(crate) decode_drops: u64,
    pub(crate) out: Records,
    /// The run's cycle period, and the grid time of the last cycle this process ran.
    pub(crate) cycle_ms: u64,
    pub(crate) last_cycle_ms: Option<u64>,
    /// Agents whose liveliness token is there: those are asked again until they say who they are.
    pub(crate) live: std::collections::HashSet<String>,
    /// Where answers to questions go (the main loop's), and the agents asked for their pending reports whose
    /// answer has not come yet (one question at a time each).
    pub(crate) answers: Option<mpsc::UnboundedSender<Identity>>,
    pub(crate) asking: std::collections::HashSet<String>,
    /// The deadline the main loop sleeps until: a callback that needs an earlier cycle wakes it.
    pub(crate) armed: Option<Instant>,
    /// What went wrong in a callback (the journal, a key that cannot be declared): the main loop ends the run with it.
    pub(crate) failed: Option<anyhow::Error>,
}

/// The run's inboxes: liveliness in, and the queries it answers. (Reports, variables and device reports are taken in
/// Zenoh's callbacks: `Callbacks`.)
pub(crate) struct Inboxes {
    pub(crate) alive: Subscriber<FifoChannelHandler<Sample>>,
    pub(crate) chart: Queryable<FifoChannelHandler<Query>>,
    pub(crate) status: Queryable<FifoChannelHandler<Query>>,
    pub(crate) set: Queryable<FifoChannelHandler<Query>>,
    pub(crate) ctl: Queryable<FifoChannelHandler<Query>>,
}

impl Inboxes {
    pub(crate) async fn declare(session: &Session, run: RunId) -> anyhow::Result<Inboxes> {
        Ok(Inboxes {
            alive: traffic::liveliness_subscriber(session, keys::alive_any()).history(true).await.zenoh()?,
            chart: traffic::queryable(session, keys::chart(run)).await.zenoh()?,
            status: traffic::queryable(session, keys::status(run)).await.zenoh()?,
            set: traffic::queryable(session, keys::set(run, "*")).await.zenoh()?,
            ctl: traffic::queryable(session, keys::ctl(run, "*")).await.zenoh()?,
        })
    }
}

/// The run's messages from agents — reports, variable updates, device reports — each handled in the Zenoh callback
/// that delivers it, under the host's lock (`baton_host::shared`): cycles due first, then the message, then what it
/// led to carried out (or handed to the journal).
pub(crate) struct Callbacks {
    _subscribers: [Subscriber<()>; 3],
}

impl Callbacks {
    pub(crate) async fn declare(
        session: &Session,
        run: RunId,
        shared: &Arc<Shared<Host>>,
    ) -> anyhow::Result<Callbacks> {
        let declare = |key: String, on: fn(&mut Host, &Sample)| {
            traffic::subscriber(session, key).allowed_origin(Locality::Remote).callback(taking(shared, on))
        };
        Ok(Callbacks {
            _subscribers: [
                declare(keys::report_any(run), Host::on_report).await.zenoh()?,
                declare(keys::vars(run, "*"), Host::on_vars).await.zenoh()?,
                declare(keys::devices(run, "*"), Host::on_devices).await.zenoh()?,
            ],
        })
    }
}

/// A Zenoh callback that hands each sample to `on` under the host's lock, with the cycles due run first and what
/// it led to carried out after; it wakes the main loop when the loop has something to look at (`Host::must_look`).
fn taking(shared: &Arc<Shared<Host>>, on: fn(&mut Host, &Sample)) -> impl Fn(Sample) + Send + Sync + 'static {
    let shared = Arc::clone(shared);
    move |sample| {
        shared.handle(sample, move |host, sample| {
            if host.failed.is_none() {
                let handled = host.due_cycles().and_then(|()| {
                    on(host, &sample);
                    host.commit(Vec::new())
                });
                if let Err(e) = handled {
                    host.failed = Some(e);
                }
            }
            host.must_look()
        })
    }
}

/// The journal writer's hook (`Writer::on_durable`): what durable batches held (the trace, answers to requests) is
/// released on the writer thread, under the host's lock, rather than by a wake-up of the main loop per commit. A
/// failed journal is the main loop's to report.
pub(crate) fn releasing(shared: &Arc<Shared<Host>>) -> OnDurable {
    let shared = Arc::downgrade(shared);
    Arc::new(move || {
        let Some(shared) = shared.upgrade() else { return };
        shared.handle_alone((), |host, ()| {
            if host.failed.is_none() {
                if let Err(e) = host.release() {
                    host.failed = Some(e);
                }
            }
            host.must_look()
        });
    })
}

/// What woke the coordinator's main loop.
pub(crate) enum Wake {
    Alive(Sample),
    Identity(Identity),
    Chart(Query),
    Status(Query),
    Set(Query),
    Ctl(Query),
    Timer,
    /// A callback made the deadline earlier, failed, or ended or reset the run.
    Look,
    Stop(baton_host::Signal),
    Closed,
}

/// Who a `set` or `ctl` query's key says sent it; why it names nobody, if not.
fn request_sender(q: &Query) -> Result<&str, String> {
    keys::sender_of_request(q.key_expr().as_str()).ok_or_else(|| {
        format!("the request on {} names no sender: ask on baton/run/<run>/ctl/<your name>", q.key_expr())
    })
}

/// Answers on the queryable's own key, which names the run: a client that asked all runs (`baton/run/*/status`)
/// gets one reply per run, where replies on the query's key would be consolidated into one.
pub(crate) fn reply(q: &Query, key: String, payload: Vec<u8>) {
    if let Err(e) = traffic::reply(q, key, payload) {
        eprintln!("warning: cannot answer a query on {}: {e}", q.key_expr());
    }
}

impl Host {
    /// The coordinator stops acting (`why`): said in its log and its trace. Nothing is sent any more.
    pub(crate) fn stopped_acting(&mut self, why: &str) {
        eprintln!("baton: stopped coordinating: {why}");
        let rec = TraceRecord {
            message: Some(why.to_string()),
            ..TraceRecord::new(self.now_ms(), TraceEvent::Deposed, "coordinator")
        };
        self.out.record(rec);
    }

    /// `baton set`: taken only from a sender the key names, answered on the run's own key with that name.
    pub(crate) fn on_set_query(&mut self, q: Query, run: RunId) {
        // Taken only from a sender the key names, answered on the run's own key with that name.
        match request_sender(&q).map(str::to_string) {
            Err(why) => reply(&q, q.key_expr().to_string(), wire::encode(&self.set_refused(why))),
            Ok(sender) if self.replies_full() => {
                let answer = wire::encode(&self.set_refused(self.busy()));
                reply(&q, keys::set(run, &sender), answer);
            }
            Ok(sender) => {
                let answer = wire::encode(&self.on_set(&q, &sender));
                self.answer(q, keys::set(run, &sender), answer);
            }
        }
    }

    /// `baton ctl`: taken only from a sender the key names, answered on the run's own key with that name.
    pub(crate) fn on_ctl_query(&mut self, q: Query, run: RunId) {
        match request_sender(&q).map(str::to_string) {
            Err(why) => reply(&q, q.key_expr().to_string(), wire::encode(&self.ctl_reply(Err(why)))),
            Ok(sender) if self.replies_full() => {
                let answer = wire::encode(&self.ctl_reply(Err(self.busy())));
                reply(&q, keys::ctl(run, &sender), answer);
            }
            Ok(sender) => {
                let answer = wire::encode(&self.on_ctl(&q, &sender));
                self.answer(q, keys::ctl(run, &sender), answer);
            }
        }
    }

    /// After a `reset`, the chart starts again as a new run, journaled: its id, for the inboxes of its own the
    /// main loop declares.
    pub(crate) fn new_run_if_reset(&mut self) -> anyhow::Result<Option<RunId>> {
        Ok(if self.core.core().wants_new_run() {
            // `reset`: the chart starts again as a new run, journaled, with inboxes of its own.
            let next = RunId(uuid::Uuid::new_v4());
            let now = self.now_ms();
            self.core.new_run(now, next);
            self.commit(Vec::new())?;
            self.vars_key = keys::vars(next, baton_proto::cluster::runtime::COORDINATOR);
            if !self.quiet {
                eprintln!(
                    "baton: reset: chart `{}` starts again as run {} (after `baton ctl start`)",
                    self.core.core().program().name,
                    next.key()
                );
            }
            Some(next)
        } else {
            None
        })
    }

    pub(crate) fn now_ms(&self) -> u64 {
        self.base_ms + self.started.elapsed().as_millis() as u64
    }

    pub(crate) fn on_report(&mut self, s: &Sample) {
        let now = self.now_ms();
        let Some(sender) = self.sender(s) else { return };
        if let Err(e) = self.core.report(now, sender, &s.payload().to_bytes()) {
            self.decode_drop(s, e);
        }
        self.out.values(now, self.core.core());
    }

    pub(crate) fn on_vars(&mut self, s: &Sample) {
        let now = self.now_ms();
        let Some(sender) = self.sender(s) else { return };
        if let Err(e) = self.core.vars(now, sender, &s.payload().to_bytes()) {
            self.decode_drop(s, e);
        }
        self.out.values(now, self.core.core());
    }

    pub(crate) fn on_devices(&mut self, s: &Sample) {
        let now = self.now_ms();
        let Some(sender) = self.sender(s) else { return };
        if let Err(e) = self.core.devices(now, sender, &s.payload().to_bytes()) {
            self.decode_drop(s, e);
        }
    }

    /// The process a run's message comes from, as its key names it (what the router's access control checks).
    fn sender<'s>(&mut self, s: &'s Sample) -> Option<&'s str> {
        let sender = keys::sender(s.key_expr().as_str());
        if sender.is_none() {
            self.decode_drops += 1;
            eprintln!("warning: dropped a message on {}: its key names no sender", s.key_expr());
        }
        sender
    }

    pub(crate) fn decode_drop(&mut self, s: &Sample, e: wire::WireError) {
        self.decode_drops += 1;
        eprintln!("warning: dropped a message on {}: {e}", s.key_expr());
    }

    /// A live agent is asked for its roles before the coordinator counts on it.
    pub(crate) fn on_alive(&mut self, s: &Sample, tx: &mpsc::UnboundedSender<Identity>) {
        let Some(name) = keys::agent_of_alive(s.key_expr().as_str()).map(str::to_string) else { return };
        match s.kind() {
            SampleKind::Put => {
                if self.live.len() < baton_proto::limits::AGENTS_MAX {
                    self.live.insert(name.clone());
                }
                identify(self.session.clone(), name, tx.clone(), Duration::ZERO);
            }
            SampleKind::Delete => {
                self.live.remove(&name);
                let now = self.now_ms();
                self.core.agent_down(now, &name);
            }
        }
    }

    pub(crate) fn on_identity(&mut self, ev: Identity, tx: &mpsc::UnboundedSender<Identity>) {
        let now = self.now_ms();
        match ev {
            Identity::One(mut info) => {
                // Its pending reports are not part of who it is: they go in as reports, after it is up.
                let pending = std::mem::take(&mut info.pending);
                let name = info.name.clone();
                self.core.agent_up(now, info);
                self.take_pending(&name, pending);
            }
            Identity::Pending(name, pending) => {
                self.asking.remove(&name);
                self.take_pending(&name, pending);
            }
            Identity::Several(name, n) => {
                self.core.agent_conflict(now, &name, n);
                // Asked again until one process answers alone (or none does).
                if self.live.contains(&name) {
                    identify(self.session.clone(), name, tx.clone(), CONFLICT_RECHECK);
                }
            }
            Identity::Unknown(name, why) => {
                // Its liveliness token is there, so it is asked again (a link that comes back, a process that was
                // stopped): as long as it is not known, nothing is dispatched to it.
                if self.live.contains(&name) {
                    eprintln!("warning: agent `{name}` is live but did not say who it is: {why}; asking again");
                    identify(self.session.clone(), name, tx.clone(), CONFLICT_RECHECK);
                }
            }
        }
    }

    /// Reports an agent listed in its answer, taken as reports from it (duplicates of what arrived are answered
    /// and dropped, as any duplicate is).
    fn take_pending(&mut self, agent: &str, pending: Vec<baton_proto::cluster::wire::Report>) {
        let now = self.now_ms();
        for report in pending {
            if let Err(e) = self.core.report(now, agent, &wire::encode(&report)) {
                self.decode_drops += 1;
                eprintln!("warning: dropped a report `{agent}` listed: {e}");
            }
        }
        self.out.values(now, self.core.core());
    }

    /// Asks process `incarnation` of `agent` for the reports it has not had acknowledged; the answer comes back to
    /// the main loop as `Identity::Pending`.
    fn ask(&mut self, agent: String, incarnation: uuid::Uuid) {
        let Some(tx) = self.answers.clone() else { return };
        if !self.asking.insert(agent.clone()) {
            return;
        }
        let session = self.session.clone();
        tokio::spawn(async move {
            let pending = match ask_info_once(&session, &agent).await {
                Ok(infos) => infos
                    .into_iter()
                    .find(|i| i.name == agent && i.incarnation == incarnation)
                    .map(|i| i.pending)
                    .unwrap_or_default(),
                Err(_) => Vec::new(),
            };
            let _ = tx.send(Identity::Pending(agent, pending));
        });
    }

    /// `baton set` of the sender `q`'s key names: applied and recorded, or refused.
    pub(crate) fn on_set(&mut self, q: &Query, sender: &str) -> SetReply {
        let chart = self.core.core().program().name.clone();
        let request: Result<SetRequest, _> = match q.payload() {
            Some(p) => wire::decode(&p.to_bytes()),
            None => return SetReply { chart, ok: false, message: "the request carries no value".into() },
        };
        let now = self.now_ms();
        match request {
            Ok(r) => match self.core.set_by(now, SetRequest { by: keys::by_whom(sender, r.user.as_deref()), ..r }) {
                Ok(message) => SetReply { chart, ok: true, message },
                Err(message) => SetReply { chart, ok: false, message },
            },
            Err(e) => SetReply { chart, ok: false, message: format!("malformed request: {e}") },
        }
    }

    /// Answers a `set` or `ctl` request: at once without a journal; with one, once the batch its request went into
    /// is durable (`held_replies`).
    pub(crate) fn answer(&mut self, q: Query, key: String, answer: Vec<u8>) {
        if self.journal.is_some() {
            self.held_replies.push_back((None, q, key, answer));
        } else {
            reply(&q, key, answer);
        }
    }

    /// Whether as many answers wait for the journal as are held: a request now is refused untaken.
    pub(crate) fn replies_full(&self) -> bool {
        self.held_replies.len() >= baton_proto::limits::HELD_REPLIES_MAX
    }

    pub(crate) fn busy(&self) -> String {
        format!(
            "not taken: {} answers already wait for the journal to be written; ask again in a moment",
            self.held_replies.len()
        )
    }

    pub(crate) fn set_refused(&self, message: String) -> SetReply {
        SetReply { chart: self.core.core().program().name.clone(), ok: false, message }
    }

    /// `baton ctl`: a command of the operator `q`'s key names, recorded and applied (or refused, which is
    /// recorded too: the trace says so). Who sent it is the key's name, which the router's access control
    /// checked, whatever the request says.
    pub(crate) fn on_ctl(&mut self, q: &Query, sender: &str) -> CtlReply {
        let request: Result<CtlRequest, String> = match q.payload() {
            Some(p) => wire::decode(&p.to_bytes()).map_err(|e| format!("malformed request: {e}")),
            None => Err("the request carries no command".into()),
        };
        let result = match request {
            Ok(r) => self.command(CtlRequest { by: keys::by_whom(sender, r.user.as_deref()), ..r }),
            Err(why) => Err(why),
        };
        self.ctl_reply(result)
    }

    /// An operator's command from this process (an interrupt is a `stop`, a second one an `abort`).
    pub(crate) fn command(&mut self, request: CtlRequest) -> Result<String, String> {
        let now = self.now_ms();
        self.core.command(now, request)
    }

    pub(crate) fn ctl_reply(&self, result: Result<String, String>) -> CtlReply {
        let core = self.core.core();
        let (ok, message) = match result {
            Ok(m) => (true, m),
            Err(m) => (false, m),
        };
        let state = core.run_state();
        CtlReply { chart: core.program().name.clone(), ok, message, state, available: state.available() }
    }

    /// The grid time of the next cycle, if the coordinator needs one.
    pub(crate) fn next_cycle(&self) -> Option<u64> {
        self.core.core().next_cycle_ms(self.last_cycle_ms)
    }

    pub(crate) fn instant_of(&self, t_ms: u64) -> Instant {
        self.started + Duration::from_millis(t_ms.saturating_sub(self.base_ms))
    }

    /// Runs the cycles that are due, each at its grid time (one that fell far behind skips to the present), and
    /// has what they asked for carried out — at once, or once its journal batch is durable.
    pub(crate) fn due_cycles(&mut self) -> anyhow::Result<()> {
        let now = self.now_ms();
        while let Some(due) = self.next_cycle().filter(|&t| t <= now) {
            let at = if now - due > CATCH_UP_CYCLES_MAX * self.cycle_ms { now - now % self.cycle_ms } else { due };
            self.last_cycle_ms = Some(at);
            self.core.cycle(at);
            self.commit(Vec::new())?;
        }
        Ok(())
    }

    pub(crate) fn commit(&mut self, mut outputs: Vec<CoordOutput>) -> anyhow::Result<()> {
        while let Some(out) = self.core.poll_output() {
            outputs.push(out);
        }
        let records = self.core.take_records();
        // The recording's values after every input, as a replay of the journal sees them.
        let now = self.core.core().now_ms();
        self.out.values(now, self.core.core());
        let Some(journal) = &mut self.journal else {
            return self.carry_out(outputs);
        };
        // Messages go with the batch: the writer sends them once it is durable. The rest waits here for it.
        let (mut messages, mut local) = (Vec::new(), Vec::new());
        for out in outputs {
            match message(&self.vars_key, &mut self.cmd_keys, self.term, &out) {
                Some(m) => messages.push(m),
                None => local.push(out),
            }
        }
        let batch = if records.is_empty() {
            // Nothing new to record: these follow the last batch.
            journal.send_after(messages)?;
            journal.sent()
        } else {
            journal.write(records, messages)?
        };
        // Answers to requests taken since the last commit: the batch just written holds what they did.
        for (waits, ..) in self.held_replies.iter_mut().rev().take_while(|(waits, ..)| waits.is_none()) {
            *waits = Some(batch);
        }
        if !local.is_empty() {
            self.held.push_back((batch, local));
        }
        if self.snapshot_every > 0 && self.core.records_counted() >= self.snapshot_due {
            self.snapshot()?;
        }
        self.release()
    }

    /// Hands the journal a snapshot of the coordinator after every record so far (with the summary's step times,
    /// which the trace before it would otherwise have to give): it starts the next segment.
    fn snapshot(&mut self) -> anyhow::Result<()> {
        let steps = serde_json::to_value(&self.out.steps)?;
        let (Some(journal), Some(bytes)) = (self.journal.as_mut(), self.core.snapshot(steps)) else {
            return Ok(());
        };
        // A cycle that changed nothing, recorded so that the snapshot follows the last record: it led to nothing.
        let quiet = self.core.take_records();
        if !quiet.is_empty() {
            journal.write(quiet, Vec::new())?;
        }
        journal.snapshot(bytes)?;
        self.snapshot_due = self.core.records_counted() + self.snapshot_every;
        Ok(())
    }

    /// Carries out what waited for journal batches that are now durable, in order.
    pub(crate) fn release(&mut self) -> anyhow::Result<()> {
        let durable = match &self.journal {
            Some(j) => j.durable()?,
            None => u64::MAX,
        };
        while self.held.front().is_some_and(|(batch, _)| *batch <= durable) {
            let Some((_, outputs)) = self.held.pop_front() else { break };
            self.carry_out(outputs)?;
        }
        while self.held_replies.front().is_some_and(|(batch, _, _, _)| batch.is_some_and(|b| b <= durable)) {
            let Some((_, q, key, answer)) = self.held_replies.pop_front() else { break };
            reply(&q, key, answer);
        }
        Ok(())
    }

    /// Carries out what the coordinator asked for: messages first, then what stays in this process.
    pub(crate) fn carry_out(&mut self, outputs: Vec<CoordOutput>) -> anyhow::Result<()> {
        // Messages leave before the trace is written: a token's round trip does not wait for the disk.
        let mut local = Vec::new();
        for out in outputs {
            match (message(&self.vars_key, &mut self.cmd_keys, self.term, &out), out) {
                (Some(Outgoing { key, payload }), _) => self.send(key, payload)?,
                (None, CoordOutput::Ask { agent, incarnation }) => self.ask(agent, incarnation),
                (None, other) => local.push(other),
            }
        }
        for out in local {
            match out {
                CoordOutput::Send { .. } | CoordOutput::Vars(_) | CoordOutput::Ask { .. } => {}
                CoordOutput::Trace(rec) => self.out.record(rec),
                CoordOutput::Log { level, message } => {
                    let tag = match level {
                        Level::Info => "info",
                        Level::Warn => "warning",
                        Level::Error => "error",
                    };
                    if level > Level::Info || !self.quiet {
                        eprintln!("{tag}: {message}");
                    }
                }
            }
        }
        Ok(())
    }

    /// Publishes through the outbox, where the coordinator decided it (without a journal; with one, the journal's
    /// writer sends, `deliver_through`), the outcome weighed by `weigh`.
    pub(crate) fn send(&mut self, key: String, payload: Vec<u8>) -> anyhow::Result<()> {
        weigh(self.outbox.put(&key, payload)).map_err(|why| anyhow!(why))
    }

    /// Whether the main loop must look again after a callback: it failed, the run ended or asks to start again,
    /// or it needs a cycle earlier than the loop sleeps until.
    fn must_look(&self) -> bool {
        let core = self.core.core();
        self.failed.is_some()
            || core.is_over()
            || core.wants_new_run()
            || baton_host::earlier(self.next_cycle().map(|t| self.instant_of(t)), self.armed)
    }

    pub(crate) fn summary(&self, loaded: &Loaded) -> Summary {
        let now = self.now_ms();
        let stats = self.core.core().stats();
        let steps = self
            .out
            .steps
            .iter()
            .map(|(name, (t, since))| {
                let mut t = *t;
                if let Some(t0) = since {
                    t.active_ms += now.saturating_sub(*t0);
                }
                (name.clone(), t)
            })
            .collect();
        let vars = loaded
            .program
            .vars
            .iter()
            .enumerate()
            .filter(|(_, v)| !v.constant && !v.hidden)
            .map(|(i, v)| {
                (v.name.clone(), self.core.core().value(baton_proto::exec::program::VarId(i as u32)).to_string())
            })
            .collect();
        Summary {
            chart: loaded.pou.clone(),
            run: self.core.core().run().key(),
            state: self.core.core().run_state().name().to_string(),
            duration_ms: now,
            tokens_dispatched: stats.dispatched,
            tokens_returned: stats.returned,
            messages_dropped: stats.dropped + self.decode_drops,
            left: false,
            deposed: false,
            steps,
            vars,
            journal: self.journal.as_ref().map(crate::journal::Writer::stats),
        }
    }
}

/// After `delay`, asks agent `name` who it is and tells the main loop: one process (`AgentUp`), several
/// (`AgentConflict`), or none that makes sense.
pub(crate) fn identify(session: Session, name: String, tx: mpsc::UnboundedSender<Identity>, delay: Duration) {
    tokio::spawn(async move {
        tokio::time::sleep(delay).await;
        let ev = match ask_info(&session, &name).await {
            Ok(mut infos) if infos.len() == 1 => match infos.pop() {
                Some(info) if info.name == name => match announced_roles(&session, info).await {
                    Ok(info) => Identity::One(info),
                    Err(why) => Identity::Unknown(name, why),
                },
                Some(info) => Identity::Unknown(name, format!("it calls itself `{}`", info.name)),
                None => Identity::Unknown(name, "no answer".to_string()),
            },
            Ok(infos) => Identity::Several(name, infos.len() as u32),
            Err(why) => Identity::Unknown(name, why),
        };
        let _ = tx.send(ev);
    });
}

/// The agent as the router vouches for it: only the roles it claims whose liveliness token the router has
/// (`keys::alive_role`), which the router's access control lets an identity announce only for the roles its
/// deployment gives it. A role claimed without its token is not taken, and said so.
async fn announced_roles(session: &Session, mut info: AgentInfo) -> Result<AgentInfo, String> {
    if info.roles.is_empty() {
        return Ok(info);
    }
    let replies = traffic::liveliness_get(session, keys::alive_roles(&info.name))
        .timeout(INFO_QUERY_TIMEOUT)
        .await
        .map_err(|e| format!("cannot ask the router for its roles: {e}"))?;
    let mut announced = std::collections::BTreeSet::new();
    while let Ok(reply) = replies.recv_async().await {
        if let Some(role) = reply.result().ok().and_then(|s| keys::role_of_alive(s.key_expr().as_str(), &info.name)) {
            announced.insert(role.to_string());
        }
    }
    let (kept, claimed): (Vec<String>, Vec<String>) = info.roles.into_iter().partition(|r| announced.contains(r));
    if !claimed.is_empty() {
        eprintln!(
            "warning: agent `{}` claims role(s) {} that the router did not let it announce: not taken",
            info.name,
            claimed.join(", ")
        );
    }
    info.roles = kept;
    Ok(info)
}

/// Asks a live agent who it is, a few times: its answer may trail its liveliness token through a router. Every
/// process answering to the name replies; they are told apart by their incarnation.
pub(crate) async fn ask_info(session: &Session, name: &str) -> Result<Vec<AgentInfo>, String> {
    let mut last = String::new();
    for attempt in 0..INFO_QUERY_ATTEMPTS {
        match ask_info_once(session, name).await {
            Ok(infos) if !infos.is_empty() => return Ok(infos),
            Ok(_) => last = "no answer to the info query".to_string(),
            Err(why) => last = why,
        }
        tokio::time::sleep(Duration::from_millis(100 << attempt)).await;
    }
    Err(last)
}

pub(crate) async fn ask_info_once(session: &Session, name: &str) -> Result<Vec<AgentInfo>, String> {
    let replies = traffic::get(session, keys::agent_info(name))
        // Every reply, not one per key: two processes of one name answer on the same key.
        .consolidation(zenoh::query::ConsolidationMode::None)
        .timeout(INFO_QUERY_TIMEOUT)
        .await
        .map_err(|e| e.to_string())?;
    let mut infos: Vec<AgentInfo> = Vec::new();
    let mut last = String::new();
    while let Ok(reply) = replies.recv_async().await {
        let info = match reply.result() {
            Ok(sample) => wire::decode::<AgentInfo>(&sample.payload().to_bytes()).map_err(|e| e.to_string()),
            Err(e) => Err(format!("{e:?}")),
        };
        match info {
            Ok(info) if !infos.iter().any(|i| i.incarnation == info.incarnation) => infos.push(info),
            Ok(_) => {}
            Err(why) => last = why,
        }
        if infos.len() >= INFO_REPLIES_MAX {
            break;
        }
    }
    if infos.is_empty() && !last.is_empty() {
        return Err(last);
    }
    Ok(infos)
}
