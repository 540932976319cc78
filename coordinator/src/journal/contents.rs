//! What a journal holds, as its stores (`store`: segment files, `etcd`: keys in etcd) read it back.

use baton_proto::cluster::journal::JournalHeader;

/// A journal opened for a coordinator by store `S`: a fresh one, or the header, the latest snapshot and the records
/// after it of a run to resume.
pub struct Opened<S> {
    pub store: S,
    /// `None` for a journal without a run yet.
    pub header: Option<JournalHeader>,
    /// The snapshot that begins the last segment (none in the first segment).
    pub snapshot: Option<Vec<u8>>,
    pub records: Vec<Vec<u8>>,
}

impl<S> Opened<S> {
    /// The same contents, held by another store.
    pub fn map<T>(self, f: impl FnOnce(S) -> T) -> Opened<T> {
        Opened { store: f(self.store), header: self.header, snapshot: self.snapshot, records: self.records }
    }
}

/// One segment, read whole: the run from its snapshot (none in the first segment) on.
pub struct Segment {
    pub number: u64,
    pub snapshot: Option<Vec<u8>>,
    pub records: Vec<Vec<u8>>,
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
