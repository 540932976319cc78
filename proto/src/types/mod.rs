//! Elementary data types and run-time values of the Structured Text subset Baton executes.
//!
//! A `Value` is not `Copy`: a STRING is an `Arc<String>` (the enum stays 16 bytes, a copy of a value is a
//! reference count at most), never changed in place; a variable's length cuts what is stored in it
//! (`Type::coerce`), and `STRING_CHARS_MAX` bounds a chart's strings so that a dispatch fits a message.

pub mod library;

use std::fmt;
use std::sync::Arc;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum IntKind {
    Sint,
    Int,
    Dint,
    Lint,
    Usint,
    Uint,
    Udint,
    Ulint,
    Byte,
    Word,
    Dword,
    Lword,
}

impl IntKind {
    pub fn bits(self) -> u32 {
        match self {
            IntKind::Sint | IntKind::Usint | IntKind::Byte => 8,
            IntKind::Int | IntKind::Uint | IntKind::Word => 16,
            IntKind::Dint | IntKind::Udint | IntKind::Dword => 32,
            IntKind::Lint | IntKind::Ulint | IntKind::Lword => 64,
        }
    }

    fn signed(self) -> bool {
        matches!(self, IntKind::Sint | IntKind::Int | IntKind::Dint | IntKind::Lint)
    }

    /// Wraps a value to this type's width, the way a PLC's integer arithmetic overflows.
    pub fn wrap(self, v: i64) -> i64 {
        let bits = self.bits();
        if bits == 64 {
            return v;
        }
        let masked = v & ((1i64 << bits) - 1);
        if self.signed() && masked >= 1i64 << (bits - 1) {
            masked - (1i64 << bits)
        } else {
            masked
        }
    }

    /// The largest value (ULINT and LWORD stop at i64::MAX: values are held in an i64).
    pub fn max_value(self) -> i64 {
        match (self.bits(), self.signed()) {
            (64, _) => i64::MAX,
            (b, true) => (1i64 << (b - 1)) - 1,
            (b, false) => (1i64 << b) - 1,
        }
    }

    pub fn contains(self, v: i64) -> bool {
        self.wrap(v) == v && (self.signed() || v >= 0)
    }

    /// Orders integer kinds by width so that mixed arithmetic takes the wider one.
    fn rank(self) -> (u32, bool) {
        (self.bits(), !self.signed())
    }

    pub fn wider(self, other: IntKind) -> IntKind {
        if other.rank() > self.rank() {
            other
        } else {
            self
        }
    }
}

/// An enumeration from a `TYPE` block: its values are held as their ordinal (0 for the first).
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct EnumType {
    /// Tells enumerations apart (their order of declaration in the file).
    pub id: u32,
    pub name: String,
    pub values: Vec<String>,
}

/// Days since 1970-01-01 of a civil date (proleptic Gregorian), and back: DATE and DATE_AND_TIME values are
/// milliseconds since 1970-01-01-00:00:00, TIME_OF_DAY values milliseconds since midnight.
pub fn days_from_civil(y: i64, m: i64, d: i64) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let doy = (153 * (m + if m > 2 { -3 } else { 9 }) + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

pub fn civil_from_days(days: i64) -> (i64, i64, i64) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    (yoe + era * 400 + i64::from(m <= 2), m, d)
}

const DAY_MS: i64 = 86_400_000;

/// `12:30:05.250` from milliseconds since midnight.
pub fn show_tod(ms: i64) -> String {
    let ms = ms.rem_euclid(DAY_MS);
    let (h, m, s, f) = (ms / 3_600_000, ms / 60_000 % 60, ms / 1000 % 60, ms % 1000);
    if f == 0 {
        format!("{h:02}:{m:02}:{s:02}")
    } else {
        format!("{h:02}:{m:02}:{s:02}.{f:03}")
    }
}

/// `2026-12-01` from milliseconds since 1970-01-01.
pub fn show_date(ms: i64) -> String {
    let (y, m, d) = civil_from_days(ms.div_euclid(DAY_MS));
    format!("{y:04}-{m:02}-{d:02}")
}

#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub enum Type {
    Enum(std::sync::Arc<EnumType>),
    /// DATE, TIME_OF_DAY, DATE_AND_TIME: held as `Value::Time` milliseconds (see `days_from_civil`).
    Date,
    Tod,
    Dt,
    Bool,
    Int(IntKind),
    /// REAL (single precision) when false, LREAL when true.
    Real {
        long: bool,
    },
    Time,
    /// `STRING[max]`: at most `max` characters; a longer value is cut to its first `max` when stored.
    Str {
        max: u32,
    },
    /// A declared type Baton does not execute (STRING, arrays, function block instances…): it may be declared,
    /// not used.
    Unsupported(String),
}

impl Type {
    /// The elementary type with this (upper-case) name.
    pub fn from_name(upper: &str) -> Option<Type> {
        if let Some(n) = upper.strip_prefix("STRING[").and_then(|r| r.strip_suffix(']')) {
            let max = n.parse::<u32>().ok().filter(|&n| n >= 1 && n as usize <= crate::limits::STRING_LENGTH_MAX)?;
            return Some(Type::Str { max });
        }
        Some(match upper {
            "BOOL" => Type::Bool,
            "SINT" => Type::Int(IntKind::Sint),
            "INT" => Type::Int(IntKind::Int),
            "DINT" => Type::Int(IntKind::Dint),
            "LINT" => Type::Int(IntKind::Lint),
            "USINT" => Type::Int(IntKind::Usint),
            "UINT" => Type::Int(IntKind::Uint),
            "UDINT" => Type::Int(IntKind::Udint),
            "ULINT" => Type::Int(IntKind::Ulint),
            "BYTE" => Type::Int(IntKind::Byte),
            "WORD" => Type::Int(IntKind::Word),
            "DWORD" => Type::Int(IntKind::Dword),
            "LWORD" => Type::Int(IntKind::Lword),
            "REAL" => Type::Real { long: false },
            "LREAL" => Type::Real { long: true },
            "TIME" | "LTIME" => Type::Time,
            "DATE" | "LDATE" => Type::Date,
            "TIME_OF_DAY" | "TOD" | "LTOD" => Type::Tod,
            "DATE_AND_TIME" | "DT" | "LDT" => Type::Dt,
            "STRING" => Type::Str { max: crate::limits::STRING_LENGTH_DEFAULT as u32 },
            _ => return None,
        })
    }

    pub fn default_value(&self) -> Value {
        match self {
            Type::Str { .. } => Value::string(""),
            Type::Bool | Type::Unsupported(_) => Value::Bool(false),
            Type::Enum(_) => Value::Int(0),
            Type::Int(_) => Value::Int(0),
            Type::Real { .. } => Value::Real(0.0),
            Type::Time | Type::Date | Type::Tod | Type::Dt => Value::Time(0),
        }
    }

    /// Whether a value (from an input, a message) is one of this type's values as they are held.
    pub fn fits(&self, v: &Value) -> bool {
        match (self, v) {
            (Type::Str { max }, Value::Str(s)) => s.chars().count() <= *max as usize,
            (Type::Bool, Value::Bool(_))
            | (Type::Time | Type::Date | Type::Tod | Type::Dt, Value::Time(_))
            | (Type::Real { .. }, Value::Real(_)) => true,
            (Type::Int(k), &Value::Int(v)) => k.contains(v),
            (Type::Enum(e), &Value::Int(v)) => v >= 0 && (v as usize) < e.values.len(),
            _ => false,
        }
    }

    /// A value as a user reads it: an enumeration's value by name, others as `Value` shows them.
    pub fn show(&self, v: &Value) -> String {
        match (self, v) {
            (Type::Enum(e), &Value::Int(i)) => e.values.get(i as usize).cloned().unwrap_or_else(|| i.to_string()),
            (Type::Date, &Value::Time(ms)) => format!("D#{}", show_date(ms)),
            (Type::Tod, &Value::Time(ms)) => format!("TOD#{}", show_tod(ms)),
            (Type::Dt, &Value::Time(ms)) => format!("DT#{}-{}", show_date(ms), show_tod(ms.rem_euclid(DAY_MS))),
            (_, v) => v.to_string(),
        }
    }

    /// Converts a value of a compatible type into this type's representation (wrapping integers, rounding
    /// REAL to single precision). The type checker guarantees compatibility.
    pub fn coerce(&self, v: Value) -> Value {
        match (self, v) {
            (Type::Int(k), Value::Int(i)) => Value::Int(k.wrap(i)),
            // A time of day past midnight wraps to the next day's.
            (Type::Tod, Value::Time(ms)) => Value::Time(ms.rem_euclid(DAY_MS)),
            (Type::Real { long }, Value::Int(i)) => Value::Real(round_real(i as f64, *long)),
            (Type::Real { long }, Value::Real(r)) => Value::Real(round_real(r, *long)),
            (Type::Str { max }, Value::Str(s)) if s.len() > *max as usize => {
                match s.char_indices().nth(*max as usize) {
                    Some((cut, _)) => Value::string(&s[..cut]),
                    None => Value::Str(s),
                }
            }
            (_, v) => v,
        }
    }
}

fn round_real(r: f64, long: bool) -> f64 {
    if long {
        r
    } else {
        r as f32 as f64
    }
}

impl fmt::Display for Type {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let name = match self {
            Type::Bool => "BOOL",
            Type::Int(k) => match k {
                IntKind::Sint => "SINT",
                IntKind::Int => "INT",
                IntKind::Dint => "DINT",
                IntKind::Lint => "LINT",
                IntKind::Usint => "USINT",
                IntKind::Uint => "UINT",
                IntKind::Udint => "UDINT",
                IntKind::Ulint => "ULINT",
                IntKind::Byte => "BYTE",
                IntKind::Word => "WORD",
                IntKind::Dword => "DWORD",
                IntKind::Lword => "LWORD",
            },
            Type::Real { long: false } => "REAL",
            Type::Real { long: true } => "LREAL",
            Type::Time => "TIME",
            Type::Str { max } if *max as usize == crate::limits::STRING_LENGTH_DEFAULT => "STRING",
            Type::Str { max } => return write!(f, "STRING[{max}]"),
            Type::Unsupported(name) => name,
            Type::Enum(e) => &e.name,
            Type::Date => "DATE",
            Type::Tod => "TIME_OF_DAY",
            Type::Dt => "DATE_AND_TIME",
        };
        f.write_str(name)
    }
}

/// A run-time value. TIME is held in milliseconds. A STRING is shared, so that copying a value stays cheap (a
/// string is never changed in place: every string function makes a new one).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub enum Value {
    Bool(bool),
    Int(i64),
    Real(f64),
    Time(i64),
    Str(Arc<String>),
}

impl Value {
    pub fn as_bool(&self) -> bool {
        matches!(self, Value::Bool(true))
    }

    pub fn as_i64(&self) -> i64 {
        match *self {
            Value::Bool(b) => b as i64,
            Value::Int(i) | Value::Time(i) => i,
            Value::Real(r) => r as i64,
            Value::Str(_) => 0,
        }
    }

    pub fn as_f64(&self) -> f64 {
        match *self {
            Value::Real(r) => r,
            ref other => other.as_i64() as f64,
        }
    }

    pub fn as_str(&self) -> &str {
        match self {
            Value::Str(s) => s,
            _ => "",
        }
    }

    pub fn string(s: impl Into<String>) -> Value {
        Value::Str(Arc::new(s.into()))
    }
}

/// A STRING literal's text in Structured Text: quoted, with `$` escapes for the quote, `$` itself and
/// characters that are not printable.
pub fn quote_string(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('\'');
    for c in s.chars() {
        match c {
            '\'' => out.push_str("$'"),
            '$' => out.push_str("$$"),
            '\n' => out.push_str("$N"),
            '\r' => out.push_str("$R"),
            '\t' => out.push_str("$T"),
            '\x0c' => out.push_str("$P"),
            c if (c as u32) < 0x20 || c as u32 == 0x7f => out.push_str(&format!("${:02X}", c as u32)),
            c => out.push(c),
        }
    }
    out.push('\'');
    out
}

/// A STRING literal's value from its text between the quotes: `$$`, `$'`, `$"`, `$L`/`$N` (line feed), `$P`
/// (form feed), `$R`, `$T` and `$hh` (a character by its code). `Err` names the first bad escape.
pub fn unquote_string(raw: &str) -> Result<String, String> {
    let mut out = String::with_capacity(raw.len());
    let mut chars = raw.chars();
    while let Some(c) = chars.next() {
        if c != '$' {
            out.push(c);
            continue;
        }
        let Some(e) = chars.next() else { return Err("a string ends with a lone `$`".into()) };
        match e.to_ascii_uppercase() {
            '$' => out.push('$'),
            '\'' => out.push('\''),
            '"' => out.push('"'),
            'L' | 'N' => out.push('\n'),
            'P' => out.push('\x0c'),
            'R' => out.push('\r'),
            'T' => out.push('\t'),
            h if h.is_ascii_hexdigit() => {
                let l = chars.next().filter(char::is_ascii_hexdigit);
                let Some(l) = l else { return Err(format!("`${e}` needs two hexadecimal digits, such as `$0A`")) };
                let code = u32::from_str_radix(&format!("{h}{l}"), 16).expect("two hexadecimal digits");
                out.push(char::from_u32(code).expect("a code below 256 is a character"));
            }
            _ => {
                return Err(format!("`${e}` is not a string escape (`$$`, `$'`, `$L`, `$N`, `$P`, `$R`, `$T`, `$hh`)"))
            }
        }
    }
    Ok(out)
}

impl fmt::Display for Value {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Value::Bool(b) => write!(f, "{}", if *b { "TRUE" } else { "FALSE" }),
            Value::Int(i) => write!(f, "{i}"),
            Value::Real(r) => write!(f, "{r}"),
            Value::Time(ms) => write!(f, "T#{ms}ms"),
            Value::Str(s) => f.write_str(&quote_string(s)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integers_wrap_like_a_plc() {
        assert_eq!(IntKind::Int.wrap(32_768), -32_768);
        assert_eq!(IntKind::Usint.wrap(256), 0);
        assert_eq!(IntKind::Uint.wrap(-1), 65_535);
        assert!(IntKind::Dint.contains(-5));
        assert!(!IntKind::Uint.contains(-1));
    }

    #[test]
    fn string_literals_read_back_as_they_were_written() {
        for text in ["", "plain", "it's $5", "tab\there\nline", "\u{1}\u{7f}ctl", "é, ü and ß"] {
            let quoted = quote_string(text);
            assert_eq!(unquote_string(&quoted[1..quoted.len() - 1]).as_deref(), Ok(text), "{quoted}");
        }
        assert_eq!(unquote_string("$41$l$$").as_deref(), Ok("A\n$"));
        assert!(unquote_string("$Q").is_err() && unquote_string("$4").is_err() && unquote_string("end$").is_err());
    }

    #[test]
    fn a_string_is_cut_to_its_length_when_stored_and_does_not_fit_when_too_long() {
        let ty = Type::Str { max: 3 };
        assert_eq!(ty.coerce(Value::string("abcdef")), Value::string("abc"));
        assert_eq!(ty.coerce(Value::string("äöüß")), Value::string("äöü"), "characters, not bytes");
        assert!(ty.fits(&Value::string("äöü")) && !ty.fits(&Value::string("abcd")));
    }
}
