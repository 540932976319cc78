//! The names of a POU's nested charts (`Nested`) as the compiler resolves them: kept in the `Compiler`, filled
//! and read by `nested.rs`.

use std::collections::HashMap;

use crate::exec::program::VarId;

/// The nested charts of one POU (the chart, or one user block instance) as the compiler resolves their names.
#[derive(Default)]
pub(super) struct Nested {
    /// Each nested step's `[x, since, last]`, by `ACTION.STEP` always and by `STEP` where one chart has it.
    pub(super) steps: HashMap<String, [VarId; 3]>,
    /// Step names that the charts of several actions have, with those actions' names.
    pub(super) shared: HashMap<String, Vec<String>>,
    /// The `Q` and `stored` of each action a chart controls, by (chart's action, controlled action), keys.
    pub(super) controlled: HashMap<(String, String), (VarId, VarId)>,
    /// The charts that control each action, by its key, as written.
    pub(super) controllers: HashMap<String, Vec<String>>,
    /// Each chart's `started`, by its action's key.
    pub(super) started: HashMap<String, VarId>,
    /// The chart being compiled (its action's key), whose own steps and actions its names find first.
    pub(super) current: Option<String>,
}

impl Nested {
    pub(super) fn controlled_keys(&self) -> impl Iterator<Item = &String> {
        self.controllers.keys()
    }

    /// The step a name (key) means: the current chart's first, then the one chart that has it.
    pub(super) fn step(&self, key: &str) -> Option<[VarId; 3]> {
        if let Some(own) = self.current.as_ref().and_then(|c| self.steps.get(&format!("{c}.{key}"))) {
            return Some(*own);
        }
        self.steps.get(key).copied()
    }

    /// The actions whose charts all have a step of this name (key), where there are several and none is current.
    pub(super) fn ambiguous(&self, key: &str) -> Option<&[String]> {
        if self.current.as_ref().is_some_and(|c| self.steps.contains_key(&format!("{c}.{key}"))) {
            return None;
        }
        self.shared.get(key).map(Vec::as_slice)
    }

    /// The `Q` of a controlled action (key): the current chart's, or that of the one chart controlling it.
    pub(super) fn q(&self, key: &str) -> Option<VarId> {
        if let Some(&(q, _)) = self.current.as_ref().and_then(|c| self.controlled.get(&(c.clone(), key.to_string()))) {
            return Some(q);
        }
        match self.controllers.get(key).map(Vec::as_slice) {
            Some([one]) => self.controlled.get(&(one.to_ascii_uppercase(), key.to_string())).map(|&(q, _)| q),
            _ => None,
        }
    }
}
