//! Where a chart's parts are drawn: one layered layout, which the PLCopen export writes as positions and the SVG
//! drawing (`back::svg`) draws. Steps go in rows by their breadth-first distance from the initial steps (a step
//! nothing reaches from them starts a row below the deepest so far), and in columns in the order they are reached
//! within a row (a step's first branch left of its second); a transition sits under its first source step, its branch of a selection divergence a column right of the
//! one before; a transition to a step on its own row or above is drawn as a jump.

use std::collections::{BTreeMap, VecDeque};

use crate::exec::program::{Program, StepId, TransitionId};

/// A step's box.
pub const STEP_W: i64 = 120;
pub const STEP_H: i64 = 30;
/// From one column, or one row, to the next: a column holds a step, its action block (200 wide, 30 to its right)
/// and a condition's text beside a bar.
pub const COLUMN: i64 = 420;
pub const ROW: i64 = 200;
/// From one branch of a selection divergence to the next: a column, so that branches into the steps of the next
/// row (which come in the same order) run straight down.
pub const BRANCH: i64 = COLUMN;
/// The margin around the chart.
pub const MARGIN: i64 = 40;

/// The layout of one chart: each step's row and column.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Diagram {
    /// Per step (by `StepId`): its row and its column.
    pub at: Vec<(i64, i64)>,
}

impl Diagram {
    /// Rows by breadth-first distance from the initial steps (steps nothing reaches after them), columns in the
    /// order the breadth-first walk reaches each row.
    pub fn lay_out(p: &Program) -> Diagram {
        let n = p.steps.len();
        let mut at = vec![(i64::MAX, 0); n];
        // Columns in the order the rows are reached: the targets of a step's first branch left of its second's.
        let mut columns: BTreeMap<i64, i64> = BTreeMap::new();
        let mut place = |at: &mut Vec<(i64, i64)>, s: StepId, row: i64| {
            let c = columns.entry(row).or_insert(0);
            at[s.index()] = (row, *c);
            *c += 1;
        };
        let mut queue = VecDeque::new();
        for &s in &p.initial_steps {
            place(&mut at, s, 0);
            queue.push_back(s);
        }
        let mut next_root = 0;
        loop {
            while let Some(s) = queue.pop_front() {
                let row = at[s.index()].0;
                for &t in p.outgoing(s) {
                    for &u in p.targets(t) {
                        if at[u.index()].0 == i64::MAX {
                            place(&mut at, u, row + 1);
                            queue.push_back(u);
                        }
                    }
                }
            }
            while next_root < n && at[next_root].0 != i64::MAX {
                next_root += 1;
            }
            if next_root == n {
                break;
            }
            let deepest = at.iter().map(|a| a.0).filter(|&r| r != i64::MAX).max().unwrap_or(-1);
            place(&mut at, StepId(next_root as u32), deepest + 1);
            queue.push_back(StepId(next_root as u32));
        }
        Diagram { at }
    }

    /// The top left corner of step `s`'s box.
    pub fn step_xy(&self, s: StepId) -> (i64, i64) {
        let (r, c) = self.at[s.index()];
        (MARGIN + c * COLUMN, MARGIN + r * ROW)
    }

    /// The row of step `s`.
    pub fn row(&self, s: StepId) -> i64 {
        self.at[s.index()].0
    }

    /// Where transition `t` is drawn: the left edge of its column and the height of its bar, below its lowest
    /// source. Under a step with one
    /// transition, the step's column; the branches of a selection divergence left to right in priority order, each
    /// over its first target in the next row where it can be (`branch_xs`). A transition without sources (none in a
    /// checked chart) is at the margin.
    pub fn transition_xy(&self, p: &Program, t: TransitionId) -> (i64, i64) {
        let Some(&first) = p.sources(t).first() else { return (MARGIN, MARGIN + STEP_H + 70) };
        let branch = p.outgoing(first).iter().position(|&u| u == t).unwrap_or(0);
        // Below the lowest of its sources (a simultaneous convergence may join steps of several rows).
        let lowest = p.sources(t).iter().map(|&s| self.step_xy(s).1).max().unwrap_or(MARGIN);
        (self.branch_xs(p, first)[branch], lowest + STEP_H + 70)
    }

    /// The left edges of the columns of step `s`'s outgoing transitions, in priority order: each over its first
    /// target in the row below if that is right of the branch before, else a column right of it (the first
    /// branch, without such a target, under the step).
    pub fn branch_xs(&self, p: &Program, s: StepId) -> Vec<i64> {
        let (sx, _) = self.step_xy(s);
        let leaving = p.outgoing(s);
        if leaving.len() < 2 {
            return vec![sx; leaving.len()];
        }
        let mut xs: Vec<i64> = Vec::with_capacity(leaving.len());
        for &t in leaving {
            let below = p.targets(t).iter().find(|&&u| self.row(u) == self.row(s) + 1).map(|&u| self.step_xy(u).0);
            let x = match xs.last() {
                None => below.unwrap_or(sx),
                Some(&before) => below.filter(|&x| x > before).unwrap_or(before + BRANCH),
            };
            xs.push(x);
        }
        xs
    }

    /// Whether transition `t` reaches step `u` by a jump (`u` on the row of `t`'s sources or above).
    pub fn is_jump(&self, p: &Program, t: TransitionId, u: StepId) -> bool {
        let row = p.sources(t).iter().map(|&s| self.row(s)).max().unwrap_or(0);
        self.row(u) <= row
    }
}
