//! The trace: what a run did, one record per event, as `baton sim`, `baton run --trace`, the simulated cluster,
//! the recording and `baton test` write and read it. The event is a type: a record is made with a
//! `TraceEvent` and matched on one, so a misspelt event does not compile; the JSON spells it in snake case
//! (`"action_on"`), as it always has.

use serde::{Deserialize, Serialize};

use crate::exec::engine::{Event, EventKind, FaultSource};
use crate::exec::eval::Fault;
use crate::exec::program::{Program, StepId};

/// What a trace record says happened. Engine events (`activate` … `value`) come from `baton sim` and every
/// engine of a run; the rest from the coordinator of a distributed run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TraceEvent {
    /// A step became active (`name` is the step).
    Activate,
    /// A step stopped being active.
    Deactivate,
    /// A transition cleared (`name` is the transition).
    Fire,
    /// An action's output Q rose (`name` is the action).
    ActionOn,
    /// An action's output Q fell.
    ActionOff,
    /// A watched variable's value after the first cycle or a change (`value` holds it).
    Value,
    /// A run-time fault, with `message`.
    Fault,
    /// A token left for an agent: `name` is the step it enters, with `agent`, `token`, `epoch`.
    Dispatch,
    /// The token came back (`name` is the step it entered).
    Return,
    /// A token has no live agent matching its placement yet.
    Wait,
    /// An agent became live.
    AgentUp,
    /// An agent's liveliness token vanished, or its lease ran out.
    AgentLost,
    /// Something needs a person (with `message`).
    Alarm,
    /// A token went back to its agent in the same epoch.
    Resume,
    /// A coordinator process took the run over from its journal.
    Recover,
    /// A report of an older epoch of a token arrived; the agent was told to drop it.
    RejectStale,
    /// An agent refused a command or a variable update of a coordinator whose term is lower than the highest it
    /// has seen of the run: a deposed coordinator's (`name` says what was refused, `message` both terms).
    StaleTerm,
    /// An agent heard a coordinator of a higher term than before in the run (one that won its election, or the
    /// first it heard): from then on lower terms are refused (`message` says both).
    Term,
    /// The coordinator stopped acting: it lost its election, or was about to (`message` says why — no renewal of
    /// its lease in time, or etcd refused its journal's write); the run is left to the coordinator that wins next.
    Deposed,
    /// A skill finished.
    SkillDone,
    /// A skill failed (with `message`).
    SkillFault,
    /// An input was set (`message` holds the value).
    Set,
    /// A device binding's connection came up.
    DeviceUp,
    /// A device binding's connection went down (with `message`).
    DeviceDown,
    /// The run's PackML state changed (`name` is the new state: `execute`, `completing`, `complete`, …).
    State,
    /// An operator's command was accepted (`name` is the command, `message` the reason, `by` who sent it).
    Command,
    /// An operator's command was refused (`message` says why and what is legal).
    CommandRefused,
    /// The run's mode changed (`name`: `auto`, `step`, `manual`).
    Mode,
    /// An alarm was acknowledged (`id`, `by`, `message` the comment; `name` its source).
    Ack,
    /// An alarm is back to normal: acknowledged and its cause gone (`id`).
    AlarmClear,
    /// An alarm was shelved (`id`, `by`, until when and why in `message`; `name` its source).
    Shelve,
    /// A shelved alarm is back in the active list (`id`; `name` its source): its time ran out (`by` who shelved it)
    /// or an operator unshelved it (`by` that operator); `message` says which, with who shelved it and why.
    Unshelve,
    /// An agent that could not be told of the run's abort (or stop) was heard from again and told (`name` is the
    /// agent): from then on nothing of the run runs there.
    Told,
    /// `reset` started the chart again from its initial steps as a new run (`message` holds the new run's id).
    NewRun,
    /// An operator took a token back (manual mode: `deactivate` or `move` of the step it held): its agent drops it
    /// (`name` is that step, with `agent`, `token`, `epoch`). It does not come back.
    Withdraw,
    // What follows is written by an agent, in its own trace (`baton-agent --trace`), where `t_ms` is Unix time
    // and `agent` names the agent; `agent_up`, `skill_done` and `skill_fault` are written there too.
    /// The agent has not heard its router for a while, or, starting, no router answers yet (`name` is the agent;
    /// `message` says what it stopped, if anything).
    ContactLost,
    /// The agent hears its router again (`name` is the agent).
    ContactBack,
    /// The agent started the skill of an action (`name` is the action, with `token`).
    SkillStart,
    /// The agent cancelled a running skill (`name` is the action; `message` says why: the run was aborted, its
    /// token is held, the lease fence).
    SkillCancel,
    /// A cancelled skill has ended (`name` is the action; `message` says how, or why it did not stop cleanly).
    SkillStopped,
    /// A skill waits for something outside the agent (`name` is what it waits for, `message` why: no server took
    /// a call yet).
    SkillWait,
    /// A device's value for an input was refused (`name` is the variable, `message` why); the input keeps its
    /// value.
    InputRefused,
    // What follows is written by `baton console`, in its own trace (`--trace`), where `t_ms` is Unix time.
    /// A user logged in to the console (`name` is the user, `message` the role).
    Login,
    /// A login was refused (`name` is the user name given, `message` why).
    LoginRefused,
}

impl TraceEvent {
    /// Every event, in the order above.
    pub const ALL: [TraceEvent; 44] = [
        TraceEvent::Activate,
        TraceEvent::Deactivate,
        TraceEvent::Fire,
        TraceEvent::ActionOn,
        TraceEvent::ActionOff,
        TraceEvent::Value,
        TraceEvent::Fault,
        TraceEvent::Dispatch,
        TraceEvent::Return,
        TraceEvent::Wait,
        TraceEvent::AgentUp,
        TraceEvent::AgentLost,
        TraceEvent::Alarm,
        TraceEvent::Resume,
        TraceEvent::Recover,
        TraceEvent::RejectStale,
        TraceEvent::StaleTerm,
        TraceEvent::Term,
        TraceEvent::Deposed,
        TraceEvent::SkillDone,
        TraceEvent::SkillFault,
        TraceEvent::Set,
        TraceEvent::DeviceUp,
        TraceEvent::DeviceDown,
        TraceEvent::State,
        TraceEvent::Command,
        TraceEvent::CommandRefused,
        TraceEvent::Mode,
        TraceEvent::Ack,
        TraceEvent::AlarmClear,
        TraceEvent::Shelve,
        TraceEvent::Unshelve,
        TraceEvent::Told,
        TraceEvent::NewRun,
        TraceEvent::Withdraw,
        TraceEvent::ContactLost,
        TraceEvent::ContactBack,
        TraceEvent::SkillStart,
        TraceEvent::SkillCancel,
        TraceEvent::SkillStopped,
        TraceEvent::SkillWait,
        TraceEvent::InputRefused,
        TraceEvent::Login,
        TraceEvent::LoginRefused,
    ];

    /// The event's name in the JSON (`action_on`). Not public: code outside matches on the event itself, and
    /// writes it with `Display`.
    pub(crate) fn as_str(self) -> &'static str {
        match self {
            TraceEvent::Activate => "activate",
            TraceEvent::Deactivate => "deactivate",
            TraceEvent::Fire => "fire",
            TraceEvent::ActionOn => "action_on",
            TraceEvent::ActionOff => "action_off",
            TraceEvent::Value => "value",
            TraceEvent::Fault => "fault",
            TraceEvent::Dispatch => "dispatch",
            TraceEvent::Return => "return",
            TraceEvent::Wait => "wait",
            TraceEvent::AgentUp => "agent_up",
            TraceEvent::AgentLost => "agent_lost",
            TraceEvent::Alarm => "alarm",
            TraceEvent::Resume => "resume",
            TraceEvent::Recover => "recover",
            TraceEvent::RejectStale => "reject_stale",
            TraceEvent::StaleTerm => "stale_term",
            TraceEvent::Term => "term",
            TraceEvent::Deposed => "deposed",
            TraceEvent::SkillDone => "skill_done",
            TraceEvent::SkillFault => "skill_fault",
            TraceEvent::Set => "set",
            TraceEvent::DeviceUp => "device_up",
            TraceEvent::DeviceDown => "device_down",
            TraceEvent::State => "state",
            TraceEvent::Command => "command",
            TraceEvent::CommandRefused => "command_refused",
            TraceEvent::Mode => "mode",
            TraceEvent::Ack => "ack",
            TraceEvent::AlarmClear => "alarm_clear",
            TraceEvent::Shelve => "shelve",
            TraceEvent::Unshelve => "unshelve",
            TraceEvent::Told => "told",
            TraceEvent::NewRun => "new_run",
            TraceEvent::Withdraw => "withdraw",
            TraceEvent::ContactLost => "contact_lost",
            TraceEvent::ContactBack => "contact_back",
            TraceEvent::SkillStart => "skill_start",
            TraceEvent::SkillCancel => "skill_cancel",
            TraceEvent::SkillStopped => "skill_stopped",
            TraceEvent::SkillWait => "skill_wait",
            TraceEvent::InputRefused => "input_refused",
            TraceEvent::Login => "login",
            TraceEvent::LoginRefused => "login_refused",
        }
    }
}

impl std::fmt::Display for TraceEvent {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// One line of a trace: `{"t_ms": 20, "event": "activate", "name": "Fill"}`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct TraceRecord {
    pub t_ms: u64,
    pub event: TraceEvent,
    pub name: String,
    /// In a distributed run: the agent the event happened on (or a token was sent to).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub agent: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub token: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub epoch: Option<u32>,
    /// What went wrong, for `fault` and `skill_fault` records.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub message: Option<String>,
    /// A watched variable's new value, for `value` records (`T#10ms`, `TRUE`, `42`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub value: Option<String>,
    /// An alarm's occurrence, for `alarm` records (`cluster::runtime::alarms::AlarmId`, a number).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub id: Option<u64>,
    /// Who sent a `command` (or `command_refused`), acknowledged (`ack`) or shelved (`shelve`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub by: Option<String>,
}

impl TraceRecord {
    pub fn new(t_ms: u64, event: TraceEvent, name: &str) -> TraceRecord {
        TraceRecord {
            t_ms,
            event,
            name: name.to_string(),
            agent: None,
            token: None,
            epoch: None,
            message: None,
            value: None,
            id: None,
            by: None,
        }
    }
}

/// What an engine event comes to: a trace record, or a run-time fault (which `baton sim` prints apart and a
/// distributed run records as a `fault` record).
#[derive(Clone, Debug, PartialEq)]
pub enum Output {
    Trace(TraceRecord),
    Fault { t_ms: u64, message: String },
}

/// An engine event as a trace record (or, for a fault, a message), with the program's names.
pub fn of_event(program: &Program, ev: Event) -> Output {
    let (event, name) = match ev.kind {
        EventKind::Activate(s) => (TraceEvent::Activate, &program.steps[s.index()].name),
        EventKind::Deactivate(s) => (TraceEvent::Deactivate, &program.steps[s.index()].name),
        EventKind::Fire(t) => (TraceEvent::Fire, &program.transitions[t.index()].name),
        EventKind::ActionOn(a) => (TraceEvent::ActionOn, &program.actions[a.index()].name),
        EventKind::ActionOff(a) => (TraceEvent::ActionOff, &program.actions[a.index()].name),
        EventKind::Fault(source, fault) => {
            return Output::Fault { t_ms: ev.t_ms, message: fault_message(program, source, fault) }
        }
        EventKind::Overrun(s) => {
            let mut rec = TraceRecord::new(ev.t_ms, TraceEvent::Alarm, &program.steps[s.index()].name);
            rec.message = Some(overrun_message(program, s));
            return Output::Trace(rec);
        }
    };
    Output::Trace(TraceRecord::new(ev.t_ms, event, name))
}

/// What a step's supervision alarm says.
pub fn overrun_message(program: &Program, s: StepId) -> String {
    let step = &program.steps[s.index()];
    format!("step `{}` has been active longer than its maximum time of {} ms", step.name, step.max_ms)
}

/// What a run-time fault says, naming where it happened.
pub fn fault_message(program: &Program, source: FaultSource, fault: Fault) -> String {
    let what = match fault {
        Fault::DivisionByZero => "division by zero",
        Fault::MuxSelector => "a MUX selector past its inputs",
        Fault::IndexOutOfRange => "an array index outside its bounds",
        Fault::NoSuchDate => "a date or time of day that is not on the calendar (CONCAT_DATE, CONCAT_TOD, CONCAT_DT)",
        Fault::LoopLimit => {
            let FaultSource::Action(a) = source else { return "a loop past its limit".to_string() };
            return format!(
                "a loop in action `{}` ran more than {} iterations in one cycle: the rest of its body was skipped",
                program.actions[a.index()].name,
                crate::limits::LOOP_ITERATIONS_MAX
            );
        }
        Fault::CallLimit => {
            let FaultSource::Action(a) = source else { return "calls past their limit".to_string() };
            return format!(
                "action `{}` ran more than {} loop passes and calls of blocks and functions in one cycle: the rest \
                 of its body was skipped",
                program.actions[a.index()].name,
                crate::limits::LOOP_ITERATIONS_MAX
            );
        }
        Fault::SecondToken(s) => {
            let FaultSource::Transition(t) = source else { return "a second token".to_string() };
            return format!(
                "transition `{}` gave step `{}` a second token while it held one (the chart is not safe): the tokens merged",
                program.transitions[t.index()].name,
                program.steps[s.index()].name
            );
        }
    };
    match source {
        FaultSource::Transition(t) => {
            format!("{what} in the condition of transition `{}` (taken as FALSE)", program.transitions[t.index()].name)
        }
        FaultSource::Action(a) => {
            format!("{what} in action `{}` (the rest of its body was skipped)", program.actions[a.index()].name)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_event_is_written_as_its_snake_case_name_and_read_back() {
        for event in TraceEvent::ALL {
            let json = serde_json::to_string(&event).expect("an event serializes");
            assert_eq!(json, format!("\"{}\"", event.as_str()));
            assert_eq!(serde_json::from_str::<TraceEvent>(&json).expect("and reads back"), event);
        }
        let line = r#"{"t_ms":20,"event":"action_on","name":"Fill"}"#;
        let record: TraceRecord = serde_json::from_str(line).expect("a record");
        assert_eq!(record, TraceRecord::new(20, TraceEvent::ActionOn, "Fill"));
        assert_eq!(serde_json::to_string(&record).expect("serializes"), line);
        assert!(serde_json::from_str::<TraceRecord>(r#"{"t_ms":0,"event":"actoin_on","name":"x"}"#).is_err());
        let mut alarm = TraceRecord::new(5, TraceEvent::Alarm, "robot1");
        alarm.id = Some(3);
        let json = serde_json::to_string(&alarm).expect("serializes");
        assert_eq!(json, r#"{"t_ms":5,"event":"alarm","name":"robot1","id":3}"#, "an alarm's id is a number");
    }
}
