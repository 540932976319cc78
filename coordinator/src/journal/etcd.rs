//! The journal in etcd (`baton run --journal etcd://HOST:PORT[,HOST:PORT…]/PREFIX`): the file journal's segments
//! (`store`) as keys under `PREFIX/journal/`, so that a standby on another machine resumes from every record the
//! active coordinator had acknowledged. Each write is a transaction that holds only while its writer still holds
//! the run's election: it compares the creation revision of the writer's leadership key with its term, as Temporal
//! compares a shard's `range_id`. A deposed writer's transaction changes nothing, and the writer stops acting at
//! once (`Fence::lose`), whatever its lease's renewals said.
//!
//! The keys, after `PREFIX/journal/`:
//!
//! - `header`: the run's header (JSON), written once, before anything else.
//! - `head`: the number of the last segment (absent: 0), written last when a snapshot starts a segment, so that
//!   a segment is never read without its whole snapshot.
//! - `s/NNNNNNNNNN/a/CCCCCC`: segment N's snapshot, in chunks (segments after the first begin with one).
//! - `s/NNNNNNNNNN/c/SSSSSSSSSSSSSSSS`: segment N's commits, in order. Each holds records, each its length (4
//!   bytes, little-endian) and its bytes.
//!
//! etcd refuses a request over `--max-request-bytes` (1.5 MiB by default) or with more than `--max-txn-ops` (128
//! by default). So a commit's records go into values of at most `CHUNK` bytes, each its own transaction of one
//! operation; a record larger than that is refused. A snapshot goes in chunks of the same size, then one
//! transaction moves `head` and deletes the segments beyond `--journal-keep`. A group commit split over several
//! transactions is acknowledged when its last one is: a crash between them leaves a prefix of the records durable,
//! which a resume replays — the run as if the coordinator had died after those inputs, with nothing sent for
//! them (what they led to is sent only once the whole commit is durable).
//!
//! etcd keeps every revision until it is compacted, and refuses writes past `--quota-backend-bytes` (2 GiB by
//! default). Baton does not compact etcd, which is shared; the etcd of a cell runs with automatic compaction
//! (`deploy/etcd/README.md`).

use std::future::Future;
use std::pin::Pin;
use std::sync::mpsc as std_mpsc;
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context};
use baton_proto::cluster::journal::{JournalHeader, JOURNAL_FORMAT};
use etcd_client::{Client, Compare, CompareOp, DeleteOptions, GetOptions, KvClient, Txn, TxnOp};

use super::contents::{Keep, Opened, Segment};
use crate::election::{refused, Election, Fence, RETRY};

/// The largest value the journal puts in etcd: a chunk of records or of a snapshot (etcd takes 1.5 MiB in one
/// request by default; the key and the transaction's framing fit in the rest).
pub const CHUNK: usize = 1 << 20;
/// How many keys one read asks for. A commit is usually a few hundred bytes to a few kB, so a resume reads a
/// segment of 50,000 records in a few hundred reads; a page of commits of `CHUNK` bytes each (a burst larger than
/// etcd takes in one request) is the most one answer may hold.
const PAGE: i64 = 256;
/// How long a reader with no election (`baton replay`) asks etcd again before it gives up.
const READ_PATIENCE: Duration = Duration::from_secs(10);

/// A write refused because another coordinator holds the election: nothing was written, and this one acts no more.
#[derive(Debug)]
pub struct Fenced(pub String);

impl std::fmt::Display for Fenced {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Fenced {}

/// A journal in etcd, written by the coordinator that holds `fence`.
pub struct Etcd {
    link: Link,
    fence: Fence,
    keys: Keys,
    /// `etcd://…/PREFIX`.
    place: String,
    /// The last segment, which commits go to, and the number of its next commit.
    number: u64,
    seq: u64,
    keep: Keep,
}

/// The journal's keys under `PREFIX/journal/`.
#[derive(Clone)]
struct Keys {
    root: String,
}

impl Keys {
    fn of(election: &Election) -> Keys {
        Keys { root: format!("{}/journal/", election.prefix) }
    }
    fn header(&self) -> String {
        format!("{}header", self.root)
    }
    fn head(&self) -> String {
        format!("{}head", self.root)
    }
    fn segments(&self) -> String {
        format!("{}s/", self.root)
    }
    fn segment(&self, n: u64) -> String {
        format!("{}s/{n:010}/", self.root)
    }
    fn chunk(&self, n: u64, i: usize) -> String {
        format!("{}a/{i:06}", self.segment(n))
    }
    fn commit(&self, n: u64, seq: u64) -> String {
        format!("{}c/{seq:016}", self.segment(n))
    }
}

/// The first key after every key that begins with `prefix` (etcd's range end for a prefix).
fn after(prefix: &str) -> Vec<u8> {
    let mut end = prefix.as_bytes().to_vec();
    while let Some(last) = end.pop() {
        if last < 0xff {
            end.push(last + 1);
            return end;
        }
    }
    vec![0]
}

/// Opens the journal of `election` for the coordinator that holds `fence`: what a crash left of a segment that was
/// being started (after `head`) is deleted; the header and the last segment are read.
pub fn open(election: &Election, fence: Fence) -> anyhow::Result<Opened<Etcd>> {
    let link = Link::start(election, fence.lease_s)?;
    let keys = Keys::of(election);
    let (k, f) = (keys.clone(), fence.clone());
    let (header, number, last) = link.call(move |client| async move {
        let header = read_header(&client, &k, Some(&f)).await?;
        let number = read_head(&client, &k, Some(&f)).await?;
        let leftovers =
            TxnOp::delete(k.segment(number + 1), Some(DeleteOptions::new().with_range(after(&k.segments()))));
        write(&client, &f, vec![leftovers], "a segment a crash left unfinished").await?;
        let last = read_segment(&client, &k, number, Some(&f)).await?;
        Ok((header, number, last))
    })?;
    let (last, commits) = last;
    let store = Etcd { link, fence, keys, place: election.to_string(), number, seq: commits, keep: Keep::All };
    Ok(Opened { store, header, snapshot: last.snapshot, records: last.records })
}

/// The journal of `election` as it stands, read without writing anything: its header and every segment it keeps,
/// oldest first (`baton replay`).
pub fn read_only(election: &Election) -> anyhow::Result<(Option<JournalHeader>, Vec<Segment>)> {
    let link = Link::start(election, 2)?;
    let keys = Keys::of(election);
    link.call(move |client| async move {
        let header = read_header(&client, &keys, None).await?;
        let head = read_head(&client, &keys, None).await?;
        Ok((header, kept_segments(&client, &keys, head, None).await?))
    })
}

/// Every segment the journal keeps, from the oldest to `head`, read whole. One missing between them, or one after
/// the first without its snapshot, is damage.
async fn kept_segments(client: &Client, keys: &Keys, head: u64, fence: Option<&Fence>) -> anyhow::Result<Vec<Segment>> {
    let first = ask(fence, "the journal's oldest segment", || {
        let mut kv = client.kv_client();
        let options = GetOptions::new().with_range(after(&keys.segments())).with_limit(1).with_keys_only();
        let from = keys.segments();
        async move { kv.get(from, Some(options)).await }
    })
    .await?;
    let oldest = match first.kvs().first() {
        Some(kv) => segment_of(keys, kv.key())?.min(head),
        None => head,
    };
    let mut segments = Vec::new();
    for n in oldest..=head {
        let (segment, commits) = read_segment(client, keys, n, fence).await?;
        if n > 0 && segment.snapshot.is_none() {
            bail!("the journal's segment {n} is missing or has no snapshot ({commits} commits), and segment {head} is its last");
        }
        segments.push(segment);
    }
    Ok(segments)
}

/// The number of the segment a key under `s/` belongs to.
fn segment_of(keys: &Keys, key: &[u8]) -> anyhow::Result<u64> {
    let rest = key.strip_prefix(keys.segments().as_bytes()).unwrap_or_default();
    std::str::from_utf8(rest.get(..10).unwrap_or_default())
        .ok()
        .and_then(|n| n.parse().ok())
        .ok_or_else(|| anyhow!("the journal holds a key it did not write: {}", String::from_utf8_lossy(key)))
}

impl Etcd {
    /// `etcd://…/PREFIX (segment N)`, as messages show the journal.
    pub fn shown(&self) -> String {
        format!("{} (segment {})", self.place, self.number)
    }

    pub fn number(&self) -> u64 {
        self.number
    }

    pub fn keep(&mut self, keep: Keep) {
        self.keep = keep;
    }

    /// Writes the header of a new run before anything else.
    pub fn write_header(&mut self, header: &JournalHeader) -> anyhow::Result<()> {
        assert_eq!(header.format, JOURNAL_FORMAT);
        let json = serde_json::to_vec(header)?;
        let (k, f) = (self.keys.clone(), self.fence.clone());
        self.link.call(move |client| async move {
            write(&client, &f, vec![TxnOp::put(k.header(), json, None)], "the run's header").await
        })
    }

    /// Every segment the journal keeps, oldest first, read whole.
    pub fn segments(&self) -> anyhow::Result<Vec<Segment>> {
        let (k, f, last) = (self.keys.clone(), self.fence.clone(), self.number);
        self.link.call(move |client| async move { kept_segments(&client, &k, last, Some(&f)).await })
    }

    /// Appends the records of `batches`, in values of at most `CHUNK` bytes, each a transaction of its own.
    pub(super) fn append(&mut self, batches: &[Vec<Vec<u8>>]) -> anyhow::Result<()> {
        for value in commit_values(batches)? {
            let key = self.keys.commit(self.number, self.seq);
            let f = self.fence.clone();
            self.link.call(move |client| async move {
                write(&client, &f, vec![TxnOp::put(key, value, None)], "a commit of the journal").await
            })?;
            self.seq += 1;
        }
        Ok(())
    }

    /// Starts the next segment with `snapshot`, in chunks; then moves `head` to it and deletes the segments beyond
    /// `keep` in one transaction. Until then the journal goes on in the segment it was in.
    pub(super) fn start_segment(&mut self, snapshot: &[u8]) -> anyhow::Result<()> {
        let n = self.number + 1;
        let (k, f, keep) = (self.keys.clone(), self.fence.clone(), self.keep);
        let chunks: Vec<Vec<u8>> = snapshot.chunks(CHUNK).map(<[u8]>::to_vec).collect();
        self.link.call(move |client| async move {
            // What an earlier try left of this segment first (etcd takes no put and delete of one key in a
            // transaction).
            let earlier = TxnOp::delete(k.segment(n), Some(DeleteOptions::new().with_prefix()));
            write(&client, &f, vec![earlier], "what an earlier snapshot left").await?;
            for (i, chunk) in chunks.into_iter().enumerate() {
                write(&client, &f, vec![TxnOp::put(k.chunk(n, i), chunk, None)], "a chunk of a snapshot").await?;
            }
            let mut ops = vec![TxnOp::put(k.head(), n.to_string(), None)];
            if let Keep::Last(last) = keep {
                let oldest = n.saturating_sub(u64::from(last) - 1);
                if oldest > 0 {
                    let older = DeleteOptions::new().with_range(k.segment(oldest));
                    ops.push(TxnOp::delete(k.segments(), Some(older)));
                }
            }
            write(&client, &f, ops, "the journal's head").await
        })?;
        self.number = n;
        self.seq = 0;
        Ok(())
    }
}

/// The values a commit of `batches` puts in etcd, in order: its records framed, at most `CHUNK` bytes each.
fn commit_values(batches: &[Vec<Vec<u8>>]) -> anyhow::Result<Vec<Vec<u8>>> {
    let mut values: Vec<Vec<u8>> = Vec::new();
    for record in batches.iter().flatten() {
        if record.len() + 4 > CHUNK {
            bail!("a record of {} bytes is more than etcd takes in one request ({CHUNK} bytes)", record.len());
        }
        if values.last().is_none_or(|v| v.len() + 4 + record.len() > CHUNK) {
            values.push(Vec::new());
        }
        let value = values.last_mut().expect("one at least");
        value.extend_from_slice(&(record.len() as u32).to_le_bytes());
        value.extend_from_slice(record);
    }
    Ok(values)
}

/// Asks etcd with `request` until it answers: a member that is down, or does not answer within the fence's
/// patience, is left for another. A writer gives up once it no longer acts (`Fenced`); a reader after
/// `READ_PATIENCE`. A request etcd refuses for what it is fails at once.
async fn ask<T, F, Fut>(fence: Option<&Fence>, what: &str, mut request: F) -> anyhow::Result<T>
where
    F: FnMut() -> Fut,
    Fut: Future<Output = Result<T, etcd_client::Error>>,
{
    let started = Instant::now();
    let patience = fence.map_or(READ_PATIENCE / 4, |f| f.patience);
    let mut last = String::from("no answer");
    loop {
        match fence {
            Some(f) if !f.acting() => {
                return Err(Fenced(format!("stopped writing {what} to etcd: this coordinator acts no more")).into())
            }
            None if started.elapsed() > READ_PATIENCE => {
                bail!("etcd did not answer for {what} within {} s: {last}", READ_PATIENCE.as_secs())
            }
            _ => {}
        }
        match tokio::time::timeout(patience, request()).await {
            Ok(Ok(answer)) => return Ok(answer),
            Ok(Err(e)) if refused(&e) => return Err(anyhow!("etcd refused {what}: {e}")),
            Ok(Err(e)) => last = e.to_string(),
            Err(_) => last = format!("no answer within {} ms", patience.as_millis()),
        }
        tokio::time::sleep(RETRY).await;
    }
}

/// Writes `ops` in one transaction that holds only while `fence`'s leadership key is the one its term made. A
/// transaction etcd did not apply for that reason deposes this coordinator.
async fn write(client: &Client, fence: &Fence, ops: Vec<TxnOp>, what: &str) -> anyhow::Result<()> {
    let txn = Txn::new()
        .when([Compare::create_revision(fence.key.clone(), CompareOp::Equal, fence.term as i64)])
        .and_then(ops);
    let answer = ask(Some(fence), what, || {
        let (mut kv, txn) = (client.kv_client(), txn.clone());
        async move { kv.txn(txn).await }
    })
    .await?;
    if !answer.succeeded() {
        let why = format!(
            "etcd refused {what}: this coordinator's term {} is over (its leadership key is gone or another's)",
            fence.term
        );
        fence.lose(why.clone());
        return Err(Fenced(why).into());
    }
    Ok(())
}

async fn read_header(client: &Client, keys: &Keys, fence: Option<&Fence>) -> anyhow::Result<Option<JournalHeader>> {
    let key = keys.header();
    let got = ask(fence, "the journal's header", || {
        let (mut kv, key) = (client.kv_client(), key.clone());
        async move { kv.get(key, None).await }
    })
    .await?;
    got.kvs()
        .first()
        .map(|kv| serde_json::from_slice(kv.value()).map_err(|e| anyhow!("its header is malformed: {e}")))
        .transpose()
}

async fn read_head(client: &Client, keys: &Keys, fence: Option<&Fence>) -> anyhow::Result<u64> {
    let key = keys.head();
    let got = ask(fence, "the journal's head", || {
        let (mut kv, key) = (client.kv_client(), key.clone());
        async move { kv.get(key, None).await }
    })
    .await?;
    match got.kvs().first() {
        None => Ok(0),
        Some(kv) => std::str::from_utf8(kv.value())
            .ok()
            .and_then(|n| n.parse().ok())
            .ok_or_else(|| anyhow!("its head `{}` is not a segment's number", String::from_utf8_lossy(kv.value()))),
    }
}

/// Segment `n`, read whole, a page of keys at a time; and how many commits it holds. A commit missing between
/// two others, or a chunk of its snapshot, is damage.
async fn read_segment(client: &Client, keys: &Keys, n: u64, fence: Option<&Fence>) -> anyhow::Result<(Segment, u64)> {
    let prefix = keys.segment(n);
    let (end, mut from) = (after(&prefix), prefix.clone().into_bytes());
    let (mut chunks, mut commits, mut records) = (Vec::<Vec<u8>>::new(), 0u64, Vec::new());
    let cannot = || format!("cannot read the journal's segment {n}");
    loop {
        let options = GetOptions::new().with_range(end.clone()).with_limit(PAGE);
        let got = ask(fence, "a segment of the journal", || {
            let kv: KvClient = client.kv_client().max_decoding_message_size(CHUNK * (PAGE as usize + 1));
            let (mut kv, from, options) = (kv, from.clone(), options.clone());
            async move { kv.get(from, Some(options)).await }
        })
        .await?;
        for kv in got.kvs() {
            let name = std::str::from_utf8(&kv.key()[prefix.len()..]).unwrap_or_default();
            let number = |digits: &str| digits.parse::<u64>().ok();
            match name.split_once('/') {
                Some(("a", i)) if number(i) == Some(chunks.len() as u64) => chunks.push(kv.value().to_vec()),
                Some(("c", seq)) if number(seq) == Some(commits) => {
                    records.extend(framed(kv.value()).with_context(|| format!("{}: commit {commits}", cannot()))?);
                    commits += 1;
                }
                _ => bail!("{}: its key `{name}` is out of place (a chunk or a commit missing before it)", cannot()),
            }
        }
        match got.kvs().last() {
            Some(last) if got.more() => from = [last.key(), &[0]].concat(),
            _ => break,
        }
    }
    if n > 0 && chunks.is_empty() && commits > 0 {
        bail!("{}: it does not begin with its snapshot", cannot());
    }
    let snapshot = (!chunks.is_empty()).then(|| chunks.concat());
    Ok((Segment { number: n, snapshot, records }, commits))
}

/// The records of a commit's value.
fn framed(mut value: &[u8]) -> anyhow::Result<Vec<Vec<u8>>> {
    let mut out = Vec::new();
    while !value.is_empty() {
        let (len, rest) = value.split_at_checked(4).ok_or_else(|| anyhow!("a record's length is cut short"))?;
        let len = u32::from_le_bytes(len.try_into().expect("4 bytes")) as usize;
        let record = rest.get(..len).ok_or_else(|| anyhow!("a record of {len} bytes runs past its commit"))?;
        out.push(record.to_vec());
        value = &rest[len..];
    }
    Ok(out)
}

/// A call on the link's thread: given a client, it answers through its own channel.
type Call = Box<dyn FnOnce(Client) -> Pin<Box<dyn Future<Output = ()> + Send>> + Send>;

/// A connection to etcd on a thread and runtime of its own, so that the journal's writer thread (and a
/// coordinator opening its journal) can wait for etcd without a runtime of their own.
struct Link {
    calls: Option<tokio::sync::mpsc::UnboundedSender<Call>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Link {
    fn start(election: &Election, lease_s: u64) -> anyhow::Result<Link> {
        let options = crate::election::connect_options(election, lease_s)?;
        let election = election.clone();
        let shown = election.to_string();
        let (calls, mut asked) = tokio::sync::mpsc::unbounded_channel::<Call>();
        let (ready, connected) = std_mpsc::sync_channel::<Result<(), String>>(1);
        let thread = std::thread::Builder::new().name("baton-etcd".into()).spawn(move || {
            let runtime = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
                Ok(runtime) => runtime,
                Err(e) => return drop(ready.send(Err(e.to_string()))),
            };
            runtime.block_on(async move {
                let client = match crate::election::connect(&election, &election.endpoints, options, true).await {
                    Ok(client) => client,
                    Err(e) => return drop(ready.send(Err(e.to_string()))),
                };
                let _ = ready.send(Ok(()));
                while let Some(call) = asked.recv().await {
                    call(client.clone()).await;
                }
            });
        })?;
        let link = Link { calls: Some(calls), thread: Some(thread) };
        match connected.recv() {
            Ok(Ok(())) => Ok(link),
            Ok(Err(e)) => Err(anyhow!("cannot reach etcd at {shown} for the journal: {e}")),
            Err(_) => Err(anyhow!("cannot reach etcd at {shown} for the journal")),
        }
    }

    /// Runs `f` with the link's client and waits for its answer.
    fn call<T, F, Fut>(&self, f: F) -> anyhow::Result<T>
    where
        T: Send + 'static,
        F: FnOnce(Client) -> Fut + Send + 'static,
        Fut: Future<Output = anyhow::Result<T>> + Send + 'static,
    {
        let (tx, rx) = std_mpsc::sync_channel(1);
        let call: Call = Box::new(move |client| {
            Box::pin(async move {
                let _ = tx.send(f(client).await);
            })
        });
        let gone = || anyhow!("the journal's connection to etcd ended");
        self.calls.as_ref().ok_or_else(gone)?.send(call).map_err(|_| gone())?;
        rx.recv().map_err(|_| gone())?
    }
}

impl Drop for Link {
    fn drop(&mut self) {
        self.calls = None;
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{after, commit_values, framed, CHUNK};

    #[test]
    fn a_prefixs_range_ends_after_every_key_that_begins_with_it() {
        assert_eq!(after("p/journal/s/"), b"p/journal/s0".to_vec());
        assert_eq!(after("a\u{7f}"), b"a\x80".to_vec());
    }

    #[test]
    fn a_commits_records_are_read_back_and_a_cut_one_is_damage() {
        let mut value = Vec::new();
        for r in [&b"one"[..], b"", b"three"] {
            value.extend_from_slice(&(r.len() as u32).to_le_bytes());
            value.extend_from_slice(r);
        }
        assert_eq!(framed(&value).unwrap(), vec![b"one".to_vec(), Vec::new(), b"three".to_vec()]);
        assert!(framed(&value[..value.len() - 1]).is_err());
        assert!(framed(&value[..2]).is_err());
    }

    #[test]
    fn a_commit_larger_than_one_request_goes_in_values_of_at_most_a_chunk_in_order() {
        let records: Vec<Vec<u8>> = (0..40u8).map(|i| vec![i; 64 * 1024 + usize::from(i)]).collect();
        let batches = vec![records[..25].to_vec(), Vec::new(), records[25..].to_vec()];
        let values = commit_values(&batches).unwrap();
        assert!(values.len() >= 3, "{} values for {} bytes", values.len(), records.iter().map(Vec::len).sum::<usize>());
        assert!(values.iter().all(|v| !v.is_empty() && v.len() <= CHUNK));
        let back: Vec<Vec<u8>> = values.iter().flat_map(|v| framed(v).unwrap()).collect();
        assert_eq!(back, records);
        assert!(commit_values(&[]).unwrap().is_empty());
        let err = commit_values(&[vec![vec![0; CHUNK]]]).unwrap_err().to_string();
        assert!(err.contains("more than etcd takes in one request"), "{err}");
    }
}
