//! ROS 2 for the agent, over rmw_zenoh on its own Zenoh session: no ROS installation, no generated code. The
//! interface types come from definition files (`interfaces`), messages are CDR built from them (`cdr`), the
//! protocol is rmw_zenoh's key expressions, liveliness tokens and queries — or zenoh-bridge-ros2dds's, for
//! robots on DDS (`keys`, `client`) — and the skills `ros2_service` and `ros2_action` drive servers with it
//! (`skills`).

pub use baton_ros2::{cdr, interfaces};
pub mod client;
pub mod rmw_keys;
pub mod skills;

pub use client::Ros2;
pub use interfaces::{Distro, Interfaces};
pub use rmw_keys::Via;
