//! Structured Text from the chart model: expressions and statements printed so that Baton's parser reads back
//! the same tree (parentheses where precedence needs them, literals in a form the lexer takes).
//!
//! Structured Text from the model, parenthesised so that the parser reads back the same tree (tested by
//! printing and re-parsing).

use std::fmt::Write;

use crate::front::model::{Arg, BinOp, CaseLabel, Expr, ExprKind, Ident, Stmt, UnOp};
use crate::types::{quote_string, Type, Value};

/// The binding strength of a binary operator, as the parser's (higher binds tighter).
fn level(op: BinOp) -> u8 {
    match op {
        BinOp::Or => 1,
        BinOp::Xor => 2,
        BinOp::And => 3,
        BinOp::Eq | BinOp::Ne => 4,
        BinOp::Lt | BinOp::Le | BinOp::Gt | BinOp::Ge => 5,
        BinOp::Add | BinOp::Sub => 6,
        BinOp::Mul | BinOp::Div | BinOp::Mod => 7,
        BinOp::Pow => 8,
    }
}

/// A REAL literal the lexer reads as REAL: always with a fraction.
fn real(v: f64) -> String {
    let s = format!("{v:?}");
    match s.find(['e', 'E']) {
        Some(i) if !s[..i].contains('.') => format!("{}.0{}", &s[..i], &s[i..]),
        Some(_) => s,
        None if s.contains('.') => s,
        None => format!("{s}.0"),
    }
}

pub fn expr(e: &Expr) -> String {
    let mut out = String::new();
    write_expr(&mut out, e, 0);
    out
}

/// Writes `e`, in parentheses if it binds less tightly than `min` requires.
/// `name[i, j]`.
fn write_element(out: &mut String, name: &Ident, indices: &[Expr]) {
    out.push_str(&name.name);
    out.push('[');
    for (i, e) in indices.iter().enumerate() {
        if i > 0 {
            out.push_str(", ");
        }
        write_expr(out, e, 0);
    }
    out.push(']');
}

fn write_expr(out: &mut String, e: &Expr, min: u8) {
    match &e.kind {
        ExprKind::Bool(b) => out.push_str(if *b { "TRUE" } else { "FALSE" }),
        ExprKind::Int(v) if *v < 0 && min > 0 => {
            let _ = write!(out, "({v})");
        }
        ExprKind::Int(v) => {
            let _ = write!(out, "{v}");
        }
        ExprKind::Real(v) if *v < 0.0 && min > 0 => {
            let _ = write!(out, "({})", real(*v));
        }
        ExprKind::Real(v) => out.push_str(&real(*v)),
        ExprKind::Time(ms) if *ms < 0 => {
            let _ = write!(out, "(-T#{}ms)", ms.unsigned_abs());
        }
        ExprKind::Time(ms) => {
            let _ = write!(out, "T#{ms}ms");
        }
        ExprKind::Date(ms) => out.push_str(&Type::Date.show(&Value::Time(*ms))),
        ExprKind::Tod(ms) => out.push_str(&Type::Tod.show(&Value::Time(*ms))),
        ExprKind::Dt(ms) => out.push_str(&Type::Dt.show(&Value::Time(*ms))),
        ExprKind::Str(text) => out.push_str(&quote_string(text)),
        ExprKind::Name(id) => out.push_str(&id.name),
        ExprKind::Field(base, field) => {
            let _ = write!(out, "{}.{}", base.name, field.name);
        }
        ExprKind::IndexField(name, indices, field) => {
            write_element(out, name, indices);
            out.push('.');
            out.push_str(&field.name);
        }
        ExprKind::Index(name, indices) => write_element(out, name, indices),
        ExprKind::EnumValue(ty, value) => {
            let _ = write!(out, "{}#{}", ty.name, value.name);
        }
        ExprKind::Call(callee, args) => {
            out.push_str(&callee.name);
            write_args(out, args);
        }
        ExprKind::Unary(op, a) => {
            // A unary operator binds tighter than any binary one but `**`.
            let paren = min > 8;
            if paren {
                out.push('(');
            }
            out.push_str(match op {
                UnOp::Neg => "-",
                UnOp::Not => "NOT ",
            });
            write_expr(out, a, 9);
            if paren {
                out.push(')');
            }
        }
        ExprKind::Binary(op, a, b) => {
            let l = level(*op);
            let paren = l < min;
            if paren {
                out.push('(');
            }
            write_expr(out, a, l);
            let _ = write!(out, " {} ", op.symbol());
            // Left-associative: a right operand of the same level needs parentheses.
            write_expr(out, b, l + 1);
            if paren {
                out.push(')');
            }
        }
    }
}

fn write_args(out: &mut String, args: &[Arg]) {
    out.push('(');
    for (i, a) in args.iter().enumerate() {
        if i > 0 {
            out.push_str(", ");
        }
        if let Some(name) = &a.name {
            if a.negated {
                out.push_str("NOT ");
            }
            let _ = write!(out, "{} {} ", name.name, if a.output { "=>" } else { ":=" });
        }
        write_expr(out, &a.value, 0);
    }
    out.push(')');
}

/// Statements, one per line, indented by `depth` levels of two spaces.
pub fn statements(body: &[Stmt], depth: usize) -> String {
    let mut out = String::new();
    write_statements(&mut out, body, depth);
    out
}

fn write_statements(out: &mut String, body: &[Stmt], depth: usize) {
    let pad = "  ".repeat(depth);
    for stmt in body {
        match stmt {
            Stmt::Assign { target, value, .. } => {
                let _ = writeln!(out, "{pad}{} := {};", expr(target), expr(value));
            }
            Stmt::If { branches, otherwise, .. } => {
                for (i, (cond, stmts)) in branches.iter().enumerate() {
                    let kw = if i == 0 { "IF" } else { "ELSIF" };
                    let _ = writeln!(out, "{pad}{kw} {} THEN", expr(cond));
                    write_statements(out, stmts, depth + 1);
                }
                if !otherwise.is_empty() {
                    let _ = writeln!(out, "{pad}ELSE");
                    write_statements(out, otherwise, depth + 1);
                }
                let _ = writeln!(out, "{pad}END_IF;");
            }
            Stmt::Call { callee, args, .. } => {
                let _ = write!(out, "{pad}{}", callee.name);
                write_args(out, args);
                out.push_str(";\n");
            }
            Stmt::Case { selector, arms, otherwise, .. } => {
                let _ = writeln!(out, "{pad}CASE {} OF", expr(selector));
                for arm in arms {
                    let labels: Vec<String> = arm
                        .labels
                        .iter()
                        .map(|l| match l {
                            CaseLabel::Value(v) => expr(v),
                            CaseLabel::Range(lo, hi) => format!("{}..{}", expr(lo), expr(hi)),
                        })
                        .collect();
                    let _ = writeln!(out, "{pad}  {}:", labels.join(", "));
                    write_statements(out, &arm.body, depth + 2);
                }
                if !otherwise.is_empty() {
                    let _ = writeln!(out, "{pad}ELSE");
                    write_statements(out, otherwise, depth + 2);
                }
                let _ = writeln!(out, "{pad}END_CASE;");
            }
            Stmt::For { var, from, to, by, body, .. } => {
                let by = by.as_ref().map(|b| format!(" BY {}", expr(b))).unwrap_or_default();
                let _ = writeln!(out, "{pad}FOR {} := {} TO {}{by} DO", var.name, expr(from), expr(to));
                write_statements(out, body, depth + 1);
                let _ = writeln!(out, "{pad}END_FOR;");
            }
            Stmt::While { condition, body, .. } => {
                let _ = writeln!(out, "{pad}WHILE {} DO", expr(condition));
                write_statements(out, body, depth + 1);
                let _ = writeln!(out, "{pad}END_WHILE;");
            }
            Stmt::Repeat { body, until, .. } => {
                let _ = writeln!(out, "{pad}REPEAT");
                write_statements(out, body, depth + 1);
                let _ = writeln!(out, "{pad}UNTIL {}", expr(until));
                let _ = writeln!(out, "{pad}END_REPEAT;");
            }
            Stmt::Exit { .. } => {
                let _ = writeln!(out, "{pad}EXIT;");
            }
            Stmt::Return { .. } => {
                let _ = writeln!(out, "{pad}RETURN;");
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::front::parser::{parse_fragment, Fragment, FragmentKind};

    fn reparse(text: &str, kind: FragmentKind) -> Fragment {
        let parsed = parse_fragment(text, |i| i, kind);
        assert!(parsed.diagnostics.is_empty(), "{text}: {:?}", parsed.diagnostics);
        parsed.fragment.expect("a fragment")
    }

    fn same_expr(text: &str) {
        let Fragment::Expr(e) = reparse(text, FragmentKind::Expr) else { panic!("an expression") };
        let printed = expr(&e);
        let Fragment::Expr(again) = reparse(&printed, FragmentKind::Expr) else { panic!("an expression") };
        assert_eq!(expr(&again), printed, "{text} printed as {printed}");
        assert_eq!(strip(&format!("{:?}", e.kind)), strip(&format!("{:?}", again.kind)), "{text} vs {printed}");
    }

    /// The tree without its spans.
    fn strip(debug: &str) -> String {
        let mut out = String::new();
        let mut rest = debug;
        while let Some(i) = rest.find("span: Span") {
            out.push_str(&rest[..i]);
            let end = rest[i..].find('}').map_or(rest.len(), |j| i + j + 1);
            rest = &rest[end..];
        }
        out.push_str(rest);
        out
    }

    #[test]
    fn expressions_print_back_to_the_same_tree() {
        for text in [
            "a AND (b OR c)",
            "(a AND b) OR c",
            "a - (b - c)",
            "a - b - c",
            "-x ** 2",
            "NOT (a = b) XOR c",
            "x * -1 + 2.5E10 / 3.0",
            "t1.Q AND S1.T >= T#1500ms",
            "LIMIT(MN := 0, IN := x * 2, MX := 10) + ABS(-3)",
            "2 ** 3 ** 2",
            "-T#5ms < t",
        ] {
            same_expr(text);
        }
    }

    #[test]
    fn statements_print_back_to_the_same_tree() {
        let text = "IF a THEN x := 1; ELSIF b THEN x := 2; ELSE x := 3; END_IF;
            CASE k OF 1, 2: y := 1; 3..5: y := 2; ELSE y := 0; END_CASE;
            FOR i := 10 TO 0 BY -2 DO IF i = 4 THEN EXIT; END_IF; END_FOR;
            WHILE n < 3 DO n := n + 1; END_WHILE;
            REPEAT n := n - 1; UNTIL n <= 0 END_REPEAT;
            t1(IN := go, PT := T#2s, Q => done, NOT Q => waiting); c(x, 3); t1.PT := T#1s; RETURN;";
        let Fragment::Statements(body) = reparse(text, FragmentKind::Statements) else { panic!("statements") };
        let printed = statements(&body, 0);
        let Fragment::Statements(again) = reparse(&printed, FragmentKind::Statements) else { panic!("statements") };
        assert_eq!(strip(&format!("{body:?}")), strip(&format!("{again:?}")), "printed:\n{printed}");
    }
}
