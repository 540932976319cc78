//! Source spans and diagnostics, rendered as `PATH:LINE:COL: error: message` with the offending text quoted.
//!
//! `Span`, `Diagnostic`, and the rustc-style rendering `PATH:LINE:COL: error: message`.

use std::fmt::Write as _;

/// A byte range in one source text.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Span {
    pub start: u32,
    pub end: u32,
}

impl Span {
    pub fn new(start: usize, end: usize) -> Span {
        // Sources are limited to `limits::SOURCE_BYTES_MAX`, far below u32::MAX.
        Span { start: start as u32, end: end as u32 }
    }

    /// The smallest span covering both.
    pub fn to(self, other: Span) -> Span {
        Span { start: self.start.min(other.start), end: self.end.max(other.end) }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Severity {
    Warning,
    Error,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Diagnostic {
    pub severity: Severity,
    pub span: Span,
    pub message: String,
}

impl Diagnostic {
    pub fn error(span: Span, message: impl Into<String>) -> Diagnostic {
        Diagnostic { severity: Severity::Error, span, message: message.into() }
    }

    pub fn warning(span: Span, message: impl Into<String>) -> Diagnostic {
        Diagnostic { severity: Severity::Warning, span, message: message.into() }
    }

    pub fn is_error(&self) -> bool {
        self.severity == Severity::Error
    }
}

/// Maps byte offsets to 1-based line and column numbers (columns count characters).
pub struct LineIndex<'a> {
    text: &'a str,
    line_starts: Vec<usize>,
}

impl<'a> LineIndex<'a> {
    pub fn new(text: &'a str) -> LineIndex<'a> {
        // A byte-order mark is not a column of the first line.
        let mut line_starts = vec![if text.starts_with('\u{feff}') { 3 } else { 0 }];
        line_starts.extend(text.match_indices('\n').map(|(i, _)| i + 1));
        LineIndex { text, line_starts }
    }

    /// 1-based line and column of a byte offset.
    pub fn line_col(&self, offset: u32) -> (usize, usize) {
        let offset = (offset as usize).min(self.text.len()).max(self.line_starts[0]);
        let line = self.line_starts.partition_point(|&s| s <= offset) - 1;
        let start = self.line_starts[line];
        let col = self.text.get(start..offset).map_or(offset - start, |s| s.chars().count());
        (line + 1, col + 1)
    }

    fn line_text(&self, line: usize) -> &'a str {
        let start = self.line_starts[line - 1];
        let end = self.line_starts.get(line).map_or(self.text.len(), |&e| e - 1);
        self.text[start..end].trim_end_matches('\r')
    }

    /// Renders one diagnostic the way rustc does: a header line, then the source line with carets under the
    /// offending text (only its first line when it spans several).
    pub fn render(&self, path: &str, diag: &Diagnostic) -> String {
        let (line, col) = self.line_col(diag.span.start);
        let severity = match diag.severity {
            Severity::Error => "error",
            Severity::Warning => "warning",
        };
        let mut out = format!("{path}:{line}:{col}: {severity}: {}\n", diag.message);
        let text = self.line_text(line);
        let (end_line, end_col) = self.line_col(diag.span.end);
        let text_chars = text.chars().count();
        let last_col = if end_line == line { end_col } else { text_chars + 1 };
        let width = last_col.saturating_sub(col).max(1);
        let gutter = line.to_string().len();
        let pad = " ".repeat(gutter);
        // A long line (generated XML holds lines of megabytes) shows a window around the column, as rustc does.
        let width = width.min(SHOWN_CHARS_MAX / 2);
        let first = (col - 1).saturating_sub(SHOWN_CHARS_MAX / 4).min(text_chars.saturating_sub(SHOWN_CHARS_MAX));
        let shown: String = text.chars().skip(first).take(SHOWN_CHARS_MAX).collect();
        let (before, after) =
            (if first > 0 { "…" } else { "" }, if first + SHOWN_CHARS_MAX < text_chars { "…" } else { "" });
        let _ = writeln!(out, "{pad} |");
        let _ = writeln!(out, "{line} | {before}{shown}{after}");
        // Keep tabs in the padding so that the carets line up under the text in a terminal.
        let lead: String = before
            .chars()
            .map(|_| ' ')
            .chain(shown.chars().take(col - 1 - first).map(|c| if c == '\t' { '\t' } else { ' ' }))
            .collect();
        let _ = writeln!(out, "{pad} | {lead}{}", "^".repeat(width));
        out
    }
}

/// Characters of a source line a diagnostic shows at most.
const SHOWN_CHARS_MAX: usize = 120;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_long_line_shows_a_window_around_the_column() {
        let src = format!("{}Foo{}\n", "x".repeat(100_000), "y".repeat(100_000));
        let index = LineIndex::new(&src);
        let d = Diagnostic::error(Span::new(100_000, 100_003), "unknown action `Foo`");
        let text = index.render("big.xml", &d);
        let lines: Vec<&str> = text.lines().collect();
        assert!(text.len() < 600, "{} bytes", text.len());
        assert!(lines[0].starts_with("big.xml:1:100001: error"), "{}", lines[0]);
        let shown = lines[2].strip_prefix("1 | ").expect("source line");
        let carets = lines[3].strip_prefix("  | ").expect("caret line");
        assert!(shown.starts_with('…') && shown.ends_with('…'), "{shown}");
        let at = carets.find('^').expect("carets");
        assert_eq!(shown.chars().skip(at).take(3).collect::<String>(), "Foo", "{shown}\n{carets}");
    }

    #[test]
    fn renders_header_and_carets() {
        let src = "STEP a:\n  Foo(N);\nEND_STEP\n";
        let index = LineIndex::new(src);
        let start = src.find("Foo").unwrap();
        let d = Diagnostic::error(Span::new(start, start + 3), "unknown action `Foo`");
        let text = index.render("c.st", &d);
        assert_eq!(text, "c.st:2:3: error: unknown action `Foo`\n  |\n2 |   Foo(N);\n  |   ^^^\n");
    }

    #[test]
    fn a_byte_order_mark_is_not_a_column() {
        let src = "\u{feff}STEP";
        let index = LineIndex::new(src);
        assert_eq!(index.line_col(0), (1, 1));
        assert_eq!(index.line_col(3), (1, 1));
        let d = Diagnostic::error(Span::new(0, 0), "no chart");
        assert!(index.render("b.st", &d).starts_with("b.st:1:1: error: no chart"));
    }

    #[test]
    fn columns_count_characters_not_bytes() {
        let src = "(* é *) x";
        let index = LineIndex::new(src);
        assert_eq!(index.line_col(src.find('x').unwrap() as u32), (1, 9));
    }
}
