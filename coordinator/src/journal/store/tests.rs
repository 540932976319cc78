use std::sync::Arc;

use baton_proto::cluster::wire::{ChartHash, RunId};

use crate::journal::{Deliver, Outgoing};

use super::*;
use crate::journal::{Keep, Store};

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
        let written = contents(&bytes, 0).map_err(|e| e.to_string())?.records;
        for m in messages {
            // Each message carries the record that led to it.
            if !written.contains(&m.payload) {
                return Err(format!("{} left before its record {:?} was written", m.key, m.payload));
            }
            seen.lock().unwrap().push(m.key);
        }
        Ok(())
    });
    let mut writer = Store::from(opened.store).start_writer(Some(deliver));
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
    let mut writer = Store::from(opened.store).start_writer(Some(deliver));
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
    let mut writer = Store::from(opened.store).start_writer(None);
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
/// Each record in a commit of its own (the store's, without the writer's grouping), so that where each stands is
/// known.
fn written(dir: &Path, n: u8) -> Vec<u8> {
    let mut opened = open(dir).unwrap();
    opened.store.write_header(&header()).unwrap();
    for b in 0..n {
        opened.store.append(&[vec![vec![b; 3]]], &mut Vec::new()).unwrap();
    }
    opened.store.trim();
    drop(opened);
    std::fs::read(dir.join(FILE_NAME)).unwrap()
}

/// Batches, then a snapshot, then more, twice: each snapshot starts a segment with the header and itself,
/// the records after it go there, a resume reads only the last segment, and a replay reads them all.
#[tokio::test]
async fn a_snapshot_starts_a_segment_and_a_resume_reads_only_the_last() {
    let dir = tempfile::tempdir().unwrap();
    let mut opened = open(dir.path()).unwrap();
    opened.store.write_header(&header()).unwrap();
    let mut writer = Store::from(opened.store).start_writer(None);
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
    let mut writer = Store::from(opened.store).start_writer(None);
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

/// The frames of a commit `seq` at byte `at`, as the store writes it.
fn commit_bytes(seq: u64, at: usize, records: &[&[u8]]) -> Vec<u8> {
    let mut out = Vec::new();
    segment::commit(&mut out, seq, at as u64, records.iter().map(|r| (KIND_RECORD, *r)));
    out
}

#[tokio::test]
async fn a_torn_last_commit_is_cut_off_and_the_journal_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    let whole = written(dir.path(), 5);
    // A crash in the middle of the seventh commit (the header's is the first): part of it reached the disk.
    let mut torn = whole.clone();
    torn.extend_from_slice(&commit_bytes(6, whole.len(), &[&[9, 9, 9, 9]])[..20]);
    std::fs::write(dir.path().join(FILE_NAME), &torn).unwrap();
    // A reader leaves it as it is.
    let (_, segments) = read_only(dir.path()).unwrap();
    assert_eq!(segments[0].records.len(), 5);
    assert_eq!(std::fs::read(dir.path().join(FILE_NAME)).unwrap(), torn, "a reader never writes");
    let again = open(dir.path()).unwrap();
    assert_eq!(again.records, (0..5u8).map(|b| vec![b; 3]).collect::<Vec<_>>());
    assert_eq!(std::fs::metadata(dir.path().join(FILE_NAME)).unwrap().len(), whole.len() as u64);
    // What comes next follows the five, and reads back.
    let mut writer = Store::from(again.store).start_writer(None);
    writer.write(vec![vec![7]], Vec::new()).unwrap();
    writer.sync().await.unwrap();
    drop(writer);
    assert_eq!(open(dir.path()).unwrap().records.last(), Some(&vec![7]));
}

/// A segment is allocated ahead of its records while it is written (so that a commit does not grow the file),
/// and a crash leaves that space behind, zeros, perhaps after a torn commit: the records end there, and opening
/// the journal cuts the rest off. Closed, the segment keeps its records alone.
#[tokio::test]
async fn space_allocated_ahead_and_a_torn_commit_in_it_end_the_records() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(FILE_NAME);
    let mut opened = open(dir.path()).unwrap();
    opened.store.write_header(&header()).unwrap();
    let mut writer = Store::from(opened.store).start_writer(None);
    for b in 0..5u8 {
        writer.write(vec![vec![b; 3]], Vec::new()).unwrap();
    }
    writer.sync().await.unwrap();
    assert!(std::fs::metadata(&path).unwrap().len() >= ALLOCATE_BYTES, "allocated ahead while written");
    drop(writer);
    let mut bytes = std::fs::read(&path).unwrap();
    let whole = bytes.len();
    let scan = segment::scan(&bytes).unwrap();
    assert_eq!((scan.end, scan.tail), (whole, segment::Tail::Clean), "trimmed once closed");
    // A crash: allocated space after the records, and in it the start of a commit that never finished.
    bytes.extend_from_slice(&commit_bytes(scan.commits, whole, &[&[7; 40]])[..20]);
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

/// Eight acknowledged commits, the length in the second record's commit damaged: the journal is refused where
/// the damage is — by a coordinator and by a reader — and neither changes a byte of it.
#[test]
fn damage_before_good_records_is_refused_not_cut_off() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(FILE_NAME);
    let mut bytes = written(dir.path(), 8);
    let first = MAGIC.len() + segment::HEAD + 5 + serde_json::to_vec(&header()).unwrap().len();
    let second = first + segment::HEAD + 5 + 3;
    // The commit's length (bytes 20..24 of its head), made to run past the end of the file.
    bytes[second + 22] = 0x7f;
    std::fs::write(&path, &bytes).unwrap();
    for err in [
        format!("{:#}", open(dir.path()).err().expect("refused")),
        format!("{:#}", read_only(dir.path()).err().expect("refused")),
    ] {
        assert!(err.contains(&format!("its commit 2 at byte {second} is damaged")), "{err}");
        assert!(err.contains("records 1 and later were acknowledged"), "{err}");
    }
    assert_eq!(std::fs::read(&path).unwrap(), bytes, "the journal is left as it was");
    // A file that is not a journal is refused too, and left as it was.
    std::fs::write(&path, b"PROGRAM p END_PROGRAM").unwrap();
    let err = format!("{:#}", open(dir.path()).err().expect("refused"));
    assert!(err.contains("not a Baton journal"), "{err}");
    assert_eq!(std::fs::read(&path).unwrap(), b"PROGRAM p END_PROGRAM");
}

/// The pages (`PAGE` bytes) where two images of a file differ, the shorter read as zeros beyond its end.
fn pages_differing(before: &[u8], after: &[u8]) -> Vec<usize> {
    let len = before.len().max(after.len());
    (0..len.div_ceil(PAGE))
        .filter(|p| {
            let range = p * PAGE..((p + 1) * PAGE).min(len);
            range.clone().any(|i| before.get(i).copied().unwrap_or(0) != after.get(i).copied().unwrap_or(0))
        })
        .collect()
}

const PAGE: usize = 4096;

/// The subsets of `n` pages a crash may have left written: every one of up to 10 pages; beyond, each page alone,
/// each left out alone, none, all, and 200 drawn at random (a fixed seed).
fn subsets(n: usize) -> Vec<Vec<bool>> {
    if n <= 10 {
        return (0u32..1 << n).map(|m| (0..n).map(|i| m & (1 << i) != 0).collect()).collect();
    }
    let mut out = vec![vec![false; n], vec![true; n]];
    for i in 0..n {
        out.push((0..n).map(|j| j == i).collect());
        out.push((0..n).map(|j| j != i).collect());
    }
    let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
    for _ in 0..200 {
        out.push(
            (0..n)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    x & 1 == 1
                })
                .collect(),
        );
    }
    out
}

/// The disk a crash leaves: `before`, with the pages of `pages` that `written` says reached the disk from `after`.
fn crash_image(before: &[u8], after: &[u8], pages: &[usize], written: &[bool]) -> Vec<u8> {
    let mut image = before.to_vec();
    image.resize(after.len().max(before.len()), 0);
    for (p, _) in pages.iter().zip(written).filter(|(_, w)| **w) {
        let range = p * PAGE..((p + 1) * PAGE).min(after.len());
        image[range.clone()].copy_from_slice(&after[range]);
    }
    image
}

/// The ALICE / SQLite crash test of a real journal: its store writes a run's header, then commits of one record
/// to a commit of many pages, then a snapshot that starts a new segment, then more commits. For every commit, the
/// disk a crash in it leaves — the file before it with any subset of the pages it wrote — is recovered: exactly
/// the acknowledged records come back (and the commit's own only when every one of its pages was written), a reader
/// reads the same and writes nothing, and the journal goes on from there and reads back after a second opening.
#[test]
fn a_crash_at_any_write_keeps_every_acknowledged_record_and_nothing_torn() {
    let dir = tempfile::tempdir().unwrap();
    let mut opened = open(dir.path()).unwrap();
    opened.store.write_header(&header()).unwrap();
    let mut store = opened.store;
    let mut buffer = Vec::new();
    // Commits: a record, a few, one of many pages, one that crosses into space allocated on the way, small ones.
    let mut batches: Vec<Vec<Vec<u8>>> = vec![
        vec![vec![1; 10]],
        (0..5).map(|i| vec![i; 300]).collect(),
        vec![vec![0xaa; 7 * PAGE + 123]],
        vec![vec![0x55; 40]; 30],
        vec![vec![0; 2 * PAGE]],
    ];
    batches.extend((0..6u8).map(|k| vec![vec![k; 7 + 50 * k as usize]]));
    let segment_path = |store: &Files| store.path().to_path_buf();
    let mut acknowledged: Vec<Vec<u8>> = Vec::new();
    let (mut checked, mut total) = (0, 0);
    for (k, batch) in batches.iter().enumerate() {
        if k == 7 {
            // A snapshot starts segment 1: the new file is written apart and renamed; a crash before the rename
            // leaves a `.new` that is never read, and the old segment with every record.
            let junk = dir.path().join("journal-000001.log.new");
            std::fs::write(&junk, b"BATON-JOURNAL-2\npartial").unwrap();
            let image = std::fs::read(&store.path).unwrap();
            let reopened = open_copy(dir.path(), &store.path, &image, store.number);
            assert!(reopened == acknowledged, "a crash while the next segment was being started");
            std::fs::remove_file(&junk).unwrap();
            store.start_segment(b"the snapshot").unwrap();
            acknowledged.clear();
        }
        let mut before = std::fs::read(segment_path(&store)).unwrap();
        store.append(std::slice::from_ref(batch), &mut buffer).unwrap();
        let mut after = std::fs::read(segment_path(&store)).unwrap();
        // Beyond a page after the commits, both are the zeros allocated ahead, in every crash: they read as the
        // end of the file does (`space_allocated_ahead_and_a_torn_commit_in_it_end_the_records`), and are left out.
        let limit = store.end as usize + PAGE;
        before.truncate(limit);
        after.truncate(limit);
        let pages = pages_differing(&before, &after);
        assert!(!pages.is_empty());
        for (i, written) in subsets(pages.len()).iter().enumerate() {
            total += 1;
            let image = crash_image(&before, &after, &pages, written);
            let mut expected = acknowledged.clone();
            if image == after {
                expected.extend(batch.iter().cloned());
            }
            let read =
                contents(&image, store.number).unwrap_or_else(|e| panic!("commit {k}, pages {written:?}: {e:#}"));
            let got = (read.records.len(), read.records == expected);
            assert_eq!(got, (expected.len(), true), "commit {k}, pages {written:?}");
            // Through the files, a sample: a coordinator's opening, a reader's, and the journal going on.
            if i % 3 == 0 || image == after {
                let opened = open_copy(dir.path(), &store.path, &image, store.number);
                assert!(opened == expected, "commit {k}, pages {written:?}: {} records", opened.len());
                checked += 1;
            }
        }
        acknowledged.extend(batch.iter().cloned());
    }
    // Each commit's pages, the large one's 8 of them in 256 ways: 2 images a page for the others.
    assert!(total >= 256 + 2 * 10 && checked * 3 >= total, "{total} crash images, {checked} of them opened");
}

/// Opens a copy of the journal in `dir` whose segment `path` (number `number`) holds `image`: the records a
/// coordinator gets. A reader gets the same and leaves the image as it was; the coordinator's journal then takes a
/// commit, and a second opening reads it after them.
fn open_copy(dir: &Path, path: &Path, image: &[u8], number: u64) -> Vec<Vec<u8>> {
    let copy = tempfile::tempdir().unwrap();
    for entry in std::fs::read_dir(dir).unwrap() {
        let entry = entry.unwrap();
        if entry.file_name() != LOCK_NAME {
            std::fs::copy(entry.path(), copy.path().join(entry.file_name())).unwrap();
        }
    }
    let name = path.file_name().unwrap();
    std::fs::write(copy.path().join(name), image).unwrap();
    let (_, segments) = read_only(copy.path()).unwrap();
    assert_eq!(std::fs::read(copy.path().join(name)).unwrap(), image, "a reader never writes");
    let read = segments.into_iter().find(|s| s.number == number).map(|s| s.records).unwrap_or_default();
    let mut opened = open(copy.path()).unwrap();
    assert!(opened.records == read, "a coordinator and a reader read the same");
    assert!(!copy.path().join("journal-000001.log.new").exists(), "a half-made segment is removed");
    opened.store.append(&[vec![b"after".to_vec()]], &mut Vec::new()).unwrap();
    drop(opened);
    let again = open(copy.path()).unwrap();
    assert!(again.records.split_last() == Some((&b"after".to_vec(), read.as_slice())), "the journal goes on");
    read
}
