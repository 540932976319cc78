//! Embeds the ROS 2 interface definitions the agent knows out of the box: the standard packages that hiroz
//! bundles for Jazzy (their definitions are those of Kilted too), and the ones Baton adds (`interfaces/`). The
//! agent reads them at start, as it reads a user's `--ros-interfaces` folder, so a robot needs no ROS install.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The packages taken from hiroz's bundle: what a cell's robots and machines speak, and what those depend on.
const PACKAGES: &[&str] = &[
    "action_msgs",
    "action_tutorials_interfaces",
    "builtin_interfaces",
    "diagnostic_msgs",
    "example_interfaces",
    "geometry_msgs",
    "nav_msgs",
    "sensor_msgs",
    "service_msgs",
    "shape_msgs",
    "std_msgs",
    "std_srvs",
    "trajectory_msgs",
    "unique_identifier_msgs",
];

fn main() {
    let bundled = hiroz_codegen::bundled_assets_dir_for("jazzy");
    let ours = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("manifest dir")).join("interfaces");
    println!("cargo:rerun-if-changed=interfaces");
    let mut files = Vec::new();
    for package in PACKAGES {
        let dir = bundled.join(package);
        assert!(dir.is_dir(), "hiroz-codegen no longer bundles {package} at {}", dir.display());
        collect(&dir, package, &mut files);
    }
    for entry in std::fs::read_dir(&ours).expect("ros2/interfaces") {
        let entry = entry.expect("entry");
        let package = entry.file_name().to_string_lossy().into_owned();
        collect(&entry.path(), &package, &mut files);
    }
    files.sort();
    let mut out =
        String::from("/// `(package/kind/Name, definition)`, sorted.\npub static EMBEDDED: &[(&str, &str)] = &[\n");
    for (name, path) in &files {
        writeln!(out, "    ({name:?}, include_str!({:?})),", path.display().to_string()).expect("write");
    }
    out.push_str("];\n");
    let dest = PathBuf::from(std::env::var("OUT_DIR").expect("out dir")).join("interfaces.rs");
    std::fs::write(dest, out).expect("write interfaces.rs");
}

/// The `msg/`, `srv/` and `action/` definitions of one package folder.
fn collect(dir: &Path, package: &str, files: &mut Vec<(String, PathBuf)>) {
    for kind in ["msg", "srv", "action"] {
        let Ok(entries) = std::fs::read_dir(dir.join(kind)) else { continue };
        for entry in entries {
            let path = entry.expect("entry").path();
            if path.extension().and_then(|e| e.to_str()) != Some(kind) {
                continue;
            }
            let name = path.file_stem().and_then(|s| s.to_str()).expect("file name").to_string();
            files.push((format!("{package}/{kind}/{name}"), path));
        }
    }
}
