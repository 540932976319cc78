//! Turns IEC 61131-3 source text into tokens; comments vanish, pragmas are kept aside with their spans.
//!
//! Source text to tokens; comments vanish; `{ … }` pragmas are set aside with their spans.

use crate::front::diag::{Diagnostic, Span};

#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Tok {
    Ident,
    Kw(Kw),
    Int(i64),
    Real(f64),
    /// A duration literal, in milliseconds.
    Time(i64),
    /// `D#2026-12-01`, `TOD#12:30:00`, `DT#2026-12-01-12:30:00`: milliseconds since 1970-01-01 (or midnight).
    Date(i64),
    Tod(i64),
    Dt(i64),
    Str,
    /// A directly represented variable such as `%IX1.0`.
    Located,
    Assign,
    Colon,
    Semi,
    Comma,
    LParen,
    RParen,
    Dot,
    DotDot,
    Plus,
    Minus,
    Star,
    StarStar,
    Slash,
    Eq,
    Ne,
    Lt,
    Le,
    Gt,
    Ge,
    Amp,
    Arrow,
    LBracket,
    RBracket,
    Hash,
    Caret,
    Eof,
}

macro_rules! keywords {
    ($($kw:ident = $text:literal),* $(,)?) => {
        #[derive(Clone, Copy, Debug, PartialEq, Eq)]
        pub enum Kw { $($kw),* }

        impl Kw {
            /// Looks a word up, ignoring case.
            pub fn from_word(word: &str) -> Option<Kw> {
                let mut buf = [0u8; 20];
                let bytes = word.as_bytes();
                if bytes.len() > buf.len() {
                    return None;
                }
                for (b, c) in buf.iter_mut().zip(bytes) {
                    *b = c.to_ascii_uppercase();
                }
                match &buf[..bytes.len()] {
                    $(x if x == $text.as_bytes() => Some(Kw::$kw),)*
                    _ => None,
                }
            }

            pub fn text(self) -> &'static str {
                match self { $(Kw::$kw => $text),* }
            }
        }
    };
}

keywords! {
    Program = "PROGRAM", EndProgram = "END_PROGRAM",
    FunctionBlock = "FUNCTION_BLOCK", EndFunctionBlock = "END_FUNCTION_BLOCK",
    Function = "FUNCTION", EndFunction = "END_FUNCTION",
    Configuration = "CONFIGURATION", EndConfiguration = "END_CONFIGURATION",
    Type = "TYPE", EndType = "END_TYPE",
    Var = "VAR", VarInput = "VAR_INPUT", VarOutput = "VAR_OUTPUT", VarInOut = "VAR_IN_OUT",
    VarExternal = "VAR_EXTERNAL", VarGlobal = "VAR_GLOBAL", VarTemp = "VAR_TEMP",
    VarAccess = "VAR_ACCESS", VarConfig = "VAR_CONFIG", EndVar = "END_VAR",
    Constant = "CONSTANT", Retain = "RETAIN", NonRetain = "NON_RETAIN", At = "AT",
    InitialStep = "INITIAL_STEP", Step = "STEP", EndStep = "END_STEP",
    Transition = "TRANSITION", EndTransition = "END_TRANSITION", From = "FROM", To = "TO",
    Action = "ACTION", EndAction = "END_ACTION",
    If = "IF", Then = "THEN", Elsif = "ELSIF", Else = "ELSE", EndIf = "END_IF",
    Case = "CASE", Of = "OF", EndCase = "END_CASE",
    For = "FOR", By = "BY", Do = "DO", EndFor = "END_FOR",
    While = "WHILE", EndWhile = "END_WHILE", Repeat = "REPEAT", Until = "UNTIL", EndRepeat = "END_REPEAT",
    Exit = "EXIT", Return = "RETURN",
    And = "AND", Or = "OR", Xor = "XOR", Not = "NOT", Mod = "MOD",
    True = "TRUE", False = "FALSE",
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Token {
    pub tok: Tok,
    pub span: Span,
}

/// A `{ … }` pragma: its whole span and the span of the text between the braces.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RawPragma {
    pub span: Span,
    pub inner: Span,
}

pub struct Lexed {
    pub tokens: Vec<Token>,
    pub pragmas: Vec<RawPragma>,
    pub diagnostics: Vec<Diagnostic>,
}

pub fn lex(src: &str) -> Lexed {
    let mut lexer =
        Lexer { src, bytes: src.as_bytes(), pos: 0, out: Vec::new(), pragmas: Vec::new(), diags: Vec::new() };
    lexer.run();
    Lexed { tokens: lexer.out, pragmas: lexer.pragmas, diagnostics: lexer.diags }
}

struct Lexer<'a> {
    src: &'a str,
    bytes: &'a [u8],
    pos: usize,
    out: Vec<Token>,
    pragmas: Vec<RawPragma>,
    diags: Vec<Diagnostic>,
}

impl Lexer<'_> {
    fn peek(&self, ahead: usize) -> u8 {
        self.bytes.get(self.pos + ahead).copied().unwrap_or(0)
    }

    fn push(&mut self, tok: Tok, start: usize) {
        self.out.push(Token { tok, span: Span::new(start, self.pos) });
    }

    fn error(&mut self, start: usize, end: usize, message: impl Into<String>) {
        self.diags.push(Diagnostic::error(Span::new(start, end), message));
    }

    fn run(&mut self) {
        // A UTF-8 byte-order mark, as Windows editors write one, is not text.
        if self.bytes.starts_with("\u{feff}".as_bytes()) {
            self.pos = 3;
        }
        while self.pos < self.bytes.len() {
            let start = self.pos;
            let c = self.bytes[self.pos];
            match c {
                b' ' | b'\t' | b'\r' | b'\n' | 0x0c => self.pos += 1,
                b'(' if self.peek(1) == b'*' => self.block_comment(start, b'(', b')'),
                b'/' if self.peek(1) == b'*' => self.block_comment(start, b'/', b'/'),
                b'/' if self.peek(1) == b'/' => {
                    while self.pos < self.bytes.len() && self.bytes[self.pos] != b'\n' {
                        self.pos += 1;
                    }
                }
                b'{' => self.pragma(start),
                b'\'' | b'"' => self.string(start, c),
                b'%' => self.located(start),
                b'0'..=b'9' => self.number(start),
                c if c == b'_' || c.is_ascii_alphabetic() => self.word(start),
                _ => self.punct(start),
            }
        }
        let end = self.bytes.len();
        self.out.push(Token { tok: Tok::Eof, span: Span::new(end, end) });
    }

    /// `(* … *)` or `/* … */`; the standard does not nest comments, and neither do we.
    fn block_comment(&mut self, start: usize, open: u8, close: u8) {
        self.pos += 2;
        while self.pos < self.bytes.len() {
            if self.bytes[self.pos] == b'*' && self.peek(1) == close {
                self.pos += 2;
                return;
            }
            self.pos += 1;
        }
        let opener = if open == b'(' { "(*" } else { "/*" };
        self.error(start, start + 2, format!("comment `{opener}` is never closed"));
    }

    fn pragma(&mut self, start: usize) {
        match self.src[start + 1..].find('}') {
            Some(len) => {
                let inner = Span::new(start + 1, start + 1 + len);
                self.pos = start + len + 2;
                self.pragmas.push(RawPragma { span: Span::new(start, self.pos), inner });
            }
            None => {
                self.pos = self.bytes.len();
                self.error(start, start + 1, "pragma `{` is never closed");
            }
        }
    }

    fn string(&mut self, start: usize, quote: u8) {
        self.pos += 1;
        while self.pos < self.bytes.len() {
            match self.bytes[self.pos] {
                b'$' => self.pos += 2,
                b'\n' => break,
                c if c == quote => {
                    self.pos += 1;
                    self.push(Tok::Str, start);
                    return;
                }
                _ => self.pos += 1,
            }
        }
        self.pos = self.pos.min(self.bytes.len());
        self.error(start, self.pos, "string literal is not closed on its line");
    }

    fn located(&mut self, start: usize) {
        self.pos += 1;
        while self.pos < self.bytes.len()
            && (self.bytes[self.pos].is_ascii_alphanumeric() || self.bytes[self.pos] == b'.')
        {
            self.pos += 1;
        }
        if self.pos == start + 1 {
            self.error(start, start + 1, "expected a location after `%`, such as `%IX0.1`");
            return;
        }
        self.push(Tok::Located, start);
    }

    fn digits(&mut self, radix: u32) -> usize {
        let begin = self.pos;
        while self.pos < self.bytes.len() {
            let c = self.bytes[self.pos];
            if c == b'_' || (c as char).is_digit(radix) {
                self.pos += 1;
            } else {
                break;
            }
        }
        self.pos - begin
    }

    fn number(&mut self, start: usize) {
        self.digits(10);
        if self.peek(0) == b'#' {
            // Based integer such as 16#FF or 2#1010.
            let radix: u32 = self.src[start..self.pos].replace('_', "").parse().unwrap_or(0);
            if matches!(radix, 2 | 8 | 16) {
                self.pos += 1;
                let body_start = self.pos;
                self.digits(radix);
                let text = self.src[body_start..self.pos].replace('_', "");
                match i64::from_str_radix(&text, radix) {
                    Ok(v) => self.push(Tok::Int(v), start),
                    Err(_) => self.error(start, self.pos, "invalid or too large based integer literal"),
                }
                return;
            }
        }
        let mut is_real = false;
        if self.peek(0) == b'.' && self.peek(1).is_ascii_digit() {
            is_real = true;
            self.pos += 1;
            self.digits(10);
        }
        if matches!(self.peek(0), b'e' | b'E')
            && (self.peek(1).is_ascii_digit() || (matches!(self.peek(1), b'+' | b'-') && self.peek(2).is_ascii_digit()))
        {
            is_real = true;
            self.pos += 2;
            self.digits(10);
        }
        let text = self.src[start..self.pos].replace('_', "");
        if is_real {
            match text.parse::<f64>() {
                Ok(v) => self.push(Tok::Real(v), start),
                Err(_) => self.error(start, self.pos, "invalid real literal"),
            }
        } else {
            match text.parse::<i64>() {
                Ok(v) => self.push(Tok::Int(v), start),
                Err(_) => self.error(start, self.pos, "integer literal is too large"),
            }
        }
    }

    fn word(&mut self, start: usize) {
        while self.pos < self.bytes.len()
            && (self.bytes[self.pos] == b'_' || self.bytes[self.pos].is_ascii_alphanumeric())
        {
            self.pos += 1;
        }
        let word = &self.src[start..self.pos];
        if self.peek(0) == b'#' {
            let upper = word.to_ascii_uppercase();
            if matches!(upper.as_str(), "T" | "TIME" | "LT" | "LTIME") {
                self.pos += 1;
                self.duration(start);
                return;
            }
            let calendar = match upper.as_str() {
                "D" | "DATE" | "LDATE" => Some(0),
                "TOD" | "TIME_OF_DAY" | "LTOD" => Some(1),
                "DT" | "DATE_AND_TIME" | "LDT" => Some(2),
                _ => None,
            };
            if let Some(kind) = calendar {
                self.pos += 1;
                self.calendar(start, kind);
                return;
            }
            if crate::types::Type::from_name(&upper).is_some() {
                // A typed literal such as INT#5 or BOOL#TRUE: the literal's own value is what matters.
                self.pos += 1;
                return;
            }
        }
        let tok = Kw::from_word(word).map_or(Tok::Ident, Tok::Kw);
        self.push(tok, start);
    }

    /// The part of a date (`kind` 0), time of day (1) or date and time (2) literal after its `#`.
    fn calendar(&mut self, start: usize, kind: u8) {
        let body_start = self.pos;
        while self.pos < self.bytes.len() && matches!(self.bytes[self.pos], b'0'..=b'9' | b'-' | b':' | b'.' | b'_') {
            self.pos += 1;
        }
        let body = self.src[body_start..self.pos].replace('_', "");
        let date = |s: &str| -> Option<i64> {
            let mut it = s.splitn(3, '-');
            let (y, m, d) =
                (it.next()?.parse::<i64>().ok()?, it.next()?.parse::<i64>().ok()?, it.next()?.parse::<i64>().ok()?);
            // Years 1 to 9999, as the calendar types of PLC tools hold them: a year of 19 digits would wrap.
            let days_in_month = match m {
                2 if y % 4 == 0 && (y % 100 != 0 || y % 400 == 0) => 29,
                2 => 28,
                4 | 6 | 9 | 11 => 30,
                _ => 31,
            };
            ((1..=9999).contains(&y) && (1..=12).contains(&m) && (1..=days_in_month).contains(&d))
                .then(|| crate::types::days_from_civil(y, m, d) * 86_400_000)
        };
        let tod = |s: &str| -> Option<i64> {
            let mut it = s.splitn(3, ':');
            let (h, m) = (it.next()?.parse::<i64>().ok()?, it.next()?.parse::<i64>().ok()?);
            let sec: f64 = it.next().unwrap_or("0").parse().ok()?;
            ((0..24).contains(&h) && (0..60).contains(&m) && (0.0..60.0).contains(&sec))
                .then(|| h * 3_600_000 + m * 60_000 + (sec * 1000.0).round() as i64)
        };
        let value = match kind {
            0 => date(&body).map(Tok::Date),
            1 => tod(&body).map(Tok::Tod),
            _ => {
                // YYYY-MM-DD-HH:MM:SS: the date is the first three fields.
                let split = body.match_indices('-').nth(2).map(|(i, _)| i);
                split.and_then(|i| Some(Tok::Dt(date(&body[..i])? + tod(&body[i + 1..])?)))
            }
        };
        match value {
            Some(tok) => self.push(tok, start),
            None => {
                let what = [
                    "a date such as D#2026-12-01 (years 1 to 9999, days that the month has)",
                    "a time of day such as TOD#12:30:00",
                    "a date and time such as DT#2026-12-01-12:30:00 (years 1 to 9999)",
                ];
                self.error(start, self.pos, format!("invalid literal: expected {}", what[kind as usize]));
            }
        }
    }

    /// The part of a duration literal after `T#`: `1h2m3s4ms`, `1.5s`, `-200ms`, `1d_2h`.
    fn duration(&mut self, start: usize) {
        let negative = self.peek(0) == b'-';
        if negative {
            self.pos += 1;
        }
        let mut total_ms = 0f64;
        let mut parts = 0;
        loop {
            if self.peek(0) == b'_' {
                self.pos += 1;
            }
            let num_start = self.pos;
            if self.digits(10) == 0 {
                break;
            }
            if self.peek(0) == b'.' && self.peek(1).is_ascii_digit() {
                self.pos += 1;
                self.digits(10);
            }
            let value: f64 = self.src[num_start..self.pos].replace('_', "").parse().unwrap_or(0.0);
            let unit_start = self.pos;
            while self.peek(0).is_ascii_alphabetic() {
                self.pos += 1;
            }
            let unit = self.src[unit_start..self.pos].to_ascii_lowercase();
            let scale = match unit.as_str() {
                "d" => 86_400_000.0,
                "h" => 3_600_000.0,
                "m" => 60_000.0,
                "s" => 1_000.0,
                "ms" => 1.0,
                "us" => 0.001,
                "ns" => 0.000_001,
                _ => {
                    self.error(
                        unit_start,
                        self.pos.max(unit_start + 1),
                        "expected a time unit (d, h, m, s, ms, us, ns)",
                    );
                    return;
                }
            };
            total_ms += value * scale;
            parts += 1;
        }
        if parts == 0 {
            self.error(start, self.pos, "expected a duration such as `T#1s500ms`");
            return;
        }
        if total_ms > i64::MAX as f64 / 2.0 {
            self.error(start, self.pos, "duration is too large");
            return;
        }
        let ms = total_ms.round() as i64;
        self.push(Tok::Time(if negative { -ms } else { ms }), start);
    }

    fn punct(&mut self, start: usize) {
        let two = [self.peek(0), self.peek(1)];
        let (tok, len) = match &two {
            b":=" => (Tok::Assign, 2),
            b"<>" => (Tok::Ne, 2),
            b"<=" => (Tok::Le, 2),
            b">=" => (Tok::Ge, 2),
            b"=>" => (Tok::Arrow, 2),
            b"**" => (Tok::StarStar, 2),
            b".." => (Tok::DotDot, 2),
            _ => match two[0] {
                b':' => (Tok::Colon, 1),
                b';' => (Tok::Semi, 1),
                b',' => (Tok::Comma, 1),
                b'(' => (Tok::LParen, 1),
                b')' => (Tok::RParen, 1),
                b'.' => (Tok::Dot, 1),
                b'+' => (Tok::Plus, 1),
                b'-' => (Tok::Minus, 1),
                b'*' => (Tok::Star, 1),
                b'/' => (Tok::Slash, 1),
                b'=' => (Tok::Eq, 1),
                b'<' => (Tok::Lt, 1),
                b'>' => (Tok::Gt, 1),
                b'&' => (Tok::Amp, 1),
                b'[' => (Tok::LBracket, 1),
                b']' => (Tok::RBracket, 1),
                b'#' => (Tok::Hash, 1),
                b'^' => (Tok::Caret, 1),
                _ => {
                    let ch = self.src[start..].chars().next().unwrap_or('?');
                    self.pos += ch.len_utf8();
                    self.error(start, self.pos, format!("unexpected character `{ch}`"));
                    return;
                }
            },
        };
        self.pos += len;
        self.push(tok, start);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn toks(src: &str) -> Vec<Tok> {
        let lexed = lex(src);
        assert!(lexed.diagnostics.is_empty(), "{:?}", lexed.diagnostics);
        lexed.tokens.into_iter().map(|t| t.tok).collect()
    }

    #[test]
    fn durations() {
        assert_eq!(
            toks("T#1s500ms t#100ms TIME#1.5s T#1h_2m T#-5s")[..5],
            [Tok::Time(1500), Tok::Time(100), Tok::Time(1500), Tok::Time(3_720_000), Tok::Time(-5000)]
        );
    }

    #[test]
    fn keywords_ignore_case_and_comments_vanish() {
        assert_eq!(toks("initial_Step (* x *) a // y\n"), [Tok::Kw(Kw::InitialStep), Tok::Ident, Tok::Eof]);
    }

    #[test]
    fn numbers() {
        assert_eq!(
            toks("16#FF 1_000 2.5 1e3 INT#5"),
            [Tok::Int(255), Tok::Int(1000), Tok::Real(2.5), Tok::Real(1000.0), Tok::Int(5), Tok::Eof]
        );
    }

    #[test]
    fn pragmas_are_kept_aside() {
        let lexed = lex("STEP a: {agent := 'r1'} END_STEP");
        assert_eq!(lexed.pragmas.len(), 1);
        let p = lexed.pragmas[0];
        assert_eq!(&"STEP a: {agent := 'r1'} END_STEP"[p.inner.start as usize..p.inner.end as usize], "agent := 'r1'");
    }

    #[test]
    fn unterminated_comment_is_reported() {
        let lexed = lex("a (* never closed");
        assert_eq!(lexed.diagnostics.len(), 1);
    }
}
