//! A run's alarms, as ISA-18.2 (IEC 62682) and OPC UA Part 9 define them: each occurrence has its own id and
//! two independent bits, *active* (the cause) and *acknowledged* (an operator saw it), so it is normal,
//! active-unacknowledged, active-acknowledged or returned-unacknowledged. An acknowledgement names one
//! occurrence, with who and an optional comment; acknowledging twice is a typed refusal; a new occurrence is a
//! new alarm, and one that returned to normal is never re-activated. A *latched* alarm (a step's supervision)
//! stays active until acknowledged even when its cause is gone. *Shelving* is the operator's and bounded in time
//! (`ALARM_SHELVE_MAX_MS`): a shelved alarm is kept (its bits move as ever, the trace and the journal have it) but
//! leaves the active list until its time runs out or an operator unshelves it; one whose cause goes while shelved
//! is simply gone (ISA-18.2's shelving; OPC UA's ShelvedStateMachine, TimedShelve and Unshelve).
//!
//! Every change is returned as an `AlarmChange`, the audit record the coordinator journals and traces (who,
//! when, the comment). Time comes in as milliseconds, as everywhere in `proto`.

use std::collections::BTreeMap;
use std::fmt;

use serde::{Deserialize, Serialize};

use crate::limits::{ALARMS_STANDING_MAX, ALARM_SHELVE_MAX_MS, ALARM_TEXT_CHARS_MAX};

/// One occurrence of an alarm, numbered per run from 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
pub struct AlarmId(pub u64);

impl fmt::Display for AlarmId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.0)
    }
}

/// Where an operator stands with an alarm.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AlarmState {
    Normal,
    ActiveUnacknowledged,
    ActiveAcknowledged,
    ReturnedUnacknowledged,
}

/// Who acknowledged an occurrence, when, and what they said.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Ack {
    pub by: String,
    pub at_ms: u64,
    pub comment: Option<String>,
}

/// One occurrence.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Alarm {
    pub id: AlarmId,
    /// What raised it: a step, an agent, an action, a device binding (as the trace names it).
    pub source: String,
    pub message: String,
    pub raised_ms: u64,
    /// Stays active until acknowledged, even when its cause is gone.
    pub latched: bool,
    /// The cause is still there.
    pub cause: bool,
    pub ack: Option<Ack>,
    /// Shelved until then: kept, not announced.
    pub shelved_until_ms: Option<u64>,
    /// Who shelved it, and why (with `shelved_until_ms`).
    #[serde(default)]
    pub shelved_by: Option<Shelf>,
}

/// Who shelved an alarm, and why.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shelf {
    pub by: String,
    pub reason: Option<String>,
}

impl Alarm {
    /// The active bit: the cause is there, or the alarm is latched and not yet acknowledged.
    pub fn is_active(&self) -> bool {
        self.cause || (self.latched && self.ack.is_none())
    }

    pub fn state(&self) -> AlarmState {
        match (self.is_active(), self.ack.is_some()) {
            (true, false) => AlarmState::ActiveUnacknowledged,
            (true, true) => AlarmState::ActiveAcknowledged,
            (false, false) => AlarmState::ReturnedUnacknowledged,
            (false, true) => AlarmState::Normal,
        }
    }

    pub fn is_shelved(&self, now_ms: u64) -> bool {
        self.shelved_until_ms.is_some_and(|until| now_ms < until)
    }
}

/// An audit record: what changed, about which occurrence.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AlarmChange {
    Raised {
        id: AlarmId,
        source: String,
        message: String,
        latched: bool,
    },
    /// Its cause is gone (a latched alarm stays active until acknowledged).
    CauseGone {
        id: AlarmId,
    },
    /// Acknowledged, by whom; `source` is the alarm's, read before an acknowledgement that ends it removes it.
    Acknowledged {
        id: AlarmId,
        source: String,
        by: String,
        comment: Option<String>,
    },
    Shelved {
        id: AlarmId,
        source: String,
        shelf: Shelf,
        until_ms: u64,
    },
    /// Back in the active list: its shelf time ran out (`by` none), or an operator unshelved it.
    Unshelved {
        id: AlarmId,
        source: String,
        shelf: Shelf,
        by: Option<String>,
    },
    /// Back to normal: acknowledged and its cause gone. The occurrence is over.
    Normal {
        id: AlarmId,
        source: String,
    },
}

/// Why an operator's request about an alarm was refused.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum AlarmRefusal {
    /// No standing alarm has this id (never raised, or already back to normal).
    Unknown(AlarmId),
    AlreadyAcknowledged {
        id: AlarmId,
        by: String,
    },
    /// Shelving longer than `ALARM_SHELVE_MAX_MS`, or for no time at all.
    ShelveTooLong {
        id: AlarmId,
        asked_ms: u64,
    },
    /// Unshelving an alarm that is not shelved.
    NotShelved(AlarmId),
}

impl fmt::Display for AlarmRefusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            AlarmRefusal::Unknown(id) => write!(f, "no standing alarm {id}"),
            AlarmRefusal::AlreadyAcknowledged { id, by } => write!(f, "alarm {id} was acknowledged already, by {by}"),
            AlarmRefusal::ShelveTooLong { id, asked_ms } => write!(
                f,
                "alarm {id} cannot be shelved for {asked_ms} ms: shelving lasts from 1 ms to {ALARM_SHELVE_MAX_MS} ms"
            ),
            AlarmRefusal::NotShelved(id) => write!(f, "alarm {id} is not shelved"),
        }
    }
}

impl std::error::Error for AlarmRefusal {}

/// The standing alarms of a run: every occurrence that is active or not yet acknowledged.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct Alarms {
    last_id: u64,
    standing: BTreeMap<AlarmId, Alarm>,
    /// Raises refused because `ALARMS_STANDING_MAX` alarms stood already.
    pub refused: u64,
}

fn bounded(text: &str) -> String {
    text.chars().take(ALARM_TEXT_CHARS_MAX).collect()
}

impl Alarms {
    /// A new occurrence, always with a new id (never a re-activation of an old one). `None`, counted in
    /// `refused`, when `ALARMS_STANDING_MAX` alarms stand already.
    pub fn raise(&mut self, now_ms: u64, source: &str, message: &str, latched: bool) -> Option<AlarmChange> {
        if self.standing.len() >= ALARMS_STANDING_MAX {
            self.refused += 1;
            return None;
        }
        self.last_id += 1;
        let id = AlarmId(self.last_id);
        let alarm = Alarm {
            id,
            source: bounded(source),
            message: bounded(message),
            raised_ms: now_ms,
            latched,
            cause: true,
            ack: None,
            shelved_until_ms: None,
            shelved_by: None,
        };
        let change = AlarmChange::Raised { id, source: alarm.source.clone(), message: alarm.message.clone(), latched };
        self.standing.insert(id, alarm);
        Some(change)
    }

    /// The cause of `id` is gone: it returns to normal if acknowledged already, else waits for an
    /// acknowledgement (returned-unacknowledged, or still active if latched).
    pub fn cause_gone(&mut self, id: AlarmId) -> Vec<AlarmChange> {
        let Some(alarm) = self.standing.get_mut(&id) else { return Vec::new() };
        if !alarm.cause {
            return Vec::new();
        }
        alarm.cause = false;
        let shelved = alarm.shelved_until_ms.is_some() && !alarm.is_active();
        let mut out = vec![AlarmChange::CauseGone { id }];
        if shelved {
            // Cleared while shelved: nobody is to be asked to acknowledge what they chose not to see.
            let alarm = self.standing.remove(&id);
            out.extend(alarm.map(|a| AlarmChange::Normal { id, source: a.source }));
            return out;
        }
        out.extend(self.settle(id));
        out
    }

    /// An operator acknowledges one occurrence.
    pub fn acknowledge(
        &mut self,
        now_ms: u64,
        id: AlarmId,
        by: &str,
        comment: Option<&str>,
    ) -> Result<Vec<AlarmChange>, AlarmRefusal> {
        let alarm = self.standing.get_mut(&id).ok_or(AlarmRefusal::Unknown(id))?;
        if let Some(ack) = &alarm.ack {
            return Err(AlarmRefusal::AlreadyAcknowledged { id, by: ack.by.clone() });
        }
        let (by, comment) = (bounded(by), comment.map(bounded));
        alarm.ack = Some(Ack { by: by.clone(), at_ms: now_ms, comment: comment.clone() });
        let mut out = vec![AlarmChange::Acknowledged { id, source: alarm.source.clone(), by, comment }];
        out.extend(self.settle(id));
        Ok(out)
    }

    /// Every standing alarm not acknowledged yet, acknowledged by `by` (`baton ctl ack all`).
    pub fn acknowledge_all(&mut self, now_ms: u64, by: &str, comment: Option<&str>) -> Vec<AlarmChange> {
        let open: Vec<AlarmId> = self.standing.values().filter(|a| a.ack.is_none()).map(|a| a.id).collect();
        open.into_iter().flat_map(|id| self.acknowledge(now_ms, id, by, comment).unwrap_or_default()).collect()
    }

    /// An operator shelves one occurrence for `for_ms` (at most `ALARM_SHELVE_MAX_MS`), saying why (optional); a
    /// shelved one is shelved again from now.
    pub fn shelve(
        &mut self,
        now_ms: u64,
        id: AlarmId,
        by: &str,
        for_ms: u64,
        reason: Option<&str>,
    ) -> Result<AlarmChange, AlarmRefusal> {
        let alarm = self.standing.get_mut(&id).ok_or(AlarmRefusal::Unknown(id))?;
        if for_ms == 0 || for_ms > ALARM_SHELVE_MAX_MS {
            return Err(AlarmRefusal::ShelveTooLong { id, asked_ms: for_ms });
        }
        let until_ms = now_ms.saturating_add(for_ms);
        let shelf = Shelf { by: bounded(by), reason: reason.map(bounded) };
        alarm.shelved_until_ms = Some(until_ms);
        alarm.shelved_by = Some(shelf.clone());
        Ok(AlarmChange::Shelved { id, source: alarm.source.clone(), shelf, until_ms })
    }

    /// An operator ends a shelf early: the alarm is back in the active list.
    pub fn unshelve(&mut self, id: AlarmId, by: &str) -> Result<AlarmChange, AlarmRefusal> {
        let alarm = self.standing.get_mut(&id).ok_or(AlarmRefusal::Unknown(id))?;
        Self::take_shelf(alarm, Some(bounded(by))).ok_or(AlarmRefusal::NotShelved(id))
    }

    /// Shelves whose time ran out by `now_ms`.
    pub fn expire_shelves(&mut self, now_ms: u64) -> Vec<AlarmChange> {
        self.standing
            .values_mut()
            .filter(|a| a.shelved_until_ms.is_some_and(|until| until <= now_ms))
            .filter_map(|a| Self::take_shelf(a, None))
            .collect()
    }

    fn take_shelf(alarm: &mut Alarm, by: Option<String>) -> Option<AlarmChange> {
        alarm.shelved_until_ms.take()?;
        let shelf = alarm.shelved_by.take().unwrap_or(Shelf { by: String::new(), reason: None });
        Some(AlarmChange::Unshelved { id: alarm.id, source: alarm.source.clone(), shelf, by })
    }

    /// The next moment a shelf runs out, for the host's timer.
    pub fn next_unshelve_ms(&self) -> Option<u64> {
        self.standing.values().filter_map(|a| a.shelved_until_ms).min()
    }

    /// Removes `id` when it is back to normal.
    fn settle(&mut self, id: AlarmId) -> Option<AlarmChange> {
        let normal = self.standing.get(&id).is_some_and(|a| a.state() == AlarmState::Normal);
        if !normal {
            return None;
        }
        let alarm = self.standing.remove(&id)?;
        Some(AlarmChange::Normal { id, source: alarm.source })
    }

    /// The standing alarms, oldest first.
    pub fn standing(&self) -> impl Iterator<Item = &Alarm> {
        self.standing.values()
    }

    /// The active list: the standing alarms not shelved at `now_ms`, oldest first.
    pub fn announced(&self, now_ms: u64) -> impl Iterator<Item = &Alarm> {
        self.standing.values().filter(move |a| !a.is_shelved(now_ms))
    }

    /// The shelved ones at `now_ms`, oldest first.
    pub fn shelved(&self, now_ms: u64) -> impl Iterator<Item = &Alarm> {
        self.standing.values().filter(move |a| a.is_shelved(now_ms))
    }

    pub fn get(&self, id: AlarmId) -> Option<&Alarm> {
        self.standing.get(&id)
    }

    /// Whether `source` has an active alarm not yet acknowledged (a supervised step's outgoing transitions wait
    /// for that acknowledgement).
    pub fn unacknowledged_from(&self, source: &str) -> bool {
        self.standing.values().any(|a| a.source == source && a.ack.is_none() && a.is_active())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn raised(alarms: &mut Alarms, now: u64, source: &str, latched: bool) -> AlarmId {
        match alarms.raise(now, source, "it went wrong", latched) {
            Some(AlarmChange::Raised { id, .. }) => id,
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn the_two_bits_move_independently_through_the_four_states() {
        let mut a = Alarms::default();
        // Acknowledged while active, then the cause goes: normal, and gone from the list.
        let one = raised(&mut a, 0, "agent robot1", false);
        assert_eq!(a.get(one).map(Alarm::state), Some(AlarmState::ActiveUnacknowledged));
        let acked = a.acknowledge(5, one, "op", Some("seen")).expect("first ack");
        assert_eq!(
            acked,
            vec![AlarmChange::Acknowledged {
                id: one,
                source: "agent robot1".into(),
                by: "op".into(),
                comment: Some("seen".into())
            }]
        );
        assert_eq!(a.get(one).map(Alarm::state), Some(AlarmState::ActiveAcknowledged));
        assert_eq!(
            a.cause_gone(one),
            vec![AlarmChange::CauseGone { id: one }, AlarmChange::Normal { id: one, source: "agent robot1".into() }]
        );
        assert!(a.get(one).is_none());
        // The cause goes first: returned-unacknowledged, until someone acknowledges it.
        let two = raised(&mut a, 10, "device door", false);
        a.cause_gone(two);
        assert_eq!(a.get(two).map(Alarm::state), Some(AlarmState::ReturnedUnacknowledged));
        let acked = a.acknowledge(20, two, "op", None).expect("ack");
        assert_eq!(acked.last(), Some(&AlarmChange::Normal { id: two, source: "device door".into() }));
    }

    #[test]
    fn a_latched_alarm_stays_active_until_acknowledged_even_when_its_cause_is_gone() {
        let mut a = Alarms::default();
        let id = raised(&mut a, 0, "step Move", true);
        a.cause_gone(id);
        assert_eq!(a.get(id).map(Alarm::state), Some(AlarmState::ActiveUnacknowledged));
        assert!(a.unacknowledged_from("step Move"), "its step's transitions still wait");
        let acked = a.acknowledge(9, id, "op", None).expect("ack");
        assert_eq!(acked.last(), Some(&AlarmChange::Normal { id, source: "step Move".into() }));
        assert!(!a.unacknowledged_from("step Move"));
    }

    #[test]
    fn an_acknowledgement_names_one_occurrence_and_a_second_is_refused() {
        let mut a = Alarms::default();
        let first = raised(&mut a, 0, "step Move", false);
        let second = raised(&mut a, 1, "step Move", false);
        assert_ne!(first, second, "a new occurrence is a new alarm");
        a.acknowledge(2, first, "alice", None).expect("ack");
        assert_eq!(
            a.acknowledge(3, first, "bob", None),
            Err(AlarmRefusal::AlreadyAcknowledged { id: first, by: "alice".into() })
        );
        assert_eq!(a.get(second).map(Alarm::state), Some(AlarmState::ActiveUnacknowledged), "the other is untouched");
        assert_eq!(a.acknowledge(4, AlarmId(99), "bob", None), Err(AlarmRefusal::Unknown(AlarmId(99))));
        // Back to normal, an occurrence is over: never re-activated, never acknowledged again.
        a.cause_gone(first);
        assert_eq!(a.acknowledge(5, first, "bob", None), Err(AlarmRefusal::Unknown(first)));
        let third = raised(&mut a, 6, "step Move", false);
        assert!(third > second);
        let all = a.acknowledge_all(7, "carol", Some("shift change"));
        let acked: Vec<AlarmId> = all
            .iter()
            .filter_map(|c| if let AlarmChange::Acknowledged { id, .. } = c { Some(*id) } else { None })
            .collect();
        assert_eq!(acked, vec![second, third]);
    }

    #[test]
    fn shelving_is_bounded_in_time_and_runs_out() {
        let mut a = Alarms::default();
        let id = raised(&mut a, 0, "device door", false);
        assert_eq!(a.shelve(0, id, "op", 0, None), Err(AlarmRefusal::ShelveTooLong { id, asked_ms: 0 }));
        let long = ALARM_SHELVE_MAX_MS + 1;
        assert_eq!(a.shelve(0, id, "op", long, None), Err(AlarmRefusal::ShelveTooLong { id, asked_ms: long }));
        let shelf = Shelf { by: "op".into(), reason: Some("sensor cleaned".into()) };
        assert_eq!(
            a.shelve(100, id, "op", 1_000, Some("sensor cleaned")),
            Ok(AlarmChange::Shelved { id, source: "device door".into(), shelf: shelf.clone(), until_ms: 1_100 })
        );
        assert!(a.get(id).is_some_and(|al| al.is_shelved(1_099) && !al.is_shelved(1_100)));
        assert_eq!(a.announced(1_099).count(), 0, "a shelved alarm leaves the active list");
        assert_eq!(a.shelved(1_099).count(), 1);
        assert_eq!(a.next_unshelve_ms(), Some(1_100));
        assert!(a.expire_shelves(1_099).is_empty());
        assert_eq!(
            a.expire_shelves(1_100),
            vec![AlarmChange::Unshelved { id, source: "device door".into(), shelf, by: None }]
        );
        assert_eq!(a.next_unshelve_ms(), None);
        assert_eq!(a.announced(1_100).count(), 1, "back in the active list");
        assert_eq!(a.unshelve(id, "op"), Err(AlarmRefusal::NotShelved(id)));
    }

    #[test]
    fn an_operator_ends_a_shelf_early_and_an_alarm_that_clears_while_shelved_is_gone() {
        let mut a = Alarms::default();
        let id = raised(&mut a, 0, "device door", false);
        a.shelve(0, id, "anna", 60_000, None).expect("shelved");
        let back = a.unshelve(id, "ben").expect("unshelved");
        assert_eq!(
            back,
            AlarmChange::Unshelved {
                id,
                source: "device door".into(),
                shelf: Shelf { by: "anna".into(), reason: None },
                by: Some("ben".into())
            }
        );
        assert_eq!(a.announced(1).count(), 1);
        // Shelved, unacknowledged, and its cause goes: over, with nothing left to acknowledge.
        a.shelve(1, id, "anna", 60_000, None).expect("shelved again");
        assert_eq!(
            a.cause_gone(id),
            vec![AlarmChange::CauseGone { id }, AlarmChange::Normal { id, source: "device door".into() }]
        );
        assert!(a.get(id).is_none());
        assert_eq!(a.next_unshelve_ms(), None);
        // A latched one (a step's supervision) stays until acknowledged, shelved or not: its step waits for that.
        let step = raised(&mut a, 2, "Move", true);
        a.shelve(2, step, "anna", 60_000, None).expect("shelved");
        assert_eq!(a.cause_gone(step), vec![AlarmChange::CauseGone { id: step }]);
        assert!(a.get(step).is_some());
    }

    #[test]
    fn an_acknowledgement_that_ends_an_alarm_still_names_its_source() {
        let mut a = Alarms::default();
        let id = raised(&mut a, 0, "Weld", false);
        a.cause_gone(id);
        let changes = a.acknowledge(5, id, "anna", None).expect("ack");
        assert!(matches!(&changes[0], AlarmChange::Acknowledged { source, .. } if source == "Weld"), "{changes:?}");
        assert!(a.get(id).is_none(), "back to normal, removed");
    }

    #[test]
    fn the_list_is_bounded_and_a_peers_long_text_is_cut() {
        let mut a = Alarms::default();
        for i in 0..ALARMS_STANDING_MAX {
            assert!(a.raise(i as u64, "s", "m", false).is_some());
        }
        assert_eq!(a.raise(0, "s", "m", false), None);
        assert_eq!((a.refused, a.standing().count()), (1, ALARMS_STANDING_MAX));
        let mut b = Alarms::default();
        let long = "x".repeat(10 * ALARM_TEXT_CHARS_MAX);
        let id = raised(&mut b, 0, &long, false);
        let alarm = b.get(id).expect("raised");
        assert_eq!(alarm.source.chars().count(), ALARM_TEXT_CHARS_MAX);
    }
}
