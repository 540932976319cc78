//! A chart drawn in the notation of IEC 61131-3 (and IEC 60848, GRAFCET), as SVG: steps as boxes, the initial
//! ones doubled; transitions as bars with their conditions; actions beside their steps, each with its qualifier
//! (and time); a selection divergence and convergence as a single line, a simultaneous one as a double line; a
//! transition to a step on its own row or above as a jump arrow with the step's name. Everything is where the
//! PLCopen export puts it (`back::diagram`).
//!
//! `baton export --svg` writes it; a page that shows a run finds each part by its data attributes —
//! `data-step`, `data-transition` (the names the trace uses), `data-action` — and marks the live ones with a
//! class (`active`, `held`, …), which the drawing leaves to the page's style sheet.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write;

use crate::back::diagram::{Diagram, MARGIN, STEP_H, STEP_W};
use crate::back::plcopen::esc;
use crate::back::st;
use crate::exec::program::{Program, StepId, TransitionId};
use crate::front::model::{Chart, Duration, FbDef, Ident, MacroStep, Step, Transition, TypeDef};

/// The action block's cells.
const QUALIFIER_W: i64 = 36;
const ACTION_W: i64 = 164;
const ACTION_H: i64 = 20;
/// How far the action block stands right of its step.
const ACTION_GAP: i64 = 30;
/// From the middle of a line of text to its baseline (12 px type).
const BASELINE: i64 = 4;
/// A condition longer than this is cut (its whole text is the element's title).
const CONDITION_CHARS: usize = 48;

/// The chart as a standalone SVG document.
pub fn chart(chart: &Chart, program: &Program) -> String {
    let diagram = Diagram::lay_out(program);
    let mut body = String::new();
    for t in 0..program.transitions.len() {
        transition(&mut body, chart, program, &diagram, TransitionId(t as u32));
    }
    for s in 0..program.steps.len() {
        step(&mut body, chart, program, &diagram, StepId(s as u32));
    }
    let (width, height) = extent(program, &diagram);
    let mut out = String::new();
    let _ = writeln!(
        out,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" class=\"sfc\" data-chart=\"{}\" width=\"{width}\" height=\"{height}\" \
         viewBox=\"0 0 {width} {height}\" font-family=\"sans-serif\" font-size=\"12\">",
        esc(&chart.name.name)
    );
    let _ = writeln!(out, "<title>{}</title>", esc(&chart.name.name));
    out.push_str(&body);
    out.push_str("</svg>\n");
    out
}

/// The chart of `action`, an action of `chart` written in SFC (IEC 61131-3 lets an action be a chart), as a chart
/// of its own, for `chart` to draw: its steps named as the trace names them (`Action.Step.X` is each one's
/// variable). `None` for an action that is not a chart. Its conditions may read the POU's own steps, which the nested
/// chart lacks: what does not resolve is still drawn as written.
pub fn nested(chart: &Chart, library: &[FbDef], types: &[TypeDef], action: &str) -> Option<(Chart, Program)> {
    let found = chart.actions.iter().find(|a| a.name.name == action)?;
    let sfc = found.sfc.as_deref()?;
    let mut inner = chart.clone();
    inner.name.name = format!("{}.{}", chart.name.name, found.name.name);
    inner.steps.clone_from(&sfc.steps);
    inner.transitions.clone_from(&sfc.transitions);
    // Its steps are now the chart's: the action that held them is no chart to compile beside them.
    inner.actions.retain(|a| a.name.key() != found.name.key());
    let mut diagnostics = Vec::new();
    let compiled = crate::exec::compile::compile(&inner, library, types, &mut diagnostics);
    compiled.net_ok.then_some((inner, compiled.program))
}

/// The chart as it is drawn, each macro step as one step in place of its body (IEC 60848's macro-step): of the whole
/// chart (`within` None), or of the body of macro step `within` (its entry step initial, for the drawing), whose own
/// nested macro steps are drawn as one step each too. `None` for a chart without macro steps, or a name that is
/// none of them. The transitions keep the names the trace gives them (`Start->Heat` for the one drawn from Start
/// to macro step Dose).
pub fn collapsed(
    chart: &Chart,
    library: &[FbDef],
    types: &[TypeDef],
    within: Option<&str>,
) -> Option<(Chart, Program)> {
    if chart.macros.is_empty() {
        return None;
    }
    let body = match within {
        Some(name) => Some(chart.macros.iter().find(|m| m.name.name == name)?),
        None => None,
    };
    let scope: BTreeSet<String> = match body {
        Some(m) => m.steps.iter().map(Ident::key).collect(),
        None => chart.steps.iter().map(|s| s.name.key()).collect(),
    };
    // The macro steps drawn as one step: in scope, and in no other such macro step.
    let inside = |m: &MacroStep| body.is_none_or(|b| b.name.key() != m.name.key()) && scope.contains(&m.entry.key());
    let candidates: Vec<&MacroStep> = chart.macros.iter().filter(|m| inside(m)).collect();
    let outermost: Vec<&MacroStep> = candidates
        .iter()
        .filter(|m| {
            !candidates.iter().any(|o| o.name.key() != m.name.key() && o.steps.iter().any(|s| s.key() == m.entry.key()))
        })
        .copied()
        .collect();
    let mut of_step: BTreeMap<String, &MacroStep> = BTreeMap::new();
    for m in &outermost {
        for s in &m.steps {
            of_step.insert(s.key(), m);
        }
    }
    let mut drawn = chart.clone();
    drawn.steps = chart
        .steps
        .iter()
        .filter(|s| scope.contains(&s.name.key()))
        .filter_map(|s| match of_step.get(&s.name.key()) {
            Some(m) if m.entry.key() == s.name.key() => {
                Some(Step { name: m.name.clone(), associations: Vec::new(), pragmas: Vec::new(), ..s.clone() })
            }
            Some(_) => None,
            None => {
                Some(Step { initial: s.initial || body.is_some_and(|b| b.entry.key() == s.name.key()), ..s.clone() })
            }
        })
        .collect();
    let shown = |step: &Ident| of_step.get(&step.key()).map_or_else(|| step.clone(), |m| m.name.clone());
    let kept: Vec<&Transition> = chart
        .transitions
        .iter()
        .filter(|t| t.from.iter().chain(&t.to).all(|s| scope.contains(&s.key())))
        // A macro step's own transitions are inside it.
        .filter(|t| {
            let of = |s: &Ident| of_step.get(&s.key()).map(|m| m.name.key());
            let within_one = t.from.iter().chain(&t.to).map(of).collect::<BTreeSet<_>>();
            !(within_one.len() == 1 && within_one.iter().all(Option::is_some))
        })
        .collect();
    // Named as the trace names them: from the steps of the bodies, not the macro steps drawn in their place.
    let names: Vec<String> = kept.iter().map(|t| t.display_name()).collect();
    drawn.transitions = kept
        .into_iter()
        .map(|t| Transition {
            from: t.from.iter().map(shown).collect(),
            to: t.to.iter().map(shown).collect(),
            ..t.clone()
        })
        .collect();
    drawn.macros = outermost.into_iter().cloned().collect();
    if let Some(b) = body {
        drawn.name.name = format!("{}.{}", chart.name.name, b.name.name);
    }
    let mut diagnostics = Vec::new();
    let mut compiled = crate::exec::compile::compile(&drawn, library, types, &mut diagnostics);
    for (info, name) in compiled.program.transitions.iter_mut().zip(names) {
        info.name = name;
    }
    compiled.net_ok.then_some((drawn, compiled.program))
}

/// The drawing's width and height: past the rightmost action block and below the lowest bar and its jumps.
fn extent(program: &Program, diagram: &Diagram) -> (i64, i64) {
    let steps = (0..program.steps.len()).map(|s| diagram.step_xy(StepId(s as u32)));
    let (mut right, mut bottom) = (0, 0);
    for (x, y) in steps {
        right = right.max(x + STEP_W + ACTION_GAP + QUALIFIER_W + ACTION_W);
        bottom = bottom.max(y + STEP_H);
    }
    for t in 0..program.transitions.len() {
        let (x, y) = diagram.transition_xy(program, TransitionId(t as u32));
        right = right.max(x + STEP_W / 2 + 20 + 7 * CONDITION_CHARS as i64);
        bottom = bottom.max(y + 80);
    }
    (right + MARGIN, bottom + MARGIN)
}

/// The centre of step `s`'s box, horizontally.
fn centre_x(diagram: &Diagram, s: StepId) -> i64 {
    diagram.step_xy(s).0 + STEP_W / 2
}

/// Step `s`: its box (doubled if initial), its name, its action block, and the line from its box to the
/// divergence or bar below (a selection divergence as a single line across its branches).
fn step(out: &mut String, chart: &Chart, program: &Program, diagram: &Diagram, s: StepId) {
    let info = &program.steps[s.index()];
    let (x, y) = diagram.step_xy(s);
    let class = if info.initial { "step initial" } else { "step" };
    let macro_step = chart.macros.iter().find(|m| m.name.name == info.name);
    // A macro step is marked, with what it stands for: its body's steps, which the trace and the run's status name.
    let (marked, stands_for) = match macro_step {
        Some(m) => {
            let steps: Vec<&str> = m.steps.iter().map(|s| s.name.as_str()).collect();
            (" macro", format!(" data-macro-steps=\"{}\"", esc(&steps.join(","))))
        }
        None => ("", String::new()),
    };
    let _ = writeln!(out, "<g class=\"{class}{marked}\" data-step=\"{}\"{stands_for}>", esc(&info.name));
    let pragmas: Vec<&str> = info.pragmas.iter().map(|p| p.text.as_str()).collect();
    let title =
        if pragmas.is_empty() { info.name.clone() } else { format!("{} {{{}}}", info.name, pragmas.join("} {")) };
    let _ = writeln!(out, "<title>{}</title>", esc(&title));
    let _ = writeln!(out, "<rect class=\"box\" x=\"{x}\" y=\"{y}\" width=\"{STEP_W}\" height=\"{STEP_H}\" fill=\"white\" stroke=\"black\"/>");
    if info.initial {
        let _ = writeln!(
            out,
            "<rect class=\"inner\" x=\"{}\" y=\"{}\" width=\"{}\" height=\"{}\" fill=\"none\" stroke=\"black\"/>",
            x + 3,
            y + 3,
            STEP_W - 6,
            STEP_H - 6
        );
    }
    if macro_step.is_some() {
        // IEC 60848's macro-step: the box with a line across its top and its bottom.
        for ly in [y + 4, y + STEP_H - 4] {
            let _ = writeln!(
                out,
                "<line class=\"macro-mark\" x1=\"{x}\" y1=\"{ly}\" x2=\"{}\" y2=\"{ly}\" stroke=\"black\"/>",
                x + STEP_W
            );
        }
    }
    let _ = writeln!(
        out,
        "<text x=\"{}\" y=\"{}\" text-anchor=\"middle\">{}</text>",
        x + STEP_W / 2,
        y + STEP_H / 2 + BASELINE,
        esc(&info.name)
    );
    step_time(out, program, s, x, y);
    actions(out, chart, s, x, y);
    // Down to what follows: one bar, or a selection divergence across the branches.
    let leaving = program.outgoing(s);
    if !leaving.is_empty() {
        let cx = x + STEP_W / 2;
        let split = y + STEP_H + 20;
        let _ = writeln!(
            out,
            "<line class=\"arc\" x1=\"{cx}\" y1=\"{}\" x2=\"{cx}\" y2=\"{split}\" stroke=\"black\"/>",
            y + STEP_H
        );
        if leaving.len() > 1 {
            let xs: Vec<i64> = diagram.branch_xs(program, s).iter().map(|bx| bx + STEP_W / 2).chain([cx]).collect();
            let (first, last) = (xs.iter().min().copied().unwrap_or(cx), xs.iter().max().copied().unwrap_or(cx));
            let _ = writeln!(
                out,
                "<line class=\"selection divergence\" x1=\"{first}\" y1=\"{split}\" x2=\"{last}\" y2=\"{split}\" stroke=\"black\"/>"
            );
        }
    }
    out.push_str("</g>\n");
}

/// Below step `s`'s box, left of the arc: its time while active (`S.T`, the page writes it) and its supervision
/// times (`{min_ms}`, `{max_ms}`), as S7-GRAPH shows them beside a step. The element carries the limits in ms
/// (`data-min-ms`, `data-max-ms`) so that a page can mark a step past its limit.
fn step_time(out: &mut String, program: &Program, s: StepId, x: i64, y: i64) {
    let info = &program.steps[s.index()];
    let mut limits = Vec::new();
    if info.min_ms > 0 {
        limits.push(format!("≥ {}", short_ms(info.min_ms)));
    }
    if info.max_ms > 0 {
        limits.push(format!("≤ {}", short_ms(info.max_ms)));
    }
    let _ = writeln!(
        out,
        "<text class=\"time\" x=\"{}\" y=\"{}\" font-size=\"10\" fill=\"#555\" data-min-ms=\"{}\" data-max-ms=\"{}\">{}</text>",
        x + 2,
        y + STEP_H + 13,
        info.min_ms,
        info.max_ms,
        esc(&limits.join(" "))
    );
}

/// A time as people read it at a glance: `200 ms`, `5 s`, `1.5 s`, `2 min`.
pub fn short_ms(ms: u64) -> String {
    if ms < 1000 {
        format!("{ms} ms")
    } else if ms.is_multiple_of(60_000) {
        format!("{} min", ms / 60_000)
    } else if ms.is_multiple_of(1000) {
        format!("{} s", ms / 1000)
    } else {
        format!("{:.1} s", ms as f64 / 1000.0)
    }
}

/// Step `s`'s action block, right of its box: a row per association, its qualifier (and time) and its action.
fn actions(out: &mut String, chart: &Chart, s: StepId, x: i64, y: i64) {
    let associations = &chart.steps[s.index()].associations;
    if associations.is_empty() {
        return;
    }
    let (bx, mid) = (x + STEP_W + ACTION_GAP, y + STEP_H / 2);
    let qualifiers: Vec<String> = associations
        .iter()
        .map(|a| {
            let time = match &a.duration {
                Some(Duration::Literal { ms, .. }) => format!(" T#{ms}ms"),
                Some(Duration::Var(v)) => format!(" {}", v.name),
                None => String::new(),
            };
            format!("{:?}{time}", a.qualifier)
        })
        .collect();
    // The qualifier cell as wide as its longest text (7 px a character), the name cell as the block's rest.
    let widest = qualifiers.iter().map(|q| q.chars().count() as i64 * 7 + 12).max().unwrap_or(0);
    let qw = widest.max(QUALIFIER_W);
    let _ = writeln!(
        out,
        "<line class=\"link\" x1=\"{}\" y1=\"{mid}\" x2=\"{bx}\" y2=\"{mid}\" stroke=\"black\"/>",
        x + STEP_W
    );
    for (i, (a, qualifier)) in associations.iter().zip(qualifiers).enumerate() {
        let ry = y + i as i64 * ACTION_H;
        // An action written in SFC is a chart of its own, which a page opens (`nested`).
        let nested = chart.actions.iter().any(|x| x.name.key() == a.action.key() && x.sfc.is_some());
        if nested {
            let name = esc(&a.action.name);
            let _ = writeln!(out, "<g class=\"action nested\" data-action=\"{name}\" data-nested=\"{name}\">");
            let _ = writeln!(out, "<title>{name}: a chart of its own (SFC)</title>");
        } else {
            let _ = writeln!(out, "<g class=\"action\" data-action=\"{}\">", esc(&a.action.name));
        }
        let _ = writeln!(
            out,
            "<rect x=\"{bx}\" y=\"{ry}\" width=\"{qw}\" height=\"{ACTION_H}\" fill=\"white\" stroke=\"black\"/>\
             <rect x=\"{}\" y=\"{ry}\" width=\"{}\" height=\"{ACTION_H}\" fill=\"white\" stroke=\"black\"/>",
            bx + qw,
            (QUALIFIER_W + ACTION_W - qw).max(ACTION_W / 2)
        );
        let _ = writeln!(
            out,
            "<text class=\"qualifier\" x=\"{}\" y=\"{}\" text-anchor=\"middle\">{}</text>\
             <text class=\"name\" x=\"{}\" y=\"{}\">{}</text>",
            bx + qw / 2,
            ry + ACTION_H / 2 + BASELINE,
            esc(&qualifier),
            bx + qw + 6,
            ry + ACTION_H / 2 + BASELINE,
            esc(&a.action.name)
        );
        out.push_str("</g>\n");
    }
}

/// Transition `t`: its bar and condition, the lines from its sources (through a simultaneous convergence's
/// double line where it has several) and to its targets (through a simultaneous divergence's double line; a
/// target on the sources' row or above as a jump arrow).
fn transition(out: &mut String, chart: &Chart, program: &Program, diagram: &Diagram, t: TransitionId) {
    let (x, y) = diagram.transition_xy(program, t);
    let bx = x + STEP_W / 2;
    let sources = program.sources(t);
    let targets = program.targets(t);
    let name = &program.transitions[t.index()].name;
    let _ = writeln!(out, "<g class=\"transition\" data-transition=\"{}\">", esc(name));
    let written = &chart.transitions[t.index()];
    let condition = match &written.name {
        Some(n) => n.name.clone(),
        None => st::expr(&written.condition),
    };
    let _ = writeln!(out, "<title>{}: {}</title>", esc(name), esc(&condition));
    // From the sources: each step's line (or its branch of a selection divergence) down to the bar, or to a
    // double line above it.
    let from = |s: StepId| {
        let branch = program.outgoing(s).iter().position(|&u| u == t).unwrap_or(0);
        let (_, sy) = diagram.step_xy(s);
        (diagram.branch_xs(program, s)[branch] + STEP_W / 2, sy + STEP_H + 20)
    };
    if sources.len() > 1 {
        let join = y - 30;
        let xs: Vec<i64> = sources.iter().map(|&s| from(s).0).chain([bx]).collect();
        double(out, "simultaneous convergence", &xs, join);
        for &s in sources {
            let (fx, fy) = from(s);
            path(out, &[(fx, fy), (fx, join - 2)]);
        }
        path(out, &[(bx, join + 2), (bx, y)]);
    } else if let Some(&s) = sources.first() {
        let (fx, fy) = from(s);
        path(out, &[(fx, fy), (fx, y)]);
    }
    let _ = writeln!(
        out,
        "<line class=\"bar\" x1=\"{}\" y1=\"{y}\" x2=\"{}\" y2=\"{y}\" stroke=\"black\" stroke-width=\"4\"/>",
        bx - 12,
        bx + 12
    );
    let shown: String = if condition.chars().count() > CONDITION_CHARS {
        condition.chars().take(CONDITION_CHARS - 1).chain(['…']).collect()
    } else {
        condition
    };
    let _ = writeln!(out, "<text class=\"condition\" x=\"{}\" y=\"{}\">{}</text>", bx + 20, y + BASELINE, esc(&shown));
    // To the targets.
    let split = if targets.len() > 1 {
        let split = y + 30;
        let xs: Vec<i64> = targets
            .iter()
            .filter(|&&u| !diagram.is_jump(program, t, u))
            .map(|&u| centre_x(diagram, u))
            .chain([bx])
            .collect();
        path(out, &[(bx, y), (bx, split - 2)]);
        double(out, "simultaneous divergence", &xs, split);
        split + 2
    } else {
        y
    };
    for (i, &u) in targets.iter().enumerate() {
        let ux = if targets.len() > 1 { centre_x(diagram, u) } else { bx };
        if diagram.is_jump(program, t, u) {
            // A jump: an arrow down from the bar (or its branch of the double line), with the step's name.
            let jx = if targets.len() > 1 { bx + i as i64 * 24 } else { bx };
            let tip = split + 40;
            path(out, &[(jx, split), (jx, tip - 8)]);
            let _ = writeln!(
                out,
                "<g class=\"jump\" data-target=\"{0}\"><polygon points=\"{1},{2} {3},{2} {4},{5}\" fill=\"black\"/>\
                 <text x=\"{6}\" y=\"{7}\">{0}</text></g>",
                esc(&program.steps[u.index()].name),
                jx - 6,
                tip - 8,
                jx + 6,
                jx,
                tip,
                jx + 10,
                tip + BASELINE
            );
            continue;
        }
        let (tx, ty) = diagram.step_xy(u);
        let tcx = tx + STEP_W / 2;
        let incoming = (0..program.transitions.len())
            .filter(|&o| program.targets(TransitionId(o as u32)).contains(&u))
            .filter(|&o| !diagram.is_jump(program, TransitionId(o as u32), u))
            .count();
        if incoming > 1 {
            // Several forward arcs into one step: a selection convergence, a single line above it.
            let merge = ty - 30;
            path(out, &[(ux, split), (ux, merge), (tcx, merge), (tcx, ty)]);
            let (lo, hi) = (ux.min(tcx), ux.max(tcx));
            let _ = writeln!(
                out,
                "<line class=\"selection convergence\" x1=\"{lo}\" y1=\"{merge}\" x2=\"{hi}\" y2=\"{merge}\" stroke=\"black\"/>"
            );
        } else {
            let bend = ty - 15;
            path(out, &[(ux, split), (ux, bend), (tcx, bend), (tcx, ty)]);
        }
    }
    out.push_str("</g>\n");
}

/// A double line across every x of `xs` (never empty: the bar's is among them) at `y`: a simultaneous divergence
/// or convergence.
fn double(out: &mut String, class: &str, xs: &[i64], y: i64) {
    let (x1, x2) = (xs.iter().min().copied().unwrap_or(0), xs.iter().max().copied().unwrap_or(0));
    let _ = writeln!(
        out,
        "<g class=\"{class}\"><line x1=\"{0}\" y1=\"{2}\" x2=\"{1}\" y2=\"{2}\" stroke=\"black\"/>\
         <line x1=\"{0}\" y1=\"{3}\" x2=\"{1}\" y2=\"{3}\" stroke=\"black\"/></g>",
        x1 - 10,
        x2 + 10,
        y - 2,
        y + 2
    );
}

/// A line through `points`, as an arc of the net.
fn path(out: &mut String, points: &[(i64, i64)]) {
    let points: Vec<String> = points.iter().map(|(x, y)| format!("{x},{y}")).collect();
    let _ = writeln!(out, "<polyline class=\"arc\" points=\"{}\" fill=\"none\" stroke=\"black\"/>", points.join(" "));
}
