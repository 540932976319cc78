//! Resolves a chart's names, type-checks its expressions and builds the `Program` the engine runs.
//!
//! One `Compiler` walks a chart; its methods are grouped by what they lower, a file each: `declare`
//! (variables and block instances), `aggregate` (arrays and structures), `typing` (type names and `Ty`),
//! `binding` (the one binder of arguments to parameters), `functions` (function calls), `blocks` (block calls and
//! actions called), `sfc` (actions, associations, transitions), `statements`, `expressions`, and `nested` (charts
//! inside function blocks).
//!
//! What it does: name resolution (case-insensitive, reported as first declared), type checking of the Structured Text
//! subset, boolean actions, durations and indicators; builds a `Program`. A standard function block instance is
//! declared as a run of variables, one per member (`t1.IN`, `t1.Q`, …, hidden state last, `VarInfo::hidden`), with its
//! initial inputs from `t1 : TON := (PT := T#2s)`; calls resolve formal, non-formal and output (`=>`, `NOT Q =>`)
//! arguments and EN/ENO; ADD, GT and their kin fold into operators; the other standard functions become `CExpr::Call`.
//! An instance of a user function block (`FbDef`, which the parsers keep in `Parsed::library` with their syntax errors
//! until a chart instantiates one) is declared recursively as variables named by path (`m.settle.timer.Q`; VAR members
//! hidden), and its body is compiled once per instance in the instance's own scope (`compile_user_bodies`, nested
//! instances first); a call is a `CStmt::UserFb` holding that body. A user function (an `FbDef` with `returns`) has one
//! frame of hidden VAR_TEMP variables shared by its calls (scratch: the layout lets several places write it) and one
//! body, compiled at its first call; a call in an expression is hoisted before its statement (`hoisted`: into a loop's
//! `pre` for WHILE/UNTIL conditions, into the transition's calls for a condition) and its result copied to a variable
//! of its own (`temps`), which the expression reads. `instance.Action();` runs a user block's action in the instance's
//! scope (`instance_action_call`), `Action();` the POU's own action where it is called (`own_action_call`; a variable
//! of that name shadows it), each body compiled once and guarded against calling itself; `GVL.x` is read as `x` where
//! `GVL` is one of the chart's global lists (`unqualified`), and `Main.x` is refused by name (`foreign_name`). A
//! literal 0 or 1 is a BOOL wherever a BOOL is wanted (`bool_literal`). The operator-named functions fold into
//! operators (AND, OR, XOR balanced; ADD, SUB, … left to right, at most `NESTING_DEPTH_MAX` arguments); ADD_TIME and
//! its kin are the operators on the types their names give (`time_function`); SPLIT_DATE and its kin are statements
//! writing their outputs (`split_call`). What the standard's tables hold and what Baton does with each is
//! `docs/book/src/standard-library.md`, which `tests/tests/standard_library.rs` checks against the compiler.
//!
//! Depth: every recursive walk over what a user wrote is bounded by `NESTING_DEPTH_MAX` — parentheses, operator chains,
//! arguments, indices, statements, macro steps, wired logic, function blocks and functions inside one another, nested
//! charts — and `program::exec_depth` measures the composed depth of what a body runs (a call runs its callee's body)
//! so that a chart `baton check` accepts runs within `CHART_STACK_BYTES` on every thread that compiles or runs a chart
//! (the binaries' main threads and runtimes, `baton test`'s workers).
#![allow(
    clippy::disallowed_types,
    reason = "name tables, looked up only: what compile emits follows the source's order"
)]

mod aggregate;
mod binding;
mod blocks;
mod declare;
mod expressions;
mod functions;
mod nested;
mod nested_names;
mod sfc;
mod statements;
mod typing;

use std::collections::HashMap;
use std::sync::Arc;

use crate::exec::program::{ActionId, CExpr, CStmt, Program, StepId, StepInfo, StepParts, VarId, VarInfo};
use crate::front::diag::{Diagnostic, Span};
use crate::front::model::{Chart, FbDef, Ident, Sfc, TypeDef, VarDecl, VarSection};
use crate::limits::NESTING_DEPTH_MAX;
use crate::types::library::StdFb;
use crate::types::{Type, Value};

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
        nested: nested_names::Nested::default(),
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
    /// A user instance's nested charts.
    nested: nested_names::Nested,
}

/// The chart's names, set aside while a POU's body is compiled against names of its own
/// (`Compiler::set_names_aside`).
struct ChartNames {
    vars: HashMap<String, VarId>,
    instances: HashMap<String, (StdFb, VarId)>,
    user_of: HashMap<String, usize>,
    steps: HashMap<String, StepId>,
    actions: HashMap<String, ActionId>,
}

/// A POU's own names as its body left them (`Compiler::restore_names`).
struct OwnNames {
    vars: HashMap<String, VarId>,
    instances: HashMap<String, (StdFb, VarId)>,
    user_of: HashMap<String, usize>,
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
    /// The nested charts (actions written in SFC) of the POU being compiled: the chart's, or a user instance's.
    nested: nested_names::Nested,
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
    /// Sets the chart's names aside for a POU's body (a function's, a block's): `vars` are the POU's variables,
    /// and it sees no instance, step or action of the chart's (a block's own instances are set after).
    fn set_names_aside(&mut self, vars: HashMap<String, VarId>) -> ChartNames {
        ChartNames {
            vars: std::mem::replace(&mut self.vars, vars),
            instances: std::mem::take(&mut self.instances),
            user_of: std::mem::take(&mut self.user_of),
            steps: std::mem::take(&mut self.steps),
            actions: std::mem::take(&mut self.actions),
        }
    }

    /// Puts the chart's names back after a POU's body; returns the POU's own, as its body left them.
    fn restore_names(&mut self, chart: ChartNames) -> OwnNames {
        self.steps = chart.steps;
        self.actions = chart.actions;
        OwnNames {
            vars: std::mem::replace(&mut self.vars, chart.vars),
            instances: std::mem::replace(&mut self.instances, chart.instances),
            user_of: std::mem::replace(&mut self.user_of, chart.user_of),
        }
    }

    fn error(&mut self, span: Span, message: impl Into<String>) {
        self.diags.push(Diagnostic::error(span, message));
    }

    /// " (did you mean `Weld`?)" for a misspelt step, as the chart writes the step's name.
    fn step_hint(&self, name: &str) -> String {
        crate::front::pragma::did_you_mean(name, self.chart.steps.iter().map(|s| s.name.name.as_str()))
    }

    fn action_hint(&self, name: &str) -> String {
        crate::front::pragma::did_you_mean(name, self.chart.actions.iter().map(|a| a.name.name.as_str()))
    }

    /// The chart's declared variables and instances.
    fn var_hint(&self, name: &str) -> String {
        crate::front::pragma::did_you_mean(name, self.chart.vars.iter().map(|v| v.name.name.as_str()))
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
        let nested: Vec<(&Ident, &Sfc)> =
            chart.actions.iter().filter_map(|a| Some((&a.name, a.sfc.as_deref()?))).collect();
        self.declare_nested(&nested, "", &chart.steps, &mut vars);
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
                info: StepInfo {
                    name: step.name.name.clone(),
                    initial: step.initial,
                    pragmas: step.pragmas.clone(),
                    min_ms: self.supervision_of(step, "min_ms"),
                    max_ms: self.supervision_of(step, "max_ms"),
                },
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

    fn warn_unused_actions(&mut self) {
        let chart = self.chart;
        let mut used: HashMap<String, ()> = self.nested.controlled_keys().map(|k| (k.clone(), ())).collect();
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
