//! Baton's element order (`ORDER_DATA`): an export's steps, transitions and actions read back in the order they were
//! written.

use std::collections::HashMap;

use roxmltree::Node;

use crate::front::model::Chart;
use crate::front::plcopen::xml::{child, is};

use super::ORDER_DATA;

/// Baton's element order from a POU's `addData` (see `ORDER_DATA`): step names, transition
/// `localId`s and action names.
pub(super) struct BatonOrder {
    pub(super) steps: Vec<String>,
    pub(super) transitions: Vec<u64>,
    pub(super) actions: Vec<String>,
}

pub(super) fn baton_order(pou: Node) -> Option<BatonOrder> {
    let data = child(pou, "addData")?.children().find(|d| is(d, "data") && d.attribute("name") == Some(ORDER_DATA))?;
    let order = child(data, "order")?;
    let words = |attr: &str| -> Vec<String> {
        order.attribute(attr).unwrap_or_default().split_whitespace().map(str::to_ascii_uppercase).collect()
    };
    Some(BatonOrder {
        steps: words("steps"),
        transitions: words("transitions").iter().filter_map(|w| w.parse().ok()).collect(),
        actions: words("actions"),
    })
}

/// Orders the chart's elements as the order data says; what it does not name keeps its place after them.
pub(super) fn apply_order(chart: &mut Chart, transition_ids: &[Option<u64>], order: &BatonOrder) {
    pub(super) fn rank<T>(items: &mut Vec<T>, key: impl Fn(usize, &T) -> Option<usize>) {
        let mut keyed: Vec<(usize, usize, T)> =
            items.drain(..).enumerate().map(|(i, t)| (key(i, &t).unwrap_or(usize::MAX), i, t)).collect();
        keyed.sort_by_key(|(k, i, _)| (*k, *i));
        items.extend(keyed.into_iter().map(|(_, _, t)| t));
    }
    let position =
        |list: &[String]| -> HashMap<String, usize> { list.iter().enumerate().map(|(i, n)| (n.clone(), i)).collect() };
    let steps = position(&order.steps);
    rank(&mut chart.steps, |_, s| steps.get(&s.name.key()).copied());
    let transitions: HashMap<u64, usize> = order.transitions.iter().enumerate().map(|(i, id)| (*id, i)).collect();
    rank(&mut chart.transitions, |i, _| {
        transition_ids.get(i).copied().flatten().and_then(|id| transitions.get(&id).copied())
    });
    let actions = position(&order.actions);
    rank(&mut chart.actions, |_, a| actions.get(&a.name.key()).copied());
}

/// Orders steps, transitions and actions as Beremiz's generator writes the chart out for matiec (and so as
/// OpenPLC runs it): depth first from the initial steps, each step followed by its actions and its outgoing
/// transitions in priority order, each transition by the steps it leads to. Action order is execution order
/// within a cycle, so a chart imported from XML runs as it does in the tool that drew it. What the walk does not
/// reach keeps its document order, after the rest.
pub(super) fn walk_order(chart: &mut Chart) {
    let step_of: HashMap<String, usize> = chart.steps.iter().enumerate().map(|(i, s)| (s.name.key(), i)).collect();
    let mut outgoing: Vec<Vec<usize>> = vec![Vec::new(); chart.steps.len()];
    for (t, tr) in chart.transitions.iter().enumerate() {
        for from in &tr.from {
            if let Some(&s) = step_of.get(&from.key()) {
                outgoing[s].push(t);
            }
        }
    }
    let (mut visited, mut placed) = (vec![false; chart.steps.len()], vec![false; chart.transitions.len()]);
    let (mut step_order, mut transition_order) = (Vec::new(), Vec::new());
    // (step, next outgoing transition, the transition whose targets are being visited and the next target)
    type Frame = (usize, usize, Option<(usize, usize)>);
    let mut frames: Vec<Frame> = Vec::new();
    let roots: Vec<usize> =
        (0..chart.steps.len()).filter(|&i| chart.steps[i].initial).chain(0..chart.steps.len()).collect();
    for root in roots {
        if visited[root] {
            continue;
        }
        visited[root] = true;
        step_order.push(root);
        frames.push((root, 0, None));
        while let Some(frame) = frames.last_mut() {
            if let Some((t, k)) = frame.2 {
                let targets = &chart.transitions[t].to;
                if k < targets.len() {
                    frame.2 = Some((t, k + 1));
                    if let Some(&s) = step_of.get(&targets[k].key()) {
                        if !visited[s] {
                            visited[s] = true;
                            step_order.push(s);
                            frames.push((s, 0, None));
                        }
                    }
                } else {
                    frame.2 = None;
                }
                continue;
            }
            let step = frame.0;
            if frame.1 < outgoing[step].len() {
                let t = outgoing[step][frame.1];
                frame.1 += 1;
                if !placed[t] {
                    placed[t] = true;
                    transition_order.push(t);
                    frame.2 = Some((t, 0));
                }
                continue;
            }
            frames.pop();
        }
    }
    transition_order.extend((0..chart.transitions.len()).filter(|&t| !placed[t]));
    let action_of: HashMap<String, usize> = chart.actions.iter().enumerate().map(|(i, a)| (a.name.key(), i)).collect();
    let mut action_placed = vec![false; chart.actions.len()];
    let mut action_order = Vec::new();
    for &s in &step_order {
        for association in &chart.steps[s].associations {
            if let Some(&a) = action_of.get(&association.action.key()) {
                if !std::mem::replace(&mut action_placed[a], true) {
                    action_order.push(a);
                }
            }
        }
    }
    action_order.extend((0..chart.actions.len()).filter(|&a| !action_placed[a]));
    pub(super) fn reorder<T>(items: &mut Vec<T>, order: &[usize]) {
        let mut slots: Vec<Option<T>> = std::mem::take(items).into_iter().map(Some).collect();
        items.extend(order.iter().filter_map(|&i| slots[i].take()));
    }
    reorder(&mut chart.steps, &step_order);
    reorder(&mut chart.transitions, &transition_order);
    reorder(&mut chart.actions, &action_order);
}
