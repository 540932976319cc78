//! The journal's writer thread: group commit of the host's batches, the messages each batch led to sent the moment
//! it is durable, and the snapshots that start new segments; and `Writer`, the host's side of it.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{mpsc as std_mpsc, Arc, Mutex};
use std::time::Instant;

use anyhow::anyhow;
use tokio::sync::watch;

use super::etcd::Fenced;
use super::place::Store;

impl Store {
    /// Starts the writer thread; batches are numbered from 1 in the order given. `deliver` sends the messages
    /// handed with a batch once it is durable (none are handed without it).
    pub fn start_writer(self, deliver: Option<Deliver>) -> Writer {
        let (tx, rx) = std_mpsc::channel::<Job>();
        let (done_tx, done_rx) = watch::channel(Durable::Upto(0));
        let stats = Arc::new(Counters::default());
        let counters = Arc::clone(&stats);
        let hook: Arc<Mutex<Option<OnDurable>>> = Arc::default();
        let told = Arc::clone(&hook);
        let thread = std::thread::Builder::new()
            .name("baton-journal".into())
            .spawn(move || {
                // Called outside the hook's lock, so that `close` never waits for a call under way.
                let tell = || {
                    let f = told.lock().ok().and_then(|hook| hook.clone());
                    if let Some(f) = f {
                        f();
                    }
                };
                writer_loop(self, rx, &done_tx, &counters, deliver, &tell);
                // Whatever ended the writer (a failure, or the host's closing it), the host is told.
                tell();
            })
            .expect("start the journal writer thread");
        Writer { tx: Some(tx), durable: done_rx, sent: 0, thread: Some(thread), stats, hook }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub enum Durable {
    /// Every batch up to this number is durable.
    Upto(u64),
    /// The journal cannot be written: the run must stop (acting without the journal would break its promise).
    Failed(String),
    /// Every batch up to this number is durable, and no more will be: etcd refused a write because another
    /// coordinator holds the election (why).
    Fenced(u64, String),
}

/// What the writer did, for the run's summary.
#[derive(Default)]
struct Counters {
    commits: AtomicU64,
    records: AtomicU64,
    snapshots: AtomicU64,
    commit_ns: AtomicU64,
    /// Batches whose messages were sent, and how long they waited in all.
    held: AtomicU64,
    held_ns: AtomicU64,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct JournalStats {
    pub records: u64,
    pub commits: u64,
    /// Snapshots written, each starting a segment.
    pub snapshots: u64,
    /// What a commit (its write and `fdatasync`) took on average, in µs: what a round trip waits for at least.
    pub commit_us: f64,
    /// From the host's handing a batch to the writer to the writer's having sent what the batch led to, on
    /// average, in µs: the wait for the commit under way when the batch came, its own commit, the messages of the
    /// batches before it in that commit, and the wake-up.
    pub held_us: f64,
}

/// A message the coordinator asked to send: it leaves once the batch that led to it is durable.
pub struct Outgoing {
    pub key: String,
    pub payload: Vec<u8>,
}

/// Sends messages, in order, from the writer thread; an error (a key that cannot be declared) stops the journal,
/// and with it the run.
pub type Deliver = Box<dyn FnMut(Vec<Outgoing>) -> Result<(), String> + Send>;

/// Called on the writer thread when more batches are durable, and when the writer fails: the host releases what
/// they held (`Writer::on_durable`).
pub type OnDurable = Arc<dyn Fn() + Send + Sync>;

/// What the host hands the writer.
enum Job {
    /// Records, and the messages they led to, handed at that instant.
    Batch(Vec<Vec<u8>>, Vec<Outgoing>, Instant),
    /// Messages that follow the batches handed before them (nothing new to record led to them).
    Messages(Vec<Outgoing>, Instant),
    /// A snapshot of the coordinator after every batch handed before it.
    Snapshot(Vec<u8>),
}

fn writer_loop(
    mut store: Store,
    rx: std_mpsc::Receiver<Job>,
    done: &watch::Sender<Durable>,
    counters: &Counters,
    mut deliver: Option<Deliver>,
    tell: &dyn Fn(),
) {
    let mut committed = 0u64;
    let mut buffer = Vec::new();
    let mut batches = Vec::new();
    // The messages of each batch that led to some, and when the batch was handed.
    let mut waiting: Vec<(Instant, Vec<Outgoing>)> = Vec::new();
    let fail = |why: String| {
        let _ = done.send(Durable::Failed(why));
    };
    while let Ok(first) = rx.recv() {
        // Group commit: everything that queued up while the last transaction was committing goes in this one,
        // up to a snapshot, which starts the next segment after the batches before it.
        let mut jobs = vec![first];
        while let Ok(more) = rx.try_recv() {
            jobs.push(more);
        }
        for job in jobs.into_iter().map(Some).chain([None]) {
            let segment = match job {
                Some(Job::Batch(b, m, at)) => {
                    batches.push(b);
                    if !m.is_empty() {
                        waiting.push((at, m));
                    }
                    continue;
                }
                Some(Job::Messages(m, at)) => {
                    waiting.push((at, m));
                    if !batches.is_empty() {
                        continue;
                    }
                    // What came before is durable already.
                    None
                }
                Some(Job::Snapshot(snapshot)) => Some(snapshot),
                None => None,
            };
            if !batches.is_empty() {
                let started = Instant::now();
                if let Err(e) = store.append(&batches, &mut buffer) {
                    if e.is::<Fenced>() {
                        // Deposed: nothing of it is durable, nor sent; the host stops acting (`Fence::lose`).
                        let _ = done.send(Durable::Fenced(committed, e.to_string()));
                        return ignore_the_rest(&rx);
                    }
                    return fail(format!("cannot write the journal {}: {e}", store.shown()));
                }
                committed += batches.len() as u64;
                counters.commits.fetch_add(1, Ordering::Relaxed);
                counters.commit_ns.fetch_add(started.elapsed().as_nanos() as u64, Ordering::Relaxed);
                counters.records.fetch_add(batches.iter().map(|b| b.len() as u64).sum(), Ordering::Relaxed);
                batches.clear();
            }
            // Sent from this thread: a hand-over to another cost more than it saved (`docs/book/src/benchmarks.md`).
            for (at, messages) in waiting.drain(..) {
                if let Some(send) = deliver.as_mut() {
                    if let Err(why) = send(messages) {
                        return fail(why);
                    }
                }
                counters.held.fetch_add(1, Ordering::Relaxed);
                counters.held_ns.fetch_add(at.elapsed().as_nanos() as u64, Ordering::Relaxed);
            }
            // The host is told only when more is durable.
            let more = done.send_if_modified(|d| {
                let was = std::mem::replace(d, Durable::Upto(committed));
                was != *d
            });
            if more {
                tell();
            }
            if let Some(snapshot) = segment {
                match store.start_segment(&snapshot) {
                    Ok(()) => {
                        counters.snapshots.fetch_add(1, Ordering::Relaxed);
                    }
                    // The records stay durable in the segment they were in; the next snapshot tries again.
                    Err(e) if e.is::<Fenced>() => {
                        let _ = done.send(Durable::Fenced(committed, e.to_string()));
                        return ignore_the_rest(&rx);
                    }
                    Err(e) => eprintln!(
                        "warning: cannot start the journal's next segment after {}: {e}; it goes on there",
                        store.shown()
                    ),
                }
            }
        }
        store.allocate_ahead();
    }
    store.trim();
}

/// A deposed writer's end: what the host hands it is dropped, never durable, until the host closes it.
fn ignore_the_rest(rx: &std_mpsc::Receiver<Job>) {
    while rx.recv().is_ok() {}
}

/// The host's side of the writer thread.
pub struct Writer {
    tx: Option<std_mpsc::Sender<Job>>,
    durable: watch::Receiver<Durable>,
    sent: u64,
    thread: Option<std::thread::JoinHandle<()>>,
    stats: Arc<Counters>,
    hook: Arc<Mutex<Option<OnDurable>>>,
}

impl Writer {
    /// Queues a batch, and the messages it led to; returns its number.
    pub fn write(&mut self, records: Vec<Vec<u8>>, messages: Vec<Outgoing>) -> anyhow::Result<u64> {
        self.send(Job::Batch(records, messages, Instant::now()))?;
        self.sent += 1;
        Ok(self.sent)
    }

    /// Queues messages to send once every batch queued so far is durable.
    pub fn send_after(&mut self, messages: Vec<Outgoing>) -> anyhow::Result<()> {
        if messages.is_empty() {
            return Ok(());
        }
        self.send(Job::Messages(messages, Instant::now()))
    }

    /// Queues a snapshot of the coordinator after every batch queued so far: it starts the next segment.
    pub fn snapshot(&mut self, snapshot: Vec<u8>) -> anyhow::Result<()> {
        self.send(Job::Snapshot(snapshot))
    }

    fn send(&mut self, job: Job) -> anyhow::Result<()> {
        let tx = self.tx.as_ref().ok_or_else(|| anyhow!("the journal is closed"))?;
        if tx.send(job).is_err() {
            return Err(anyhow!("{}", self.failure().unwrap_or_else(|| "the journal writer stopped".into())));
        }
        Ok(())
    }

    /// Calls `f` on the writer thread each time more batches are durable, and when the writer fails or stops:
    /// the host releases what they held there, with no wake-up of its main loop per commit.
    pub fn on_durable(&self, f: OnDurable) {
        if let Ok(mut hook) = self.hook.lock() {
            *hook = Some(f);
        }
    }

    /// Records written, transactions committed and snapshots written so far.
    pub fn stats(&self) -> JournalStats {
        JournalStats {
            records: self.stats.records.load(Ordering::Relaxed),
            commits: self.stats.commits.load(Ordering::Relaxed),
            snapshots: self.stats.snapshots.load(Ordering::Relaxed),
            commit_us: self.stats.commit_ns.load(Ordering::Relaxed) as f64
                / 1e3
                / self.stats.commits.load(Ordering::Relaxed).max(1) as f64,
            held_us: self.stats.held_ns.load(Ordering::Relaxed) as f64
                / 1e3
                / self.stats.held.load(Ordering::Relaxed).max(1) as f64,
        }
    }

    pub fn sent(&self) -> u64 {
        self.sent
    }

    fn failure(&self) -> Option<String> {
        match &*self.durable.borrow() {
            Durable::Failed(why) => Some(why.clone()),
            Durable::Upto(_) | Durable::Fenced(..) => None,
        }
    }

    /// The number of the last durable batch.
    pub fn durable(&self) -> anyhow::Result<u64> {
        match &*self.durable.borrow() {
            Durable::Upto(n) | Durable::Fenced(n, _) => Ok(*n),
            Durable::Failed(why) => Err(anyhow!("{why}")),
        }
    }

    /// Waits until the writer makes progress (or fails).
    pub async fn changed(&mut self) -> anyhow::Result<u64> {
        if self.durable.changed().await.is_err() {
            return Err(anyhow!("{}", self.failure().unwrap_or_else(|| "the journal writer stopped".into())));
        }
        self.durable()
    }

    /// Waits until every batch written so far is durable. A deposed writer's (`Fenced`) never will be.
    pub async fn sync(&mut self) -> anyhow::Result<()> {
        while self.durable()? < self.sent {
            if let Durable::Fenced(_, why) = &*self.durable.borrow() {
                return Err(Fenced(why.clone()).into());
            }
            self.changed().await?;
        }
        Ok(())
    }

    /// Stops the writer after what was written so far.
    pub fn close(&mut self) {
        self.tx = None;
        if let Ok(mut hook) = self.hook.lock() {
            *hook = None;
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for Writer {
    fn drop(&mut self) {
        self.close();
    }
}
