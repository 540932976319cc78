//! ST statements: assignments, calls with their arguments, IF, CASE, FOR, WHILE, REPEAT, and the places they write.

use crate::front::lexer::{Kw, Tok, Token};
use crate::front::model::{Arg, CaseArm, CaseLabel, Expr, ExprKind, Ident, Stmt};

use super::{PResult, Parser};

impl Parser<'_> {
    pub(super) fn statements(&mut self) -> PResult<Vec<Stmt>> {
        let mut out = Vec::new();
        loop {
            match self.peek() {
                Tok::Semi => {
                    self.bump();
                }
                Tok::Kw(Kw::If) => out.push(self.nested(Parser::if_stmt_inner)?),
                Tok::Kw(Kw::Case) => out.push(self.nested(Parser::case_stmt)?),
                Tok::Kw(Kw::For) => out.push(self.nested(Parser::for_stmt)?),
                Tok::Kw(Kw::While) => out.push(self.nested(Parser::while_stmt)?),
                Tok::Kw(Kw::Repeat) => out.push(self.nested(Parser::repeat_stmt)?),
                Tok::Kw(kw @ (Kw::Exit | Kw::Return)) => {
                    let span = self.bump().span;
                    self.expect(Tok::Semi, "`;`")?;
                    out.push(if kw == Kw::Exit { Stmt::Exit { span } } else { Stmt::Return { span } });
                }
                // An enumeration value ending the statements of the arm before it: `OPEN:`, `VALVE#OPEN:`.
                Tok::Ident
                    if self.in_case > 0
                        && matches!(self.peek_at(1), Tok::Colon | Tok::Comma | Tok::DotDot | Tok::Hash) =>
                {
                    return Ok(out)
                }
                Tok::Ident if self.peek_at(1) == Tok::LParen || self.dotted_call() => {
                    let callee = self.dotted_callee()?;
                    let (args, close) = self.args()?;
                    let semi = self.expect(Tok::Semi, "`;`")?;
                    let _ = close;
                    out.push(Stmt::Call { span: callee.span.to(semi.span), callee, args });
                }
                Tok::Ident => {
                    let target = self.place()?;
                    self.expect(Tok::Assign, "`:=`")?;
                    let value = self.expr()?;
                    let semi = self.expect(Tok::Semi, "`;`")?;
                    out.push(Stmt::Assign { span: target.span.to(semi.span), target, value });
                }
                Tok::Kw(
                    Kw::EndAction
                    | Kw::Action
                    | Kw::EndFunctionBlock
                    | Kw::EndFunction
                    | Kw::Elsif
                    | Kw::Else
                    | Kw::EndIf
                    | Kw::EndCase
                    | Kw::EndFor
                    | Kw::EndWhile
                    | Kw::Until
                    | Kw::EndRepeat,
                )
                | Tok::Eof => return Ok(out),
                // A CASE arm's labels end the statements of the arm before it.
                Tok::Int(_) | Tok::Minus if self.in_case > 0 => return Ok(out),
                _ => {
                    return Err(self.error_here("a statement (`variable := expression;`, `IF`, `CASE`, `FOR`, …)"));
                }
            }
        }
    }

    /// Whether a statement here is a call of a dotted name: `m.Stop();`, `cell.arm.Home();` (an action of a
    /// function block instance).
    pub(super) fn dotted_call(&self) -> bool {
        let mut k = 1;
        while self.peek_at(k) == Tok::Dot && self.peek_at(k + 1) == Tok::Ident {
            k += 2;
        }
        k > 1 && self.peek_at(k) == Tok::LParen
    }

    /// The name a call statement calls, its parts joined by `.`.
    pub(super) fn dotted_callee(&mut self) -> PResult<Ident> {
        let mut callee = self.ident("a function block instance")?;
        while self.peek() == Tok::Dot {
            self.bump();
            let part = self.ident("an action name")?;
            callee = Ident { name: format!("{}.{}", callee.name, part.name), span: callee.span.to(part.span) };
        }
        Ok(callee)
    }

    /// An assignment's target: a variable, or a member of an instance (`t1.PT`).
    pub(super) fn place(&mut self) -> PResult<Expr> {
        let name = self.ident("a variable")?;
        self.designator(name)
    }

    /// What a name designates: a variable, `step.X`, an instance's or a structure's member (`a.b.c`), an array
    /// element (`a[i]`), a field of one (`pts[i].x`).
    pub(super) fn designator(&mut self, mut name: Ident) -> PResult<Expr> {
        // `a.b.c`, `a.b[i]`: the path up to the last member is one name (a structure's fields are
        // variables named by their path).
        while self.peek() == Tok::Dot
            && self.peek_at(1) == Tok::Ident
            && matches!(self.peek_at(2), Tok::Dot | Tok::LBracket)
        {
            self.bump();
            let part = self.ident("a member")?;
            name = Ident { name: format!("{}.{}", name.name, part.name), span: name.span.to(part.span) };
        }
        if self.peek() == Tok::LBracket {
            let element = self.index(name)?;
            if !(self.peek() == Tok::Dot && self.peek_at(1) == Tok::Ident) {
                return Ok(element);
            }
            self.bump();
            let field = self.ident("a field after `.`")?;
            let span = element.span.to(field.span);
            let ExprKind::Index(name, indices) = element.kind else { unreachable!("an index expression") };
            let constant: Option<Vec<String>> = indices
                .iter()
                .map(|i| match i.kind {
                    ExprKind::Int(v) => Some(v.to_string()),
                    _ => None,
                })
                .collect();
            return Ok(match constant {
                Some(labels) => {
                    let base = Ident { name: format!("{}[{}]", name.name, labels.join(",")), span: element.span };
                    Expr { kind: ExprKind::Field(base, field), span }
                }
                None => Expr { kind: ExprKind::IndexField(name, indices, field), span },
            });
        }
        if self.eat(Tok::Dot) {
            let field = self.ident("a member such as `X`, `T` or `Q` after `.`")?;
            let span = name.span.to(field.span);
            return Ok(Expr { kind: ExprKind::Field(name, field), span });
        }
        Ok(Expr { span: name.span, kind: ExprKind::Name(name) })
    }

    /// `( … )` of a call: formal (`IN := x`, `Q => y`, `NOT Q => y`) and non-formal arguments.
    /// The arguments are one level deeper than the call.
    pub(super) fn args(&mut self) -> PResult<(Vec<Arg>, Token)> {
        self.expect(Tok::LParen, "`(`")?;
        if let Some(close) = self.peek_eat(Tok::RParen) {
            return Ok((Vec::new(), close));
        }
        self.nest()?;
        let args = self.arg_list();
        self.depth -= 1;
        args
    }

    pub(super) fn arg_list(&mut self) -> PResult<(Vec<Arg>, Token)> {
        let mut args = Vec::new();
        loop {
            let start = self.span();
            let negated =
                self.peek() == Tok::Kw(Kw::Not) && self.peek_at(1) == Tok::Ident && self.peek_at(2) == Tok::Arrow;
            if negated {
                self.bump();
            }
            let formal = self.peek() == Tok::Ident && matches!(self.peek_at(1), Tok::Assign | Tok::Arrow);
            let arg = if formal {
                let name = self.ident("a parameter")?;
                let output = self.bump().tok == Tok::Arrow;
                let value = if output { self.place()? } else { self.expr()? };
                Arg { span: start.to(value.span), name: Some(name), output, negated, value }
            } else {
                let value = self.expr()?;
                Arg { span: value.span, name: None, output: false, negated: false, value }
            };
            args.push(arg);
            if self.eat(Tok::Comma) {
                continue;
            }
            let close = self.expect(Tok::RParen, "`,` or `)`")?;
            return Ok((args, close));
        }
    }

    /// `[i, j]` after an array's name: its indices are one level deeper.
    pub(super) fn index(&mut self, name: Ident) -> PResult<Expr> {
        self.bump();
        self.nest()?;
        let indices = self.index_list();
        self.depth -= 1;
        let indices = indices?;
        let close = self.expect(Tok::RBracket, "`,` or `]`")?;
        let span = name.span.to(close.span);
        Ok(Expr { kind: ExprKind::Index(name, indices), span })
    }

    pub(super) fn index_list(&mut self) -> PResult<Vec<Expr>> {
        let mut indices = vec![self.expr()?];
        while self.eat(Tok::Comma) {
            indices.push(self.expr()?);
        }
        Ok(indices)
    }

    pub(super) fn case_stmt(&mut self) -> PResult<Stmt> {
        let start = self.bump().span;
        let selector = self.expr()?;
        self.expect(Tok::Kw(Kw::Of), "`OF`")?;
        let mut arms = Vec::new();
        let mut otherwise = Vec::new();
        loop {
            match self.peek() {
                Tok::Kw(Kw::Else) => {
                    self.bump();
                    otherwise = self.case_body()?;
                }
                Tok::Kw(Kw::EndCase) => break,
                _ => {
                    let mut labels = Vec::new();
                    loop {
                        let low = self.expr()?;
                        if self.eat(Tok::DotDot) {
                            labels.push(CaseLabel::Range(low, self.expr()?));
                        } else {
                            labels.push(CaseLabel::Value(low));
                        }
                        if !self.eat(Tok::Comma) {
                            break;
                        }
                    }
                    self.expect(Tok::Colon, "`:` after the CASE labels")?;
                    arms.push(CaseArm { labels, body: self.case_body()? });
                }
            }
        }
        let end = self.expect(Tok::Kw(Kw::EndCase), "`END_CASE`")?;
        self.eat(Tok::Semi);
        Ok(Stmt::Case { selector, arms, otherwise, span: start.to(end.span) })
    }

    pub(super) fn case_body(&mut self) -> PResult<Vec<Stmt>> {
        self.in_case += 1;
        let body = self.statements();
        self.in_case -= 1;
        body
    }

    pub(super) fn for_stmt(&mut self) -> PResult<Stmt> {
        let start = self.bump().span;
        let var = self.ident("the loop variable")?;
        self.expect(Tok::Assign, "`:=`")?;
        let from = self.expr()?;
        self.expect(Tok::Kw(Kw::To), "`TO`")?;
        let to = self.expr()?;
        let by = if self.eat(Tok::Kw(Kw::By)) { Some(self.expr()?) } else { None };
        self.expect(Tok::Kw(Kw::Do), "`DO`")?;
        let body = self.loop_body()?;
        let end = self.expect(Tok::Kw(Kw::EndFor), "`END_FOR`")?;
        self.eat(Tok::Semi);
        Ok(Stmt::For { var, from, to, by, body, span: start.to(end.span) })
    }

    pub(super) fn while_stmt(&mut self) -> PResult<Stmt> {
        let start = self.bump().span;
        let condition = self.expr()?;
        self.expect(Tok::Kw(Kw::Do), "`DO`")?;
        let body = self.loop_body()?;
        let end = self.expect(Tok::Kw(Kw::EndWhile), "`END_WHILE`")?;
        self.eat(Tok::Semi);
        Ok(Stmt::While { condition, body, span: start.to(end.span) })
    }

    pub(super) fn repeat_stmt(&mut self) -> PResult<Stmt> {
        let start = self.bump().span;
        let body = self.loop_body()?;
        self.expect(Tok::Kw(Kw::Until), "`UNTIL`")?;
        let until = self.expr()?;
        let end = self.expect(Tok::Kw(Kw::EndRepeat), "`END_REPEAT`")?;
        self.eat(Tok::Semi);
        Ok(Stmt::Repeat { body, until, span: start.to(end.span) })
    }

    /// A loop's body: a CASE arm around the loop does not end it at a number.
    pub(super) fn loop_body(&mut self) -> PResult<Vec<Stmt>> {
        let outer = std::mem::take(&mut self.in_case);
        let body = self.statements();
        self.in_case = outer;
        body
    }

    pub(super) fn if_stmt_inner(&mut self) -> PResult<Stmt> {
        let start = self.bump().span;
        let mut branches = Vec::new();
        let cond = self.expr()?;
        self.expect(Tok::Kw(Kw::Then), "`THEN`")?;
        branches.push((cond, self.statements()?));
        let mut otherwise = Vec::new();
        loop {
            match self.peek() {
                Tok::Kw(Kw::Elsif) => {
                    self.bump();
                    let cond = self.expr()?;
                    self.expect(Tok::Kw(Kw::Then), "`THEN`")?;
                    branches.push((cond, self.statements()?));
                }
                Tok::Kw(Kw::Else) => {
                    self.bump();
                    otherwise = self.statements()?;
                }
                _ => break,
            }
        }
        let end = self.expect(Tok::Kw(Kw::EndIf), "`END_IF`")?;
        self.eat(Tok::Semi);
        Ok(Stmt::If { branches, otherwise, span: start.to(end.span) })
    }
}
