//! The coordinator's journal, as records: every input its state machine takes, with the time it took it, in
//! order. The coordinator is deterministic — the same inputs at the same times give the same situation, the same
//! tokens (their ids come from the run id and a counter) and the same trace — so replaying the records rebuilds
//! the run exactly: activations, dispatches, returns, epochs and the values it owns.
//!
//! `Journaled` wraps a `Coordinator` so that nothing reaches it without a record: the host takes the records
//! (`take_records`), makes them durable, and only then carries out what the coordinator asked for. Storage is
//! the host's business (`baton run` keeps records in segment files of commits, `coordinator/src/journal`); this
//! module only encodes, decodes and applies them (`journaled.rs`: `Journaled`, its `--watch` values and its
//! snapshots).
//!
//! A record is `[tag: u8][t_ms: u64, little endian][body]`. Bodies of reports, variable updates and agent
//! announcements are the wire messages as they arrived, so journaling them costs a copy, not an encoding.
//!
//! The coordinator's journal as records — every input of `Coordinator` with its time (`Record`: cycle,
//! report, variable update, device report, agent up/down, set, loss policy, recover, end) — their binary framing,
//! `apply` (the one place records become inputs), `Journaled` (a `Coordinator` whose inputs are all recorded first, and
//! `replay`), the journal header (with `program_pin`, a hash of what the records' variable, step, transition, action
//! and segment numbers mean, so a journal is resumed or replayed only by the compilation that wrote it), and
//! `token_ids` (token ids from the run id and a counter, so that a replay makes the same tokens). Storage is the
//! host's.

mod journaled;
mod records;
#[cfg(test)]
mod tests;

pub use crate::cluster::runtime::coordinator::{token_ids, TokenIds};

pub use journaled::{snapshot_meta, Journaled, Replayed, SnapshotMeta, SNAPSHOT_FORMAT};
pub use records::{apply, decode, encode, program_pin, Entry, JournalError, JournalHeader, Record, JOURNAL_FORMAT};
