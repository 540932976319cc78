//! ROS 2 message types without a ROS installation or generated code, for the agent's skills and bindings: the
//! interface library (`interfaces`: the definitions `build.rs` embeds — hiroz's bundled Jazzy packages and
//! `interfaces/` — and a user's `--ros-interfaces` folders, read with hiroz-codegen's parser and resolver, which
//! gives the RIHS01 type hashes) and CDR messages of run-time types (`cdr`: an IEC literal encoded field by field
//! with hiroz-cdr's writer, an answer decoded to a `RosValue`). A crate of its own, apart from the agent's Zenoh
//! host, so that its decoder of outside bytes can be fuzzed without instrumenting the network stack (`fuzz/`).

pub mod cdr;
pub mod interfaces;

pub use interfaces::{Distro, Interfaces};
