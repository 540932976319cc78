//! `baton export --svg`: every chart of the project and every valid chart of the shared corpus drawn in IEC 61131-3
//! notation, read back as XML by a reader we did not write (roxmltree) and held to the notation: one box per step
//! (the initial ones doubled), one bar per transition between its sources and its targets, a double line for every
//! simultaneous divergence and convergence, a single one for every selection divergence, a jump for every arc back,
//! an action block with each association's qualifier; no two boxes overlap; and every step where the PLCopen export
//! puts it, so that the two drawings of a chart are one.

use std::collections::{BTreeMap, BTreeSet};

use baton_proto::exec::program::{Program, StepId, TransitionId};
use baton_proto::front::model::Chart;
use baton_tests::loopback::{bin, repo};

/// A rectangle: x, y, width, height.
type Rect = (f64, f64, f64, f64);

fn number(node: roxmltree::Node, attr: &str) -> f64 {
    node.attribute(attr).and_then(|v| v.parse().ok()).unwrap_or_else(|| panic!("{attr} of {node:?}"))
}

fn rect(node: roxmltree::Node) -> Rect {
    (number(node, "x"), number(node, "y"), number(node, "width"), number(node, "height"))
}

fn overlap(a: Rect, b: Rect) -> bool {
    a.0 < b.0 + b.2 && b.0 < a.0 + a.2 && a.1 < b.1 + b.3 && b.1 < a.1 + a.3
}

fn has_class(node: roxmltree::Node, class: &str) -> bool {
    node.attribute("class").is_some_and(|c| c.split(' ').any(|w| w == class))
}

/// Whether `t` reaches `u` going down: `u` on a row below every source of `t` (otherwise the arc is a jump).
fn forward(boxes: &BTreeMap<String, Rect>, program: &Program, t: TransitionId, u: StepId) -> bool {
    let top = |s: StepId| boxes[&program.steps[s.index()].name].1;
    program.sources(t).iter().all(|&s| top(s) < top(u))
}

/// Checks the drawing of one chart against its program; returns the boxes of its steps by name.
fn check(what: &str, chart: &Chart, program: &Program, svg: &str) -> BTreeMap<String, Rect> {
    let doc = roxmltree::Document::parse(svg).unwrap_or_else(|e| panic!("{what}: not XML: {e}"));
    let root = doc.root_element();
    assert_eq!((root.tag_name().name(), root.tag_name().namespace()), ("svg", Some("http://www.w3.org/2000/svg")));
    let groups = |class: &str| -> Vec<roxmltree::Node> {
        root.descendants().filter(|n| n.tag_name().name() == "g" && has_class(*n, class)).collect()
    };
    // One box per step, named as the trace names it; the initial ones doubled.
    let mut boxes = BTreeMap::new();
    for g in groups("step") {
        let name = g.attribute("data-step").expect("data-step").to_string();
        let rects: Vec<roxmltree::Node> = g.children().filter(|n| n.tag_name().name() == "rect").collect();
        let info = program.steps.iter().find(|s| s.name == name).unwrap_or_else(|| panic!("{what}: no step {name}"));
        assert_eq!(rects.len(), if info.initial { 2 } else { 1 }, "{what}: step {name}");
        assert_eq!(has_class(g, "initial"), info.initial, "{what}: step {name}");
        if let [outer, inner] = rects[..] {
            let (o, i) = (rect(outer), rect(inner));
            assert!(o.0 < i.0 && o.1 < i.1 && i.0 + i.2 < o.0 + o.2 && i.1 + i.3 < o.1 + o.3, "{what}: {name} doubled");
        }
        // Its time below the box: the supervision limits the chart gives it, which the console marks against S.T.
        let time = g.children().find(|n| has_class(*n, "time")).unwrap_or_else(|| panic!("{what}: {name} has no time"));
        let ms = |attr: &str| time.attribute(attr).and_then(|v| v.parse::<u64>().ok());
        assert_eq!((ms("data-min-ms"), ms("data-max-ms")), (Some(info.min_ms), Some(info.max_ms)), "{what}: {name}");
        let text = time.text().unwrap_or("");
        assert_eq!(text.contains('≤'), info.max_ms > 0, "{what}: {name}'s limit shown: {text:?}");
        assert_eq!(text.contains('≥'), info.min_ms > 0, "{what}: {name}'s minimum shown: {text:?}");
        let b = rect(rects[0]);
        assert!(number(time, "y") > b.1 + b.3 && (b.0..b.0 + b.2).contains(&number(time, "x")), "{what}: {name}");
        assert!(boxes.insert(name.clone(), b).is_none(), "{what}: step {name} drawn twice");
    }
    assert_eq!(boxes.len(), program.steps.len(), "{what}: a box per step");
    // Action blocks: a row per association, with its qualifier, right of its step; nothing overlaps a box.
    let mut blocks: Vec<Rect> = Vec::new();
    for (s, step) in chart.steps.iter().enumerate() {
        let g = groups("step").into_iter().find(|g| g.attribute("data-step") == Some(&program.steps[s].name));
        let actions: Vec<roxmltree::Node> = g.expect("drawn").children().filter(|n| has_class(*n, "action")).collect();
        assert_eq!(actions.len(), step.associations.len(), "{what}: actions of {}", program.steps[s].name);
        for (a, node) in step.associations.iter().zip(&actions) {
            assert_eq!(node.attribute("data-action"), Some(a.action.name.as_str()), "{what}");
            let qualifier = node.descendants().find(|n| has_class(*n, "qualifier")).and_then(|n| n.text());
            let expected = format!("{:?}", a.qualifier);
            assert!(qualifier.is_some_and(|q| q.starts_with(&expected)), "{what}: {qualifier:?} for {expected}");
            let cells: Vec<Rect> = node.children().filter(|n| n.tag_name().name() == "rect").map(rect).collect();
            let whole = (cells[0].0, cells[0].1, cells.iter().map(|c| c.2).sum(), cells[0].3);
            assert!(
                whole.0 >= boxes[&program.steps[s].name].0 + boxes[&program.steps[s].name].2,
                "{what}: right of it"
            );
            blocks.push(whole);
        }
    }
    let all: Vec<(&String, Rect)> = boxes.iter().map(|(n, r)| (n, *r)).collect();
    for (i, (a, ra)) in all.iter().enumerate() {
        for (b, rb) in &all[i + 1..] {
            assert!(!overlap(*ra, *rb), "{what}: steps {a} and {b} overlap");
        }
        assert!(blocks.iter().all(|blk| !overlap(*ra, *blk)), "{what}: an action block covers step {a}");
    }
    // One bar per transition, named as the trace names it, below its sources and above the targets it reaches going
    // down; a jump, with the step's name, for each one it reaches going back.
    let transitions = groups("transition");
    assert_eq!(transitions.len(), program.transitions.len(), "{what}: a group per transition");
    for (t, info) in program.transitions.iter().enumerate() {
        let t = TransitionId(t as u32);
        let g = transitions.iter().find(|g| g.attribute("data-transition") == Some(info.name.as_str()));
        let g = g.unwrap_or_else(|| panic!("{what}: no transition {}", info.name));
        let bar =
            g.children().find(|n| has_class(*n, "bar")).unwrap_or_else(|| panic!("{what}: {} has no bar", info.name));
        let y = number(bar, "y1");
        for &s in program.sources(t) {
            let r = boxes[&program.steps[s.index()].name];
            assert!(y > r.1 + r.3, "{what}: {} above its source", info.name);
        }
        let jumps: BTreeSet<&str> =
            g.children().filter(|n| has_class(*n, "jump")).filter_map(|n| n.attribute("data-target")).collect();
        for &u in program.targets(t) {
            let name = program.steps[u.index()].name.as_str();
            if forward(&boxes, program, t, u) {
                assert!(y < boxes[name].1, "{what}: {} below its target {name}", info.name);
            } else {
                assert!(jumps.contains(name), "{what}: {} back to {name} is no jump", info.name);
            }
        }
    }
    // Double lines where the net is simultaneous, single ones where it is a selection.
    let count = |class: &str, with: &str| {
        groups(class).iter().filter(|g| has_class(**g, with)).count()
            + root
                .descendants()
                .filter(|n| n.tag_name().name() == "line" && has_class(*n, class) && has_class(*n, with))
                .count()
    };
    let ts = || (0..program.transitions.len()).map(|t| TransitionId(t as u32));
    assert_eq!(count("simultaneous", "divergence"), ts().filter(|&t| program.targets(t).len() > 1).count(), "{what}");
    assert_eq!(count("simultaneous", "convergence"), ts().filter(|&t| program.sources(t).len() > 1).count(), "{what}");
    let selections = (0..program.steps.len()).filter(|&s| program.outgoing(StepId(s as u32)).len() > 1).count();
    assert_eq!(count("selection", "divergence"), selections, "{what}");
    for g in groups("simultaneous") {
        assert_eq!(g.children().filter(|n| n.tag_name().name() == "line").count(), 2, "{what}: a double line");
    }
    boxes
}

/// The steps' positions in the PLCopen export of the same chart: `<step name=… ><position x y>`.
fn plcopen_positions(xml: &str, pou: &str) -> BTreeMap<String, (f64, f64)> {
    let doc = roxmltree::Document::parse(xml).expect("the export is XML");
    let pou = doc.descendants().find(|n| n.tag_name().name() == "pou" && n.attribute("name") == Some(pou));
    // The chart's own body (`pou/body/SFC`), not the SFC bodies of its actions.
    let body = pou.expect("the pou").children().find(|c| c.tag_name().name() == "body");
    let sfc = body.and_then(|b| b.children().find(|c| c.tag_name().name() == "SFC")).expect("its SFC body");
    sfc.children()
        .filter(|n| n.tag_name().name() == "step")
        .map(|s| {
            let at = s.children().find(|n| n.tag_name().name() == "position").expect("a position");
            (s.attribute("name").expect("a name").to_string(), (number(at, "x"), number(at, "y")))
        })
        .collect()
}

/// A chart's macro steps drawn as the console draws them, each held to the notation: the chart with each one as a
/// single step (marked, and naming the steps of its body), and each one's body as a chart of its own, whose steps are
/// its body's but for those of a macro step nested in it, drawn as that one step. The macro steps drawn.
fn macro_steps_drawn(what: &str, chart: &Chart, report: &baton_proto::pipeline::Report) -> usize {
    if chart.macros.is_empty() {
        return 0;
    }
    let (library, types) = (&report.library, &report.types);
    let (drawn, program) = baton_proto::back::svg::collapsed(chart, library, types, None)
        .unwrap_or_else(|| panic!("{what}: its macro steps are not drawn"));
    let svg = baton_proto::back::svg::chart(&drawn, &program);
    let boxes = check(&format!("{what} (macro steps as one step)"), &drawn, &program, &svg);
    // Nested in no other, a macro step is one box; the steps of its body are none.
    let top: Vec<_> = chart
        .macros
        .iter()
        .filter(|m| !chart.macros.iter().any(|o| o.name != m.name && o.steps.contains(&m.entry)))
        .collect();
    for m in &top {
        assert!(boxes.contains_key(&m.name.name), "{what}: macro step {} is not drawn", m.name.name);
        let steps: Vec<&str> = m.steps.iter().map(|s| s.name.as_str()).collect();
        let marked = format!("data-macro-steps=\"{}\"", steps.join(","));
        assert!(svg.contains(&marked), "{what}: {} does not name its body's steps", m.name.name);
        assert!(steps.iter().all(|s| !boxes.contains_key(*s)), "{what}: a step of {}'s body is drawn", m.name.name);
    }
    for m in &chart.macros {
        let (body, body_program) = baton_proto::back::svg::collapsed(chart, library, types, Some(&m.name.name))
            .unwrap_or_else(|| panic!("{what}: the body of {} is not drawn", m.name.name));
        let body_svg = baton_proto::back::svg::chart(&body, &body_program);
        let body_boxes = check(&format!("{what} (macro step {})", m.name.name), &body, &body_program, &body_svg);
        let nested: Vec<_> = chart.macros.iter().filter(|n| n.name != m.name && m.steps.contains(&n.entry)).collect();
        let hidden: BTreeSet<&str> = nested.iter().flat_map(|n| n.steps.iter().map(|s| s.name.as_str())).collect();
        let mut expected: BTreeSet<&str> =
            m.steps.iter().map(|s| s.name.as_str()).filter(|s| !hidden.contains(s)).collect();
        // Only the outermost of the nested ones: one nested deeper is inside another.
        expected.extend(
            nested
                .iter()
                .filter(|n| !nested.iter().any(|o| o.name != n.name && o.steps.contains(&n.entry)))
                .map(|n| n.name.name.as_str()),
        );
        assert_eq!(body_boxes.keys().map(String::as_str).collect::<BTreeSet<_>>(), expected, "{what}: {}", m.name.name);
    }
    top.len()
}

fn every_chart_is_drawn_in_the_notation_where_the_plcopen_export_puts_it() {
    let (mut drawn, mut supervised, mut nested, mut macros) = (0, 0, 0, 0);
    for (what, src) in baton_tests::chart_sources() {
        let report = baton_proto::pipeline::check_source(&src);
        if report.error_count() > 0 {
            continue; // diagnostics cases
        }
        let charts: Vec<(&Chart, &Program)> =
            report.charts.iter().filter_map(|c| Some((&c.chart, c.program.as_ref()?))).collect();
        let xml = baton_proto::back::plcopen::export(
            &charts,
            &report.library,
            &report.types,
            "drawing",
            "2026-12-07T00:00:00",
        );
        for (chart, program) in charts {
            let svg = baton_proto::back::svg::chart(chart, program);
            let boxes = check(&format!("{what} ({})", chart.name.name), chart, program, &svg);
            let boxes: BTreeMap<String, (f64, f64)> = boxes.into_iter().map(|(n, r)| (n, (r.0, r.1))).collect();
            assert_eq!(boxes, plcopen_positions(&xml, &chart.name.name), "{what}: not where the export puts it");
            drawn += 1;
            // Each action written in SFC: marked openable on the chart, and drawn as a chart of its own, in the same
            // notation, its steps those the action holds.
            for action in chart.actions.iter().filter(|a| a.sfc.is_some()) {
                let marked = format!("data-nested=\"{}\"", action.name.name);
                assert!(svg.contains(&marked), "{what}: {} is not marked openable", action.name.name);
                let (inner, inner_program) =
                    baton_proto::back::svg::nested(chart, &report.library, &report.types, &action.name.name)
                        .unwrap_or_else(|| panic!("{what}: {} is not drawn", action.name.name));
                let inner_svg = baton_proto::back::svg::chart(&inner, &inner_program);
                let inner_boxes = check(&format!("{what} ({})", inner.name.name), &inner, &inner_program, &inner_svg);
                let held: BTreeSet<&str> = action
                    .sfc
                    .as_ref()
                    .map_or(BTreeSet::new(), |f| f.steps.iter().map(|s| s.name.name.as_str()).collect());
                assert_eq!(inner_boxes.keys().map(String::as_str).collect::<BTreeSet<_>>(), held, "{what}");
                nested += 1;
            }
            supervised += usize::from(program.steps.iter().any(|s| s.max_ms > 0));
            macros += macro_steps_drawn(&what, chart, &report);
        }
    }
    assert!(drawn >= 40, "only {drawn} charts drawn");
    assert!(macros >= 1, "no macro step was drawn (the conformance chart plcopen_macro_step has one)");
    assert!(supervised >= 1, "no chart with a supervised step was drawn (examples/motion.st has one)");
    assert!(nested >= 1, "no action written in SFC was drawn (the conformance chart nested_action_chart has one)");
}

/// The command as a user runs it: a file, a chart picked from several, and a chart with errors drawing nothing.
fn baton_export_svg_writes_the_picture_and_refuses_what_it_cannot_draw() {
    let dir = tempfile::tempdir().expect("a temp folder");
    let out = dir.path().join("cell.svg");
    let cell = repo("examples/cell.st");
    let run =
        |args: &[&std::ffi::OsStr]| std::process::Command::new(bin("baton")).args(args).output().expect("baton runs");
    let done = run(&["export".as_ref(), "--svg".as_ref(), cell.as_os_str(), "-o".as_ref(), out.as_os_str()]);
    assert!(done.status.success(), "{}", String::from_utf8_lossy(&done.stderr));
    let svg = std::fs::read_to_string(&out).expect("the picture");
    let report = baton_proto::pipeline::check_source(&std::fs::read_to_string(&cell).expect("the chart"));
    let c = &report.charts[0];
    check("examples/cell.st", &c.chart, c.program.as_ref().expect("compiled"), &svg);
    // Both formats at once is a usage error; a chart with errors draws nothing (exit 1) and says why.
    let both = run(&["export".as_ref(), "--svg".as_ref(), "--plcopen".as_ref(), cell.as_os_str()]);
    assert_eq!(both.status.code(), Some(2), "{}", String::from_utf8_lossy(&both.stderr));
    let bad = dir.path().join("bad.st");
    std::fs::write(
        &bad,
        "PROGRAM bad\nINITIAL_STEP A: END_STEP\nTRANSITION FROM A TO Nowhere := TRUE; END_TRANSITION\nEND_PROGRAM\n",
    )
    .expect("write");
    let refused = run(&["export".as_ref(), "--svg".as_ref(), bad.as_os_str()]);
    assert_eq!(refused.status.code(), Some(1));
    assert!(refused.stdout.is_empty(), "drew something: {}", String::from_utf8_lossy(&refused.stdout));
    assert!(String::from_utf8_lossy(&refused.stderr).contains("nothing was drawn"));
}

baton_tests::harness_main!(
    sync every_chart_is_drawn_in_the_notation_where_the_plcopen_export_puts_it,
    sync baton_export_svg_writes_the_picture_and_refuses_what_it_cannot_draw,
);
