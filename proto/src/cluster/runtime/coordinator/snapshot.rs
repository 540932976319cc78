//! A coordinator's whole state in bytes (`snapshot`), and a coordinator made from them (`restore`): what a
//! journal's snapshot holds (`cluster::journal`), so that a resumed run replays only the records after it.
//!
//! Everything the coordinator keeps goes in — its engine to the last generation counter, tokens, agents, alarms,
//! timers, the outputs not yet taken — except the program and layout, which the journal pins and the restorer
//! gives. So a restored coordinator is the one that was snapshotted: given the same inputs it gives the same
//! outputs, and its own snapshot is the same bytes. CBOR (`ciborium`): self-describing, so the wire types' optional
//! fields read back, and binary, so a REAL value comes back to the bit.

use std::sync::Arc;

use crate::cluster::layout::Layout;
use crate::exec::program::Program;

use super::state::TokenState;
use super::Coordinator;

/// A snapshot that cannot be restored: malformed, or made from another chart.
#[derive(Debug, thiserror::Error, PartialEq)]
#[error("cannot be restored: {0}")]
pub struct SnapshotError(pub String);

impl Coordinator {
    /// The coordinator's state. Taken between inputs, after the outputs were taken (`has_output` false), it holds
    /// nothing in flight; taken otherwise, the outputs not yet taken are in it too.
    pub fn snapshot(&self) -> Vec<u8> {
        let mut out = Vec::new();
        ciborium::into_writer(self, &mut out).expect("a coordinator serializes: it holds no foreign types");
        out
    }

    /// The coordinator `snapshot` gave, for `program` and `layout` (those the journal's header pins).
    pub fn restore(program: Arc<Program>, layout: Arc<Layout>, bytes: &[u8]) -> Result<Coordinator, SnapshotError> {
        let mut core: Coordinator = ciborium::from_reader(bytes).map_err(|e| SnapshotError(e.to_string()))?;
        core.engine.attach(Arc::clone(&program)).map_err(SnapshotError)?;
        core.fits(&program, &layout).map_err(SnapshotError)?;
        core.program = program;
        core.layout = layout;
        Ok(core)
    }

    /// Whether what the coordinator holds names only what the chart has, so that nothing indexes past it.
    fn fits(&self, program: &Program, layout: &Layout) -> Result<(), String> {
        let (n_steps, n_segments) = (program.steps.len(), layout.segments.len());
        if self.by_segment.len() != n_segments {
            return Err(format!("it holds {} segments where the chart has {n_segments}", self.by_segment.len()));
        }
        if self.owned.len() != self.published.len() || self.owned.iter().any(|v| v.index() >= program.vars.len()) {
            return Err("its published variables do not fit the chart".into());
        }
        if !self.var_writes.fits(program.vars.len()) {
            return Err("its variable writes do not fit the chart".into());
        }
        let token_fits = |t: &TokenState| t.segment.0 < n_segments as u32 && t.entry.index() < n_steps;
        if !self.tokens.values().all(token_fits) {
            return Err("a token it holds is in a segment or step the chart does not have".into());
        }
        let steps = self.partial.steps.iter().copied().chain(self.supervised.values().map(|s| s.step));
        if steps.clone().any(|s| s.index() >= n_steps)
            || self.agent_waiting.iter().any(|t| t.index() >= program.transitions.len())
        {
            return Err("it names a step or a transition the chart does not have".into());
        }
        let by_segment_fits = self.by_segment.iter().flatten().all(|id| self.tokens.contains_key(id));
        if !by_segment_fits || !self.waiting.iter().all(|id| self.tokens.contains_key(id)) {
            return Err("it names a token it does not hold".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cluster::journal::token_ids;
    use crate::cluster::wire::ChartHash;
    use crate::cluster::wire::RunId;

    #[test]
    fn garbage_and_another_charts_snapshot_are_refused() {
        let (program, layout) = crate::testing::simulated_cluster::compile(
            "PROGRAM p\nVAR go : BOOL; END_VAR\nINITIAL_STEP A: END_STEP\n\
             TRANSITION FROM A TO B := go; END_TRANSITION\nSTEP B: {agent := 'r1'} END_STEP\n\
             TRANSITION FROM B TO C := TRUE; END_TRANSITION\nSTEP C: END_STEP\nEND_PROGRAM\n",
        );
        let run = RunId(uuid::Uuid::from_u128(9));
        let core =
            Coordinator::new(Arc::clone(&program), Arc::clone(&layout), run, ChartHash("h".into()), token_ids(run));
        let bytes = core.snapshot();
        let again = Coordinator::restore(Arc::clone(&program), Arc::clone(&layout), &bytes).expect("restores");
        assert_eq!(again.snapshot(), bytes);
        for cut in [0, 1, bytes.len() / 2, bytes.len() - 1] {
            assert!(Coordinator::restore(Arc::clone(&program), Arc::clone(&layout), &bytes[..cut]).is_err(), "{cut}");
        }
        let (other, other_layout) = crate::testing::simulated_cluster::compile(
            "PROGRAM p\nVAR go : BOOL; END_VAR\nINITIAL_STEP A: END_STEP\n\
             TRANSITION FROM A TO B := go; END_TRANSITION\nSTEP B: END_STEP\nEND_PROGRAM\n",
        );
        let err = Coordinator::restore(other, other_layout, &bytes).err().expect("refused").to_string();
        assert!(err.contains("where the chart has"), "{err}");
    }
}
