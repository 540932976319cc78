//! The ROS 2 interface types an agent knows: the definitions built into it (see `build.rs`) and those of the
//! user's `--ros-interfaces` folders, read with hiroz's `.msg`/`.srv`/`.action` parser. hiroz's resolver gives
//! each service and action the RIHS01 type hashes that rmw_zenoh puts in its key expressions, so a type from
//! a definition file works exactly like a built-in one: no code is generated.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use hiroz_codegen::resolver::Resolver;
use hiroz_codegen::types::{ArrayType, DefaultValue, ParsedMessage};

mod embedded {
    include!(concat!(env!("OUT_DIR"), "/interfaces.rs"));
}

/// Definition files read from one `--ros-interfaces` folder, at most.
const USER_FILES_MAX: usize = 10_000;
const DEFINITION_BYTES_MAX: u64 = 1024 * 1024;

/// The ROS 2 distribution whose type hashes the agent speaks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Distro {
    /// Jazzy, Kilted and later: RIHS01 type hashes in key expressions.
    Jazzy,
    /// Humble's rmw_zenoh: no type hashes (`TypeHashNotSupported`).
    Humble,
}

impl Distro {
    pub fn parse(name: &str) -> Option<Distro> {
        match name.to_ascii_lowercase().as_str() {
            "jazzy" | "kilted" | "rolling" | "lyrical" => Some(Distro::Jazzy),
            "humble" => Some(Distro::Humble),
            _ => None,
        }
    }
}

/// A field's element type.
#[derive(Clone, Debug, PartialEq)]
pub enum Prim {
    Bool,
    /// `byte`, `uint8`, `char`.
    U8,
    I8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
    /// `string`, `string<=N` (bound in characters).
    Str(Option<usize>),
    /// A nested message, by its full name `pkg/msg/Name`.
    Msg(String),
}

#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    One,
    Fixed(usize),
    Bounded(usize),
    Unbounded,
}

#[derive(Clone, Debug)]
pub struct Field {
    pub name: String,
    pub prim: Prim,
    pub shape: Shape,
    pub default: Option<DefaultValue>,
}

/// A message's fields in order, as CDR lays them out.
#[derive(Clone, Debug)]
pub struct MsgDef {
    /// `pkg/msg/Name`, `pkg/srv/Name_Request`, `pkg/action/Name_Goal`…
    pub name: String,
    pub fields: Vec<Field>,
}

/// A ROS type on the wire: its DDS name and type hash, as rmw_zenoh writes them in key expressions.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct WireType {
    pub dds_name: String,
    pub hash: String,
}

#[derive(Clone, Debug)]
pub struct ServiceType {
    pub wire: WireType,
    pub request: Arc<MsgDef>,
    pub response: Arc<MsgDef>,
}

#[derive(Clone, Debug)]
pub struct ActionType {
    /// `pkg/action/Name`.
    pub name: String,
    pub goal: Arc<MsgDef>,
    pub result: Arc<MsgDef>,
    pub feedback: Arc<MsgDef>,
    pub send_goal: ServiceType,
    pub get_result: ServiceType,
    pub cancel_goal: ServiceType,
    /// The feedback topic's message (`goal_id` + `feedback`).
    pub feedback_message: (WireType, Arc<MsgDef>),
}

#[derive(Clone, Debug)]
pub struct TopicType {
    pub wire: WireType,
    pub msg: Arc<MsgDef>,
}

struct State {
    resolver: Resolver,
    msgs: HashMap<String, Arc<MsgDef>>,
    /// Per message type: its RIHS01 hash.
    msg_hashes: HashMap<String, String>,
    services: HashMap<String, Arc<ServiceType>>,
    actions: HashMap<String, Arc<ActionType>>,
}

/// The interface library: definitions by `pkg/kind/Name`, resolved on first use.
pub struct Interfaces {
    distro: Distro,
    /// `pkg/kind/Name` → definition text and its file (a path named after the type, for the built-in ones).
    sources: BTreeMap<String, (String, PathBuf)>,
    state: Mutex<State>,
}

impl Interfaces {
    /// The built-in definitions, then those of `dirs` (a definition there replaces a built-in one of the same
    /// name: the user's robot was built from it).
    pub fn load(distro: Distro, dirs: &[PathBuf]) -> Result<Interfaces, String> {
        let mut sources: BTreeMap<String, (String, PathBuf)> = BTreeMap::new();
        for (name, text) in embedded::EMBEDDED {
            let (_, kind, _) = split(name).expect("built-in names are pkg/kind/Name");
            sources.insert(name.to_string(), (text.to_string(), PathBuf::from(format!("<built-in>/{name}.{kind}"))));
        }
        for dir in dirs {
            let mut found = Vec::new();
            find_definitions(dir, None, 0, &mut found)?;
            if found.is_empty() {
                return Err(format!(
                    "{} holds no ROS 2 interface definitions (<package>/msg/*.msg, srv/*.srv, action/*.action)",
                    dir.display()
                ));
            }
            for (name, path) in found {
                let text = read_definition(&path)?;
                sources.insert(name, (text, path));
            }
        }
        let mut parsed = Vec::new();
        for (name, (text, origin)) in &sources {
            let (package, kind, _) = split(name).expect("names are built as pkg/kind/Name");
            if kind == "msg" {
                let msg = hiroz_codegen::parser::msg::parse_msg_string(text, package, origin)
                    .map_err(|e| format!("cannot read {name} ({}): {e:#}", origin.display()))?;
                // hiroz hashes no wstring, and robots' interfaces hardly use it: the built-in
                // example_interfaces/msg/WString is left out, a user's definition is refused.
                if msg.fields.iter().any(|f| f.field_type.base_type.starts_with("wstring")) {
                    if origin.starts_with("<built-in>") {
                        continue;
                    }
                    return Err(format!(
                        "{name} ({}) has a wstring field, which Baton does not support",
                        origin.display()
                    ));
                }
                parsed.push(msg);
            }
        }
        let mut resolver = Resolver::new(distro == Distro::Humble);
        let resolved =
            resolver.resolve_messages(parsed).map_err(|e| format!("cannot resolve the ROS 2 message types: {e:#}"))?;
        let mut msgs = HashMap::new();
        let mut msg_hashes = HashMap::new();
        for r in resolved {
            let name = format!("{}/msg/{}", r.parsed.package, r.parsed.name);
            msg_hashes.insert(name.clone(), r.type_hash.to_rihs_string());
            msgs.insert(name.clone(), Arc::new(msg_def(&name, &r.parsed)));
        }
        let state = State { resolver, msgs, msg_hashes, services: HashMap::new(), actions: HashMap::new() };
        Ok(Interfaces { distro, sources, state: Mutex::new(state) })
    }

    fn hash(&self, rihs: String) -> String {
        match self.distro {
            Distro::Jazzy => rihs,
            Distro::Humble => "TypeHashNotSupported".to_string(),
        }
    }

    /// A message type's definition, by `pkg/msg/Name`.
    pub fn msg(&self, name: &str) -> Option<Arc<MsgDef>> {
        self.state.lock().expect("interfaces").msgs.get(name).cloned()
    }

    /// A message type for a topic: `std_msgs/msg/Bool`.
    pub fn topic(&self, name: &str) -> Result<TopicType, String> {
        let (package, kind, short) = split(name).filter(|(_, k, _)| *k == "msg").ok_or_else(|| {
            format!("`{name}` is not a message type: write it as <package>/msg/<Name>, such as std_msgs/msg/Bool")
        })?;
        let state = self.state.lock().expect("interfaces");
        let msg = state.msgs.get(name).cloned().ok_or_else(|| self.unknown(name))?;
        let hash = state.msg_hashes.get(name).cloned().unwrap_or_default();
        drop(state);
        Ok(TopicType { wire: WireType { dds_name: dds(package, kind, short), hash: self.hash(hash) }, msg })
    }

    /// A service type: `std_srvs/srv/SetBool`.
    pub fn service(&self, name: &str) -> Result<Arc<ServiceType>, String> {
        let (package, kind, short) = split(name).filter(|(_, k, _)| *k == "srv").ok_or_else(|| {
            format!("`{name}` is not a service type: write it as <package>/srv/<Name>, such as std_srvs/srv/SetBool")
        })?;
        let mut state = self.state.lock().expect("interfaces");
        if let Some(s) = state.services.get(name) {
            return Ok(Arc::clone(s));
        }
        let (text, origin) = self.sources.get(name).ok_or_else(|| self.unknown(name))?;
        let parsed = hiroz_codegen::parser::srv::parse_srv_string(text, package, origin)
            .map_err(|e| format!("cannot read {name} ({}): {e:#}", origin.display()))?;
        let resolved = state.resolver.resolve_service(parsed).map_err(|e| format!("cannot resolve {name}: {e:#}"))?;
        let request = Arc::new(msg_def(&format!("{name}_Request"), &resolved.request.parsed));
        let response = Arc::new(msg_def(&format!("{name}_Response"), &resolved.response.parsed));
        let wire =
            WireType { dds_name: dds(package, kind, short), hash: self.hash(resolved.type_hash.to_rihs_string()) };
        let service = Arc::new(ServiceType { wire, request, response });
        state.services.insert(name.to_string(), Arc::clone(&service));
        Ok(service)
    }

    /// An action type: `example_interfaces/action/Fibonacci`, with the services and topics rmw_zenoh makes of it.
    pub fn action(&self, name: &str) -> Result<Arc<ActionType>, String> {
        let (package, kind, short) = split(name).filter(|(_, k, _)| *k == "action").ok_or_else(|| {
            format!("`{name}` is not an action type: write it as <package>/action/<Name>, such as example_interfaces/action/Fibonacci")
        })?;
        // CancelGoal is an ordinary service of action_msgs.
        let cancel_goal = (*self.service("action_msgs/srv/CancelGoal")?).clone();
        let mut state = self.state.lock().expect("interfaces");
        if let Some(a) = state.actions.get(name) {
            return Ok(Arc::clone(a));
        }
        let (text, origin) = self.sources.get(name).ok_or_else(|| self.unknown(name))?;
        let parsed = hiroz_codegen::parser::action::parse_action(text, short, package, origin)
            .map_err(|e| format!("cannot read {name} ({}): {e:#}", origin.display()))?;
        let resolved = state.resolver.resolve_action(parsed).map_err(|e| format!("cannot resolve {name}: {e:#}"))?;
        let empty = |what: &str| ParsedMessage {
            name: format!("{short}_{what}"),
            package: package.to_string(),
            fields: Vec::new(),
            constants: Vec::new(),
            source: String::new(),
            path: PathBuf::new(),
        };
        let goal = Arc::new(msg_def(&format!("{name}_Goal"), &resolved.goal.parsed));
        let result_parsed = resolved.result.as_ref().map(|r| r.parsed.clone()).unwrap_or_else(|| empty("Result"));
        let feedback_parsed = resolved.feedback.as_ref().map(|r| r.parsed.clone()).unwrap_or_else(|| empty("Feedback"));
        let result = Arc::new(msg_def(&format!("{name}_Result"), &result_parsed));
        let feedback = Arc::new(msg_def(&format!("{name}_Feedback"), &feedback_parsed));
        let uuid = || Field {
            name: "goal_id".into(),
            prim: Prim::Msg("unique_identifier_msgs/msg/UUID".into()),
            shape: Shape::One,
            default: None,
        };
        let nested = |field: &str, of: &str| Field {
            name: field.into(),
            prim: Prim::Msg(of.into()),
            shape: Shape::One,
            default: None,
        };
        let plain = |field: &str, prim: Prim| Field { name: field.into(), prim, shape: Shape::One, default: None };
        let def = |suffix: &str, fields: Vec<Field>| Arc::new(MsgDef { name: format!("{name}_{suffix}"), fields });
        for (part, def) in [("Goal", &goal), ("Result", &result), ("Feedback", &feedback)] {
            state.msgs.insert(format!("{name}_{part}"), Arc::clone(def));
        }
        let send_goal = ServiceType {
            wire: WireType {
                dds_name: dds(package, kind, &format!("{short}_SendGoal")),
                hash: self.hash(resolved.send_goal_hash.to_rihs_string()),
            },
            request: def("SendGoal_Request", vec![uuid(), nested("goal", &format!("{name}_Goal"))]),
            response: def(
                "SendGoal_Response",
                vec![plain("accepted", Prim::Bool), nested("stamp", "builtin_interfaces/msg/Time")],
            ),
        };
        let get_result = ServiceType {
            wire: WireType {
                dds_name: dds(package, kind, &format!("{short}_GetResult")),
                hash: self.hash(resolved.get_result_hash.to_rihs_string()),
            },
            request: def("GetResult_Request", vec![uuid()]),
            response: def(
                "GetResult_Response",
                vec![plain("status", Prim::I8), nested("result", &format!("{name}_Result"))],
            ),
        };
        let feedback_message = (
            WireType {
                dds_name: dds(package, kind, &format!("{short}_FeedbackMessage")),
                hash: self.hash(resolved.feedback_message_hash.to_rihs_string()),
            },
            def("FeedbackMessage", vec![uuid(), nested("feedback", &format!("{name}_Feedback"))]),
        );
        let action = Arc::new(ActionType {
            name: name.to_string(),
            goal,
            result,
            feedback,
            send_goal,
            get_result,
            cancel_goal,
            feedback_message,
        });
        state.actions.insert(name.to_string(), Arc::clone(&action));
        Ok(action)
    }

    fn unknown(&self, name: &str) -> String {
        let (package, kind, _) = split(name).unwrap_or(("", "", ""));
        let same: Vec<&str> = self
            .sources
            .keys()
            .filter(|k| split(k).is_some_and(|(p, k2, _)| p == package && k2 == kind))
            .map(String::as_str)
            .take(12)
            .collect();
        let known = if same.is_empty() {
            format!("the agent knows no {kind} of package `{package}`")
        } else {
            format!("the agent knows {}", same.join(", "))
        };
        format!("unknown ROS 2 type `{name}` ({known}): give its definition file with --ros-interfaces DIR")
    }
}

/// `pkg/kind/Name` → its parts.
fn split(name: &str) -> Option<(&str, &str, &str)> {
    hiroz_schema::type_name::split_canonical(name)
}

/// rmw_zenoh's spelling of a type: `std_srvs::srv::dds_::SetBool_`.
fn dds(package: &str, kind: &str, name: &str) -> String {
    hiroz_schema::type_name::dds_from_namespace(&format!("{package}::{kind}"), name)
}

fn msg_def(name: &str, parsed: &ParsedMessage) -> MsgDef {
    let fields = parsed
        .fields
        .iter()
        .map(|f| {
            let t = &f.field_type;
            let prim = match t.base_type.as_str() {
                "bool" => Prim::Bool,
                "byte" | "uint8" | "char" => Prim::U8,
                "int8" => Prim::I8,
                "int16" => Prim::I16,
                "uint16" => Prim::U16,
                "int32" => Prim::I32,
                "uint32" => Prim::U32,
                "int64" => Prim::I64,
                "uint64" => Prim::U64,
                "float32" => Prim::F32,
                "float64" => Prim::F64,
                "string" => Prim::Str(t.string_bound),
                other => {
                    let other = other.strip_prefix("string<=").map_or(other, |_| "string");
                    if other == "string" {
                        Prim::Str(t.string_bound)
                    } else {
                        // An unqualified nested type is of the same package (`Vector3` in geometry_msgs/Twist).
                        let package = t.package.clone().unwrap_or_else(|| parsed.package.clone());
                        Prim::Msg(format!("{package}/msg/{other}"))
                    }
                }
            };
            let shape = match t.array {
                ArrayType::Single => Shape::One,
                ArrayType::Fixed(n) => Shape::Fixed(n),
                ArrayType::Bounded(n) => Shape::Bounded(n),
                ArrayType::Unbounded => Shape::Unbounded,
            };
            Field { name: f.name.clone(), prim, shape, default: f.default.clone() }
        })
        .collect();
    MsgDef { name: name.to_string(), fields }
}

fn read_definition(path: &Path) -> Result<String, String> {
    let meta = std::fs::metadata(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    if meta.len() > DEFINITION_BYTES_MAX {
        return Err(format!(
            "{} is larger than {DEFINITION_BYTES_MAX} bytes: not an interface definition",
            path.display()
        ));
    }
    std::fs::read_to_string(path).map_err(|e| format!("cannot read {}: {e}", path.display()))
}

/// Finds `<package>/{msg,srv,action}/<Name>.<kind>` under `dir`: `dir` may be a package, a folder of packages (an
/// ament `share/`), or a folder of such folders.
fn find_definitions(
    dir: &Path,
    package: Option<&str>,
    depth: usize,
    found: &mut Vec<(String, PathBuf)>,
) -> Result<(), String> {
    let entries = std::fs::read_dir(dir).map_err(|e| format!("cannot read --ros-interfaces {}: {e}", dir.display()))?;
    let name = dir.file_name().and_then(|n| n.to_str()).unwrap_or_default().to_string();
    let mut subdirs = Vec::new();
    for entry in entries.flatten() {
        let path = entry.path();
        if !path.is_dir() {
            continue;
        }
        let sub = entry.file_name().to_string_lossy().into_owned();
        if ["msg", "srv", "action"].contains(&sub.as_str()) {
            let package = package.unwrap_or(&name);
            for file in std::fs::read_dir(&path).map_err(|e| format!("cannot read {}: {e}", path.display()))?.flatten()
            {
                let file = file.path();
                if file.extension().and_then(|e| e.to_str()) == Some(sub.as_str()) {
                    let stem = file.file_stem().and_then(|s| s.to_str()).unwrap_or_default();
                    found.push((format!("{package}/{sub}/{stem}"), file));
                    if found.len() > USER_FILES_MAX {
                        return Err(format!("more than {USER_FILES_MAX} definitions under {}", dir.display()));
                    }
                }
            }
        } else {
            subdirs.push(path);
        }
    }
    if depth < 3 {
        subdirs.sort();
        for sub in subdirs {
            find_definitions(&sub, None, depth + 1, found)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_built_in_types_resolve_with_their_hashes() {
        let lib = Interfaces::load(Distro::Jazzy, &[]).expect("built-in interfaces");
        let set_bool = lib.service("std_srvs/srv/SetBool").unwrap();
        assert_eq!(set_bool.wire.dds_name, "std_srvs::srv::dds_::SetBool_");
        assert!(set_bool.wire.hash.starts_with("RIHS01_") && set_bool.wire.hash.len() == 7 + 64);
        let fib = lib.action("example_interfaces/action/Fibonacci").unwrap();
        assert_eq!(fib.send_goal.wire.dds_name, "example_interfaces::action::dds_::Fibonacci_SendGoal_");
        assert_eq!(fib.goal.fields[0].name, "order");
        assert_eq!(fib.result.fields[0].shape, Shape::Unbounded);
        let nav = lib.action("nav2_msgs/action/NavigateToPose").unwrap();
        assert_eq!(nav.goal.fields[0].prim, Prim::Msg("geometry_msgs/msg/PoseStamped".into()));
        assert!(lib.topic("geometry_msgs/msg/Twist").is_ok());
        let humble = Interfaces::load(Distro::Humble, &[]).unwrap();
        assert_eq!(humble.service("std_srvs/srv/SetBool").unwrap().wire.hash, "TypeHashNotSupported");
    }

    #[test]
    fn unknown_and_misspelt_types_say_what_to_do() {
        let lib = Interfaces::load(Distro::Jazzy, &[]).unwrap();
        let e = lib.service("std_srvs/srv/SetBoll").unwrap_err();
        assert!(e.contains("std_srvs/srv/SetBool") && e.contains("--ros-interfaces"), "{e}");
        assert!(lib.service("std_srvs/SetBool").unwrap_err().contains("<package>/srv/<Name>"));
        assert!(lib.action("std_srvs/srv/SetBool").unwrap_err().contains("not an action type"));
    }

    #[test]
    fn definition_files_add_types_without_code() {
        let dir = tempfile::tempdir().unwrap();
        let pkg = dir.path().join("cell_interfaces");
        std::fs::create_dir_all(pkg.join("action")).unwrap();
        std::fs::create_dir_all(pkg.join("msg")).unwrap();
        std::fs::write(pkg.join("msg/Slot.msg"), "int32 row\nint32 col\n").unwrap();
        std::fs::write(
            pkg.join("action/Pick.action"),
            "Slot slot\nfloat64 speed 0.5\n---\nbool ok\n---\nfloat64 progress\n",
        )
        .unwrap();
        let lib = Interfaces::load(Distro::Jazzy, &[dir.path().to_path_buf()]).unwrap();
        let pick = lib.action("cell_interfaces/action/Pick").unwrap();
        assert_eq!(pick.goal.fields[0].prim, Prim::Msg("cell_interfaces/msg/Slot".into()));
        assert!(lib.msg("cell_interfaces/msg/Slot").is_some());
        std::fs::write(pkg.join("msg/Broken.msg"), "int32 row\nNoSuchType x\n").unwrap();
        let err =
            Interfaces::load(Distro::Jazzy, &[dir.path().to_path_buf()]).err().expect("a missing type is an error");
        assert!(err.contains("NoSuchType") || err.contains("Broken"), "{err}");
        let empty = tempfile::tempdir().unwrap();
        let err = Interfaces::load(Distro::Jazzy, &[empty.path().to_path_buf()]).err().unwrap();
        assert!(err.contains("holds no ROS 2 interface definitions"), "{err}");
    }
}
