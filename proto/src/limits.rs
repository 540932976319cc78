//! Every limit Baton enforces, in one place, checked against each other at compile time.

/// A chart's text, as UTF-8: one limit for `baton check`, `baton run` and every agent that fetches the chart
/// (spans are u32 byte offsets, so a text must stay below 4 GiB; we stop far earlier).
pub const SOURCE_BYTES_MAX: usize = 16 * 1024 * 1024;

/// A cycle period, in ms (`--cycle-ms`): an hour at most.
pub const CYCLE_MS_MAX: u64 = 3_600_000;

/// Nesting, counted one way wherever a chart's code nests: parentheses, operators (a chain of one operator as
/// deep as it is long, but for AND, OR and XOR, which are built balanced), calls and their arguments, indices,
/// IF/CASE/loop statements, macro steps, and — for what runs — the function blocks, functions and nested charts a
/// body runs inside one another. Deeper input is a located error, never a stack overflow: what `baton check`
/// accepts, every thread that compiles or runs a chart (`CHART_STACK_BYTES`) can hold.
pub const NESTING_DEPTH_MAX: usize = 64;

/// The stack of every thread that compiles or runs a chart (the hosts' main loops and runtimes, `baton test`'s
/// workers). A chart at `NESTING_DEPTH_MAX` needs about 1 MiB in a debug build (measured by the limit test,
/// tests/tests/limits.rs); this leaves room for what the hosts add around it.
pub const CHART_STACK_BYTES: usize = 8 * 1024 * 1024;

/// Nodes (elements, texts, comments) of one XML file: a bound on the memory its tree takes.
pub const XML_NODES_MAX: u32 = 20_000_000;

/// Connections the PLCopen reader follows for one transition or one LD/FBD network: wired logic with shared
/// inputs unfolds into an expression that can grow exponentially with the file.
pub const XML_CONNECTIONS_WALKED_MAX: usize = 100_000;

/// Loop iterations (FOR, WHILE, REPEAT together) in one run of an action body: past that the body stops with a
/// reported fault and the chart goes on, so that a loop whose end never comes cannot hang a cycle.
pub const LOOP_ITERATIONS_MAX: usize = 100_000;

/// Elements of one array variable (each is a variable of the chart).
pub const ARRAY_ELEMENTS_MAX: usize = 1_000_000;

/// Variables of one chart, counting each element of an array and each member of a block instance: the bound on
/// what a declaration can make the compiler hold, whatever the file's size (`ARRAY [0..999999] OF INT` is 21
/// bytes).
pub const VARIABLES_MAX: usize = 1_000_000;

/// Characters of a STRING declared without a length, as CODESYS and TwinCAT have it.
pub const STRING_LENGTH_DEFAULT: usize = 80;

/// Characters of one STRING variable (`STRING[n]`), and of all a chart's STRING variables together: a dispatch
/// carries every variable's value, and even escaped in JSON (six bytes a character at worst) they must fit a message.
pub const STRING_LENGTH_MAX: usize = 4096;
pub const STRING_CHARS_MAX: usize = 64 * 1024;

/// Elements of one structured literal in a skill parameter (a goal, a request, a method's arguments), and
/// mappings of one result: a goal is a message, not a data set.
pub const LITERAL_ELEMENTS_MAX: usize = 65_536;

/// Steps in one chart (and, separately, transitions and actions).
pub const CHART_ELEMENTS_MAX: usize = 4_000_000;

/// Steps named in one `FROM (…)` or `TO (…)` list: the branches of one divergence or convergence.
pub const BRANCHES_MAX: usize = 1024;

/// Situations (sets of active steps) the exhaustive net analysis explores before it gives up and says so.
pub const ANALYSIS_SITUATIONS_MAX: usize = 200_000;

/// Diagnostics reported for one file before the rest are summarised.
pub const DIAGNOSTICS_MAX: usize = 1_000;

/// One message on Baton's keys. A chart's source travels in a reply, so it gets its own, larger limit.
pub const MESSAGE_BYTES_MAX: usize = 1024 * 1024;

/// The reply that serves a chart to agents: its text at `SOURCE_BYTES_MAX`, escaped in JSON at worst (six bytes
/// a byte), with room for the rest. Derived, so that every chart `baton check` accepts reaches every agent.
pub const CHART_SOURCE_BYTES_MAX: usize = 6 * SOURCE_BYTES_MAX + 64 * 1024;

/// Unacknowledged reports an agent lists in its info answer (`AgentInfo::pending`), oldest first, and what they may
/// weigh together (`Report::weight`): the answer stays a message.
pub const PENDING_LISTED_MAX: usize = 32;
pub const PENDING_LISTED_BYTES_MAX: usize = MESSAGE_BYTES_MAX / 2;

/// Reports of one token that arrived ahead of a missing one and wait for it; more are dropped (and resent).
pub const REPORTS_AHEAD_MAX: usize = 256;

/// Bytes of the reports of one token held ahead of a missing one: together with `REPORTS_AHEAD_MAX`, what a peer
/// can make the coordinator hold.
pub const REPORTS_AHEAD_BYTES_MAX: usize = 4 * 1024 * 1024;

/// Older epochs of one token whose stale reports the coordinator traces (once each).
pub const STALE_EPOCHS_TRACED: usize = 16;

/// Bytes of variable updates an agent holds from writers' processes the coordinator has not named yet.
pub const PARKED_UPDATE_BYTES_MAX: usize = 1024 * 1024;

/// Unacknowledged reports an agent keeps per token for resending; past that it numbers no new one until
/// acknowledgements come, and what happens meanwhile waits, coalesced, for the next report.
pub const REPORTS_UNACKED_MAX: usize = 1024;

/// Events in one report: what waited during a long silence leaves in several.
pub const REPORT_EVENTS_MAX: usize = 4096;

/// Finished tokens an agent remembers, to recognise a late duplicate dispatch.
pub const FINISHED_TOKENS_REMEMBERED: usize = 65_536;

/// Rounds of one reaction (`Engine::react`): transitions cleared one after another between two cycles.
pub const REACTION_ROUNDS_MAX: usize = 64;

/// Missed cycles a runtime that fell behind (a stopped process, a loaded machine) runs back to back at their grid
/// times; past that it skips to the present.
pub const CATCH_UP_CYCLES_MAX: u64 = 10;

/// Samples a subscriber holds before Zenoh's reader waits for the process to take them. Large, so that two
/// processes publishing to each other from their main loops never both wait (see the hosts' `put`).
pub const RECEIVE_QUEUE_MAX: usize = 16_384;

/// Answers to `baton set` and `baton ctl` a journaled coordinator holds until what they answer is durable; a request
/// past it is refused at once, untaken (the operator asks again), rather than held without bound.
pub const HELD_REPLIES_MAX: usize = 1024;

/// How long the coordinator may hold acknowledgements to batch them (or send them with the next dispatch to the
/// same agent). Far below the agents' first resend delay, so acknowledged reports are not sent twice.
pub const ACK_DELAY_MS: u64 = 5;

/// The lease fence, for an agent announcing `lease_ms`. An agent whose tokens may be taken away stops their skills
/// once it has not heard its router for `fence_after_ms` (a quarter of its lease), checking every
/// `fence_check_ms`: by `fence_after_ms + 2 · fence_check_ms` after its last contact with the router it has
/// stopped. The router cannot drop the agent before that last contact, and the coordinator gives such a token to
/// another agent only `fence_margin_ms` (half the lease) after the router dropped the agent — however fast the
/// router noticed (a closed socket, a dead link: at once; silence: after the lease). So the two never run the
/// segment at once.
pub const fn fence_after_ms(lease_ms: u64) -> u64 {
    lease_ms / 4
}

pub const fn fence_margin_ms(lease_ms: u64) -> u64 {
    lease_ms / 2
}

pub const fn fence_check_ms(lease_ms: u64) -> u64 {
    let p = lease_ms / 20;
    if p < 5 {
        5
    } else {
        p
    }
}

const fn fence_holds(lease_ms: u64) -> bool {
    fence_after_ms(lease_ms) + 2 * fence_check_ms(lease_ms) < fence_margin_ms(lease_ms)
}
const _: () = assert!(fence_holds(100) && fence_holds(1_000) && fence_holds(10_000) && fence_holds(600_000));

/// How long an agent whose liveliness token went stays live for the coordinator, in case it comes back: a session
/// that Zenoh drops and takes back in milliseconds — zenoh-link-tls 1.10.2 drops a TLS session now and then and
/// reconnects it at once (`tests/tests/zenoh_tls_race.rs`) — is no loss, and raises no alarm. An eighth of the
/// agent's lease, at most `LOSS_GRACE_MS_MAX`; it only delays what a loss does (a reassignment comes later still,
/// so the fence above holds as it did).
pub const LOSS_GRACE_MS_MAX: u64 = 250;

pub const fn loss_grace_ms(lease_ms: u64) -> u64 {
    let g = lease_ms / 8;
    if g < LOSS_GRACE_MS_MAX {
        g
    } else {
        LOSS_GRACE_MS_MAX
    }
}

/// Agents one coordinator tracks (live ones, and lost ones that still hold a token).
pub const AGENTS_MAX: usize = 4096;

/// Skill names an agent's announcement may list (`AgentInfo::skills`); an announcement with more is taken as one
/// that says nothing of its skills.
pub const SKILLS_ANNOUNCED_MAX: usize = 1024;

/// Replaced processes (incarnations) whose late variable values are still recognised and refused.
pub const RETIRED_INCARNATIONS_MAX: usize = 256;

const _: () = assert!(CHART_SOURCE_BYTES_MAX >= MESSAGE_BYTES_MAX);
const _: () = assert!(ARRAY_ELEMENTS_MAX <= VARIABLES_MAX && VARIABLES_MAX < u32::MAX as usize);
const _: () = assert!(SOURCE_BYTES_MAX < u32::MAX as usize);
const _: () = assert!(CHART_ELEMENTS_MAX < u32::MAX as usize);
const _: () = assert!(BRANCHES_MAX <= CHART_ELEMENTS_MAX);
const _: () = assert!(NESTING_DEPTH_MAX >= 16);
// The strings of a dispatch, escaped at worst, fill at most half a message.
const _: () = assert!(STRING_LENGTH_DEFAULT <= STRING_LENGTH_MAX && STRING_LENGTH_MAX <= STRING_CHARS_MAX);
const _: () = assert!(STRING_CHARS_MAX * 6 * 2 <= MESSAGE_BYTES_MAX);

/// Characters kept of why a bound device cannot be reached (`DeviceReport`): a peer's text is bounded.
pub const DEVICE_MESSAGE_CHARS_MAX: usize = 1024;

/// Alarms a run keeps standing at once (active, or waiting for an acknowledgement); a raise past it is counted
/// and refused, never grows the list.
pub const ALARMS_STANDING_MAX: usize = 1024;

/// The longest an operator may shelve an alarm: shelving is bounded in time (ISA-18.2).
pub const ALARM_SHELVE_MAX_MS: u64 = 8 * 3_600_000;

/// Characters kept of an alarm's message, an acknowledgement's comment and the name of who gave it.
pub const ALARM_TEXT_CHARS_MAX: usize = 1024;

/// The longest step supervision time (`min_ms`): a year, in milliseconds.
pub const SUPERVISION_MS_MAX: u64 = 365 * 86_400_000;
