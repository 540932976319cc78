//! What the coordinator keeps per token, per agent, per supervised step and per partial hold, and the ids of a
//! run's tokens: the records every part of the coordinator reads, which import none of those parts in turn.

use std::collections::{BTreeMap, BTreeSet};

use crate::cluster::layout::SegmentId;
use crate::cluster::wire::{Report, RunId, TokenId};
use crate::exec::program::StepId;
#[derive(serde::Serialize, serde::Deserialize)]
pub(super) struct TokenState {
    pub(super) segment: SegmentId,
    pub(super) entry: StepId,
    pub(super) epoch: u32,
    pub(super) agent: Option<String>,
    pub(super) next_seq: u32,
    pub(super) ahead: BTreeMap<u32, Report>,
    /// What the reports held ahead weigh (`Report::weight`), bounded by `REPORTS_AHEAD_BYTES_MAX`.
    pub(super) ahead_bytes: usize,
    /// The older epochs whose reports were traced as stale (`reject_stale`, once each): later ones are only
    /// answered with a `Drop`.
    pub(super) stale_traced: Vec<u32>,
    pub(super) dispatched_ms: u64,
    /// Its agent was lost under `LossPolicy::Pause`.
    pub(super) paused: bool,
    /// False from a restart from the journal until the agent says it holds the token (or reports on it).
    pub(super) confirmed: bool,
    /// When the dispatch is sent again if no report came, and the delay after that.
    pub(super) resend_at_ms: u64,
    pub(super) resend_backoff_ms: u64,
    /// The process of its agent it was given to: a token goes back in the same epoch only to that process.
    pub(super) incarnation: uuid::Uuid,
    /// Its agent was lost under `LossPolicy::Reassign`: when the token goes to another agent, unless the lost one
    /// comes back first. Not before the agent has stopped its skills (`limits::fence_margin_ms`).
    pub(super) reassign_at_ms: Option<u64>,
    /// Held by an operator (`operate`); whether its agent confirmed that (or its release); when the hold or release
    /// is sent again if not, and the delay after that.
    pub(super) hold: bool,
    pub(super) hold_ok: bool,
    pub(super) hold_resend_at_ms: u64,
    pub(super) hold_backoff_ms: u64,
    /// The mode and permits its agent was told (`modes`).
    pub(super) gate: TokenGate,
}

/// The ids of a run's tokens: the run id mixed with a counter, so that a replay makes the same ones.
pub fn token_ids(run: RunId) -> TokenIds {
    TokenIds { base: run.0.as_u128(), made: 0 }
}

/// A run's token ids, one after the other (`token_ids`): a counter, kept in a snapshot with the rest.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct TokenIds {
    base: u128,
    made: u64,
}

impl TokenIds {
    pub fn next_id(&mut self) -> TokenId {
        self.made += 1;
        let n = self.made;
        let hi = u128::from(splitmix64(n));
        let lo = u128::from(splitmix64(n ^ 0x5bd1_e995_5bd1_e995));
        TokenId(uuid::Uuid::from_u128(self.base ^ (hi << 64 | lo)))
    }
}

/// SplitMix64's finalizer: a bijection of u64, so distinct counters give distinct ids.
fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

#[derive(serde::Serialize, serde::Deserialize)]
pub(super) struct AgentState {
    pub(super) roles: Vec<String>,
    pub(super) alive: bool,
    pub(super) tokens: usize,
    pub(super) incarnation: uuid::Uuid,
    /// This coordinator started again from its journal and has not heard from the agent since.
    pub(super) recovering: bool,
    /// How long the agent may stay silent before it counts as lost (its own setting).
    pub(super) lease_ms: u64,
    /// More than one process answers to the name: nothing is dispatched to it until one answers alone.
    pub(super) conflict: bool,
    /// Its bound devices it cannot reach (`Layout::io` index → why), as of its device report `devices_seq`.
    pub(super) devices_down: BTreeMap<u32, String>,
    pub(super) devices_seq: u64,
    /// Its current process was sent a dispatch or a join: it takes part in the run, and hears when the writers
    /// it may take values from change (`ToAgent::Peers`).
    pub(super) joined: bool,
    /// When its liveliness token went, while it may still come back (`limits::loss_grace_ms`): it is lost only if
    /// it has not by then.
    pub(super) gone_at_ms: Option<u64>,
    /// The skills its current process announced; `None`: it did not say (it is sent whatever its placement allows).
    #[serde(default)]
    pub(super) skills: Option<BTreeSet<String>>,
}

impl AgentState {
    /// An agent first heard of: not live until it announces itself.
    pub(super) fn new(incarnation: uuid::Uuid, lease_ms: u64) -> AgentState {
        AgentState {
            roles: Vec::new(),
            alive: false,
            tokens: 0,
            incarnation,
            recovering: false,
            lease_ms,
            conflict: false,
            devices_down: BTreeMap::new(),
            devices_seq: 0,
            joined: false,
            gone_at_ms: None,
            skills: None,
        }
    }
}

/// What a token's agent was told of the mode and permits, and what it said back.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub(super) struct TokenGate {
    pub(super) seq: u64,
    pub(super) confirmed: u64,
    pub(super) permit: Option<u32>,
    pub(super) resend_at_ms: u64,
    pub(super) backoff_ms: u64,
}

/// A supervision alarm: whose step, on which token (none: the coordinator's own step), and the acknowledgement
/// on its way to the agent.
#[derive(serde::Serialize, serde::Deserialize)]
pub(super) struct Supervised {
    pub(super) step: StepId,
    pub(super) token: Option<(TokenId, u32)>,
    /// Acknowledged by an operator and not yet applied by the agent: when it is sent again, and the delay after.
    pub(super) ack_resend_at_ms: Option<u64>,
    pub(super) ack_backoff_ms: u64,
}

/// Parts of a run held while the rest goes on (`hold --agent`, `hold --step`).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub(super) struct PartialHolds {
    pub(super) agents: BTreeSet<String>,
    pub(super) steps: BTreeSet<StepId>,
}
