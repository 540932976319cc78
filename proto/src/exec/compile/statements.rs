//! ST statements: assignments, IF, CASE, loops, and the places an assignment writes.

use crate::exec::compile::typing::{assignable, bool_literal, Ty};
use crate::exec::eval::{eval, is_constant, NoEnv};
use crate::exec::program::{CExpr, CStmt, VarId, VarInfo};
use crate::front::model::{CaseLabel, Expr, ExprKind, Stmt, VarSection};
use crate::types::library::MemberKind;
use crate::types::Value;

use super::Compiler;

impl<'a> Compiler<'a> {
    pub(super) fn statements(&mut self, body: &[Stmt], vars: &[VarInfo]) -> Vec<CStmt> {
        let mut out = Vec::with_capacity(body.len());
        for stmt in body {
            let outer = std::mem::take(&mut self.hoisted);
            let compiled = self.statement(stmt, vars);
            // The function calls its expressions need run first.
            out.append(&mut self.hoisted);
            self.hoisted = outer;
            out.extend(compiled);
        }
        out
    }

    pub(super) fn statement(&mut self, stmt: &Stmt, vars: &[VarInfo]) -> Option<CStmt> {
        Some(match stmt {
            Stmt::Assign { target, value, .. } => return self.assign(target, value, vars),
            Stmt::If { branches, otherwise, .. } => {
                let mut cbranches = Vec::with_capacity(branches.len());
                for (cond, stmts) in branches {
                    let ccond = self.condition(cond, vars, "an IF condition");
                    cbranches.push((ccond, self.statements(stmts, vars)));
                }
                let otherwise = self.statements(otherwise, vars);
                CStmt::If { branches: cbranches, otherwise }
            }
            Stmt::Call { callee, args, span } => return self.fb_call(callee, args, *span, vars),
            Stmt::Case { selector, arms, otherwise, .. } => {
                let (cselector, ty) = self.expr(selector, vars);
                if !ty.is_int() && !matches!(ty, Ty::Enum(_)) && ty != Ty::Err {
                    let message =
                        format!("a CASE selector must be an integer or an enumeration value, found {}", ty.name());
                    self.error(selector.span, message);
                }
                let mut carms = Vec::with_capacity(arms.len());
                for arm in arms {
                    let mut labels = Vec::with_capacity(arm.labels.len());
                    for label in &arm.labels {
                        let range = match label {
                            CaseLabel::Value(v) => self.case_label(v).map(|v| (v, v)),
                            CaseLabel::Range(lo, hi) => match (self.case_label(lo), self.case_label(hi)) {
                                (Some(lo), Some(hi)) if lo <= hi => Some((lo, hi)),
                                (Some(_), Some(_)) => {
                                    let span = lo.span.to(hi.span);
                                    self.error(span, "an empty CASE range: its lower bound is above its upper bound");
                                    None
                                }
                                _ => None,
                            },
                        };
                        labels.extend(range);
                    }
                    carms.push((labels, self.statements(&arm.body, vars)));
                }
                let otherwise = self.statements(otherwise, vars);
                CStmt::Case { selector: cselector, arms: carms, otherwise }
            }
            Stmt::For { var, from, to, by, body, .. } => {
                let target = Expr { kind: ExprKind::Name(var.clone()), span: var.span };
                let id = self.place(&target, vars);
                let bound = |c: &mut Self, e: &Expr, what: &str| {
                    let (ce, ty) = c.expr(e, vars);
                    if !ty.is_int() && ty != Ty::Err {
                        c.error(e.span, format!("a FOR loop's {what} must be an integer, found {}", ty.name()));
                    }
                    ce
                };
                let from = bound(self, from, "start");
                let to = bound(self, to, "end");
                let by = match by {
                    Some(e) => bound(self, e, "step"),
                    None => CExpr::Const(Value::Int(1)),
                };
                if let Some(id) = id {
                    if !Ty::of(&vars[id.index()].ty).is_int() {
                        let message = format!(
                            "a FOR loop's variable must be an integer, and `{}` is {}",
                            var.name,
                            vars[id.index()].ty
                        );
                        self.error(var.span, message);
                    }
                }
                let body = self.loop_body(body, vars);
                CStmt::For { var: id?, from, to, by, body }
            }
            Stmt::While { condition, body, .. } => {
                let outer = std::mem::take(&mut self.hoisted);
                let condition = self.condition(condition, vars, "a WHILE condition");
                let pre = std::mem::replace(&mut self.hoisted, outer);
                CStmt::While { pre, condition, body: self.loop_body(body, vars) }
            }
            Stmt::Repeat { body, until, .. } => {
                let body = self.loop_body(body, vars);
                let outer = std::mem::take(&mut self.hoisted);
                let until = self.condition(until, vars, "an UNTIL condition");
                let pre = std::mem::replace(&mut self.hoisted, outer);
                CStmt::Repeat { body, pre, until }
            }
            Stmt::Exit { span } => {
                if self.loops == 0 {
                    self.error(*span, "EXIT outside a FOR, WHILE or REPEAT loop");
                    return None;
                }
                CStmt::Exit
            }
            Stmt::Return { .. } => CStmt::Return,
        })
    }

    /// `target := value;`: to a variable, an array's element or a structure's field, of a type it takes.
    fn assign(&mut self, target: &Expr, value: &Expr, vars: &[VarInfo]) -> Option<CStmt> {
        let plain = self.unqualified(target);
        let target = plain.as_ref().unwrap_or(target);
        let (mut cvalue, mut vty) = self.expr(value, vars);
        let indexed = match &target.kind {
            ExprKind::Index(name, indices) => Some((name, self.element(name, indices, vars))),
            ExprKind::IndexField(name, indices, field) => Some((name, self.element_field(name, indices, field, vars))),
            _ => None,
        };
        if let Some((name, element)) = indexed {
            let (element, ety) = element?;
            if !assignable(ety, vty) {
                self.error(
                    value.span,
                    format!(
                        "cannot assign {} to an element of `{}`, which holds {}",
                        vty.name(),
                        name.name,
                        ety.name()
                    ),
                );
                return None;
            }
            let base = self.arrays.get(&name.key()).map(|a| a.base.index());
            if base.and_then(|b| vars.get(b)).is_some_and(|v| v.constant) {
                self.error(target.span, format!("`{}` is a CONSTANT and cannot be assigned", name.name));
                return None;
            }
            return Some(match element {
                CExpr::Var(var) => CStmt::Assign { var, value: cvalue },
                CExpr::Index(ix) => CStmt::AssignIndex { target: ix, value: cvalue },
                _ => return None,
            });
        }
        let id = self.place(target, vars)?;
        let var = &vars[id.index()];
        // IEC 61131-3 writes BOOL literals as 0 and 1 too (`ORANGE_LIGHT := 1;` in Beremiz's examples).
        if Ty::of(&var.ty) == Ty::Bool {
            if let ExprKind::Int(v @ (0 | 1)) = value.kind {
                (cvalue, vty) = (CExpr::Const(Value::Bool(v == 1)), Ty::Bool);
            }
        }
        if !assignable(Ty::of(&var.ty), vty) {
            let message = format!("cannot assign {} to `{}`, which is {}", vty.name(), var.name, var.ty);
            self.error(value.span, message);
            return None;
        }
        if let Some(r) = self.ranges.get(&id).cloned() {
            if let (true, Ok(v)) = (is_constant(&cvalue), eval(&cvalue, &NoEnv)) {
                self.check_range(value.span, &v, &r);
            }
        }
        Some(CStmt::Assign { var: id, value: cvalue })
    }

    pub(super) fn loop_body(&mut self, body: &[Stmt], vars: &[VarInfo]) -> Vec<CStmt> {
        self.loops += 1;
        let out = self.statements(body, vars);
        self.loops -= 1;
        out
    }

    pub(super) fn condition(&mut self, e: &Expr, vars: &[VarInfo], what: &str) -> CExpr {
        let (c, ty) = bool_literal(self.expr(e, vars));
        if ty != Ty::Bool && ty != Ty::Err {
            self.error(e.span, format!("{what} must be BOOL, found {}", ty.name()));
        }
        c
    }

    /// A CASE label: a constant integer.
    pub(super) fn case_label(&mut self, e: &Expr) -> Option<i64> {
        let outer = std::mem::take(&mut self.hoisted);
        let (c, ty) = self.expr(e, &[]);
        self.hoisted = outer;
        if ty == Ty::Err {
            return None;
        }
        match ((ty.is_int() || matches!(ty, Ty::Enum(_))) && is_constant(&c)).then(|| eval(&c, &NoEnv)) {
            Some(Ok(v)) => Some(v.as_i64()),
            _ => {
                self.error(e.span, "a CASE label must be a constant integer");
                None
            }
        }
    }

    /// The variable an assignment (or an output `=>`) writes: a variable, or an input of an instance.
    pub(super) fn place(&mut self, target: &Expr, vars: &[VarInfo]) -> Option<VarId> {
        if let Some(plain) = self.unqualified(target) {
            return self.place(&plain, vars);
        }
        let (id, name) = match &target.kind {
            ExprKind::Name(name) => {
                let Some(&id) = self.vars.get(&name.key()) else {
                    if self.chart.broken.var(&name.key()) {
                        return None;
                    }
                    let message = if self.steps.contains_key(&name.key()) {
                        format!("`{}` is a step: a step's state cannot be assigned", name.name)
                    } else if let Some((fb, _)) = self.instances.get(&name.key()) {
                        format!(
                            "`{}` is a {} instance: assign its inputs (`{}.IN := …`) or call it",
                            name.name,
                            fb.name(),
                            name.name
                        )
                    } else {
                        format!("undeclared variable `{}`{}", name.name, self.var_hint(&name.name))
                    };
                    self.error(name.span, message);
                    return None;
                };
                (id, name)
            }
            ExprKind::Field(base, field) if self.structs.contains_key(&base.key()) => {
                match self.vars.get(&format!("{}.{}", base.key(), field.key())) {
                    Some(&id) => (id, base),
                    None => {
                        let message = self.missing_field(base, field);
                        self.error(field.span, message);
                        return None;
                    }
                }
            }
            ExprKind::Field(base, field) if self.user_of.contains_key(&base.key()) => {
                let u = self.user_of[&base.key()];
                let param = self.users[u].params.iter().find(|p| p.0.eq_ignore_ascii_case(&field.name)).cloned();
                match param {
                    Some((_, VarSection::Input | VarSection::InOut, id)) => (id, base),
                    Some(_) => {
                        let message = format!("`{}.{}` is an output: only the block writes it", base.name, field.name);
                        self.error(target.span, message);
                        return None;
                    }
                    None => {
                        let message = format!("`{}` has no input `{}`", base.name, field.name);
                        self.error(field.span, message);
                        return None;
                    }
                }
            }
            ExprKind::Field(base, field) => {
                let Some(&(fb, inst_base)) = self.instances.get(&base.key()) else {
                    if let Some(message) = self.bad_path(base) {
                        self.error(base.span, message);
                    } else if !self.known_name(base) {
                        let message = self.foreign_name(base, field);
                        self.error(target.span, message);
                    } else if !self.chart.broken.var(&base.key()) {
                        let message = format!(
                            "`{}.{}` cannot be assigned: only the inputs of a function block instance can",
                            base.name, field.name
                        );
                        self.error(target.span, message);
                    }
                    return None;
                };
                let id = self.member(fb, inst_base, base, field)?;
                let index = id.0 - inst_base.0;
                if fb.members()[index as usize].kind != MemberKind::Input {
                    let message = format!(
                        "`{}.{}` is an output of {}: only the block writes it",
                        base.name,
                        field.name,
                        fb.name()
                    );
                    self.error(target.span, message);
                    return None;
                }
                (id, base)
            }
            _ => {
                self.error(target.span, "only a variable or an instance's input can be assigned");
                return None;
            }
        };
        let var = &vars[id.index()];
        if var.constant {
            self.error(name.span, format!("`{}` is a CONSTANT and cannot be assigned", var.name));
            return None;
        }
        if self.reject_unsupported(name.span, var) {
            return None;
        }
        Some(id)
    }
}
