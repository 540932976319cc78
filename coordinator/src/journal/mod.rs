//! `baton run --journal DIR` (or `--journal etcd://…/PREFIX`, `etcd`: the same segments as keys in etcd, each write
//! a transaction fenced by the run's election — see that module; `place` says which store a journal is in): the
//! coordinator's records (`baton_proto::cluster::journal`) appended to segment files by
//! a thread of their own with group commit (`writer`), and the coordinator's snapshots that begin each segment after
//! the first.
//!
//! The host hands each batch of records to the writer with the messages the coordinator asked to send (its
//! dispatches, its variable updates) and holds back the rest of what it asked for. The writer sends the messages
//! itself the moment the batch is durable (written and `fdatasync`'d), then says so, and the host carries out
//! the rest: a round trip waits for the commit, not for the main loop's turn as well. While one commit is on its
//! way to the disk, the batches that arrive meanwhile wait and go together in the next one, so a slow disk makes
//! batches larger, not the chart slower: durability costs latency (one commit), not throughput.
//!
//! A segment file is a run of commits, each what one `fdatasync` made durable, with a head of its own (`segment`,
//! which says how a segment is read back). The first segment is `journal.log`: the header, then records. Every
//! `snapshot_every` records the host hands the writer a snapshot of the coordinator (`Journaled::snapshot`); the
//! writer starts segment `journal-NNNNNN.log` with the header and the snapshot (written apart, `fdatasync`'d, then
//! renamed into place, so a segment is never seen without its snapshot), the records after it go there, and the
//! segments beyond `keep` are deleted: the journal is compacted behind its snapshots. A resume reads only the last
//! segment: the snapshot, then its records.
//!
//! A crash while a commit was being written leaves it torn — any of its pages on the disk, the rest still the zeros
//! allocated ahead — and nobody was told it was durable: a coordinator opening the journal cuts it off. A commit
//! that is not whole with a whole one after it is damage, and the journal is refused. `baton replay` reads a journal
//! without writing to it (`read_only`). `store/tests.rs` builds the disk of a crash at every write of a real journal,
//! with every subset of the last commit's pages. (An append-only file replaced redb here: a commit is one write and
//! one `fdatasync` instead of a B-tree's pages, `docs/book/src/benchmarks.md`.)

mod contents;
mod etcd;
mod place;
mod segment;
mod store;
mod writer;

pub use contents::{Keep, Segment, Settings, SNAPSHOT_EVERY};
pub use etcd::Fenced;
pub use place::{open, read_only, Place, Store};
pub use store::FILE_NAME;
pub use writer::{Deliver, JournalStats, OnDurable, Outgoing, Writer};
