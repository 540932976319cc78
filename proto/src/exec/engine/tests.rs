//! The engine alone, one cycle at a time.

use super::*;

#[test]
fn a_second_token_on_a_step_is_a_reported_fault() {
    // Not safe: C can be given a token by B while it holds the one from the divergence. `check_source` refuses
    // such a chart (unless its safety could not be decided and the user accepted that); compiled directly,
    // it shows what the engine does then.
    let src = "PROGRAM p
        INITIAL_STEP A: END_STEP
        TRANSITION FROM A TO (B, C) := TRUE; END_TRANSITION
        STEP B: END_STEP
        STEP C: END_STEP
        TRANSITION FROM B TO C := TRUE; END_TRANSITION
        END_PROGRAM";
    let parsed = crate::front::parser::parse(src);
    let mut diags = Vec::new();
    let compiled = crate::exec::compile::compile(&parsed.charts[0], &parsed.library, &parsed.types, &mut diags);
    assert!(diags.is_empty(), "{diags:?}");
    let mut engine = Engine::new(Arc::new(compiled.program));
    let mut faults = Vec::new();
    for now in [0, 10, 20] {
        engine.handle_cycle(now).expect("cycle");
        while let Some(ev) = engine.poll_event() {
            if let EventKind::Fault(FaultSource::Transition(_), Fault::SecondToken(s)) = ev.kind {
                faults.push((ev.t_ms, s));
            }
        }
    }
    assert_eq!(faults, [(10, StepId(2))]);
    assert_eq!(engine.collisions(), 1);
}

fn compiled(src: &str) -> Arc<Program> {
    let parsed = crate::front::parser::parse(src);
    let mut diags = Vec::new();
    let compiled = crate::exec::compile::compile(&parsed.charts[0], &parsed.library, &parsed.types, &mut diags);
    assert!(diags.is_empty(), "{diags:?}");
    Arc::new(compiled.program)
}

/// Runs cycles every 10 ms from `from` to `to` (inclusive), returning when each transition cleared.
fn cycles(engine: &mut Engine, from: u64, to: u64, fired: &mut Vec<(u64, TransitionId)>) {
    for now in (from..=to).step_by(10) {
        engine.handle_cycle(now).expect("cycle");
        while let Some(ev) = engine.poll_event() {
            if let EventKind::Fire(t) = ev.kind {
                fired.push((ev.t_ms, t));
            }
        }
    }
}

#[test]
fn a_held_step_keeps_its_time_and_its_token_until_released() {
    // B waits for its own time to reach 100 ms; it is held from 50 ms to 250 ms, so its time reaches 100 ms
    // 200 ms later than it would have, at 300 ms (it became active in the first cycle, at 0 ms). C's transition is TRUE at once
    // but C is held as soon as a token reaches it, until released.
    let program = compiled(
        "PROGRAM p
        INITIAL_STEP A: END_STEP
        TRANSITION FROM A TO B := TRUE; END_TRANSITION
        STEP B: END_STEP
        TRANSITION FROM B TO C := B.T >= T#100ms; END_TRANSITION
        STEP C: END_STEP
        TRANSITION FROM C TO D := TRUE; END_TRANSITION
        STEP D: END_STEP
        END_PROGRAM",
    );
    let (b, c) = (program.step_by_name("B").unwrap(), program.step_by_name("C").unwrap());
    let mut engine = Engine::new(Arc::clone(&program));
    let mut fired = Vec::new();
    cycles(&mut engine, 0, 40, &mut fired);
    engine.set_held(50, b, true);
    engine.set_held(50, c, true);
    cycles(&mut engine, 50, 240, &mut fired);
    assert_eq!(engine.step_t(b), 50, "B's time stood still at what it was when held");
    assert_eq!(fired.len(), 1, "only A's transition cleared: {fired:?}");
    engine.set_held(250, b, false);
    cycles(&mut engine, 250, 400, &mut fired);
    assert_eq!(fired.iter().map(|f| f.0).collect::<Vec<_>>(), [0, 300], "C is held: its TRUE transition waits");
    assert!(engine.is_active(c));
    engine.set_held(405, c, false);
    cycles(&mut engine, 410, 420, &mut fired);
    assert_eq!(fired.last().map(|f| f.0), Some(410), "released, C's transition clears at the next cycle");
}
