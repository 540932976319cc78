//! The chart model: what a parser (textual SFC today, PLCopen XML later) produces, before names are resolved.
//!
//! The chart model (`Chart`, `Step`, `Transition`, `Action`, `Association`, `Qualifier` — the IEC ones and
//! CODESYS's `Entry`/`Exit`, which only vendor data writes —, `Expr`, `Stmt`; `Sfc`, an action written in SFC; `FbDef`
//! with its `actions`; `GlobalList`) as both parsers produce it, names unresolved, spans kept. Operator chains that are
//! associative (AND, OR, XOR) are built balanced (`Expr::balanced`, by `fold_balanced`, which the compiler's typing of
//! such a chain uses too), so 30,000 wired contacts nest 15 levels; `Expr::height` measures any tree without recursion.

use crate::front::diag::Span;

/// A name as written, with where it was written. Names compare without regard to case.
#[derive(Clone, Debug, PartialEq)]
pub struct Ident {
    pub name: String,
    pub span: Span,
}

impl Ident {
    /// The key under which the name is looked up: IEC 61131-3 identifiers are case-insensitive.
    pub fn key(&self) -> String {
        self.name.to_ascii_uppercase()
    }
}

/// A `{ … }` pragma, kept with the element it belongs to.
#[derive(Clone, Debug, PartialEq)]
pub struct Pragma {
    /// The text between the braces, trimmed.
    pub text: String,
    pub span: Span,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PouKind {
    Program,
    FunctionBlock,
    /// SFC elements written at the top level of a file, outside any POU.
    Bare,
}

/// One sequential function chart: the SFC body of a PROGRAM or FUNCTION_BLOCK, or a bare list of elements.
#[derive(Clone, Debug, PartialEq)]
pub struct Chart {
    pub name: Ident,
    pub kind: PouKind,
    pub vars: Vec<VarDecl>,
    pub steps: Vec<Step>,
    pub transitions: Vec<Transition>,
    pub actions: Vec<Action>,
    /// Pragmas that follow no element of the chart.
    pub pragmas: Vec<Pragma>,
    /// The whole POU, or the run of bare elements.
    pub span: Span,
    /// Elements left out because of a syntax error in them.
    pub broken: Broken,
    /// The project's named global variable lists (CODESYS's and TwinCAT's GVLs) whose variables the chart holds
    /// as VAR_GLOBAL: `GVL.x` names `x` of list `GVL`.
    pub global_lists: Vec<GlobalList>,
    /// The macro steps of a PLCopen chart (`macroStep`), whose bodies' steps the chart holds in their place:
    /// kept so that a drawing can show each as one step that opens on its body.
    pub macros: Vec<MacroStep>,
}

/// A macro step (`macroStep` in PLCopen TC6, outside the IEC 61131-3 scope but in IEC 60848, GRAFCET): its body's
/// steps joined the chart, a transition to the macro step leading to `entry` (and one leaving it leaving the body's
/// exit step).
#[derive(Clone, Debug, PartialEq)]
pub struct MacroStep {
    pub name: Ident,
    /// Its body's steps, with those of the macro steps nested in it.
    pub steps: Vec<Ident>,
    pub entry: Ident,
}

/// A named global variable list: its name, and the names of its variables.
#[derive(Clone, Debug, PartialEq)]
pub struct GlobalList {
    pub name: Ident,
    pub vars: Vec<Ident>,
}

impl Chart {
    /// A chart with nothing in it yet, for a parser to fill.
    pub fn empty(name: Ident, kind: PouKind, span: Span) -> Chart {
        Chart {
            name,
            kind,
            vars: Vec::new(),
            steps: Vec::new(),
            transitions: Vec::new(),
            actions: Vec::new(),
            pragmas: Vec::new(),
            span,
            broken: Broken::default(),
            macros: Vec::new(),
            global_lists: Vec::new(),
        }
    }
}

/// A type declared in a `TYPE` block (or a PLCopen `dataType`).
#[derive(Clone, Debug, PartialEq)]
pub struct TypeDef {
    pub name: Ident,
    pub kind: TypeKind,
}

#[derive(Clone, Debug, PartialEq)]
pub enum TypeKind {
    /// `(OPEN, CLOSED) := CLOSED`.
    Enum {
        values: Vec<Ident>,
        init: Option<Ident>,
    },
    /// `INT (0..1000)`: held as its base type.
    Subrange {
        base: Ident,
        low: i64,
        high: i64,
    },
    /// `Speed : INT;`, or another declared type.
    Alias(Ident),
    Array(ArraySpec),
    /// `STRUCT x : INT := 1; on : BOOL; END_STRUCT`: its fields, in order.
    Struct(Vec<VarDecl>),
    /// A structure, an array, a string type…: declared, not executed yet; the construct named.
    Unsupported(String),
}

/// A function block (or a function, with `returns`) with a Structured Text body, declared in the same file as
/// the charts that use it. Its syntax
/// errors are kept, not reported, until a chart declares an instance of it: a project file may hold blocks that
/// no chart uses, in constructs Baton does not read.
#[derive(Clone, Debug, PartialEq)]
pub struct FbDef {
    pub name: Ident,
    /// A `FUNCTION`'s result type; `None` for a function block.
    pub returns: Option<Ident>,
    pub vars: Vec<VarDecl>,
    pub body: Vec<Stmt>,
    /// A function block's actions (CODESYS, TwinCAT): bodies an instance runs when called as
    /// `instance.Action();` (or as a step's action), in the instance's scope; ST or a nested chart.
    pub actions: Vec<FbAction>,
    pub problems: Vec<crate::front::diag::Diagnostic>,
    pub span: Span,
}

#[derive(Clone, Debug, PartialEq)]
pub struct FbAction {
    pub name: Ident,
    pub body: Vec<Stmt>,
    /// An action written in SFC: a nested chart each instance holds the state of.
    pub sfc: Option<Box<Sfc>>,
}

/// What a syntax error took out of a chart: the names (keys) of the elements it was in, so that what follows from
/// their absence — an unknown step, action or variable, a chart without an initial step — is not reported as
/// another error, as rustc does.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Broken {
    pub steps: Vec<String>,
    pub actions: Vec<String>,
    pub vars: Vec<String>,
    /// A broken element of that kind whose name could not be read: any unknown name of the kind may be it.
    pub unnamed_step: bool,
    pub unnamed_action: bool,
    pub unnamed_var: bool,
    /// A broken `INITIAL_STEP`.
    pub initial_step: bool,
    /// Spans of conditions that could not be read, kept as FALSE so that the net around them is checked.
    pub conditions: Vec<Span>,
}

impl Broken {
    pub fn absorb(&mut self, other: Broken) {
        self.steps.extend(other.steps);
        self.actions.extend(other.actions);
        self.vars.extend(other.vars);
        self.unnamed_step |= other.unnamed_step;
        self.unnamed_action |= other.unnamed_action;
        self.unnamed_var |= other.unnamed_var;
        self.initial_step |= other.initial_step;
        self.conditions.extend(other.conditions);
    }

    pub fn step(&self, key: &str) -> bool {
        self.unnamed_step || self.steps.iter().any(|s| s == key)
    }

    pub fn action(&self, key: &str) -> bool {
        self.unnamed_action || self.actions.iter().any(|s| s == key)
    }

    pub fn var(&self, key: &str) -> bool {
        self.unnamed_var || self.vars.iter().any(|s| s == key)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VarSection {
    Local,
    Input,
    Output,
    InOut,
    External,
    Global,
    Temp,
}

#[derive(Clone, Debug, PartialEq)]
pub struct VarDecl {
    pub name: Ident,
    pub section: VarSection,
    pub constant: bool,
    /// The type's name as written.
    pub type_name: Ident,
    pub init: Option<Expr>,
    /// A function block instance's initial inputs: `t1 : TON := (PT := T#2s);`.
    pub members: Vec<(Ident, Expr)>,
    /// `ARRAY [1..3, 0..1] OF INT := [1, 2, 4(0)]` (the type name is then `ARRAY`).
    pub array: Option<ArraySpec>,
    /// Pragmas written right after the declaration's `;`, on its line: `door : BOOL; {input := 'zenoh', …}`.
    pub pragmas: Vec<Pragma>,
    /// The device address it is declared at (PLCopen's `address`: `%I*`, `%QX0.1`): one of the device's signals,
    /// which a test sets and a trace shows even where it is a function block's local.
    pub address: Option<String>,
}

/// An array type: its dimensions (inclusive bounds), element type, and initial elements in order, as runs
/// (`3(0)` is a run of three; fewer than the array's size leave the rest at the element type's default). Runs
/// are kept as written, never expanded here: a count of a billion costs nothing until the compiler weighs it
/// against the array's size.
#[derive(Clone, Debug, PartialEq)]
pub struct ArraySpec {
    pub dims: Vec<(i64, i64)>,
    pub elem: Ident,
    pub init: Vec<InitRun>,
    pub span: Span,
}

/// `count` times `value` among an array's initial values.
#[derive(Clone, Debug, PartialEq)]
pub struct InitRun {
    pub count: u64,
    pub value: Expr,
}

impl ArraySpec {
    /// How many initial values the runs give (saturating).
    pub fn init_len(&self) -> u64 {
        self.init.iter().fold(0u64, |n, r| n.saturating_add(r.count))
    }

    /// The elements, `None` when the dimensions are empty (`high < low`) or hold more than `u64::MAX`.
    pub fn elements(&self) -> Option<u64> {
        self.dims.iter().try_fold(1u64, |n, &(low, high)| {
            let size = u64::try_from(i128::from(high) - i128::from(low) + 1).ok().filter(|&s| s > 0)?;
            n.checked_mul(size)
        })
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct Step {
    pub name: Ident,
    pub initial: bool,
    pub associations: Vec<Association>,
    pub pragmas: Vec<Pragma>,
    /// From the keyword to `END_STEP`.
    pub span: Span,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Qualifier {
    N,
    R,
    S,
    L,
    D,
    P,
    P0,
    P1,
    SD,
    DS,
    SL,
    /// A step's entry action, as CODESYS and TwinCAT attach it in their exports' vendor data (no IEC qualifier
    /// and no textual form): its body runs once in the cycle the step becomes active, with no final scan.
    Entry,
    /// A step's exit action, likewise: its body runs once in the cycle the step is left. In a cycle, exit actions
    /// run before entry actions, and those before every other action, as CODESYS documents.
    Exit,
    /// A step's main action ("step action"), likewise: its body runs every cycle while the step is active, with
    /// no final scan (CODESYS and TwinCAT do not run it once more when the step is left), after the entry actions
    /// and before the IEC actions.
    Active,
}

impl Qualifier {
    pub fn from_word(word: &str) -> Option<Qualifier> {
        Some(match word.to_ascii_uppercase().as_str() {
            "N" => Qualifier::N,
            "R" => Qualifier::R,
            "S" => Qualifier::S,
            "L" => Qualifier::L,
            "D" => Qualifier::D,
            "P" => Qualifier::P,
            "P0" => Qualifier::P0,
            "P1" => Qualifier::P1,
            "SD" => Qualifier::SD,
            "DS" => Qualifier::DS,
            "SL" => Qualifier::SL,
            _ => return None,
        })
    }

    /// L, D, SD, DS and SL need a duration.
    pub fn is_timed(self) -> bool {
        matches!(self, Qualifier::L | Qualifier::D | Qualifier::SD | Qualifier::DS | Qualifier::SL)
    }
}

#[derive(Clone, Debug, PartialEq)]
pub enum Duration {
    Literal { ms: i64, span: Span },
    Var(Ident),
}

#[derive(Clone, Debug, PartialEq)]
pub struct Association {
    pub action: Ident,
    pub qualifier: Qualifier,
    /// Where the qualifier was written; the action name's span when it was left out (N).
    pub qualifier_span: Span,
    pub duration: Option<Duration>,
    pub indicators: Vec<Ident>,
    pub span: Span,
}

impl Association {
    /// `action(S)`, written nowhere (a reader holds an action it makes so): placed at `at`, a step's span.
    pub fn stored(action: Ident, at: Span) -> Association {
        Association {
            action,
            qualifier: Qualifier::S,
            qualifier_span: at,
            duration: None,
            indicators: Vec::new(),
            span: at,
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct Transition {
    pub name: Option<Ident>,
    pub priority: Option<(u32, Span)>,
    pub from: Vec<Ident>,
    pub to: Vec<Ident>,
    pub condition: Expr,
    pub pragmas: Vec<Pragma>,
    /// From the keyword to `END_TRANSITION`.
    pub span: Span,
    /// The span of `FROM … TO …`, used to report problems with the net.
    pub arc_span: Span,
}

impl Transition {
    /// The transition's name, or `FROM->TO` when it has none (`(A,B)->C` for several steps).
    pub fn display_name(&self) -> String {
        if let Some(name) = &self.name {
            return name.name.clone();
        }
        fn list(steps: &[Ident]) -> String {
            match steps {
                [one] => one.name.clone(),
                many => format!("({})", many.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join(",")),
            }
        }
        format!("{}->{}", list(&self.from), list(&self.to))
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct Action {
    pub name: Ident,
    pub body: Vec<Stmt>,
    /// An action written in SFC (a nested chart): its steps and transitions, in place of statements.
    pub sfc: Option<Box<Sfc>>,
    pub pragmas: Vec<Pragma>,
    pub span: Span,
}

/// A chart that is an action's body (IEC 61131-3 lets an action be written in SFC). Its associations name
/// actions of the POU (as in PLCopen XML, where every action is the POU's), which it then controls alone; each
/// run of the action is one scan of the chart.
#[derive(Clone, Debug, PartialEq)]
pub struct Sfc {
    pub steps: Vec<Step>,
    pub transitions: Vec<Transition>,
    /// Which of CODESYS's SFC flags the chart uses, where the file says (a CODESYS export's `SFCSettings`);
    /// `None`: each flag the POU declares as a BOOL (`SFCInit`, `SFCReset`) is used, as CoDeSys V2.3 had it.
    pub flags: Option<SfcFlags>,
}

/// CODESYS's SFC flags a nested chart obeys: `SFCInit` (back to the initial step and held there, no action run)
/// and `SFCReset` (back to the initial step, which then runs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SfcFlags {
    pub init: bool,
    pub reset: bool,
}

#[derive(Clone, Debug, PartialEq)]
pub enum Stmt {
    /// `target := value;` where the target is a variable (`Name`) or a member of an instance (`Field`).
    Assign {
        target: Expr,
        value: Expr,
        span: Span,
    },
    If {
        branches: Vec<(Expr, Vec<Stmt>)>,
        otherwise: Vec<Stmt>,
        span: Span,
    },
    /// A function block call: `t1(IN := x, PT := T#2s);`, `t1(x, T#2s);`, `t1(Q => done);`.
    Call {
        callee: Ident,
        args: Vec<Arg>,
        span: Span,
    },
    Case {
        selector: Expr,
        arms: Vec<CaseArm>,
        otherwise: Vec<Stmt>,
        span: Span,
    },
    For {
        var: Ident,
        from: Expr,
        to: Expr,
        by: Option<Expr>,
        body: Vec<Stmt>,
        span: Span,
    },
    While {
        condition: Expr,
        body: Vec<Stmt>,
        span: Span,
    },
    Repeat {
        body: Vec<Stmt>,
        until: Expr,
        span: Span,
    },
    Exit {
        span: Span,
    },
    Return {
        span: Span,
    },
}

/// One argument of a call: formal (`IN := x`, or `Q => y` for an output, `NOT Q => y` negated) or not (`x`).
#[derive(Clone, Debug, PartialEq)]
pub struct Arg {
    pub name: Option<Ident>,
    /// `=>`: the parameter is an output and `value` the variable it is written to.
    pub output: bool,
    /// `NOT Q => y`.
    pub negated: bool,
    pub value: Expr,
    pub span: Span,
}

/// `1, 3..5, 8:` — the labels of one CASE arm.
#[derive(Clone, Debug, PartialEq)]
pub struct CaseArm {
    pub labels: Vec<CaseLabel>,
    pub body: Vec<Stmt>,
}

#[derive(Clone, Debug, PartialEq)]
pub enum CaseLabel {
    Value(Expr),
    Range(Expr, Expr),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UnOp {
    Neg,
    Not,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BinOp {
    Or,
    Xor,
    And,
    Eq,
    Ne,
    Lt,
    Le,
    Gt,
    Ge,
    Add,
    Sub,
    Mul,
    Div,
    Mod,
    Pow,
}

impl BinOp {
    pub fn symbol(self) -> &'static str {
        match self {
            BinOp::Or => "OR",
            BinOp::Xor => "XOR",
            BinOp::And => "AND",
            BinOp::Eq => "=",
            BinOp::Ne => "<>",
            BinOp::Lt => "<",
            BinOp::Le => "<=",
            BinOp::Gt => ">",
            BinOp::Ge => ">=",
            BinOp::Add => "+",
            BinOp::Sub => "-",
            BinOp::Mul => "*",
            BinOp::Div => "/",
            BinOp::Mod => "MOD",
            BinOp::Pow => "**",
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
pub enum ExprKind {
    Bool(bool),
    Int(i64),
    Real(f64),
    Time(i64),
    Date(i64),
    Tod(i64),
    Dt(i64),
    /// A STRING literal's value (escapes resolved).
    Str(String),
    Name(Ident),
    /// `step.X`, `step.T`, `action.Q`, `instance.Q`.
    Field(Ident, Ident),
    /// An array element: `a[i]`, `grid[i, j + 1]`.
    Index(Ident, Vec<Expr>),
    /// A field of an array's structure element indexed at run time: `pts[i].x` (with constant indices the
    /// parser writes `Field(pts[2], x)`, the element's own name).
    IndexField(Ident, Vec<Expr>, Ident),
    /// An enumeration value written with its type: `MYTYPE#OPEN`.
    EnumValue(Ident, Ident),
    /// A function call: `ABS(x)`, `LIMIT(0, x, 10)`, `INT_TO_REAL(i)`, `SEL(G := c, IN0 := a, IN1 := b)`.
    Call(Ident, Vec<Arg>),
    Unary(UnOp, Box<Expr>),
    Binary(BinOp, Box<Expr>, Box<Expr>),
}

#[derive(Clone, Debug, PartialEq)]
pub struct Expr {
    pub kind: ExprKind,
    pub span: Span,
}

impl BinOp {
    /// `a op (b op c)` is `(a op b) op c` for every operand type the compiler accepts (BOOL and bit strings), and
    /// evaluating either reads the operands left to right: a chain of them may be built as a balanced tree.
    pub fn associative(self) -> bool {
        matches!(self, BinOp::And | BinOp::Or | BinOp::Xor)
    }
}

impl Expr {
    /// The nodes on the longest path from this expression down to a leaf (a literal or a name counts 1), counted
    /// without recursion, so that it is safe on any tree.
    pub fn height(&self) -> usize {
        let mut max = 0;
        let mut stack = vec![(self, 1usize)];
        while let Some((e, h)) = stack.pop() {
            max = max.max(h);
            match &e.kind {
                ExprKind::Index(_, ix) | ExprKind::IndexField(_, ix, _) => stack.extend(ix.iter().map(|c| (c, h + 1))),
                ExprKind::Call(_, args) => stack.extend(args.iter().map(|a| (&a.value, h + 1))),
                ExprKind::Unary(_, c) => stack.push((c, h + 1)),
                ExprKind::Binary(_, l, r) => {
                    stack.push((l, h + 1));
                    stack.push((r, h + 1));
                }
                _ => {}
            }
        }
        max
    }

    /// `operands` (at least one) joined by `op`, associative (`BinOp::associative`), as a balanced tree: a chain
    /// of n operands is ⌈log₂ n⌉ levels deep rather than n, in the same left-to-right order. A wired network of
    /// 30,000 parallel contacts is 15 levels deep.
    pub fn balanced(op: BinOp, operands: Vec<Expr>) -> Expr {
        debug_assert!(op.associative());
        let joined = fold_balanced(operands, |a, b| {
            let span = a.span.to(b.span);
            Some(Expr { kind: ExprKind::Binary(op, Box::new(a), Box::new(b)), span })
        });
        joined.unwrap_or(Expr { kind: ExprKind::Bool(op == BinOp::And), span: Span::new(0, 0) })
    }
}

/// `items` joined pairwise, level by level, into a balanced tree — ⌈log₂ n⌉ levels for n items, in the same
/// left-to-right order — without recursion. `None` for no items, or as soon as `join` gives up.
pub fn fold_balanced<T>(items: Vec<T>, mut join: impl FnMut(T, T) -> Option<T>) -> Option<T> {
    let mut level = items;
    while level.len() > 1 {
        let mut next = Vec::with_capacity(level.len().div_ceil(2));
        let mut items = level.into_iter();
        while let Some(a) = items.next() {
            next.push(match items.next() {
                Some(b) => join(a, b)?,
                None => a,
            });
        }
        level = next;
    }
    level.pop()
}
