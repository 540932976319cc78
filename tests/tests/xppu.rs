//! The xPPU (TUM's extended Pick-and-Place Unit), scenario 1 as CODESYS exports it (not in the shared corpus:
//! `baton_tests::xppu_scenario_1` says where to get it), run against a model of its plant: Baton's engine scans
//! the chart every 10 ms (the project's task cycle), and between scans the model moves the cylinders, the turning
//! table, the vacuum and the workpieces as the outputs command, and sets the sensors the inputs read. What is
//! expected comes from the machine, not from Baton: after the start button, a workpiece in the magazine is pushed
//! out by the separator, picked up by the crane at the stack, turned to the ramp and put down there; nothing raises
//! the emergency path.

use std::sync::Arc;

use baton_proto::exec::engine::{Engine, EventKind, Input};
use baton_proto::exec::program::{Program, VarId};
use baton_proto::types::Value;

/// A cylinder's stroke, the table's turn between the stack and the ramp, and the vacuum's build-up, in ms.
const STROKE_MS: i64 = 300;
const TURN_MS: i64 = 1500;
const VACUUM_MS: i64 = 100;
const CYCLE_MS: u64 = 10;

/// A monostable cylinder: it travels while its valve says, and its end switches tell where it is.
struct Cylinder {
    valve: VarId,
    extended: VarId,
    retracted: VarId,
    /// 0 retracted, `STROKE_MS` extended.
    at: i64,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Piece {
    Magazine,
    PickUp,
    Gripper,
    Ramp,
}

struct Plant {
    lift: Cylinder,
    separator: Cylinder,
    clockwise: VarId,
    counterclockwise: VarId,
    at_stack: VarId,
    at_ramp: VarId,
    /// 0 at the ramp, `TURN_MS` at the stack.
    table: i64,
    vacuum: VarId,
    taken_in: VarId,
    /// How long the vacuum has been on with a piece under the cup.
    sucking: i64,
    piece_at_pick_up: VarId,
    piece: Piece,
}

fn var(p: &Program, name: &str) -> VarId {
    p.var_by_name(name).unwrap_or_else(|| panic!("the xPPU has no variable {name}"))
}

impl Plant {
    fn new(p: &Program) -> Plant {
        let cylinder = |prefix: &str| Cylinder {
            valve: var(p, &format!("{prefix}.DO_Extend")),
            extended: var(p, &format!("{prefix}.DI_Extended")),
            retracted: var(p, &format!("{prefix}.DI_Retracted")),
            at: 0,
        };
        Plant {
            lift: cylinder("Crane.LiftingCylinder"),
            separator: cylinder("Stack.Seperator"),
            clockwise: var(p, "Crane.Table.Motor.DO_TurnClockwise"),
            counterclockwise: var(p, "Crane.Table.Motor.DO_TurnCounterclockwise"),
            at_stack: var(p, "Crane.Table.AtStack.DI_SwitchTrue"),
            at_ramp: var(p, "Crane.Table.AtRamp.DI_SwitchTrue"),
            table: 0,
            vacuum: var(p, "Crane.Gripper.Valve.DO_VacuumOn"),
            taken_in: var(p, "Crane.Gripper.VacuumSwitch.DI_TakenIn"),
            sucking: 0,
            piece_at_pick_up: var(p, "Stack.WPAvailable.DI_SwitchTrue"),
            piece: Piece::Magazine,
        }
    }

    /// `dt` ms of the machine under the outputs the last scan left.
    fn advance(&mut self, e: &Engine, dt: i64) {
        let on = |v: VarId| e.value(v) == Value::Bool(true);
        for c in [&mut self.lift, &mut self.separator] {
            c.at = if on(c.valve) { (c.at + dt).min(STROKE_MS) } else { (c.at - dt).max(0) };
        }
        match (on(self.clockwise), on(self.counterclockwise)) {
            (true, false) => self.table = (self.table + dt).min(TURN_MS),
            (false, true) => self.table = (self.table - dt).max(0),
            _ => {}
        }
        let at_stack = self.table == TURN_MS;
        let at_ramp = self.table == 0;
        let down = self.lift.at == STROKE_MS;
        // The separator pushes the magazine's piece out to the pick-up place.
        if self.piece == Piece::Magazine && self.separator.at == STROKE_MS {
            self.piece = Piece::PickUp;
        }
        // The cup, down on a piece at the stack, takes it once the vacuum has built up; off, it lets it go.
        if on(self.vacuum) {
            if self.piece == Piece::PickUp && down && at_stack {
                self.sucking += dt;
                if self.sucking >= VACUUM_MS {
                    self.piece = Piece::Gripper;
                }
            }
        } else {
            self.sucking = 0;
            if self.piece == Piece::Gripper {
                assert!(
                    down && at_ramp,
                    "the crane let the piece fall: table at {}, lift at {}",
                    self.table,
                    self.lift.at
                );
                self.piece = Piece::Ramp;
            }
        }
    }

    fn sense(&self, e: &mut Engine) {
        let mut set = |v: VarId, b: bool| e.handle(Input::Set(v, Value::Bool(b))).expect("a sensor is a BOOL");
        for c in [&self.lift, &self.separator] {
            set(c.extended, c.at == STROKE_MS);
            set(c.retracted, c.at == 0);
        }
        set(self.at_stack, self.table == TURN_MS);
        set(self.at_ramp, self.table == 0);
        set(self.taken_in, self.piece == Piece::Gripper);
        set(self.piece_at_pick_up, self.piece == Piece::PickUp);
    }
}

/// The step flags of the crane's automatic chart, in the order the cycle visits them.
const CRANE_CYCLE: [&str; 7] = [
    "Waiting_For_Stack_To_Provide_WP",
    "Check_WP_Type",
    "Crane_To_Stack_1",
    "Pick_Up_WP_1",
    "Crane_Turning_To_Ramp_1",
    "Putting_Down_WP_1",
    "Short_Delay",
];

fn a_piece_goes_from_the_magazine_to_the_ramp() {
    let program = Arc::new(baton_tests::xppu_scenario_1());
    let p = &program;
    let mut plant = Plant::new(p);
    let estop_closed = var(p, "Stack.Panel.DI_EmergencyStop");
    let start = var(p, "Stack.Panel.DI_StartButton");
    let software_emergency = var(p, "Crane.SoftwareEmergency");
    let crane_steps: Vec<VarId> =
        CRANE_CYCLE.iter().map(|s| var(p, &format!("Crane.ACT_AutomaticExecute.{s}.X"))).collect();
    let emergency = p.steps.iter().position(|s| s.name == "Emergency_Stop").expect("PPU has a step Emergency_Stop");
    let mut engine = Engine::new(Arc::clone(&program));
    engine.handle(Input::Set(estop_closed, Value::Bool(true))).expect("the contact closes");
    let (mut visited, mut ramp_at, mut log) = (Vec::new(), None, Vec::new());
    // The outputs the log shows as they change (it is in every failure's message).
    let outputs = [
        ("the lift's valve", plant.lift.valve),
        ("the separator's valve", plant.separator.valve),
        ("the vacuum", plant.vacuum),
        ("the table clockwise", plant.clockwise),
        ("the table counterclockwise", plant.counterclockwise),
    ];
    let mut shown = [false; 5];
    let mut t = 0;
    while t <= 60_000 {
        plant.sense(&mut engine);
        // The operator presses start for 50 ms, half a second in.
        engine.handle(Input::Set(start, Value::Bool((500..550).contains(&t)))).expect("a button is a BOOL");
        engine.handle_cycle(t).expect("a scan");
        while let Some(ev) = engine.poll_event() {
            match ev.kind {
                EventKind::Fire(tr) => log.push(format!("{t} ms: {}", p.transitions[tr.index()].name)),
                EventKind::Fault(_, f) => panic!("a fault at {t} ms: {f:?} ({log:?})"),
                _ => {}
            }
        }
        for (i, &s) in crane_steps.iter().enumerate() {
            if engine.value(s) == Value::Bool(true) && visited.last() != Some(&i) {
                visited.push(i);
            }
        }
        assert!(
            !engine.active_steps().iter().any(|s| s.index() == emergency),
            "PPU went to Emergency_Stop at {t} ms: {log:?}"
        );
        assert_eq!(
            engine.value(software_emergency),
            Value::Bool(false),
            "the crane signalled an error at {t} ms: {log:?}"
        );
        let before = plant.piece;
        for (k, (name, v)) in outputs.iter().enumerate() {
            let now = engine.value(*v) == Value::Bool(true);
            if shown[k] != now {
                shown[k] = now;
                log.push(format!("{t} ms: {name} {}", if now { "on" } else { "off" }));
            }
        }
        plant.advance(&engine, CYCLE_MS as i64);
        if plant.piece != before {
            log.push(format!("{t} ms: the piece {before:?} -> {:?}", plant.piece));
        }
        if plant.piece == Piece::Ramp && ramp_at.is_none() {
            ramp_at = Some(t);
        }
        if ramp_at.is_some_and(|r| t >= r + 2 * STROKE_MS as u64) {
            break;
        }
        t += CYCLE_MS;
    }
    let ramp_at = ramp_at.unwrap_or_else(|| {
        panic!("the piece never reached the ramp: it is at {:?}; crane steps {visited:?}; {log:?}", plant.piece)
    });
    let names: Vec<&str> = visited.iter().map(|&i| CRANE_CYCLE[i]).collect();
    assert_eq!(names.get(..6), Some(&CRANE_CYCLE[..6]), "the crane's automatic cycle, in order: {log:?}");
    // A stroke later the crane is up again and the vacuum off; the separator went back once the crane had taken
    // the piece. (The crane then sets off for the next piece, which this magazine does not have.)
    assert_eq!((plant.lift.at, plant.separator.at), (0, 0), "lift and separator at rest: {log:?}");
    assert_eq!(engine.value(plant.vacuum), Value::Bool(false), "the vacuum is off: {log:?}");
    // The machine's own times bound the cycle from below: two strokes down and two up, two turns, the vacuum.
    let least = 500 + 2 * TURN_MS + 3 * STROKE_MS + VACUUM_MS;
    assert!(ramp_at as i64 > least, "the piece reached the ramp at {ramp_at} ms, sooner than the machine can");
}

baton_tests::harness_main!(sync a_piece_goes_from_the_magazine_to_the_ramp,);
