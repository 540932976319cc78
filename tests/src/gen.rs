//! Chart generators: structured charts (sequences, selections, simultaneous branches, loops) that are safe by
//! construction, and the large charts the benchmarks use.

use std::fmt::Write;

/// One structured element, to be laid out as steps and transitions.
#[derive(Clone, Debug)]
pub enum Shape {
    Step,
    Selection(Vec<Vec<Shape>>),
    Parallel(Vec<Vec<Shape>>),
    /// The body, then a choice between jumping back to its start and leaving.
    Loop(Vec<Shape>),
}

/// Random structured shapes, nested up to `depth`, for property tests.
pub fn shape_strategy(depth: u32) -> impl proptest::strategy::Strategy<Value = Shape> {
    use proptest::prelude::*;
    Just(Shape::Step).prop_recursive(depth, 24, 3, |inner| {
        let seq = prop::collection::vec(inner, 0..3);
        prop_oneof![
            2 => Just(Shape::Step),
            1 => prop::collection::vec(seq.clone(), 2..4).prop_map(Shape::Selection),
            1 => prop::collection::vec(seq.clone(), 2..4).prop_map(Shape::Parallel),
            1 => seq.prop_map(Shape::Loop),
        ]
    })
}

/// Builds chart text from shapes. Transition conditions read BOOL inputs `c0 … c{inputs-1}`, chosen in turn.
pub struct ChartBuilder {
    steps: Vec<String>,
    transitions: Vec<(Vec<usize>, Vec<usize>)>,
    inputs: usize,
}

impl ChartBuilder {
    pub fn new(inputs: usize) -> ChartBuilder {
        ChartBuilder { steps: Vec::new(), transitions: Vec::new(), inputs: inputs.max(1) }
    }

    fn step(&mut self) -> usize {
        self.steps.push(format!("S{}", self.steps.len()));
        self.steps.len() - 1
    }

    fn arc(&mut self, from: Vec<usize>, to: Vec<usize>) {
        self.transitions.push((from, to));
    }

    /// Lays out a sequence of shapes after `entry`; returns the last step.
    pub fn sequence(&mut self, entry: usize, shapes: &[Shape]) -> usize {
        shapes.iter().fold(entry, |at, shape| self.shape(at, shape))
    }

    fn shape(&mut self, entry: usize, shape: &Shape) -> usize {
        match shape {
            Shape::Step => {
                let s = self.step();
                self.arc(vec![entry], vec![s]);
                s
            }
            Shape::Selection(branches) => {
                let join = self.step();
                for branch in branches {
                    let first = self.step();
                    self.arc(vec![entry], vec![first]);
                    let last = self.sequence(first, branch);
                    self.arc(vec![last], vec![join]);
                }
                join
            }
            Shape::Parallel(branches) => {
                let firsts: Vec<usize> = branches.iter().map(|_| self.step()).collect();
                self.arc(vec![entry], firsts.clone());
                let lasts: Vec<usize> = firsts.iter().zip(branches).map(|(&f, b)| self.sequence(f, b)).collect();
                let join = self.step();
                self.arc(lasts, vec![join]);
                join
            }
            Shape::Loop(body) => {
                let first = self.step();
                self.arc(vec![entry], vec![first]);
                let last = self.sequence(first, body);
                self.arc(vec![last], vec![first]);
                let exit = self.step();
                self.arc(vec![last], vec![exit]);
                exit
            }
        }
    }

    /// A whole chart: initial step `S0`, the shapes, then a jump back to `S0` when `cyclic`.
    pub fn chart(shapes: &[Shape], inputs: usize, cyclic: bool) -> String {
        let mut b = ChartBuilder::new(inputs);
        let init = b.step();
        let last = b.sequence(init, shapes);
        if cyclic && last != init {
            b.arc(vec![last], vec![init]);
        }
        b.render()
    }

    pub fn render(&self) -> String {
        let mut out = String::with_capacity(self.steps.len() * 80);
        out.push_str("PROGRAM Generated\nVAR\n");
        for i in 0..self.inputs {
            let _ = writeln!(out, "  c{i} : BOOL;");
        }
        out.push_str("END_VAR\n");
        for (i, name) in self.steps.iter().enumerate() {
            let kw = if i == 0 { "INITIAL_STEP" } else { "STEP" };
            let _ = writeln!(out, "{kw} {name}: END_STEP");
        }
        let list = |ids: &[usize]| match ids {
            [one] => format!("S{one}"),
            many => format!("({})", many.iter().map(|i| format!("S{i}")).collect::<Vec<_>>().join(", ")),
        };
        for (k, (from, to)) in self.transitions.iter().enumerate() {
            let _ =
                writeln!(out, "TRANSITION FROM {} TO {} := c{}; END_TRANSITION", list(from), list(to), k % self.inputs);
        }
        out.push_str("END_PROGRAM\n");
        out
    }
}

/// A deterministic structured chart of about `steps` steps: sequences, selections, simultaneous branches and
/// loops in turn, nested two deep. Used for the parse + check benchmark.
pub fn large_structured_chart(steps: usize) -> String {
    let pattern = vec![
        Shape::Step,
        Shape::Selection(vec![vec![Shape::Step, Shape::Step], vec![Shape::Step]]),
        Shape::Parallel(vec![
            vec![Shape::Step, Shape::Selection(vec![vec![Shape::Step], vec![Shape::Step]])],
            vec![Shape::Step],
            vec![Shape::Loop(vec![Shape::Step])],
        ]),
        Shape::Loop(vec![Shape::Step, Shape::Step]),
    ];
    // The pattern above lays out 25 steps.
    let repeats = steps.div_ceil(25);
    let shapes: Vec<Shape> = std::iter::repeat_n(pattern, repeats).flatten().collect();
    ChartBuilder::chart(&shapes, 8, true)
}

/// `rings` independent networks (each its own initial step), each a loop of `ring_len` steps whose transitions
/// read `go`; every step drives action `Work` (N) and a counter action. With `go` TRUE every token moves every
/// cycle: `rings` active steps and `rings` cleared transitions per cycle, whatever `ring_len` is.
pub fn rings(rings: usize, ring_len: usize) -> String {
    let mut out = String::with_capacity(rings * ring_len * 90);
    out.push_str("PROGRAM Rings\nVAR\n  go : BOOL := TRUE;\n  work : DINT;\nEND_VAR\n");
    out.push_str("ACTION Work:\n  work := work + 1;\nEND_ACTION\n");
    for r in 0..rings {
        for i in 0..ring_len {
            let kw = if i == 0 { "INITIAL_STEP" } else { "STEP" };
            let _ = writeln!(out, "{kw} R{r}_{i}: Work(N); END_STEP");
            let next = (i + 1) % ring_len;
            let _ = writeln!(out, "TRANSITION FROM R{r}_{i} TO R{r}_{next} := go; END_TRANSITION");
        }
    }
    out.push_str("END_PROGRAM\n");
    out
}

/// A small deterministic random source (SplitMix64) for simulations that derive everything from one seed.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed ^ 0x6a09_e667_f3bc_c908)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// A number in `0..n` (`n` > 0).
    pub fn below(&mut self, n: u64) -> u64 {
        self.next_u64() % n.max(1)
    }

    pub fn chance(&mut self, p: f64) -> bool {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64 <= p
    }

    /// A number in `[0, max)`.
    pub fn fraction(&mut self, max: f64) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64 * max
    }
}

/// Random structured shapes from `rng`, nested up to `depth`: one to four of them.
pub fn random_shapes(rng: &mut Rng, depth: u32) -> Vec<Shape> {
    (0..1 + rng.below(4)).map(|_| random_shape(rng, depth)).collect()
}

fn random_shape(rng: &mut Rng, depth: u32) -> Shape {
    let seq = |rng: &mut Rng| (0..rng.below(3)).map(|_| random_shape(rng, depth - 1)).collect::<Vec<_>>();
    if depth == 0 {
        return Shape::Step;
    }
    match rng.below(5) {
        0 | 1 => Shape::Step,
        2 => Shape::Selection((0..2 + rng.below(2)).map(|_| seq(rng)).collect()),
        3 => Shape::Parallel((0..2 + rng.below(2)).map(|_| seq(rng)).collect()),
        _ => Shape::Loop(seq(rng)),
    }
}

/// A deterministic PLCopen TC6 v2.01 file of one SFC program with `steps` steps, as Beremiz writes them: a
/// chain with inline ST conditions, every fourth one wired from an LD contact instead, an N action with inline
/// ST on every fifth step, a selection every tenth step (the branch taken first skips a step), and a jump back to
/// the initial step. Used for the import + check benchmark.
pub fn large_plcopen_chart(steps: usize) -> String {
    let steps = steps.max(2);
    let mut out = String::with_capacity(steps * 900);
    out.push_str(
        "<?xml version=\"1.0\" encoding=\"utf-8\"?>\n<project xmlns=\"http://www.plcopen.org/xml/tc6_0201\" \
         xmlns:xhtml=\"http://www.w3.org/1999/xhtml\">\n<types><pous><pou name=\"Big\" pouType=\"program\">\n\
         <interface><localVars>\n<variable name=\"go\"><type><BOOL/></type></variable>\n\
         <variable name=\"n\"><type><DINT/></type></variable>\n</localVars></interface>\n<body><SFC>\n",
    );
    // Ids: step i is 10·i + 1, its outgoing transition 10·i + 2, its contact 10·i + 3, its action block
    // 10·i + 4, its divergence 10·i + 5, the skipping transition 10·i + 6 and the convergence 10·i + 7.
    let step_id = |i: usize| 10 * i + 1;
    out.push_str("<leftPowerRail localId=\"9\"><position x=\"0\" y=\"0\"/><connectionPointOut formalParameter=\"\"/></leftPowerRail>\n");
    for i in 0..steps {
        let y = 100 * i;
        let input = if i == 0 {
            format!("<connectionPointIn><connection refLocalId=\"{}\"/></connectionPointIn>", 10 * steps + 8)
        } else if (i - 1) % 10 == 9 && i >= 2 {
            format!("<connectionPointIn><connection refLocalId=\"{}\"/></connectionPointIn>", 10 * (i - 2) + 7)
        } else {
            format!("<connectionPointIn><connection refLocalId=\"{}\"/></connectionPointIn>", 10 * (i - 1) + 2)
        };
        let initial = if i == 0 { " initialStep=\"true\"" } else { "" };
        let _ = writeln!(
            out,
            "<step localId=\"{}\" name=\"S{i}\"{initial}><position x=\"100\" y=\"{y}\"/>{input}\
             <connectionPointOut formalParameter=\"sfc\"/><connectionPointOutAction formalParameter=\"\"/></step>",
            step_id(i)
        );
        if i % 5 == 0 {
            let _ = writeln!(
                out,
                "<actionBlock localId=\"{}\"><position x=\"200\" y=\"{y}\"/><connectionPointIn><connection refLocalId=\"{}\"/></connectionPointIn>\
                 <action localId=\"0\" qualifier=\"N\"><inline><ST><xhtml:p><![CDATA[n := n + {i};]]></xhtml:p></ST></inline></action></actionBlock>",
                10 * i + 4,
                step_id(i)
            );
        }
        let from = if i % 10 == 8 && i + 2 < steps {
            // A selection: the skipping branch (to step i + 2) or the plain one (to step i + 1).
            let _ = writeln!(
                out,
                "<selectionDivergence localId=\"{}\"><position x=\"100\" y=\"{}\"/><connectionPointIn><connection refLocalId=\"{}\"/></connectionPointIn>\
                 <connectionPointOut formalParameter=\"\"/><connectionPointOut formalParameter=\"\"/></selectionDivergence>",
                10 * i + 5,
                y + 40,
                step_id(i)
            );
            let _ = writeln!(
                out,
                "<transition localId=\"{}\"><position x=\"50\" y=\"{}\"/><connectionPointIn><connection refLocalId=\"{}\"/></connectionPointIn>\
                 <connectionPointOut/><condition><inline name=\"\"><ST><xhtml:p><![CDATA[go AND n > {i}]]></xhtml:p></ST></inline></condition></transition>",
                10 * i + 6,
                y + 60,
                10 * i + 5
            );
            10 * i + 5
        } else {
            step_id(i)
        };
        let condition = if i % 4 == 3 {
            let _ = writeln!(
                out,
                "<contact localId=\"{}\"><position x=\"20\" y=\"{}\"/><connectionPointIn><connection refLocalId=\"9\"/></connectionPointIn>\
                 <connectionPointOut/><variable>go</variable></contact>",
                10 * i + 3,
                y + 60
            );
            format!(
                "<condition><connectionPointIn><connection refLocalId=\"{}\"/></connectionPointIn></condition>",
                10 * i + 3
            )
        } else {
            "<condition><inline name=\"\"><ST><xhtml:p><![CDATA[go]]></xhtml:p></ST></inline></condition>".to_string()
        };
        let _ = writeln!(
            out,
            "<transition localId=\"{}\"><position x=\"150\" y=\"{}\"/><connectionPointIn><connection refLocalId=\"{from}\"/></connectionPointIn>\
             <connectionPointOut/>{condition}</transition>",
            10 * i + 2,
            y + 60
        );
        if i % 10 == 9 && i >= 1 && (i - 1) % 10 == 8 && i + 1 < steps {
            // The convergence after the plain branch's step i and the skipping transition of step i − 1.
            let _ = writeln!(
                out,
                "<selectionConvergence localId=\"{}\"><position x=\"100\" y=\"{}\"/><connectionPointIn><connection refLocalId=\"{}\"/></connectionPointIn>\
                 <connectionPointIn><connection refLocalId=\"{}\"/></connectionPointIn><connectionPointOut/></selectionConvergence>",
                10 * (i - 1) + 7,
                y + 80,
                10 * i + 2,
                10 * (i - 1) + 6
            );
        }
    }
    let _ = writeln!(
        out,
        "<jumpStep localId=\"{}\" targetName=\"S0\"><position x=\"100\" y=\"{}\"/><connectionPointIn><connection refLocalId=\"{}\"/></connectionPointIn></jumpStep>",
        10 * steps + 8,
        100 * steps,
        10 * (steps - 1) + 2
    );
    out.push_str("</SFC></body></pou></pous></types></project>\n");
    out
}

/// `rings` (see `rings`) whose steps each call one of `timers_per_ring` TON instances of their ring in their
/// action: `rings · timers_per_ring` instances, `rings` of them called per cycle, whatever `ring_len` is.
pub fn timer_rings(rings: usize, ring_len: usize, timers_per_ring: usize) -> String {
    let mut out = String::with_capacity(rings * ring_len * 90 + rings * timers_per_ring * 80);
    out.push_str("PROGRAM TimerRings\nVAR\n  go : BOOL := TRUE;\n");
    for r in 0..rings {
        for k in 0..timers_per_ring {
            let _ = writeln!(out, "  T{r}_{k} : TON;");
        }
    }
    out.push_str("END_VAR\n");
    for r in 0..rings {
        for k in 0..timers_per_ring {
            let _ = writeln!(out, "ACTION Time{r}_{k}: T{r}_{k}(IN := go, PT := T#50ms); END_ACTION");
        }
        for i in 0..ring_len {
            let kw = if i == 0 { "INITIAL_STEP" } else { "STEP" };
            let _ = writeln!(out, "{kw} R{r}_{i}: Time{r}_{}(N); END_STEP", i % timers_per_ring);
            let next = (i + 1) % ring_len;
            let _ = writeln!(out, "TRANSITION FROM R{r}_{i} TO R{r}_{next} := go; END_TRANSITION");
        }
    }
    out.push_str("END_PROGRAM\n");
    out
}

/// The skeleton of a PLCopen TC6 v2.01 file with one SFC program `P` over variables `x` (BOOL) and `n`, `y`
/// (INT): `sfc` is its body's elements, `actions` its `<actions>`.
fn plcopen_program(sfc: &str, actions: &str) -> String {
    format!(
        "<?xml version=\"1.0\" encoding=\"utf-8\"?>\n<project xmlns=\"http://www.plcopen.org/xml/tc6_0201\" \
         xmlns:xhtml=\"http://www.w3.org/1999/xhtml\">\n<types><pous><pou name=\"P\" pouType=\"program\">\n\
         <interface><localVars><variable name=\"x\"><type><BOOL/></type></variable>\
         <variable name=\"n\"><type><INT/></type></variable><variable name=\"y\"><type><BOOL/></type></variable>\
         </localVars></interface>\n<actions>{actions}</actions>\n<body><SFC>\n{sfc}</SFC></body></pou></pous></types></project>\n"
    )
}

/// Step `S0` (initial, running action `actions` names with N, if any) and the transition `S0 → S1` whose condition
/// is `condition`, then `S1`. Ids below 10 are theirs.
fn two_steps(condition: &str, action: Option<&str>) -> String {
    let block = action.map_or(String::new(), |a| {
        format!(
            "<actionBlock localId=\"4\"><position x=\"0\" y=\"0\"/><connectionPointIn><connection refLocalId=\"1\"/>\
             </connectionPointIn><action localId=\"0\" qualifier=\"N\"><reference name=\"{a}\"/></action></actionBlock>\n"
        )
    });
    format!(
        "<step localId=\"1\" name=\"S0\" initialStep=\"true\"><position x=\"0\" y=\"0\"/><connectionPointOut/>\
         <connectionPointOutAction/></step>\n{block}<transition localId=\"2\"><position x=\"0\" y=\"0\"/>\
         <connectionPointIn><connection refLocalId=\"1\"/></connectionPointIn><connectionPointOut/>{condition}</transition>\n\
         <step localId=\"3\" name=\"S1\"><position x=\"0\" y=\"0\"/><connectionPointIn><connection refLocalId=\"2\"/>\
         </connectionPointIn></step>\n"
    )
}

/// A transition wired from `contacts` LD contacts on `x`: in parallel (each from the left rail, OR-ed into the
/// condition) or in series (each fed by the one before).
pub fn plcopen_contacts(contacts: usize, parallel: bool) -> String {
    let mut sfc =
        String::from("<leftPowerRail localId=\"9\"><position x=\"0\" y=\"0\"/><connectionPointOut/></leftPowerRail>\n");
    for i in 0..contacts {
        let from = if parallel || i == 0 { 9 } else { 10 + i - 1 };
        let _ = writeln!(
            sfc,
            "<contact localId=\"{}\"><position x=\"0\" y=\"0\"/><connectionPointIn><connection refLocalId=\"{from}\"/>\
             </connectionPointIn><connectionPointOut/><variable>x</variable></contact>",
            10 + i
        );
    }
    let inputs: String = if parallel {
        (0..contacts).map(|i| format!("<connection refLocalId=\"{}\"/>", 10 + i)).collect()
    } else {
        format!("<connection refLocalId=\"{}\"/>", 10 + contacts - 1)
    };
    sfc.push_str(&two_steps(&format!("<condition><connectionPointIn>{inputs}</connectionPointIn></condition>"), None));
    plcopen_program(&sfc, "")
}

/// An LD action of `rungs` rungs, each a contact on `x` into a connector and, through its continuation, a coil of
/// `y`: how editors draw rungs that do not fit the page. Each continuation must find its connector by name.
pub fn plcopen_continuations(rungs: usize) -> String {
    let mut ld =
        String::from("<leftPowerRail localId=\"1\"><position x=\"0\" y=\"0\"/><connectionPointOut/></leftPowerRail>\n");
    for r in 0..rungs {
        let id = 10 + 4 * r;
        let _ = writeln!(
            ld,
            "<contact localId=\"{id}\"><position x=\"0\" y=\"0\"/><connectionPointIn><connection refLocalId=\"1\"/>\
             </connectionPointIn><connectionPointOut/><variable>x</variable></contact>\
             <connector localId=\"{}\" name=\"K{r}\"><position x=\"0\" y=\"0\"/><connectionPointIn>\
             <connection refLocalId=\"{id}\"/></connectionPointIn></connector>\
             <continuation localId=\"{}\" name=\"K{r}\"><position x=\"0\" y=\"0\"/><connectionPointOut/></continuation>\
             <coil localId=\"{}\"><position x=\"0\" y=\"0\"/><connectionPointIn><connection refLocalId=\"{}\"/>\
             </connectionPointIn><connectionPointOut/><variable>y</variable></coil>",
            id + 1,
            id + 2,
            id + 3,
            id + 2
        );
    }
    let action = format!("<action name=\"Rungs\"><body><LD>{ld}</LD></body></action>");
    plcopen_program(
        &two_steps(
            "<condition><inline name=\"\"><ST><xhtml:p><![CDATA[x]]></xhtml:p></ST></inline></condition>",
            Some("Rungs"),
        ),
        &action,
    )
}

/// A macro step whose body is a chain of `steps` steps; with `nested`, each macro body holds the next macro
/// step instead, `steps` deep.
pub fn plcopen_macro(steps: usize, nested: bool) -> String {
    let cond = "<condition><inline name=\"\"><ST><xhtml:p><![CDATA[x]]></xhtml:p></ST></inline></condition>";
    let chain = |prefix: &str, steps: usize| {
        let mut body = String::new();
        for i in 0..steps {
            let input = if i == 0 {
                String::new()
            } else {
                format!("<connectionPointIn><connection refLocalId=\"{}\"/></connectionPointIn>", 2 * i)
            };
            let initial = if i == 0 { " initialStep=\"true\"" } else { "" };
            let _ = write!(
                body,
                "<step localId=\"{}\" name=\"{prefix}{i}\"{initial}><position x=\"0\" y=\"0\"/>{input}<connectionPointOut/></step>",
                2 * i + 1
            );
            if i + 1 < steps {
                let _ = write!(
                    body,
                    "<transition localId=\"{}\"><position x=\"0\" y=\"0\"/><connectionPointIn><connection refLocalId=\"{}\"/>\
                     </connectionPointIn><connectionPointOut/>{cond}</transition>",
                    2 * i + 2,
                    2 * i + 1
                );
            }
        }
        body
    };
    let macro_step = |name: &str, body: &str| {
        format!(
            "<macroStep localId=\"5\" name=\"{name}\"><position x=\"0\" y=\"0\"/><connectionPointIn><connection refLocalId=\"2\"/>\
             </connectionPointIn><connectionPointOut/><body><SFC>{body}</SFC></body></macroStep>"
        )
    };
    let body = if nested {
        // Innermost first: each macro body is a step, a transition and the next macro step.
        let mut inner = chain("Deepest", 1);
        for d in (0..steps).rev() {
            let around = format!(
                "<step localId=\"1\" name=\"In{d}\" initialStep=\"true\"><position x=\"0\" y=\"0\"/><connectionPointOut/></step>\
                 <transition localId=\"2\"><position x=\"0\" y=\"0\"/><connectionPointIn><connection refLocalId=\"1\"/>\
                 </connectionPointIn><connectionPointOut/>{cond}</transition>{}",
                macro_step(&format!("M{d}"), &inner)
            );
            inner = around;
        }
        inner
    } else {
        chain("B", steps)
    };
    let sfc = format!(
        "<step localId=\"1\" name=\"S0\" initialStep=\"true\"><position x=\"0\" y=\"0\"/><connectionPointOut/></step>\
         <transition localId=\"2\"><position x=\"0\" y=\"0\"/><connectionPointIn><connection refLocalId=\"1\"/>\
         </connectionPointIn><connectionPointOut/>{cond}</transition>{}\
         <transition localId=\"6\"><position x=\"0\" y=\"0\"/><connectionPointIn><connection refLocalId=\"5\"/>\
         </connectionPointIn><connectionPointOut/>{cond}</transition>\
         <step localId=\"7\" name=\"S1\"><position x=\"0\" y=\"0\"/><connectionPointIn><connection refLocalId=\"6\"/>\
         </connectionPointIn></step>",
        macro_step("Outer", &body)
    );
    plcopen_program(&sfc, "")
}

/// Checks `base` with `len` bytes at `cut` replaced by `insert` (cuts inside a character are skipped): whatever
/// the text, the check returns.
pub fn check_mutated(base: &str, cut: proptest::sample::Index, len: usize, insert: &str) {
    let at = cut.index(base.len());
    let end = (at + len).min(base.len());
    if base.is_char_boundary(at) && base.is_char_boundary(end) {
        let _ = baton_proto::pipeline::check_source(&format!("{}{}{}", &base[..at], insert, &base[end..]));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_generated_plcopen_file_is_one_valid_chart_of_that_size() {
        let report = baton_proto::pipeline::check_source(&large_plcopen_chart(95));
        assert_eq!(report.error_count(), 0, "{:?}", report.diagnostics);
        let program = report.charts[0].program.as_ref().expect("a program");
        // 95 steps; a skipping transition at steps 8, 18, …, 88.
        assert_eq!((program.steps.len(), program.transitions.len()), (95, 95 + 9));
    }

    #[test]
    fn timer_rings_declare_and_call_their_instances() {
        let report = baton_proto::pipeline::check_source(&timer_rings(3, 4, 2));
        assert_eq!(report.error_count(), 0, "{:?}", report.diagnostics);
        let program = report.charts[0].program.as_ref().expect("a program");
        assert_eq!(program.steps.len(), 12);
        assert!(program.var_by_name("T2_1.Q").is_some());
    }
}
