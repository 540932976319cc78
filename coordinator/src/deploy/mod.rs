//! `baton deploy`: what a cell needs before it runs — the identities its processes prove themselves with
//! (`certs`).

pub mod certs;
