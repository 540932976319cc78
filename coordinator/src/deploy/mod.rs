//! `baton deploy`: what a cell needs before it runs — the identities its processes prove themselves with
//! (`certs`), and what the router lets each of them do (`acl`).

pub mod acl;
pub mod certs;
