//! Calls of function block instances (standard and user), their members, and actions called as subroutines.

use std::sync::Arc;

use crate::exec::compile::binding::{Dir, Params};
use crate::exec::compile::typing::Ty;
use crate::exec::program::{CStmt, FbOutput, UserCall, VarId, VarInfo};
use crate::front::diag::Span;
use crate::front::model::{Arg, Ident, Stmt, VarSection};
use crate::limits::NESTING_DEPTH_MAX;
use crate::types::library::{DatePart, Func, MemberKind, StdFb};
use crate::types::{Type, Value};

use super::Compiler;

impl<'a> Compiler<'a> {
    /// The user instance at a path of instance names from the current scope (`m`, `table.motor`).
    pub(super) fn user_at(&self, path: &str) -> Option<usize> {
        let mut parts = path.split('.');
        let mut u = *self.user_of.get(&parts.next()?.to_ascii_uppercase())?;
        for part in parts {
            u = *self.users[u].scope.users.get(&part.to_ascii_uppercase())?;
        }
        Some(u)
    }

    /// `instance.Action(…);`: the action of a user block instance (`table.motor.Stop();` of an instance inside
    /// one), run in the instance's scope (CODESYS, TwinCAT); inputs given as in a call of the instance are set
    /// first (`crane.Init(SFCReset := TRUE);`). An action written in SFC runs one scan of its chart.
    pub(super) fn instance_action_call(
        &mut self,
        callee: &Ident,
        instance: &str,
        action: &str,
        args: &[Arg],
        vars: &[VarInfo],
    ) -> Option<CStmt> {
        if let Some(u) = self.user_at(instance) {
            let def = self.users[u].def;
            let Some(a) = def.actions.iter().find(|a| a.name.name.eq_ignore_ascii_case(action)) else {
                let has: Vec<&str> = def.actions.iter().map(|a| a.name.name.as_str()).collect();
                let list = if has.is_empty() { "none".to_string() } else { has.join(", ") };
                let message = format!(
                    "`{instance}` is a `{}` instance, and `{}` has no action `{action}` (its actions: {list})",
                    def.name.name, def.name.name
                );
                self.error(callee.span, message);
                return None;
            };
            let body = self.users[u].actions.get(&a.name.key()).cloned()?;
            return self.user_call_of(u, callee, args, vars, body);
        }
        let key = instance.to_ascii_uppercase();
        let message = match self.instances.get(&key) {
            Some((fb, _)) => {
                format!("`{instance}` is a {} instance: a standard block has no action `{action}`", fb.name())
            }
            None => format!(
                "`{}` calls action `{action}` of `{instance}`, and chart `{}` has no function block instance \
                 `{instance}` (a call of another program's action is not something one chart can make)",
                callee.name, self.chart.name.name
            ),
        };
        self.error(callee.span, message);
        None
    }

    /// `Action();` of the POU's own action (CODESYS), run where it is called, as a subroutine: its body, once,
    /// whatever its step associations do; RETURN ends it. `None` when the name is no action of this POU.
    pub(super) fn own_action_call(&mut self, callee: &Ident, args: &[Arg], vars: &[VarInfo]) -> Option<Option<CStmt>> {
        let key = callee.key();
        let (body, eno) = if let Some(u) = self.current_user {
            // Inside a function block's body: one of the block's actions.
            self.users[u].def.actions.iter().find(|a| a.name.key() == key)?;
            (self.fb_action_body(u, callee, vars), self.users[u].eno)
        } else {
            let chart = self.chart;
            let action = chart.actions.iter().find(|a| a.name.key() == key)?;
            if action.sfc.is_some() {
                let message = format!(
                    "action `{}` is written in SFC: it runs under its step's qualifier, and cannot be called",
                    action.name.name
                );
                self.error(callee.span, message);
                return Some(None);
            }
            (self.chart_action_body(callee, &action.body, vars), self.call_eno(callee))
        };
        if let Some(arg) = args.first() {
            self.error(arg.span, format!("action `{}` takes no arguments", callee.name));
            return Some(None);
        }
        let body = body?;
        let call = UserCall { body, en: None, inputs: Vec::new(), inouts: Vec::new(), outputs: Vec::new(), eno };
        Some(Some(CStmt::UserFb(Box::new(call))))
    }

    /// The body of action `name` of user instance `u`, compiled once in the instance's scope (which must be the
    /// current one); an action that calls itself, directly or through others, is an error.
    pub(super) fn fb_action_body(&mut self, u: usize, name: &Ident, vars: &[VarInfo]) -> Option<Arc<Vec<CStmt>>> {
        let key = name.key();
        if let Some(body) = self.users[u].actions.get(&key) {
            return Some(Arc::clone(body));
        }
        let def = self.users[u].def;
        let action = def.actions.iter().find(|a| a.name.key() == key)?;
        let body = match &action.sfc {
            Some(sfc) => self.block_chart(u, &action.name, sfc, vars)?,
            None => self.action_body(&format!("{}#{key}", def.name.key()), name, &action.body, vars)?,
        };
        self.users[u].actions.insert(key, Arc::clone(&body));
        Some(body)
    }

    /// The body of the chart's action called as a subroutine, compiled once.
    pub(super) fn chart_action_body(
        &mut self,
        name: &Ident,
        body: &'a [Stmt],
        vars: &[VarInfo],
    ) -> Option<Arc<Vec<CStmt>>> {
        let key = name.key();
        if let Some(body) = self.called_actions.get(&key) {
            return Some(Arc::clone(body));
        }
        let compiled = self.action_body(&key, name, body, vars)?;
        self.called_actions.insert(key, Arc::clone(&compiled));
        Some(compiled)
    }

    pub(super) fn action_body(
        &mut self,
        key: &str,
        name: &Ident,
        body: &[Stmt],
        vars: &[VarInfo],
    ) -> Option<Arc<Vec<CStmt>>> {
        self.within_action(key, name, |c| Arc::new(c.statements(body, vars)))
    }

    /// `f` compiling the body of action `name` (`key`: unique among the POUs' actions) inside those being compiled
    /// around it: an action that runs itself, directly or through others (a call, a chart's association), or past
    /// `NESTING_DEPTH_MAX` of them, is an error and compiles nothing.
    pub(super) fn within_action<R>(&mut self, key: &str, name: &Ident, f: impl FnOnce(&mut Self) -> R) -> Option<R> {
        if self.calling_actions.iter().any(|k| k == key) {
            self.error(name.span, format!("action `{}` calls itself, directly or through others", name.name));
            return None;
        }
        if self.calling_actions.len() >= NESTING_DEPTH_MAX {
            self.error(name.span, format!("calls of actions nested more than {NESTING_DEPTH_MAX} levels deep"));
            return None;
        }
        self.calling_actions.push(key.to_string());
        let compiled = f(self);
        self.calling_actions.pop();
        Some(compiled)
    }

    /// A hidden variable for the ENO of a call of `callee` that has none of its own (an action).
    pub(super) fn call_eno(&mut self, callee: &Ident) -> VarId {
        let id = VarId((self.declared + self.temps.len()) as u32);
        self.temps.push(VarInfo {
            name: format!("{}.ENO#{}", callee.name, self.temps.len() + 1),
            ty: Type::Bool,
            init: Value::Bool(false),
            constant: false,
            section: VarSection::Temp,
            hidden: true,
        });
        id
    }

    /// A member of an instance, by name (hidden state has none).
    pub(super) fn member(&mut self, fb: StdFb, base: VarId, inst: &Ident, field: &Ident) -> Option<VarId> {
        let members = fb.members();
        match members.iter().position(|m| m.kind != MemberKind::State && m.name.eq_ignore_ascii_case(&field.name)) {
            Some(i) => Some(VarId(base.0 + i as u32)),
            None => {
                let list = |kind: MemberKind| {
                    members.iter().filter(|m| m.kind == kind).map(|m| m.name).collect::<Vec<_>>().join(", ")
                };
                let message = format!(
                    "{} has no member `{}` (`{}` is a {}: its inputs are {}; its outputs {})",
                    fb.name(),
                    field.name,
                    inst.name,
                    fb.name(),
                    list(MemberKind::Input),
                    list(MemberKind::Output)
                );
                self.error(field.span, message);
                None
            }
        }
    }

    /// A call of a standard function block instance as a statement.
    pub(super) fn fb_call(&mut self, callee: &Ident, args: &[Arg], span: Span, vars: &[VarInfo]) -> Option<CStmt> {
        if let Some(plain) = self.unqualified_name(callee) {
            return self.fb_call(&plain, args, span, vars);
        }
        if let Some((instance, action)) = callee.name.rsplit_once('.') {
            return self.instance_action_call(callee, instance, action, args, vars);
        }
        if let Some((input, parts)) = DatePart::of_split(&callee.key()) {
            return self.split_call(callee, args, Ty::of(&input), parts, vars);
        }
        // A variable of the action's name shadows the action (Beremiz lets an action `Blink` call its TON `blink`).
        if !self.declared_name(&callee.key()) {
            if let Some(called) = self.own_action_call(callee, args, vars) {
                return called;
            }
        }
        if let Some(&u) = self.user_of.get(&callee.key()) {
            return self.user_call(u, callee, args, vars);
        }
        let Some(&(fb, base)) = self.instances.get(&callee.key()) else {
            let message = if StdFb::from_name(&callee.key()).is_some() {
                format!(
                    "`{0}` is a function block type: declare an instance (`t1 : {0};`) and call that",
                    callee.name.to_ascii_uppercase()
                )
            } else if Func::from_name(&callee.key()).is_some() {
                format!("`{}` is a function: use its result (`x := {}(…);`)", callee.name, callee.name)
            } else if let Some(&v) = self.vars.get(&callee.key()) {
                match vars.get(v.index()).map(|v| &v.ty) {
                    Some(Type::Unsupported(ty)) => format!(
                        "`{}` is a {ty} instance: Baton runs the standard function blocks (TON, TOF, TP, R_TRIG, F_TRIG, CTU, CTD, CTUD, SR, RS), not user function blocks yet",
                        callee.name
                    ),
                    _ => format!("`{}` is a variable, not a function block instance: it cannot be called", callee.name),
                }
            } else if self.chart.broken.var(&callee.key()) {
                return None;
            } else {
                format!(
                    "unknown function block instance `{}`: declare it as a variable, such as `{}: TON;`",
                    callee.name, callee.name
                )
            };
            self.error(callee.span, message);
            return None;
        };
        let members = fb.members();
        // What a call may name: every member but the hidden state, in the instance's order.
        let visible: Vec<usize> = (0..members.len()).filter(|&i| members[i].kind != MemberKind::State).collect();
        let dir = |kind: MemberKind| if kind == MemberKind::Input { Dir::Input } else { Dir::Output };
        let params = Params::block(
            fb.name(),
            visible.iter().map(|&i| (members[i].name.to_string(), dir(members[i].kind))).collect(),
        );
        let bound = self.bind(&params, args, vars, &mut |c: &mut Self, n: &Ident| {
            c.member(fb, base, callee, n);
        })?;
        let (mut inputs, mut outputs, mut ok) = (Vec::new(), Vec::new(), true);
        for (p, arg) in bound.args {
            let member = &members[visible[p]];
            let id = VarId(base.0 + visible[p] as u32);
            if member.kind == MemberKind::Input {
                let what = format!("input `{}` of {}", member.name, fb.name());
                match self.input_value(arg, &member.ty, &what, vars) {
                    Some(value) => inputs.push((id, value)),
                    None => ok = false,
                }
            } else {
                match self.output_target(arg, member.name, &member.ty, vars) {
                    Some(target) => outputs.push(FbOutput { member: id, target, negated: arg.negated }),
                    None => ok = false,
                }
            }
        }
        let _ = span;
        ok.then_some(CStmt::Fb { fb, base, en: bound.en, inputs, outputs })
    }

    /// A call of a user function block instance: formal or non-formal inputs and in-outs (in declaration
    /// order), outputs with `=>`, EN and ENO.
    pub(super) fn user_call(&mut self, u: usize, callee: &Ident, args: &[Arg], vars: &[VarInfo]) -> Option<CStmt> {
        let body = Arc::clone(&self.users[u].body);
        self.user_call_of(u, callee, args, vars, body)
    }

    /// A call binding instance `u`'s parameters, then running `body` (its own, or one of its actions').
    pub(super) fn user_call_of(
        &mut self,
        u: usize,
        callee: &Ident,
        args: &[Arg],
        vars: &[VarInfo],
        body: Arc<Vec<CStmt>>,
    ) -> Option<CStmt> {
        let def_name = self.users[u].def.name.name.clone();
        let user_params = self.users[u].params.clone();
        let eno = self.users[u].eno;
        let dir = |section: VarSection| match section {
            VarSection::Output => Dir::Output,
            VarSection::InOut => Dir::InOut,
            _ => Dir::Input,
        };
        let mut names: Vec<(String, Dir)> =
            user_params.iter().map(|(n, section, _)| (n.clone(), dir(*section))).collect();
        names.push(("ENO".to_string(), Dir::Output));
        let params = Params::block(format!("`{def_name}`"), names);
        let list = user_params.iter().map(|p| p.0.clone()).collect::<Vec<_>>().join(", ");
        let bound = self.bind(&params, args, vars, &mut |c: &mut Self, n: &Ident| {
            let message = format!("function block `{def_name}` has no parameter `{}` (it has {list})", n.name);
            c.error(n.span, message);
        })?;
        let (mut inputs, mut inouts, mut outputs, mut ok) = (Vec::new(), Vec::new(), Vec::new(), true);
        for (p, arg) in bound.args {
            let Some((name, section, id)) = user_params.get(p).cloned() else {
                // ENO, after the declared parameters.
                match self.place(&arg.value, vars) {
                    Some(target) => outputs.push(FbOutput { member: eno, target, negated: arg.negated }),
                    None => ok = false,
                }
                continue;
            };
            let ty = vars[id.index()].ty.clone();
            match section {
                VarSection::Output => match self.output_target(arg, &name, &ty, vars) {
                    Some(target) => outputs.push(FbOutput { member: id, target, negated: arg.negated }),
                    None => ok = false,
                },
                VarSection::InOut => {
                    let Some(caller) = self.place(&arg.value, vars) else {
                        ok = false;
                        continue;
                    };
                    if vars[caller.index()].ty != ty {
                        let message = format!(
                            "in-out `{name}` of `{def_name}` is {ty}, and `{}` is {}",
                            vars[caller.index()].name,
                            vars[caller.index()].ty
                        );
                        self.error(arg.value.span, message);
                        ok = false;
                        continue;
                    }
                    inouts.push((id, caller));
                }
                _ => match self.input_value(arg, &ty, &format!("input `{name}` of `{def_name}`"), vars) {
                    Some(value) => inputs.push((id, value)),
                    None => ok = false,
                },
            }
        }
        let _ = callee;
        let en = bound.en;
        ok.then(|| CStmt::UserFb(Box::new(UserCall { body, en, inputs, inouts, outputs, eno })))
    }
}
