//! The journal's store: its segment files opened, read, appended to in commits, allocated ahead and trimmed
//! behind the snapshots (see the module's documentation).

use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use anyhow::{anyhow, bail, Context};
use baton_proto::cluster::journal::{JournalHeader, JOURNAL_FORMAT};

use super::contents::{Keep, Opened, Segment};
use super::segment::{self, Tail, KIND_HEADER, KIND_RECORD, KIND_SNAPSHOT, MAGIC};

/// The first segment of a journal, which holds the run from its start.
pub const FILE_NAME: &str = "journal.log";
/// Held (locked) while a coordinator uses the journal.
const LOCK_NAME: &str = "journal.lock";
/// Where journals of Baton before the append-only file were kept.
const OLD_FILE_NAME: &str = "journal.redb";
/// How much a segment's file is allocated ahead of its records at a time (about a thousand commits; zeroing it
/// takes the writer 1–3 ms on this project's disks).
const ALLOCATE_BYTES: u64 = 4 << 20;

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

/// A journal in segment files of a folder (`baton run --journal DIR`).
pub struct Files {
    pub(super) dir: PathBuf,
    /// The last segment, which records are appended to, and its number.
    file: File,
    pub(super) path: PathBuf,
    number: u64,
    /// The number of its next commit; where its commits end, and how far it is allocated (`allocate`).
    seq: u64,
    end: u64,
    allocated: u64,
    /// The header, which begins every segment.
    header_json: Vec<u8>,
    keep: Keep,
    _lock: File,
}

/// Opens (or creates) the journal in `dir` for a coordinator. Another process using it is refused. The last
/// commit of its last segment, if a crash cut it short, is cut off: nobody was told it was durable.
pub fn open(dir: &Path) -> anyhow::Result<Opened<Files>> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create the journal folder {}", dir.display()))?;
    let numbers = segment_numbers(dir)?;
    refuse_redb(dir, &numbers)?;
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
    let read = contents(&bytes, number).with_context(|| format!("cannot read the journal {}", path.display()))?;
    let end = if bytes.is_empty() {
        file.write_all(MAGIC)?;
        file.sync_data()?;
        // The new file's name, durable too: what is committed in it must not vanish with its directory entry.
        File::open(dir)?.sync_all()?;
        MAGIC.len()
    } else {
        if let Tail::Torn { bytes: torn } = read.tail {
            eprintln!(
                "baton: the journal {}'s last commit ({torn} bytes at byte {}) was cut short by a crash before it \
                 was acknowledged: it is cut off",
                path.display(),
                read.end
            );
        }
        if read.end < bytes.len() {
            // That commit, or space allocated ahead: cut off, durably, before anything is written after it.
            file.set_len(read.end as u64)?;
            file.sync_data()?;
        }
        read.end
    } as u64;
    let header_json = match &read.header {
        Some(h) => serde_json::to_vec(h)?,
        None => Vec::new(),
    };
    let store = Files {
        dir: dir.to_path_buf(),
        file,
        path,
        number,
        seq: read.commits,
        end,
        allocated: end,
        header_json,
        keep: Keep::All,
        _lock: lock,
    };
    Ok(Opened { store, header: read.header, snapshot: read.snapshot, records: read.records })
}

/// A journal as it stands, read without writing anything — no lock taken, no torn commit cut off (it is left out):
/// its header and every segment it keeps, oldest first (`baton replay`).
pub fn read_only(dir: &Path) -> anyhow::Result<(Option<JournalHeader>, Vec<Segment>)> {
    let numbers = segment_numbers(dir)?;
    refuse_redb(dir, &numbers)?;
    let mut header = None;
    let mut out = Vec::new();
    for (i, &number) in numbers.iter().enumerate() {
        let last = i + 1 == numbers.len();
        let (read, segment) = read_segment(dir, number, last)?;
        header = header.or(read);
        out.push(segment);
    }
    Ok((header, out))
}

fn refuse_redb(dir: &Path, numbers: &[u64]) -> anyhow::Result<()> {
    if numbers.is_empty() && dir.join(OLD_FILE_NAME).exists() {
        bail!(
            "{} holds a journal of an earlier Baton ({OLD_FILE_NAME}); this one keeps journals in {FILE_NAME}: \
             resume or replay it with the Baton that wrote it",
            dir.display()
        );
    }
    Ok(())
}

/// Segment `number` of the journal in `dir`, read whole; only the `last` may end in a torn commit.
fn read_segment(dir: &Path, number: u64, last: bool) -> anyhow::Result<(Option<JournalHeader>, Segment)> {
    let path = dir.join(segment_name(number));
    let cannot = || format!("cannot read the journal {}", path.display());
    let bytes = std::fs::read(&path).with_context(cannot)?;
    let read = contents(&bytes, number).with_context(cannot)?;
    if !last && read.tail != Tail::Clean {
        bail!("{}: it ends in a torn commit at byte {}, and segments follow it", cannot(), read.end);
    }
    Ok((read.header, Segment { number, snapshot: read.snapshot, records: read.records }))
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

/// What a segment holds: its header, its snapshot (a segment after the first begins with one) and its records,
/// from its whole commits; how many those are and where they end, and what follows them.
struct Contents {
    header: Option<JournalHeader>,
    snapshot: Option<Vec<u8>>,
    records: Vec<Vec<u8>>,
    commits: u64,
    end: usize,
    tail: Tail,
}

/// Segment `number`'s bytes, read: its first commit holds the header (and, after the first segment, the snapshot
/// right after it), the others records.
fn contents(bytes: &[u8], number: u64) -> anyhow::Result<Contents> {
    let mut out = Contents { header: None, snapshot: None, records: Vec::new(), commits: 0, end: 0, tail: Tail::Clean };
    if bytes.is_empty() && number == 0 {
        return Ok(out);
    }
    let scan = segment::scan(bytes).map_err(|d| anyhow!("{d}"))?;
    for (i, (seq, f)) in scan.frames.iter().enumerate() {
        match f.kind {
            KIND_HEADER if i == 0 && *seq == 0 => {
                out.header = Some(
                    serde_json::from_slice::<JournalHeader>(f.payload)
                        .map_err(|e| anyhow!("its header is malformed: {e}"))?,
                );
            }
            KIND_SNAPSHOT if i == 1 && *seq == 0 && number > 0 => out.snapshot = Some(f.payload.to_vec()),
            KIND_RECORD if out.header.is_some() && (number == 0 || out.snapshot.is_some()) => {
                out.records.push(f.payload.to_vec())
            }
            kind => bail!("its commit {seq} holds a frame of kind {kind} out of place (frame {i} of the segment)"),
        }
    }
    if number > 0 && out.snapshot.is_none() {
        bail!("it does not begin with its snapshot");
    }
    (out.commits, out.end, out.tail) = (scan.commits, scan.end, scan.tail);
    Ok(out)
}

impl Files {
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
        assert_eq!(self.seq, 0, "the header is a segment's first commit");
        let json = serde_json::to_vec(header)?;
        self.commit(&[(KIND_HEADER, json.as_slice())], &mut Vec::new())?;
        self.header_json = json;
        Ok(())
    }

    /// Writes one commit of `frames` where the commits end, in space allocated ahead, and makes it durable.
    fn commit(&mut self, frames: &[(u8, &[u8])], buffer: &mut Vec<u8>) -> std::io::Result<()> {
        buffer.clear();
        segment::commit(buffer, self.seq, self.end, frames.iter().copied());
        let end = self.end + buffer.len() as u64;
        if end > self.allocated {
            self.allocate(end.max(self.allocated + ALLOCATE_BYTES));
        }
        std::os::unix::fs::FileExt::write_all_at(&self.file, buffer, self.end)?;
        self.file.sync_data()?;
        self.seq += 1;
        self.end = end;
        Ok(())
    }

    /// Allocates the segment's file up to `len` bytes, ahead of its records, and writes zeros there, durably: a
    /// commit then overwrites blocks that are already the file's, and its `fdatasync` flushes the data alone — not
    /// the file's size, nor the inode of extents that `fallocate` left unwritten, each an extra write the commit
    /// would wait for (`docs/book/src/benchmarks.md`). Where that fails (a full disk), the file grows as it is written.
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
    pub(super) fn allocate_ahead(&mut self) {
        if self.allocated < self.end + ALLOCATE_BYTES / 4 {
            self.allocate(self.end + ALLOCATE_BYTES);
        }
    }

    /// Cuts off the space allocated ahead of the records (when the segment is done with).
    pub(super) fn trim(&mut self) {
        if self.allocated > self.end && self.file.set_len(self.end).is_ok() {
            self.allocated = self.end;
        }
    }

    /// Every segment the journal keeps, oldest first, read whole. A segment of the middle with a torn end is
    /// damage: only the last one is written to.
    pub fn segments(&self) -> anyhow::Result<Vec<Segment>> {
        let numbers = segment_numbers(&self.dir)?;
        numbers.iter().map(|&n| read_segment(&self.dir, n, n == self.number).map(|(_, s)| s)).collect()
    }

    /// Appends the records of `batches` in one commit: one write, made durable by one `fdatasync`.
    pub(super) fn append(&mut self, batches: &[Vec<Vec<u8>>], buffer: &mut Vec<u8>) -> anyhow::Result<()> {
        let frames: Vec<(u8, &[u8])> = batches.iter().flatten().map(|r| (KIND_RECORD, r.as_slice())).collect();
        if !frames.is_empty() {
            self.commit(&frames, buffer)?;
        }
        Ok(())
    }

    /// Starts the next segment with the header and `snapshot`, then deletes the segments beyond `keep`. The new
    /// segment is written apart and renamed into place once durable, so it is never seen without its snapshot; if
    /// anything fails before the rename, the journal goes on in the segment it was in.
    pub(super) fn start_segment(&mut self, snapshot: &[u8]) -> anyhow::Result<()> {
        let number = self.number + 1;
        let path = self.dir.join(segment_name(number));
        let new = path.with_extension("log.new");
        let mut bytes = Vec::with_capacity(MAGIC.len() + segment::HEAD + self.header_json.len() + snapshot.len() + 16);
        bytes.extend_from_slice(MAGIC);
        let frames = [(KIND_HEADER, self.header_json.as_slice()), (KIND_SNAPSHOT, snapshot)];
        segment::commit(&mut bytes, 0, MAGIC.len() as u64, frames);
        let mut file = OpenOptions::new().read(true).write(true).create(true).truncate(true).open(&new)?;
        file.write_all(&bytes)?;
        file.sync_data()?;
        std::fs::rename(&new, &path)?;
        File::open(&self.dir)?.sync_all()?;
        self.trim();
        self.file = file;
        self.path = path;
        self.number = number;
        self.seq = 1;
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
}

#[cfg(test)]
mod tests;
