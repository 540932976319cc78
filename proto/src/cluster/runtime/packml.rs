//! A run's state, as PackML (ISA-TR88.00.02; OPC UA's PackML companion specification, OPC 30050) defines a
//! unit's: 17 states, 9 commands, and every "-ing" state leaving by itself when its work is done.
//!
//! Which command is legal where is not written per command: it follows from the standard's three nested
//! machines. The base machine holds Aborting, Aborted and the composite *Cleared*; Cleared holds Stopped,
//! Stopping, Clearing and the composite *Running*; Running holds the execute machine (Resetting, Idle, Starting,
//! Execute, Holding, Held, Unholding, Suspending, Suspended, Unsuspending, Completing, Complete). A command is
//! legal from a set of states or from everywhere inside a machine — Abort from anywhere inside Cleared, Stop from
//! anywhere inside Running — so the table cannot forget Abort from Stopping, as hand-written ones have.
//! `State::available` is the list OPC UA makes mandatory (AvailableTransitions); `State::apply` refuses an
//! illegal command with the state and what is legal.

use std::fmt;

use serde::{Deserialize, Serialize};

/// A run's PackML state.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum State {
    Stopped,
    Resetting,
    Idle,
    Starting,
    Execute,
    Completing,
    Complete,
    Holding,
    Held,
    Unholding,
    Suspending,
    Suspended,
    Unsuspending,
    Stopping,
    Aborting,
    Aborted,
    Clearing,
}

/// A command an operator (or the chart's end) gives a run, numbered as PackTags number them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Command {
    Reset = 1,
    Start = 2,
    Stop = 3,
    Hold = 4,
    Unhold = 5,
    Suspend = 6,
    Unsuspend = 7,
    Abort = 8,
    Clear = 9,
}

/// The nested machines of the standard: `Cleared` is inside `Base`, `Running` inside `Cleared`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Machine {
    Base,
    Cleared,
    Running,
}

/// Where a command is legal: in these states, or anywhere inside a machine (its own states and those of the
/// machines inside it).
enum From {
    States(&'static [State]),
    Inside(Machine),
}

/// The whole of PackML's command legality, and where each command leads.
const COMMANDS: [(Command, From, State); 9] = [
    (Command::Abort, From::Inside(Machine::Cleared), State::Aborting),
    (Command::Clear, From::States(&[State::Aborted]), State::Clearing),
    (Command::Stop, From::Inside(Machine::Running), State::Stopping),
    (Command::Reset, From::States(&[State::Stopped, State::Complete]), State::Resetting),
    (Command::Start, From::States(&[State::Idle]), State::Starting),
    (Command::Hold, From::States(&[State::Execute]), State::Holding),
    (Command::Unhold, From::States(&[State::Held]), State::Unholding),
    (Command::Suspend, From::States(&[State::Execute]), State::Suspending),
    (Command::Unsuspend, From::States(&[State::Suspended]), State::Unsuspending),
];

impl Machine {
    /// The machine this one is a state of, if any.
    pub fn parent(self) -> Option<Machine> {
        match self {
            Machine::Base => None,
            Machine::Cleared => Some(Machine::Base),
            Machine::Running => Some(Machine::Cleared),
        }
    }
}

impl State {
    /// Every state, in PackML's order.
    pub const ALL: [State; 17] = [
        State::Stopped,
        State::Resetting,
        State::Idle,
        State::Starting,
        State::Execute,
        State::Completing,
        State::Complete,
        State::Holding,
        State::Held,
        State::Unholding,
        State::Suspending,
        State::Suspended,
        State::Unsuspending,
        State::Stopping,
        State::Aborting,
        State::Aborted,
        State::Clearing,
    ];

    /// The machine whose own state this is.
    pub fn machine(self) -> Machine {
        match self {
            State::Aborting | State::Aborted => Machine::Base,
            State::Stopped | State::Stopping | State::Clearing => Machine::Cleared,
            _ => Machine::Running,
        }
    }

    /// Whether the state is inside `machine`: one of its own, or of a machine nested in it.
    pub fn is_inside(self, machine: Machine) -> bool {
        let mut m = Some(self.machine());
        while let Some(here) = m {
            if here == machine {
                return true;
            }
            m = here.parent();
        }
        false
    }

    /// Where `command` leads from here, if it is legal here.
    pub fn after(self, command: Command) -> Option<State> {
        COMMANDS.iter().find(|(c, _, _)| *c == command).and_then(|(_, from, to)| {
            let legal = match from {
                From::States(states) => states.contains(&self),
                From::Inside(machine) => self.is_inside(*machine),
            };
            legal.then_some(*to)
        })
    }

    /// The commands legal now, in PackTags order (OPC UA's AvailableTransitions).
    pub fn available(self) -> Vec<Command> {
        Command::ALL.into_iter().filter(|&c| self.after(c).is_some()).collect()
    }

    /// The state `command` leads to, or why not.
    pub fn apply(self, command: Command) -> Result<State, Refused> {
        self.after(command).ok_or(Refused { state: self, command, legal: self.available() })
    }

    /// Where an acting ("-ing") state goes by itself once its work is done (PackML's "state complete"); `None` for
    /// a state that waits for a command (Execute leaves by itself too, to Completing, when the chart reaches a
    /// terminal situation: that is the run's, not the state's, so it is not here).
    pub fn when_done(self) -> Option<State> {
        Some(match self {
            State::Resetting => State::Idle,
            State::Starting => State::Execute,
            State::Completing => State::Complete,
            State::Holding => State::Held,
            State::Unholding | State::Unsuspending => State::Execute,
            State::Suspending => State::Suspended,
            State::Stopping | State::Clearing => State::Stopped,
            State::Aborting => State::Aborted,
            _ => return None,
        })
    }

    /// The state's name in the trace and the status JSON (`held`).
    pub fn name(self) -> &'static str {
        match self {
            State::Stopped => "stopped",
            State::Resetting => "resetting",
            State::Idle => "idle",
            State::Starting => "starting",
            State::Execute => "execute",
            State::Completing => "completing",
            State::Complete => "complete",
            State::Holding => "holding",
            State::Held => "held",
            State::Unholding => "unholding",
            State::Suspending => "suspending",
            State::Suspended => "suspended",
            State::Unsuspending => "unsuspending",
            State::Stopping => "stopping",
            State::Aborting => "aborting",
            State::Aborted => "aborted",
            State::Clearing => "clearing",
        }
    }
}

impl Command {
    /// Every command, in PackTags order.
    pub const ALL: [Command; 9] = [
        Command::Reset,
        Command::Start,
        Command::Stop,
        Command::Hold,
        Command::Unhold,
        Command::Suspend,
        Command::Unsuspend,
        Command::Abort,
        Command::Clear,
    ];

    /// The command's name, as `baton ctl` takes it and the trace writes it (`hold`).
    pub fn name(self) -> &'static str {
        match self {
            Command::Reset => "reset",
            Command::Start => "start",
            Command::Stop => "stop",
            Command::Hold => "hold",
            Command::Unhold => "unhold",
            Command::Suspend => "suspend",
            Command::Unsuspend => "unsuspend",
            Command::Abort => "abort",
            Command::Clear => "clear",
        }
    }

    /// The command of this name (case-insensitive).
    pub fn from_name(name: &str) -> Option<Command> {
        Command::ALL.into_iter().find(|c| c.name().eq_ignore_ascii_case(name))
    }
}

impl fmt::Display for State {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl fmt::Display for Command {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// An illegal command: what was asked, in which state, and what is legal there.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Refused {
    pub state: State,
    pub command: Command,
    pub legal: Vec<Command>,
}

impl fmt::Display for Refused {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let legal: Vec<&str> = self.legal.iter().map(|c| c.name()).collect();
        let legal = if legal.is_empty() { "nothing (it leaves by itself)".to_string() } else { legal.join(", ") };
        write!(f, "cannot {} a run that is {}: legal now: {legal}", self.command, self.state)
    }
}

impl std::error::Error for Refused {}

#[cfg(test)]
mod tests {
    use super::*;

    /// The nesting as OPC 30050 draws it, written out state by state — apart from the code's `machine()` — so
    /// that the table below is generated from the standard, not from the code under test.
    fn inside_running(s: State) -> bool {
        use State::*;
        [
            Resetting,
            Idle,
            Starting,
            Execute,
            Holding,
            Held,
            Unholding,
            Suspending,
            Suspended,
            Unsuspending,
            Completing,
            Complete,
        ]
        .contains(&s)
    }

    fn inside_cleared(s: State) -> bool {
        inside_running(s) || [State::Stopped, State::Stopping, State::Clearing].contains(&s)
    }

    /// What the standard says each command does from `s`.
    fn expected(s: State, c: Command) -> Option<State> {
        use State::*;
        match c {
            Command::Abort => inside_cleared(s).then_some(Aborting),
            Command::Stop => inside_running(s).then_some(Stopping),
            Command::Clear => (s == Aborted).then_some(Clearing),
            Command::Reset => matches!(s, Stopped | Complete).then_some(Resetting),
            Command::Start => (s == Idle).then_some(Starting),
            Command::Hold => (s == Execute).then_some(Holding),
            Command::Unhold => (s == Held).then_some(Unholding),
            Command::Suspend => (s == Execute).then_some(Suspending),
            Command::Unsuspend => (s == Suspended).then_some(Unsuspending),
        }
    }

    #[test]
    fn every_state_and_command_pair_is_legal_exactly_where_the_nesting_says() {
        let mut legal = 0;
        for s in State::ALL {
            for c in Command::ALL {
                let want = expected(s, c);
                assert_eq!(s.after(c), want, "{c} from {s}");
                match (s.apply(c), want) {
                    (Ok(to), Some(w)) => {
                        assert_eq!(to, w);
                        legal += 1;
                    }
                    (Err(refused), None) => {
                        assert_eq!((refused.state, refused.command), (s, c));
                        assert_eq!(refused.legal, s.available(), "a refusal says what is legal");
                        assert!(!refused.legal.contains(&c));
                    }
                    (got, want) => panic!("{c} from {s}: {got:?}, expected {want:?}"),
                }
            }
            let available: Vec<Command> = Command::ALL.into_iter().filter(|&c| expected(s, c).is_some()).collect();
            assert_eq!(s.available(), available, "the legal commands of {s}");
        }
        // 12 states inside Running take Stop, 15 inside Cleared take Abort, and 8 pairs name their states: Clear
        // from Aborted, Reset from Stopped and Complete, Start, Hold, Unhold, Suspend and Unsuspend.
        assert_eq!(legal, 12 + 15 + 8);
    }

    #[test]
    fn abort_is_legal_where_hand_written_tables_forgot_it() {
        // The ROS-Industrial table forgets Abort from Stopping; a popular simulator from Stopped, Clearing and
        // Stopping too.
        for s in [State::Stopping, State::Stopped, State::Clearing] {
            assert_eq!(s.apply(Command::Abort), Ok(State::Aborting), "{s}");
        }
        assert!(State::Aborting.apply(Command::Abort).is_err() && State::Aborted.apply(Command::Abort).is_err());
    }

    #[test]
    fn acting_states_leave_by_themselves_and_waiting_states_do_not() {
        for s in State::ALL {
            let acting = s.name().ends_with("ing");
            assert_eq!(s.when_done().is_some(), acting, "{s}");
            if let Some(next) = s.when_done() {
                assert!(next.when_done().is_none(), "{s} → {next} is a state that waits");
            }
        }
        // From anywhere, the commands and the state-complete steps reach Stopped again: a run can always be
        // brought back.
        for s in State::ALL {
            let mut seen = vec![s];
            let mut frontier = vec![s];
            while let Some(here) = frontier.pop() {
                let next = Command::ALL.into_iter().filter_map(|c| here.after(c)).chain(here.when_done());
                for n in next {
                    if !seen.contains(&n) {
                        seen.push(n);
                        frontier.push(n);
                    }
                }
            }
            assert!(seen.contains(&State::Stopped) && seen.contains(&State::Execute), "from {s}: {seen:?}");
        }
    }

    #[test]
    fn names_read_back_and_a_refusal_says_the_state_and_what_is_legal() {
        for c in Command::ALL {
            assert_eq!(Command::from_name(&c.name().to_uppercase()), Some(c));
            assert_eq!(serde_json::to_string(&c).expect("json"), format!("\"{}\"", c.name()));
        }
        for s in State::ALL {
            assert_eq!(serde_json::to_string(&s).expect("json"), format!("\"{}\"", s.name()));
        }
        assert_eq!(Command::from_name("pause"), None);
        let refused = State::Stopped.apply(Command::Hold).expect_err("no hold from stopped");
        assert_eq!(refused.to_string(), "cannot hold a run that is stopped: legal now: reset, abort");
        let busy = State::Aborting.apply(Command::Stop).expect_err("aborting");
        assert_eq!(busy.to_string(), "cannot stop a run that is aborting: legal now: nothing (it leaves by itself)");
    }
}
