//! Structured literals in skill parameters: a ROS 2 goal `'(order := 5)'`, a pose `'(x := 1.0, y := 2.0)'`, the
//! arguments of an OPC UA method `'[3, T#2s]'`, and the mappings that write a result into chart variables,
//! `'sequence[4] => last, status => code'`. They are written as IEC 61131-3 structure and array literals
//! because a pragma ends at its first `}` (so never JSON), and they are read here, where `baton check` sees
//! them, so that a malformed goal is an error in the editor rather than a fault on the robot.
//!
//! IEC 61131-3 structure and array literals in skill parameters (a goal `'(order := 5)'`, arguments `'[3,
//! T#2s]'`) and the mappings of a skill's answer to variables (`'sequence[4] => last'`), bounded by
//! `LITERAL_ELEMENTS_MAX`.

use crate::front::lexer::{lex, Kw, Tok, Token};
use crate::limits::LITERAL_ELEMENTS_MAX;
use crate::types::{unquote_string, Value};

/// A value written as an IEC 61131-3 literal.
#[derive(Clone, Debug, PartialEq)]
pub enum Literal {
    /// A number, a duration, a date or a boolean.
    Scalar(Value),
    /// A quoted string, unescaped.
    Text(String),
    /// `(field := literal, …)`, fields in the order written (names as written).
    Struct(Vec<(String, Literal)>),
    /// `[literal, …]`, repetitions `n(literal)` expanded.
    Array(Vec<Literal>),
}

impl Literal {
    /// The field called `name` (ignoring case), in a structure literal.
    pub fn field(&self, name: &str) -> Option<&Literal> {
        match self {
            Literal::Struct(fields) => fields.iter().find(|(n, _)| n.eq_ignore_ascii_case(name)).map(|(_, l)| l),
            _ => None,
        }
    }
}

/// One step of a path into a message: a field by name, or an element by index (from 0).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum PathPart {
    Field(String),
    Index(usize),
}

/// `sequence[4]`, `pose.position.x`, `[0]`.
pub type FieldPath = Vec<PathPart>;

/// Shows a path as it was written.
pub fn show_path(path: &[PathPart]) -> String {
    let mut out = String::new();
    for part in path {
        match part {
            PathPart::Field(f) if out.is_empty() => out.push_str(f),
            PathPart::Field(f) => {
                out.push('.');
                out.push_str(f);
            }
            PathPart::Index(i) => out.push_str(&format!("[{i}]")),
        }
    }
    out
}

struct Reader<'a> {
    text: &'a str,
    toks: &'a [Token],
    at: usize,
    elements: usize,
}

impl<'a> Reader<'a> {
    fn new(text: &'a str, toks: &'a [Token]) -> Reader<'a> {
        Reader { text, toks, at: 0, elements: 0 }
    }

    fn peek(&self) -> Tok {
        self.toks.get(self.at).map_or(Tok::Eof, |t| t.tok)
    }

    fn peek2(&self) -> Tok {
        self.toks.get(self.at + 1).map_or(Tok::Eof, |t| t.tok)
    }

    fn word(&self) -> String {
        let t = &self.toks[self.at];
        self.text[t.span.start as usize..t.span.end as usize].to_string()
    }

    fn bump(&mut self) {
        self.at += 1;
    }

    fn expect(&mut self, tok: Tok, what: &str) -> Result<(), String> {
        if self.peek() == tok {
            self.bump();
            Ok(())
        } else {
            Err(format!("expected {what}"))
        }
    }

    fn count(&mut self, n: usize) -> Result<(), String> {
        self.elements = self.elements.saturating_add(n);
        if self.elements > LITERAL_ELEMENTS_MAX {
            return Err(format!("more than {LITERAL_ELEMENTS_MAX} elements"));
        }
        Ok(())
    }

    fn literal(&mut self, depth: usize) -> Result<Literal, String> {
        if depth > 32 {
            return Err("nested more than 32 deep".to_string());
        }
        match self.peek() {
            Tok::LParen => {
                self.bump();
                let mut fields: Vec<(String, Literal)> = Vec::new();
                if self.peek() != Tok::RParen {
                    loop {
                        if !matches!(self.peek(), Tok::Ident | Tok::Kw(_)) {
                            return Err("expected a field name in `(field := value, …)`".to_string());
                        }
                        let name = self.word();
                        self.bump();
                        self.expect(Tok::Assign, &format!("`:=` after field `{name}`"))?;
                        let value = self.literal(depth + 1)?;
                        if fields.iter().any(|(n, _)| n.eq_ignore_ascii_case(&name)) {
                            return Err(format!("field `{name}` is given twice"));
                        }
                        self.count(1)?;
                        fields.push((name, value));
                        if self.peek() != Tok::Comma {
                            break;
                        }
                        self.bump();
                    }
                }
                self.expect(Tok::RParen, "`,` or `)` in a structure literal")?;
                Ok(Literal::Struct(fields))
            }
            Tok::LBracket => {
                self.bump();
                let mut items = Vec::new();
                if self.peek() != Tok::RBracket {
                    loop {
                        // `3(0)` repeats an element, as in an array's initial value.
                        if let (Tok::Int(n), Tok::LParen) = (self.peek(), self.peek2()) {
                            self.bump();
                            self.bump();
                            let n = usize::try_from(n).map_err(|_| "a repetition count is not negative".to_string())?;
                            self.count(n)?;
                            let item = self.literal(depth + 1)?;
                            self.expect(Tok::RParen, "`)` after a repeated element")?;
                            items.extend(std::iter::repeat_n(item, n));
                        } else {
                            self.count(1)?;
                            items.push(self.literal(depth + 1)?);
                        }
                        if self.peek() != Tok::Comma {
                            break;
                        }
                        self.bump();
                    }
                }
                self.expect(Tok::RBracket, "`,` or `]` in an array literal")?;
                Ok(Literal::Array(items))
            }
            _ => self.scalar(),
        }
    }

    fn scalar(&mut self) -> Result<Literal, String> {
        let negative = self.peek() == Tok::Minus;
        if negative {
            self.bump();
        }
        let sign = if negative { -1 } else { 1 };
        let lit = match self.peek() {
            Tok::Int(v) => Literal::Scalar(Value::Int(sign * v)),
            Tok::Real(v) => Literal::Scalar(Value::Real(sign as f64 * v)),
            Tok::Time(v) => Literal::Scalar(Value::Time(sign * v)),
            Tok::Date(v) | Tok::Tod(v) | Tok::Dt(v) if !negative => Literal::Scalar(Value::Time(v)),
            Tok::Kw(Kw::True) if !negative => Literal::Scalar(Value::Bool(true)),
            Tok::Kw(Kw::False) if !negative => Literal::Scalar(Value::Bool(false)),
            Tok::Str if !negative => {
                let quoted = self.word();
                Literal::Text(unquote_string(&quoted[1..quoted.len() - 1])?)
            }
            _ => return Err("expected a value: a number, a duration, TRUE, FALSE, a 'string', (…) or […]".to_string()),
        };
        self.bump();
        Ok(lit)
    }

    fn end(&self) -> Result<(), String> {
        match self.peek() {
            Tok::Eof => Ok(()),
            _ => Err(format!("unexpected `{}` after the value", self.word())),
        }
    }

    fn path(&mut self) -> Result<FieldPath, String> {
        let mut path = Vec::new();
        loop {
            match self.peek() {
                Tok::Ident | Tok::Kw(_) if path.is_empty() || self.toks[self.at - 1].tok == Tok::Dot => {
                    path.push(PathPart::Field(self.word()));
                    self.bump();
                }
                Tok::LBracket => {
                    self.bump();
                    let Tok::Int(i) = self.peek() else {
                        return Err("expected an index (0, 1, …) between `[` and `]`".to_string());
                    };
                    let i = usize::try_from(i).map_err(|_| "an index is not negative".to_string())?;
                    self.bump();
                    self.expect(Tok::RBracket, "`]`")?;
                    path.push(PathPart::Index(i));
                }
                _ => return Err("expected a field name or `[index]`".to_string()),
            }
            match self.peek() {
                Tok::Dot => self.bump(),
                Tok::LBracket => {}
                _ => return Ok(path),
            }
        }
    }
}

fn lexed(text: &str) -> Result<Vec<Token>, String> {
    let lexed = lex(text);
    if let Some(d) = lexed.diagnostics.first() {
        return Err(d.message.clone());
    }
    Ok(lexed.tokens)
}

/// Reads one literal, the whole text.
pub fn parse(text: &str) -> Result<Literal, String> {
    let toks = lexed(text)?;
    let mut r = Reader::new(text, &toks);
    let lit = r.literal(0)?;
    r.end()?;
    Ok(lit)
}

/// Reads a path alone: `pose.position.x`, `data`, `sequence[2]`.
pub fn parse_path(text: &str) -> Result<FieldPath, String> {
    let toks = lexed(text)?;
    let mut r = Reader::new(text, &toks);
    let path = r.path()?;
    r.end()?;
    Ok(path)
}

/// Reads `path => variable {, path => variable}`: where each part of a message goes. Variable names are
/// returned as written; the caller resolves them.
pub fn parse_mapping(text: &str) -> Result<Vec<(FieldPath, String)>, String> {
    let toks = lexed(text)?;
    let mut r = Reader::new(text, &toks);
    let mut out = Vec::new();
    loop {
        let path = r.path()?;
        r.expect(Tok::Arrow, &format!("`=>` after `{}`", show_path(&path)))?;
        if !matches!(r.peek(), Tok::Ident | Tok::Kw(_)) {
            return Err(format!("expected a variable after `{} =>`", show_path(&path)));
        }
        let mut var = r.word();
        r.bump();
        // A structure's field is a variable of its own, `pose.x`.
        while r.peek() == Tok::Dot && matches!(r.peek2(), Tok::Ident | Tok::Kw(_)) {
            r.bump();
            var.push('.');
            var.push_str(&r.word());
            r.bump();
        }
        r.count(1)?;
        out.push((path, var));
        match r.peek() {
            Tok::Comma => r.bump(),
            Tok::Eof => return Ok(out),
            _ => return Err(format!("unexpected `{}`: separate two mappings with `,`", r.word())),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn structures_arrays_and_scalars() {
        let lit = parse("(order := 5, pose := (x := 1.0, y := -2.5), name := 'a$'b', ok := TRUE, t := T#2s)").unwrap();
        assert_eq!(lit.field("ORDER"), Some(&Literal::Scalar(Value::Int(5))));
        let pose = lit.field("pose").unwrap();
        assert_eq!(pose.field("y"), Some(&Literal::Scalar(Value::Real(-2.5))));
        assert_eq!(lit.field("name"), Some(&Literal::Text("a'b".into())));
        assert_eq!(lit.field("t"), Some(&Literal::Scalar(Value::Time(2000))));
        assert_eq!(
            parse("[3, 2(0), -1]").unwrap(),
            Literal::Array(vec![
                Literal::Scalar(Value::Int(3)),
                Literal::Scalar(Value::Int(0)),
                Literal::Scalar(Value::Int(0)),
                Literal::Scalar(Value::Int(-1)),
            ])
        );
        assert_eq!(parse("()").unwrap(), Literal::Struct(vec![]));
        assert_eq!(parse("[]").unwrap(), Literal::Array(vec![]));
    }

    #[test]
    fn malformed_literals_say_why() {
        assert!(parse("(order = 5)").unwrap_err().contains("`:=`"));
        assert!(parse("(order := 5").unwrap_err().contains("`)`"));
        assert!(parse("(a := 1, a := 2)").unwrap_err().contains("twice"));
        assert!(parse("[1, 2] 3").unwrap_err().contains("after the value"));
        assert!(parse("{\"order\": 5}").is_err());
        assert!(parse("[100000000(0)]").unwrap_err().contains("elements"));
        let deep = "[".repeat(40) + &"]".repeat(40);
        assert!(parse(&deep).unwrap_err().contains("deep"));
    }

    #[test]
    fn mappings() {
        let m = parse_mapping("sequence[4] => last, pose.position.x => p.x, [0] => n").unwrap();
        assert_eq!(m[0].0, vec![PathPart::Field("sequence".into()), PathPart::Index(4)]);
        assert_eq!(m[0].1, "last");
        assert_eq!(show_path(&m[1].0), "pose.position.x");
        assert_eq!(m[1].1, "p.x");
        assert_eq!(m[2].0, vec![PathPart::Index(0)]);
        assert!(parse_mapping("sequence last").unwrap_err().contains("`=>`"));
        assert!(parse_mapping("a => ").unwrap_err().contains("variable"));
        assert!(parse_mapping("a => b c => d").unwrap_err().contains("`,`"));
        assert_eq!(parse_path("pose.position.x").unwrap().len(), 3);
        assert_eq!(parse_path("data[2]").unwrap(), vec![PathPart::Field("data".into()), PathPart::Index(2)]);
        assert!(parse_path("a b").is_err());
        assert!(parse_path("").is_err());
    }
}
