//! Parses IEC 61131-3 textual SFC into the chart model, recovering after errors so that all are reported.
//!
//! POUs without an SFC body (ST functions, configurations, type declarations) are skipped: a chart file may
//! hold a whole project.

use crate::front::diag::{Diagnostic, Span};
use crate::front::lexer::{lex, Kw, RawPragma, Tok, Token};
use crate::front::model::*;
use crate::limits::{BRANCHES_MAX, NESTING_DEPTH_MAX};

pub struct Parsed {
    pub charts: Vec<Chart>,
    /// Types declared in `TYPE` blocks.
    pub types: Vec<TypeDef>,
    /// Function blocks with ST bodies, which charts of the file may instantiate.
    pub library: Vec<FbDef>,
    pub diagnostics: Vec<Diagnostic>,
}

pub fn parse(src: &str) -> Parsed {
    let lexed = lex(src);
    let mut p = Parser::new(src, None, lexed.tokens, lexed.diagnostics);
    let mut charts = p.file();
    attach_pragmas(src, &mut charts, &lexed.pragmas);
    Parsed { charts, types: p.types, library: p.library, diagnostics: p.diags }
}

/// What a piece of Structured Text found in another format (a PLCopen XML body) must be.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FragmentKind {
    /// A condition or an initial value: one expression, a `;` after it allowed.
    Expr,
    /// A transition's named body: an expression, `:= expression;` as in textual SFC, or `NAME := expression;`.
    TransitionBody,
    /// An action's body: statements.
    Statements,
}

pub enum Fragment {
    Expr(Expr),
    Statements(Vec<Stmt>),
}

pub struct ParsedFragment {
    /// `None` when the text has a syntax error (reported in `diagnostics`).
    pub fragment: Option<Fragment>,
    /// The texts of the `{ … }` pragmas in the fragment, with their spans.
    pub pragmas: Vec<Pragma>,
    pub diagnostics: Vec<Diagnostic>,
}

/// Parses `text`, a piece of a larger file, as `kind`. `at` gives the file offset of each offset of `text` (the
/// text may be shorter than its place in the file, when entities were decoded), so that every span — and so
/// every diagnostic — points into the file.
pub fn parse_fragment(text: &str, at: impl Fn(usize) -> usize, kind: FragmentKind) -> ParsedFragment {
    let map = |span: Span| Span::new(at(span.start as usize), at(span.end as usize));
    let mut lexed = lex(text);
    let local: Vec<Span> = lexed.tokens.iter().map(|t| t.span).collect();
    for t in &mut lexed.tokens {
        t.span = map(t.span);
    }
    for d in &mut lexed.diagnostics {
        d.span = map(d.span);
    }
    let pragmas = lexed
        .pragmas
        .iter()
        .map(|raw| Pragma {
            text: text[raw.inner.start as usize..raw.inner.end as usize].trim().to_string(),
            span: map(raw.span),
        })
        .collect();
    let mut p = Parser::new(text, Some(local), lexed.tokens, lexed.diagnostics);
    let fragment = p.fragment(kind).ok();
    ParsedFragment { fragment, pragmas, diagnostics: p.diags }
}

/// Parse failed here; the error is already recorded.
struct Failed;
type PResult<T> = Result<T, Failed>;

struct Parser<'a> {
    src: &'a str,
    /// For a fragment, each token's span in `src`, where the token spans are the file's; `None` when the two
    /// are one.
    local: Option<Vec<Span>>,
    toks: Vec<Token>,
    pos: usize,
    diags: Vec<Diagnostic>,
    depth: usize,
    /// CASE arms being parsed around the current statements: a number then starts the next arm.
    in_case: usize,
    /// Declarations a syntax error took out, for the chart they belong to.
    broken_vars: Broken,
    /// Function blocks with ST bodies read so far.
    library: Vec<FbDef>,
    types: Vec<TypeDef>,
}

fn is_element_start(tok: Tok) -> bool {
    matches!(tok, Tok::Kw(Kw::InitialStep | Kw::Step | Kw::Transition | Kw::Action))
}

fn is_var_block(tok: Tok) -> bool {
    matches!(
        tok,
        Tok::Kw(
            Kw::Var
                | Kw::VarInput
                | Kw::VarOutput
                | Kw::VarInOut
                | Kw::VarExternal
                | Kw::VarGlobal
                | Kw::VarTemp
                | Kw::VarAccess
                | Kw::VarConfig
        )
    )
}

fn is_top_level(tok: Tok) -> bool {
    matches!(tok, Tok::Kw(Kw::Program | Kw::FunctionBlock | Kw::Function | Kw::Configuration | Kw::Type))
        || is_element_start(tok)
        || is_var_block(tok)
}

impl<'a> Parser<'a> {
    fn new(src: &'a str, local: Option<Vec<Span>>, toks: Vec<Token>, diags: Vec<Diagnostic>) -> Parser<'a> {
        Parser {
            src,
            local,
            toks,
            pos: 0,
            diags,
            depth: 0,
            in_case: 0,
            broken_vars: Broken::default(),
            library: Vec::new(),
            types: Vec::new(),
        }
    }
}

impl Parser<'_> {
    fn peek(&self) -> Tok {
        self.toks[self.pos].tok
    }

    fn peek_at(&self, ahead: usize) -> Tok {
        self.toks[(self.pos + ahead).min(self.toks.len() - 1)].tok
    }

    fn span(&self) -> Span {
        self.toks[self.pos].span
    }

    fn prev_span(&self) -> Span {
        self.toks[self.pos.saturating_sub(1)].span
    }

    fn bump(&mut self) -> Token {
        let t = self.toks[self.pos];
        if t.tok != Tok::Eof {
            self.pos += 1;
        }
        t
    }

    fn eat(&mut self, tok: Tok) -> bool {
        if self.peek() == tok {
            self.bump();
            true
        } else {
            false
        }
    }

    fn text(&self, span: Span) -> &str {
        // Every span asked for is a token's.
        let span = match &self.local {
            Some(local) => local[self.toks.partition_point(|t| t.span.start < span.start).min(local.len() - 1)],
            None => span,
        };
        &self.src[span.start as usize..span.end as usize]
    }

    fn found(&self) -> String {
        match self.peek() {
            Tok::Eof if self.local.is_some() => "the end of the body".to_string(),
            Tok::Eof => "end of file".to_string(),
            _ => format!("`{}`", self.text(self.span())),
        }
    }

    fn error_here(&mut self, expected: &str) -> Failed {
        let message = format!("expected {expected}, found {}", self.found());
        self.diags.push(Diagnostic::error(self.span(), message));
        Failed
    }

    fn expect(&mut self, tok: Tok, expected: &str) -> PResult<Token> {
        if self.peek() == tok {
            Ok(self.bump())
        } else {
            Err(self.error_here(expected))
        }
    }

    fn ident(&mut self, what: &str) -> PResult<Ident> {
        if self.peek() == Tok::Ident {
            let t = self.bump();
            Ok(Ident { name: self.text(t.span).to_string(), span: t.span })
        } else {
            Err(self.error_here(what))
        }
    }

    /// Skips to just after `end` (and a following `;`), or up to (not over) a token that `stop` accepts.
    fn recover(&mut self, end: Kw, stop: fn(Tok) -> bool) {
        loop {
            let tok = self.peek();
            if tok == Tok::Eof || stop(tok) {
                return;
            }
            self.bump();
            if tok == Tok::Kw(end) {
                self.eat(Tok::Semi);
                return;
            }
        }
    }

    /// Skips a whole block we do not execute, up to and including its end keyword.
    fn skip_block(&mut self, end: Kw) {
        let start = self.bump().span;
        while self.peek() != Tok::Kw(end) {
            if self.peek() == Tok::Eof {
                let message = format!("`{}` is never closed: expected `{}`", self.text(start), end.text());
                self.diags.push(Diagnostic::error(start, message));
                return;
            }
            self.bump();
        }
        self.bump();
        self.eat(Tok::Semi);
    }

    fn file(&mut self) -> Vec<Chart> {
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
    fn type_block(&mut self) {
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

    fn type_decl(&mut self) -> PResult<TypeDef> {
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
    fn array_spec(&mut self, start: Span) -> PResult<ArraySpec> {
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
    fn type_ident(&mut self, what: &str) -> PResult<Ident> {
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

    fn signed_int(&mut self) -> PResult<i64> {
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
    fn function(&mut self) {
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

    fn pou(&mut self, kind: PouKind, end: Kw) -> Option<Chart> {
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

    /// `ACTION name: statements END_ACTION` of a function block.
    fn fb_action(&mut self) -> PResult<FbAction> {
        self.bump();
        let name = self.ident("an action name")?;
        self.expect(Tok::Colon, "`:`")?;
        let body = self.statements()?;
        self.expect(Tok::Kw(Kw::EndAction), "`END_ACTION`")?;
        self.eat(Tok::Semi);
        Ok(FbAction { name, body })
    }

    fn var_block(&mut self) -> Vec<VarDecl> {
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

    fn declaration(&mut self, section: VarSection, constant: bool, out: &mut Vec<VarDecl>) -> PResult<()> {
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
            });
        }
        Ok(())
    }

    fn element(&mut self, chart: &mut Chart) {
        let kw = self.peek();
        // The element's name, read ahead: a syntax error further on takes the element out, not its name.
        let name = match (kw, self.peek_at(1)) {
            (Tok::Kw(Kw::Transition), _) => None,
            (_, Tok::Ident) => Some(self.text(self.toks[self.pos + 1].span).to_ascii_uppercase()),
            _ => None,
        };
        let (result, end) = match self.peek() {
            Tok::Kw(Kw::InitialStep | Kw::Step) => (self.step().map(|s| chart.steps.push(s)), Kw::EndStep),
            Tok::Kw(Kw::Transition) => (self.transition().map(|t| chart.transitions.push(t)), Kw::EndTransition),
            _ => (self.action().map(|a| chart.actions.push(a)), Kw::EndAction),
        };
        if result.is_err() {
            let broken = &mut chart.broken;
            match kw {
                Tok::Kw(k @ (Kw::InitialStep | Kw::Step)) => {
                    broken.initial_step |= k == Kw::InitialStep;
                    match name {
                        Some(n) => broken.steps.push(n),
                        None => broken.unnamed_step = true,
                    }
                }
                Tok::Kw(Kw::Action) => match name {
                    Some(n) => broken.actions.push(n),
                    None => broken.unnamed_action = true,
                },
                _ => {}
            }
            self.recover(end, is_element_start);
        }
    }

    fn step(&mut self) -> PResult<Step> {
        let kw = self.bump();
        let initial = kw.tok == Tok::Kw(Kw::InitialStep);
        let name = self.ident("a step name")?;
        self.expect(Tok::Colon, "`:`")?;
        let mut associations = Vec::new();
        while self.peek() != Tok::Kw(Kw::EndStep) {
            associations.push(self.association()?);
            self.expect(Tok::Semi, "`;`")?;
        }
        let end = self.bump().span;
        self.eat(Tok::Semi);
        Ok(Step { name, initial, associations, pragmas: Vec::new(), span: kw.span.to(end) })
    }

    fn association(&mut self) -> PResult<Association> {
        let action = self.ident("an action association such as `Fill(N)`, or `END_STEP`")?;
        self.expect(Tok::LParen, "`(`")?;
        let mut qualifier = Qualifier::N;
        let mut qualifier_span = action.span;
        if self.peek() == Tok::Ident {
            let t = self.bump();
            // An unknown qualifier is reported and read as N, so that the rest of the step is still checked.
            match Qualifier::from_word(self.text(t.span)) {
                Some(q) => qualifier = q,
                None => {
                    let message = format!(
                        "unknown action qualifier `{}`: expected one of N, R, S, L, D, P, P0, P1, SD, DS, SL",
                        self.text(t.span)
                    );
                    self.diags.push(Diagnostic::error(t.span, message));
                }
            }
            qualifier_span = t.span;
        }
        let mut duration = None;
        let mut indicators = Vec::new();
        let mut first = true;
        while self.eat(Tok::Comma) {
            if first && qualifier.is_timed() {
                duration = Some(match self.peek() {
                    Tok::Time(ms) => Duration::Literal { ms, span: self.bump().span },
                    Tok::Ident => Duration::Var(self.ident("a duration")?),
                    _ => return Err(self.error_here("a duration such as `T#2s` or a TIME variable")),
                });
            } else {
                indicators.push(self.ident("an indicator variable")?);
            }
            first = false;
        }
        let close = self.expect(Tok::RParen, "`,` or `)`")?;
        Ok(Association { span: action.span.to(close.span), action, qualifier, qualifier_span, duration, indicators })
    }

    fn step_list(&mut self) -> PResult<Vec<Ident>> {
        if !self.eat(Tok::LParen) {
            return Ok(vec![self.ident("a step name or `(`")?]);
        }
        let mut steps = vec![self.ident("a step name")?];
        while self.eat(Tok::Comma) {
            steps.push(self.ident("a step name")?);
        }
        self.expect(Tok::RParen, "`,` or `)`")?;
        if steps.len() > BRANCHES_MAX {
            let span = steps[0].span;
            self.diags.push(Diagnostic::error(span, format!("more than {BRANCHES_MAX} steps in one list")));
            return Err(Failed);
        }
        Ok(steps)
    }

    fn transition(&mut self) -> PResult<Transition> {
        let kw = self.bump();
        let name = if self.peek() == Tok::Ident { Some(self.ident("a transition name")?) } else { None };
        let mut priority = None;
        if self.eat(Tok::LParen) {
            let word = self.ident("`PRIORITY`")?;
            if word.key() != "PRIORITY" {
                self.diags.push(Diagnostic::error(word.span, format!("expected `PRIORITY`, found `{}`", word.name)));
                return Err(Failed);
            }
            self.expect(Tok::Assign, "`:=`")?;
            let span = self.span();
            match self.peek() {
                Tok::Int(n) if (0..=i64::from(u32::MAX)).contains(&n) => {
                    self.bump();
                    priority = Some((n as u32, span));
                }
                _ => return Err(self.error_here("a non-negative integer priority")),
            }
            self.expect(Tok::RParen, "`)`")?;
        }
        let from_kw = self.expect(Tok::Kw(Kw::From), "`FROM`")?;
        let from = self.step_list()?;
        self.expect(Tok::Kw(Kw::To), "`TO`")?;
        let to = self.step_list()?;
        let arc_span = from_kw.span.to(self.prev_span());
        if self.peek() == Tok::Colon {
            let span = self.span();
            self.diags.push(Diagnostic::error(
                span,
                "Instruction List transition conditions are not supported: write `:= expression;`",
            ));
            return Err(Failed);
        }
        self.expect(Tok::Assign, "`:=` and a condition")?;
        let condition = self.expr()?;
        self.expect(Tok::Semi, "`;`")?;
        let end = self.expect(Tok::Kw(Kw::EndTransition), "`END_TRANSITION`")?;
        self.eat(Tok::Semi);
        Ok(Transition {
            name,
            priority,
            from,
            to,
            condition,
            pragmas: Vec::new(),
            span: kw.span.to(end.span),
            arc_span,
        })
    }

    fn action(&mut self) -> PResult<Action> {
        let kw = self.bump();
        let name = self.ident("an action name")?;
        self.expect(Tok::Colon, "`:`")?;
        let (body, sfc) = if matches!(self.peek(), Tok::Kw(Kw::InitialStep | Kw::Step | Kw::Transition)) {
            (Vec::new(), Some(Box::new(self.nested_sfc()?)))
        } else {
            (self.statements()?, None)
        };
        let end = self.expect(Tok::Kw(Kw::EndAction), "`END_ACTION`")?;
        self.eat(Tok::Semi);
        Ok(Action { name, body, sfc, pragmas: Vec::new(), span: kw.span.to(end.span) })
    }

    /// The steps and transitions of an action written in SFC, up to its `END_ACTION`. A syntax error in one of
    /// them fails the whole action: a nested chart with an element missing is not the chart drawn.
    fn nested_sfc(&mut self) -> PResult<Sfc> {
        let (mut steps, mut transitions) = (Vec::new(), Vec::new());
        loop {
            match self.peek() {
                Tok::Kw(Kw::InitialStep | Kw::Step) => steps.push(self.step()?),
                Tok::Kw(Kw::Transition) => transitions.push(self.transition()?),
                Tok::Kw(Kw::Action) => {
                    let span = self.span();
                    self.diags.push(Diagnostic::error(
                        span,
                        "an action written in SFC names the POU's actions: declare this one after `END_ACTION`",
                    ));
                    return Err(Failed);
                }
                _ => break,
            }
        }
        Ok(Sfc { steps, transitions })
    }

    fn fragment(&mut self, kind: FragmentKind) -> PResult<Fragment> {
        let fragment = match kind {
            FragmentKind::Expr => {
                let e = self.expr()?;
                self.eat(Tok::Semi);
                Fragment::Expr(e)
            }
            FragmentKind::TransitionBody => {
                if self.peek() == Tok::Ident && self.peek_at(1) == Tok::Assign {
                    self.bump();
                }
                self.eat(Tok::Assign);
                let e = self.expr()?;
                self.eat(Tok::Semi);
                Fragment::Expr(e)
            }
            FragmentKind::Statements => Fragment::Statements(self.statements()?),
        };
        if self.peek() != Tok::Eof {
            let what = match kind {
                FragmentKind::Statements => "a statement",
                _ => "the end of the expression",
            };
            return Err(self.error_here(what));
        }
        Ok(fragment)
    }

    fn statements(&mut self) -> PResult<Vec<Stmt>> {
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
    fn dotted_call(&self) -> bool {
        let mut k = 1;
        while self.peek_at(k) == Tok::Dot && self.peek_at(k + 1) == Tok::Ident {
            k += 2;
        }
        k > 1 && self.peek_at(k) == Tok::LParen
    }

    /// The name a call statement calls, its parts joined by `.`.
    fn dotted_callee(&mut self) -> PResult<Ident> {
        let mut callee = self.ident("a function block instance")?;
        while self.peek() == Tok::Dot {
            self.bump();
            let part = self.ident("an action name")?;
            callee = Ident { name: format!("{}.{}", callee.name, part.name), span: callee.span.to(part.span) };
        }
        Ok(callee)
    }

    /// An assignment's target: a variable, or a member of an instance (`t1.PT`).
    fn place(&mut self) -> PResult<Expr> {
        let name = self.ident("a variable")?;
        self.designator(name)
    }

    /// What a name designates: a variable, `step.X`, an instance's or a structure's member (`a.b.c`), an array
    /// element (`a[i]`), a field of one (`pts[i].x`).
    fn designator(&mut self, mut name: Ident) -> PResult<Expr> {
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
    fn args(&mut self) -> PResult<(Vec<Arg>, Token)> {
        self.expect(Tok::LParen, "`(`")?;
        if let Some(close) = self.peek_eat(Tok::RParen) {
            return Ok((Vec::new(), close));
        }
        self.nest()?;
        let args = self.arg_list();
        self.depth -= 1;
        args
    }

    fn arg_list(&mut self) -> PResult<(Vec<Arg>, Token)> {
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
    fn index(&mut self, name: Ident) -> PResult<Expr> {
        self.bump();
        self.nest()?;
        let indices = self.index_list();
        self.depth -= 1;
        let indices = indices?;
        let close = self.expect(Tok::RBracket, "`,` or `]`")?;
        let span = name.span.to(close.span);
        Ok(Expr { kind: ExprKind::Index(name, indices), span })
    }

    fn index_list(&mut self) -> PResult<Vec<Expr>> {
        let mut indices = vec![self.expr()?];
        while self.eat(Tok::Comma) {
            indices.push(self.expr()?);
        }
        Ok(indices)
    }

    fn peek_eat(&mut self, tok: Tok) -> Option<Token> {
        (self.peek() == tok).then(|| self.bump())
    }

    /// Parses a statement that nests others, within the nesting limit.
    fn nested(&mut self, f: fn(&mut Self) -> PResult<Stmt>) -> PResult<Stmt> {
        self.nest()?;
        let result = f(self);
        self.depth -= 1;
        result
    }

    fn case_stmt(&mut self) -> PResult<Stmt> {
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

    fn case_body(&mut self) -> PResult<Vec<Stmt>> {
        self.in_case += 1;
        let body = self.statements();
        self.in_case -= 1;
        body
    }

    fn for_stmt(&mut self) -> PResult<Stmt> {
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

    fn while_stmt(&mut self) -> PResult<Stmt> {
        let start = self.bump().span;
        let condition = self.expr()?;
        self.expect(Tok::Kw(Kw::Do), "`DO`")?;
        let body = self.loop_body()?;
        let end = self.expect(Tok::Kw(Kw::EndWhile), "`END_WHILE`")?;
        self.eat(Tok::Semi);
        Ok(Stmt::While { condition, body, span: start.to(end.span) })
    }

    fn repeat_stmt(&mut self) -> PResult<Stmt> {
        let start = self.bump().span;
        let body = self.loop_body()?;
        self.expect(Tok::Kw(Kw::Until), "`UNTIL`")?;
        let until = self.expr()?;
        let end = self.expect(Tok::Kw(Kw::EndRepeat), "`END_REPEAT`")?;
        self.eat(Tok::Semi);
        Ok(Stmt::Repeat { body, until, span: start.to(end.span) })
    }

    /// A loop's body: a CASE arm around the loop does not end it at a number.
    fn loop_body(&mut self) -> PResult<Vec<Stmt>> {
        let outer = std::mem::take(&mut self.in_case);
        let body = self.statements();
        self.in_case = outer;
        body
    }

    fn nest(&mut self) -> PResult<()> {
        self.depth += 1;
        if self.depth > NESTING_DEPTH_MAX {
            let span = self.span();
            self.diags.push(Diagnostic::error(span, format!("nested more than {NESTING_DEPTH_MAX} levels deep")));
            return Err(Failed);
        }
        Ok(())
    }

    fn if_stmt_inner(&mut self) -> PResult<Stmt> {
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

    pub fn expr(&mut self) -> PResult<Expr> {
        self.binary(0)
    }

    /// Operators of a higher level than `min_level`, as a chain: each operand parsed one level deeper, then the
    /// chain folded (`fold`). A chain's length is bounded like any nesting: its tree is as deep as it is long,
    /// but for runs of one associative operator (`a OR b OR c …`), which are built balanced.
    fn binary(&mut self, min_level: u8) -> PResult<Expr> {
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
    fn fold(&mut self, operands: Vec<Expr>, ops: Vec<(BinOp, Span)>) -> PResult<Expr> {
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

    fn unary(&mut self) -> PResult<Expr> {
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

    fn primary(&mut self) -> PResult<Expr> {
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

/// Gives each pragma to the element it stands in, or else to the element it follows, or else to its chart;
/// pragmas outside every chart are dropped, as a standard tool would ignore them.
/// The declaration a pragma at `at` follows on its line, right after its `;` (`door : BOOL; {input := …}`).
fn declaration_before<'a>(src: &str, vars: &'a mut [VarDecl], at: u32) -> Option<&'a mut VarDecl> {
    let i = vars.iter().rposition(|d| d.name.span.start < at)?;
    let between = src.get(vars[i].name.span.start as usize..at as usize)?;
    let (_, after) = between.split_once(';')?;
    let follows = !after.contains(';') && after.chars().all(|c| c == ' ' || c == '\t');
    follows.then(|| &mut vars[i])
}

fn attach_pragmas(src: &str, charts: &mut [Chart], pragmas: &[RawPragma]) {
    for raw in pragmas {
        let text = src[raw.inner.start as usize..raw.inner.end as usize].trim().to_string();
        let pragma = Pragma { text, span: raw.span };
        let Some(chart) = charts.iter_mut().find(|c| c.span.start <= raw.span.start && raw.span.end <= c.span.end)
        else {
            continue;
        };
        let at = raw.span.start;
        if let Some(decl) = declaration_before(src, &mut chart.vars, at) {
            decl.pragmas.push(pragma);
            continue;
        }
        // Elements of each kind are in source order, so the last one starting before the pragma is found by
        // binary search; the closest of the three kinds is the element the pragma follows or stands in.
        let step = chart.steps.partition_point(|s| s.span.start <= at).checked_sub(1);
        let trans = chart.transitions.partition_point(|t| t.span.start <= at).checked_sub(1);
        let action = chart.actions.partition_point(|a| a.span.start <= at).checked_sub(1);
        let starts = [
            step.map(|i| chart.steps[i].span.start),
            trans.map(|i| chart.transitions[i].span.start),
            action.map(|i| chart.actions[i].span.start),
        ];
        let best = starts.iter().enumerate().filter_map(|(k, s)| s.map(|s| (s, k))).max();
        match best {
            Some((_, 0)) => chart.steps[step.unwrap_or_default()].pragmas.push(pragma),
            Some((_, 1)) => chart.transitions[trans.unwrap_or_default()].pragmas.push(pragma),
            Some(_) => chart.actions[action.unwrap_or_default()].pragmas.push(pragma),
            None => chart.pragmas.push(pragma),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pragmas_attach_to_the_element_they_stand_in_or_follow() {
        let src = "PROGRAM P {chart_note}\nINITIAL_STEP A: {agent := 'r1'} END_STEP\n{after_a}\n\
                   TRANSITION FROM A TO B := TRUE; {inside_t} END_TRANSITION\nSTEP B: END_STEP\nEND_PROGRAM\n{outside}";
        let parsed = parse(src);
        assert!(parsed.diagnostics.is_empty(), "{:?}", parsed.diagnostics);
        let chart = &parsed.charts[0];
        let texts = |p: &[Pragma]| p.iter().map(|p| p.text.clone()).collect::<Vec<_>>();
        assert_eq!(texts(&chart.pragmas), ["chart_note"]);
        assert_eq!(texts(&chart.steps[0].pragmas), ["agent := 'r1'", "after_a"]);
        assert_eq!(texts(&chart.transitions[0].pragmas), ["inside_t"]);
        assert!(chart.steps[1].pragmas.is_empty());
    }

    #[test]
    fn a_pragma_after_a_declaration_on_its_line_is_the_declarations() {
        let src =
            "PROGRAM P\nVAR\n  door : BOOL; {input := 'zenoh'}\n  lamp : BOOL := TRUE;\n  {below_lamp}\n  n : INT; \
                   {on_n} {and_n}\nEND_VAR\n{after_vars}\nINITIAL_STEP A: END_STEP\nEND_PROGRAM";
        let parsed = parse(src);
        assert!(parsed.diagnostics.is_empty(), "{:?}", parsed.diagnostics);
        let chart = &parsed.charts[0];
        let texts = |p: &[Pragma]| p.iter().map(|p| p.text.clone()).collect::<Vec<_>>();
        assert_eq!(texts(&chart.vars[0].pragmas), ["input := 'zenoh'"]);
        assert!(chart.vars[1].pragmas.is_empty(), "a pragma on the next line is not the declaration's");
        assert_eq!(texts(&chart.vars[2].pragmas), ["on_n"], "only the first pragma follows the `;` directly");
        assert_eq!(texts(&chart.pragmas), ["below_lamp", "and_n", "after_vars"]);
    }

    #[test]
    fn bare_elements_form_one_chart_with_top_level_declarations() {
        let parsed =
            parse("VAR go : BOOL; END_VAR\nINITIAL_STEP A: END_STEP\nTRANSITION FROM A TO A := go; END_TRANSITION");
        assert!(parsed.diagnostics.is_empty());
        assert_eq!(parsed.charts.len(), 1);
        assert_eq!(parsed.charts[0].kind, PouKind::Bare);
        assert_eq!(parsed.charts[0].vars.len(), 1);
    }

    #[test]
    fn deep_nesting_is_an_error_not_a_stack_overflow() {
        let src = format!(
            "INITIAL_STEP A: END_STEP TRANSITION FROM A TO A := {}TRUE{}; END_TRANSITION",
            "(".repeat(5000),
            ")".repeat(5000)
        );
        let parsed = parse(&src);
        assert!(parsed.diagnostics.iter().any(|d| d.message.contains("nested more than")));
        let src =
            format!("INITIAL_STEP A: END_STEP TRANSITION FROM A TO A := {}TRUE; END_TRANSITION", "NOT ".repeat(5000));
        assert!(!parse(&src).diagnostics.is_empty());
    }
}
