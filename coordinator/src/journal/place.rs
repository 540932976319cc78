//! Where a journal is kept — segment files in a folder (`store`), or keys in etcd (`etcd`) — and the store the
//! writer thread writes to, whichever it is.

use std::path::PathBuf;

use baton_proto::cluster::journal::JournalHeader;

use super::contents::{Keep, Opened, Segment};
use super::etcd::Etcd;
use super::store::Files;
use crate::election::{Election, Fence};

/// `baton run --journal DIR` or `--journal etcd://HOST:PORT[,HOST:PORT…]/PREFIX`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Place {
    Dir(PathBuf),
    Etcd(Election),
}

impl std::str::FromStr for Place {
    type Err = String;
    fn from_str(s: &str) -> Result<Place, String> {
        if s.starts_with("etcd://") || s.starts_with("etcds://") {
            return s.parse().map(Place::Etcd);
        }
        if s.is_empty() {
            return Err("a journal needs a folder (or etcd://HOST:PORT/PREFIX)".into());
        }
        Ok(Place::Dir(PathBuf::from(s)))
    }
}

impl std::fmt::Display for Place {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Place::Dir(dir) => write!(f, "{}", dir.display()),
            Place::Etcd(election) => write!(f, "{election}"),
        }
    }
}

/// A journal's store, as the writer thread writes to it.
pub enum Store {
    Files(Files),
    Etcd(Etcd),
}

impl From<Files> for Store {
    fn from(files: Files) -> Store {
        Store::Files(files)
    }
}

/// Opens the journal at `place` for a coordinator; one in etcd is written only under `fence` (`baton run
/// --election`, which a journal in etcd needs).
pub fn open(place: &Place, fence: Option<Fence>) -> anyhow::Result<Opened<Store>> {
    match (place, fence) {
        (Place::Dir(dir), _) => super::store::open(dir).map(|o| o.map(Store::Files)),
        (Place::Etcd(election), Some(fence)) => super::etcd::open(election, fence).map(|o| o.map(Store::Etcd)),
        (Place::Etcd(election), None) => {
            anyhow::bail!("the journal at {election} is written only by the winner of the run's election")
        }
    }
}

/// The journal at `place` as it stands, read without writing anything (`baton replay`): its header (`None`: no
/// run in it) and the segments it keeps, oldest first.
pub fn read_only(place: &Place) -> anyhow::Result<(Option<JournalHeader>, Vec<Segment>)> {
    match place {
        Place::Dir(dir) if !super::store::exists(dir) => Ok((None, Vec::new())),
        Place::Dir(dir) => super::store::read_only(dir),
        Place::Etcd(election) => super::etcd::read_only(election),
    }
}

impl Store {
    /// The journal as messages show it: its last segment's file, or etcd's endpoints and prefix.
    pub fn shown(&self) -> String {
        match self {
            Store::Files(f) => f.path().display().to_string(),
            Store::Etcd(e) => e.shown(),
        }
    }

    /// The number of the last segment.
    pub fn number(&self) -> u64 {
        match self {
            Store::Files(f) => f.number(),
            Store::Etcd(e) => e.number(),
        }
    }

    /// How many segments to keep when a snapshot starts a new one.
    pub fn keep(&mut self, keep: Keep) {
        match self {
            Store::Files(f) => f.keep(keep),
            Store::Etcd(e) => e.keep(keep),
        }
    }

    /// Writes the header of a new run (durably) before anything else.
    pub fn write_header(&mut self, header: &JournalHeader) -> anyhow::Result<()> {
        match self {
            Store::Files(f) => f.write_header(header),
            Store::Etcd(e) => e.write_header(header),
        }
    }

    /// Every segment the journal keeps, oldest first, read whole.
    pub fn segments(&self) -> anyhow::Result<Vec<Segment>> {
        match self {
            Store::Files(f) => f.segments(),
            Store::Etcd(e) => e.segments(),
        }
    }

    /// Appends the records of `batches` durably, as one commit (in etcd, as few transactions as its limits allow).
    pub(super) fn append(&mut self, batches: &[Vec<Vec<u8>>], buffer: &mut Vec<u8>) -> anyhow::Result<()> {
        match self {
            Store::Files(f) => f.append(batches, buffer),
            Store::Etcd(e) => e.append(batches),
        }
    }

    /// Starts the next segment with `snapshot`, then drops the segments beyond `keep`.
    pub(super) fn start_segment(&mut self, snapshot: &[u8]) -> anyhow::Result<()> {
        match self {
            Store::Files(f) => f.start_segment(snapshot),
            Store::Etcd(e) => e.start_segment(snapshot),
        }
    }

    /// Between commits: a segment file is allocated ahead of its records.
    pub(super) fn allocate_ahead(&mut self) {
        if let Store::Files(f) = self {
            f.allocate_ahead();
        }
    }

    /// At the end: a segment file's space allocated ahead is cut off.
    pub(super) fn trim(&mut self) {
        if let Store::Files(f) = self {
            f.trim();
        }
    }
}
