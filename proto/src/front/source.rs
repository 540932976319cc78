//! A chart file's bytes to its text, as vendor tools write them: UTF-8 (with or without a byte-order mark),
//! UTF-16 with a byte-order mark, the encoding an XML declaration names (`encoding="ISO-8859-1"`), and, for a file
//! that is none of these, Windows-1252 — what CODESYS and TwinCAT exports and most Western PLC tools write, and a
//! superset of Latin-1's printable characters. Reading a file other than UTF-8 is said in a note at its place, so
//! that a user knows how the text was read; nothing is refused for its encoding alone.
//!
//! A file's bytes to text before anything reads it: UTF-8 (with or without a byte-order mark), UTF-16 with
//! a byte-order mark, an XML declaration's encoding, else Windows-1252 (what vendor tools write), said in a located
//! warning; past `SOURCE_BYTES_MAX` a file is refused before it is read whole (encoding_rs).

use encoding_rs::{Encoding, UTF_16BE, UTF_16LE, UTF_8, WINDOWS_1252};

use crate::limits::SOURCE_BYTES_MAX;

/// A file's text, and how it was read when that was not plain UTF-8.
#[derive(Clone, Debug, PartialEq)]
pub struct Decoded {
    pub text: String,
    pub note: Option<Note>,
}

/// How a file was read, at the place that made it so (the first byte that is not UTF-8, or the declaration):
/// a line and column of the file's text, from 1.
#[derive(Clone, Debug, PartialEq)]
pub struct Note {
    pub line: usize,
    pub col: usize,
    pub message: String,
}

#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SourceError {
    #[error("the file is {0} bytes, more than the {max} MiB a chart may be", max = SOURCE_BYTES_MAX >> 20)]
    TooLarge(u64),
}

/// Whether a file of `len` bytes may be read as a chart: checked before it is read.
pub fn check_size(len: u64) -> Result<(), SourceError> {
    if len > SOURCE_BYTES_MAX as u64 {
        return Err(SourceError::TooLarge(len));
    }
    Ok(())
}

/// Decodes a chart file (see the module's documentation).
pub fn decode(bytes: &[u8]) -> Result<Decoded, SourceError> {
    check_size(bytes.len() as u64)?;
    if let Some((encoding, bom)) = Encoding::for_bom(bytes) {
        let (text, _) = encoding.decode_without_bom_handling(&bytes[bom..]);
        let note = (encoding != UTF_8).then(|| Note {
            line: 1,
            col: 1,
            message: format!("read as {}, as its byte-order mark says", encoding.name()),
        });
        return Ok(Decoded { text: text.into_owned(), note });
    }
    // An XML declaration that names an encoding other than UTF-8 is taken at its word (the declaration itself is
    // ASCII in every encoding it can name, but for UTF-16, which needs the mark above).
    if let Some((label, at)) = declared_encoding(bytes) {
        if let Some(encoding) = Encoding::for_label(label.as_bytes()).filter(|e| *e != UTF_8 && !is_utf16(e)) {
            let (text, _, _) = encoding.decode(bytes);
            let (line, col) = line_col(bytes, at);
            let message = format!("read as {}, as its XML declaration says (`encoding=\"{label}\"`)", encoding.name());
            return Ok(Decoded { text: text.into_owned(), note: Some(Note { line, col, message }) });
        }
    }
    match std::str::from_utf8(bytes) {
        Ok(text) => Ok(Decoded { text: text.to_string(), note: None }),
        Err(e) => {
            let at = e.valid_up_to();
            let (text, _, _) = WINDOWS_1252.decode(bytes);
            let (line, col) = line_col(bytes, at);
            let message = format!(
                "the file is not UTF-8 (byte 0x{:02X} here): read as Windows-1252 (Latin-1), as PLC tools write it; \
                 save it as UTF-8 to be sure of its characters",
                bytes[at]
            );
            Ok(Decoded { text: text.into_owned(), note: Some(Note { line, col, message }) })
        }
    }
}

fn is_utf16(e: &&'static Encoding) -> bool {
    *e == UTF_16LE || *e == UTF_16BE
}

/// The label of `<?xml … encoding="…"?>` at the start of the file, and where it stands.
fn declared_encoding(bytes: &[u8]) -> Option<(String, usize)> {
    let head = &bytes[..bytes.len().min(512)];
    if !head.starts_with(b"<?xml") {
        return None;
    }
    let end = head.windows(2).position(|w| w == b"?>")?;
    let decl = std::str::from_utf8(&head[..end]).ok()?;
    let at = decl.find("encoding")?;
    let rest = decl[at + "encoding".len()..].trim_start().strip_prefix('=')?.trim_start();
    let quote = rest.chars().next().filter(|c| *c == '"' || *c == '\'')?;
    let label = rest[1..].split(quote).next()?;
    Some((label.to_string(), at))
}

/// The line and column (from 1, in characters of ASCII-compatible text) of byte `at`.
fn line_col(bytes: &[u8], at: usize) -> (usize, usize) {
    let before = &bytes[..at.min(bytes.len())];
    let line = before.iter().filter(|&&b| b == b'\n').count() + 1;
    let start = before.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
    (line, at - start + 1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn files_are_read_as_their_tools_wrote_them() {
        let plain = decode("PROGRAM P END_PROGRAM".as_bytes()).expect("read");
        assert_eq!((plain.text.as_str(), plain.note), ("PROGRAM P END_PROGRAM", None));
        let bom = decode(b"\xEF\xBB\xBF(* \xC3\xA0 *)").expect("read");
        assert_eq!((bom.text.as_str(), bom.note), ("(* \u{e0} *)", None));
        // A Latin-1 `à` in a comment on line 2: read, and said where.
        let latin = decode(b"PROGRAM P\n(* d\xE9j\xE0 *)\nEND_PROGRAM").expect("read");
        assert_eq!(latin.text, "PROGRAM P\n(* d\u{e9}j\u{e0} *)\nEND_PROGRAM");
        let note = latin.note.expect("a note");
        assert_eq!((note.line, note.col), (2, 5));
        assert!(note.message.contains("0xE9") && note.message.contains("Windows-1252"), "{}", note.message);
        // Windows-1252's own characters (0x80-0x9F): the euro sign and curly quotes.
        assert_eq!(decode(b"(* \x80 \x93x\x94 *)").expect("read").text, "(* \u{20ac} \u{201c}x\u{201d} *)");
        // UTF-16 with its mark, either way round.
        let utf16: Vec<u8> =
            [0xFF, 0xFE].into_iter().chain("<?xml?>\u{e0}".encode_utf16().flat_map(|u| u.to_le_bytes())).collect();
        assert_eq!(decode(&utf16).expect("read").text, "<?xml?>\u{e0}");
        let be: Vec<u8> = [0xFE, 0xFF].into_iter().chain("ab".encode_utf16().flat_map(|u| u.to_be_bytes())).collect();
        assert_eq!(decode(&be).expect("read").text, "ab");
        // An XML declaration's encoding is followed.
        let declared =
            decode(b"<?xml version=\"1.0\" encoding=\"ISO-8859-1\"?>\n<project>\xE0</project>").expect("read");
        assert_eq!(declared.text, "<?xml version=\"1.0\" encoding=\"ISO-8859-1\"?>\n<project>\u{e0}</project>");
        assert!(declared.note.is_some_and(|n| n.message.contains("ISO-8859-1")));
        assert_eq!(check_size(SOURCE_BYTES_MAX as u64 + 1), Err(SourceError::TooLarge(SOURCE_BYTES_MAX as u64 + 1)));
    }
}
