//! Declarations: a chart's variables, instances of standard and user blocks (with their bodies and initial values).

use std::collections::HashMap;
use std::sync::Arc;

use crate::exec::compile::typing::{assignable, Ty};
use crate::exec::eval::{eval, is_constant, NoEnv};
use crate::exec::program::{VarId, VarInfo};
use crate::front::model::{Expr, FbDef, Ident, Sfc, TypeKind, VarDecl, VarSection};
use crate::limits::NESTING_DEPTH_MAX;
use crate::types::library::{MemberKind, StdFb};
use crate::types::{Type, Value};

use super::{Compiler, Scope, Storage, UserInstance};

impl<'a> Compiler<'a> {
    /// Whether a variable, instance, structure or array of this name (key) is declared in the current scope.
    pub(super) fn declared_name(&self, key: &str) -> bool {
        self.vars.contains_key(key)
            || self.instances.contains_key(key)
            || self.user_of.contains_key(key)
            || self.structs.contains_key(key)
            || self.arrays.contains_key(key)
    }

    pub(super) fn declare_vars(&mut self) -> Vec<VarInfo> {
        let mut vars = Vec::with_capacity(self.chart.vars.len());
        for decl in &self.chart.vars {
            let key = decl.name.key();
            if self.declared_name(&key) {
                self.error(decl.name.span, format!("variable `{}` is declared twice", decl.name.name));
                continue;
            }
            if let Some(fb) = StdFb::from_name(&decl.type_name.key()) {
                self.declare_instance(decl, fb, &mut vars);
                continue;
            }
            if let Some(spec) = self.array_spec_of(decl) {
                self.declare_array(decl, &spec, &mut vars);
                continue;
            }
            if let Some(TypeKind::Struct(fields)) = self.types.get(&decl.type_name.key()).map(|t| &t.kind) {
                self.declare_struct(decl, fields, &decl.name.name, false, &mut vars);
                continue;
            }
            if let Some(&def) = self.library.get(&decl.type_name.key()).filter(|d| d.returns.is_none()) {
                if let Some(u) = self.declare_user(decl, def, &decl.name.name, &mut vars) {
                    // Its parameters, and (as CODESYS reads them) its locals and its instances' variables.
                    for (name, &id) in &self.users[u].scope.vars {
                        self.vars.insert(format!("{}.{name}", decl.name.key()), id);
                    }
                    self.user_inits(u, decl, &mut vars);
                    let eno = self.users[u].eno;
                    self.vars.insert(format!("{}.ENO", decl.name.key()), eno);
                    self.user_of.insert(decl.name.key(), u);
                }
                continue;
            }
            let ty = self.resolve_type(&decl.type_name);
            let range = self.subrange(&decl.type_name);
            let init = match &decl.init {
                Some(e) => {
                    let v = self.initial_value(e, &ty);
                    if let Some(r) = &range {
                        self.check_range(e.span, &v, r);
                    }
                    v
                }
                // A subrange's default initial value is its lower limit.
                None => match &range {
                    Some((low, _, _)) if matches!(ty, Type::Int(_)) => Value::Int(*low),
                    _ => self.default_of(&ty),
                },
            };
            let id = VarId(vars.len() as u32);
            if let Some(r) = range {
                self.ranges.insert(id, r);
            }
            self.vars.insert(decl.name.key(), id);
            vars.push(VarInfo {
                name: decl.name.name.clone(),
                ty,
                init,
                constant: decl.constant,
                section: decl.section,
                hidden: false,
            });
        }
        vars
    }

    /// An instance of user block `def` named `path` (`m`, or `m.inner` inside another): a variable per
    /// declaration of the block (inputs, outputs and in-outs visible as `m.NAME`, the rest hidden), nested
    /// instances, and ENO. Its body is compiled once every variable of the chart is declared.
    pub(super) fn declare_user(
        &mut self,
        decl: &VarDecl,
        def: &'a FbDef,
        path: &str,
        vars: &mut Vec<VarInfo>,
    ) -> Option<usize> {
        let key = def.name.key();
        if self.declaring.len() >= NESTING_DEPTH_MAX {
            let message =
                format!("function block instances nested more than {NESTING_DEPTH_MAX} levels deep (through `{path}`)");
            self.error(decl.name.span, message);
            return None;
        }
        if self.declaring.contains(&key) {
            let message = format!(
                "function block `{}` contains an instance of itself (through `{path}`): instances cannot nest for ever",
                def.name.name
            );
            self.error(decl.name.span, message);
            return None;
        }
        if !def.problems.is_empty() && !self.reported.contains(&key) {
            self.reported.push(key.clone());
            self.diags.extend(def.problems.iter().cloned());
        }
        self.declaring.push(key);
        let mut scope = Scope::default();
        let mut params = Vec::new();
        for d in &def.vars {
            self.declare_member(def, d, path, &mut scope, &mut params, vars);
        }
        // Its actions written in SFC: their state, this instance's own.
        let charts: Vec<(&'a Ident, &'a Sfc)> =
            def.actions.iter().filter_map(|a| Some((&a.name, a.sfc.as_deref()?))).collect();
        if !charts.is_empty() {
            let outer = std::mem::take(&mut self.nested);
            self.declare_nested(&charts, &format!("{path}."), &[], vars);
            scope.nested = std::mem::replace(&mut self.nested, outer);
        }
        let eno = VarId(vars.len() as u32);
        vars.push(VarInfo {
            name: format!("{path}.ENO"),
            ty: Type::Bool,
            init: Value::Bool(false),
            constant: false,
            section: VarSection::Output,
            hidden: false,
        });
        self.declaring.pop();
        self.users.push(UserInstance { def, params, eno, scope, body: Arc::new(Vec::new()), actions: HashMap::new() });
        Some(self.users.len() - 1)
    }

    /// Declaration `d` of user block `def`, in the instance at `path`: a standard block's members, a nested user
    /// instance, a structure's or an array's elements, or a variable (a parameter where `d` is one).
    fn declare_member(
        &mut self,
        def: &'a FbDef,
        d: &'a VarDecl,
        path: &str,
        scope: &mut Scope,
        params: &mut Vec<(String, VarSection, VarId)>,
        vars: &mut Vec<VarInfo>,
    ) {
        let inner = format!("{path}.{}", d.name.name);
        if let Some(fb) = StdFb::from_name(&d.type_name.key()) {
            let base = VarId(vars.len() as u32);
            for m in fb.members() {
                let id = VarId(vars.len() as u32);
                if m.kind != MemberKind::State {
                    scope.vars.insert(format!("{}.{}", d.name.key(), m.name), id);
                }
                vars.push(VarInfo {
                    name: format!("{inner}.{}", m.name),
                    init: m.ty.default_value(),
                    ty: m.ty,
                    constant: false,
                    section: VarSection::Local,
                    hidden: true,
                });
            }
            for (name, value) in &d.members {
                match fb
                    .members()
                    .iter()
                    .position(|m| m.kind == MemberKind::Input && m.name.eq_ignore_ascii_case(&name.name))
                {
                    Some(i) => {
                        let ty = vars[base.index() + i].ty.clone();
                        vars[base.index() + i].init = self.initial_value(value, &ty);
                    }
                    None => self.error(name.span, format!("{} has no input `{}`", fb.name(), name.name)),
                }
            }
            scope.instances.insert(d.name.key(), (fb, base));
            return;
        }
        if let Some(&inner_def) = self.library.get(&d.type_name.key()).filter(|d| d.returns.is_none()) {
            if let Some(u) = self.declare_user(d, inner_def, &inner, vars) {
                self.user_inits(u, d, vars);
                for (name, &id) in &self.users[u].scope.vars {
                    scope.vars.insert(format!("{}.{name}", d.name.key()), id);
                }
                scope.vars.insert(format!("{}.ENO", d.name.key()), self.users[u].eno);
                scope.users.insert(d.name.key(), u);
            }
            return;
        }
        if d.section == VarSection::External {
            // Resolved to the chart's variable of that name when the body is compiled.
            return;
        }
        let visible = matches!(d.section, VarSection::Input | VarSection::Output | VarSection::InOut);
        let structure = match self.types.get(&d.type_name.key()).copied().map(|t| &t.kind) {
            Some(TypeKind::Struct(fields)) => Some(fields),
            _ => None,
        };
        if let Some(fields) = structure {
            if visible {
                let message = format!(
                    "`{}` of function block `{}` is a structure parameter, which Baton does not support yet: \
                     declare it in VAR",
                    d.name.name, def.name.name
                );
                self.error(d.name.span, message);
                return;
            }
            // Declared in the instance's scope: its fields are `d.f` there.
            self.in_scope(scope, |c| c.declare_struct(d, fields, &inner, true, vars));
            return;
        }
        if let Some(spec) = self.array_spec_of(d) {
            if visible {
                let message = format!(
                    "`{}` of function block `{}` is an array parameter, which Baton does not support yet: \
                     declare it in VAR",
                    d.name.name, def.name.name
                );
                self.error(d.name.span, message);
            } else {
                // In the instance's scope, where the fields of structure elements are named too.
                self.in_scope(scope, |c| {
                    if let Some(info) = c.array_elements((&inner, &d.name.name), &spec, Storage::of(d, true), vars) {
                        c.arrays.insert(d.name.key(), info);
                    }
                });
            }
            return;
        }
        let ty = self.resolve_type(&d.type_name);
        let init = match &d.init {
            Some(e) => self.initial_value(e, &ty),
            None => self.default_of(&ty),
        };
        let id = VarId(vars.len() as u32);
        scope.vars.insert(d.name.key(), id);
        if visible {
            params.push((d.name.name.clone(), d.section, id));
        }
        // A device signal (`%I*`) is seen as the parameters are: a test sets it, a trace shows it.
        let hidden = !visible && d.address.is_none();
        vars.push(VarInfo { name: inner, ty, init, constant: d.constant, section: d.section, hidden });
    }

    /// Runs `f` with an instance's names (variables, structures, arrays) in place of the chart's.
    pub(super) fn in_scope<R>(&mut self, scope: &mut Scope, f: impl FnOnce(&mut Self) -> R) -> R {
        let chart_vars = std::mem::replace(&mut self.vars, std::mem::take(&mut scope.vars));
        let chart_structs = std::mem::replace(&mut self.structs, std::mem::take(&mut scope.structs));
        let chart_arrays = std::mem::replace(&mut self.arrays, std::mem::take(&mut scope.arrays));
        let result = f(self);
        scope.vars = std::mem::replace(&mut self.vars, chart_vars);
        scope.structs = std::mem::replace(&mut self.structs, chart_structs);
        scope.arrays = std::mem::replace(&mut self.arrays, chart_arrays);
        result
    }

    /// A user instance's initial inputs from its declaration, `m : Motor := (speed := 10)`.
    pub(super) fn user_inits(&mut self, u: usize, decl: &VarDecl, vars: &mut [VarInfo]) {
        for (name, value) in &decl.members {
            let param = self.users[u].params.iter().find(|p| p.0.eq_ignore_ascii_case(&name.name)).cloned();
            match param {
                Some((_, VarSection::Input | VarSection::Output, id)) => {
                    let ty = vars[id.index()].ty.clone();
                    vars[id.index()].init = self.initial_value(value, &ty);
                }
                _ => {
                    let message = format!(
                        "function block `{}` has no input `{}` to initialise",
                        self.users[u].def.name.name, name.name
                    );
                    self.error(name.span, message);
                }
            }
        }
    }

    /// Compiles every user instance's body in its own scope (nested instances first, so that calls of them
    /// find their bodies compiled).
    pub(super) fn compile_user_bodies(&mut self, vars: &[VarInfo]) {
        let chart_vars = self.vars.clone();
        for u in 0..self.users.len() {
            let def = self.users[u].def;
            let mut names = std::mem::take(&mut self.users[u].scope.vars);
            for d in def.vars.iter().filter(|d| d.section == VarSection::External) {
                match chart_vars.get(&d.name.key()) {
                    Some(&id) => {
                        names.insert(d.name.key(), id);
                    }
                    None => {
                        let message = format!(
                            "`{}` is VAR_EXTERNAL in function block `{}`, and chart `{}` declares no variable of that name",
                            d.name.name, def.name.name, self.chart.name.name
                        );
                        self.error(d.name.span, message);
                    }
                }
            }
            // The project's global variable lists are seen from every block (CODESYS, TwinCAT): `GVL.x` and `x`.
            for list in &self.chart.global_lists {
                for v in &list.vars {
                    if let Some(&id) = chart_vars.get(&v.key()) {
                        names.entry(v.key()).or_insert(id);
                    }
                }
            }
            let chart = self.set_names_aside(names);
            self.instances = std::mem::take(&mut self.users[u].scope.instances);
            self.user_of = std::mem::take(&mut self.users[u].scope.users);
            let chart_arrays = std::mem::replace(&mut self.arrays, std::mem::take(&mut self.users[u].scope.arrays));
            let chart_structs = std::mem::replace(&mut self.structs, std::mem::take(&mut self.users[u].scope.structs));
            let chart_nested = std::mem::replace(&mut self.nested, std::mem::take(&mut self.users[u].scope.nested));
            self.current_user = Some(u);
            let body = self.statements(&def.body, vars);
            for a in &def.actions {
                self.fb_action_body(u, &a.name, vars);
            }
            self.current_user = None;
            self.users[u].scope.nested = std::mem::replace(&mut self.nested, chart_nested);
            self.users[u].scope.arrays = std::mem::replace(&mut self.arrays, chart_arrays);
            self.users[u].scope.structs = std::mem::replace(&mut self.structs, chart_structs);
            let own = self.restore_names(chart);
            (self.users[u].scope.vars, self.users[u].scope.instances, self.users[u].scope.users) =
                (own.vars, own.instances, own.user_of);
            self.users[u].body = Arc::new(body);
        }
    }

    /// An instance of a standard block: one variable per member, named `instance.MEMBER`.
    pub(super) fn declare_instance(&mut self, decl: &VarDecl, fb: StdFb, vars: &mut Vec<VarInfo>) {
        if decl.constant {
            self.error(decl.name.span, format!("a {} instance cannot be CONSTANT", fb.name()));
        }
        let base = VarId(vars.len() as u32);
        self.instances.insert(decl.name.key(), (fb, base));
        for m in fb.members() {
            let hidden = m.kind == MemberKind::State;
            if !hidden {
                self.vars.insert(format!("{}.{}", decl.name.key(), m.name), VarId(vars.len() as u32));
            }
            vars.push(VarInfo {
                name: format!("{}.{}", decl.name.name, m.name),
                init: m.ty.default_value(),
                ty: m.ty,
                constant: false,
                section: decl.section,
                hidden,
            });
        }
        let members = fb.members();
        for (name, value) in &decl.members {
            let found =
                members.iter().position(|m| m.kind == MemberKind::Input && m.name.eq_ignore_ascii_case(&name.name));
            let Some(i) = found else {
                let inputs: Vec<&str> =
                    members.iter().filter(|m| m.kind == MemberKind::Input).map(|m| m.name).collect();
                let message =
                    format!("{} has no input `{}`: its inputs are {}", fb.name(), name.name, inputs.join(", "));
                self.error(name.span, message);
                continue;
            };
            let id = base.index() + i;
            let ty = vars[id].ty.clone();
            vars[id].init = self.initial_value(value, &ty);
        }
    }

    pub(super) fn initial_value(&mut self, e: &Expr, ty: &Type) -> Value {
        let outer = std::mem::take(&mut self.hoisted);
        let (cexpr, vty) = self.expr(e, &[]);
        self.hoisted = outer;
        if vty == Ty::Err {
            return ty.default_value();
        }
        if !is_constant(&cexpr) {
            self.error(e.span, "an initial value must be a constant");
            return ty.default_value();
        }
        let Ok(value) = eval(&cexpr, &NoEnv) else {
            self.error(e.span, "division by zero in an initial value");
            return ty.default_value();
        };
        let target = Ty::of(ty);
        // `x : BOOL := 1;` is common in real projects.
        if target == Ty::Bool && vty == Ty::IntLit && matches!(value, Value::Int(0 | 1)) {
            return Value::Bool(value == Value::Int(1));
        }
        if !assignable(target, vty) {
            self.error(e.span, format!("initial value of type {} does not fit a {ty} variable", vty.name()));
            return ty.default_value();
        }
        if let (Type::Int(k), &Value::Int(v)) = (ty, &value) {
            if !k.contains(v) {
                self.error(e.span, format!("{v} does not fit in {ty}"));
                return ty.default_value();
            }
        }
        ty.coerce(value)
    }
}
