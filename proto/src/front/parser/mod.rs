//! Parses IEC 61131-3 textual SFC into the chart model, recovering after errors so that all are reported.
//!
//! POUs without an SFC body (ST functions, configurations, type declarations) are skipped: a chart file may
//! hold a whole project.
//!
//! Recursive descent over the tokens into the chart model, with error recovery at each SFC element so that
//! every syntax error is reported. Function blocks and functions with ST bodies go to the library (`Parsed::library`,
//! their syntax errors kept until a chart uses them), TYPE blocks to `Parsed::types`; ST programs and configurations
//! are skipped. `parse_fragment` parses one condition, body or value found in another format, given a map from its
//! offsets to the file's, applied to the tokens as they are made (so every span of the tree is the file's). Pragmas are
//! attached afterwards by position (`attach_pragmas`; one right after a declaration's `;`, on its line, is the
//! declaration's). What a syntax error took out is noted in `Chart::broken`, so that the compiler does not report it
//! again as unknown.

mod declarations;
mod expressions;
mod sfc;
mod statements;

use crate::front::diag::{Diagnostic, Span};
use crate::front::lexer::{lex, Kw, RawPragma, Tok, Token};
use crate::front::model::{Broken, Chart, Expr, FbDef, Ident, Pragma, Stmt, TypeDef, VarDecl};
use crate::limits::NESTING_DEPTH_MAX;

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

    fn nest(&mut self) -> PResult<()> {
        self.depth += 1;
        if self.depth > NESTING_DEPTH_MAX {
            let span = self.span();
            self.diags.push(Diagnostic::error(span, format!("nested more than {NESTING_DEPTH_MAX} levels deep")));
            return Err(Failed);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::front::model::PouKind;

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
