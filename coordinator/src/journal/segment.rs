//! A journal segment's bytes: what a commit looks like on the disk, and how a segment is read back — which commits
//! are whole, where a crash cut the last one short, and where damage lies. Pure: bytes in, a verdict out.
//!
//! ```text
//! segment := MAGIC commit* zeros            (zeros: space allocated ahead of the commits)
//! commit  := head body
//! head    := "BTNC" seq:u64 at:u64 len:u32 body_crc:u32 head_crc:u32      32 bytes, little-endian
//! body    := frame*                          len bytes, CRC-32 body_crc
//! frame   := len:u32 kind:u8 payload         kind 0 the run's header (JSON), 1 a record, 2 a snapshot
//! ```
//!
//! A commit is what one `fdatasync` made durable: the run was told nothing of it before. Its head says where it
//! stands (`seq`, its number in the segment from 0; `at`, its byte offset) and how long its body is, and the head's
//! own CRC covers all of that — a damaged length is seen as damage, never followed into the wrong place.
//!
//! Reading stops at the first commit that is not whole. What that means depends on what follows it:
//!
//! - a whole commit somewhere after it: every commit was written only once the one before was durable, so the bad
//!   one had been acknowledged, and is **damage** — the segment is refused with the commit's place, never cut short;
//! - nothing whole after it: it is the last commit, which a crash cut short (**torn**) — its pages reach the disk
//!   in no promised order, so any mix of them and the zeros they overwrite may be there. Nobody was told it was
//!   durable; a writer cuts it off. (A last commit damaged after it was acknowledged looks the same, and is cut
//!   off too: no later commit vouches for it.)

/// The first bytes of a segment of this format.
pub const MAGIC: &[u8; 16] = b"BATON-JOURNAL-2\n";
/// The first bytes of a segment of the format before commits had heads of their own.
pub const MAGIC_1: &[u8; 16] = b"BATON-JOURNAL-1\n";
const TAG: &[u8; 4] = b"BTNC";
/// A commit's head.
pub const HEAD: usize = 32;
const FRAME_HEAD: usize = 5;
pub const KIND_HEADER: u8 = 0;
pub const KIND_RECORD: u8 = 1;
pub const KIND_SNAPSHOT: u8 = 2;
/// A commit longer than this is damage, not a batch of records or a snapshot.
pub const COMMIT_BYTES_MAX: usize = 1 << 30;

/// Appends the commit `seq` of frames `(kind, payload)`, to stand at byte `at` of its segment.
pub fn commit<'a>(out: &mut Vec<u8>, seq: u64, at: u64, frames: impl IntoIterator<Item = (u8, &'a [u8])>) {
    let start = out.len();
    out.extend_from_slice(&[0; HEAD]);
    for (kind, payload) in frames {
        out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
        out.push(kind);
        out.extend_from_slice(payload);
    }
    let len = out.len() - start - HEAD;
    assert!(len <= COMMIT_BYTES_MAX, "a commit of {len} bytes");
    let body_crc = crc32fast::hash(&out[start + HEAD..]);
    let head = &mut out[start..start + HEAD];
    head[0..4].copy_from_slice(TAG);
    head[4..12].copy_from_slice(&seq.to_le_bytes());
    head[12..20].copy_from_slice(&at.to_le_bytes());
    head[20..24].copy_from_slice(&(len as u32).to_le_bytes());
    head[24..28].copy_from_slice(&body_crc.to_le_bytes());
    let head_crc = crc32fast::hash(&head[..28]);
    head[28..32].copy_from_slice(&head_crc.to_le_bytes());
}

/// One frame of a whole commit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Frame<'a> {
    pub kind: u8,
    pub payload: &'a [u8],
}

/// The whole commits of a segment, and how it ends after them.
#[derive(Debug, PartialEq, Eq)]
pub struct Scan<'a> {
    /// The frames of the whole commits, in order, each with the number of the commit that holds it.
    pub frames: Vec<(u64, Frame<'a>)>,
    /// How many commits are whole.
    pub commits: u64,
    /// Where they end.
    pub end: usize,
    /// What follows them.
    pub tail: Tail,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Tail {
    /// The end of the file, or zeros (space allocated ahead).
    Clean,
    /// The last commit, cut short by a crash (or damaged with nothing after it): `bytes` from `end` on are not
    /// zeros.
    Torn { bytes: usize },
}

/// Why a segment cannot be read.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Damage {
    NotAJournal,
    /// A segment of the format before this one.
    Format1,
    /// Commit `seq` at byte `at` is not whole, and a whole commit follows it at byte `next`: it had been
    /// acknowledged. `records_before`: the records of the whole commits before it.
    Commit {
        seq: u64,
        at: usize,
        records_before: usize,
        next: usize,
    },
    /// Commit `seq` at byte `at` is whole, but its frames do not fill it.
    Malformed {
        seq: u64,
        at: usize,
    },
}

impl std::fmt::Display for Damage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Damage::NotAJournal => {
                write!(f, "it is not a Baton journal (it does not start with {:?})", show(MAGIC))
            }
            Damage::Format1 => write!(
                f,
                "it is a journal of an earlier Baton (it starts with {:?}, and this Baton writes {:?}): resume or \
                 replay it with the Baton that wrote it",
                show(MAGIC_1),
                show(MAGIC)
            ),
            Damage::Commit { seq, at, records_before, next } => write!(
                f,
                "its commit {seq} at byte {at} is damaged, and a whole commit follows it at byte {next}: records \
                 {records_before} and later were acknowledged and cannot be read. The journal is refused rather than \
                 cut short there; restore the folder from a copy, or give another --journal folder"
            ),
            Damage::Malformed { seq, at } => {
                write!(f, "its commit {seq} at byte {at} is whole, but its frames do not fill it")
            }
        }
    }
}

fn show(magic: &[u8]) -> String {
    String::from_utf8_lossy(magic).trim().to_string()
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    let mut x = [0u8; 8];
    x.copy_from_slice(&b[at..at + 8]);
    u64::from_le_bytes(x)
}

/// The body of the commit `seq` if a whole one stands at byte `at` of `bytes`.
fn whole_at(bytes: &[u8], at: usize, seq: Option<u64>) -> Option<(u64, &[u8])> {
    let head = bytes.get(at..at.checked_add(HEAD)?)?;
    if &head[0..4] != TAG || crc32fast::hash(&head[..28]) != u32_at(head, 28) {
        return None;
    }
    let (n, claimed_at, len) = (u64_at(head, 4), u64_at(head, 12), u32_at(head, 20) as usize);
    if claimed_at != at as u64 || seq.is_some_and(|s| s != n) || len > COMMIT_BYTES_MAX {
        return None;
    }
    let body = bytes.get(at + HEAD..at + HEAD + len)?;
    (crc32fast::hash(body) == u32_at(head, 24)).then_some((n, body))
}

/// The frames of a whole commit's body; `None` if they do not fill it exactly.
fn frames_of(body: &[u8]) -> Option<Vec<Frame<'_>>> {
    let mut out = Vec::new();
    let mut at = 0;
    while at < body.len() {
        let head = body.get(at..at + FRAME_HEAD)?;
        let len = u32_at(head, 0) as usize;
        let payload = body.get(at + FRAME_HEAD..(at + FRAME_HEAD).checked_add(len)?)?;
        out.push(Frame { kind: head[4], payload });
        at += FRAME_HEAD + len;
    }
    Some(out)
}

/// Reads a segment: its whole commits, and what follows them — or the damage that makes it unreadable.
pub fn scan(bytes: &[u8]) -> Result<Scan<'_>, Damage> {
    if bytes.starts_with(MAGIC_1) {
        return Err(Damage::Format1);
    }
    if !bytes.starts_with(MAGIC) {
        return Err(Damage::NotAJournal);
    }
    let mut out = Scan { frames: Vec::new(), commits: 0, end: MAGIC.len(), tail: Tail::Clean };
    let mut records = 0;
    loop {
        let at = out.end;
        if bytes[at..].iter().all(|b| *b == 0) {
            return Ok(out);
        }
        let Some((seq, body)) = whole_at(bytes, at, Some(out.commits)) else { break };
        let frames = frames_of(body).ok_or(Damage::Malformed { seq, at })?;
        records += frames.iter().filter(|f| f.kind == KIND_RECORD).count();
        out.frames.extend(frames.into_iter().map(|f| (seq, f)));
        out.commits += 1;
        out.end = at + HEAD + body.len();
    }
    // The commit at `end` is not whole. A whole one after it means it had been acknowledged.
    let at = out.end;
    let later = (at + 1..bytes.len().saturating_sub(HEAD - 1))
        .filter(|&p| bytes[p..p + 4] == *TAG)
        .find(|&p| whole_at(bytes, p, None).is_some_and(|(n, _)| n > out.commits));
    if let Some(next) = later {
        return Err(Damage::Commit { seq: out.commits, at, records_before: records, next });
    }
    let last = bytes.iter().rposition(|b| *b != 0).map_or(at, |i| i + 1);
    out.tail = Tail::Torn { bytes: last - at };
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A segment of `n` commits, the k-th holding `k + 1` records of `k + 3` bytes, and where each commit starts.
    fn segment(n: u64) -> (Vec<u8>, Vec<usize>) {
        let mut bytes = MAGIC.to_vec();
        let mut starts = Vec::new();
        for k in 0..n {
            starts.push(bytes.len());
            let payloads: Vec<Vec<u8>> = (0..=k).map(|i| vec![k as u8 + i as u8 + 1; k as usize + 3]).collect();
            let at = bytes.len() as u64;
            commit(&mut bytes, k, at, payloads.iter().map(|p| (KIND_RECORD, p.as_slice())));
        }
        (bytes, starts)
    }

    fn records(scan: &Scan) -> usize {
        scan.frames.iter().filter(|(_, f)| f.kind == KIND_RECORD).count()
    }

    #[test]
    fn whole_commits_read_back_and_zeros_after_them_end_the_segment() {
        let (mut bytes, _) = segment(5);
        let whole = bytes.len();
        let read = scan(&bytes).expect("whole");
        assert_eq!((read.commits, read.end, read.tail, records(&read)), (5, whole, Tail::Clean, 15));
        bytes.resize(whole + 10_000, 0);
        let read = scan(&bytes).expect("whole");
        assert_eq!((read.commits, read.end, read.tail), (5, whole, Tail::Clean));
        assert_eq!(scan(b"PROGRAM p END_PROGRAM"), Err(Damage::NotAJournal));
        assert_eq!(scan(b"BATON-JOURNAL-1\n\0\0\0"), Err(Damage::Format1));
    }

    /// Every single byte of every commit but the last, damaged, is refused at that commit — the length fields
    /// included, which a CRC of the body alone would not cover. A damaged byte of the last commit cuts it off.
    #[test]
    fn any_damaged_byte_before_the_last_commit_is_refused_where_it_is() {
        let (bytes, starts) = segment(8);
        let last = *starts.last().expect("commits");
        for i in MAGIC.len()..bytes.len() {
            for flip in [0x01u8, 0x80, 0xff] {
                let mut damaged = bytes.clone();
                damaged[i] ^= flip;
                let k = starts.iter().rposition(|&s| s <= i).expect("in a commit");
                let read = scan(&damaged);
                if i < last {
                    let before: usize = (0..k).map(|c| c + 1).sum();
                    assert!(
                        matches!(read, Err(Damage::Commit { seq, at, records_before, .. })
                            if seq == k as u64 && at == starts[k] && records_before == before),
                        "byte {i} ^ {flip:#x}: {read:?}"
                    );
                } else {
                    let read = read.expect("the last commit is cut off");
                    assert_eq!((read.commits, read.end), (7, last), "byte {i} ^ {flip:#x}");
                    assert!(matches!(read.tail, Tail::Torn { .. }));
                }
            }
        }
    }

    /// The last commit of a segment in zeroed space, torn at every page and sector boundary — any subset of its
    /// 512-byte sectors written, the rest still zeros: whatever reached the disk, the commits before it read back
    /// and it is cut off; only all of it reads as a commit.
    #[test]
    fn a_torn_last_commit_is_cut_off_whatever_part_of_it_was_written() {
        let (mut before, _) = segment(3);
        let at = before.len();
        // A last commit of a few sectors, starting inside a sector.
        let payload = vec![7u8; 2_000];
        let mut after = before.clone();
        commit(&mut after, 3, at as u64, [(KIND_RECORD, payload.as_slice())]);
        before.resize(after.len() + 512, 0);
        after.resize(before.len(), 0);
        let sectors: Vec<usize> = (at / 512..after.len().div_ceil(512)).collect();
        for subset in 0u32..(1 << sectors.len()) {
            let mut image = before.clone();
            for (i, s) in sectors.iter().enumerate() {
                if subset & (1 << i) != 0 {
                    let range = s * 512..((s + 1) * 512).min(image.len());
                    image[range.clone()].copy_from_slice(&after[range]);
                }
            }
            let read = scan(&image).unwrap_or_else(|d| panic!("sectors {subset:b}: refused: {d}"));
            if image == after {
                assert_eq!(read.commits, 4, "sectors {subset:b}");
            } else {
                assert_eq!((read.commits, read.end), (3, at), "sectors {subset:b}");
            }
        }
    }

    #[test]
    fn a_whole_commit_whose_frames_overrun_it_is_refused() {
        let mut bytes = MAGIC.to_vec();
        // A commit of one frame, then the frame's length raised and both CRCs made again, as a writer with that
        // bug would.
        let mut good = Vec::new();
        commit(&mut good, 0, MAGIC.len() as u64, [(KIND_RECORD, b"short".as_slice())]);
        good[HEAD..HEAD + 4].copy_from_slice(&100u32.to_le_bytes());
        let body_crc = crc32fast::hash(&good[HEAD..]);
        good[24..28].copy_from_slice(&body_crc.to_le_bytes());
        let head_crc = crc32fast::hash(&good[..28]);
        good[28..32].copy_from_slice(&head_crc.to_le_bytes());
        bytes.extend_from_slice(&good);
        assert_eq!(scan(&bytes), Err(Damage::Malformed { seq: 0, at: MAGIC.len() }));
    }
}
