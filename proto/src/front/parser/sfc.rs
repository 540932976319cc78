//! SFC elements: steps with their action associations, transitions, actions, nested charts, and fragments (a PLCopen
//! file's ST in pieces).

use crate::front::diag::Diagnostic;
use crate::front::lexer::{Kw, Tok};
use crate::front::model::{Action, Association, Chart, Duration, Ident, Qualifier, Sfc, Step, Transition};
use crate::limits::BRANCHES_MAX;

use super::{is_element_start, Failed, Fragment, FragmentKind, PResult, Parser};

impl Parser<'_> {
    pub(super) fn element(&mut self, chart: &mut Chart) {
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

    pub(super) fn step(&mut self) -> PResult<Step> {
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

    pub(super) fn association(&mut self) -> PResult<Association> {
        let mut action = self.ident("an action association such as `Fill(N)`, or `END_STEP`")?;
        // An action of a function block instance, `gripper.Close(N)` (CODESYS's step actions name them).
        while self.eat(Tok::Dot) {
            let part = self.ident("the name of an action of the instance")?;
            action = Ident { name: format!("{}.{}", action.name, part.name), span: action.span.to(part.span) };
        }
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

    pub(super) fn step_list(&mut self) -> PResult<Vec<Ident>> {
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

    pub(super) fn transition(&mut self) -> PResult<Transition> {
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

    pub(super) fn action(&mut self) -> PResult<Action> {
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
    pub(super) fn nested_sfc(&mut self) -> PResult<Sfc> {
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
        Ok(Sfc { steps, transitions, flags: None })
    }

    pub(super) fn fragment(&mut self, kind: FragmentKind) -> PResult<Fragment> {
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
}
