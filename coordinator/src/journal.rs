//! `baton run --journal DIR`: the coordinator's records (`baton_proto::dist::journal`) kept in an embedded database
//! (redb, one file `DIR/journal.redb`), written by a thread of their own with group commit.
//!
//! The shell hands each batch of records to the writer and holds back what the coordinator asked for until the
//! writer says the batch is durable (an fsync'd transaction). While one transaction commits, the batches that
//! arrive meanwhile wait and go together in the next one, so a slow disk makes batches larger, not the chart
//! slower: durability costs latency (one commit), not throughput.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc as std_mpsc;
use std::sync::Arc;

use anyhow::{anyhow, bail, Context};
use baton_proto::dist::journal::{JournalHeader, JOURNAL_FORMAT};
use redb::{Database, ReadableDatabase, ReadableTable, TableDefinition};
use tokio::sync::watch;

const RECORDS: TableDefinition<u64, &[u8]> = TableDefinition::new("records");
const META: TableDefinition<&str, &[u8]> = TableDefinition::new("meta");
const HEADER_KEY: &str = "header";
pub const FILE_NAME: &str = "journal.redb";

/// An opened journal: a fresh one, or the header and records of a run to resume.
pub struct Opened {
    pub store: Store,
    /// `None` for a journal without a run yet.
    pub header: Option<JournalHeader>,
    pub records: Vec<Vec<u8>>,
}

pub struct Store {
    db: Database,
    path: PathBuf,
    next_key: u64,
}

/// Opens (or creates) the journal in `dir`. Another process using it is refused.
pub fn open(dir: &Path) -> anyhow::Result<Opened> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create the journal folder {}", dir.display()))?;
    let path = dir.join(FILE_NAME);
    let db = Database::create(&path).map_err(|e| match e {
        redb::DatabaseError::DatabaseAlreadyOpen => {
            anyhow!("the journal {} is in use by another coordinator", path.display())
        }
        other => anyhow!("cannot open the journal {}: {other}", path.display()),
    })?;
    let (header, records) = read(&db).with_context(|| format!("cannot read the journal {}", path.display()))?;
    let next_key = records.len() as u64;
    Ok(Opened { store: Store { db, path, next_key }, header, records })
}

fn read(db: &Database) -> anyhow::Result<(Option<JournalHeader>, Vec<Vec<u8>>)> {
    let tx = db.begin_read()?;
    let header = match tx.open_table(META) {
        Ok(meta) => match meta.get(HEADER_KEY)? {
            Some(bytes) => Some(
                serde_json::from_slice::<JournalHeader>(bytes.value())
                    .map_err(|e| anyhow!("its header is malformed: {e}"))?,
            ),
            None => None,
        },
        Err(redb::TableError::TableDoesNotExist(_)) => None,
        Err(e) => return Err(e.into()),
    };
    let mut records = Vec::new();
    match tx.open_table(RECORDS) {
        Ok(table) => {
            for (i, item) in table.iter()?.enumerate() {
                let (key, value) = item?;
                if key.value() != i as u64 {
                    bail!("record {i} is missing (next is {})", key.value());
                }
                records.push(value.value().to_vec());
            }
        }
        Err(redb::TableError::TableDoesNotExist(_)) => {}
        Err(e) => return Err(e.into()),
    }
    Ok((header, records))
}

impl Store {
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Writes the header of a new run (durably) before anything else.
    pub fn write_header(&mut self, header: &JournalHeader) -> anyhow::Result<()> {
        assert_eq!(header.format, JOURNAL_FORMAT);
        let bytes = serde_json::to_vec(header)?;
        let tx = self.db.begin_write()?;
        tx.open_table(META)?.insert(HEADER_KEY, bytes.as_slice())?;
        tx.open_table(RECORDS)?;
        tx.commit()?;
        Ok(())
    }

    /// Appends records in one durable transaction.
    fn append(&mut self, batches: &[Vec<Vec<u8>>]) -> anyhow::Result<()> {
        let tx = self.db.begin_write()?;
        {
            let mut table = tx.open_table(RECORDS)?;
            for record in batches.iter().flatten() {
                table.insert(self.next_key, record.as_slice())?;
                self.next_key += 1;
            }
        }
        tx.commit()?;
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
    while let Ok(first) = rx.recv() {
        // Group commit: everything that queued up while the last transaction was committing goes in this one.
        let mut batches = vec![first];
        while let Ok(more) = rx.try_recv() {
            batches.push(more);
        }
        if let Err(e) = store.append(&batches) {
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
}
