//! What skills agents offer, as the desk and the coordinator know them.
//!
//! A chart binds an action to a skill by name (`{skill := 'motion', ms := 800}`); the agent that runs the action
//! must have a skill of that name. Three places know which names exist, so that a misspelt one is found before a
//! robot waits for it:
//! - `baton check` knows the skills `baton-agent` ships (`Catalogue::builtin`) and those a `--skills FILE` lists
//!   (what `baton-agent --list-skills` prints, or a file the user writes), and warns of an unknown name or
//!   parameter with a suggestion (`check`);
//! - `baton test` refuses a scenario whose chart binds a skill neither built in nor simulated;
//! - every agent announces the names it has (`wire::AgentInfo::skills`), and the coordinator sends a segment only
//!   to an agent that has every skill its steps run (`Layout::segment_skills`), raising an alarm that names the
//!   agent and the skill otherwise.

use std::collections::BTreeSet;

use serde::{Deserialize, Serialize};

use crate::cluster::layout::{Layout, OUTPUT_KEYS};
use crate::exec::program::Program;
use crate::front::diag::Diagnostic;
use crate::front::pragma::{did_you_mean, nearest};

/// One skill: its name and, where known, the parameters it reads.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SkillSpec {
    pub name: String,
    /// The keys it reads; absent: any (a custom skill nobody described).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub params: Option<Vec<String>>,
    /// The keys it cannot do without.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub required: Vec<String>,
    /// What it does, in a line.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub summary: String,
}

/// Keys any binding may carry, whatever its skill: what a hold does to it (`layout::skill_bindings` reads it).
pub const COMMON_KEYS: [&str; 1] = ["hold"];

/// The skills known by name: a `--skills` file, or what an agent prints with `--list-skills`.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Catalogue {
    #[serde(default)]
    pub skills: Vec<SkillSpec>,
}

fn spec(name: &str, params: &[&str], required: &[&str], summary: &str) -> SkillSpec {
    SkillSpec {
        name: name.to_string(),
        params: Some(params.iter().map(|p| p.to_string()).collect()),
        required: required.iter().map(|p| p.to_string()).collect(),
        summary: summary.to_string(),
    }
}

impl Catalogue {
    /// The skills `baton-agent` ships: `motion` always, `shell` with `--allow-shell`, the ROS 2 ones with a ROS 2
    /// connection, `opcua_method` with OPC UA (the book's skills, ROS 2 and OPC UA chapters).
    pub fn builtin() -> Catalogue {
        let opcua_endpoint = ["endpoint", "security", "policy", "user", "password"];
        let mut opcua: Vec<&str> = opcua_endpoint.to_vec();
        opcua.extend([
            "object",
            "method",
            "args",
            "timeout_ms",
            "result_nodes",
            "done_node",
            "fault_node",
            "cancel_method",
            "result",
            "outputs",
        ]);
        Catalogue {
            skills: vec![
                spec(
                    "motion",
                    &["ms", "fault_rate"],
                    &[],
                    "a simulated motion: waits `ms`, fails with probability `fault_rate`",
                ),
                spec("shell", &["cmd"], &["cmd"], "runs `sh -c cmd` (only on agents started with --allow-shell)"),
                spec(
                    "ros2_action",
                    &["action", "type", "goal", "result", "feedback", "timeout_ms"],
                    &["action", "type"],
                    "sends a ROS 2 action goal and waits for its result",
                ),
                spec(
                    "ros2_service",
                    &["service", "type", "request", "response", "fault_if_false", "timeout_ms"],
                    &["service", "type"],
                    "calls a ROS 2 service",
                ),
                spec("opcua_method", &opcua, &["endpoint", "object", "method"], "calls a method of an OPC UA server"),
            ],
        }
    }

    /// A catalogue file: TOML (`[[skills]]` tables with `name`, `params`, `required`), or JSON of the same shape
    /// when `json`.
    pub fn parse(text: &str, json: bool) -> Result<Catalogue, String> {
        let read: Catalogue = if json {
            serde_json::from_str(text).map_err(|e| e.to_string())?
        } else {
            toml::from_str(text).map_err(|e| e.to_string())?
        };
        for s in &read.skills {
            if !crate::cluster::keys::is_valid_name(&s.name) {
                return Err(format!("`{}` is not a skill name: letters, digits, `_` or `-`", s.name));
            }
            if let Some(missing) = s.required.iter().find(|r| s.params.as_ref().is_some_and(|p| !p.contains(r))) {
                return Err(format!("skill `{}` requires `{missing}` but does not list it in its params", s.name));
            }
        }
        Ok(read)
    }

    /// The catalogue as TOML, as `parse` reads it.
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a catalogue is plain data")
    }

    /// Adds `other`'s skills; one of the same name replaces the one known before.
    pub fn merge(&mut self, other: Catalogue) {
        for s in other.skills {
            match self.skills.iter_mut().find(|k| k.name == s.name) {
                Some(known) => *known = s,
                None => self.skills.push(s),
            }
        }
    }

    /// The skills of `names`, as an agent that has them is known: a built-in one with its parameters, any other
    /// with its parameters left open; each name once, in the order given.
    pub fn of_names(names: impl IntoIterator<Item = String>) -> Catalogue {
        let builtin = Catalogue::builtin();
        let mut out = Catalogue::default();
        for name in names {
            if out.get(&name).is_none() {
                let spec = builtin.get(&name).cloned().unwrap_or(SkillSpec {
                    name,
                    params: None,
                    required: Vec::new(),
                    summary: String::new(),
                });
                out.skills.push(spec);
            }
        }
        out
    }

    pub fn get(&self, name: &str) -> Option<&SkillSpec> {
        self.skills.iter().find(|s| s.name == name)
    }

    pub fn names(&self) -> impl Iterator<Item = &str> + '_ {
        self.skills.iter().map(|s| s.name.as_str())
    }
}

/// What `known` says of the chart's skill bindings: a skill it does not have, a parameter its skill does not
/// read, one it needs and lacks — warnings, with the nearest known name. An agent decides in the end (it may
/// offer a skill nobody listed); these are what would otherwise be found on the robot.
pub fn check(program: &Program, layout: &Layout, known: &Catalogue) -> Vec<Diagnostic> {
    let mut out = Vec::new();
    for (i, binding) in layout.skills.iter().enumerate() {
        let Some(b) = binding else { continue };
        let action = &program.actions[i].name;
        let Some(spec) = known.get(&b.skill) else {
            let names: Vec<&str> = known.names().collect();
            let hint = match nearest(&b.skill, names.iter().copied()) {
                Some(n) => format!("did you mean `{n}`?"),
                None => format!("the skills known are {}.", names.join(", ")),
            };
            out.push(Diagnostic::warning(
                b.span,
                format!(
                    "action `{action}` uses skill `{}`, which no agent is known to have: {hint} An agent without it \
                     is sent nothing of this action's steps (list custom skills with --skills FILE)",
                    b.skill
                ),
            ));
            continue;
        };
        let Some(params) = &spec.params else { continue };
        let accepted: BTreeSet<&str> = params.iter().map(String::as_str).chain(COMMON_KEYS).collect();
        for key in b.params.keys() {
            if accepted.contains(key.as_str()) {
                continue;
            }
            let what = if OUTPUT_KEYS.contains(&key.as_str()) { "mapping" } else { "parameter" };
            out.push(Diagnostic::warning(
                b.span,
                format!(
                    "skill `{}` of action `{action}` has no {what} `{key}`{} (it reads: {})",
                    b.skill,
                    did_you_mean(key, accepted.iter().copied()),
                    params.join(", ")
                ),
            ));
        }
        for need in spec.required.iter().filter(|r| !b.params.contains_key(r.as_str())) {
            out.push(Diagnostic::warning(
                b.span,
                format!("skill `{}` of action `{action}` needs `{need} := …`: the agent faults it without", b.skill),
            ));
        }
    }
    out
}

/// For `baton test`: each action whose skill is neither built in nor one `simulated` accepts (by action index and
/// skill name), said with the nearest built-in name and how to simulate it.
pub fn not_built_in(program: &Program, layout: &Layout, simulated: impl Fn(usize, &str) -> bool) -> Vec<String> {
    let builtin = Catalogue::builtin();
    let mut out = Vec::new();
    for (i, binding) in layout.skills.iter().enumerate() {
        let Some(b) = binding else { continue };
        if builtin.get(&b.skill).is_some() || simulated(i, &b.skill) {
            continue;
        }
        let action = &program.actions[i].name;
        let hint = nearest(&b.skill, builtin.names()).map(|n| format!("did you mean `{n}`? ")).unwrap_or_default();
        out.push(format!(
            "action `{action}` of the chart uses skill `{}`, which is not built in and which the scenario does not \
             simulate: {hint}A custom skill is simulated by saying what it does in `[actions.{action}]`, or by naming \
             it in an agent's `skills`",
            b.skill
        ));
    }
    out
}

/// The skills of the actions `segment` runs that `has` lacks, each with the first action that binds it and the
/// first step of the segment that runs that action.
pub fn lacking<'a>(
    program: &'a Program,
    layout: &'a Layout,
    segment: usize,
    has: &BTreeSet<String>,
) -> Vec<(&'a str, &'a str, &'a str)> {
    let mut out: Vec<(&str, &str, &str)> = Vec::new();
    for a in &layout.segment_skills[segment] {
        let Some(b) = &layout.skills[a.index()] else { continue };
        if !has.contains(&b.skill) && !out.iter().any(|(s, _, _)| *s == b.skill) {
            let steps = &layout.segments[segment].steps;
            let step = steps.iter().find(|&&s| program.associations(s).iter().any(|x| x.action == *a));
            let step = step.map_or("", |s| program.steps[s.index()].name.as_str());
            out.push((b.skill.as_str(), program.actions[a.index()].name.as_str(), step));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::check_source;

    fn warnings(src: &str, known: &Catalogue) -> Vec<String> {
        let report = check_source(src);
        assert_eq!(report.error_count(), 0, "{:?}", report.diagnostics);
        let c = &report.charts[0];
        check(c.program.as_ref().unwrap(), c.layout.as_ref().unwrap(), known).into_iter().map(|d| d.message).collect()
    }

    const CHART: &str = "PROGRAM p\nVAR done : BOOL; END_VAR\n\
        ACTION Pick: {skill := 'motoin', ms := 800} END_ACTION\n\
        ACTION Place: {skill := 'motion', mss := 800, hold := 'cancel'} END_ACTION\n\
        ACTION Grip: {skill := 'grip', force := 20} END_ACTION\n\
        ACTION Run: {skill := 'shell'} END_ACTION\n\
        INITIAL_STEP A: {agent := 'r1'} Pick(N, done); Place(N); Grip(N); Run(N); END_STEP\n\
        TRANSITION FROM A TO B := done; END_TRANSITION\nSTEP B: END_STEP\nEND_PROGRAM\n";

    #[test]
    fn an_unknown_skill_or_parameter_is_named_with_the_nearest_known_one() {
        let w = warnings(CHART, &Catalogue::builtin());
        assert!(w.iter().any(|m| m.contains("skill `motoin`") && m.contains("did you mean `motion`?")), "{w:#?}");
        assert!(w.iter().any(|m| m.contains("no parameter `mss`") && m.contains("did you mean `ms`?")), "{w:#?}");
        // `grip` resembles no built-in skill: no suggestion, but the list of known ones.
        let grip = w.iter().find(|m| m.contains("skill `grip`")).expect("grip is unknown");
        assert!(!grip.contains("did you mean") && grip.contains("the skills known are motion, shell"), "{grip}");
        assert!(w.iter().any(|m| m.contains("`shell`") && m.contains("needs `cmd")), "{w:#?}");
        // `hold` belongs to every binding; `ms` to motion.
        assert!(!w.iter().any(|m| m.contains("`hold`") || m.contains("parameter `ms`")), "{w:#?}");
        assert_eq!(w.len(), 4, "{w:#?}");
    }

    #[test]
    fn a_catalogue_file_names_custom_skills_and_may_leave_their_parameters_open() {
        let mut known = Catalogue::builtin();
        let file = "[[skills]]\nname = \"grip\"\nparams = [\"force\"]\n\n[[skills]]\nname = \"motoin\"\n";
        known.merge(Catalogue::parse(file, false).unwrap());
        let w = warnings(CHART, &known);
        assert!(!w.iter().any(|m| m.contains("`grip`") || m.contains("`motoin`")), "{w:#?}");
        let json = r#"{"skills":[{"name":"grip","params":["speed"]}]}"#;
        known.merge(Catalogue::parse(json, true).unwrap());
        let w = warnings(CHART, &known);
        assert!(w.iter().any(|m| m.contains("no parameter `force`")), "{w:#?}");
        // What an agent prints reads back the same.
        assert_eq!(Catalogue::parse(&known.to_toml(), false).unwrap(), known);
    }

    #[test]
    fn a_malformed_catalogue_is_refused_with_its_reason() {
        assert!(Catalogue::parse("[[skills]]\nname = \"a b\"\n", false).unwrap_err().contains("not a skill name"));
        let bad = "[[skills]]\nname = \"g\"\nparams = [\"x\"]\nrequired = [\"y\"]\n";
        assert!(Catalogue::parse(bad, false).unwrap_err().contains("requires `y`"));
        assert!(Catalogue::parse("skills = 3", false).is_err());
        assert!(Catalogue::parse("{", true).is_err());
    }

    #[test]
    fn a_segment_needs_the_skills_of_the_actions_its_steps_run() {
        let report = check_source(CHART);
        let c = &report.charts[0];
        let (p, l) = (c.program.as_ref().unwrap(), c.layout.as_ref().unwrap());
        let has: BTreeSet<String> = ["motion".to_string(), "grip".to_string()].into();
        assert_eq!(lacking(p, l, 0, &has), vec![("motoin", "Pick", "A"), ("shell", "Run", "A")]);
    }
}
