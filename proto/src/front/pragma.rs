//! Baton's pragmas, `{key := literal, …}`, read from the text between the braces. Keys are names whatever their
//! spelling (`type`, `action` or `step` are IEC keywords, and fine keys). A pragma that names one of Baton's keys
//! but cannot be read, and one whose key is a near miss of Baton's, are reported (`baton check`); any other
//! pragma is another tool's and is left alone.
//!
//! Reads a pragma's text as `key := literal` pairs (keys are names whatever their spelling), as malformed
//! (with why), or as another tool's; near misses of Baton's keys.

use crate::front::lexer::{lex, Kw, Tok, Token};
use crate::types::Value;

/// A pragma value: `'text'`, a number, a duration or a boolean.
#[derive(Clone, Debug, PartialEq)]
pub enum Param {
    Str(String),
    Value(Value),
}

impl Param {
    pub fn as_str(&self) -> Option<&str> {
        match self {
            Param::Str(s) => Some(s),
            Param::Value(_) => None,
        }
    }

    /// A number or a duration, in its own unit (a duration in ms).
    pub fn as_f64(&self) -> Option<f64> {
        match self {
            Param::Value(Value::Int(i) | Value::Time(i)) => Some(*i as f64),
            Param::Value(Value::Real(r)) => Some(*r),
            _ => None,
        }
    }
}

/// What the text of a pragma is.
#[derive(Clone, Debug, PartialEq)]
pub enum Pragma {
    /// `key := literal {, key := literal}`, keys lower-cased.
    Pairs(Vec<(String, Param)>),
    /// It assigns to keys (`keys`, lower-cased) but is not a list of `key := literal`: `why` says what is wrong.
    Malformed { keys: Vec<String>, why: String },
    /// Not of that form at all: another tool's pragma.
    Foreign,
}

pub fn read(text: &str) -> Pragma {
    let lexed = lex(text);
    let toks = &lexed.tokens;
    let word = |t: &Token| matches!(t.tok, Tok::Ident | Tok::Kw(_));
    let text_of = |t: &Token| text[t.span.start as usize..t.span.end as usize].to_ascii_lowercase();
    // Every word followed by `:=` or `=`: the keys the pragma means to set, readable or not.
    let keys: Vec<String> = toks
        .windows(2)
        .filter(|w| word(&w[0]) && matches!(w[1].tok, Tok::Assign | Tok::Eq))
        .map(|w| text_of(&w[0]))
        .collect();
    if keys.is_empty() || !toks.first().is_some_and(word) {
        return Pragma::Foreign;
    }
    let malformed = |why: String| Pragma::Malformed { keys: keys.clone(), why };
    if let Some(d) = lexed.diagnostics.first() {
        return malformed(d.message.clone());
    }
    let mut out = Vec::new();
    let mut i = 0;
    loop {
        let Some(k) = toks.get(i).filter(|t| word(t)) else {
            return malformed("expected a key after `,`".to_string());
        };
        let key = text_of(k);
        match toks.get(i + 1).map(|t| t.tok) {
            Some(Tok::Assign) => {}
            Some(Tok::Eq) => {
                return malformed(format!("write `{key} := …`: Baton's pragmas assign with `:=`, not `=`"))
            }
            _ => return malformed(format!("expected `:=` after `{key}`")),
        }
        let Some((value, used)) = literal(text, &toks[i + 2..]) else {
            return malformed(format!(
                "`{key}` needs a literal value: a quoted 'text', a number, a TIME such as T#2s, TRUE or FALSE"
            ));
        };
        out.push((key, value));
        i += 2 + used;
        match toks.get(i).map(|t| t.tok) {
            Some(Tok::Comma) => i += 1,
            Some(Tok::Eof) | None => return Pragma::Pairs(out),
            _ => return malformed("expected `,` between two `key := value`".to_string()),
        }
    }
}

fn literal(text: &str, toks: &[Token]) -> Option<(Param, usize)> {
    let first = toks.first()?;
    let negative = first.tok == Tok::Minus;
    let tok = if negative { toks.get(1)? } else { first };
    let param = match tok.tok {
        Tok::Str if !negative => {
            let raw = &text[tok.span.start as usize + 1..tok.span.end as usize - 1];
            Param::Str(raw.replace("$'", "'").replace("$$", "$"))
        }
        Tok::Int(v) => Param::Value(Value::Int(if negative { -v } else { v })),
        Tok::Real(v) => Param::Value(Value::Real(if negative { -v } else { v })),
        Tok::Time(v) if !negative => Param::Value(Value::Time(v)),
        Tok::Kw(Kw::True) if !negative => Param::Value(Value::Bool(true)),
        Tok::Kw(Kw::False) if !negative => Param::Value(Value::Bool(false)),
        _ => return None,
    };
    Some((param, 1 + usize::from(negative)))
}

/// The Baton key that `key` looks like a misspelling of (one or two edits for keys of five letters or more,
/// one for shorter ones), if any.
pub fn near_miss<'a>(key: &str, baton_keys: &[&'a str]) -> Option<&'a str> {
    baton_keys.iter().copied().find(|k| {
        let d = edit_distance(key, k);
        d > 0 && d <= if k.len() >= 5 { 2 } else { 1 }
    })
}

/// The name among `candidates` that `name` looks like a misspelling of — compared without case, as IEC 61131-3
/// names are; one edit for names under five letters, two from five — the nearest one, if any.
pub fn nearest<'a>(name: &str, candidates: impl IntoIterator<Item = &'a str>) -> Option<&'a str> {
    let wanted = name.to_ascii_lowercase();
    candidates
        .into_iter()
        .filter(|c| !another_number(&wanted, &c.to_ascii_lowercase()))
        .filter_map(|c| {
            let d = edit_distance(&wanted, &c.to_ascii_lowercase());
            let limit = if c.len() >= 5 { 2 } else { 1 };
            (d > 0 && d <= limit).then_some((d, c))
        })
        .min_by_key(|(d, _)| *d)
        .map(|(_, c)| c)
}

/// Whether two names differ only in their digits (`IX3`, `IX1`; `robot2`, `robot1`): another item of a numbered
/// set, not a misspelling of it.
fn another_number(a: &str, b: &str) -> bool {
    a.len() == b.len() && a.bytes().zip(b.bytes()).all(|(x, y)| x == y || (x.is_ascii_digit() && y.is_ascii_digit()))
}

/// " (did you mean `X`?)" for the nearest of `candidates`, or nothing.
pub fn did_you_mean<'a>(name: &str, candidates: impl IntoIterator<Item = &'a str>) -> String {
    nearest(name, candidates).map_or(String::new(), |c| format!(" (did you mean `{c}`?)"))
}

/// Optimal string alignment distance: insertions, deletions, substitutions and swaps of two neighbours.
fn edit_distance(a: &str, b: &str) -> usize {
    let (a, b): (Vec<char>, Vec<char>) = (a.chars().collect(), b.chars().collect());
    let mut d = vec![vec![0usize; b.len() + 1]; a.len() + 1];
    for (i, row) in d.iter_mut().enumerate() {
        row[0] = i;
    }
    for (j, cell) in d[0].iter_mut().enumerate() {
        *cell = j;
    }
    for i in 1..=a.len() {
        for j in 1..=b.len() {
            let cost = usize::from(a[i - 1] != b[j - 1]);
            d[i][j] = (d[i - 1][j] + 1).min(d[i][j - 1] + 1).min(d[i - 1][j - 1] + cost);
            if i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1] {
                d[i][j] = d[i][j].min(d[i - 2][j - 2] + 1);
            }
        }
    }
    d[a.len()][b.len()]
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_nearest_name_is_suggested_without_case_and_never_another_number() {
        let names = ["Weld", "Load", "loaded", "LoadPart", "IX1", "robot1"];
        assert_eq!(nearest("Wled", names), Some("Weld"));
        assert_eq!(nearest("LOADEDD", names), Some("loaded"));
        assert_eq!(nearest("LodPart", names), Some("LoadPart"));
        assert_eq!(nearest("robto1", names), Some("robot1"));
        assert_eq!(nearest("IX3", names), None, "another input of a numbered set, not a typo");
        assert_eq!(nearest("robot2", names), None);
        assert_eq!(nearest("weld", names), None, "the same name, as IEC compares names");
        assert_eq!(nearest("Paint", names), None);
    }
    use super::*;

    fn keys(p: &Pragma) -> Vec<String> {
        match p {
            Pragma::Pairs(pairs) => pairs.iter().map(|(k, _)| k.clone()).collect(),
            Pragma::Malformed { keys, .. } => keys.clone(),
            Pragma::Foreign => Vec::new(),
        }
    }

    #[test]
    fn keys_are_names_whatever_their_spelling() {
        let p = read("skill := 'motion', ms := 50, type := 'x', action := '/arm', step := 2, END_IF := TRUE");
        assert_eq!(keys(&p), ["skill", "ms", "type", "action", "step", "end_if"]);
        assert!(matches!(p, Pragma::Pairs(_)));
    }

    #[test]
    fn what_cannot_be_read_says_why_and_foreign_pragmas_are_left_alone() {
        for (text, why) in [
            ("agent := r1", "needs a literal value"),
            ("agent = 'r1'", "assign with `:=`"),
            ("agent := 'r1' role := 'x'", "expected `,`"),
            ("agent := 'r1", "string"),
        ] {
            match read(text) {
                Pragma::Malformed { keys, why: got } => {
                    assert_eq!(keys[0], "agent", "{text}");
                    assert!(got.contains(why), "{text}: {got}");
                }
                other => panic!("{text}: {other:?}"),
            }
        }
        for text in ["attribute 'qualified_only'", "warning disable C0195", "", "$$ weird"] {
            assert_eq!(read(text), Pragma::Foreign, "{text}");
        }
    }

    #[test]
    fn near_misses() {
        assert_eq!(near_miss("agnet", &["agent", "role"]), Some("agent"));
        assert_eq!(near_miss("rol", &["agent", "role"]), Some("role"));
        assert_eq!(near_miss("skil", &["skill"]), Some("skill"));
        assert_eq!(near_miss("agent", &["agent", "role"]), None);
        assert_eq!(near_miss("speed", &["agent", "role"]), None);
        assert_eq!(near_miss("rule", &["agent", "role"]), Some("role"));
    }
}
