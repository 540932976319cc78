//! The Baton agent library. It will run dispatched chart segments with the `baton-proto` engine on a robot or
//! cell and hand tokens back over Zenoh; that distributed runtime is the next milestone, so this crate holds
//! only the workspace's place for it today.
