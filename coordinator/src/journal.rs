//! `baton run --journal DIR`: the coordinator's records (`baton_proto::dist::journal`) appended to segment files by
//! a thread of their own with group commit, and the coordinator's snapshots that begin each segment after the first.
//!
//! The shell hands each batch of records to the writer with the messages the coordinator asked to send (its
//! dispatches, its variable updates) and holds back the rest of what it asked for. The writer sends the messages
//! itself the moment the batch is durable (written and `fdatasync`'d), then says so, and the shell carries out
//! the rest: a round trip waits for the commit, not for the main loop's turn as well. While one commit is on its
//! way to the disk, the batches that arrive meanwhile wait and go together in the next one, so a slow disk makes
//! batches larger, not the chart slower: durability costs latency (one commit), not throughput.
//!
//! A segment file: `MAGIC`, then frames — payload length (u32, little-endian), CRC-32 of the kind and payload
//! (u32), the kind (0 the run's header, JSON; 1 a record; 2 a snapshot), the payload. The first segment is
//! `journal.log`: the header, then records. Every `snapshot_every` records the shell hands the writer a snapshot
//! of the coordinator (`Journaled::snapshot`); the writer starts segment `journal-NNNNNN.log` with the header and
//! the snapshot (written apart, `fdatasync`'d, then renamed into place, so a segment is never seen without its
//! snapshot), the records after it go there, and the segments beyond `keep` are deleted: the journal is
//! compacted behind its snapshots. A resume reads only the last segment: the snapshot, then its records.
//!
//! A crash while a commit was being written leaves a torn last frame, which nobody was told was durable: opening
//! the journal cuts it off. A bad frame with good ones after it is damage, and the journal is refused. (An
//! append-only file replaced redb here: a commit is one write and one `fdatasync` instead of a B-tree's pages,
//! `docs/benchmarks.md`.)

use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc as std_mpsc;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{anyhow, bail, Context};
use baton_proto::dist::journal::{JournalHeader, JOURNAL_FORMAT};
use tokio::sync::watch;

/// The first segment of a journal, which holds the run from its start.
pub const FILE_NAME: &str = "journal.log";
/// Held (locked) while a coordinator uses the journal.
const LOCK_NAME: &str = "journal.lock";
/// Where journals of Baton before the append-only file were kept.
const OLD_FILE_NAME: &str = "journal.redb";
const MAGIC: &[u8; 16] = b"BATON-JOURNAL-1\n";
const FRAME_HEAD: usize = 9;
const KIND_HEADER: u8 = 0;
const KIND_RECORD: u8 = 1;
const KIND_SNAPSHOT: u8 = 2;
/// How much a segment's file is allocated ahead of its records at a time (about a thousand commits; zeroing it
/// takes the writer 1–3 ms on this project's disks).
const ALLOCATE_BYTES: u64 = 4 << 20;
/// A frame larger than this is damage, not a record or a snapshot.
const FRAME_BYTES_MAX: usize = 1 << 30;

/// Segment `n`'s file name: `journal.log` for the first, `journal-NNNNNN.log` after it.
fn segment_name(n: u64) -> String {
    if n == 0 {
        FILE_NAME.to_string()
    } else {
        format!("journal-{n:06}.log")
    }
}

fn segment_number(name: &str) -> Option<u64> {
    if name == FILE_NAME {
        return Some(0);
    }
    let digits = name.strip_prefix("journal-")?.strip_suffix(".log")?;
    digits.bytes().all(|b| b.is_ascii_digit()).then(|| digits.parse().ok()).flatten().filter(|n| *n > 0)
}

/// When the coordinator snapshots itself, and how much of the journal is kept (`baton run --snapshot-every`,
/// `--journal-keep`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Settings {
    /// A snapshot after this many records since the last (0: never).
    pub snapshot_every: u64,
    pub keep: Keep,
}

/// A snapshot every 50 000 records: a resume replays at most that many (a quarter of a second at the 200 000
/// records a second `baton bench` measures), and a snapshot costs the coordinator a few milliseconds at most
/// that often.
pub const SNAPSHOT_EVERY: u64 = 50_000;

/// The last segment and the one before it: the run from the last snapshot but one.
pub const KEEP: Keep = Keep::Last(2);

impl Default for Settings {
    fn default() -> Settings {
        Settings { snapshot_every: SNAPSHOT_EVERY, keep: KEEP }
    }
}

/// How many segments a journal keeps: all of them (a replay rebuilds the whole run), or the last `n` (a replay
/// rebuilds the run from the oldest kept snapshot on).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Keep {
    All,
    Last(u32),
}

impl std::str::FromStr for Keep {
    type Err = String;
    fn from_str(s: &str) -> Result<Keep, String> {
        match s {
            "all" => Ok(Keep::All),
            n => match n.parse::<u32>() {
                Ok(n) if n >= 1 => Ok(Keep::Last(n)),
                _ => Err(format!("`{s}` is neither `all` nor a number of segments of at least 1")),
            },
        }
    }
}

/// An opened journal: a fresh one, or the header, the latest snapshot and the records after it of a run to resume.
pub struct Opened {
    pub store: Store,
    /// `None` for a journal without a run yet.
    pub header: Option<JournalHeader>,
    /// The snapshot that begins the last segment (none in the first segment).
    pub snapshot: Option<Vec<u8>>,
    pub records: Vec<Vec<u8>>,
}

/// One segment, read whole (`Store::segments`).
pub struct Segment {
    pub number: u64,
    pub snapshot: Option<Vec<u8>>,
    pub records: Vec<Vec<u8>>,
}

pub struct Store {
    dir: PathBuf,
    /// The last segment, which records are appended to, and its number.
    file: File,
    path: PathBuf,
    number: u64,
    /// Where its records end, and how far it is allocated (`allocate`).
    end: u64,
    allocated: u64,
    /// The header's frame, which begins every segment.
    header_frame: Vec<u8>,
    keep: Keep,
    _lock: File,
}

/// Opens (or creates) the journal in `dir`. Another process using it is refused.
pub fn open(dir: &Path) -> anyhow::Result<Opened> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create the journal folder {}", dir.display()))?;
    let numbers = segment_numbers(dir)?;
    if numbers.is_empty() && dir.join(OLD_FILE_NAME).exists() {
        bail!(
            "{} holds a journal of an earlier Baton ({OLD_FILE_NAME}); this one keeps journals in {FILE_NAME}: \
             resume or replay it with the Baton that wrote it",
            dir.display()
        );
    }
    let lock = OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(dir.join(LOCK_NAME))
        .with_context(|| format!("cannot open the journal's lock {}", dir.join(LOCK_NAME).display()))?;
    let shown = dir.join(numbers.last().map_or(FILE_NAME.to_string(), |n| segment_name(*n)));
    match lock.try_lock() {
        Ok(()) => {}
        Err(std::fs::TryLockError::WouldBlock) => {
            bail!("the journal {} is in use by another coordinator", shown.display())
        }
        Err(std::fs::TryLockError::Error(e)) => bail!("cannot lock the journal {}: {e}", shown.display()),
    }
    // A segment that was being started when the process died: it was never renamed into place, nothing in it
    // was acknowledged.
    for entry in std::fs::read_dir(dir)?.flatten() {
        if entry.file_name().to_str().is_some_and(|n| n.starts_with("journal-") && n.ends_with(".log.new")) {
            let _ = std::fs::remove_file(entry.path());
        }
    }
    let number = numbers.last().copied().unwrap_or(0);
    let path = dir.join(segment_name(number));
    let mut file = OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .with_context(|| format!("cannot open the journal {}", path.display()))?;
    let mut bytes = Vec::new();
    file.read_to_end(&mut bytes).with_context(|| format!("cannot read the journal {}", path.display()))?;
    let read = read(&bytes).with_context(|| format!("cannot read the journal {}", path.display()))?;
    if number > 0 && read.snapshot.is_none() {
        bail!("cannot read the journal {}: it does not begin with its snapshot", path.display());
    }
    let end = if bytes.is_empty() {
        file.write_all(MAGIC)?;
        file.sync_data()?;
        MAGIC.len()
    } else {
        if read.good < bytes.len() {
            // The torn frame of a commit that never finished (nothing in it was acknowledged), or space allocated
            // ahead: cut off.
            file.set_len(read.good as u64)?;
            file.sync_data()?;
        }
        read.good
    } as u64;
    let mut header_frame = Vec::new();
    if let Some(h) = &read.header {
        frame(&mut header_frame, KIND_HEADER, &serde_json::to_vec(h)?);
    }
    let store = Store {
        dir: dir.to_path_buf(),
        file,
        path,
        number,
        end,
        allocated: end,
        header_frame,
        keep: Keep::All,
        _lock: lock,
    };
    Ok(Opened { store, header: read.header, snapshot: read.snapshot, records: read.records })
}

/// Whether `dir` holds a journal (one segment at least).
pub fn exists(dir: &Path) -> bool {
    segment_numbers(dir).is_ok_and(|n| !n.is_empty())
}

/// The numbers of the segments in `dir`, in order.
fn segment_numbers(dir: &Path) -> anyhow::Result<Vec<u64>> {
    let mut numbers = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("cannot read the journal folder {}", dir.display()))? {
        if let Some(n) = entry?.file_name().to_str().and_then(segment_number) {
            numbers.push(n);
        }
    }
    numbers.sort_unstable();
    Ok(numbers)
}

/// A segment file's contents, and how many of its bytes are whole frames.
struct Contents {
    header: Option<JournalHeader>,
    snapshot: Option<Vec<u8>>,
    records: Vec<Vec<u8>>,
    good: usize,
    /// It ends in a frame a crash cut short (not merely in allocated space).
    torn: bool,
}

fn read(bytes: &[u8]) -> anyhow::Result<Contents> {
    let mut out = Contents { header: None, snapshot: None, records: Vec::new(), good: 0, torn: false };
    if bytes.is_empty() {
        return Ok(out);
    }
    if !bytes.starts_with(MAGIC) {
        bail!("it is not a Baton journal (it does not start with {:?})", String::from_utf8_lossy(MAGIC).trim());
    }
    let mut at = MAGIC.len();
    while at < bytes.len() {
        let frame = Frame::at(&bytes[at..]);
        // Space allocated ahead of the records (`Store::allocate`) reads as zeros: the records end there.
        let rest_zero = |from: usize| bytes.get(from..).is_none_or(|rest| rest.iter().all(|b| *b == 0));
        let (kind, payload, len) = match frame {
            Frame::Whole { kind, payload } => (kind, payload, FRAME_HEAD + payload.len()),
            _ if rest_zero(at) => break,
            // Only the last frame may be torn (what follows it, if anything, is allocated space).
            Frame::Torn => {
                out.torn = true;
                break;
            }
            Frame::Bad { len } if rest_zero(at.saturating_add(len)) => {
                out.torn = true;
                break;
            }
            Frame::Bad { .. } => bail!("its frame at byte {at} is damaged (record {} and later)", out.records.len()),
        };
        let first = out.snapshot.is_none() && out.records.is_empty();
        match kind {
            KIND_HEADER if out.header.is_none() && first => {
                out.header = Some(
                    serde_json::from_slice::<JournalHeader>(payload)
                        .map_err(|e| anyhow!("its header is malformed: {e}"))?,
                );
            }
            KIND_SNAPSHOT if out.header.is_some() && first => out.snapshot = Some(payload.to_vec()),
            KIND_RECORD if out.header.is_some() => out.records.push(payload.to_vec()),
            _ => bail!("its frame at byte {at} (kind {kind}) is out of place"),
        }
        at += len;
    }
    out.good = at.min(bytes.len());
    Ok(out)
}

enum Frame<'a> {
    Whole {
        kind: u8,
        payload: &'a [u8],
    },
    /// Its length runs past the end of the file.
    Torn,
    /// Its checksum does not match (`len`: the bytes it claims).
    Bad {
        len: usize,
    },
}

impl Frame<'_> {
    fn at(bytes: &[u8]) -> Frame<'_> {
        if bytes.len() < FRAME_HEAD {
            return Frame::Torn;
        }
        let len = u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]) as usize;
        let crc = u32::from_le_bytes([bytes[4], bytes[5], bytes[6], bytes[7]]);
        if len > FRAME_BYTES_MAX {
            return Frame::Bad { len: FRAME_HEAD.saturating_add(len) };
        }
        let Some(body) = bytes.get(8..FRAME_HEAD + len) else { return Frame::Torn };
        if crc32fast::hash(body) != crc {
            return Frame::Bad { len: FRAME_HEAD + len };
        }
        Frame::Whole { kind: body[0], payload: &body[1..] }
    }
}

/// Appends one frame to `out`.
fn frame(out: &mut Vec<u8>, kind: u8, payload: &[u8]) {
    let mut hasher = crc32fast::Hasher::new();
    hasher.update(&[kind]);
    hasher.update(payload);
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(&hasher.finalize().to_le_bytes());
    out.push(kind);
    out.extend_from_slice(payload);
}

impl Store {
    /// The last segment's file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The number of the last segment.
    pub fn number(&self) -> u64 {
        self.number
    }

    /// How many segments to keep when a snapshot starts a new one.
    pub fn keep(&mut self, keep: Keep) {
        self.keep = keep;
    }

    /// Writes the header of a new run (durably) before anything else.
    pub fn write_header(&mut self, header: &JournalHeader) -> anyhow::Result<()> {
        assert_eq!(header.format, JOURNAL_FORMAT);
        let mut out = Vec::new();
        frame(&mut out, KIND_HEADER, &serde_json::to_vec(header)?);
        self.put(&out)?;
        self.file.sync_data()?;
        self.header_frame = out;
        Ok(())
    }

    /// Writes `bytes` where the records end, in space allocated ahead.
    fn put(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        let end = self.end + bytes.len() as u64;
        if end > self.allocated {
            self.allocate(end.max(self.allocated + ALLOCATE_BYTES));
        }
        std::os::unix::fs::FileExt::write_all_at(&self.file, bytes, self.end)?;
        self.end = end;
        Ok(())
    }

    /// Allocates the segment's file up to `len` bytes, ahead of its records, and writes zeros there, durably: a
    /// commit then overwrites blocks that are already the file's, and its `fdatasync` flushes the data alone — not
    /// the file's size, nor the inode of extents that `fallocate` left unwritten, each an extra write the commit
    /// would wait for (`docs/benchmarks.md`). Where that fails (a full disk), the file grows as it is written.
    fn allocate(&mut self, len: u64) {
        if len <= self.allocated {
            return;
        }
        #[cfg(target_os = "linux")]
        {
            use std::os::fd::AsRawFd;
            let (from, more) = (self.allocated as libc::off_t, (len - self.allocated) as libc::off_t);
            // SAFETY: `fallocate` on a file descriptor this store owns, with offsets that fit `off_t`.
            if unsafe { libc::fallocate(self.file.as_raw_fd(), 0, from, more) } != 0 {
                return;
            }
        }
        let zeros = vec![0u8; (len - self.allocated) as usize];
        let written = std::os::unix::fs::FileExt::write_all_at(&self.file, &zeros, self.allocated);
        if written.and_then(|()| self.file.sync_data()).is_ok() {
            self.allocated = len;
        }
    }

    /// Allocates the next stretch ahead before the records reach it, between commits.
    fn allocate_ahead(&mut self) {
        if self.allocated < self.end + ALLOCATE_BYTES / 4 {
            self.allocate(self.end + ALLOCATE_BYTES);
        }
    }

    /// Cuts off the space allocated ahead of the records (when the segment is done with).
    fn trim(&mut self) {
        if self.allocated > self.end && self.file.set_len(self.end).is_ok() {
            self.allocated = self.end;
        }
    }

    /// Every segment the journal keeps, oldest first, read whole (for `baton replay`). A segment of the middle
    /// with a torn end is damage: only the last one is written to.
    pub fn segments(&self) -> anyhow::Result<Vec<Segment>> {
        let mut out = Vec::new();
        for number in segment_numbers(&self.dir)? {
            let path = self.dir.join(segment_name(number));
            let bytes = std::fs::read(&path).with_context(|| format!("cannot read the journal {}", path.display()))?;
            let read = read(&bytes).with_context(|| format!("cannot read the journal {}", path.display()))?;
            if read.torn && number != self.number {
                bail!("cannot read the journal {}: it ends in a torn frame, and segments follow it", path.display());
            }
            if number > 0 && read.snapshot.is_none() {
                bail!("cannot read the journal {}: it does not begin with its snapshot", path.display());
            }
            out.push(Segment { number, snapshot: read.snapshot, records: read.records });
        }
        Ok(out)
    }

    /// Appends records in one write, made durable by one `fdatasync`.
    fn append(&mut self, batches: &[Vec<Vec<u8>>], buffer: &mut Vec<u8>) -> anyhow::Result<()> {
        buffer.clear();
        for record in batches.iter().flatten() {
            frame(buffer, KIND_RECORD, record);
        }
        self.put(buffer)?;
        self.file.sync_data()?;
        Ok(())
    }

    /// Starts the next segment with the header and `snapshot`, then deletes the segments beyond `keep`. The new
    /// segment is written apart and renamed into place once durable, so it is never seen without its snapshot; if
    /// anything fails before the rename, the journal goes on in the segment it was in.
    fn start_segment(&mut self, snapshot: &[u8]) -> anyhow::Result<()> {
        let number = self.number + 1;
        let path = self.dir.join(segment_name(number));
        let new = path.with_extension("log.new");
        let mut bytes = Vec::with_capacity(MAGIC.len() + self.header_frame.len() + FRAME_HEAD + snapshot.len());
        bytes.extend_from_slice(MAGIC);
        bytes.extend_from_slice(&self.header_frame);
        frame(&mut bytes, KIND_SNAPSHOT, snapshot);
        let mut file = OpenOptions::new().read(true).write(true).create(true).truncate(true).open(&new)?;
        file.write_all(&bytes)?;
        file.sync_data()?;
        std::fs::rename(&new, &path)?;
        File::open(&self.dir)?.sync_all()?;
        self.trim();
        self.file = file;
        self.path = path;
        self.number = number;
        self.end = bytes.len() as u64;
        self.allocated = self.end;
        if let Keep::Last(n) = self.keep {
            let oldest = number.saturating_sub(u64::from(n) - 1);
            for old in segment_numbers(&self.dir)?.into_iter().filter(|&k| k < oldest) {
                std::fs::remove_file(self.dir.join(segment_name(old)))?;
            }
        }
        Ok(())
    }

    /// Starts the writer thread; batches are numbered from 1 in the order given. `deliver` sends the messages
    /// handed with a batch once it is durable (none are handed without it).
    pub fn start_writer(self, deliver: Option<Deliver>) -> Writer {
        let (tx, rx) = std_mpsc::channel::<Job>();
        let (done_tx, done_rx) = watch::channel(Durable::Upto(0));
        let stats = Arc::new(Counters::default());
        let counters = Arc::clone(&stats);
        let thread = std::thread::Builder::new()
            .name("baton-journal".into())
            .spawn(move || writer_loop(self, rx, done_tx, &counters, deliver))
            .expect("start the journal writer thread");
        Writer { tx: Some(tx), durable: done_rx, sent: 0, thread: Some(thread), stats }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub enum Durable {
    /// Every batch up to this number is durable.
    Upto(u64),
    /// The journal cannot be written: the run must stop (acting without the journal would break its promise).
    Failed(String),
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
    /// From the shell's handing a batch to the writer to the writer's having sent what the batch led to, on
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

/// What the shell hands the writer.
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
    done: watch::Sender<Durable>,
    counters: &Counters,
    mut deliver: Option<Deliver>,
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
                    return fail(format!("cannot write the journal {}: {e}", store.path.display()));
                }
                committed += batches.len() as u64;
                counters.commits.fetch_add(1, Ordering::Relaxed);
                counters.commit_ns.fetch_add(started.elapsed().as_nanos() as u64, Ordering::Relaxed);
                counters.records.fetch_add(batches.iter().map(|b| b.len() as u64).sum(), Ordering::Relaxed);
                batches.clear();
            }
            // Sent from this thread: a hand-over to another cost more than it saved (`docs/benchmarks.md`).
            for (at, messages) in waiting.drain(..) {
                if let Some(send) = deliver.as_mut() {
                    if let Err(why) = send(messages) {
                        return fail(why);
                    }
                }
                counters.held.fetch_add(1, Ordering::Relaxed);
                counters.held_ns.fetch_add(at.elapsed().as_nanos() as u64, Ordering::Relaxed);
            }
            // The shell is told only when more is durable.
            done.send_if_modified(|d| {
                let was = std::mem::replace(d, Durable::Upto(committed));
                was != *d
            });
            if let Some(snapshot) = segment {
                match store.start_segment(&snapshot) {
                    Ok(()) => {
                        counters.snapshots.fetch_add(1, Ordering::Relaxed);
                    }
                    // The records stay durable in the segment they were in; the next snapshot tries again.
                    Err(e) => eprintln!(
                        "warning: cannot start the journal's next segment in {}: {e}; it goes on in {}",
                        store.dir.display(),
                        store.path.display()
                    ),
                }
            }
        }
        store.allocate_ahead();
    }
    store.trim();
}

/// The shell's side of the writer thread.
pub struct Writer {
    tx: Option<std_mpsc::Sender<Job>>,
    durable: watch::Receiver<Durable>,
    sent: u64,
    thread: Option<std::thread::JoinHandle<()>>,
    stats: Arc<Counters>,
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

    /// A receiver that changes when batches become durable, for a `select!` outside the shell.
    pub fn watcher(&self) -> watch::Receiver<Durable> {
        self.durable.clone()
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
            Durable::Upto(_) => None,
        }
    }

    /// The number of the last durable batch.
    pub fn durable(&self) -> anyhow::Result<u64> {
        match &*self.durable.borrow() {
            Durable::Upto(n) => Ok(*n),
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

    /// Waits until every batch written so far is durable.
    pub async fn sync(&mut self) -> anyhow::Result<()> {
        while self.durable()? < self.sent {
            self.changed().await?;
        }
        Ok(())
    }

    /// Stops the writer after what was written so far.
    pub fn close(&mut self) {
        self.tx = None;
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

#[cfg(test)]
mod tests {
    use super::*;
    use baton_proto::dist::wire::{ChartHash, RunId};

    fn header() -> JournalHeader {
        JournalHeader {
            format: JOURNAL_FORMAT,
            run: RunId(uuid::Uuid::from_u128(3)),
            chart: ChartHash("abc".into()),
            pou: "Cell".into(),
            source: "PROGRAM Cell END_PROGRAM".into(),
            started_unix_ms: 1,
            cycle_ms: 10,
            program: "0123456789abcdef".into(),
        }
    }

    /// What a batch led to leaves from the writer once the batch is in the journal, and in the order it was
    /// handed — messages with nothing new to record after the batches handed before them.
    #[tokio::test]
    async fn messages_leave_once_the_records_that_led_to_them_are_written_and_in_order() {
        let dir = tempfile::tempdir().unwrap();
        let mut opened = open(dir.path()).unwrap();
        opened.store.write_header(&header()).unwrap();
        let path = dir.path().join(FILE_NAME);
        let sent = Arc::new(std::sync::Mutex::new(Vec::new()));
        let seen = Arc::clone(&sent);
        let deliver: Deliver = Box::new(move |messages| {
            let bytes = std::fs::read(&path).map_err(|e| e.to_string())?;
            let written = read(&bytes).map_err(|e| e.to_string())?.records;
            for m in messages {
                // Each message carries the record that led to it.
                if !written.contains(&m.payload) {
                    return Err(format!("{} left before its record {:?} was written", m.key, m.payload));
                }
                seen.lock().unwrap().push(m.key);
            }
            Ok(())
        });
        let mut writer = opened.store.start_writer(Some(deliver));
        let mut expected = Vec::new();
        for k in 0..60u8 {
            let key = format!("m{k}");
            if k % 5 == 4 {
                writer.send_after(vec![Outgoing { key: key.clone(), payload: vec![k - 1] }]).unwrap();
            } else {
                writer.write(vec![vec![k]], vec![Outgoing { key: key.clone(), payload: vec![k] }]).unwrap();
            }
            expected.push(key);
        }
        writer.sync().await.unwrap();
        writer.close();
        assert_eq!(*sent.lock().unwrap(), expected);
        assert!(writer.stats().held_us > 0.0);
    }

    /// A message that cannot be sent (its key cannot be declared) stops the journal with the reason, as the run's
    /// own sending would stop the run.
    #[tokio::test]
    async fn a_message_that_cannot_be_sent_stops_the_journal() {
        let dir = tempfile::tempdir().unwrap();
        let mut opened = open(dir.path()).unwrap();
        opened.store.write_header(&header()).unwrap();
        let deliver: Deliver = Box::new(|_| Err("cannot publish on baton/x: refused".into()));
        let mut writer = opened.store.start_writer(Some(deliver));
        writer.write(vec![vec![1]], vec![Outgoing { key: "baton/x".into(), payload: vec![1] }]).unwrap();
        let err = writer.sync().await.unwrap_err().to_string();
        assert!(err.contains("cannot publish on baton/x: refused"), "{err}");
        assert!(writer.durable().is_err());
    }

    #[tokio::test]
    async fn records_written_in_batches_are_read_back_in_order() {
        let dir = tempfile::tempdir().unwrap();
        let mut opened = open(dir.path()).unwrap();
        assert!(opened.header.is_none() && opened.records.is_empty());
        opened.store.write_header(&header()).unwrap();
        let mut writer = opened.store.start_writer(None);
        let mut expected = Vec::new();
        for b in 0..50u8 {
            let batch: Vec<Vec<u8>> = (0..b % 7).map(|i| vec![b, i]).collect();
            expected.extend(batch.clone());
            writer.write(batch, Vec::new()).unwrap();
        }
        writer.sync().await.unwrap();
        assert_eq!(writer.durable().unwrap(), 50);
        // A second opener is refused while the first holds the file.
        let err = open(dir.path()).err().expect("refused").to_string();
        assert!(err.contains("in use by another coordinator"), "{err}");
        drop(writer);
        let again = open(dir.path()).unwrap();
        assert_eq!(again.header, Some(header()));
        assert_eq!(again.records, expected);
    }

    /// A journal with `n` records written and made durable, and the bytes of its file.
    async fn written(dir: &Path, n: u8) -> Vec<u8> {
        let mut opened = open(dir).unwrap();
        opened.store.write_header(&header()).unwrap();
        let mut writer = opened.store.start_writer(None);
        for b in 0..n {
            writer.write(vec![vec![b; 3]], Vec::new()).unwrap();
        }
        writer.sync().await.unwrap();
        drop(writer);
        std::fs::read(dir.join(FILE_NAME)).unwrap()
    }

    /// Batches, then a snapshot, then more, twice: each snapshot starts a segment with the header and itself,
    /// the records after it go there, a resume reads only the last segment, and a replay reads them all.
    #[tokio::test]
    async fn a_snapshot_starts_a_segment_and_a_resume_reads_only_the_last() {
        let dir = tempfile::tempdir().unwrap();
        let mut opened = open(dir.path()).unwrap();
        opened.store.write_header(&header()).unwrap();
        let mut writer = opened.store.start_writer(None);
        let record = |k: u8| vec![k; 4];
        for part in 0..3u8 {
            for k in 0..5u8 {
                writer.write(vec![record(10 * part + k)], Vec::new()).unwrap();
            }
            if part < 2 {
                writer.snapshot(vec![b'S', part]).unwrap();
            }
        }
        writer.sync().await.unwrap();
        assert_eq!(writer.stats().snapshots, 2);
        drop(writer);
        let again = open(dir.path()).unwrap();
        assert_eq!(again.header, Some(header()), "every segment begins with the header");
        assert_eq!(again.snapshot, Some(vec![b'S', 1]));
        assert_eq!(again.records, (20..25).map(record).collect::<Vec<_>>());
        assert_eq!(again.store.number(), 2);
        let segments = again.store.segments().unwrap();
        let shape: Vec<_> = segments.iter().map(|s| (s.number, s.snapshot.clone(), s.records.len())).collect();
        assert_eq!(shape, [(0, None, 5), (1, Some(vec![b'S', 0]), 5), (2, Some(vec![b'S', 1]), 5)]);
        assert_eq!(segments[1].records, (10..15).map(record).collect::<Vec<_>>());
    }

    /// With `Keep::Last(2)`, a snapshot deletes the segments before the one before it; a segment that was being
    /// started when the process died is never read, and is removed.
    #[tokio::test]
    async fn segments_beyond_what_is_kept_are_deleted_and_a_half_made_one_is_ignored() {
        let dir = tempfile::tempdir().unwrap();
        let mut opened = open(dir.path()).unwrap();
        opened.store.write_header(&header()).unwrap();
        opened.store.keep(Keep::Last(2));
        let mut writer = opened.store.start_writer(None);
        for k in 0..4u8 {
            writer.write(vec![vec![k]], Vec::new()).unwrap();
            writer.snapshot(vec![k]).unwrap();
        }
        writer.write(vec![vec![9]], Vec::new()).unwrap();
        writer.sync().await.unwrap();
        drop(writer);
        let mut names: Vec<String> =
            std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
        names.sort();
        assert_eq!(names, ["journal-000003.log", "journal-000004.log", LOCK_NAME]);
        // A crash while segment 5 was being written: its bytes never got their name.
        std::fs::write(dir.path().join("journal-000005.log.new"), b"BATON-JOURNAL-1\n partial").unwrap();
        let again = open(dir.path()).unwrap();
        assert_eq!((again.snapshot, again.records), (Some(vec![3]), vec![vec![9]]));
        assert!(!dir.path().join("journal-000005.log.new").exists());
        assert_eq!(again.store.segments().unwrap().len(), 2);
        assert_eq!("all".parse::<Keep>(), Ok(Keep::All));
        assert_eq!("3".parse::<Keep>(), Ok(Keep::Last(3)));
        assert!("0".parse::<Keep>().is_err() && "some".parse::<Keep>().is_err());
    }

    #[tokio::test]
    async fn a_torn_last_commit_is_cut_off_and_the_journal_goes_on() {
        let dir = tempfile::tempdir().unwrap();
        let whole = written(dir.path(), 5).await;
        // A crash in the middle of the sixth commit: part of its frame reached the disk.
        let mut torn = whole.clone();
        frame(&mut torn, KIND_RECORD, &[9, 9, 9, 9]);
        torn.truncate(whole.len() + 6);
        std::fs::write(dir.path().join(FILE_NAME), &torn).unwrap();
        let again = open(dir.path()).unwrap();
        assert_eq!(again.records, (0..5u8).map(|b| vec![b; 3]).collect::<Vec<_>>());
        assert_eq!(std::fs::metadata(dir.path().join(FILE_NAME)).unwrap().len(), whole.len() as u64);
        // What comes next follows the five, and reads back.
        let mut writer = again.store.start_writer(None);
        writer.write(vec![vec![7]], Vec::new()).unwrap();
        writer.sync().await.unwrap();
        drop(writer);
        assert_eq!(open(dir.path()).unwrap().records.last(), Some(&vec![7]));
    }

    /// A segment is allocated ahead of its records while it is written (so that a commit does not grow the file),
    /// and a crash leaves that space behind, zeros, perhaps after a torn frame: the records end there, and opening
    /// the journal cuts the rest off. Closed, the segment keeps its records alone.
    #[tokio::test]
    async fn space_allocated_ahead_and_a_torn_frame_in_it_end_the_records() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(FILE_NAME);
        let mut opened = open(dir.path()).unwrap();
        opened.store.write_header(&header()).unwrap();
        let mut writer = opened.store.start_writer(None);
        for b in 0..5u8 {
            writer.write(vec![vec![b; 3]], Vec::new()).unwrap();
        }
        writer.sync().await.unwrap();
        let whole = MAGIC.len() + FRAME_HEAD + serde_json::to_vec(&header()).unwrap().len() + 5 * (FRAME_HEAD + 3);
        assert!(std::fs::metadata(&path).unwrap().len() >= ALLOCATE_BYTES, "allocated ahead while written");
        drop(writer);
        assert_eq!(std::fs::metadata(&path).unwrap().len(), whole as u64, "trimmed once closed");
        // A crash: allocated space after the records, and in it the start of a commit that never finished.
        let mut bytes = std::fs::read(&path).unwrap();
        let mut torn = Vec::new();
        frame(&mut torn, KIND_RECORD, &[7; 40]);
        bytes.extend_from_slice(&torn[..20]);
        bytes.resize(whole + 4096, 0);
        std::fs::write(&path, &bytes).unwrap();
        let again = open(dir.path()).unwrap();
        assert_eq!(again.records, (0..5u8).map(|b| vec![b; 3]).collect::<Vec<_>>());
        assert_eq!(std::fs::metadata(&path).unwrap().len(), whole as u64);
        // Zeros alone after the records read the same.
        drop(again);
        bytes.truncate(whole);
        bytes.resize(whole + 100, 0);
        std::fs::write(&path, &bytes).unwrap();
        assert_eq!(open(dir.path()).unwrap().records.len(), 5);
    }

    #[tokio::test]
    async fn damage_before_good_records_is_refused_not_skipped() {
        let dir = tempfile::tempdir().unwrap();
        let mut bytes = written(dir.path(), 5).await;
        // Flip a byte in the second record's payload: three good records follow it.
        let second = bytes.len() - 3 * (FRAME_HEAD + 3) - 1;
        bytes[second] ^= 0xff;
        std::fs::write(dir.path().join(FILE_NAME), &bytes).unwrap();
        let err = format!("{:#}", open(dir.path()).err().expect("refused"));
        assert!(err.contains("is damaged (record 1 and later)"), "{err}");
        // A file that is not a journal is refused too, and left as it was.
        std::fs::write(dir.path().join(FILE_NAME), b"PROGRAM p END_PROGRAM").unwrap();
        let err = format!("{:#}", open(dir.path()).err().expect("refused"));
        assert!(err.contains("not a Baton journal"), "{err}");
        assert_eq!(std::fs::read(dir.path().join(FILE_NAME)).unwrap(), b"PROGRAM p END_PROGRAM");
    }
}
