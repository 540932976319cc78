//! Property tests: generated charts against the validator and the engine; arbitrary text against the parser;
//! arbitrary and mutated PLCopen XML against the XML reader.

use std::sync::Arc;

use baton_proto::exec::analysis::{analyse, exhaustive};
use baton_proto::exec::engine::{Engine, Input};
use baton_proto::pipeline::check_source;
use baton_proto::types::Value;
use baton_tests::gen::{check_mutated, shape_strategy, ChartBuilder};
use proptest::prelude::*;

const INPUTS: usize = 4;

/// One SFC-body element with small ids, so that references often hit, miss, loop or point at the wrong kind.
fn xml_element() -> impl Strategy<Value = String> {
    let id = 0u8..8;
    let name = prop::sample::select(vec!["A", "B", "C", "a", ""]);
    let refs = prop::collection::vec(0u8..9, 0..3);
    let kind = prop::sample::select(vec![
        "step",
        "transition",
        "selectionDivergence",
        "selectionConvergence",
        "simultaneousDivergence",
        "simultaneousConvergence",
        "jumpStep",
        "actionBlock",
        "inVariable",
        "contact",
        "leftPowerRail",
        "block",
        "macroStep",
        "coil",
        "connector",
        "continuation",
    ]);
    let cond = prop::sample::select(vec![
        "<condition><inline><ST>TRUE</ST></inline></condition>",
        "<condition><inline><ST><![CDATA[x AND (]]></ST></inline></condition>",
        "<condition><connectionPointIn><connection refLocalId=\"3\"/></connectionPointIn></condition>",
        "<condition><reference name=\"T\"/></condition>",
        "<condition negated=\"true\"><connection refLocalId=\"1\"/></condition>",
        "",
    ]);
    (kind, id, name, refs, any::<bool>(), cond).prop_map(|(kind, id, name, refs, initial, cond)| {
        let connections: String = refs.iter().map(|r| format!("<connection refLocalId=\"{r}\"/>")).collect();
        format!(
            "<{kind} localId=\"{id}\" name=\"{name}\" targetName=\"{name}\" initialStep=\"{initial}\" typeName=\"AND\">\
             <connectionPointIn>{connections}</connectionPointIn><expression>{name}</expression><variable>{name}</variable>\
             <action qualifier=\"N\"><inline><ST>x := 1;</ST></inline></action>{cond}</{kind}>"
        )
    })
}

/// Runs a valid chart for `cycles` cycles, setting the BOOL inputs c0…c3 from `toggles` before each cycle, and
/// returns how many times a step received a token while holding one.
fn collisions(src: &str, toggles: &[u8]) -> u64 {
    let report = check_source(src);
    let program = Arc::new(report.charts[0].program.clone().expect("valid chart"));
    let inputs: Vec<_> = (0..INPUTS).map(|i| program.var_by_name(&format!("c{i}")).expect("input")).collect();
    let mut engine = Engine::new(program);
    for (cycle, bits) in toggles.iter().enumerate() {
        for (i, var) in inputs.iter().enumerate() {
            engine.handle(Input::Set(*var, Value::Bool(bits & (1 << i) != 0))).expect("BOOL input");
        }
        engine.handle_cycle(cycle as u64 * 10).expect("time moves forward");
        while engine.poll_event().is_some() {}
    }
    engine.collisions()
}

/// A generated chart with actions on its steps, chosen by `picks`: N, P, S, R, L, D, SD and P0 associations of
/// three ST actions (counting, an IF, a timer call) and a boolean action, durations, indicators, named transitions
/// with priorities, and placement pragmas.
fn decorate(src: &str, picks: &[u8]) -> String {
    let pick = |i: usize| picks.get(i % picks.len().max(1)).copied().unwrap_or(0) as usize;
    let mut out = String::new();
    let mut step = 0;
    let mut transition = 0;
    for line in src.lines() {
        if line == "END_VAR" {
            out.push_str("  n : INT;\n  m : DINT := 1;\n  lamp : BOOL;\n  done : BOOL;\n  t1 : TON := (PT := T#30ms);\n  hold : TIME := T#20ms;\n  label : STRING[12] := 'it$'s';\n  bumps : INT;\nEND_VAR\n");
            out.push_str("ACTION Count: n := n + 1; END_ACTION\n");
            out.push_str("ACTION Double: {note := 'kept'} IF c0 AND n MOD 2 = 0 THEN m := m * 2 + 1; ELSE m := m - 1; END_IF; END_ACTION\n");
            out.push_str("ACTION Time: t1(IN := c1, Q => done); END_ACTION\n");
            out.push_str("ACTION Tag: label := CONCAT(LEFT(label, 3), '#', INT_TO_STRING(n MOD 10)); END_ACTION\n");
            // An action written in SFC, controlling an action of its own.
            out.push_str("ACTION Sub:\n  INITIAL_STEP Sa: Bump(N); END_STEP\n  TRANSITION FROM Sa TO Sb := Sa.T >= T#20ms; END_TRANSITION\n  STEP Sb: END_STEP\n  TRANSITION FROM Sb TO Sa := c0; END_TRANSITION\nEND_ACTION\n");
            out.push_str("ACTION Bump: bumps := bumps + 1; END_ACTION\n");
            continue;
        }
        if let Some(rest) = line.strip_suffix(": END_STEP") {
            let k = pick(step);
            let assoc = match k % 11 {
                0 => "Count(N);",
                1 => "Count(P); Double(N);",
                2 => "lamp(S);",
                3 => "lamp(R); Time(N);",
                4 => "Double(L, T#40ms);",
                5 => "Count(D, hold);",
                6 => "Time(SD, T#10ms, done);",
                7 => "Count(P0);",
                8 => "Tag(N);",
                9 => "Sub(N);",
                _ => "",
            };
            // A placed step with no actions: an action runs in one place.
            let pragma = if k % 11 == 10 && k % 2 == 0 { " {agent := 'r1'}" } else { "" };
            out.push_str(&format!("{rest}:{pragma} {assoc} END_STEP\n"));
            step += 1;
            continue;
        }
        if let Some(rest) = line.strip_prefix("TRANSITION FROM ") {
            let k = pick(transition + 7);
            let head = match k % 4 {
                0 => format!("TRANSITION T{transition} FROM "),
                1 => format!("TRANSITION (PRIORITY := {}) FROM ", k % 3),
                _ => "TRANSITION FROM ".to_string(),
            };
            let cond = match k % 5 {
                2 => rest.replace(" := c", " := t1.Q OR NOT c"),
                3 => rest.replace(" := c", " := (Sb.X AND LEN(label) > 4) OR c"),
                _ => rest.to_string(),
            };
            out.push_str(&format!("{head}{cond}\n"));
            transition += 1;
            continue;
        }
        out.push_str(line);
        out.push('\n');
    }
    out
}

proptest! {
    /// A chart written as PLCopen XML and read back is the same program with the same trace (random charts,
    /// with actions of every kind; the project's and the corpus's charts are in `tests/export.rs`).
    #[test]
    fn import_of_export_is_the_same_chart(
        shapes in prop::collection::vec(shape_strategy(3), 1..5),
        cyclic in any::<bool>(),
        picks in prop::collection::vec(any::<u8>(), 1..40),
    ) {
        let src = decorate(&ChartBuilder::chart(&shapes, INPUTS, cyclic), &picks);
        let report = check_source(&src);
        let errors: Vec<_> = report.diagnostics.iter().filter(|d| d.is_error()).map(|d| d.message.clone()).collect();
        prop_assert!(errors.is_empty(), "the decorated chart is valid: {errors:?}\n{src}");
        baton_tests::roundtrip::assert_round_trip("a random chart", &src);
    }

    /// Structured charts are safe by construction: the validator must accept them, and the engine must never
    /// put two tokens on one step, whatever the inputs do.
    #[test]
    fn random_safe_charts_never_put_two_tokens_on_a_step(
        shapes in prop::collection::vec(shape_strategy(3), 1..6),
        cyclic in any::<bool>(),
        toggles in prop::collection::vec(any::<u8>(), 1..200),
    ) {
        let src = ChartBuilder::chart(&shapes, INPUTS, cyclic);
        let report = check_source(&src);
        let errors: Vec<_> = report.diagnostics.iter().filter(|d| d.is_error()).map(|d| d.message.clone()).collect();
        prop_assert!(errors.is_empty(), "validator rejected a safe chart: {errors:?}\n{src}");
        prop_assert_eq!(collisions(&src, &toggles), 0);
    }

    /// On structured charts the linear structural pass must agree with the exhaustive exploration.
    #[test]
    fn structural_analysis_agrees_with_exhaustive_exploration(shapes in prop::collection::vec(shape_strategy(2), 1..4), cyclic in any::<bool>()) {
        let src = ChartBuilder::chart(&shapes, INPUTS, cyclic);
        let report = check_source(&src);
        let program = report.charts[0].program.as_ref().expect("valid chart");
        prop_assert_eq!(analyse(program), exhaustive(program));
    }

    #[test]
    fn parser_and_validator_never_panic_on_arbitrary_text(src in ".{0,400}") {
        let _ = check_source(&src);
    }

    #[test]
    fn parser_and_validator_never_panic_on_token_soup(words in prop::collection::vec(prop::sample::select(vec![
        "PROGRAM", "END_PROGRAM", "FUNCTION_BLOCK", "VAR", "END_VAR", "INITIAL_STEP", "STEP", "END_STEP", "TRANSITION",
        "END_TRANSITION", "FROM", "TO", "ACTION", "END_ACTION", "IF", "THEN", "ELSIF", "ELSE", "END_IF", "PRIORITY",
        "a", "b", "S1", "S2", "x", ":", ":=", ";", ",", "(", ")", ".", "X", "T", "Q", "N", "S", "SD", "L", "T#1s",
        "1", "2.5", "TRUE", "NOT", "AND", "+", "/", "0", "=", "<", "BOOL", "INT", "TIME", "{p}", "(*", "*)", "'s",
        "CASE", "OF", "END_CASE", "FOR", "BY", "DO", "END_FOR", "WHILE", "END_WHILE", "REPEAT", "UNTIL", "END_REPEAT",
        "EXIT", "RETURN", "TON", "CTU", "R_TRIG", "=>", "[", "]", "..", "ARRAY", "TYPE", "END_TYPE", "FUNCTION",
        "END_FUNCTION", "END_FUNCTION_BLOCK", "#", "**", "IN", "PT", "LIMIT", "INT_TO_REAL",
    ]), 0..120)) {
        let _ = check_source(&words.join(" "));
    }

    #[test]
    fn xml_reader_never_panics_on_element_soup(elements in prop::collection::vec(xml_element(), 0..40)) {
        let body: String = elements.concat();
        let src = format!(
            "<?xml version=\"1.0\"?><project xmlns=\"http://www.plcopen.org/xml/tc6_0201\"><types><pous>\
             <pou name=\"P\" pouType=\"program\"><body><SFC>{body}</SFC></body></pou></pous></types></project>"
        );
        let _ = check_source(&src);
    }

    #[test]
    fn parser_and_validator_never_panic_on_mutated_charts(
        cut in any::<prop::sample::Index>(),
        len in 0usize..40,
        insert in "[ -~]{0,8}",
    ) {
        check_mutated(include_str!("../conformance/traces/st_arithmetic/chart.st"), cut, len, &insert);
    }
}

/// Arbitrary nets: whenever the validator accepts one, running it never collides. This holds the exhaustive pass
/// (which such nets mostly need) to its word — and it means something only if enough nets are accepted, so the
/// test also fails when fewer than a fifth are.
#[test]
fn accepted_arbitrary_nets_are_safe() {
    use proptest::test_runner::{Config, TestRunner};
    let strategy = (
        2usize..7,
        prop::collection::vec((prop::collection::vec(0usize..7, 1..3), prop::collection::vec(0usize..7, 1..3)), 0..5),
        prop::collection::vec(any::<u8>(), 1..100),
    );
    let cases = std::env::var("PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(256);
    let mut runner = TestRunner::new(Config { cases, ..Config::default() });
    let (tried, accepted) = (std::cell::Cell::new(0u32), std::cell::Cell::new(0u32));
    let result = runner.run(&strategy, |(n_steps, arcs, toggles)| {
        let mut src =
            String::from("VAR c0 : BOOL; c1 : BOOL; c2 : BOOL; c3 : BOOL; END_VAR\nINITIAL_STEP S0: END_STEP\n");
        // A chain through every step keeps most nets reachable, so that many are accepted and then run.
        for i in 1..n_steps {
            src.push_str(&format!(
                "STEP S{i}: END_STEP\nTRANSITION FROM S{} TO S{i} := c{}; END_TRANSITION\n",
                i - 1,
                i % INPUTS
            ));
        }
        for (k, (from, to)) in arcs.iter().enumerate() {
            let list = |v: &[usize]| {
                let mut v: Vec<usize> = v.iter().map(|s| s % n_steps).collect();
                v.sort();
                v.dedup();
                format!("({})", v.iter().map(|s| format!("S{s}")).collect::<Vec<_>>().join(", "))
            };
            src.push_str(&format!(
                "TRANSITION FROM {} TO {} := c{}; END_TRANSITION\n",
                list(from),
                list(to),
                k % INPUTS
            ));
        }
        tried.set(tried.get() + 1);
        if check_source(&src).error_count() == 0 {
            accepted.set(accepted.get() + 1);
            prop_assert_eq!(collisions(&src, &toggles), 0, "accepted but unsafe:\n{}", src);
        }
        Ok(())
    });
    if let Err(e) = result {
        panic!("{e}");
    }
    let (tried, accepted) = (tried.get(), accepted.get());
    eprintln!("arbitrary nets: {accepted} of {tried} accepted and run");
    assert!(accepted * 5 >= tried, "only {accepted} of {tried} arbitrary nets were accepted: too few to mean anything");
}
