//! Resolves a chart's names, type-checks its expressions and builds the `Program` the engine runs.
#![allow(
    clippy::disallowed_types,
    reason = "name tables, looked up only: what compile emits follows the source's order"
)]

use std::collections::HashMap;
use std::sync::Arc;

use crate::exec::eval::{eval, is_constant, NoEnv};
use crate::exec::program::*;
use crate::front::diag::{Diagnostic, Span};
use crate::front::model::*;
use crate::limits::NESTING_DEPTH_MAX;
use crate::types::library::{DateFn, DatePart, Func, MemberKind, StdFb, TextFn};
use crate::types::{IntKind, Type, Value};

/// The result of compiling one chart: a program (with placeholders wherever an error was reported) and whether
/// its net of steps and transitions resolved well enough to be analysed.
pub struct Compiled {
    pub program: Program,
    pub net_ok: bool,
}

/// Compiles a chart; `library` holds the function blocks with ST bodies that its instances may be of.
pub fn compile(chart: &Chart, library: &[FbDef], types: &[TypeDef], diags: &mut Vec<Diagnostic>) -> Compiled {
    let mut c = Compiler {
        chart,
        diags,
        vars: HashMap::new(),
        steps: HashMap::new(),
        actions: HashMap::new(),
        instances: HashMap::new(),
        loops: 0,
        library: library.iter().map(|d| (d.name.key(), d)).collect(),
        users: Vec::new(),
        user_of: HashMap::new(),
        declaring: Vec::new(),
        reported: Vec::new(),
        functions: HashMap::new(),
        hoisted: Vec::new(),
        temps: Vec::new(),
        declared: 0,
        types: types.iter().map(|t| (t.name.key(), t)).collect(),
        resolved: HashMap::new(),
        enums: Vec::new(),
        arrays: HashMap::new(),
        structs: HashMap::new(),
        nested_steps: HashMap::new(),
        controlled: HashMap::new(),
        started: HashMap::new(),
        ranges: HashMap::new(),
        struct_depth: 0,
        functions_compiling: 0,
        current_user: None,
        calling_actions: Vec::new(),
        called_actions: HashMap::new(),
        depth_memo: std::collections::BTreeMap::new(),
    };
    c.run()
}

/// An instance of a user function block: its parameters' variables, the names its body sees, its body.
struct UserInstance<'a> {
    def: &'a FbDef,
    /// Inputs, outputs and in-outs in declaration order: (name as declared, section, variable).
    params: Vec<(String, VarSection, VarId)>,
    eno: VarId,
    scope: Scope,
    body: Arc<Vec<CStmt>>,
    /// Its block's actions, compiled in its scope (by upper-case name), as they are first needed.
    actions: HashMap<String, Arc<Vec<CStmt>>>,
}

/// The names a body resolves: variables (and visible members, `T.Q`), standard and user instances.
#[derive(Default)]
struct Scope {
    vars: HashMap<String, VarId>,
    instances: HashMap<String, (StdFb, VarId)>,
    users: HashMap<String, usize>,
    arrays: HashMap<String, ArrayInfo>,
    structs: HashMap<String, (String, Vec<String>)>,
}

/// The static type of an expression. `IntLit` is an integer literal, which fits any numeric type; `Err` follows
/// an expression whose error is already reported, so that one mistake yields one message.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Ty {
    Bool,
    Int(IntKind),
    IntLit,
    Real {
        long: bool,
    },
    Time,
    Date,
    Tod,
    Dt,
    /// A value of the enumeration with this id.
    Enum(u32),
    /// A STRING of any length: a variable's own length cuts what is stored in it.
    Str,
    Err,
}

impl Ty {
    fn of(ty: &Type) -> Ty {
        match ty {
            Type::Enum(e) => Ty::Enum(e.id),
            Type::Date => Ty::Date,
            Type::Tod => Ty::Tod,
            Type::Dt => Ty::Dt,
            Type::Bool => Ty::Bool,
            Type::Int(k) => Ty::Int(*k),
            Type::Real { long } => Ty::Real { long: *long },
            Type::Time => Ty::Time,
            Type::Str { .. } => Ty::Str,
            Type::Unsupported(_) => Ty::Err,
        }
    }

    fn is_int(self) -> bool {
        matches!(self, Ty::Int(_) | Ty::IntLit)
    }

    fn is_num(self) -> bool {
        self.is_int() || matches!(self, Ty::Real { .. })
    }

    fn name(self) -> String {
        match self {
            Ty::Bool => "BOOL".into(),
            Ty::Int(k) => Type::Int(k).to_string(),
            Ty::IntLit => "an integer".into(),
            Ty::Real { long } => Type::Real { long }.to_string(),
            Ty::Time => "TIME".into(),
            Ty::Enum(_) => "an enumeration value".into(),
            Ty::Date => "DATE".into(),
            Ty::Tod => "TIME_OF_DAY".into(),
            Ty::Dt => "DATE_AND_TIME".into(),
            Ty::Str => "STRING".into(),
            Ty::Err => "an invalid expression".into(),
        }
    }

    fn wrap(self) -> Option<IntKind> {
        match self {
            Ty::Int(k) => Some(k),
            _ => None,
        }
    }

    /// The run-time type a result of this static type is held as.
    fn repr(self) -> Type {
        match self {
            Ty::Bool | Ty::Err => Type::Bool,
            Ty::Int(k) => Type::Int(k),
            Ty::IntLit => Type::Int(IntKind::Lint),
            Ty::Real { long } => Type::Real { long },
            Ty::Time => Type::Time,
            Ty::Enum(_) => Type::Int(IntKind::Dint),
            Ty::Date => Type::Date,
            Ty::Tod => Type::Tod,
            Ty::Dt => Type::Dt,
            Ty::Str => Type::Str { max: crate::limits::STRING_LENGTH_MAX as u32 },
        }
    }
}

/// The common numeric type of two numeric operands.
fn join(a: Ty, b: Ty) -> Ty {
    match (a, b) {
        (Ty::Real { long: x }, Ty::Real { long: y }) => Ty::Real { long: x || y },
        (Ty::Real { long }, _) | (_, Ty::Real { long }) => Ty::Real { long },
        (Ty::Int(x), Ty::Int(y)) => Ty::Int(x.wider(y)),
        (Ty::Int(k), _) | (_, Ty::Int(k)) => Ty::Int(k),
        _ => Ty::IntLit,
    }
}

fn binary_type(op: BinOp, a: Ty, b: Ty) -> Option<Ty> {
    use BinOp::*;
    match op {
        Or | Xor | And if a.is_int() && b.is_int() => Some(join(a, b)),
        Or | Xor | And => (a == Ty::Bool && b == Ty::Bool).then_some(Ty::Bool),
        Pow => (a.is_num() && b.is_num()).then(|| join(a, b)),
        Eq | Ne | Lt | Le | Gt | Ge => {
            let ok = (a.is_num() && b.is_num())
                || (a == b && matches!(a, Ty::Time | Ty::Date | Ty::Tod | Ty::Dt | Ty::Str))
                || (a == Ty::Bool && b == Ty::Bool)
                || (matches!(a, Ty::Enum(_)) && a == b);
            ok.then_some(Ty::Bool)
        }
        Add | Sub if a == Ty::Time && b == Ty::Time => Some(Ty::Time),
        // A time of day or a date and time moved by a duration; the duration between two of them.
        Add if matches!((a, b), (Ty::Tod | Ty::Dt, Ty::Time)) => Some(a),
        Add if matches!((a, b), (Ty::Time, Ty::Tod | Ty::Dt)) => Some(b),
        Sub if matches!((a, b), (Ty::Tod | Ty::Dt, Ty::Time)) => Some(a),
        Sub if a == b && matches!(a, Ty::Tod | Ty::Dt | Ty::Date) => Some(Ty::Time),
        Mul if (a == Ty::Time && b.is_num()) || (a.is_num() && b == Ty::Time) => Some(Ty::Time),
        Div if a == Ty::Time && b.is_num() => Some(Ty::Time),
        Mod => (a.is_int() && b.is_int()).then(|| join(a, b)),
        Add | Sub | Mul | Div => (a.is_num() && b.is_num()).then(|| join(a, b)),
    }
}

/// The standard's functions of durations, times of day and dates that are operators on them (IEC 61131-3
/// table 30): the operator and the types of its two operands (`None`: any number). The LTIME forms are the same
/// functions: Baton holds every duration in milliseconds.
fn time_function(upper: &str) -> Option<(BinOp, [Option<Ty>; 2])> {
    let plain: Vec<&str> = upper
        .split('_')
        .map(|w| match w {
            "LTIME" => "TIME",
            "LTOD" => "TOD",
            "LDT" => "DT",
            "LDATE" => "DATE",
            w => w,
        })
        .collect();
    let (t, tod, dt, date) = (Some(Ty::Time), Some(Ty::Tod), Some(Ty::Dt), Some(Ty::Date));
    Some(match plain.join("_").as_str() {
        "ADD_TIME" => (BinOp::Add, [t, t]),
        "ADD_TOD_TIME" => (BinOp::Add, [tod, t]),
        "ADD_DT_TIME" => (BinOp::Add, [dt, t]),
        "SUB_TIME" => (BinOp::Sub, [t, t]),
        "SUB_DATE_DATE" => (BinOp::Sub, [date, date]),
        "SUB_TOD_TIME" => (BinOp::Sub, [tod, t]),
        "SUB_TOD_TOD" => (BinOp::Sub, [tod, tod]),
        "SUB_DT_TIME" => (BinOp::Sub, [dt, t]),
        "SUB_DT_DT" => (BinOp::Sub, [dt, dt]),
        "MUL_TIME" => (BinOp::Mul, [t, None]),
        "DIV_TIME" => (BinOp::Div, [t, None]),
        _ => return None,
    })
}

/// IEC 61131-3 writes BOOL literals as 0 and 1 too (a transition `:= 1;`, `ORANGE_LIGHT := 1;` in Beremiz's
/// examples): an untyped integer 0 or 1 where a BOOL is wanted is that BOOL; anything else is left as it is.
fn bool_literal((c, ty): (CExpr, Ty)) -> (CExpr, Ty) {
    match (&c, ty) {
        (CExpr::Const(Value::Int(v @ (0 | 1))), Ty::IntLit) => (CExpr::Const(Value::Bool(*v == 1)), Ty::Bool),
        _ => (c, ty),
    }
}

/// Whether a value of type `value` may be stored in a variable of type `target`.
fn assignable(target: Ty, value: Ty) -> bool {
    target == value
        || target == Ty::Err
        || value == Ty::Err
        || (target.is_int() && value.is_int())
        || (matches!(target, Ty::Real { .. }) && value.is_num())
}

struct Compiler<'a> {
    chart: &'a Chart,
    diags: &'a mut Vec<Diagnostic>,
    vars: HashMap<String, VarId>,
    steps: HashMap<String, StepId>,
    actions: HashMap<String, ActionId>,
    /// Standard function block instances: their type and first member.
    instances: HashMap<String, (StdFb, VarId)>,
    /// Loops around the statements being compiled (EXIT needs one).
    loops: usize,
    /// User function blocks by name; their instances (nested ones before those that hold them); the chart's
    /// user instances by name; the blocks being declared (a block holding itself is an error); blocks whose
    /// syntax errors were reported.
    library: HashMap<String, &'a FbDef>,
    users: Vec<UserInstance<'a>>,
    user_of: HashMap<String, usize>,
    declaring: Vec<String>,
    reported: Vec<String>,
    /// User functions by name: their frames and (once compiled) bodies.
    functions: HashMap<String, Function<'a>>,
    /// Calls of user functions in the expression being compiled, to run before the statement that holds it.
    hoisted: Vec<CStmt>,
    /// Variables made while compiling (a function call's result), after the declared ones.
    temps: Vec<VarInfo>,
    declared: usize,
    /// Types declared in the file, and those resolved so far; enumerations with their initial ordinals.
    types: HashMap<String, &'a TypeDef>,
    resolved: HashMap<String, Type>,
    enums: Vec<(std::sync::Arc<crate::types::EnumType>, i64)>,
    /// The chart's arrays: first element, bounds, element type.
    arrays: HashMap<String, ArrayInfo>,
    /// The chart's structure variables: their type's name and field names.
    structs: HashMap<String, (String, Vec<String>)>,
    /// Steps of the nested charts (actions written in SFC): their variables `[x, since, last]`.
    nested_steps: HashMap<String, [VarId; 3]>,
    /// Actions a nested chart controls: the action holding that chart, the action's Q and stored S variables.
    controlled: HashMap<String, (String, VarId, VarId)>,
    /// Each nested chart's `started` variable, by the key of the action it is the body of.
    started: HashMap<String, VarId>,
    /// The chart's variables of a subrange type: the range and the type's name.
    ranges: HashMap<VarId, (i64, i64, String)>,
    /// Structures being declared inside one another (a structure holding itself is an error).
    struct_depth: usize,
    /// Bodies of functions being compiled around the call being compiled (a call compiles its function's body).
    functions_compiling: usize,
    /// The user instance whose body (or action) is being compiled.
    current_user: Option<usize>,
    /// Actions called as subroutines being compiled around the call being compiled, and those compiled.
    calling_actions: Vec<String>,
    called_actions: HashMap<String, Arc<Vec<CStmt>>>,
    /// `exec_depth` of every shared body measured so far, by address.
    depth_memo: std::collections::BTreeMap<*const Vec<CStmt>, usize>,
}

/// How a declaration's variables are held: CONSTANT or not, their section, hidden from names or not.
#[derive(Clone, Copy)]
struct Storage {
    constant: bool,
    section: VarSection,
    hidden: bool,
}

impl Storage {
    fn of(decl: &VarDecl, hidden: bool) -> Storage {
        Storage { constant: decl.constant, section: decl.section, hidden }
    }

    /// A function's frame: scratch that several places may write.
    fn frame() -> Storage {
        Storage { constant: false, section: VarSection::Temp, hidden: true }
    }
}

#[derive(Clone)]
struct ArrayInfo {
    base: VarId,
    dims: Vec<(i64, i64)>,
    /// Variables of the array: elements times `stride`.
    len: u32,
    elem: Type,
    /// For an array of structures: variables per element, and each direct field's position and type in it.
    stride: u32,
    fields: HashMap<String, (u32, Type)>,
}

/// A user function: its frame (parameters, locals, result; shared by its calls, as IEC functions do not
/// recurse), and its body once compiled.
struct Function<'a> {
    def: &'a FbDef,
    /// Inputs in order: (name as declared, variable).
    inputs: Vec<(String, VarId)>,
    /// Locals and the result, reset at each call: (variable, initial value).
    resets: Vec<(VarId, Value)>,
    result: VarId,
    eno: VarId,
    scope: HashMap<String, VarId>,
    arrays: HashMap<String, ArrayInfo>,
    body: Option<Arc<Vec<CStmt>>>,
    compiling: bool,
}

const FALSE: CExpr = CExpr::Const(Value::Bool(false));

impl<'a> Compiler<'a> {
    fn error(&mut self, span: Span, message: impl Into<String>) {
        self.diags.push(Diagnostic::error(span, message));
    }

    /// What runs nests deeper than the engine walks: each body alone is bounded by the parsers, so this comes of
    /// what it calls, each block's, function's and nested chart's body one level deeper than its call.
    fn too_deep(&mut self, span: Span, what: &str, depth: usize) {
        let message = format!(
            "{what} nests {depth} levels deep, more than {NESTING_DEPTH_MAX}, counting the function blocks, \
             functions and nested charts it runs inside one another: call fewer of them inside one another, or split \
             their bodies"
        );
        self.error(span, message);
    }

    fn run(&mut self) -> Compiled {
        let chart = self.chart;
        // Every declared type, so that an enumeration's values are known even where no variable has its type.
        let types: Vec<&TypeDef> = self.types.values().copied().collect();
        let mut types = types;
        types.sort_by_key(|t| t.name.span.start);
        for t in types {
            self.resolve_type(&t.name);
        }
        let mut vars = self.declare_vars();
        self.declare_functions(&mut vars);
        self.declare_nested(&mut vars);
        self.declared = vars.len();
        self.compile_user_bodies(&vars);
        let mut net_ok = true;
        let mut steps = Vec::with_capacity(chart.steps.len());
        // The chart element behind each id: duplicates get no id of their own.
        let mut step_sources = Vec::with_capacity(chart.steps.len());
        for step in &chart.steps {
            if self.steps.contains_key(&step.name.key()) {
                self.error(step.name.span, format!("step `{}` is declared twice", step.name.name));
                net_ok = false;
                continue;
            }
            self.steps.insert(step.name.key(), StepId(steps.len() as u32));
            step_sources.push(step);
            steps.push(StepParts {
                info: StepInfo { name: step.name.name.clone(), initial: step.initial, pragmas: step.pragmas.clone() },
                associations: Vec::new(),
            });
        }
        let (mut actions, action_sources) = self.declare_actions();
        self.associate(&vars, &step_sources, &mut steps, &mut actions);
        let mut transitions = Vec::with_capacity(chart.transitions.len());
        net_ok &= self.transitions(&vars, &mut transitions);
        for (id, action) in action_sources.iter().enumerate() {
            actions[id].body = self.statements(&action.body, &vars);
        }
        self.nested_charts(&action_sources, &step_sources, &vars, &mut actions);
        for (id, action) in action_sources.iter().enumerate() {
            let depth = crate::exec::program::exec_depth(&actions[id].body, &mut self.depth_memo);
            if depth > NESTING_DEPTH_MAX {
                self.too_deep(action.name.span, &format!("action `{}`", action.name.name), depth);
            }
        }
        self.warn_unused_actions();
        if !chart.steps.iter().any(|s| s.initial) && !chart.broken.initial_step {
            let message = format!("chart `{}` has no initial step: declare one with `INITIAL_STEP`", chart.name.name);
            self.error(chart.name.span, message);
        }
        vars.append(&mut self.temps);
        let chars: usize = vars.iter().map(|v| if let Type::Str { max } = v.ty { max as usize } else { 0 }).sum();
        if chars > crate::limits::STRING_CHARS_MAX {
            let message = format!(
                "chart `{}`'s STRING variables hold {chars} characters together, more than the {} a distributed run \
                 can carry in one message: declare shorter ones (`STRING[20]`)",
                chart.name.name,
                crate::limits::STRING_CHARS_MAX
            );
            self.error(chart.name.span, message);
        }
        let program = Program::assemble(chart.name.name.clone(), vars, steps, transitions, actions);
        Compiled { program, net_ok }
    }

    /// Whether a variable, instance, structure or array of this name (key) is declared in the current scope.
    fn declared_name(&self, key: &str) -> bool {
        self.vars.contains_key(key)
            || self.instances.contains_key(key)
            || self.user_of.contains_key(key)
            || self.structs.contains_key(key)
            || self.arrays.contains_key(key)
    }

    fn declare_vars(&mut self) -> Vec<VarInfo> {
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
                    for &(ref name, _, id) in &self.users[u].params {
                        self.vars.insert(format!("{}.{}", decl.name.key(), name.to_ascii_uppercase()), id);
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
    fn declare_user(&mut self, decl: &VarDecl, def: &'a FbDef, path: &str, vars: &mut Vec<VarInfo>) -> Option<usize> {
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
                continue;
            }
            if let Some(&inner_def) = self.library.get(&d.type_name.key()).filter(|d| d.returns.is_none()) {
                if let Some(u) = self.declare_user(d, inner_def, &inner, vars) {
                    self.user_inits(u, d, vars);
                    for &(ref name, _, id) in &self.users[u].params {
                        scope.vars.insert(format!("{}.{}", d.name.key(), name.to_ascii_uppercase()), id);
                    }
                    scope.vars.insert(format!("{}.ENO", d.name.key()), self.users[u].eno);
                    scope.users.insert(d.name.key(), u);
                }
                continue;
            }
            if d.section == VarSection::External {
                // Resolved to the chart's variable of that name when the body is compiled.
                continue;
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
                    continue;
                }
                // Declared in the instance's scope: its fields are `d.f` there.
                self.in_scope(&mut scope, |c| c.declare_struct(d, fields, &inner, true, vars));
                continue;
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
                    self.in_scope(&mut scope, |c| {
                        if let Some(info) = c.array_elements((&inner, &d.name.name), &spec, Storage::of(d, true), vars)
                        {
                            c.arrays.insert(d.name.key(), info);
                        }
                    });
                }
                continue;
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
            vars.push(VarInfo { name: inner, ty, init, constant: d.constant, section: d.section, hidden: !visible });
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

    /// Runs `f` with an instance's names (variables, structures, arrays) in place of the chart's.
    fn in_scope<R>(&mut self, scope: &mut Scope, f: impl FnOnce(&mut Self) -> R) -> R {
        let chart_vars = std::mem::replace(&mut self.vars, std::mem::take(&mut scope.vars));
        let chart_structs = std::mem::replace(&mut self.structs, std::mem::take(&mut scope.structs));
        let chart_arrays = std::mem::replace(&mut self.arrays, std::mem::take(&mut scope.arrays));
        let result = f(self);
        scope.vars = std::mem::replace(&mut self.vars, chart_vars);
        scope.structs = std::mem::replace(&mut self.structs, chart_structs);
        scope.arrays = std::mem::replace(&mut self.arrays, chart_arrays);
        result
    }

    /// Every user function's frame: a hidden VAR_TEMP variable per input and local, and its result. Frames are
    /// scratch (written and read within one call), so several places may write them.
    fn declare_functions(&mut self, vars: &mut Vec<VarInfo>) {
        let library: Vec<&'a FbDef> = self.library.values().copied().filter(|d| d.returns.is_some()).collect();
        let mut library = library;
        library.sort_by_key(|d| d.span.start);
        for def in library {
            let returns = def.returns.as_ref().expect("a function");
            let mut scope = HashMap::new();
            let mut arrays = HashMap::new();
            let (mut inputs, mut resets) = (Vec::new(), Vec::new());
            let declare =
                |c: &mut Self, name: String, type_name: &Ident, init: Option<&Expr>, vars: &mut Vec<VarInfo>| {
                    let ty = c.resolve_type(type_name);
                    let init = match init {
                        Some(e) => c.initial_value(e, &ty),
                        None => c.default_of(&ty),
                    };
                    let id = VarId(vars.len() as u32);
                    vars.push(VarInfo {
                        name,
                        ty,
                        init: init.clone(),
                        constant: false,
                        section: VarSection::Temp,
                        hidden: true,
                    });
                    (id, init)
                };
            for d in def.vars.iter().filter(|d| d.section != VarSection::External) {
                if let Some(spec) = self.array_spec_of(d) {
                    let of_structs =
                        matches!(self.types.get(&spec.elem.key()).map(|t| &t.kind), Some(TypeKind::Struct(_)));
                    if d.section == VarSection::Input || of_structs {
                        let what = if of_structs { "an array of structures" } else { "an array input" };
                        let message = format!(
                            "`{}` of function `{}` is {what}, which Baton does not support yet",
                            d.name.name, def.name.name
                        );
                        self.error(d.name.span, message);
                    } else {
                        let label = format!("{}.{}", def.name.name, d.name.name);
                        let before = vars.len();
                        if let Some(info) = self.array_elements((&label, &d.name.name), &spec, Storage::frame(), vars) {
                            // A function's locals start again at every call.
                            resets.extend((before..vars.len()).map(|i| (VarId(i as u32), vars[i].init.clone())));
                            arrays.insert(d.name.key(), info);
                        }
                    }
                    continue;
                }
                let (id, init) =
                    declare(self, format!("{}.{}", def.name.name, d.name.name), &d.type_name, d.init.as_ref(), vars);
                scope.insert(d.name.key(), id);
                match d.section {
                    VarSection::Input => inputs.push((d.name.name.clone(), id)),
                    _ => resets.push((id, init)),
                }
            }
            let (result, init) = declare(self, def.name.name.clone(), returns, None, vars);
            resets.push((result, init));
            scope.insert(def.name.key(), result);
            let (eno, _) = declare(
                self,
                format!("{}.ENO", def.name.name),
                &Ident { name: "BOOL".into(), span: def.name.span },
                None,
                vars,
            );
            let function = Function { def, inputs, resets, result, eno, scope, arrays, body: None, compiling: false };
            self.functions.insert(def.name.key(), function);
        }
    }

    /// A user function's body, compiled at its first call in the function's own scope.
    fn function_body(&mut self, key: &str, callee: &Ident, vars: &[VarInfo]) -> Option<Arc<Vec<CStmt>>> {
        let f = self.functions.get(key)?;
        if let Some(body) = &f.body {
            return Some(Arc::clone(body));
        }
        let def = f.def;
        if self.functions_compiling >= NESTING_DEPTH_MAX {
            let message = format!(
                "calls of functions nested more than {NESTING_DEPTH_MAX} levels deep (here, through `{}`)",
                callee.name
            );
            self.error(callee.span, message);
            return None;
        }
        if f.compiling {
            let message = format!(
                "function `{}` calls itself (here, through `{}`): IEC functions do not recurse",
                def.name.name, callee.name
            );
            self.error(callee.span, message);
            return None;
        }
        if !def.problems.is_empty() && !self.reported.contains(&key.to_string()) {
            self.reported.push(key.to_string());
            self.diags.extend(def.problems.iter().cloned());
        }
        let mut names = self.functions[key].scope.clone();
        let arrays = self.functions[key].arrays.clone();
        for d in def.vars.iter().filter(|d| d.section == VarSection::External) {
            if let Some(&id) = self.vars.get(&d.name.key()) {
                names.insert(d.name.key(), id);
            }
        }
        self.functions.get_mut(key).expect("declared").compiling = true;
        self.functions_compiling += 1;
        let saved = (
            std::mem::replace(&mut self.vars, names),
            std::mem::take(&mut self.instances),
            std::mem::take(&mut self.user_of),
            std::mem::take(&mut self.steps),
            std::mem::take(&mut self.actions),
            std::mem::take(&mut self.hoisted),
            std::mem::take(&mut self.loops),
            std::mem::replace(&mut self.arrays, arrays),
        );
        let body = Arc::new(self.statements(&def.body, vars));
        (self.vars, self.instances, self.user_of, self.steps, self.actions, self.hoisted, self.loops, self.arrays) =
            saved;
        self.functions_compiling -= 1;
        let f = self.functions.get_mut(key).expect("declared");
        f.compiling = false;
        f.body = Some(Arc::clone(&body));
        Some(body)
    }

    /// A call of a user function in an expression: the call is hoisted before the statement, its result kept in
    /// a variable of its own, which the expression reads.
    fn function_call(&mut self, key: &str, callee: &Ident, args: &[Arg], vars: &[VarInfo]) -> (CExpr, Ty) {
        if vars.len() < self.declared {
            self.error(
                callee.span,
                format!("a call of function `{}` is not a constant, and a constant is needed here", callee.name),
            );
            return (FALSE, Ty::Err);
        }
        let (inputs, resets, result, eno) = {
            let f = &self.functions[key];
            (f.inputs.clone(), f.resets.clone(), f.result, f.eno)
        };
        let names: Vec<String> = inputs.iter().map(|(n, _)| n.to_ascii_uppercase()).collect();
        let params: Vec<&str> = names.iter().map(String::as_str).collect();
        let Some(values) = self.positional(callee, args, &params, false) else { return (FALSE, Ty::Err) };
        let mut assigned = Vec::with_capacity(values.len() + resets.len());
        for ((name, id), value) in inputs.iter().zip(&values) {
            let target = Ty::of(&vars[id.index()].ty);
            let (c, ty) = self.expr(value, vars);
            let (c, ty) = if target == Ty::Bool { bool_literal((c, ty)) } else { (c, ty) };
            if !assignable(target, ty) {
                let message =
                    format!("input `{name}` of `{}` is {}, found {}", callee.name, vars[id.index()].ty, ty.name());
                self.error(value.span, message);
                return (FALSE, Ty::Err);
            }
            assigned.push((*id, c));
        }
        assigned.extend(resets.iter().map(|(id, init)| (*id, CExpr::Const(init.clone()))));
        let Some(body) = self.function_body(key, callee, vars) else { return (FALSE, Ty::Err) };
        let ty = vars[result.index()].ty.clone();
        let temp = VarId((self.declared + self.temps.len()) as u32);
        self.temps.push(VarInfo {
            name: format!("{}#{}", callee.name, self.temps.len() + 1),
            ty: ty.clone(),
            init: ty.default_value(),
            constant: false,
            section: VarSection::Temp,
            hidden: true,
        });
        let outputs = vec![FbOutput { member: result, target: temp, negated: false }];
        let call = UserCall { body, en: None, inputs: assigned, inouts: Vec::new(), outputs, eno };
        self.hoisted.push(CStmt::UserFb(Box::new(call)));
        (CExpr::Var(temp), Ty::of(&ty))
    }

    /// `SPLIT_DATE(IN := d, YEAR => y, MONTH => m, DAY => dd);` (and SPLIT_TOD, SPLIT_DT): a function whose
    /// results are output parameters, written formally or in order (`SPLIT_DATE(d, y, m, dd)`); outputs left out
    /// are not written.
    fn split_call(
        &mut self,
        callee: &Ident,
        args: &[Arg],
        input: Ty,
        parts: &[(&str, DatePart)],
        vars: &[VarInfo],
    ) -> Option<CStmt> {
        let name = callee.key();
        let formal = args.iter().any(|a| a.name.is_some());
        let mut value = None;
        let mut targets: Vec<(DatePart, &Expr)> = Vec::new();
        for (i, arg) in args.iter().enumerate() {
            let slot = match &arg.name {
                Some(n) if n.key() == "IN" && !arg.output => None,
                Some(n) => match parts.iter().find(|(p, _)| *p == n.key()) {
                    Some(&(_, part)) if arg.output => Some(part),
                    Some(_) => {
                        self.error(
                            arg.span,
                            format!("`{}` is an output of {name}: write it `{} => variable`", n.name, n.name),
                        );
                        return None;
                    }
                    None => {
                        let outputs: Vec<&str> = parts.iter().map(|(p, _)| *p).collect();
                        let message =
                            format!("{name} has no parameter `{}`: it has IN and {}", n.name, outputs.join(", "));
                        self.error(n.span, message);
                        return None;
                    }
                },
                None if formal => {
                    self.error(
                        arg.span,
                        "a call mixes formal (`IN := x`) and non-formal arguments: name every argument",
                    );
                    return None;
                }
                None if i == 0 => None,
                None => match parts.get(i - 1) {
                    Some(&(_, part)) => Some(part),
                    None => {
                        self.error(arg.span, format!("{name} takes IN and {} outputs", parts.len()));
                        return None;
                    }
                },
            };
            match slot {
                None => value = Some(&arg.value),
                Some(part) => targets.push((part, &arg.value)),
            }
        }
        let Some(value) = value else {
            self.error(callee.span, format!("{name} needs its input `IN`"));
            return None;
        };
        let (c, ty) = self.expr(value, vars);
        if ty != input && ty != Ty::Err {
            self.error(value.span, format!("IN of {name} must be {}, found {}", input.name(), ty.name()));
            return None;
        }
        let mut assigns = Vec::with_capacity(targets.len());
        for (part, target) in targets {
            let id = self.place(target, vars)?;
            if !Ty::of(&vars[id.index()].ty).is_int() {
                let message = format!(
                    "an output of {name} is an integer, and `{}` is {}",
                    vars[id.index()].name,
                    vars[id.index()].ty
                );
                self.error(target.span, message);
                return None;
            }
            let part = CExpr::call(Func::Date(DateFn::Part(part)), vec![c.clone()], vars[id.index()].ty.clone());
            assigns.push(CStmt::Assign { var: id, value: part });
        }
        // The outputs as one statement.
        Some(CStmt::If { branches: vec![(CExpr::Const(Value::Bool(true)), assigns)], otherwise: Vec::new() })
    }

    /// `instance.Action();`: the action of a user block instance, run in the instance's scope (CODESYS, TwinCAT).
    fn instance_action_call(&mut self, callee: &Ident, instance: &str, action: &str, args: &[Arg]) -> Option<CStmt> {
        let key = instance.to_ascii_uppercase();
        if let Some(&u) = self.user_of.get(&key) {
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
            if let Some(arg) = args.first() {
                self.error(arg.span, format!("action `{}` of `{}` takes no arguments", a.name.name, def.name.name));
                return None;
            }
            let body = self.users[u].actions.get(&a.name.key()).cloned()?;
            let eno = self.users[u].eno;
            let call = UserCall { body, en: None, inputs: Vec::new(), inouts: Vec::new(), outputs: Vec::new(), eno };
            return Some(CStmt::UserFb(Box::new(call)));
        }
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
    fn own_action_call(&mut self, callee: &Ident, args: &[Arg], vars: &[VarInfo]) -> Option<Option<CStmt>> {
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
    fn fb_action_body(&mut self, u: usize, name: &Ident, vars: &[VarInfo]) -> Option<Arc<Vec<CStmt>>> {
        let key = name.key();
        if let Some(body) = self.users[u].actions.get(&key) {
            return Some(Arc::clone(body));
        }
        let def = self.users[u].def;
        let action = def.actions.iter().find(|a| a.name.key() == key)?;
        let stack = format!("{}#{key}", def.name.key());
        let body = self.action_body(&stack, name, &action.body, vars)?;
        self.users[u].actions.insert(key, Arc::clone(&body));
        Some(body)
    }

    /// The body of the chart's action called as a subroutine, compiled once.
    fn chart_action_body(&mut self, name: &Ident, body: &'a [Stmt], vars: &[VarInfo]) -> Option<Arc<Vec<CStmt>>> {
        let key = name.key();
        if let Some(body) = self.called_actions.get(&key) {
            return Some(Arc::clone(body));
        }
        let compiled = self.action_body(&key, name, body, vars)?;
        self.called_actions.insert(key, Arc::clone(&compiled));
        Some(compiled)
    }

    fn action_body(&mut self, key: &str, name: &Ident, body: &[Stmt], vars: &[VarInfo]) -> Option<Arc<Vec<CStmt>>> {
        if self.calling_actions.iter().any(|k| k == key) {
            self.error(name.span, format!("action `{}` calls itself, directly or through others", name.name));
            return None;
        }
        if self.calling_actions.len() >= NESTING_DEPTH_MAX {
            self.error(name.span, format!("calls of actions nested more than {NESTING_DEPTH_MAX} levels deep"));
            return None;
        }
        self.calling_actions.push(key.to_string());
        let compiled = self.statements(body, vars);
        self.calling_actions.pop();
        Some(Arc::new(compiled))
    }

    /// A hidden variable for the ENO of a call of `callee` that has none of its own (an action).
    fn call_eno(&mut self, callee: &Ident) -> VarId {
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

    /// A user instance's initial inputs from its declaration, `m : Motor := (speed := 10)`.
    fn user_inits(&mut self, u: usize, decl: &VarDecl, vars: &mut [VarInfo]) {
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
    fn compile_user_bodies(&mut self, vars: &[VarInfo]) {
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
            let saved = (
                std::mem::replace(&mut self.vars, names),
                std::mem::take(&mut self.instances),
                std::mem::take(&mut self.user_of),
                std::mem::take(&mut self.steps),
                std::mem::take(&mut self.actions),
            );
            self.instances = std::mem::take(&mut self.users[u].scope.instances);
            self.user_of = std::mem::take(&mut self.users[u].scope.users);
            let chart_arrays = std::mem::replace(&mut self.arrays, std::mem::take(&mut self.users[u].scope.arrays));
            let chart_structs = std::mem::replace(&mut self.structs, std::mem::take(&mut self.users[u].scope.structs));
            self.current_user = Some(u);
            let body = self.statements(&def.body, vars);
            for a in &def.actions {
                self.fb_action_body(u, &a.name, vars);
            }
            self.current_user = None;
            self.users[u].scope.arrays = std::mem::replace(&mut self.arrays, chart_arrays);
            self.users[u].scope.structs = std::mem::replace(&mut self.structs, chart_structs);
            self.users[u].scope.vars = std::mem::replace(&mut self.vars, saved.0);
            self.users[u].scope.instances = std::mem::replace(&mut self.instances, saved.1);
            self.users[u].scope.users = std::mem::replace(&mut self.user_of, saved.2);
            self.steps = saved.3;
            self.actions = saved.4;
            self.users[u].body = Arc::new(body);
        }
    }

    /// A structure variable: one variable per field, `s.field`, with the field's initial value or the one the
    /// declaration gives (`s : Point := (x := 1)`).
    fn declare_struct(
        &mut self,
        decl: &VarDecl,
        fields: &[VarDecl],
        label: &str,
        hidden: bool,
        vars: &mut Vec<VarInfo>,
    ) {
        if self.struct_depth >= crate::limits::NESTING_DEPTH_MAX {
            let message = format!("structure `{}` holds itself, or nests too deep", decl.type_name.name);
            self.error(decl.type_name.span, message);
            return;
        }
        self.struct_depth += 1;
        let mut names = Vec::new();
        for f in fields {
            if StdFb::from_name(&f.type_name.key()).is_some() || self.library.contains_key(&f.type_name.key()) {
                let message = format!(
                    "field `{}` of `{}`: structures holding function block instances are not supported yet",
                    f.name.name, decl.type_name.name
                );
                self.error(f.type_name.span, message);
                continue;
            }
            // A field that is an array or a structure is a run of variables of its own, named by its path.
            let local = format!("{}.{}", decl.name.name, f.name.name);
            let path = format!("{label}.{}", f.name.name);
            if let Some(spec) = self.array_spec_of(f) {
                if let Some(info) = self.array_elements((&path, &local), &spec, Storage::of(decl, hidden), vars) {
                    self.arrays.insert(local.to_ascii_uppercase(), info);
                }
                names.push(f.name.name.clone());
                continue;
            }
            let structure = match self.types.get(&f.type_name.key()).copied().map(|t| &t.kind) {
                Some(TypeKind::Struct(inner)) => Some(inner),
                _ => None,
            };
            if let Some(inner) = structure {
                let sub = VarDecl {
                    name: Ident { name: local, span: f.name.span },
                    section: decl.section,
                    constant: decl.constant,
                    type_name: f.type_name.clone(),
                    init: None,
                    members: Vec::new(),
                    array: None,
                    pragmas: Vec::new(),
                };
                self.declare_struct(&sub, inner, &path, hidden, vars);
                names.push(f.name.name.clone());
                continue;
            }
            let ty = self.resolve_type(&f.type_name);
            let given = decl.members.iter().find(|(m, _)| m.key() == f.name.key()).map(|(_, e)| e);
            let init = match given.or(f.init.as_ref()) {
                Some(e) => self.initial_value(e, &ty),
                None => self.default_of(&ty),
            };
            self.vars.insert(format!("{}.{}", decl.name.key(), f.name.key()), VarId(vars.len() as u32));
            vars.push(VarInfo {
                name: format!("{label}.{}", f.name.name),
                ty,
                init,
                constant: decl.constant,
                section: decl.section,
                hidden,
            });
            names.push(f.name.name.clone());
        }
        for (m, _) in &decl.members {
            if !fields.iter().any(|f| f.name.key() == m.key()) {
                self.error(m.span, format!("`{}` has no field `{}`", decl.type_name.name, m.name));
            }
        }
        self.structs.insert(decl.name.key(), (decl.type_name.name.clone(), names));
        self.struct_depth -= 1;
    }

    /// An array variable: one variable per element, `a[1]`, `a[1,2]`, row-major.
    fn declare_array(&mut self, decl: &VarDecl, spec: &ArraySpec, vars: &mut Vec<VarInfo>) {
        let label = decl.name.name.clone();
        if let Some(info) = self.array_elements((&label, &label), spec, Storage::of(decl, false), vars) {
            self.arrays.insert(decl.name.key(), info);
        }
    }

    /// The array a declaration declares: `ARRAY […] OF …` in it, or an array type by name.
    fn array_spec_of(&self, decl: &VarDecl) -> Option<ArraySpec> {
        decl.array.clone().or_else(|| match self.types.get(&decl.type_name.key()).map(|t| &t.kind) {
            Some(TypeKind::Array(spec)) => Some(spec.clone()),
            _ => None,
        })
    }

    /// An array's elements, as variables named `label[1,2]` (row-major, the last index fastest) with their
    /// initial values; `None` after an error.
    fn array_elements(
        &mut self,
        (label, local): (&str, &str),
        spec: &ArraySpec,
        storage: Storage,
        vars: &mut Vec<VarInfo>,
    ) -> Option<ArrayInfo> {
        let Storage { constant, section, hidden } = storage;
        if let Some(&(low, high)) = spec.dims.iter().find(|(low, high)| high < low) {
            self.error(spec.span, format!("array `{label}` has an empty dimension {low}..{high}"));
            return None;
        }
        // In 128 bits: a dimension over the whole of LINT has 2^64 elements, which must not wrap to zero.
        let len = spec.elements().filter(|&n| n <= crate::limits::ARRAY_ELEMENTS_MAX as u64);
        let Some(len) = len.map(|n| n as usize) else {
            let size: String = spec.dims.iter().map(|(l, h)| format!("[{l}..{h}]")).collect();
            let message = format!(
                "array `{label}` {size} has more elements than the {} Baton holds",
                crate::limits::ARRAY_ELEMENTS_MAX
            );
            self.error(spec.span, message);
            return None;
        };
        if vars.len().saturating_add(len) > crate::limits::VARIABLES_MAX {
            let message = format!(
                "array `{label}` takes the chart past {} variables (elements of arrays, members of blocks)",
                crate::limits::VARIABLES_MAX
            );
            self.error(spec.span, message);
            return None;
        }
        if StdFb::from_name(&spec.elem.key()).is_some() || self.library.contains_key(&spec.elem.key()) {
            self.error(spec.elem.span, "arrays of function block instances are not supported yet");
            return None;
        }
        let structure = match self.types.get(&spec.elem.key()).copied().map(|t| &t.kind) {
            Some(TypeKind::Struct(fields)) => Some(fields),
            _ => None,
        };
        if let Some(fields) = structure {
            return self.struct_elements((label, local), spec, fields, len, storage, vars);
        }
        let elem = self.resolve_type(&spec.elem);
        if spec.init_len() > len as u64 {
            // The run that goes past the end: the values before it still count.
            let mut given = 0u64;
            let past = spec.init.iter().find(|r| {
                given = given.saturating_add(r.count);
                given > len as u64
            });
            if let Some(run) = past {
                self.error(run.value.span, format!("array `{label}` has {len} elements, and more initial values"));
            }
        }
        let base = VarId(vars.len() as u32);
        let default = self.default_of(&elem);
        let mut index: Vec<i64> = spec.dims.iter().map(|&(low, _)| low).collect();
        // Each run's value is computed once, then given to as many elements as it counts.
        let mut runs = spec.init.iter();
        let mut current: Option<(Value, u64)> = None;
        for _ in 0..len {
            if current.as_ref().is_none_or(|(_, left)| *left == 0) {
                current = runs.next().map(|r| (self.initial_value(&r.value, &elem), r.count));
            }
            let init = match current.as_mut() {
                Some((v, left)) if *left > 0 => {
                    *left -= 1;
                    v.clone()
                }
                _ => default.clone(),
            };
            let index_label: Vec<String> = index.iter().map(|i| i.to_string()).collect();
            vars.push(VarInfo {
                name: format!("{label}[{}]", index_label.join(",")),
                ty: elem.clone(),
                init,
                constant,
                section,
                hidden,
            });
            // The next index, the last dimension fastest.
            for d in (0..index.len()).rev() {
                if index[d] < spec.dims[d].1 {
                    index[d] += 1;
                    break;
                }
                index[d] = spec.dims[d].0;
            }
        }
        Some(ArrayInfo { base, dims: spec.dims.clone(), len: len as u32, elem, stride: 1, fields: HashMap::new() })
    }

    /// An array of structures: each element a run of field variables (`pts[2].x`, the fields of fields too),
    /// elements one after another, so that a field of an element indexed at run time is `base + field + i ·
    /// stride`.
    fn struct_elements(
        &mut self,
        (label, local): (&str, &str),
        spec: &ArraySpec,
        fields: &[VarDecl],
        len: usize,
        Storage { constant, section, hidden }: Storage,
        vars: &mut Vec<VarInfo>,
    ) -> Option<ArrayInfo> {
        if let Some(first) = spec.init.first() {
            self.error(
                first.value.span,
                format!("initial values of `{label}`, an array of structures, are not supported yet"),
            );
        }
        let base = VarId(vars.len() as u32);
        let mut index: Vec<i64> = spec.dims.iter().map(|&(low, _)| low).collect();
        let (mut stride, mut at) = (0, HashMap::new());
        for k in 0..len {
            let idx = index.iter().map(|i| i.to_string()).collect::<Vec<_>>().join(",");
            let start = vars.len();
            let decl = VarDecl {
                name: Ident { name: format!("{local}[{idx}]"), span: spec.span },
                section,
                constant,
                type_name: spec.elem.clone(),
                init: None,
                members: Vec::new(),
                array: None,
                pragmas: Vec::new(),
            };
            self.declare_struct(&decl, fields, &format!("{label}[{idx}]"), hidden, vars);
            if k == 0 {
                stride = vars.len() - start;
                for f in fields {
                    let name = format!("{label}[{idx}].{}", f.name.name);
                    if let Some(i) = (start..vars.len()).find(|&i| vars[i].name.eq_ignore_ascii_case(&name)) {
                        at.insert(f.name.key(), ((i - start) as u32, vars[i].ty.clone()));
                    }
                }
            }
            let total = len.saturating_mul(stride);
            if stride == 0
                || total > crate::limits::ARRAY_ELEMENTS_MAX
                || start.saturating_add(total) > crate::limits::VARIABLES_MAX
            {
                let message = format!("array `{label}` holds structures with no field, or too many variables");
                self.error(spec.span, message);
                return None;
            }
            for d in (0..index.len()).rev() {
                if index[d] < spec.dims[d].1 {
                    index[d] += 1;
                    break;
                }
                index[d] = spec.dims[d].0;
            }
        }
        let elem = Type::Unsupported(spec.elem.name.clone());
        Some(ArrayInfo {
            base,
            dims: spec.dims.clone(),
            len: (len * stride) as u32,
            elem,
            stride: stride as u32,
            fields: at,
        })
    }

    /// An array element: a variable when every index is a constant (checked against the bounds), else an
    /// index computed at run time.
    fn element(&mut self, name: &Ident, indices: &[Expr], vars: &[VarInfo]) -> Option<(CExpr, Ty)> {
        let Some(info) = self.arrays.get(&name.key()) else {
            if !self.chart.broken.var(&name.key()) {
                self.error(name.span, format!("`{}` is not an array", name.name));
            }
            return None;
        };
        if !info.fields.is_empty() {
            let first = info.fields.iter().min_by_key(|(_, (at, _))| *at).map(|(f, _)| f.clone()).unwrap_or_default();
            let message = format!(
                "`{}` holds structures: use one of their fields, such as `{}[…].{}`",
                name.name,
                name.name,
                first.to_ascii_lowercase()
            );
            self.error(name.span, message);
            return None;
        }
        self.indexed(name, indices, 0, None, vars)
    }

    /// A field of an array's structure element: `pts[i].x`.
    fn element_field(
        &mut self,
        name: &Ident,
        indices: &[Expr],
        field: &Ident,
        vars: &[VarInfo],
    ) -> Option<(CExpr, Ty)> {
        let Some(info) = self.arrays.get(&name.key()) else {
            if !self.chart.broken.var(&name.key()) {
                self.error(name.span, format!("`{}` is not an array", name.name));
            }
            return None;
        };
        let Some((offset, ty)) = info.fields.get(&field.key()).cloned() else {
            let message = if info.fields.is_empty() {
                format!("`{}` holds {} values, which have no field `{}`", name.name, info.elem, field.name)
            } else {
                format!(
                    "the structures in `{}` have no field `{}` (fields of fields need constant indices)",
                    name.name, field.name
                )
            };
            self.error(field.span, message);
            return None;
        };
        self.indexed(name, indices, offset, Some(ty), vars)
    }

    /// Element `offset` of the element `indices` name: a variable when every index is a constant (checked
    /// against the bounds), else an index computed at run time.
    fn indexed(
        &mut self,
        name: &Ident,
        indices: &[Expr],
        offset: u32,
        field: Option<Type>,
        vars: &[VarInfo],
    ) -> Option<(CExpr, Ty)> {
        let info = self.arrays.get(&name.key())?;
        let (base, dims, len, stride) = (info.base, info.dims.clone(), info.len, info.stride);
        let elem = field.unwrap_or_else(|| info.elem.clone());
        if indices.len() != dims.len() {
            let message = format!("`{}` has {} dimension(s), indexed with {}", name.name, dims.len(), indices.len());
            self.error(name.span, message);
            return None;
        }
        let mut compiled = Vec::with_capacity(indices.len());
        let mut constant = Some(0i64);
        for (e, &(low, high)) in indices.iter().zip(&dims) {
            let (c, ty) = self.expr(e, vars);
            if !ty.is_int() && ty != Ty::Err {
                self.error(e.span, format!("an array index must be an integer, found {}", ty.name()));
                return None;
            }
            match (constant, is_constant(&c).then(|| eval(&c, &NoEnv))) {
                (Some(acc), Some(Ok(v))) => {
                    let i = v.as_i64();
                    if i < low || i > high {
                        self.error(e.span, format!("index {i} is outside `{}`'s bounds {low}..{high}", name.name));
                        return None;
                    }
                    constant = Some(acc * (high - low + 1) + (i - low));
                }
                _ => constant = None,
            }
            compiled.push(c);
        }
        let ty = Ty::of(&elem);
        Some(match constant {
            Some(at) => (CExpr::Var(VarId(base.0 + offset + at as u32 * stride)), ty),
            None => (CExpr::Index(Box::new(IndexExpr { base, dims, indices: compiled, len, stride, offset })), ty),
        })
    }

    /// A type by name: elementary, or declared in the file (an enumeration; a subrange or an alias as its base).
    fn resolve_type(&mut self, name: &Ident) -> Type {
        self.resolve_depth(name, 0)
    }

    fn resolve_depth(&mut self, name: &Ident, depth: usize) -> Type {
        let key = name.key();
        if let Some(t) = Type::from_name(&key) {
            return t;
        }
        if let Some(t) = self.resolved.get(&key) {
            return t.clone();
        }
        let unsupported = || Type::Unsupported(name.name.to_ascii_uppercase());
        let Some(&def) = self.types.get(&key) else { return unsupported() };
        if depth > 16 {
            self.error(name.span, format!("type `{}` is defined through itself", name.name));
            return unsupported();
        }
        let ty = match &def.kind {
            TypeKind::Enum { values, init } => {
                let id = self.enums.len() as u32;
                let et = crate::types::EnumType {
                    id,
                    name: def.name.name.clone(),
                    values: values.iter().map(|v| v.name.clone()).collect(),
                };
                let start = match init {
                    Some(i) => match values.iter().position(|v| v.key() == i.key()) {
                        Some(p) => p as i64,
                        None => {
                            self.error(i.span, format!("`{}` is not a value of `{}`", i.name, def.name.name));
                            0
                        }
                    },
                    None => 0,
                };
                let et = std::sync::Arc::new(et);
                self.enums.push((std::sync::Arc::clone(&et), start));
                Type::Enum(et)
            }
            TypeKind::Subrange { base, .. } | TypeKind::Alias(base) => self.resolve_depth(base, depth + 1),
            // Arrays and structures are laid out where a variable is declared with them.
            TypeKind::Array(_) | TypeKind::Struct(_) => unsupported(),
            TypeKind::Unsupported(_) => unsupported(),
        };
        self.resolved.insert(key, ty.clone());
        ty
    }

    /// A variable's initial value when its declaration gives none: an enumeration's declared one, or the type's.
    /// The range of a subrange type (through aliases of it), with the type's name.
    fn subrange(&self, name: &Ident) -> Option<(i64, i64, String)> {
        let mut key = name.key();
        for _ in 0..crate::limits::NESTING_DEPTH_MAX {
            match &self.types.get(&key)?.kind {
                TypeKind::Subrange { low, high, .. } => return Some((*low, *high, name.name.clone())),
                TypeKind::Alias(base) => key = base.key(),
                _ => return None,
            }
        }
        None
    }

    /// A constant stored in a subrange variable must be in its range (IEC 61131-3 calls anything else an error;
    /// like matiec and CODESYS without its CheckRange functions, Baton checks constants, not run-time values).
    fn check_range(&mut self, span: Span, v: &Value, (low, high, ty): &(i64, i64, String)) {
        if let Value::Int(i) = *v {
            if i < *low || i > *high {
                self.error(span, format!("{i} is outside the range of {ty} ({low}..{high})"));
            }
        }
    }

    fn default_of(&self, ty: &Type) -> Value {
        match ty {
            Type::Enum(e) => Value::Int(self.enums.get(e.id as usize).map_or(0, |(_, start)| *start)),
            other => other.default_value(),
        }
    }

    /// An enumeration value by name (alone, or with its type: `VALVE#OPEN`).
    fn enum_value(&mut self, ty: Option<&Ident>, value: &Ident) -> Option<(CExpr, Ty)> {
        let mut found = Vec::new();
        if let Some(t) = ty {
            if let Type::Enum(e) = self.resolve_type(t) {
                found.extend(e.values.iter().position(|v| v.eq_ignore_ascii_case(&value.name)).map(|i| (e.id, i)));
            }
        } else {
            for (e, _) in &self.enums {
                found.extend(e.values.iter().position(|v| v.eq_ignore_ascii_case(&value.name)).map(|i| (e.id, i)));
            }
        }
        match found.as_slice() {
            [(id, i)] => Some((CExpr::Const(Value::Int(*i as i64)), Ty::Enum(*id))),
            [] => None,
            _ => {
                let message = format!(
                    "`{}` is a value of several enumerations: write it with its type, `TYPE#{}`",
                    value.name, value.name
                );
                self.error(value.span, message);
                Some((FALSE, Ty::Err))
            }
        }
    }

    /// An instance of a standard block: one variable per member, named `instance.MEMBER`.
    fn declare_instance(&mut self, decl: &VarDecl, fb: StdFb, vars: &mut Vec<VarInfo>) {
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

    fn initial_value(&mut self, e: &Expr, ty: &Type) -> Value {
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

    /// Declared actions, and the chart element behind each.
    fn declare_actions(&mut self) -> (Vec<ActionInfo>, Vec<&'a Action>) {
        let chart = self.chart;
        let mut actions = Vec::new();
        let mut sources = Vec::new();
        for action in &chart.actions {
            if self.actions.contains_key(&action.name.key()) {
                self.error(action.name.span, format!("action `{}` is declared twice", action.name.name));
                continue;
            }
            self.actions.insert(action.name.key(), ActionId(actions.len() as u32));
            sources.push(action);
            actions.push(ActionInfo {
                name: action.name.name.clone(),
                body: Vec::new(),
                once: None,
                bool_var: None,
                pragmas: action.pragmas.clone(),
            });
        }
        (actions, sources)
    }

    fn associate(
        &mut self,
        vars: &[VarInfo],
        sources: &[&Step],
        steps: &mut [StepParts],
        actions: &mut Vec<ActionInfo>,
    ) {
        for (parts, step) in steps.iter_mut().zip(sources) {
            let mut assocs = Vec::with_capacity(step.associations.len());
            for a in &step.associations {
                let Some(action) = self.action_for(a, vars, actions) else { continue };
                let duration = self.duration(a, vars);
                let mut indicators = Vec::new();
                for ind in &a.indicators {
                    match self.vars.get(&ind.key()) {
                        Some(&v) if vars[v.index()].ty == Type::Bool => indicators.push(v),
                        Some(&v) => {
                            let message =
                                format!("indicator variable `{}` must be BOOL, not {}", ind.name, vars[v.index()].ty);
                            self.error(ind.span, message);
                        }
                        None if self.chart.broken.var(&ind.key()) => {}
                        None => self.error(ind.span, format!("undeclared indicator variable `{}`", ind.name)),
                    }
                }
                assocs.push((Assoc { action, qualifier: a.qualifier, duration }, indicators));
            }
            parts.associations = assocs;
        }
        // An action associated only as entry actions (or only as exit actions) runs once each time: no final
        // scan, and before the others of its cycle.
        let mut kinds: Vec<Option<Option<Once>>> = vec![None; actions.len()];
        for (assoc, _) in steps.iter().flat_map(|p| &p.associations) {
            let kind = match assoc.qualifier {
                Qualifier::Entry => Some(Once::Entry),
                Qualifier::Exit => Some(Once::Exit),
                _ => None,
            };
            let slot = &mut kinds[assoc.action.index()];
            *slot = Some(match *slot {
                None => kind,
                Some(k) if k == kind => kind,
                Some(_) => None,
            });
        }
        for (a, kind) in actions.iter_mut().zip(kinds) {
            a.once = kind.flatten();
        }
    }

    /// The action an association names: a declared action, or a boolean action named after a BOOL variable.
    fn action_for(&mut self, a: &Association, vars: &[VarInfo], actions: &mut Vec<ActionInfo>) -> Option<ActionId> {
        if let Some(&id) = self.actions.get(&a.action.key()) {
            return Some(id);
        }
        match self.vars.get(&a.action.key()) {
            Some(&v) if vars[v.index()].ty == Type::Bool => {
                let id = ActionId(actions.len() as u32);
                self.actions.insert(a.action.key(), id);
                actions.push(ActionInfo {
                    name: vars[v.index()].name.clone(),
                    body: Vec::new(),
                    once: None,
                    bool_var: Some(v),
                    pragmas: Vec::new(),
                });
                Some(id)
            }
            Some(&v) => {
                let message = format!(
                    "`{}` has no ACTION body and is a {} variable: a boolean action needs a BOOL variable",
                    a.action.name,
                    vars[v.index()].ty
                );
                self.error(a.action.span, message);
                None
            }
            None if self.chart.broken.action(&a.action.key()) || self.chart.broken.var(&a.action.key()) => None,
            None => {
                self.error(
                    a.action.span,
                    format!(
                        "unknown action `{}`: declare it with `ACTION {}: … END_ACTION` or as a BOOL variable",
                        a.action.name, a.action.name
                    ),
                );
                None
            }
        }
    }

    fn duration(&mut self, a: &Association, vars: &[VarInfo]) -> Option<DurationSrc> {
        match (&a.duration, a.qualifier.is_timed()) {
            (None, true) => {
                let message = format!(
                    "qualifier {:?} needs a duration, such as `{}({:?}, T#1s)`",
                    a.qualifier, a.action.name, a.qualifier
                );
                self.error(a.qualifier_span, message);
                None
            }
            (None, false) => None,
            (Some(Duration::Literal { ms, span }), _) => {
                if *ms < 0 {
                    self.error(*span, "a duration must not be negative");
                }
                Some(DurationSrc::Ms((*ms).max(0)))
            }
            (Some(Duration::Var(name)), _) => match self.vars.get(&name.key()) {
                Some(&v) if vars[v.index()].ty == Type::Time => Some(DurationSrc::Var(v)),
                Some(&v) => {
                    let message = format!("duration variable `{}` must be TIME, not {}", name.name, vars[v.index()].ty);
                    self.error(name.span, message);
                    None
                }
                None => {
                    if !self.chart.broken.var(&name.key()) {
                        self.error(name.span, format!("undeclared variable `{}`", name.name));
                    }
                    None
                }
            },
        }
    }

    fn step_list(&mut self, list: &[Ident]) -> Option<Vec<StepId>> {
        let mut ids = Vec::with_capacity(list.len());
        let mut ok = true;
        for name in list {
            match self.steps.get(&name.key()) {
                Some(&id) if ids.contains(&id) => {
                    self.error(name.span, format!("step `{}` appears twice in this list", name.name));
                    ok = false;
                }
                Some(&id) => ids.push(id),
                None => {
                    if !self.chart.broken.step(&name.key()) {
                        self.error(name.span, format!("unknown step `{}`", name.name));
                    }
                    ok = false;
                }
            }
        }
        ok.then_some(ids)
    }

    fn transitions(&mut self, vars: &[VarInfo], out: &mut Vec<TransitionParts>) -> bool {
        let chart = self.chart;
        let mut names: HashMap<String, Span> = HashMap::new();
        let mut net_ok = true;
        for t in &chart.transitions {
            if let Some(name) = &t.name {
                if names.insert(name.key(), name.span).is_some() {
                    self.error(name.span, format!("transition `{}` is declared twice", name.name));
                }
            }
            let sources = self.step_list(&t.from);
            let targets = self.step_list(&t.to);
            let outer = std::mem::take(&mut self.hoisted);
            let (condition, ty) = bool_literal(self.expr(&t.condition, vars));
            let hoisted = std::mem::replace(&mut self.hoisted, outer);
            if ty != Ty::Bool && ty != Ty::Err {
                self.error(t.condition.span, format!("a transition condition must be BOOL, found {}", ty.name()));
            } else if ty == Ty::Bool
                && is_constant(&condition)
                && eval(&condition, &NoEnv) == Ok(Value::Bool(false))
                && !self.chart.broken.conditions.contains(&t.condition.span)
            {
                let name = t.display_name();
                self.diags.push(Diagnostic::warning(
                    t.condition.span,
                    format!("transition `{name}` can never clear: its condition is always FALSE"),
                ));
            }
            let (Some(sources), Some(targets)) = (sources, targets) else {
                net_ok = false;
                continue;
            };
            // The function calls in the condition run when it is judged.
            let calls = hoisted;
            let depth = crate::exec::program::condition_depth(&calls, &condition, &mut self.depth_memo);
            if depth > NESTING_DEPTH_MAX {
                self.too_deep(t.condition.span, &format!("the condition of transition `{}`", t.display_name()), depth);
            }
            let info = TransitionInfo { name: t.display_name(), condition, pragmas: t.pragmas.clone() };
            out.push(TransitionParts { info, calls, sources, targets, rank: 0 });
        }
        // Clearing order: explicit priorities first, lower number first, then declaration order.
        if net_ok {
            let mut order: Vec<usize> = (0..out.len()).collect();
            order.sort_by_key(|&i| match chart.transitions[i].priority {
                Some((p, _)) => (0, p, i),
                None => (1, 0, i),
            });
            for (rank, i) in order.into_iter().enumerate() {
                out[i].rank = rank as u32;
            }
        }
        net_ok
    }

    fn statements(&mut self, body: &[Stmt], vars: &[VarInfo]) -> Vec<CStmt> {
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

    fn statement(&mut self, stmt: &Stmt, vars: &[VarInfo]) -> Option<CStmt> {
        Some(match stmt {
            Stmt::Assign { target, value, .. } => {
                let plain = self.unqualified(target);
                let target = plain.as_ref().unwrap_or(target);
                let (mut cvalue, mut vty) = self.expr(value, vars);
                let indexed = match &target.kind {
                    ExprKind::Index(name, indices) => Some((name, self.element(name, indices, vars))),
                    ExprKind::IndexField(name, indices, field) => {
                        Some((name, self.element_field(name, indices, field, vars)))
                    }
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
                CStmt::Assign { var: id, value: cvalue }
            }
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

    fn loop_body(&mut self, body: &[Stmt], vars: &[VarInfo]) -> Vec<CStmt> {
        self.loops += 1;
        let out = self.statements(body, vars);
        self.loops -= 1;
        out
    }

    fn condition(&mut self, e: &Expr, vars: &[VarInfo], what: &str) -> CExpr {
        let (c, ty) = bool_literal(self.expr(e, vars));
        if ty != Ty::Bool && ty != Ty::Err {
            self.error(e.span, format!("{what} must be BOOL, found {}", ty.name()));
        }
        c
    }

    /// A CASE label: a constant integer.
    fn case_label(&mut self, e: &Expr) -> Option<i64> {
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
    fn place(&mut self, target: &Expr, vars: &[VarInfo]) -> Option<VarId> {
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
                        format!("undeclared variable `{}`", name.name)
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

    /// A member of an instance, by name (hidden state has none).
    fn member(&mut self, fb: StdFb, base: VarId, inst: &Ident, field: &Ident) -> Option<VarId> {
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
    fn fb_call(&mut self, callee: &Ident, args: &[Arg], span: Span, vars: &[VarInfo]) -> Option<CStmt> {
        if let Some(plain) = self.unqualified_name(callee) {
            return self.fb_call(&plain, args, span, vars);
        }
        if let Some((instance, action)) = callee.name.rsplit_once('.') {
            return self.instance_action_call(callee, instance, action, args);
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
        let inputs_order: Vec<usize> = (0..members.len()).filter(|&i| members[i].kind == MemberKind::Input).collect();
        let (mut en, mut inputs, mut outputs) = (None, Vec::new(), Vec::new());
        let formal = args.iter().any(|a| a.name.is_some());
        let mut positional = 0;
        let mut ok = true;
        for arg in args {
            if formal && arg.name.is_none() {
                self.error(arg.span, "a call mixes formal (`IN := x`) and non-formal arguments: name every argument");
                ok = false;
                continue;
            }
            let name = arg.name.as_ref();
            if name.is_some_and(|n| n.key() == "EN") {
                if arg.output {
                    self.error(arg.span, "EN is an input: write `EN := condition`");
                    ok = false;
                } else {
                    en = Some(self.condition(&arg.value, vars, "EN"));
                }
                continue;
            }
            let index = match name {
                Some(n) => match members
                    .iter()
                    .position(|m| m.kind != MemberKind::State && m.name.eq_ignore_ascii_case(&n.name))
                {
                    Some(i) => i,
                    None => {
                        self.member(fb, base, callee, n);
                        ok = false;
                        continue;
                    }
                },
                None => match inputs_order.get(positional) {
                    Some(&i) => {
                        positional += 1;
                        i
                    }
                    None => {
                        let message = format!("too many arguments: {} takes {} inputs", fb.name(), inputs_order.len());
                        self.error(arg.span, message);
                        ok = false;
                        continue;
                    }
                },
            };
            let member = &members[index];
            let id = VarId(base.0 + index as u32);
            if arg.output {
                if member.kind == MemberKind::Input {
                    let message =
                        format!("`{}` is an input of {}: write `{} := value`", member.name, fb.name(), member.name);
                    self.error(arg.span, message);
                    ok = false;
                    continue;
                }
                let Some(target) = self.place(&arg.value, vars) else {
                    ok = false;
                    continue;
                };
                let target_ty = Ty::of(&vars[target.index()].ty);
                let member_ty = Ty::of(&member.ty);
                if arg.negated && member_ty != Ty::Bool {
                    self.error(
                        arg.span,
                        format!("NOT applies to BOOL outputs, and `{}` is {}", member.name, member.ty),
                    );
                    ok = false;
                } else if !assignable(target_ty, member_ty) {
                    let message = format!(
                        "`{}` is {} and cannot be written to `{}`, which is {}",
                        member.name,
                        member.ty,
                        vars[target.index()].name,
                        vars[target.index()].ty
                    );
                    self.error(arg.value.span, message);
                    ok = false;
                } else {
                    outputs.push(FbOutput { member: id, target, negated: arg.negated });
                }
                continue;
            }
            if member.kind != MemberKind::Input {
                let message =
                    format!("`{}` is an output of {}: write `{} => variable`", member.name, fb.name(), member.name);
                self.error(arg.span, message);
                ok = false;
                continue;
            }
            let (mut value, mut ty) = self.expr(&arg.value, vars);
            if Ty::of(&member.ty) == Ty::Bool {
                if let ExprKind::Int(v @ (0 | 1)) = arg.value.kind {
                    (value, ty) = (CExpr::Const(Value::Bool(v == 1)), Ty::Bool);
                }
            }
            if !assignable(Ty::of(&member.ty), ty) {
                let message = format!("input `{}` of {} is {}, found {}", member.name, fb.name(), member.ty, ty.name());
                self.error(arg.value.span, message);
                ok = false;
                continue;
            }
            inputs.push((id, value));
        }
        let _ = span;
        ok.then_some(CStmt::Fb { fb, base, en, inputs, outputs })
    }

    /// A call of a user function block instance: formal or non-formal inputs and in-outs (in declaration
    /// order), outputs with `=>`, EN and ENO.
    fn user_call(&mut self, u: usize, callee: &Ident, args: &[Arg], vars: &[VarInfo]) -> Option<CStmt> {
        let def_name = self.users[u].def.name.name.clone();
        let params = self.users[u].params.clone();
        let eno = self.users[u].eno;
        let positional_params: Vec<usize> = (0..params.len()).filter(|&i| params[i].1 != VarSection::Output).collect();
        let formal = args.iter().any(|a| a.name.is_some());
        let (mut en, mut inputs, mut inouts, mut outputs) = (None, Vec::new(), Vec::new(), Vec::new());
        let mut ok = true;
        let mut positional = 0;
        let list = || params.iter().map(|p| p.0.clone()).collect::<Vec<_>>().join(", ");
        for arg in args {
            if formal && arg.name.is_none() {
                self.error(arg.span, "a call mixes formal (`IN := x`) and non-formal arguments: name every argument");
                ok = false;
                continue;
            }
            let index = match &arg.name {
                Some(n) if n.key() == "EN" => {
                    en = Some(self.condition(&arg.value, vars, "EN"));
                    continue;
                }
                Some(n) if n.key() == "ENO" && arg.output => {
                    if let Some(target) = self.place(&arg.value, vars) {
                        outputs.push(FbOutput { member: eno, target, negated: arg.negated });
                    }
                    continue;
                }
                Some(n) => match params.iter().position(|p| p.0.eq_ignore_ascii_case(&n.name)) {
                    Some(i) => i,
                    None => {
                        let message =
                            format!("function block `{def_name}` has no parameter `{}` (it has {})", n.name, list());
                        self.error(n.span, message);
                        ok = false;
                        continue;
                    }
                },
                None => match positional_params.get(positional) {
                    Some(&i) => {
                        positional += 1;
                        i
                    }
                    None => {
                        let message =
                            format!("too many arguments: `{def_name}` takes {} inputs", positional_params.len());
                        self.error(arg.span, message);
                        ok = false;
                        continue;
                    }
                },
            };
            let (name, section, id) = params[index].clone();
            match (section, arg.output) {
                (VarSection::Output, true) => {
                    let Some(target) = self.place(&arg.value, vars) else {
                        ok = false;
                        continue;
                    };
                    if !assignable(Ty::of(&vars[target.index()].ty), Ty::of(&vars[id.index()].ty)) {
                        let message = format!(
                            "`{name}` is {} and cannot be written to `{}`, which is {}",
                            vars[id.index()].ty,
                            vars[target.index()].name,
                            vars[target.index()].ty
                        );
                        self.error(arg.value.span, message);
                        ok = false;
                        continue;
                    }
                    outputs.push(FbOutput { member: id, target, negated: arg.negated });
                }
                (VarSection::Output, false) => {
                    self.error(arg.span, format!("`{name}` is an output of `{def_name}`: write `{name} => variable`"));
                    ok = false;
                }
                (VarSection::InOut, false) => {
                    let Some(caller) = self.place(&arg.value, vars) else {
                        ok = false;
                        continue;
                    };
                    if vars[caller.index()].ty != vars[id.index()].ty {
                        let message = format!(
                            "in-out `{name}` of `{def_name}` is {}, and `{}` is {}",
                            vars[id.index()].ty,
                            vars[caller.index()].name,
                            vars[caller.index()].ty
                        );
                        self.error(arg.value.span, message);
                        ok = false;
                        continue;
                    }
                    inouts.push((id, caller));
                }
                (_, true) => {
                    self.error(arg.span, format!("`{name}` is an input of `{def_name}`: write `{name} := value`"));
                    ok = false;
                }
                (_, false) => {
                    let (mut value, mut ty) = self.expr(&arg.value, vars);
                    let target = Ty::of(&vars[id.index()].ty);
                    if target == Ty::Bool {
                        if let ExprKind::Int(v @ (0 | 1)) = arg.value.kind {
                            (value, ty) = (CExpr::Const(Value::Bool(v == 1)), Ty::Bool);
                        }
                    }
                    if !assignable(target, ty) {
                        let message =
                            format!("input `{name}` of `{def_name}` is {}, found {}", vars[id.index()].ty, ty.name());
                        self.error(arg.value.span, message);
                        ok = false;
                        continue;
                    }
                    inputs.push((id, value));
                }
            }
        }
        let _ = callee;
        let body = Arc::clone(&self.users[u].body);
        ok.then(|| CStmt::UserFb(Box::new(UserCall { body, en, inputs, inouts, outputs, eno })))
    }

    /// A standard function call in an expression.
    fn call(&mut self, e: &Expr, callee: &Ident, args: &[Arg], vars: &[VarInfo]) -> (CExpr, Ty) {
        let key = callee.key();
        if self.functions.contains_key(&key) {
            return self.function_call(&key, callee, args, vars);
        }
        if let Some(&u) = self.user_of.get(&key) {
            let message = format!(
                "`{}` is a `{}` instance: call it as a statement in an action (`{}(…);`) and read its outputs here",
                callee.name, self.users[u].def.name.name, callee.name
            );
            self.error(callee.span, message);
            return (FALSE, Ty::Err);
        }
        if let Some((fb, _)) = self.instances.get(&key) {
            let message = format!(
                "`{}` is a {} instance: call it as a statement in an action (`{}(…);`) and read its outputs here (`{}.Q`)",
                callee.name,
                fb.name(),
                callee.name,
                callee.name
            );
            self.error(callee.span, message);
            return (FALSE, Ty::Err);
        }
        // ADD, SUB, …, GT, EQ, …, AND, OR, XOR: the operators, folded over the arguments.
        let op = match key.as_str() {
            "AND" => Some((BinOp::And, true)),
            "OR" => Some((BinOp::Or, true)),
            "XOR" => Some((BinOp::Xor, true)),
            "ADD" => Some((BinOp::Add, true)),
            "MUL" => Some((BinOp::Mul, true)),
            "SUB" => Some((BinOp::Sub, false)),
            "DIV" => Some((BinOp::Div, false)),
            "MOD" => Some((BinOp::Mod, false)),
            "GT" => Some((BinOp::Gt, true)),
            "GE" => Some((BinOp::Ge, true)),
            "EQ" => Some((BinOp::Eq, true)),
            "LE" => Some((BinOp::Le, true)),
            "LT" => Some((BinOp::Lt, true)),
            "NE" => Some((BinOp::Ne, false)),
            _ => None,
        };
        if let Some((op, extensible)) = op {
            let Some(values) = self.positional(callee, args, &["IN1", "IN2"], extensible) else {
                return (FALSE, Ty::Err);
            };
            let comparison = matches!(op, BinOp::Gt | BinOp::Ge | BinOp::Eq | BinOp::Le | BinOp::Lt | BinOp::Ne);
            let mut folded = if comparison {
                // GT(a, b, c) is a > b AND b > c.
                let pairs: Vec<Expr> = values
                    .windows(2)
                    .map(|w| Expr {
                        kind: ExprKind::Binary(op, Box::new(w[0].clone()), Box::new(w[1].clone())),
                        span: e.span,
                    })
                    .collect();
                Expr::balanced(BinOp::And, pairs)
            } else if op.associative() {
                Expr::balanced(op, values)
            } else if values.len() > NESTING_DEPTH_MAX {
                // ADD(a, b, c) is (a + b) + c, in that order (REAL sums and the widths of mixed integers depend
                // on it): its arguments nest as deep as they are many.
                let message = format!(
                    "{key} with {} arguments nests them {} levels deep, more than {NESTING_DEPTH_MAX}: add them in \
                     parts, each with a name of its own",
                    values.len(),
                    values.len() - 1
                );
                self.error(callee.span, message);
                return (FALSE, Ty::Err);
            } else {
                let mut it = values.into_iter();
                let first = it.next().expect("two arguments at least");
                it.fold(first, |acc, v| Expr { kind: ExprKind::Binary(op, Box::new(acc), Box::new(v)), span: e.span })
            };
            folded.span = e.span;
            return self.expr(&folded, vars);
        }
        // ADD_TIME, SUB_DT_DT, MUL_TIME and their kin: the operators on the types their names give.
        if let Some((op, wanted)) = time_function(&key) {
            let Some(values) = self.positional(callee, args, &["IN1", "IN2"], false) else {
                return (FALSE, Ty::Err);
            };
            let operands = [self.expr(&values[0], vars), self.expr(&values[1], vars)];
            for (i, ((_, t), want)) in operands.iter().zip(wanted).enumerate() {
                let fits = match want {
                    Some(w) => *t == w,
                    None => t.is_num(),
                };
                if !fits && *t != Ty::Err {
                    let name = want.map_or_else(|| "a number".to_string(), |w| w.name());
                    let message = format!("argument {} of {key} must be {name}, found {}", i + 1, t.name());
                    self.error(values[i].span, message);
                    return (FALSE, Ty::Err);
                }
            }
            let [a, b] = operands;
            return self.binary_node(op, a, b, e.span);
        }
        let Some((func, params)) = Func::from_name(&key) else {
            let message = if StdFb::from_name(&key).is_some() {
                format!("`{0}` is a function block type: declare an instance (`t1 : {0};`), call it in an action and read `t1.Q`", key)
            } else {
                format!("unknown function `{}`", callee.name)
            };
            self.error(callee.span, message);
            return (FALSE, Ty::Err);
        };
        let Some(values) = self.positional(callee, args, params, func.extensible()) else {
            return (FALSE, Ty::Err);
        };
        let mut cargs = Vec::with_capacity(values.len());
        let mut tys = Vec::with_capacity(values.len());
        for (i, v) in values.iter().enumerate() {
            let (c, t) = self.expr(v, vars);
            // SEL's selector is a BOOL, which may be written 0 or 1.
            let (c, t) = if i == 0 && func == Func::Sel { bool_literal((c, t)) } else { (c, t) };
            if t == Ty::Err {
                return (FALSE, Ty::Err);
            }
            cargs.push(c);
            tys.push(t);
        }
        let bad = |c: &mut Self, i: usize, want: &str| {
            let message = format!("argument {} of {} must be {want}, found {}", i + 1, key, tys[i].name());
            c.error(values[i].span, message);
            (FALSE, Ty::Err)
        };
        let real_of = |t: Ty| match t {
            Ty::Real { long } => Ty::Real { long },
            _ => Ty::Real { long: false },
        };
        // The common type of some arguments: all numbers, or all of one other type.
        let common = |c: &mut Self, from: usize| -> Option<Ty> {
            let mut acc = tys[from];
            for (i, &t) in tys.iter().enumerate().skip(from + 1) {
                acc = if acc.is_num() && t.is_num() {
                    join(acc, t)
                } else if acc == t {
                    t
                } else {
                    let message = format!("arguments of {} must have one type: {} and {}", key, acc.name(), t.name());
                    c.error(values[i].span, message);
                    return None;
                };
            }
            Some(acc)
        };
        let ty = match &func {
            Func::Abs if tys[0].is_num() => tys[0],
            Func::Abs => return bad(self, 0, "a number"),
            Func::Real(_) if tys[0].is_num() => real_of(tys[0]),
            Func::Real(_) => return bad(self, 0, "a number"),
            Func::Trunc(k) if tys[0].is_num() => Ty::Int(*k),
            Func::Trunc(_) => return bad(self, 0, "a REAL"),
            Func::Atan2 if !tys[0].is_num() => return bad(self, 0, "a number"),
            Func::Atan2 if !tys[1].is_num() => return bad(self, 1, "a number"),
            Func::Atan2 => real_of(join(tys[0], tys[1])),
            Func::BcdToInt(_) | Func::IntToBcd(_) | Func::IsValidBcd | Func::SwapBytes if !tys[0].is_int() => {
                return bad(self, 0, "an integer or a bit string")
            }
            Func::BcdToInt(k) | Func::IntToBcd(k) => Ty::Int(*k),
            Func::IsValidBcd => Ty::Bool,
            Func::IsValid if !tys[0].is_num() => return bad(self, 0, "a REAL"),
            Func::IsValid => Ty::Bool,
            Func::SwapBytes => match tys[0] {
                Ty::IntLit => Ty::Int(IntKind::Dword),
                t => t,
            },
            Func::Date(f) => {
                let (wanted, result): (&[Ty], Ty) = match f {
                    DateFn::ConcatDateTod => (&[Ty::Date, Ty::Tod], Ty::Dt),
                    DateFn::DayOfWeek => (&[Ty::Date], Ty::Int(IntKind::Usint)),
                    DateFn::ConcatDate => (&[], Ty::Date),
                    DateFn::ConcatTod => (&[], Ty::Tod),
                    DateFn::ConcatDt | DateFn::Part(_) => (&[], Ty::Dt),
                };
                for (i, t) in tys.iter().enumerate() {
                    match wanted.get(i) {
                        Some(w) if t != w => return bad(self, i, w.name().as_str()),
                        None if !t.is_int() => return bad(self, i, "an integer"),
                        _ => {}
                    }
                }
                result
            }
            Func::Expt if !tys[0].is_num() => return bad(self, 0, "a number"),
            Func::Expt if !tys[1].is_num() => return bad(self, 1, "a number"),
            Func::Expt => join(tys[0], tys[1]),
            Func::Move => tys[0],
            Func::Sel if tys[0] != Ty::Bool => return bad(self, 0, "BOOL"),
            Func::Sel => match common(self, 1) {
                Some(t) => t,
                None => return (FALSE, Ty::Err),
            },
            Func::Max | Func::Min | Func::Limit => match common(self, 0) {
                Some(t) => t,
                None => return (FALSE, Ty::Err),
            },
            Func::Mux if !tys[0].is_int() => return bad(self, 0, "an integer"),
            Func::Mux => match common(self, 1) {
                Some(t) => t,
                None => return (FALSE, Ty::Err),
            },
            Func::Shl | Func::Shr | Func::Rol | Func::Ror if !tys[0].is_int() => {
                return bad(self, 0, "a bit string or an integer")
            }
            Func::Shl | Func::Shr | Func::Rol | Func::Ror if !tys[1].is_int() => return bad(self, 1, "an integer"),
            Func::Shl | Func::Shr | Func::Rol | Func::Ror => match tys[0] {
                Ty::IntLit => Ty::Int(IntKind::Dword),
                t => t,
            },
            Func::Text(f) => {
                // Which arguments are strings; the others are lengths or positions.
                let strings: &[usize] = match f {
                    TextFn::Len | TextFn::Left | TextFn::Right | TextFn::Mid | TextFn::Delete => &[0],
                    TextFn::Insert | TextFn::Replace | TextFn::Find => &[0, 1],
                    TextFn::Concat => &[],
                };
                for (i, t) in tys.iter().enumerate() {
                    let string = strings.contains(&i) || *f == TextFn::Concat;
                    if string && *t != Ty::Str {
                        return bad(self, i, "a STRING");
                    }
                    if !string && !t.is_int() {
                        return bad(self, i, "an integer");
                    }
                }
                match f {
                    TextFn::Len | TextFn::Find => Ty::Int(IntKind::Int),
                    _ => Ty::Str,
                }
            }
            Func::ToString(_) => unreachable!("from_name gives Convert"),
            Func::Convert(to) => {
                if let Some((from, _)) = key.split_once("_TO_") {
                    let from_ty = Type::from_name(from).map(|t| Ty::of(&t));
                    let fits = match from_ty {
                        Some(f) if f.is_int() => tys[0].is_int(),
                        Some(f @ Ty::Real { .. }) => tys[0].is_num() || tys[0] == f,
                        Some(f) => tys[0] == f,
                        None => true,
                    };
                    if !fits {
                        return bad(self, 0, from);
                    }
                }
                // To a STRING, the text depends on the argument's type (a DATE and a TIME are both held in ms).
                if let Type::Str { .. } = to {
                    if matches!(tys[0], Ty::Enum(_)) {
                        return bad(self, 0, "a number, a BOOL, a duration, a date or a time");
                    }
                    return (CExpr::call(Func::ToString(tys[0].repr()), cargs, Ty::Str.repr()), Ty::Str);
                }
                Ty::of(to)
            }
            Func::BitAnd | Func::BitOr | Func::BitXor | Func::BitNot => tys[0],
        };
        (CExpr::call(func, cargs, ty.repr()), ty)
    }

    /// A call's arguments in parameter order: non-formal as written, or formal matched to the parameter names
    /// (`IN1`, `IN2`, … beyond the declared ones for an extensible function).
    fn positional(&mut self, callee: &Ident, args: &[Arg], params: &[&str], extensible: bool) -> Option<Vec<Expr>> {
        let formal = args.iter().any(|a| a.name.is_some());
        let name = callee.name.to_ascii_uppercase();
        if args.iter().any(|a| a.output) {
            let arg = args.iter().find(|a| a.output).expect("an output argument");
            self.error(arg.span, format!("{name} is a function: it has no outputs to write with `=>`"));
            return None;
        }
        let values: Vec<Expr> = if formal {
            let mut slots: Vec<Option<Expr>> = vec![None; params.len().max(args.len())];
            for arg in args {
                let Some(n) = &arg.name else {
                    self.error(
                        arg.span,
                        "a call mixes formal (`IN := x`) and non-formal arguments: name every argument",
                    );
                    return None;
                };
                let key = n.key();
                let index = params.iter().position(|p| *p == key).or_else(|| {
                    // IN3, IN4, … of an extensible function; MUX numbers its inputs from IN0.
                    let number: usize = key.strip_prefix("IN")?.parse().ok()?;
                    let first_in = params.iter().position(|p| p.starts_with("IN"))?;
                    let offset = if params[first_in] == "IN0" { number } else { number.checked_sub(1)? };
                    extensible.then_some(first_in + offset)
                });
                let Some(index) = index.filter(|&i| i < slots.len()) else {
                    self.error(n.span, format!("{name} has no parameter `{}`", n.name));
                    return None;
                };
                slots[index] = Some(arg.value.clone());
            }
            while slots.len() > params.len() && slots.last().is_some_and(|s| s.is_none()) {
                slots.pop();
            }
            if let Some(missing) = slots.iter().position(|s| s.is_none()) {
                let p = params.get(missing).map_or_else(|| format!("IN{missing}"), |p| p.to_string());
                self.error(callee.span, format!("{name} needs its parameter `{p}`"));
                return None;
            }
            slots.into_iter().map(|s| s.expect("every slot is filled")).collect()
        } else {
            args.iter().map(|a| a.value.clone()).collect()
        };
        let ok = if extensible { values.len() >= params.len() } else { values.len() == params.len() };
        if !ok {
            let n = params.len();
            let message = if extensible {
                format!("{name} takes {n} arguments or more, found {}", values.len())
            } else {
                format!("{name} takes {n} argument{}, found {}", if n == 1 { "" } else { "s" }, values.len())
            };
            self.error(callee.span, message);
            return None;
        }
        Some(values)
    }

    fn expr(&mut self, e: &Expr, vars: &[VarInfo]) -> (CExpr, Ty) {
        if let Some(plain) = self.unqualified(e) {
            return self.expr(&plain, vars);
        }
        match &e.kind {
            ExprKind::Bool(b) => (CExpr::Const(Value::Bool(*b)), Ty::Bool),
            ExprKind::Int(v) => (CExpr::Const(Value::Int(*v)), Ty::IntLit),
            ExprKind::Real(v) => (CExpr::Const(Value::Real(*v)), Ty::Real { long: false }),
            ExprKind::Time(v) => (CExpr::Const(Value::Time(*v)), Ty::Time),
            ExprKind::Date(v) => (CExpr::Const(Value::Time(*v)), Ty::Date),
            ExprKind::Tod(v) => (CExpr::Const(Value::Time(*v)), Ty::Tod),
            ExprKind::Dt(v) => (CExpr::Const(Value::Time(*v)), Ty::Dt),
            ExprKind::Str(text) => (CExpr::Const(Value::string(text.as_str())), Ty::Str),
            ExprKind::Name(name) => self.name(name, vars),
            ExprKind::Field(base, field) => self.field(base, field, vars),
            ExprKind::Call(callee, args) => self.call(e, callee, args, vars),
            ExprKind::Index(name, indices) => self.element(name, indices, vars).unwrap_or((FALSE, Ty::Err)),
            ExprKind::IndexField(name, indices, field) => {
                self.element_field(name, indices, field, vars).unwrap_or((FALSE, Ty::Err))
            }
            ExprKind::EnumValue(ty, value) => match self.enum_value(Some(ty), value) {
                Some(found) => found,
                None => {
                    self.error(value.span, format!("`{}` is not a value of enumeration `{}`", value.name, ty.name));
                    (FALSE, Ty::Err)
                }
            },
            ExprKind::Unary(op, a) => {
                let (ca, ta) = self.expr(a, vars);
                match (op, ta) {
                    (_, Ty::Err) => (FALSE, Ty::Err),
                    (UnOp::Not, Ty::Bool) => (CExpr::Not(Box::new(ca)), Ty::Bool),
                    (UnOp::Not, t) if t.is_int() => (CExpr::call(Func::BitNot, vec![ca], t.repr()), t),
                    (UnOp::Neg, t) if t.is_num() || t == Ty::Time => (CExpr::Neg(Box::new(ca), t.wrap()), t),
                    (UnOp::Not, t) => {
                        self.error(e.span, format!("NOT needs a BOOL operand, found {}", t.name()));
                        (FALSE, Ty::Err)
                    }
                    (UnOp::Neg, t) => {
                        self.error(e.span, format!("unary minus needs a number or a TIME, found {}", t.name()));
                        (FALSE, Ty::Err)
                    }
                }
            }
            // A chain of one associative operator, however the source grouped it, compiles to one balanced tree of
            // its operands in their order: `(a AND b) AND (c AND d)` and `a AND b AND c AND d` are the same program
            // (a round trip through another format may group them otherwise), and no chain is deeper than it must.
            ExprKind::Binary(op, _, _) if op.associative() => {
                let mut operands = Vec::new();
                let mut stack = vec![e];
                while let Some(x) = stack.pop() {
                    match &x.kind {
                        ExprKind::Binary(o, a, b) if o == op => {
                            stack.push(b);
                            stack.push(a);
                        }
                        _ => operands.push(x),
                    }
                }
                // Every operand is compiled, for its own errors, before any is given up on.
                let level: Vec<(CExpr, Ty)> = operands.into_iter().map(|x| self.expr(x, vars)).collect();
                if level.iter().any(|(_, t)| *t == Ty::Err) {
                    return (FALSE, Ty::Err);
                }
                let joined = crate::front::model::fold_balanced(level, |a, b| {
                    let node = self.binary_node(*op, a, b, e.span);
                    (node.1 != Ty::Err).then_some(node)
                });
                joined.unwrap_or((FALSE, Ty::Err))
            }
            ExprKind::Binary(op, a, b) => {
                let a = self.expr(a, vars);
                let b = self.expr(b, vars);
                self.binary_node(*op, a, b, e.span)
            }
        }
    }

    /// `a op b`, typed; an error (at `span`) when the operator does not apply to their types.
    fn binary_node(&mut self, op: BinOp, a: (CExpr, Ty), b: (CExpr, Ty), span: Span) -> (CExpr, Ty) {
        // A BOOL beside a literal 0 or 1 (`x = 1`, `a AND 0`): the literal is a BOOL.
        let (a, b) = match (a.1, b.1) {
            (Ty::Bool, Ty::IntLit) => (a, bool_literal(b)),
            (Ty::IntLit, Ty::Bool) => (bool_literal(a), b),
            _ => (a, b),
        };
        let ((ca, ta), (cb, tb)) = (a, b);
        if ta == Ty::Err || tb == Ty::Err {
            return (FALSE, Ty::Err);
        }
        let Some(ty) = binary_type(op, ta, tb) else {
            let message = format!("cannot apply `{}` to {} and {}", op.symbol(), ta.name(), tb.name());
            self.error(span, message);
            return (FALSE, Ty::Err);
        };
        if matches!(op, BinOp::And | BinOp::Or | BinOp::Xor) && ty != Ty::Bool {
            let func = match op {
                BinOp::And => Func::BitAnd,
                BinOp::Or => Func::BitOr,
                _ => Func::BitXor,
            };
            return (CExpr::call(func, vec![ca, cb], ty.repr()), ty);
        }
        let (ca, cb) = (Box::new(ca), Box::new(cb));
        let cexpr = match op {
            BinOp::Or => CExpr::Logic(LogicOp::Or, ca, cb),
            BinOp::Xor => CExpr::Logic(LogicOp::Xor, ca, cb),
            BinOp::And => CExpr::Logic(LogicOp::And, ca, cb),
            BinOp::Eq => CExpr::Cmp(CmpOp::Eq, ca, cb),
            BinOp::Ne => CExpr::Cmp(CmpOp::Ne, ca, cb),
            BinOp::Lt => CExpr::Cmp(CmpOp::Lt, ca, cb),
            BinOp::Le => CExpr::Cmp(CmpOp::Le, ca, cb),
            BinOp::Gt => CExpr::Cmp(CmpOp::Gt, ca, cb),
            BinOp::Ge => CExpr::Cmp(CmpOp::Ge, ca, cb),
            BinOp::Add => CExpr::Arith { op: ArithOp::Add, wrap: ty.wrap(), lhs: ca, rhs: cb },
            BinOp::Sub => CExpr::Arith { op: ArithOp::Sub, wrap: ty.wrap(), lhs: ca, rhs: cb },
            BinOp::Mul => CExpr::Arith { op: ArithOp::Mul, wrap: ty.wrap(), lhs: ca, rhs: cb },
            BinOp::Div => CExpr::Arith { op: ArithOp::Div, wrap: ty.wrap(), lhs: ca, rhs: cb },
            BinOp::Mod => CExpr::Arith { op: ArithOp::Mod, wrap: ty.wrap(), lhs: ca, rhs: cb },
            BinOp::Pow => CExpr::Arith { op: ArithOp::Pow, wrap: ty.wrap(), lhs: ca, rhs: cb },
        };
        (cexpr, ty)
    }

    /// Reports a use of a variable whose type Baton does not execute; true when it did.
    fn reject_unsupported(&mut self, span: Span, var: &VarInfo) -> bool {
        let Type::Unsupported(ty) = &var.ty else { return false };
        self.error(span, format!("variable `{}` has type {ty}, which Baton does not execute", var.name));
        true
    }

    fn name(&mut self, name: &Ident, vars: &[VarInfo]) -> (CExpr, Ty) {
        if let Some(&id) = self.vars.get(&name.key()) {
            // Constant contexts (initial values, CASE labels) see no variables.
            let Some(var) = vars.get(id.index()) else {
                self.error(name.span, format!("`{}` is a variable, and a constant is needed here", name.name));
                return (FALSE, Ty::Err);
            };
            if self.reject_unsupported(name.span, var) {
                return (FALSE, Ty::Err);
            }
            return (CExpr::Var(id), Ty::of(&var.ty));
        }
        if let Some((ty_name, names)) = self.structs.get(&name.key()) {
            let first = names.first().cloned().unwrap_or_default();
            let message = format!(
                "`{}` is a {ty_name} structure: use one of its fields, such as `{}.{first}`",
                name.name, name.name
            );
            self.error(name.span, message);
            return (FALSE, Ty::Err);
        }
        if self.arrays.contains_key(&name.key()) {
            self.error(name.span, format!("`{}` is an array: index it, such as `{}[…]`", name.name, name.name));
            return (FALSE, Ty::Err);
        }
        if let Some(found) = self.enum_value(None, name) {
            return found;
        }
        let message = if self.steps.contains_key(&name.key()) {
            format!("`{}` is a step: write `{}.X` for its active flag", name.name, name.name)
        } else if let Some((fb, _)) = self.instances.get(&name.key()) {
            format!("`{}` is a {} instance: read one of its outputs, such as `{}.Q`", name.name, fb.name(), name.name)
        } else if let Some(&u) = self.user_of.get(&name.key()) {
            format!(
                "`{}` is a `{}` instance: read one of its outputs (`{}.NAME`)",
                name.name, self.users[u].def.name.name, name.name
            )
        } else if self.chart.broken.var(&name.key()) {
            return (FALSE, Ty::Err);
        } else {
            format!("undeclared variable `{}`", name.name)
        };
        self.error(name.span, message);
        (FALSE, Ty::Err)
    }

    /// Why a path naming no structure (`ln.c` in `ln.c.x`, `pts[4]` in `pts[4].x`) is wrong, when it starts
    /// with one: the field its structure lacks, or the index its array's bounds exclude.
    fn bad_path(&self, base: &Ident) -> Option<String> {
        if let Some((array, rest)) = base.name.split_once('[') {
            let info = self.arrays.get(&array.to_ascii_uppercase())?;
            let indices = rest.strip_suffix(']')?.split(',').map(|i| i.trim().parse::<i64>().ok());
            for (i, &(low, high)) in indices.zip(&info.dims) {
                let i = i?;
                if i < low || i > high {
                    return Some(format!("index {i} is outside `{array}`'s bounds {low}..{high}"));
                }
            }
            return None;
        }
        let (prefix, last) = base.name.rsplit_once('.')?;
        self.structs.contains_key(&prefix.to_ascii_uppercase()).then(|| {
            let prefix = Ident { name: prefix.to_string(), span: base.span };
            self.missing_field(&prefix, &Ident { name: last.to_string(), span: base.span })
        })
    }

    /// Why `base.field` of a structure `base` is no variable: a structure or an array itself, or no field.
    fn missing_field(&self, base: &Ident, field: &Ident) -> String {
        let path = format!("{}.{}", base.key(), field.key());
        let whole = format!("{}.{}", base.name, field.name);
        if let Some((inner, fields)) = self.structs.get(&path) {
            let first = fields.first().cloned().unwrap_or_default();
            return format!("`{whole}` is a {inner} structure: use one of its fields, such as `{whole}.{first}`");
        }
        if self.arrays.contains_key(&path) {
            return format!("`{whole}` is an array: index it, such as `{whole}[…]`");
        }
        let (ty_name, names) = self.structs.get(&base.key()).cloned().unwrap_or_default();
        format!("`{}` (a {ty_name}) has no field `{}`: it has {}", base.name, field.name, names.join(", "))
    }

    fn field(&mut self, base: &Ident, field: &Ident, vars: &[VarInfo]) -> (CExpr, Ty) {
        let step_field = matches!(field.key().as_str(), "X" | "T")
            && (self.steps.contains_key(&base.key()) || self.nested_steps.contains_key(&base.key()));
        if self.structs.contains_key(&base.key()) && !step_field {
            return match self.vars.get(&format!("{}.{}", base.key(), field.key())) {
                Some(&id) => match vars.get(id.index()) {
                    Some(v) => (CExpr::Var(id), Ty::of(&v.ty)),
                    None => {
                        self.error(base.span, format!("`{}` is a variable, and a constant is needed here", base.name));
                        (FALSE, Ty::Err)
                    }
                },
                None => {
                    let message = self.missing_field(base, field);
                    self.error(field.span, message);
                    (FALSE, Ty::Err)
                }
            };
        }
        if let Some(&u) = self.user_of.get(&base.key()).filter(|_| !step_field) {
            return match self.vars.get(&format!("{}.{}", base.key(), field.key())) {
                Some(&id) => match vars.get(id.index()) {
                    Some(v) => (CExpr::Var(id), Ty::of(&v.ty)),
                    None => {
                        self.error(base.span, format!("`{}` is an instance, and a constant is needed here", base.name));
                        (FALSE, Ty::Err)
                    }
                },
                None => {
                    let def = self.users[u].def;
                    let names: Vec<String> = self.users[u].params.iter().map(|p| p.0.clone()).collect();
                    let message = format!(
                        "function block `{}` has no parameter `{}`: `{}` has {} and ENO",
                        def.name.name,
                        field.name,
                        base.name,
                        names.join(", ")
                    );
                    self.error(field.span, message);
                    (FALSE, Ty::Err)
                }
            };
        }
        if let Some(&(fb, inst)) = self.instances.get(&base.key()).filter(|_| !step_field) {
            return match self.member(fb, inst, base, field) {
                Some(id) => {
                    let ty = Ty::of(&fb.members()[(id.0 - inst.0) as usize].ty);
                    (CExpr::Var(id), ty)
                }
                None => (FALSE, Ty::Err),
            };
        }
        if let (Some(&v), false) = (self.nested_steps.get(&base.key()), self.steps.contains_key(&base.key())) {
            match field.key().as_str() {
                "X" => return (CExpr::Var(v[0]), Ty::Bool),
                "T" => return (CExpr::NestedT(Box::new(v)), Ty::Time),
                _ => {}
            }
        }
        if let (Some(&(_, q, _)), "Q") = (self.controlled.get(&base.key()), field.key().as_str()) {
            return (CExpr::Var(q), Ty::Bool);
        }
        if let Some(message) = self.bad_path(base) {
            self.error(base.span, message);
            return (FALSE, Ty::Err);
        }
        match field.key().as_str() {
            "X" | "T" => match self.steps.get(&base.key()) {
                Some(&id) if field.key() == "X" => (CExpr::StepX(id), Ty::Bool),
                Some(&id) => (CExpr::StepT(id), Ty::Time),
                None => {
                    if !self.chart.broken.step(&base.key()) {
                        self.error(base.span, format!("unknown step `{}`", base.name));
                    }
                    (FALSE, Ty::Err)
                }
            },
            "Q" => match self.actions.get(&base.key()) {
                Some(&id) => (CExpr::ActionQ(id), Ty::Bool),
                None => {
                    if !self.chart.broken.action(&base.key()) {
                        self.error(base.span, format!("unknown action `{}`", base.name));
                    }
                    (FALSE, Ty::Err)
                }
            },
            _ if !self.known_name(base) && !self.chart.broken.var(&base.key()) => {
                let message = self.foreign_name(base, field);
                self.error(base.span.to(field.span), message);
                (FALSE, Ty::Err)
            }
            _ => {
                let message = format!(
                    "unknown field `.{}`: a step has `.X` and `.T`, an action has `.Q`, a function block instance its outputs",
                    field.name
                );
                self.error(field.span, message);
                (FALSE, Ty::Err)
            }
        }
    }

    /// Whether `base` (before its last `.`) is something of this scope: a variable, an instance, a step, an
    /// action, a structure or an array.
    fn known_name(&self, base: &Ident) -> bool {
        let key = base.key();
        let root = key.split(['.', '[']).next().unwrap_or(&key).to_string();
        [&key, &root].iter().any(|k| {
            self.vars.contains_key(*k)
                || self.instances.contains_key(*k)
                || self.user_of.contains_key(*k)
                || self.steps.contains_key(*k)
                || self.actions.contains_key(*k)
                || self.structs.contains_key(*k)
                || self.arrays.contains_key(*k)
        }) || self.vars.keys().any(|v| v.starts_with(&format!("{root}.")))
    }

    /// `GVL.x`, `GVL.s.f`, `GVL.a[i]`: an expression naming a variable by one of the project's global variable
    /// lists, as the same expression without the list's name (the list's variables are the chart's VAR_GLOBAL).
    /// `None` for any other expression, and where the scope declares a variable of the list's name.
    fn unqualified(&self, e: &Expr) -> Option<Expr> {
        if self.chart.global_lists.is_empty() {
            return None;
        }
        let kind = match &e.kind {
            ExprKind::Field(base, field) if self.in_global_list(&base.name, &field.name) => {
                ExprKind::Name(field.clone())
            }
            ExprKind::Field(base, field) => ExprKind::Field(self.unqualified_name(base)?, field.clone()),
            ExprKind::Name(name) => ExprKind::Name(self.unqualified_name(name)?),
            ExprKind::Index(name, indices) => ExprKind::Index(self.unqualified_name(name)?, indices.clone()),
            ExprKind::IndexField(name, indices, field) => {
                ExprKind::IndexField(self.unqualified_name(name)?, indices.clone(), field.clone())
            }
            _ => return None,
        };
        Some(Expr { kind, span: e.span })
    }

    /// `GVL.x.y` as `x.y` where `x` is a variable of global list `GVL`.
    fn unqualified_name(&self, name: &Ident) -> Option<Ident> {
        let (list, rest) = name.name.split_once('.')?;
        let root = rest.split(['.', '[']).next()?;
        self.in_global_list(list, root).then(|| Ident { name: rest.to_string(), span: name.span })
    }

    fn in_global_list(&self, list: &str, var: &str) -> bool {
        !self.declared_name(&list.to_ascii_uppercase())
            && self.declared_name(&var.to_ascii_uppercase())
            && self.chart.global_lists.iter().any(|l| {
                l.name.name.eq_ignore_ascii_case(list) && l.vars.iter().any(|v| v.name.eq_ignore_ascii_case(var))
            })
    }

    /// `GVL.x`, `Main.x`: a name qualified by something this chart does not have — a global variable list, or
    /// another program — which Baton does not read: said as such.
    fn foreign_name(&self, base: &Ident, field: &Ident) -> String {
        if let Some(list) = self.chart.global_lists.iter().find(|l| l.name.key() == base.key()) {
            let names: Vec<&str> = list.vars.iter().map(|v| v.name.as_str()).collect();
            return format!(
                "global variable list `{}` has no variable `{}` (it has {})",
                list.name.name,
                field.name,
                if names.is_empty() { "none".to_string() } else { names.join(", ") }
            );
        }
        format!(
            "`{}.{}` qualifies `{}` by `{}`, which chart `{}` does not have: Baton reads a global variable list \
             (`GVL.x`) from the PLCopen project that declares it, and no other program's variables (`Main.x`); \
             declare `{}` in chart `{}` (as VAR_GLOBAL, VAR or an input)",
            base.name, field.name, field.name, base.name, self.chart.name.name, field.name, self.chart.name.name
        )
    }

    /// The state of every nested chart (an action written in SFC) as variables: `started`, each step's `X`,
    /// `since` and `last`, and the `Q` and `stored` of each action it controls (`X` and `Q` can be watched, the rest
    /// is hidden). A nested step's name is one of the POU's, as CODESYS has it: two steps of one name are an error
    /// wherever they are.
    fn declare_nested(&mut self, vars: &mut Vec<VarInfo>) {
        let chart = self.chart;
        let add = |vars: &mut Vec<VarInfo>, name: String, ty: Type, hidden: bool| {
            let id = VarId(vars.len() as u32);
            let init = ty.default_value();
            vars.push(VarInfo { name, ty, init, constant: false, section: VarSection::Local, hidden });
            id
        };
        for action in &chart.actions {
            let Some(sfc) = &action.sfc else { continue };
            let parent = action.name.key();
            if self.started.contains_key(&parent) {
                continue; // an action declared twice, reported with the actions
            }
            let started = add(vars, format!("{}.started", action.name.name), Type::Bool, true);
            self.started.insert(parent.clone(), started);
            for step in &sfc.steps {
                let key = step.name.key();
                if self.nested_steps.contains_key(&key) || chart.steps.iter().any(|s| s.name.key() == key) {
                    self.error(step.name.span, format!("step `{}` is declared twice", step.name.name));
                    continue;
                }
                let base = format!("{}.{}", action.name.name, step.name.name);
                let x = add(vars, format!("{base}.X"), Type::Bool, false);
                let since = add(vars, format!("{base}.since"), Type::Time, true);
                let last = add(vars, format!("{base}.last"), Type::Time, true);
                self.nested_steps.insert(key, [x, since, last]);
            }
            for a in sfc.steps.iter().flat_map(|s| &s.associations) {
                let key = a.action.key();
                if key == parent {
                    continue; // reported when the chart is compiled
                }
                match self.controlled.get(&key) {
                    Some((other, _, _)) if *other != parent => {
                        let message = format!(
                            "action `{}` is controlled by the chart of action `{other}` already: an action has one chart",
                            a.action.name
                        );
                        self.error(a.action.span, message);
                    }
                    Some(_) => {}
                    None => {
                        let base = format!("{}.{}", action.name.name, a.action.name);
                        let q = add(vars, format!("{base}.Q"), Type::Bool, false);
                        let stored = add(vars, format!("{base}.stored"), Type::Bool, true);
                        self.controlled.insert(key, (parent.clone(), q, stored));
                    }
                }
            }
        }
    }

    /// Compiles every nested chart into its action's body (`CStmt::Chart`), those it controls first, so that a
    /// chart's controlled actions carry their own compiled bodies; a chart that controls itself, directly or
    /// through others, is an error.
    fn nested_charts(
        &mut self,
        sources: &[&'a Action],
        parent_steps: &[&'a Step],
        vars: &[VarInfo],
        actions: &mut Vec<ActionInfo>,
    ) {
        for step in parent_steps {
            for a in &step.associations {
                if let Some((owner, _, _)) = self.controlled.get(&a.action.key()) {
                    let message = format!(
                        "action `{}` is controlled by the chart of action `{owner}`, and so cannot be associated with \
                         step `{}` too: an action has one chart",
                        a.action.name, step.name.name
                    );
                    self.error(a.action.span, message);
                }
            }
        }
        // Charts in an order where each comes after those it controls (Kahn's, linear in the charts and their
        // associations), so that a chart's controlled actions carry their compiled bodies; each chart is as deep
        // as the deepest it controls plus one, bounded like any nesting.
        let charts: Vec<(usize, &'a Action)> =
            sources.iter().enumerate().filter(|(_, a)| a.sfc.is_some()).map(|(i, a)| (i, *a)).collect();
        let index: HashMap<String, usize> = charts.iter().enumerate().map(|(k, (_, a))| (a.name.key(), k)).collect();
        let mut children: Vec<Vec<usize>> = vec![Vec::new(); charts.len()];
        let mut parents: Vec<Vec<usize>> = vec![Vec::new(); charts.len()];
        for (k, (_, a)) in charts.iter().enumerate() {
            let sfc = a.sfc.as_ref().expect("a nested chart");
            for assoc in sfc.steps.iter().flat_map(|s| &s.associations) {
                if let Some(&c) = index.get(&assoc.action.key()).filter(|&&c| c != k) {
                    if !children[k].contains(&c) {
                        children[k].push(c);
                        parents[c].push(k);
                    }
                }
            }
        }
        let mut waiting: Vec<usize> = children.iter().map(Vec::len).collect();
        let mut ready: std::collections::VecDeque<usize> = (0..charts.len()).filter(|&k| waiting[k] == 0).collect();
        let mut depth = vec![0usize; charts.len()];
        let mut done = vec![false; charts.len()];
        while let Some(k) = ready.pop_front() {
            done[k] = true;
            let (id, action) = charts[k];
            depth[k] = 1 + children[k].iter().map(|&c| depth[c]).max().unwrap_or(0);
            if depth[k] > NESTING_DEPTH_MAX {
                // Said once, of the chart where the nesting goes past the limit, not of every chart around it.
                if depth[k] > NESTING_DEPTH_MAX + 1 {
                    continue_parents(&parents[k], &mut waiting, &mut ready);
                    continue;
                }
                let message = format!(
                    "the chart of action `{}` holds charts nested more than {NESTING_DEPTH_MAX} levels deep",
                    action.name.name
                );
                self.error(action.name.span, message);
            } else if let Some(chart) = self.nested_chart(action, vars, actions) {
                actions[id].body = vec![CStmt::Chart(Box::new(chart))];
            }
            continue_parents(&parents[k], &mut waiting, &mut ready);
        }
        fn continue_parents(parents: &[usize], waiting: &mut [usize], ready: &mut std::collections::VecDeque<usize>) {
            for &p in parents {
                waiting[p] -= 1;
                if waiting[p] == 0 {
                    ready.push_back(p);
                }
            }
        }
        // What is left controls itself, through the actions it names: each is still compiled, for its other
        // errors, but runs nothing.
        for (k, &(_, a)) in charts.iter().enumerate().filter(|(k, _)| !done[*k]) {
            let _ = k;
            let message = format!(
                "the chart of action `{}` controls itself, through the actions it names: nested charts must form a tree",
                a.name.name
            );
            self.error(a.name.span, message);
            self.nested_chart(a, vars, actions);
        }
    }

    fn nested_chart(
        &mut self,
        action: &Action,
        vars: &[VarInfo],
        actions: &mut Vec<ActionInfo>,
    ) -> Option<NestedChart> {
        let sfc = action.sfc.as_ref()?;
        let parent = action.name.key();
        let started = *self.started.get(&parent)?;
        let index: HashMap<String, usize> = sfc.steps.iter().enumerate().map(|(i, s)| (s.name.key(), i)).collect();
        let mut steps = Vec::with_capacity(sfc.steps.len());
        for s in &sfc.steps {
            let [x, since, last] = *self.nested_steps.get(&s.name.key())?;
            steps.push(NestedStep { initial: s.initial, x, since, last });
        }
        if !sfc.steps.iter().any(|s| s.initial) {
            let message = format!(
                "the chart of action `{}` has no initial step: declare one with `INITIAL_STEP`",
                action.name.name
            );
            self.error(action.name.span, message);
        }
        let list = |c: &mut Self, names: &[Ident]| -> Option<Vec<usize>> {
            let mut out = Vec::with_capacity(names.len());
            for n in names {
                match index.get(&n.key()) {
                    Some(&i) if !out.contains(&i) => out.push(i),
                    Some(_) => c.error(n.span, format!("step `{}` appears twice in this list", n.name)),
                    None => {
                        let message =
                            format!("unknown step `{}` in the chart of action `{}`", n.name, action.name.name);
                        c.error(n.span, message);
                        return None;
                    }
                }
            }
            Some(out)
        };
        let mut transitions = Vec::with_capacity(sfc.transitions.len());
        for (i, t) in sfc.transitions.iter().enumerate() {
            let (sources, targets) = (list(self, &t.from), list(self, &t.to));
            let outer = std::mem::take(&mut self.hoisted);
            let (condition, ty) = bool_literal(self.expr(&t.condition, vars));
            let hoisted = std::mem::replace(&mut self.hoisted, outer);
            if ty != Ty::Bool && ty != Ty::Err {
                self.error(t.condition.span, format!("a transition condition must be BOOL, found {}", ty.name()));
            }
            let calls = hoisted;
            let rank = match t.priority {
                Some((p, _)) => (0, p, i),
                None => (1, 0, i),
            };
            if let (Some(sources), Some(targets)) = (sources, targets) {
                transitions.push((rank, NestedTransition { sources, targets, calls, condition }));
            }
        }
        // Clearing order: explicit priorities first, lower number first, then declaration order.
        transitions.sort_by_key(|(rank, _)| *rank);
        let mut controlled: Vec<NestedAction> = Vec::new();
        let mut of_action: HashMap<ActionId, usize> = HashMap::new();
        for (si, s) in sfc.steps.iter().enumerate() {
            for a in &s.associations {
                if matches!(a.qualifier, Qualifier::SD | Qualifier::DS | Qualifier::SL) {
                    let message = format!(
                        "qualifier {:?} in the chart of action `{}` is not supported: a nested chart takes N, S, R, P, \
                         P0, P1, L and D",
                        a.qualifier, action.name.name
                    );
                    self.error(a.qualifier_span, message);
                    continue;
                }
                if let Some(ind) = a.indicators.first() {
                    let message =
                        format!("indicator variables in the chart of action `{}` are not supported", action.name.name);
                    self.error(ind.span, message);
                }
                if a.action.key() == parent {
                    self.error(
                        a.action.span,
                        format!("the chart of action `{}` cannot control that action itself", action.name.name),
                    );
                    continue;
                }
                let Some(id) = self.action_for(a, vars, actions) else { continue };
                let duration = self.duration(a, vars);
                let Some(&(_, q, stored)) = self.controlled.get(&a.action.key()) else { continue };
                let k = *of_action.entry(id).or_insert_with(|| {
                    let info = &actions[id.index()];
                    controlled.push(NestedAction {
                        q,
                        stored,
                        bool_var: info.bool_var,
                        body: Arc::new(info.body.clone()),
                        associations: Vec::new(),
                    });
                    controlled.len() - 1
                });
                controlled[k].associations.push((si, a.qualifier, duration));
            }
        }
        Some(NestedChart {
            started,
            steps,
            transitions: transitions.into_iter().map(|(_, t)| t).collect(),
            actions: controlled,
        })
    }

    fn warn_unused_actions(&mut self) {
        let chart = self.chart;
        let mut used: HashMap<String, ()> = self.controlled.keys().map(|k| (k.clone(), ())).collect();
        // Called as a subroutine by another action (`Reset();`): it runs there.
        used.extend(self.called_actions.keys().map(|k| (k.clone(), ())));
        for step in &chart.steps {
            for a in &step.associations {
                used.insert(a.action.key(), ());
            }
        }
        for action in &chart.actions {
            if !used.contains_key(&action.name.key()) {
                let message =
                    format!("action `{}` is never associated with a step, so it never runs", action.name.name);
                self.diags.push(Diagnostic::warning(action.name.span, message));
            }
        }
    }
}
