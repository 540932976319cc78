//! Source spans and diagnostics, rendered as `PATH:LINE:COL: error: message` with the offending text quoted.

use std::fmt::Write as _;

/// A byte range in one source text.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
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
        let mut line_starts = vec![0];
        line_starts.extend(text.match_indices('\n').map(|(i, _)| i + 1));
        LineIndex { text, line_starts }
    }

    /// 1-based line and column of a byte offset.
    pub fn line_col(&self, offset: u32) -> (usize, usize) {
        let offset = (offset as usize).min(self.text.len());
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
        let _ = writeln!(out, "{pad} |");
        let _ = writeln!(out, "{line} | {text}");
        // Keep tabs in the padding so that the carets line up under the text in a terminal.
        let lead: String = text.chars().take(col - 1).map(|c| if c == '\t' { '\t' } else { ' ' }).collect();
        let _ = writeln!(out, "{pad} | {lead}{}", "^".repeat(width));
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn columns_count_characters_not_bytes() {
        let src = "(* é *) x";
        let index = LineIndex::new(src);
        assert_eq!(index.line_col(src.find('x').unwrap() as u32), (1, 9));
    }
}
