//! ST expressions by precedence climbing; AND, OR and XOR chains are built balanced (`model::fold_balanced`).

use crate::front::diag::{Diagnostic, Span};
use crate::front::lexer::{Kw, Tok};
use crate::front::model::{BinOp, Expr, ExprKind, Ident, UnOp};
use crate::limits::NESTING_DEPTH_MAX;

use super::{Failed, PResult, Parser};

impl Parser<'_> {
    pub fn expr(&mut self) -> PResult<Expr> {
        self.binary(0)
    }

    /// Operators of a higher level than `min_level`, as a chain: each operand parsed one level deeper, then the
    /// chain folded (`fold`). A chain's length is bounded like any nesting: its tree is as deep as it is long,
    /// but for runs of one associative operator (`a OR b OR c …`), which are built balanced.
    pub(super) fn binary(&mut self, min_level: u8) -> PResult<Expr> {
        let mut operands = vec![self.unary()?];
        let mut ops: Vec<(BinOp, Span)> = Vec::new();
        loop {
            let (op, level) = match self.peek() {
                Tok::Kw(Kw::Or) => (BinOp::Or, 1),
                Tok::Kw(Kw::Xor) => (BinOp::Xor, 2),
                Tok::Kw(Kw::And) | Tok::Amp => (BinOp::And, 3),
                Tok::Eq => (BinOp::Eq, 4),
                Tok::Ne => (BinOp::Ne, 4),
                Tok::Lt => (BinOp::Lt, 5),
                Tok::Le => (BinOp::Le, 5),
                Tok::Gt => (BinOp::Gt, 5),
                Tok::Ge => (BinOp::Ge, 5),
                Tok::Plus => (BinOp::Add, 6),
                Tok::Minus => (BinOp::Sub, 6),
                Tok::Star => (BinOp::Mul, 7),
                Tok::Slash => (BinOp::Div, 7),
                Tok::Kw(Kw::Mod) => (BinOp::Mod, 7),
                Tok::StarStar => (BinOp::Pow, 8),
                _ => break,
            };
            if level <= min_level {
                break;
            }
            let at = self.bump().span;
            self.nest()?;
            let rhs = self.binary(level);
            self.depth -= 1;
            operands.push(rhs?);
            ops.push((op, at));
        }
        self.fold(operands, ops)
    }

    /// Folds a chain left, as IEC reads it, except that a run of one associative operator becomes a balanced
    /// tree; a tree deeper than the nesting limit allows here is an error at the operator that made it so.
    pub(super) fn fold(&mut self, operands: Vec<Expr>, ops: Vec<(BinOp, Span)>) -> PResult<Expr> {
        let mut operands = operands.into_iter();
        let Some(mut acc) = operands.next() else { return Err(self.error_here("an expression")) };
        let mut height = acc.height();
        let mut i = 0;
        while i < ops.len() {
            let (op, at) = ops[i];
            let mut j = i + 1;
            while op.associative() && j < ops.len() && ops[j].0 == op {
                j += 1;
            }
            let run: Vec<Expr> = operands.by_ref().take(j - i).collect();
            let tallest = run.iter().map(Expr::height).max().unwrap_or(0).max(height);
            if op.associative() {
                let n = run.len() + 1;
                height = tallest + (usize::BITS - (n - 1).leading_zeros()) as usize;
                acc = Expr::balanced(op, std::iter::once(acc).chain(run).collect());
            } else {
                height = tallest + 1;
                let rhs = run.into_iter().next().expect("one operand per operator");
                let span = acc.span.to(rhs.span);
                acc = Expr { kind: ExprKind::Binary(op, Box::new(acc), Box::new(rhs)), span };
            }
            if self.depth + height - 1 > NESTING_DEPTH_MAX {
                let message = format!(
                    "nested more than {NESTING_DEPTH_MAX} levels deep (a chain of operators nests as deep as it is \
                     long: give parts of it names of their own)"
                );
                self.diags.push(Diagnostic::error(at, message));
                return Err(Failed);
            }
            i = j;
        }
        Ok(acc)
    }

    pub(super) fn unary(&mut self) -> PResult<Expr> {
        let op = match self.peek() {
            Tok::Minus => UnOp::Neg,
            Tok::Kw(Kw::Not) => UnOp::Not,
            _ => return self.primary(),
        };
        let start = self.bump().span;
        self.nest()?;
        let operand = self.unary();
        self.depth -= 1;
        let operand = operand?;
        // Fold a minus sign into a numeric literal so that `-32768` is one INT literal.
        let span = start.to(operand.span);
        let kind = match (op, &operand.kind) {
            (UnOp::Neg, ExprKind::Int(v)) => ExprKind::Int(v.wrapping_neg()),
            (UnOp::Neg, ExprKind::Real(v)) => ExprKind::Real(-v),
            (UnOp::Neg, ExprKind::Time(v)) => ExprKind::Time(-v),
            _ => ExprKind::Unary(op, Box::new(operand)),
        };
        Ok(Expr { kind, span })
    }

    pub(super) fn primary(&mut self) -> PResult<Expr> {
        let span = self.span();
        let kind = match self.peek() {
            Tok::Int(v) => ExprKind::Int(v),
            Tok::Real(v) => ExprKind::Real(v),
            Tok::Time(v) => ExprKind::Time(v),
            Tok::Date(v) => ExprKind::Date(v),
            Tok::Tod(v) => ExprKind::Tod(v),
            Tok::Dt(v) => ExprKind::Dt(v),
            Tok::Str => {
                let raw = self.text(span).to_string();
                let problem = if raw.starts_with('"') {
                    Err("a double-quoted literal is a WSTRING, which Baton does not execute: write 'text'".to_string())
                } else {
                    crate::types::unquote_string(&raw[1..raw.len() - 1])
                };
                // A bad literal is reported and read as its raw text, so that the body around it is checked too.
                match problem {
                    Ok(text) => ExprKind::Str(text),
                    Err(message) => {
                        self.diags.push(Diagnostic::error(span, message));
                        ExprKind::Str(raw[1..raw.len() - 1].to_string())
                    }
                }
            }
            Tok::Kw(Kw::True) => ExprKind::Bool(true),
            Tok::Kw(Kw::False) => ExprKind::Bool(false),
            Tok::LParen => {
                self.bump();
                self.nest()?;
                let inner = self.expr();
                self.depth -= 1;
                let inner = inner?;
                let close = self.expect(Tok::RParen, "`)`")?;
                return Ok(Expr { kind: inner.kind, span: span.to(close.span) });
            }
            // The standard functions named like operators, called as functions: `OR(a, b, c)`, `AND(…)`,
            // `XOR(…)`, `MOD(a, b)` (IEC 61131-3 tables 27 and 28; the Annex F example writes `OR(JOG_PB, …)`).
            Tok::Kw(Kw::And | Kw::Or | Kw::Xor | Kw::Mod) if self.peek_at(1) == Tok::LParen => {
                self.bump();
                let name = Ident { name: self.text(span).to_ascii_uppercase(), span };
                let (args, close) = self.args()?;
                return Ok(Expr { kind: ExprKind::Call(name, args), span: span.to(close.span) });
            }
            Tok::Ident => {
                let name = self.ident("a name")?;
                if self.peek() == Tok::LParen {
                    let (args, close) = self.args()?;
                    let span = name.span.to(close.span);
                    return Ok(Expr { kind: ExprKind::Call(name, args), span });
                }
                if self.eat(Tok::Hash) {
                    let value = self.ident("an enumeration value after `#`")?;
                    let span = name.span.to(value.span);
                    return Ok(Expr { kind: ExprKind::EnumValue(name, value), span });
                }
                return self.designator(name);
            }
            _ => return Err(self.error_here("an expression")),
        };
        self.bump();
        Ok(Expr { kind, span })
    }
}
