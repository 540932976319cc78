//! The public charts in `../shared/corpus/sfc` (see its SOURCES.md), textual and PLCopen XML: each parses, or is
//! rejected with precise errors, exactly as recorded in `tests/corpus_expected`; the valid ones also run; and
//! the charts that exist in both forms give the same chart and the same trace.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use baton_proto::exec::sim::simulate;
use baton_proto::exec::trace::TraceEvent;
use baton_proto::pipeline::check_source;

fn corpus_files() -> Vec<PathBuf> {
    let dir = baton_tests::shared_dir().join("corpus/sfc");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        // CI always has ../shared; a missing corpus there is a broken setup, not a reason to pass.
        baton_tests::missing(&format!(
            "the shared SFC corpus is absent ({}): these tests need ../shared beside the checkout",
            dir.display()
        ));
    };
    // Charts beyond the shared corpus (BATON_EXTRA_CORPUS), where given, are held to their expectations too.
    let extra = baton_tests::extra_corpus_dir().and_then(|d| std::fs::read_dir(d).ok());
    let mut files: Vec<PathBuf> = entries
        .chain(extra.into_iter().flatten())
        .map(|e| e.expect("directory entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "st" || e == "txt" || e == "test" || e == "xml"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no charts in {}", dir.display());
    files
}

fn expected_path(file: &Path) -> PathBuf {
    let name = file.file_name().expect("file name").to_string_lossy().into_owned();
    Path::new(env!("CARGO_MANIFEST_DIR")).join("corpus_expected").join(format!("{name}.expected"))
}

fn corpus_charts_parse_or_are_rejected_precisely() {
    let files = corpus_files();
    let failures: Vec<String> = files
        .iter()
        .filter_map(|f| baton_tests::conformance::check_diagnostics_against(f, &expected_path(f)).err())
        .collect();
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}

fn valid_corpus_charts_run() {
    let files = corpus_files();
    let mut ran = 0;
    for file in files {
        let src = std::fs::read_to_string(&file).expect("readable corpus file");
        for chart in check_source(&src).charts {
            let Some(program) = chart.program else { continue };
            let mut events = 0;
            simulate(Arc::new(program), &[], 10, 2000, |_| events += 1).expect("simulation runs");
            assert!(events > 0, "{}: chart `{}` produced no events", file.display(), chart.chart.name.name);
            ran += 1;
        }
    }
    // matiec's sfc.txt and both ironplc charts are valid, and so are matiec's SFC_TEST.xml, Beremiz's
    // first_steps and the TwinCAT export.
    assert!(ran >= 6, "only {ran} corpus charts ran");
}

/// The one chart of a corpus file, checked.
fn program_of(name: &str) -> baton_proto::exec::program::Program {
    let path = baton_tests::shared_dir().join("corpus/sfc").join(name);
    let Ok(src) = std::fs::read_to_string(&path) else {
        baton_tests::missing(&format!("{} is absent", path.display()));
    };
    let mut charts = check_source(&src).charts;
    assert_eq!(charts.len(), 1, "{name}");
    charts.remove(0).program.unwrap_or_else(|| panic!("{name} is not valid"))
}

/// A name upper-cased, and an inline action's generated name without its step: matiec's textual twin names
/// them `INLINE1`…, Beremiz `STEP2_INLINE1`…, both numbered in document order.
fn plain(name: &str) -> String {
    let upper = name.to_ascii_uppercase();
    match upper.find("_INLINE") {
        Some(i) if upper[i + 7..].chars().all(|c| c.is_ascii_digit()) => upper[i + 1..].to_string(),
        _ => upper,
    }
}

/// Steps, transitions (sources, targets, rank) and actions by name, whatever order the file declares them in.
fn shape(p: &baton_proto::exec::program::Program) -> (Vec<String>, Vec<String>, Vec<String>) {
    let upper = |s: &str| plain(s);
    let mut steps: Vec<String> = p
        .steps
        .iter()
        .enumerate()
        .map(|(i, s)| {
            format!(
                "{}{}",
                upper(&s.name),
                if p.initial_steps.iter().any(|x| x.index() == i) { " (initial)" } else { "" }
            )
        })
        .collect();
    steps.sort();
    let mut transitions: Vec<String> = p.transitions.iter().map(|t| upper(&t.name)).collect();
    transitions.sort();
    let mut actions: Vec<String> = p.actions.iter().map(|a| upper(&a.name)).collect();
    actions.sort();
    (steps, transitions, actions)
}

/// The trace of a program under a script that flips each BOOL input and steps each integer one, variable by
/// variable, one every 30 ms, with names upper-cased (the two forms may spell them differently).
fn trace(p: baton_proto::exec::program::Program) -> Vec<String> {
    baton_tests::roundtrip::trace_with(&p, 200, plain)
}

fn same_chart_and_trace(xml: &str, text: &str) {
    let (a, b) = (program_of(xml), program_of(text));
    assert_eq!(shape(&a), shape(&b), "{xml} and {text} are not the same chart");
    let (ta, tb) = (trace(a), trace(b));
    assert!(ta.len() > 10, "the script moves the chart: {ta:#?}");
    assert_eq!(ta, tb, "{xml} and {text} run differently");
}

fn matiec_sfc_test_in_xml_and_in_text_is_one_chart() {
    same_chart_and_trace("matiec__tests__SFC_TEST.xml", "matiec__tests__syntax__sfc__sfc.txt");
}

fn beremiz_first_steps_in_xml_and_ironplc_text_are_one_chart() {
    same_chart_and_trace(
        "beremiz__exemples__first_steps__plc.xml",
        "ironplc__compiler__resources__test__first_steps_function_block_counter_sfc.st",
    );
}

/// Beremiz's traffic light draws an SR, a TON and their wiring in the SFC body, which Baton runs as Beremiz
/// compiles it (COMPUTE_FUNCTION_BLOCKS, held by the initial step): the light goes round its steps, a lap lasts
/// its timers' sum, a pedestrian request during GREEN (latched by the SR, released by the TON's 2 s) ends GREEN
/// 2 s later instead of at its 20 s, and the request is spent — the next GREEN lasts its full time.
fn beremiz_traffic_light_cycles_and_answers_the_pedestrian_button() {
    use baton_proto::exec::sim::{parse_inputs, simulate};
    use baton_proto::exec::trace::Output;
    let program = program_of("beremiz__exemples__svghmi_traffic_light__plc.xml");
    let script = "{\"t_ms\": 100, \"set\": {\"SWITCH_BUTTON\": true}}\n\
                  {\"t_ms\": 60000, \"set\": {\"PEDESTRIAN_BUTTON\": true}}\n\
                  {\"t_ms\": 60200, \"set\": {\"PEDESTRIAN_BUTTON\": false}}\n";
    let inputs = parse_inputs(script, &program).expect("the script names the chart's inputs");
    let mut fired = Vec::new();
    simulate(std::sync::Arc::new(program), &inputs, 20, 110_000, |out| {
        if let Output::Trace(r) = out {
            if r.event == TraceEvent::Fire {
                fired.push((r.t_ms, r.name));
            }
        }
    })
    .expect("simulation");
    let at = |name: &str, nth: usize| fired.iter().filter(|(_, n)| n == name).nth(nth).map(|(t, _)| *t);
    let (Some(g0), Some(g1)) = (at("PEDESTRIAN_RED->GREEN", 0), at("PEDESTRIAN_RED->GREEN", 1)) else {
        panic!("the light does not cycle: {fired:?}")
    };
    // A full lap lasts its timers' sum (GREEN alone is 20 s).
    assert!(g1 - g0 > 30_000, "a lap from GREEN to GREEN: {fired:?}");
    // The second GREEN began before the press (60 s) and ends about 2 s after it, long before its 20 s are up.
    assert!(g1 < 60_000 && g1 + 20_000 > 62_200, "the press falls early in the second GREEN: {fired:?}");
    let left = fired.iter().find(|(t, n)| *t > g1 && n == "GREEN->ORANGE").map(|(t, _)| *t).expect("GREEN is left");
    assert!((61_900..=62_200).contains(&left), "GREEN ends 2 s after the press, at {left}: {fired:?}");
    // The request is spent: the next GREEN lasts its full 20 s.
    let g2 = at("PEDESTRIAN_RED->GREEN", 2).expect("a third GREEN");
    let next = fired.iter().find(|(t, n)| *t > g2 && n == "GREEN->ORANGE").map(|(t, _)| *t).expect("left again");
    assert!(next - g2 >= 19_900, "the third GREEN lasts {} ms: {fired:?}", next - g2);
}

/// Beremiz's first_steps declares `VAR_EXTERNAL CONSTANT ResetCounterValue : INT;` in `CounterSFC`, without a
/// value: the configuration's global list gives it 17, and Beremiz (matiec) resets the counter to 17. Baton reads
/// the project's global lists, so a reset gives 17 here too (it gave 0, the type's default).
fn beremiz_first_steps_counter_resets_to_the_configurations_global_value() {
    use baton_proto::exec::sim::{parse_inputs, simulate_watching};
    use baton_proto::exec::trace::Output;
    let program = program_of("beremiz__exemples__first_steps__plc.xml");
    let inputs = parse_inputs("{\"t_ms\": 0, \"set\": {\"Reset\": true}}\n", &program).expect("Reset is an input");
    let watch = [program.var_by_name("OUT").expect("CounterSFC has an output OUT")];
    let mut values = Vec::new();
    simulate_watching(Arc::new(program), &inputs, 10, 50, &watch, |o| {
        if let Output::Trace(r) = o {
            values.extend(r.value);
        }
    })
    .expect("simulation");
    assert_eq!(values, ["17"], "OUT after a reset");
}

/// The XML reader returns, with diagnostics, whatever is cut out of or put into three real exports of the corpus
/// (Beremiz, matiec): no panic, no hang. A property test, run here because it needs the corpus.
fn xml_reader_never_panics_on_mutated_plcopen_files() {
    use proptest::prelude::*;
    use proptest::test_runner::{Config, TestRunner};
    const FILES: [&str; 3] = [
        "beremiz__exemples__first_steps__plc.xml",
        "matiec__tests__SFC_TEST.xml",
        "beremiz__exemples__svghmi_traffic_light__plc.xml",
    ];
    let dir = baton_tests::shared_dir().join("corpus/sfc");
    let files: Vec<String> = FILES
        .iter()
        .map(|f| {
            std::fs::read_to_string(dir.join(f))
                .unwrap_or_else(|e| baton_tests::missing(&format!("{} is absent: {e}", dir.join(f).display())))
        })
        .collect();
    let inserts = vec![
        "",
        "<",
        ">",
        "/>",
        "</step>",
        "<step localId=\"1\" name=\"S\">",
        "refLocalId=\"0\"",
        "&amp;",
        "&#0;",
        "<![CDATA[",
        "]]>",
        "\"",
        "<connection refLocalId=\"99\"/>",
        "<jumpStep localId=\"7\" targetName=\"X\"/>",
        "initialStep=\"true\"",
        "x := (",
        "<!--",
        "-->",
        "\u{feff}",
        "<block localId=\"5\" typeName=\"TON\">",
    ];
    let strategy = (0..FILES.len(), any::<prop::sample::Index>(), 0usize..60, prop::sample::select(inserts));
    let mut runner = TestRunner::new(Config { failure_persistence: None, ..Config::default() });
    let result = runner.run(&strategy, |(file, cut, len, insert)| {
        baton_tests::gen::check_mutated(&files[file], cut, len, insert);
        Ok(())
    });
    if let Err(e) = result {
        panic!("{e}");
    }
}

/// The xPPU's scenario 1 (CODESYS) keeps its sequence in function block `PPU`, run from program `MAIN` in ST, and
/// its blocks' actions in SFC. Baton runs PPU as the chart with MAIN's body around it, and each instance's action
/// charts apart. Pressing the operator panel's start button (the emergency-stop contact closed, as a healthy cell
/// has it) reaches PPU only through that body: the panel's body (called by `Stack`'s, which MAIN calls as
/// `PPU.Stack()`) copies the button to `Stack.StartButton` in the cycle of the press (MAIN runs after PPU's own
/// actions), PPU's ACT_Start copies it to its own in the next, and the transition out of `Start` sees it in the one
/// after: 20 ms after the press, and not before. There PPU's ACT_Init chart (a chart's
/// action in SFC) runs `Crane.ACT_Init` as a step action, a chart of the crane's instance, whose first step moves
/// on once nothing resets (`NOT InitCompleted AND NOT GVL.IsSFCResetting`).
fn xppu_scenario_1_starts_through_main_and_runs_its_blocks_charts() {
    use baton_proto::exec::sim::{parse_inputs, simulate_watching};
    use baton_proto::exec::trace::Output;
    let program = baton_tests::xppu_scenario_1();
    let script = "{\"t_ms\": 0, \"set\": {\"Stack.Panel.DI_EmergencyStop\": true}}\n\
                  {\"t_ms\": 500, \"set\": {\"Stack.Panel.DI_StartButton\": true}}\n\
                  {\"t_ms\": 520, \"set\": {\"Stack.Panel.DI_StartButton\": false}}\n";
    let inputs = parse_inputs(script, &program).expect("the panel's located inputs can be set");
    let step = |name: &str| program.var_by_name(name).unwrap_or_else(|| panic!("no variable {name}"));
    let watch = [step("Crane.ACT_Init.Crane_ACT_Init.X"), step("Stack.StartButton")];
    let (mut fired, mut values) = (Vec::new(), Vec::new());
    simulate_watching(Arc::new(program), &inputs, 10, 1_000, &watch, |out| {
        if let Output::Trace(r) = out {
            match r.event {
                TraceEvent::Fire => fired.push((r.t_ms, r.name)),
                TraceEvent::Value => values.push((r.t_ms, r.name, r.value.unwrap_or_default())),
                _ => {}
            }
        }
    })
    .expect("simulation");
    let start = fired.iter().find(|(_, n)| n == "Start->Initialisation_2").map(|(t, _)| *t);
    assert_eq!(start, Some(520), "the press at 500 ms reaches PPU through MAIN's body: {fired:?}");
    assert!(
        values.iter().any(|(t, n, v)| *t == 500 && n == "Stack.StartButton" && v == "TRUE"),
        "Stack's body copies its panel's button in the cycle of the press: {values:?}"
    );
    assert!(
        values.iter().any(|(_, n, v)| n == "Crane.ACT_Init.Crane_ACT_Init.X" && v == "TRUE"),
        "the crane instance's ACT_Init chart runs: {values:?}"
    );
}

baton_tests::harness_main!(
    sync corpus_charts_parse_or_are_rejected_precisely,
    sync valid_corpus_charts_run,
    sync matiec_sfc_test_in_xml_and_in_text_is_one_chart,
    sync beremiz_first_steps_in_xml_and_ironplc_text_are_one_chart,
    sync beremiz_traffic_light_cycles_and_answers_the_pedestrian_button,
    sync beremiz_first_steps_counter_resets_to_the_configurations_global_value,
    sync xppu_scenario_1_starts_through_main_and_runs_its_blocks_charts,
    sync xml_reader_never_panics_on_mutated_plcopen_files,
);
