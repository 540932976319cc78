use uuid::Uuid;

use crate::cluster::journal::records::{frame, NEW_RUN, POLICY, REPORT};
use crate::cluster::runtime::coordinator::{Coordinator, LossPolicy};
use crate::cluster::wire::{
    self, AgentInfo, ChartHash, CtlRequest, DeviceReport, Report, RunId, SetRequest, VarUpdate,
};

use super::journaled::{encode_snapshot, split_snapshot};
use super::*;

#[test]
fn records_round_trip_and_garbage_is_an_error() {
    let run = RunId(Uuid::from_u128(5));
    let entries = [
        Entry { t_ms: 0, record: Record::Policy(LossPolicy::Reassign) },
        Entry { t_ms: 7, record: Record::Cycle },
        Entry { t_ms: 9, record: Record::AgentDown("r1".into()) },
        Entry { t_ms: 10, record: Record::AgentConflict("r1".into(), 2) },
        Entry {
            t_ms: 11,
            record: Record::Set(SetRequest {
                name: "go".into(),
                value: serde_json::Value::Bool(true),
                by: "anna".into(),
                user: None,
            }),
        },
        Entry {
            t_ms: 12,
            record: Record::Vars(VarUpdate {
                run,
                from: "r2".into(),
                incarnation: Uuid::from_u128(9),
                seq: 3,
                vars: Vec::new(),
            }),
        },
        Entry { t_ms: 13, record: Record::Recover },
        Entry { t_ms: 13, record: Record::Stay },
        Entry { t_ms: 13, record: Record::NewRun(RunId(Uuid::from_u128(0x1234_5678_9abc))) },
        Entry {
            t_ms: 14,
            record: Record::Devices(DeviceReport {
                run,
                agent: "cell1".into(),
                incarnation: Uuid::from_u128(9),
                seq: 2,
                down: vec![wire::DeviceDown { binding: 1, message: "no answer".into() }],
            }),
        },
        Entry { t_ms: u64::MAX, record: Record::End { failure: Some("agent `r1` was lost".into()) } },
        Entry { t_ms: 20, record: Record::End { failure: None } },
    ];
    for e in &entries {
        assert_eq!(decode(&encode(e)).as_ref(), Ok(e));
    }
    assert_eq!(decode(&[1, 2, 3]), Err(JournalError::Truncated(3)));
    assert_eq!(decode(&[200, 0, 0, 0, 0, 0, 0, 0, 0]), Err(JournalError::UnknownTag(200)));
    assert!(matches!(decode(&frame(REPORT, 1, b"{not json")), Err(JournalError::Malformed { tag: REPORT, .. })));
    assert!(matches!(decode(&frame(POLICY, 1, &[9])), Err(JournalError::Malformed { .. })));
    assert!(matches!(decode(&frame(NEW_RUN, 1, &[1, 2, 3])), Err(JournalError::Malformed { .. })));
}

#[test]
fn token_ids_are_distinct_and_repeat_for_the_same_run() {
    let run = RunId(Uuid::from_u128(0xfeed));
    let mut a = token_ids(run);
    let mut b = token_ids(run);
    let first: Vec<wire::TokenId> = (0..1000).map(|_| a.next_id()).collect();
    let again: Vec<wire::TokenId> = (0..1000).map(|_| b.next_id()).collect();
    assert_eq!(first, again);
    let distinct: std::collections::BTreeSet<_> = first.iter().collect();
    assert_eq!(distinct.len(), first.len());
    let mut other = token_ids(RunId(Uuid::from_u128(0xbeef)));
    assert_ne!(other.next_id(), first[0]);
}

/// A coordinator of a chart with a step on r1 that writes `n` and waits for input `go`, with r1 up.
fn journaled() -> (Journaled, RunId) {
    let (program, layout) = crate::testing::simulated_cluster::compile(
        "PROGRAM p\nVAR go : BOOL; n : DINT; note : STRING[8]; END_VAR\nINITIAL_STEP A: END_STEP\n\
         TRANSITION FROM A TO B := TRUE; END_TRANSITION\nSTEP B: {agent := 'r1'} Count(N); END_STEP\n\
         TRANSITION FROM B TO C := go; END_TRANSITION\nSTEP C: END_STEP\n\
         ACTION Count: n := n + 1; note := 'x'; END_ACTION\nEND_PROGRAM\n",
    );
    let run = RunId(Uuid::from_u128(7));
    let core = Coordinator::new(program, layout, run, ChartHash("h".into()), token_ids(run));
    let mut j = Journaled::new(core);
    let info = AgentInfo {
        name: "r1".into(),
        roles: Vec::new(),
        lease_ms: 1000,
        incarnation: Uuid::from_u128(1),
        held: Vec::new(),
        pending: Vec::new(),
        skills: None,
    };
    j.agent_up(0, info);
    j.cycle(0);
    j.take_records();
    (j, run)
}

fn value(j: &Journaled, name: &str, v: crate::types::Value) -> wire::VarValue {
    wire::VarValue::new(j.core().program().var_by_name(name).expect("a variable"), v)
}

/// A snapshot says where it stands (records, trace records, time) and restores the coordinator it was taken
/// of; one taken with outputs not yet taken is not made; one of another Baton version or format is refused.
#[test]
fn a_snapshot_restores_where_it_stands_and_only_for_the_baton_that_wrote_it() {
    let (mut j, _) = journaled();
    j.set(20, "go", &serde_json::json!(true)).expect("go");
    assert!(j.snapshot(serde_json::Value::Null).is_none(), "outputs not yet taken");
    let traced = std::iter::from_fn(|| j.poll_output())
        .filter(|o| matches!(o, crate::cluster::runtime::coordinator::CoordOutput::Trace(_)))
        .count() as u64;
    j.cycle(30);
    while j.poll_output().is_some() {}
    j.take_records();
    let bytes = j.snapshot(serde_json::json!({"shell": 1})).expect("nothing pending");
    // The cycle at 30 changed nothing and was not recorded yet: the snapshot records it first, so that it
    // follows the last record exactly.
    let quiet: Vec<Entry> = j.take_records().iter().map(|r| decode(r).expect("a record")).collect();
    assert_eq!(quiet, [Entry { t_ms: 30, record: Record::Cycle }]);
    let records = j.records_counted();
    let (program, layout) = (std::sync::Arc::clone(j.core().program()), std::sync::Arc::clone(j.core().layout()));
    let (again, meta) =
        Journaled::restore(std::sync::Arc::clone(&program), std::sync::Arc::clone(&layout), &bytes).expect("restores");
    assert_eq!((meta.records, meta.last_ms, meta.host), (records, 30, serde_json::json!({"shell": 1})));
    assert!(meta.trace_records >= traced && traced > 0, "{} trace records, {traced} taken before", meta.trace_records);
    assert_eq!(again.core().snapshot(), j.core().snapshot(), "the same coordinator");
    // Another version's snapshot: its meta rewritten, the state as it was.
    let (old, state) = split_snapshot(&bytes).expect("a snapshot");
    let older = encode_snapshot(&SnapshotMeta { baton: "0.0.1".into(), ..old }, state);
    let err = Journaled::restore(program, layout, &older).err().expect("refused");
    assert!(
        err.contains("was written by Baton 0.0.1") && err.contains("resume it with the Baton that wrote it"),
        "{err}"
    );
}

/// A run that stays, completes, is reset and runs again: its journal, replayed into a new coordinator, makes
/// the same trace and ends in the same run, state and situation.
#[test]
fn a_reset_is_replayed_into_the_same_runs_and_trace() {
    use crate::cluster::runtime::coordinator::CoordOutput;
    use crate::cluster::runtime::packml::State;
    let (program, layout) = crate::testing::simulated_cluster::compile(
        "PROGRAM p\nVAR go : BOOL; n : DINT; END_VAR\nINITIAL_STEP A: Count(N); END_STEP\n\
         TRANSITION FROM A TO B := go; END_TRANSITION\nSTEP B: END_STEP\n\
         ACTION Count: n := n + 1; END_ACTION\nEND_PROGRAM\n",
    );
    let first = RunId(Uuid::from_u128(7));
    let fresh = || {
        let (p, l) = (std::sync::Arc::clone(&program), std::sync::Arc::clone(&layout));
        Coordinator::new(p, l, first, ChartHash("h".into()), token_ids(first))
    };
    let trace = |j: &mut Journaled| {
        std::iter::from_fn(|| j.poll_output())
            .filter_map(|o| match o {
                CoordOutput::Trace(t) => Some(t),
                _ => None,
            })
            .collect::<Vec<_>>()
    };
    let ctl = |command: &str| CtlRequest {
        command: command.into(),
        reason: "shift change".into(),
        by: "op".into(),
        ..Default::default()
    };
    let mut live = Journaled::new(fresh());
    live.stay(0);
    live.set(0, "go", &serde_json::json!(true)).expect("go");
    for t in [10, 20, 30] {
        live.cycle(t);
    }
    assert_eq!(live.core().run_state(), State::Complete);
    live.command(40, ctl("reset")).expect("reset");
    let second = RunId(Uuid::from_u128(8));
    assert!(live.core().wants_new_run());
    live.new_run(40, second);
    live.command(50, ctl("start")).expect("start");
    for t in [60, 70] {
        live.cycle(t);
    }
    let n = program.var_by_name("n").expect("n");
    let counted = live.core().value(n);
    let live_trace = trace(&mut live);
    assert!(live_trace
        .iter()
        .any(|r| r.event == crate::exec::trace::TraceEvent::NewRun && r.message == Some(second.key())));
    let records = live.take_records();
    let mut again = Journaled::new(fresh());
    again.replay(records.iter().map(Vec::as_slice)).expect("the records decode");
    assert_eq!(trace(&mut again), live_trace);
    assert_eq!((again.core().run(), again.core().run_state()), (second, State::Execute));
    assert_eq!(again.core().value(n), counted);
}

#[test]
fn what_the_coordinator_refuses_is_not_journaled() {
    use crate::types::Value;
    let (mut j, run) = journaled();
    let update = |from: &str, incarnation: u128, seq: u64, vars: Vec<wire::VarValue>| VarUpdate {
        run,
        from: from.into(),
        incarnation: Uuid::from_u128(incarnation),
        seq,
        vars,
    };
    // A megabyte from an agent the coordinator does not know, 50 times; one from r1's replaced or made-up
    // process; one of another run; a value r1 does not write; a string longer than its variable: nothing
    // to record.
    let big = value(&j, "note", Value::Str(std::sync::Arc::new("x".repeat(1_000_000))));
    for seq in 0..50 {
        j.vars(10, "ghost", &wire::encode(&update("ghost", 9, seq, vec![big.clone()]))).expect("decodes");
    }
    j.vars(11, "r1", &wire::encode(&update("r1", 2, 1, vec![value(&j, "n", Value::Int(5))]))).expect("decodes");
    let mut other = update("r1", 1, 1, vec![value(&j, "n", Value::Int(5))]);
    other.run = RunId(Uuid::from_u128(8));
    j.vars(12, "r1", &wire::encode(&other)).expect("decodes");
    j.vars(13, "r1", &wire::encode(&update("r1", 1, 1, vec![value(&j, "go", Value::Bool(true))]))).expect("decodes");
    j.vars(14, "r1", &wire::encode(&update("r1", 1, 1, vec![big.clone()]))).expect("decodes");
    assert!(j.take_records().is_empty(), "refused updates were journaled");
    assert_eq!(j.core().value(j.core().program().var_by_name("go").expect("go")), Value::Bool(false));
    // A set the coordinator refuses is not journaled either; one it takes is.
    assert!(j.set(15, "n", &serde_json::json!(3)).is_err());
    assert!(j.set(15, "nothing", &serde_json::json!(3)).is_err());
    assert!(j.take_records().is_empty());
    assert!(j.set(16, "go", &serde_json::json!(false)).is_ok());
    assert_eq!(j.take_records().len(), 1);
    // An update that mixes what r1 writes with what it does not: only r1's own value is recorded, once.
    let mixed = update(
        "r1",
        1,
        2,
        vec![value(&j, "n", Value::Int(7)), value(&j, "go", Value::Bool(true)), value(&j, "n", Value::Int(8))],
    );
    j.vars(17, "r1", &wire::encode(&mixed)).expect("decodes");
    let records = j.take_records();
    assert_eq!(records.len(), 1);
    let Ok(Entry { record: Record::Vars(kept), .. }) = decode(&records[0]) else { panic!("a Vars record") };
    assert_eq!(kept.vars, vec![value(&j, "n", Value::Int(7))]);
    // The same update again is old news: not recorded.
    j.vars(18, "r1", &wire::encode(&mixed)).expect("decodes");
    assert!(j.take_records().is_empty());
    // r2 publishing on its own key an update that says it is r1's: dropped, not recorded, nothing taken.
    let claimed = update("r1", 1, 3, vec![value(&j, "n", Value::Int(9))]);
    j.vars(19, "r2", &wire::encode(&claimed)).expect("decodes");
    assert!(j.take_records().is_empty());
    assert_eq!(j.core().value(j.core().program().var_by_name("n").expect("n")), Value::Int(7));
}

#[test]
fn reports_held_ahead_of_a_gap_are_bounded_by_bytes_and_duplicates_are_not_journaled() {
    use crate::cluster::wire::{AgentEvent, AgentEventKind, ToAgent};
    use crate::limits::REPORTS_AHEAD_BYTES_MAX;
    let (mut j, run) = journaled();
    let mut token = None;
    while let Some(out) = j.poll_output() {
        if let crate::cluster::runtime::coordinator::CoordOutput::Send {
            msg: ToAgent::Dispatch { token: t, .. }, ..
        } = out
        {
            token = Some(t);
        }
    }
    let token = token.expect("B was dispatched to r1");
    let report = |seq: u32, message: String| Report {
        run,
        agent: "r1".into(),
        incarnation: Uuid::from_u128(1),
        token,
        epoch: 1,
        seq,
        events: vec![AgentEvent { dt_ms: 1, kind: AgentEventKind::Fault { message } }],
        vars: Vec::new(),
        vars_seq: 0,
        done: false,
    };
    // Reports ahead of the missing seq 0, each 100 KB: those within REPORTS_AHEAD_BYTES_MAX are held (and
    // recorded, since they will apply), the rest are dropped unrecorded (the agent sends them again).
    let mut recorded = 0;
    for seq in 1..100 {
        j.report(20, "r1", &wire::encode(&report(seq, "f".repeat(100_000)))).expect("decodes");
        recorded += j.take_records().len();
    }
    assert!(recorded > 0 && recorded * 100_000 <= REPORTS_AHEAD_BYTES_MAX, "{recorded} held");
    // The same one ahead again, and one from another process: not recorded.
    j.report(21, "r1", &wire::encode(&report(1, "f".into()))).expect("decodes");
    let mut forged = report(0, "f".into());
    forged.incarnation = Uuid::from_u128(2);
    j.report(21, "r1", &wire::encode(&forged)).expect("decodes");
    assert!(j.take_records().is_empty());
    // On r2's key, saying it is r1's: dropped before anything looks at it.
    j.report(21, "r2", &wire::encode(&report(0, "f".into()))).expect("decodes");
    assert!(j.take_records().is_empty());
    // The one it waits for applies, and so do those held.
    j.report(22, "r1", &wire::encode(&report(0, "f".into()))).expect("decodes");
    assert_eq!(j.take_records().len(), 1);
    // Now old: acknowledged again, not recorded.
    j.report(23, "r1", &wire::encode(&report(0, "f".into()))).expect("decodes");
    assert!(j.take_records().is_empty());
}

#[test]
fn the_program_pin_changes_with_what_the_numbers_mean() {
    let pin = |src: &str| {
        let (program, layout) = crate::testing::simulated_cluster::compile(src);
        program_pin(&program, &layout)
    };
    let chart = |vars: &str, placed: &str| {
        format!(
            "PROGRAM p\nVAR {vars} END_VAR\nINITIAL_STEP A: END_STEP\nTRANSITION FROM A TO B := go; \
             END_TRANSITION\nSTEP B: {placed} END_STEP\nEND_PROGRAM\n"
        )
    };
    let base = chart("go : BOOL; n : INT;", "");
    assert_eq!(pin(&base), pin(&base), "the same compilation, the same pin");
    // Variables numbered the other way round, a type changed, a step placed elsewhere: each moves the pin.
    for other in [
        chart("n : INT; go : BOOL;", ""),
        chart("go : BOOL; n : DINT;", ""),
        chart("go : BOOL; n : INT;", "{agent := 'r1'}"),
    ] {
        assert_ne!(pin(&base), pin(&other), "{other}");
    }
}
