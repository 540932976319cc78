//! XML helpers: elements by local name in any TC6 namespace, ids and flags, positions, and the markup of a body blanked
//! in place so that ST in it keeps its offsets in the file.

use roxmltree::{Node, TextPos};

/// roxmltree ends its messages with ` at LINE:COL`, which the diagnostic header already says.
pub(super) fn strip_position(message: &str) -> &str {
    match message.rfind(" at ") {
        Some(i) if message[i + 4..].chars().all(|c| c.is_ascii_digit() || c == ':') => &message[..i],
        _ => message,
    }
}

/// The byte offset of a 1-based line and character column.
pub(super) fn offset_of(src: &str, pos: TextPos) -> usize {
    let mut line_start = 0;
    for _ in 1..pos.row {
        match src[line_start..].find('\n') {
            Some(i) => line_start += i + 1,
            None => return src.len(),
        }
    }
    let line = &src[line_start..];
    line_start + line.char_indices().nth(pos.col.saturating_sub(1) as usize).map_or(line.len(), |(i, _)| i)
}

pub(super) fn is(n: &Node, name: &str) -> bool {
    n.is_element() && n.tag_name().name() == name
}

pub(super) fn child<'a, 'i>(n: Node<'a, 'i>, name: &str) -> Option<Node<'a, 'i>> {
    n.children().find(|c| is(c, name))
}

pub(super) fn children<'a, 'i: 'a>(n: Node<'a, 'i>, name: &'a str) -> impl Iterator<Item = Node<'a, 'i>> + 'a {
    n.children().filter(move |c| is(c, name))
}

/// An element's `localId`, where it is a number (`Reader::elements` reports it where it is not).
pub(super) fn local_id(n: Node) -> Option<u64> {
    n.attribute("localId")?.trim().parse().ok()
}

pub(super) fn flag(n: Node, attr: &str) -> bool {
    matches!(n.attribute(attr), Some("true" | "1"))
}

/// The text of an element with markup blanked out and entities decoded, and how to find each of its bytes in the
/// file: a tag, a comment and CDATA delimiters become spaces (newlines kept) so that offsets stay; an entity
/// becomes its character, which shortens the text (padding it would split `&gt;=`), and each one is noted.
pub(super) struct BodyText {
    pub(super) text: String,
    /// (offset in `text` after an entity, bytes the text is shorter than the file from there on).
    pub(super) shifts: Vec<(usize, usize)>,
}

impl BodyText {
    /// The file offset (relative to where the text starts) of offset `at` of the text.
    pub(super) fn raw(&self, at: usize) -> usize {
        let i = self.shifts.partition_point(|&(pos, _)| pos <= at);
        at + if i == 0 { 0 } else { self.shifts[i - 1].1 }
    }
}

pub(super) fn blank_markup(raw: &str) -> BodyText {
    let mut out = String::with_capacity(raw.len());
    let mut shifts = Vec::new();
    let mut rest = raw;
    while let Some(c) = rest.chars().next() {
        if let Some(inner) = rest.strip_prefix("<![CDATA[") {
            out.push_str("         ");
            let end = inner.find("]]>").unwrap_or(inner.len());
            out.push_str(&inner[..end]);
            rest = &inner[end..];
            if let Some(r) = rest.strip_prefix("]]>") {
                out.push_str("   ");
                rest = r;
            }
        } else if rest.starts_with("<!--") {
            let end = rest.find("-->").map_or(rest.len(), |i| i + 3);
            blank_bytes(&mut out, &rest[..end]);
            rest = &rest[end..];
        } else if c == '<' {
            let end = rest.find('>').map_or(rest.len(), |i| i + 1);
            blank_bytes(&mut out, &rest[..end]);
            rest = &rest[end..];
        } else if c == '&' {
            let end = rest.find(';').filter(|&i| i <= 10);
            match end.and_then(|i| Some((i, entity(&rest[1..i])?))) {
                Some((i, ch)) => {
                    out.push(ch);
                    let extra = shifts.last().map_or(0, |&(_, e)| e) + (i + 1 - ch.len_utf8());
                    shifts.push((out.len(), extra));
                    rest = &rest[i + 1..];
                }
                None => {
                    out.push('&');
                    rest = &rest[1..];
                }
            }
        } else {
            out.push(c);
            rest = &rest[c.len_utf8()..];
        }
    }
    BodyText { text: out, shifts }
}

/// The name of the type a `<type>`'s element stands for: a derived type's name, `STRING[n]` for a string with a
/// length, the element's name in capitals for an elementary type; `None` for an unnamed derived type or a length
/// that is no number.
pub(super) fn type_name(t: Node) -> Option<String> {
    match t.tag_name().name() {
        "derived" => Some(t.attribute("name")?.to_string()),
        "string" => match t.attribute("length") {
            Some(n) => {
                let n: usize = n.trim().parse().ok()?;
                (1..=crate::limits::STRING_LENGTH_MAX).contains(&n).then(|| format!("STRING[{n}]"))
            }
            None => Some("STRING".to_string()),
        },
        other => Some(other.to_ascii_uppercase()),
    }
}

/// Spaces for every byte of `s` but newlines, so that offsets and lines stay as they were.
pub(super) fn blank_bytes(out: &mut String, s: &str) {
    out.extend(s.bytes().map(|b| if b == b'\n' { '\n' } else { ' ' }));
}

pub(super) fn entity(name: &str) -> Option<char> {
    Some(match name {
        "lt" => '<',
        "gt" => '>',
        "amp" => '&',
        "quot" => '"',
        "apos" => '\'',
        _ => {
            let code = match name.strip_prefix("#x").or_else(|| name.strip_prefix("#X")) {
                Some(hex) => u32::from_str_radix(hex, 16).ok()?,
                None => name.strip_prefix('#')?.parse().ok()?,
            };
            char::from_u32(code)?
        }
    })
}
