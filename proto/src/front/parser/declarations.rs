//! Declarations: a file's TYPE blocks, FUNCTIONs, PROGRAMs and FUNCTION_BLOCKs, and their VAR blocks.

use crate::front::diag::{Diagnostic, Span};
use crate::front::lexer::{Kw, Tok};
use crate::front::model::{
    ArraySpec, Broken, Chart, FbAction, FbDef, Ident, InitRun, PouKind, TypeDef, TypeKind, VarDecl, VarSection,
};

use super::{is_element_start, is_top_level, is_var_block, Failed, PResult, Parser};

impl Parser<'_> {
    pub(super) fn file(&mut self) -> Vec<Chart> {
        let mut charts = Vec::new();
        let mut bare: Option<Chart> = None;
        let mut bare_vars = Vec::new();
        loop {
            match self.peek() {
                Tok::Eof => break,
                Tok::Kw(Kw::Program) => charts.extend(self.pou(PouKind::Program, Kw::EndProgram)),
                Tok::Kw(Kw::FunctionBlock) => charts.extend(self.pou(PouKind::FunctionBlock, Kw::EndFunctionBlock)),
                Tok::Kw(Kw::Function) => self.function(),
                Tok::Kw(Kw::Configuration) => self.skip_block(Kw::EndConfiguration),
                Tok::Kw(Kw::Type) => self.type_block(),
                tok if is_var_block(tok) => {
                    let vars = self.var_block();
                    match &mut bare {
                        Some(chart) => chart.vars.extend(vars),
                        None => bare_vars.extend(vars),
                    }
                }
                tok if is_element_start(tok) => {
                    let chart = bare.get_or_insert_with(|| {
                        let span = self.toks[self.pos].span;
                        let name = Ident { name: "main".to_string(), span };
                        Chart { vars: std::mem::take(&mut bare_vars), ..Chart::empty(name, PouKind::Bare, span) }
                    });
                    self.element(chart);
                    chart.span = chart.span.to(self.prev_span());
                }
                _ => {
                    self.error_here("PROGRAM, FUNCTION_BLOCK or an SFC element");
                    self.bump();
                    while !is_top_level(self.peek()) && self.peek() != Tok::Eof {
                        self.bump();
                    }
                }
            }
        }
        if let Some(chart) = &mut bare {
            chart.broken.absorb(std::mem::take(&mut self.broken_vars));
        }
        charts.extend(bare);
        charts
    }

    /// `TYPE name : (A, B) := B; name : INT (0..100); name : INT; … END_TYPE`. What Baton does not execute (a
    /// structure, an array) is kept as `Unsupported`, naming the construct.
    pub(super) fn type_block(&mut self) {
        let start = self.bump().span;
        loop {
            match self.peek() {
                Tok::Kw(Kw::EndType) => {
                    self.bump();
                    self.eat(Tok::Semi);
                    return;
                }
                Tok::Eof => {
                    self.diags.push(Diagnostic::error(start, "`TYPE` is never closed: expected `END_TYPE`"));
                    return;
                }
                _ => {
                    if let Ok(t) = self.type_decl() {
                        self.types.push(t);
                    } else {
                        while !matches!(self.peek(), Tok::Semi | Tok::Kw(Kw::EndType) | Tok::Eof) {
                            self.bump();
                        }
                        self.eat(Tok::Semi);
                    }
                }
            }
        }
    }

    pub(super) fn type_decl(&mut self) -> PResult<TypeDef> {
        let name = self.ident("a type name")?;
        self.expect(Tok::Colon, "`:`")?;
        let kind = if self.eat(Tok::LParen) {
            let mut values = vec![self.ident("an enumeration value")?];
            while self.eat(Tok::Comma) {
                values.push(self.ident("an enumeration value")?);
            }
            self.expect(Tok::RParen, "`,` or `)`")?;
            let init = if self.eat(Tok::Assign) { Some(self.ident("an enumeration value")?) } else { None };
            TypeKind::Enum { values, init }
        } else if self.peek() == Tok::Ident {
            let base = self.type_ident("a type")?;
            if base.key().starts_with("STRING") {
                TypeKind::Alias(base)
            } else if self.eat(Tok::LParen) {
                let low = self.signed_int()?;
                self.expect(Tok::DotDot, "`..`")?;
                let high = self.signed_int()?;
                self.expect(Tok::RParen, "`)`")?;
                TypeKind::Subrange { base, low, high }
            } else if base.key() == "ARRAY" {
                TypeKind::Array(self.array_spec(base.span)?)
            } else if matches!(self.peek(), Tok::LBracket) || base.key() == "WSTRING" {
                let what = "wide strings (WSTRING)";
                while !matches!(self.peek(), Tok::Semi | Tok::Kw(Kw::EndType) | Tok::Eof) {
                    self.bump();
                }
                TypeKind::Unsupported(what.to_string())
            } else if base.key() == "STRUCT" {
                let end = |p: &Self| p.peek() == Tok::Ident && p.text(p.span()).eq_ignore_ascii_case("END_STRUCT");
                let mut fields = Vec::new();
                while !end(self) && !matches!(self.peek(), Tok::Eof | Tok::Kw(Kw::EndType)) {
                    self.declaration(VarSection::Local, false, &mut fields)?;
                }
                if !end(self) {
                    return Err(self.error_here("`END_STRUCT`"));
                }
                self.bump();
                TypeKind::Struct(fields)
            } else {
                TypeKind::Alias(base)
            }
        } else {
            return Err(self.error_here("a type: `(A, B)`, `INT (0..10)`, a type name, `STRUCT` or `ARRAY`"));
        };
        // An initial value of the whole type (a subrange's or an alias's default) is not kept yet.
        if self.eat(Tok::Assign) {
            while !matches!(self.peek(), Tok::Semi | Tok::Kw(Kw::EndType) | Tok::Eof) {
                self.bump();
            }
        }
        self.expect(Tok::Semi, "`;`")?;
        Ok(TypeDef { name, kind })
    }

    /// After `ARRAY`: `[1..3, 0..1] OF INT`, and an initial value `:= [1, 2, 3(0)]` if one follows.
    pub(super) fn array_spec(&mut self, start: Span) -> PResult<ArraySpec> {
        self.expect(Tok::LBracket, "`[` and the array's bounds")?;
        let mut dims = Vec::new();
        loop {
            let low = self.signed_int()?;
            self.expect(Tok::DotDot, "`..`")?;
            let high = self.signed_int()?;
            dims.push((low, high));
            if !self.eat(Tok::Comma) {
                break;
            }
        }
        self.expect(Tok::RBracket, "`,` or `]`")?;
        if !(self.peek() == Tok::Ident && self.text(self.span()).eq_ignore_ascii_case("OF"))
            && self.peek() != Tok::Kw(Kw::Of)
        {
            return Err(self.error_here("`OF` and the element type"));
        }
        self.bump();
        let elem = self.type_ident("an element type")?;
        let mut init = Vec::new();
        if self.peek() == Tok::Assign && self.peek_at(1) == Tok::LBracket {
            self.bump();
            self.bump();
            loop {
                // `n(value)` repeats a value n times.
                if let (Tok::Int(n), Tok::LParen) = (self.peek(), self.peek_at(1)) {
                    let at = self.bump().span;
                    self.bump();
                    let value = self.expr()?;
                    self.expect(Tok::RParen, "`)`")?;
                    let Ok(count) = u64::try_from(n) else {
                        self.diags.push(Diagnostic::error(at, format!("a repetition count is not negative: {n}")));
                        return Err(Failed);
                    };
                    init.push(InitRun { count, value });
                } else {
                    init.push(InitRun { count: 1, value: self.expr()? });
                }
                if !self.eat(Tok::Comma) {
                    break;
                }
            }
            self.expect(Tok::RBracket, "`,` or `]`")?;
        }
        Ok(ArraySpec { dims, elem, init, span: start.to(self.prev_span()) })
    }

    /// A type's name; `STRING[n]` and `STRING(n)` (CODESYS) are read as one name, `STRING[n]`, whose length
    /// must be within `STRING_LENGTH_MAX`.
    pub(super) fn type_ident(&mut self, what: &str) -> PResult<Ident> {
        let mut name = self.ident(what)?;
        if name.key() != "STRING" || !matches!(self.peek(), Tok::LBracket | Tok::LParen) {
            return Ok(name);
        }
        let close = if self.bump().tok == Tok::LBracket { Tok::RBracket } else { Tok::RParen };
        let length_span = self.span();
        let Tok::Int(n) = self.peek() else { return Err(self.error_here("the string's length, such as `STRING[20]`")) };
        self.bump();
        self.expect(close, if close == Tok::RBracket { "`]`" } else { "`)`" })?;
        let max = crate::limits::STRING_LENGTH_MAX as i64;
        if !(1..=max).contains(&n) {
            let message = format!("a STRING holds 1 to {max} characters, not {n}");
            self.diags.push(Diagnostic::error(length_span, message));
        }
        name.name = format!("STRING[{}]", n.clamp(1, max));
        name.span = name.span.to(self.prev_span());
        Ok(name)
    }

    pub(super) fn signed_int(&mut self) -> PResult<i64> {
        let negative = self.eat(Tok::Minus);
        match self.peek() {
            Tok::Int(v) => {
                self.bump();
                Ok(if negative { -v } else { v })
            }
            _ => Err(self.error_here("an integer")),
        }
    }

    /// `FUNCTION name : TYPE … END_FUNCTION` with an ST body, kept in the library with its syntax errors.
    pub(super) fn function(&mut self) {
        let start = self.bump().span;
        let outer = std::mem::take(&mut self.diags);
        let head = (|| {
            let name = self.ident("a function name")?;
            self.expect(Tok::Colon, "`:` and the function's result type")?;
            let returns = self.type_ident("a result type")?;
            Ok::<_, Failed>((name, returns))
        })();
        let Ok((name, returns)) = head else {
            self.diags = outer;
            self.recover(Kw::EndFunction, |_| false);
            return;
        };
        let mut vars = Vec::new();
        while is_var_block(self.peek()) {
            vars.extend(self.var_block());
        }
        let body = self.statements();
        if body.is_err() || self.peek() != Tok::Kw(Kw::EndFunction) {
            if !self.diags.iter().any(|d| d.is_error()) {
                self.error_here("a statement or `END_FUNCTION`");
            }
            self.recover(Kw::EndFunction, |_| false);
        } else {
            self.bump();
            self.eat(Tok::Semi);
        }
        let problems = std::mem::replace(&mut self.diags, outer);
        self.broken_vars = Broken::default();
        let span = start.to(self.prev_span());
        let body = body.unwrap_or_default();
        self.library.push(FbDef { name, returns: Some(returns), vars, body, actions: Vec::new(), problems, span });
    }

    pub(super) fn pou(&mut self, kind: PouKind, end: Kw) -> Option<Chart> {
        let start = self.bump().span;
        let Ok(name) = self.ident("a name") else {
            self.recover(end, |_| false);
            return None;
        };
        // FUNCTION_BLOCK … EXTENDS/IMPLEMENTS … : nothing Baton needs.
        while self.peek() == Tok::Ident || self.peek() == Tok::Comma {
            self.bump();
        }
        let mut chart = Chart::empty(name, kind, start);
        let outside = std::mem::take(&mut self.broken_vars);
        loop {
            let tok = self.peek();
            if is_var_block(tok) {
                let vars = self.var_block();
                chart.vars.extend(vars);
            } else if is_element_start(tok) {
                self.element(&mut chart);
            } else if tok == Tok::Kw(end) || tok == Tok::Eof {
                break;
            } else if chart.steps.is_empty() && chart.transitions.is_empty() && chart.actions.is_empty() {
                // A body in another language: this POU is not a chart. A function block's ST body is kept for
                // the charts that instantiate it, its errors with it.
                if kind == PouKind::FunctionBlock {
                    let outer = std::mem::take(&mut self.diags);
                    let body = self.statements();
                    // Its actions (CODESYS, TwinCAT): `ACTION name: statements END_ACTION`, after the body.
                    let mut actions = Vec::new();
                    while body.is_ok() && self.peek() == Tok::Kw(Kw::Action) {
                        match self.fb_action() {
                            Ok(a) => actions.push(a),
                            Err(Failed) => break,
                        }
                    }
                    if body.is_err() || self.peek() != Tok::Kw(end) {
                        if !self.diags.iter().any(|d| d.is_error()) {
                            self.error_here(&format!("a statement or `{}`", end.text()));
                        }
                        self.recover(end, |_| false);
                    } else {
                        self.bump();
                        self.eat(Tok::Semi);
                    }
                    let problems = std::mem::replace(&mut self.diags, outer);
                    self.broken_vars = outside;
                    self.library.push(FbDef {
                        name: chart.name,
                        returns: None,
                        vars: chart.vars,
                        body: body.unwrap_or_default(),
                        actions,
                        problems,
                        span: start.to(self.prev_span()),
                    });
                    return None;
                }
                self.recover(end, |_| false);
                return None;
            } else {
                self.error_here(&format!("an SFC element or `{}`", end.text()));
                self.bump();
                while !is_element_start(self.peek()) && self.peek() != Tok::Kw(end) && self.peek() != Tok::Eof {
                    self.bump();
                }
            }
        }
        let closing = self.expect(Tok::Kw(end), &format!("`{}`", end.text()));
        chart.span = start.to(self.prev_span());
        chart.broken.absorb(std::mem::replace(&mut self.broken_vars, outside));
        let broken = &chart.broken;
        let has_sfc =
            !chart.steps.is_empty() || !chart.transitions.is_empty() || !broken.steps.is_empty() || broken.unnamed_step;
        if closing.is_ok() {
            self.eat(Tok::Semi);
        }
        if !has_sfc && kind == PouKind::FunctionBlock {
            // A block with declarations and no body at all.
            let span = chart.span;
            self.library.push(FbDef {
                name: chart.name,
                returns: None,
                vars: chart.vars,
                body: Vec::new(),
                actions: Vec::new(),
                problems: Vec::new(),
                span,
            });
            return None;
        }
        has_sfc.then_some(chart)
    }

    /// `ACTION name: … END_ACTION` of a function block: statements, or steps and transitions (a nested chart).
    pub(super) fn fb_action(&mut self) -> PResult<FbAction> {
        let action = self.action()?;
        Ok(FbAction { name: action.name, body: action.body, sfc: action.sfc })
    }

    pub(super) fn var_block(&mut self) -> Vec<VarDecl> {
        let kw = self.bump();
        let section = match kw.tok {
            Tok::Kw(Kw::VarInput) => VarSection::Input,
            Tok::Kw(Kw::VarOutput) => VarSection::Output,
            Tok::Kw(Kw::VarInOut) => VarSection::InOut,
            Tok::Kw(Kw::VarExternal) => VarSection::External,
            Tok::Kw(Kw::VarGlobal) => VarSection::Global,
            Tok::Kw(Kw::VarTemp) => VarSection::Temp,
            Tok::Kw(Kw::VarAccess | Kw::VarConfig) => {
                self.pos -= 1;
                self.skip_block(Kw::EndVar);
                return Vec::new();
            }
            _ => VarSection::Local,
        };
        let mut constant = false;
        while let Tok::Kw(k @ (Kw::Constant | Kw::Retain | Kw::NonRetain)) = self.peek() {
            constant |= k == Kw::Constant;
            self.bump();
        }
        let mut vars = Vec::new();
        while self.peek() != Tok::Kw(Kw::EndVar) {
            if self.peek() == Tok::Eof || is_element_start(self.peek()) {
                self.error_here("`END_VAR`");
                return vars;
            }
            let name = (self.peek() == Tok::Ident).then(|| self.text(self.span()).to_ascii_uppercase());
            if self.declaration(section, constant, &mut vars).is_err() {
                match name {
                    Some(n) => self.broken_vars.vars.push(n),
                    None => self.broken_vars.unnamed_var = true,
                }
                while !matches!(self.peek(), Tok::Semi | Tok::Kw(Kw::EndVar) | Tok::Eof) {
                    self.bump();
                }
                self.eat(Tok::Semi);
            }
        }
        self.bump();
        vars
    }

    pub(super) fn declaration(&mut self, section: VarSection, constant: bool, out: &mut Vec<VarDecl>) -> PResult<()> {
        let mut names = vec![self.ident("a variable name")?];
        while self.eat(Tok::Comma) {
            names.push(self.ident("a variable name")?);
        }
        if self.eat(Tok::Kw(Kw::At)) {
            self.expect(Tok::Located, "a location such as `%IX0.1`")?;
        }
        self.expect(Tok::Colon, "`:`")?;
        let type_name = self.type_ident("a type name")?;
        let elementary = crate::types::Type::from_name(&type_name.key()).is_some();
        let mut init = None;
        let mut members = Vec::new();
        let mut array = None;
        if type_name.key() == "ARRAY" {
            array = Some(self.array_spec(type_name.span)?);
        } else if elementary {
            if self.eat(Tok::Assign) {
                init = Some(self.expr()?);
            }
        } else if self.peek() == Tok::Assign
            && (self.peek_at(1) == Tok::LParen || crate::types::library::StdFb::from_name(&type_name.key()).is_some())
        {
            // An instance's (or a structure's) initial members: `:= (PT := T#2s)`.
            self.bump();
            if self.peek() != Tok::LParen {
                let span = self.span();
                let message = format!(
                    "a {} instance is initialised with its inputs, such as `:= (PT := T#2s)`",
                    type_name.name.to_ascii_uppercase()
                );
                self.diags.push(Diagnostic::error(span, message));
                return Err(Failed);
            }
            self.bump();
            loop {
                let member = self.ident("an input name")?;
                self.expect(Tok::Assign, "`:=`")?;
                members.push((member, self.expr()?));
                if !self.eat(Tok::Comma) {
                    break;
                }
            }
            self.expect(Tok::RParen, "`,` or `)`")?;
        } else if self.peek() == Tok::Assign && !matches!(type_name.key().as_str(), "ARRAY" | "STRING" | "WSTRING") {
            // A declared type's initial value (an enumeration value).
            self.bump();
            init = Some(self.expr()?);
        } else {
            // ARRAY[…] OF …, STRING[n], structured initialisers: declared, never executed.
            while !matches!(self.peek(), Tok::Semi | Tok::Kw(Kw::EndVar) | Tok::Eof) {
                self.bump();
            }
        }
        self.expect(Tok::Semi, "`;`")?;
        for name in names {
            out.push(VarDecl {
                name,
                section,
                constant,
                type_name: type_name.clone(),
                init: init.clone(),
                members: members.clone(),
                array: array.clone(),
                pragmas: Vec::new(),
                address: None,
            });
        }
        Ok(())
    }
}
