//! A value given as JSON — `baton set`, `baton sim`'s input scripts, a scenario's inputs, an operator's `set` —
//! read as a value of a chart variable's type.

use crate::front::lexer::{lex, Tok};
use crate::types::{Type, Value};

/// A JSON value as a value of type `ty`: a boolean, an integer in range, a number, a duration as milliseconds or
/// a `T#…` literal, an enumeration value by name, or a string that fits the variable's length.
pub fn parse(ty: &Type, json: &serde_json::Value) -> Option<Value> {
    match ty {
        Type::Bool => json.as_bool().map(Value::Bool),
        Type::Int(k) => json.as_i64().filter(|v| k.contains(*v)).map(Value::Int),
        Type::Real { .. } => json.as_f64().map(|r| ty.coerce(Value::Real(r))),
        Type::Time | Type::Date | Type::Tod | Type::Dt => match json {
            serde_json::Value::String(s) => match lex(s).tokens[..] {
                [t, e] if e.tok == Tok::Eof => match (ty, t.tok) {
                    (Type::Time, Tok::Time(ms))
                    | (Type::Date, Tok::Date(ms))
                    | (Type::Tod, Tok::Tod(ms))
                    | (Type::Dt, Tok::Dt(ms)) => Some(Value::Time(ms)),
                    _ => None,
                },
                _ => None,
            },
            other => other.as_i64().map(Value::Time),
        },
        Type::Enum(e) => match json {
            serde_json::Value::String(s) => {
                let name = s.rsplit('#').next().unwrap_or(s);
                e.values.iter().position(|v| v.eq_ignore_ascii_case(name)).map(|i| Value::Int(i as i64))
            }
            other => other.as_i64().filter(|&i| i >= 0 && (i as usize) < e.values.len()).map(Value::Int),
        },
        // Text as it is, or as an ST literal (`'go'`, as value records show it); a number as its digits.
        Type::Str { .. } => {
            let text = match json {
                serde_json::Value::String(s) if s.len() >= 2 && s.starts_with('\'') && s.ends_with('\'') => {
                    crate::types::unquote_string(&s[1..s.len() - 1]).unwrap_or_else(|_| s.clone())
                }
                serde_json::Value::String(s) => s.clone(),
                serde_json::Value::Number(n) => n.to_string(),
                _ => return None,
            };
            Some(Value::string(text)).filter(|v| ty.fits(v))
        }
        Type::Unsupported(_) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_string_is_set_from_text_an_st_literal_or_a_number_and_refused_too_long_or_of_another_kind() {
        let ty = Type::Str { max: 3 };
        let set = |json| parse(&ty, &json);
        assert_eq!(set(serde_json::json!("go")), Some(Value::string("go")));
        assert_eq!(set(serde_json::json!("'a$'b'")), Some(Value::string("a'b")), "an ST literal is unquoted");
        assert_eq!(set(serde_json::json!(42)), Some(Value::string("42")));
        assert_eq!(set(serde_json::json!("toolong")), None);
        assert_eq!(set(serde_json::json!(true)), None);
    }
}
