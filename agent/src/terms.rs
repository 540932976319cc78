//! The highest coordinator term this agent has heard in each run, kept on disk: a restarted agent still refuses
//! what a deposed coordinator sends (a coordinator paused past its lease, say, that wakes and sends before it
//! sees it lost), as the process before it did. Without it, the restarted agent would take the deposed one's
//! commands until the active coordinator's next message.
//!
//! One small file per agent name, `<state>/terms/<name>.json`: the last `RUNS_KEPT` runs' terms, rewritten whole
//! (written apart, `fsync`'d, renamed) each time a term rises — once per run and election, before the host carries
//! out what the message asked. A state folder that cannot be written costs the memory, not the agent: it says so
//! once and goes on.

use std::io::Write;
use std::path::{Path, PathBuf};

use baton_proto::cluster::wire::RunId;

/// Runs whose terms are kept, the most recently raised last.
const RUNS_KEPT: usize = 256;

pub struct Terms {
    /// The file, while it can be written.
    path: Option<PathBuf>,
    known: Vec<(RunId, u64)>,
}

impl Terms {
    /// The terms the agent `name` remembers in the folder `state` (`None`: it remembers none).
    pub fn open(state: Option<&Path>, name: &str) -> Terms {
        let Some(state) = state else { return Terms { path: None, known: Vec::new() } };
        let path = state.join("terms").join(format!("{name}.json"));
        let known = match std::fs::read(&path) {
            Ok(bytes) => serde_json::from_slice::<Vec<(RunId, u64)>>(&bytes).unwrap_or_else(|e| {
                eprintln!("warning: {} is not a list of runs' terms ({e}): starting from none", path.display());
                Vec::new()
            }),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
            Err(e) => {
                eprintln!("warning: cannot read the coordinators' terms from {}: {e}", path.display());
                Vec::new()
            }
        };
        Terms { path: Some(path), known }
    }

    /// The highest term remembered of `run` (0: none).
    pub fn of(&self, run: RunId) -> u64 {
        self.known.iter().find(|(r, _)| *r == run).map_or(0, |(_, t)| *t)
    }

    /// Remembers `term` for `run` where it is higher than what is remembered, durably before returning.
    pub fn raise(&mut self, run: RunId, term: u64) {
        if term <= self.of(run) {
            return;
        }
        self.known.retain(|(r, _)| *r != run);
        self.known.push((run, term));
        if self.known.len() > RUNS_KEPT {
            self.known.remove(0);
        }
        let Some(path) = &self.path else { return };
        if let Err(e) = write_durably(path, &serde_json::to_vec(&self.known).unwrap_or_default()) {
            eprintln!(
                "warning: cannot keep the coordinators' terms in {}: {e}; after a restart this agent takes a deposed \
                 coordinator's commands until the active one speaks",
                path.display()
            );
            self.path = None;
        }
    }
}

fn write_durably(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir)?;
    let new = path.with_extension("json.new");
    let mut file = std::fs::File::create(&new)?;
    file.write_all(bytes)?;
    file.sync_all()?;
    std::fs::rename(&new, path)?;
    std::fs::File::open(dir)?.sync_all()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(n: u128) -> RunId {
        RunId(uuid::Uuid::from_u128(n))
    }

    #[test]
    fn a_term_raised_is_remembered_by_the_next_process_and_only_ever_rises() {
        let dir = tempfile::tempdir().expect("temp dir");
        let mut terms = Terms::open(Some(dir.path()), "r1");
        assert_eq!(terms.of(run(1)), 0);
        terms.raise(run(1), 9);
        terms.raise(run(1), 4);
        terms.raise(run(2), 3);
        let again = Terms::open(Some(dir.path()), "r1");
        assert_eq!((again.of(run(1)), again.of(run(2))), (9, 3), "read back by a restarted agent");
        assert_eq!(Terms::open(Some(dir.path()), "r2").of(run(1)), 0, "each agent name its own");
        let mut many = again;
        for n in 0..RUNS_KEPT as u128 + 10 {
            many.raise(run(100 + n), 1);
        }
        let kept = Terms::open(Some(dir.path()), "r1");
        assert_eq!(kept.known.len(), RUNS_KEPT);
        assert_eq!(kept.of(run(1)), 0, "the oldest forgotten first");
        assert_eq!(kept.of(run(100 + RUNS_KEPT as u128 + 9)), 1);
    }

    #[test]
    fn a_state_folder_that_cannot_be_written_costs_the_memory_not_the_agent() {
        let dir = tempfile::tempdir().expect("temp dir");
        let file = dir.path().join("not-a-folder");
        std::fs::write(&file, b"x").expect("a file");
        let mut terms = Terms::open(Some(&file), "r1");
        terms.raise(run(1), 5);
        assert_eq!(terms.of(run(1)), 5, "still known to this process");
        std::fs::create_dir_all(dir.path().join("terms")).expect("mkdir");
        std::fs::write(dir.path().join("terms/damaged.json"), b"{").expect("write");
        let damaged = Terms::open(Some(dir.path()), "damaged");
        assert_eq!(damaged.of(run(1)), 0);
    }
}
