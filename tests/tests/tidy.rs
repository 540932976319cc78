//! The house rules that the compiler does not check, checked by reading the source tree (as rust-analyzer's
//! `tidy` does): `proto`'s layers import only downwards, no two files of a crate import each other (directly
//! or round a circle), `proto` does no I/O, and no source file outgrows one job.
//!
//! Each failure names the file and the rule; ARCHITECTURE.md's invariants point here.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// A source file over this many lines holds more than one job: split it along its seams.
const FILE_LINES_MAX: usize = 1_000;

/// `proto`'s layers, each with the layers it may import. A layer is a top-level module (`front`, `exec`, …);
/// its files may import one another and the layers listed, nothing else.
const PROTO_LAYERS: &[(&str, &[&str])] = &[
    ("limits", &[]),
    ("types", &["limits"]),
    ("front", &["limits", "types"]),
    ("exec", &["limits", "types", "front"]),
    ("back", &["limits", "types", "front", "exec"]),
    ("cluster", &["limits", "types", "front", "exec"]),
    ("pipeline", &["limits", "types", "front", "exec", "cluster"]),
    ("testing", &["limits", "types", "front", "exec", "cluster", "back", "pipeline"]),
];

/// Paths that `proto` never names: clocks, files, the network, processes, the environment. (`proto/clippy.toml`
/// refuses the same calls at compile time; this also catches a `use` of the module.)
const PROTO_FORBIDDEN: &[&str] = &[
    "std::fs",
    "std::net",
    "std::process",
    "std::env",
    "std::time::Instant",
    "std::time::SystemTime",
    "thread::sleep",
];

fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("the workspace").to_path_buf()
}

/// Every `.rs` file under `dir`, sorted.
fn sources(dir: &Path) -> Vec<PathBuf> {
    baton_tests::walk(dir)
        .into_iter()
        .filter(|(path, is_dir)| !is_dir && path.extension().is_some_and(|e| e == "rs"))
        .map(|(path, _)| path)
        .collect()
}

/// The text with comments, string and char literals blanked (lengths kept), so that a path in a doc comment or a
/// message is not read as an import.
fn code_only(text: &str) -> String {
    let b = text.as_bytes();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'/' && b.get(i + 1) == Some(&b'/') {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if b[i] == b'/' && b.get(i + 1) == Some(&b'*') {
            while i + 1 < b.len() && !(b[i] == b'*' && b[i + 1] == b'/') {
                i += 1;
            }
            i += 2;
        } else if b[i] == b'r' && (b.get(i + 1) == Some(&b'"') || b.get(i + 1) == Some(&b'#')) && is_raw_start(b, i) {
            let mut j = i + 1;
            let mut hashes = 0;
            while b[j] == b'#' {
                hashes += 1;
                j += 1;
            }
            j += 1;
            loop {
                if j >= b.len() {
                    break;
                }
                if b[j] == b'"' && b[j + 1..].iter().take(hashes).filter(|&&c| c == b'#').count() == hashes {
                    j += 1 + hashes;
                    break;
                }
                j += 1;
            }
            out.push_str("\"\"");
            i = j;
        } else if b[i] == b'"' {
            i += 1;
            while i < b.len() && b[i] != b'"' {
                i += if b[i] == b'\\' { 2 } else { 1 };
            }
            i += 1;
            out.push_str("\"\"");
        } else if b[i] == b'\'' && b.get(i + 2) == Some(&b'\'') {
            out.push_str("' '");
            i += 3;
        } else if b[i] == b'\'' && b.get(i + 1) == Some(&b'\\') {
            // An escaped char ('\n', '\'', '\u{..}'): its closing quote comes after the escaped character.
            let close = b.get(i + 3..).and_then(|r| r.iter().position(|&c| c == b'\'')).map_or(b.len(), |p| i + 4 + p);
            out.push_str("' '");
            i = close;
        } else {
            let ch = text[i..].chars().next().expect("a char");
            out.push(ch);
            i += ch.len_utf8();
        }
    }
    out
}

/// The code without its `#[cfg(test)]` items: a test may build its fixtures with a layer above the code under
/// test, as a dev-dependency may.
fn without_tests(code: &str) -> String {
    let mut out = code.to_string();
    while let Some(at) = out.find("#[cfg(test)]") {
        let b = out.as_bytes();
        let mut i = at;
        let mut depth = 0usize;
        let end = loop {
            match b.get(i) {
                None => break b.len(),
                Some(b'{') => depth += 1,
                Some(b'}') => {
                    depth -= 1;
                    if depth == 0 {
                        break i + 1;
                    }
                }
                Some(b';') if depth == 0 => break i + 1,
                _ => {}
            }
            i += 1;
        };
        out.replace_range(at..end, &" ".repeat(end - at));
    }
    out
}

/// Whether `r` at `i` opens a raw string rather than ending an identifier (`for"` cannot happen, `r"` can).
fn is_raw_start(b: &[u8], i: usize) -> bool {
    let before = i.checked_sub(1).map(|j| b[j]);
    let ident = |c: u8| c.is_ascii_alphanumeric() || c == b'_';
    if before.is_some_and(ident) {
        return false;
    }
    let mut j = i + 1;
    while b.get(j) == Some(&b'#') {
        j += 1;
    }
    b.get(j) == Some(&b'"')
}

/// Every path the code names that starts with `crate::`, `super::`, `self::` or one of `children` (the file's own
/// child modules, named relative to it: `tokens::X` in `coordinator/mod.rs`), with `use` trees expanded (`use
/// crate::a::{b, c::d}` gives `crate::a::b` and `crate::a::c::d`) and a glob naming its module (`use super::*`
/// gives `super`).
fn paths(code: &str, children: &[String]) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    let b = code.as_bytes();
    let ident = |c: u8| c.is_ascii_alphanumeric() || c == b'_';
    let mut i = 0;
    while i < b.len() {
        let at_word = i == 0 || !ident(b[i - 1]) && b[i - 1] != b':';
        let rest = &code[i..];
        let relative = || {
            let word: String = rest.bytes().take_while(|c| ident(*c)).map(char::from).collect();
            rest[word.len()..].starts_with("::") && (word == "self" || children.contains(&word))
        };
        if at_word && (rest.starts_with("crate::") || rest.starts_with("super::") || relative()) {
            let (found, used) = tree(rest);
            out.extend(found);
            i += used.max(1);
        } else {
            i += rest.chars().next().map_or(1, char::len_utf8);
        }
    }
    out
}

/// The paths of one `a::b::{c, d::e}` tree at the start of `s`, and how many bytes it took.
fn tree(s: &str) -> (Vec<Vec<String>>, usize) {
    let b = s.as_bytes();
    let mut prefix = Vec::new();
    let mut i = 0;
    loop {
        while i < b.len() && b[i].is_ascii_whitespace() {
            i += 1;
        }
        if b.get(i) == Some(&b'{') {
            let mut out = Vec::new();
            i += 1;
            loop {
                while i < b.len() && (b[i].is_ascii_whitespace() || b[i] == b',') {
                    i += 1;
                }
                if i >= b.len() || b[i] == b'}' {
                    return (out, i + 1);
                }
                let (inner, used) = tree(&s[i..]);
                for p in inner {
                    out.push(prefix.iter().cloned().chain(p).collect());
                }
                if used == 0 {
                    return (out, i + 1);
                }
                i += used;
            }
        }
        let start = i;
        while i < b.len() && (b[i].is_ascii_alphanumeric() || b[i] == b'_') {
            i += 1;
        }
        if start == i {
            return (vec![prefix], i);
        }
        prefix.push(s[start..i].to_string());
        if s[i..].starts_with("::") {
            i += 2;
        } else {
            return (vec![prefix], i);
        }
    }
}

/// One crate's source files by module path (`["exec", "eval"]` for `exec/eval.rs`).
struct Crate {
    name: &'static str,
    /// Each file's text by module path, read once.
    files: BTreeMap<Vec<String>, String>,
    /// Files that are `#[cfg(test)] mod NAME;` of their parent: test code, which may build its fixtures with a
    /// layer above the code under test.
    tests: BTreeSet<Vec<String>>,
}

impl Crate {
    /// The files under `src`, rooted at `root_file` (`lib.rs` or `main.rs`); `skip` are other crate roots there.
    fn read(name: &'static str, src: &Path, skip: &[&str]) -> Crate {
        let mut files = BTreeMap::new();
        for path in sources(src) {
            let rel = path.strip_prefix(src).expect("under src");
            if skip.iter().any(|s| rel == Path::new(s)) {
                continue;
            }
            let mut module: Vec<String> = rel.iter().map(|c| c.to_string_lossy().into_owned()).collect();
            let last = module.pop().expect("a file name");
            match last.as_str() {
                "lib.rs" | "main.rs" | "mod.rs" => {}
                other => module.push(other.trim_end_matches(".rs").to_string()),
            }
            files.insert(module, std::fs::read_to_string(&path).expect("a source file"));
        }
        let mut tests = BTreeSet::new();
        for (module, text) in &files {
            let lines: Vec<&str> = text.lines().map(str::trim).collect();
            for pair in lines.windows(2) {
                if pair[0] == "#[cfg(test)]" {
                    if let Some(child) = pair[1].strip_prefix("mod ").and_then(|r| r.strip_suffix(';')) {
                        let mut m = module.clone();
                        m.push(child.to_string());
                        tests.insert(m);
                    }
                }
            }
        }
        Crate { name, files, tests }
    }

    /// The file that a path names: its longest prefix that is a file's module.
    fn resolve(&self, from: &[String], path: &[String]) -> Option<Vec<String>> {
        let mut full: Vec<String> = match path.first().map(String::as_str) {
            Some("crate") => Vec::new(),
            Some("super") => {
                // A file's own module is `from`; `super` is its parent (for `mod.rs`, `from` is the folder).
                let mut m = from.to_vec();
                let mut rest = path;
                while rest.first().map(String::as_str) == Some("super") {
                    m.pop();
                    rest = &rest[1..];
                }
                m.extend(rest.iter().cloned());
                return (0..=m.len()).rev().map(|n| m[..n].to_vec()).find(|p| self.files.contains_key(p));
            }
            Some("self") => from.to_vec(),
            // A child module named relative to the file (`paths` takes only those).
            Some(_) => {
                let mut m = from.to_vec();
                m.extend(path.iter().cloned());
                return (0..=m.len()).rev().map(|n| m[..n].to_vec()).find(|p| self.files.contains_key(p));
            }
            None => return None,
        };
        full.extend(path[1..].iter().cloned());
        (0..=full.len()).rev().map(|n| full[..n].to_vec()).find(|p| self.files.contains_key(p))
    }

    /// The names of `module`'s child modules that are files of the crate.
    fn children(&self, module: &[String]) -> Vec<String> {
        self.files
            .keys()
            .filter(|k| k.len() == module.len() + 1 && k.starts_with(module))
            .filter_map(|k| k.last().cloned())
            .collect()
    }

    /// Each file's imports of other files of the crate, its parent's and its children's among them (the parent
    /// declaring a child with `mod` is not an import; naming what the child holds is).
    fn edges(&self) -> BTreeMap<Vec<String>, BTreeSet<Vec<String>>> {
        let mut out: BTreeMap<Vec<String>, BTreeSet<Vec<String>>> = BTreeMap::new();
        for (module, text) in &self.files {
            if self.tests.contains(module) {
                continue;
            }
            let children = self.children(module);
            let code = without_tests(&code_only(text));
            let entry = out.entry(module.clone()).or_default();
            for p in paths(&code, &children) {
                let Some(target) = self.resolve(module, &p) else { continue };
                if target != *module {
                    entry.insert(target);
                }
            }
        }
        out
    }
}

fn show(m: &[String]) -> String {
    if m.is_empty() {
        "<root>".to_string()
    } else {
        m.join("::")
    }
}

/// The strongly connected components with more than one file (Tarjan's algorithm, iteratively).
fn circles(edges: &BTreeMap<Vec<String>, BTreeSet<Vec<String>>>) -> Vec<Vec<Vec<String>>> {
    let nodes: Vec<&Vec<String>> = edges.keys().collect();
    let index_of: BTreeMap<&Vec<String>, usize> = nodes.iter().enumerate().map(|(i, n)| (*n, i)).collect();
    let succ: Vec<Vec<usize>> =
        nodes.iter().map(|n| edges[*n].iter().filter_map(|t| index_of.get(t).copied()).collect()).collect();
    let n = nodes.len();
    let (mut index, mut low, mut on) = (vec![usize::MAX; n], vec![0; n], vec![false; n]);
    let (mut stack, mut next, mut out) = (Vec::new(), 0, Vec::new());
    for start in 0..n {
        if index[start] != usize::MAX {
            continue;
        }
        let mut work = vec![(start, 0usize)];
        index[start] = next;
        low[start] = next;
        next += 1;
        stack.push(start);
        on[start] = true;
        while let Some(&mut (v, ref mut k)) = work.last_mut() {
            if *k < succ[v].len() {
                let w = succ[v][*k];
                *k += 1;
                if index[w] == usize::MAX {
                    index[w] = next;
                    low[w] = next;
                    next += 1;
                    stack.push(w);
                    on[w] = true;
                    work.push((w, 0));
                } else if on[w] {
                    low[v] = low[v].min(index[w]);
                }
            } else {
                work.pop();
                if let Some(&(u, _)) = work.last() {
                    low[u] = low[u].min(low[v]);
                }
                if low[v] == index[v] {
                    let mut scc = Vec::new();
                    loop {
                        let w = stack.pop().expect("on the stack");
                        on[w] = false;
                        scc.push(nodes[w].clone());
                        if w == v {
                            break;
                        }
                    }
                    if scc.len() > 1 {
                        scc.sort();
                        out.push(scc);
                    }
                }
            }
        }
    }
    out
}

fn crates() -> Vec<Crate> {
    let root = root();
    vec![
        Crate::read("proto", &root.join("proto/src"), &[]),
        Crate::read("host", &root.join("host/src"), &[]),
        Crate::read("ros2", &root.join("ros2/src"), &[]),
        Crate::read("coordinator", &root.join("coordinator/src"), &[]),
        Crate::read("agent", &root.join("agent/src"), &["main.rs"]),
        Crate::read("tests", &root.join("tests/src"), &[]),
    ]
}

#[test]
fn proto_layers_import_only_the_layers_below_them() {
    let proto = Crate::read("proto", &root().join("proto/src"), &[]);
    let allowed: BTreeMap<&str, &[&str]> = PROTO_LAYERS.iter().copied().collect();
    let mut wrong = Vec::new();
    for (from, targets) in proto.edges() {
        let Some(layer) = from.first() else { continue };
        let may = allowed.get(layer.as_str()).unwrap_or_else(|| {
            panic!("proto/src/{layer} is in no layer: add it to PROTO_LAYERS (and to ARCHITECTURE.md's code map)")
        });
        for to in targets {
            let Some(other) = to.first() else { continue };
            if other != layer && !may.contains(&other.as_str()) {
                wrong.push(format!("{} imports {} ({layer} may import: {})", show(&from), show(&to), may.join(", ")));
            }
        }
    }
    assert!(wrong.is_empty(), "imports that run up or across a layer:\n  {}", wrong.join("\n  "));
}

#[test]
fn no_two_files_of_a_crate_import_each_other() {
    let mut found = Vec::new();
    for krate in crates() {
        for scc in circles(&krate.edges()) {
            let names: Vec<String> = scc.iter().map(|m| show(m)).collect();
            found.push(format!("{}: {}", krate.name, names.join(" ↔ ")));
        }
    }
    assert!(
        found.is_empty(),
        "import circles (cut each along the seam that makes one side a leaf):\n  {}",
        found.join("\n  ")
    );
}

#[test]
fn proto_touches_no_clock_file_network_or_process() {
    let mut found = Vec::new();
    for path in sources(&root().join("proto/src")) {
        let code = code_only(&std::fs::read_to_string(&path).expect("a source file"));
        for (n, line) in code.lines().enumerate() {
            for bad in PROTO_FORBIDDEN {
                if line.contains(bad) {
                    found.push(format!("{}:{}: {bad}", path.display(), n + 1));
                }
            }
        }
    }
    let manifest = std::fs::read_to_string(root().join("proto/Cargo.toml")).expect("proto/Cargo.toml");
    let deps = manifest.split("[dependencies]").nth(1).unwrap_or("").split("\n[").next().unwrap_or("");
    for host_only in ["tokio", "zenoh", "rerun", "rand", "crc32fast"] {
        if deps.lines().any(|l| l.trim_start().starts_with(host_only)) {
            found.push(format!("proto/Cargo.toml depends on {host_only}"));
        }
    }
    assert!(found.is_empty(), "proto is the pure core (ARCHITECTURE.md, `pure-core`):\n  {}", found.join("\n  "));
}

#[test]
fn no_source_file_holds_more_than_one_job() {
    let root = root();
    let mut long = Vec::new();
    for dir in ["proto", "host", "ros2", "coordinator", "agent", "tests", "fuzz"] {
        for path in sources(&root.join(dir)) {
            let rel = path.strip_prefix(&root).expect("in the workspace");
            // The external peers are other projects' code, built apart.
            if rel.starts_with("tests/ros2-peer") || rel.starts_with("tests/ros2dds-bridge") {
                continue;
            }
            let lines = std::fs::read_to_string(&path).expect("a source file").lines().count();
            if lines > FILE_LINES_MAX {
                long.push(format!("{} has {lines} lines", rel.display()));
            }
        }
    }
    assert!(
        long.is_empty(),
        "files over {FILE_LINES_MAX} lines (split each along its seams):\n  {}",
        long.join("\n  ")
    );
}

#[test]
fn the_path_reader_expands_use_trees_and_skips_comments_and_strings() {
    let code = code_only(
        "use crate::a::{b, c::{d, e}};\n// crate::x::y\nlet s = \"crate::z\";\nlet t = r#\"crate::q\"#;\nsuper::f::g();",
    );
    let found: Vec<String> = paths(&code, &[]).iter().map(|p| p.join("::")).collect();
    assert_eq!(found, ["crate::a::b", "crate::a::c::d", "crate::a::c::e", "super::f::g"]);
    // Relative paths and globs: a child module by its name, `self::`, and `*` naming the module it is in.
    let code = code_only(
        "mod tokens;
use tokens::*;
use self::tokens::Ids;
use super::*;
let x = other::f();",
    );
    let found: Vec<String> = paths(&code, &["tokens".to_string()]).iter().map(|p| p.join("::")).collect();
    assert_eq!(found, ["tokens", "self::tokens::Ids", "super"]);
    // In a crate, those make the circle `a` ↔ `a::b` that the old reader (ancestors skipped) missed.
    let krate = Crate {
        name: "t",
        files: BTreeMap::from([
            (vec![], "mod a;".to_string()),
            (vec!["a".to_string()], "mod b;\nuse b::Helper;\npub struct A;".to_string()),
            (vec!["a".to_string(), "b".to_string()], "use super::*;\npub struct Helper(A);".to_string()),
        ]),
        tests: BTreeSet::new(),
    };
    let (a, ab) = (vec!["a".to_string()], vec!["a".to_string(), "b".to_string()]);
    assert_eq!(circles(&krate.edges()), vec![vec![a.clone(), ab.clone()]]);
    assert_eq!(krate.resolve(&a, &["b".to_string(), "Helper".to_string()]), Some(ab.clone()));
    assert_eq!(krate.resolve(&ab, &["super".to_string()]), Some(a));
    let mut edges = BTreeMap::new();
    let m = |s: &str| vec![s.to_string()];
    edges.insert(m("a"), BTreeSet::from([m("b")]));
    edges.insert(m("b"), BTreeSet::from([m("c")]));
    edges.insert(m("c"), BTreeSet::from([m("a")]));
    edges.insert(m("d"), BTreeSet::from([m("a")]));
    assert_eq!(circles(&edges), vec![vec![m("a"), m("b"), m("c")]]);
    let kept = without_tests(
        "use crate::a;\n#[cfg(test)]\nuse crate::b;\n#[cfg(test)]\nmod tests { fn f() { crate::c::d(); } }\n",
    );
    let found: Vec<String> = paths(&kept, &[]).iter().map(|p| p.join("::")).collect();
    assert_eq!(found, ["crate::a"]);
}

/// Calls that send a Zenoh message without `baton_host::traffic` listing it.
const ZENOH_UNLISTED: &[&str] = &[
    ".declare_subscriber(",
    ".declare_queryable(",
    ".declare_publisher(",
    ".declare_token(",
    ".declare_querier(",
    ".liveliness()",
    ".reply(",
    ".reply_err(",
    "session.get(",
    "session.put(",
    "session.delete(",
];

/// Every Zenoh message a process of Baton's sends is declared through `baton_host::traffic`, which lists it
/// (`BATON_TRAFFIC`): the access control `baton deploy acl` writes is checked against those lists
/// (`tests/tests/deploying.rs`), so a message sent around it would be one the rules were never checked for.
#[test]
fn every_zenoh_message_goes_through_traffic() {
    let root = root();
    let mut found = Vec::new();
    for dir in ["host/src", "agent/src", "coordinator/src"] {
        for path in sources(&root.join(dir)) {
            let rel = path.strip_prefix(&root).expect("in the workspace");
            if rel == Path::new("host/src/traffic.rs") {
                continue;
            }
            let code = without_tests(&code_only(&std::fs::read_to_string(&path).expect("a source file")));
            for (n, line) in code.lines().enumerate() {
                if let Some(call) = ZENOH_UNLISTED.iter().find(|c| line.contains(*c)) {
                    found.push(format!("{}:{}: {call}", rel.display(), n + 1));
                }
            }
        }
    }
    assert!(found.is_empty(), "Zenoh messages sent around baton_host::traffic:\n  {}", found.join("\n  "));
}

/// Folder names that global ignore files and tools drop as build output, caches or vendored code: a folder of
/// sources under one of them can be left out of a commit without anyone noticing.
const SKIPPED_FOLDER_NAMES: &[&str] =
    &["dist", "build", "out", "output", "bin", "obj", "tmp", "temp", "cache", "logs", "node_modules", "vendor"];

/// Names that cannot be mistaken (ARCHITECTURE.md's code map): no source folder is named like build output, and
/// "shell" names only the skill that runs a command — the process side of a state machine is its host.
#[test]
fn no_folder_looks_like_build_output_and_shell_names_only_the_skill() {
    let root = root();
    let mut found = Vec::new();
    for (path, is_dir) in baton_tests::walk(&root) {
        let rel = path.strip_prefix(&root).expect("in the workspace");
        // The external peers are other projects' code, built apart; `.ci`'s tools live outside the clone.
        if rel.starts_with("tests/ros2-peer")
            || rel.starts_with("tests/ros2dds-bridge")
            || rel.starts_with("fuzz/target")
        {
            continue;
        }
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or_default().to_ascii_lowercase();
        if is_dir && SKIPPED_FOLDER_NAMES.contains(&name.as_str()) {
            found.push(format!("{}: a folder named like build output", rel.display()));
        }
        let stem = name.split('.').next().unwrap_or_default();
        if stem == "shell" || stem == "shells" {
            found.push(format!(
                "{}: \"shell\" is the skill's name; a state machine's process side is a host",
                rel.display()
            ));
        }
    }
    // The distributed runtimes take what they share with `baton sim` from where it lives, not from `sim`.
    for path in sources(&root.join("proto/src/cluster")).into_iter().chain(sources(&root.join("proto/src/testing"))) {
        let code = code_only(&std::fs::read_to_string(&path).expect("a source file"));
        if code.contains("exec::sim") {
            found.push(format!(
                "{}: reaches into `baton sim`'s module",
                path.strip_prefix(&root).expect("inside").display()
            ));
        }
    }
    assert!(found.is_empty(), "names that can be mistaken:\n  {}", found.join("\n  "));
}

/// A file names what it takes from the crate's other files (ARCHITECTURE.md, [layers]): a glob import of one of
/// them (`use super::*;`, `use tokens::*;`) hides which items cross, and a circle through it. Test modules may
/// glob their parent, which they test; a glob of an enum's variants inside a function stays local.
#[test]
fn no_file_glob_imports_another_file_of_its_crate() {
    let found: Vec<String> = crates().iter().flat_map(own_globs).collect();
    assert!(found.is_empty(), "glob imports of the crate's own files (name what crosses):\n  {}", found.join("\n  "));
}

/// The glob imports of `krate`'s own files outside its tests, as `crate: module: line`.
fn own_globs(krate: &Crate) -> Vec<String> {
    let mut found = Vec::new();
    for (module, text) in &krate.files {
        if krate.tests.contains(module) {
            continue;
        }
        let children = krate.children(module);
        let code = without_tests(&code_only(text));
        for line in code.lines() {
            let Some(path) = ["use ", "pub use ", "pub(crate) use ", "pub(super) use "]
                .iter()
                .find_map(|kw| line.strip_prefix(kw))
                .and_then(|rest| rest.trim_end().strip_suffix("::*;"))
            else {
                continue;
            };
            let first = path.split("::").next().unwrap_or_default();
            if ["crate", "super", "self"].contains(&first) || children.iter().any(|c| c == first) {
                found.push(format!("{}: {}: {}", krate.name, show(module), line.trim()));
            }
        }
    }
    found
}

#[test]
fn the_glob_reader_finds_own_files_and_leaves_variants_preludes_and_tests() {
    let a = vec!["a".to_string()];
    let krate = Crate {
        name: "t",
        files: BTreeMap::from([
            (vec![], "mod a;\nuse a::*;\nuse serde::prelude::*;".to_string()),
            (
                a.clone(),
                "use super::*;\nfn f() {\n    use Kind::*;\n}\n#[cfg(test)]\nmod tests {\nuse super::*;\n}".to_string(),
            ),
        ]),
        tests: BTreeSet::new(),
    };
    assert_eq!(own_globs(&krate), ["t: <root>: use a::*;", "t: a: use super::*;"]);
}

/// The longest function a reader holds at once (ARCHITECTURE.md, [short-functions]): about two screens. Past it, a
/// function is split along the seams its comments mark — a section of a file read, a phase of a run.
const FUNCTION_LINES_MAX: usize = 120;

/// Functions over the limit that stay, each with its reason.
const LONG_FUNCTIONS: &[(&str, &str, &str)] = &[];

/// Each function of `code` (comments and strings blanked) as its name, first line (1-based) and length in lines,
/// from `fn` to its body's closing brace. Declarations without a body (trait methods) are left out.
fn functions(code: &str) -> Vec<(String, usize, usize)> {
    let b = code.as_bytes();
    let ident = |c: u8| c.is_ascii_alphanumeric() || c == b'_';
    let mut out = Vec::new();
    let mut i = 0;
    while let Some(at) = code[i..].find("fn ").map(|k| k + i) {
        i = at + 3;
        if at > 0 && ident(b[at - 1]) {
            continue;
        }
        let name: String = code[i..].trim_start().bytes().take_while(|c| ident(*c)).map(char::from).collect();
        if name.is_empty() {
            continue;
        }
        // The body's `{`: the first outside the signature's parentheses and brackets, unless a `;` ends it first.
        let (mut j, mut depth) = (i, 0i32);
        while j < b.len() {
            match b[j] {
                b'(' | b'[' => depth += 1,
                b')' | b']' => depth -= 1,
                b';' if depth == 0 => break,
                b'{' if depth == 0 => break,
                _ => {}
            }
            j += 1;
        }
        if j >= b.len() || b[j] != b'{' {
            continue;
        }
        let mut braces = 0;
        let mut k = j;
        while k < b.len() {
            match b[k] {
                b'{' => braces += 1,
                b'}' => {
                    braces -= 1;
                    if braces == 0 {
                        break;
                    }
                }
                _ => {}
            }
            k += 1;
        }
        let first = code[..at].matches('\n').count() + 1;
        let last = code[..k.min(b.len())].matches('\n').count() + 1;
        out.push((name, first, last - first + 1));
    }
    out
}

#[test]
fn no_function_is_longer_than_a_reader_holds() {
    let root = root();
    let mut long = Vec::new();
    for dir in ["proto/src", "host/src", "ros2/src", "coordinator/src", "agent/src", "tests/src", "tests/tests", "fuzz"]
    {
        for path in sources(&root.join(dir)) {
            let rel = path.strip_prefix(&root).expect("in the workspace").to_string_lossy().into_owned();
            let code = code_only(&std::fs::read_to_string(&path).expect("a source file"));
            for (name, line, lines) in functions(&code) {
                let allowed = LONG_FUNCTIONS.iter().any(|(file, f, _)| *file == rel && *f == name);
                if lines > FUNCTION_LINES_MAX && !allowed {
                    long.push(format!("{rel}:{line}: `{name}` has {lines} lines"));
                }
            }
        }
    }
    assert!(
        long.is_empty(),
        "functions over {FUNCTION_LINES_MAX} lines (split each along its seams, or allow it in LONG_FUNCTIONS with why):\n  {}",
        long.join("\n  ")
    );
}

#[test]
fn the_function_reader_measures_from_fn_to_the_closing_brace() {
    let code = code_only(
        "trait T {\n    fn decl(&self);\n}\nfn short() {}\n/// fn in a comment\nfn long(a: [u8; 2]) -> u8 {\n    let s = \"}\";\n    { a[0] }\n}\n",
    );
    assert_eq!(functions(&code), vec![("short".to_string(), 4, 1), ("long".to_string(), 6, 4)]);
}
