//! Every limit Baton enforces, in one place, checked against each other at compile time.

/// Spans are u32 byte offsets, so a source text must stay below 4 GiB; we stop far earlier.
pub const SOURCE_BYTES_MAX: usize = 256 * 1024 * 1024;

/// Nesting of parentheses, unary operators and IF statements; deeper input is rejected, not overflowed.
pub const NESTING_DEPTH_MAX: usize = 64;

/// Steps in one chart (and, separately, transitions and actions).
pub const CHART_ELEMENTS_MAX: usize = 4_000_000;

/// Steps named in one `FROM (…)` or `TO (…)` list: the branches of one divergence or convergence.
pub const BRANCHES_MAX: usize = 1024;

/// Situations (sets of active steps) the exhaustive net analysis explores before it gives up and says so.
pub const ANALYSIS_SITUATIONS_MAX: usize = 200_000;

/// Diagnostics reported for one file before the rest are summarised.
pub const DIAGNOSTICS_MAX: usize = 1_000;

const _: () = assert!(SOURCE_BYTES_MAX < u32::MAX as usize);
const _: () = assert!(CHART_ELEMENTS_MAX < u32::MAX as usize);
const _: () = assert!(BRANCHES_MAX <= CHART_ELEMENTS_MAX);
const _: () = assert!(NESTING_DEPTH_MAX >= 16);
