//! `baton run --journal DIR`: the coordinator's records (`baton_proto::dist::journal`) appended to one file,
//! `DIR/journal.log`, by a thread of their own with group commit.
//!
//! The shell hands each batch of records to the writer and holds back what the coordinator asked for until the
//! writer says the batch is durable (written and `fdatasync`'d). While one commit is on its way to the disk, the
//! batches that arrive meanwhile wait and go together in the next one, so a slow disk makes batches larger, not
//! the chart slower: durability costs latency (one commit), not throughput.
//!
//! The file: `MAGIC`, then frames — payload length (u32, little-endian), CRC-32 of the kind and payload (u32), the
//! kind (0 the run's header, JSON; 1 a record), the payload. A crash while a commit was being written leaves a
//! torn last frame, which nobody was told was durable: opening the journal cuts it off. A bad frame with good
//! ones after it is damage, and the journal is refused. (An append-only file replaced redb here: a commit is one
//! write and one `fdatasync` instead of a B-tree's pages, `docs/benchmarks.md`.)

use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc as std_mpsc;
use std::sync::Arc;

use anyhow::{anyhow, bail, Context};
use baton_proto::dist::journal::{JournalHeader, JOURNAL_FORMAT};
use tokio::sync::watch;

pub const FILE_NAME: &str = "journal.log";
/// Where journals of Baton before the append-only file were kept.
const OLD_FILE_NAME: &str = "journal.redb";
const MAGIC: &[u8; 16] = b"BATON-JOURNAL-1\n";
const FRAME_HEAD: usize = 9;
const KIND_HEADER: u8 = 0;
const KIND_RECORD: u8 = 1;
/// A frame larger than this is damage, not a record (a record is at most a message and a chart's header).
const FRAME_BYTES_MAX: usize = 64 << 20;

/// An opened journal: a fresh one, or the header and records of a run to resume.
pub struct Opened {
    pub store: Store,
    /// `None` for a journal without a run yet.
    pub header: Option<JournalHeader>,
    pub records: Vec<Vec<u8>>,
}

pub struct Store {
    file: File,
    path: PathBuf,
}

/// Opens (or creates) the journal in `dir`. Another process using it is refused.
pub fn open(dir: &Path) -> anyhow::Result<Opened> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create the journal folder {}", dir.display()))?;
    let path = dir.join(FILE_NAME);
    if !path.exists() && dir.join(OLD_FILE_NAME).exists() {
        bail!(
            "{} holds a journal of an earlier Baton ({OLD_FILE_NAME}); this one keeps journals in {FILE_NAME}: \
             resume or replay it with the Baton that wrote it",
            dir.display()
        );
    }
    let mut file = OpenOptions::new()
        .read(true)
        .append(true)
        .create(true)
        .open(&path)
        .with_context(|| format!("cannot open the journal {}", path.display()))?;
    match file.try_lock() {
        Ok(()) => {}
        Err(std::fs::TryLockError::WouldBlock) => {
            bail!("the journal {} is in use by another coordinator", path.display())
        }
        Err(std::fs::TryLockError::Error(e)) => bail!("cannot lock the journal {}: {e}", path.display()),
    }
    let mut bytes = Vec::new();
    file.read_to_end(&mut bytes).with_context(|| format!("cannot read the journal {}", path.display()))?;
    let (header, records, good) =
        read(&bytes).with_context(|| format!("cannot read the journal {}", path.display()))?;
    if bytes.is_empty() {
        file.write_all(MAGIC)?;
        file.sync_data()?;
    } else if good < bytes.len() {
        // The torn frame of a commit that never finished: nothing in it was acknowledged.
        file.set_len(good as u64)?;
        file.sync_data()?;
    }
    Ok(Opened { store: Store { file, path }, header, records })
}

/// The header and records of a journal file's bytes, and how many of its bytes are whole frames.
fn read(bytes: &[u8]) -> anyhow::Result<(Option<JournalHeader>, Vec<Vec<u8>>, usize)> {
    if bytes.is_empty() {
        return Ok((None, Vec::new(), 0));
    }
    if !bytes.starts_with(MAGIC) {
        bail!("it is not a Baton journal (it does not start with {:?})", String::from_utf8_lossy(MAGIC).trim());
    }
    let (mut header, mut records, mut at) = (None, Vec::new(), MAGIC.len());
    while at < bytes.len() {
        let frame = Frame::at(&bytes[at..]);
        let (kind, payload, len) = match frame {
            Frame::Whole { kind, payload } => (kind, payload, FRAME_HEAD + payload.len()),
            // Only the last frame may be torn.
            Frame::Torn => break,
            Frame::Bad { len } if at + len >= bytes.len() => break,
            Frame::Bad { .. } => bail!("its frame at byte {at} is damaged (record {} and later)", records.len()),
        };
        match kind {
            KIND_HEADER if header.is_none() && records.is_empty() => {
                header = Some(
                    serde_json::from_slice::<JournalHeader>(payload)
                        .map_err(|e| anyhow!("its header is malformed: {e}"))?,
                );
            }
            KIND_RECORD if header.is_some() => records.push(payload.to_vec()),
            _ => bail!("its frame at byte {at} (kind {kind}) is out of place"),
        }
        at += len;
    }
    Ok((header, records, at.min(bytes.len())))
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
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Writes the header of a new run (durably) before anything else.
    pub fn write_header(&mut self, header: &JournalHeader) -> anyhow::Result<()> {
        assert_eq!(header.format, JOURNAL_FORMAT);
        let mut out = Vec::new();
        frame(&mut out, KIND_HEADER, &serde_json::to_vec(header)?);
        self.file.write_all(&out)?;
        self.file.sync_data()?;
        Ok(())
    }

    /// Appends records in one write, made durable by one `fdatasync`.
    fn append(&mut self, batches: &[Vec<Vec<u8>>], buffer: &mut Vec<u8>) -> anyhow::Result<()> {
        buffer.clear();
        for record in batches.iter().flatten() {
            frame(buffer, KIND_RECORD, record);
        }
        self.file.write_all(buffer)?;
        self.file.sync_data()?;
        Ok(())
    }

    /// Starts the writer thread; batches are numbered from 1 in the order given.
    pub fn start_writer(self) -> Writer {
        let (tx, rx) = std_mpsc::channel::<Vec<Vec<u8>>>();
        let (done_tx, done_rx) = watch::channel(Durable::Upto(0));
        let stats = Arc::new(Counters::default());
        let counters = Arc::clone(&stats);
        let thread = std::thread::Builder::new()
            .name("baton-journal".into())
            .spawn(move || writer_loop(self, rx, done_tx, &counters))
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
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct JournalStats {
    pub records: u64,
    pub commits: u64,
}

fn writer_loop(
    mut store: Store,
    rx: std_mpsc::Receiver<Vec<Vec<u8>>>,
    done: watch::Sender<Durable>,
    counters: &Counters,
) {
    let mut committed = 0u64;
    let mut buffer = Vec::new();
    while let Ok(first) = rx.recv() {
        // Group commit: everything that queued up while the last transaction was committing goes in this one.
        let mut batches = vec![first];
        while let Ok(more) = rx.try_recv() {
            batches.push(more);
        }
        if let Err(e) = store.append(&batches, &mut buffer) {
            let _ = done.send(Durable::Failed(format!("cannot write the journal {}: {e}", store.path.display())));
            return;
        }
        committed += batches.len() as u64;
        counters.commits.fetch_add(1, Ordering::Relaxed);
        counters.records.fetch_add(batches.iter().map(|b| b.len() as u64).sum(), Ordering::Relaxed);
        let _ = done.send(Durable::Upto(committed));
    }
}

/// The shell's side of the writer thread.
pub struct Writer {
    tx: Option<std_mpsc::Sender<Vec<Vec<u8>>>>,
    durable: watch::Receiver<Durable>,
    sent: u64,
    thread: Option<std::thread::JoinHandle<()>>,
    stats: Arc<Counters>,
}

impl Writer {
    /// Queues a batch; returns its number.
    pub fn write(&mut self, records: Vec<Vec<u8>>) -> anyhow::Result<u64> {
        let tx = self.tx.as_ref().ok_or_else(|| anyhow!("the journal is closed"))?;
        if tx.send(records).is_err() {
            return Err(anyhow!("{}", self.failure().unwrap_or_else(|| "the journal writer stopped".into())));
        }
        self.sent += 1;
        Ok(self.sent)
    }

    /// A receiver that changes when batches become durable, for a `select!` outside the shell.
    pub fn watcher(&self) -> watch::Receiver<Durable> {
        self.durable.clone()
    }

    /// Records written and transactions committed so far.
    pub fn stats(&self) -> JournalStats {
        JournalStats {
            records: self.stats.records.load(Ordering::Relaxed),
            commits: self.stats.commits.load(Ordering::Relaxed),
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

    #[tokio::test]
    async fn records_written_in_batches_are_read_back_in_order() {
        let dir = tempfile::tempdir().unwrap();
        let mut opened = open(dir.path()).unwrap();
        assert!(opened.header.is_none() && opened.records.is_empty());
        opened.store.write_header(&header()).unwrap();
        let mut writer = opened.store.start_writer();
        let mut expected = Vec::new();
        for b in 0..50u8 {
            let batch: Vec<Vec<u8>> = (0..b % 7).map(|i| vec![b, i]).collect();
            expected.extend(batch.clone());
            writer.write(batch).unwrap();
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
        let mut writer = opened.store.start_writer();
        for b in 0..n {
            writer.write(vec![vec![b; 3]]).unwrap();
        }
        writer.sync().await.unwrap();
        drop(writer);
        std::fs::read(dir.join(FILE_NAME)).unwrap()
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
        let mut writer = again.store.start_writer();
        writer.write(vec![vec![7]]).unwrap();
        writer.sync().await.unwrap();
        drop(writer);
        assert_eq!(open(dir.path()).unwrap().records.last(), Some(&vec![7]));
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
