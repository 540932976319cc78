//! `baton console`: the operator console in a browser, for the runs behind a router.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::process::ExitCode;

use super::common::block_on;

/// The arguments of `baton console`.
#[derive(clap::Args)]
pub struct Console {
    #[command(flatten)]
    pub reach: super::common::Reach,
    /// Where the page is served (port 0: any free one, printed at start). Beyond loopback it needs --tls-cert,
    /// --tls-key and --users.
    #[arg(long, default_value = "127.0.0.1:8080", value_name = "ADDR")]
    pub listen: SocketAddr,
    /// Serve HTTPS with this certificate (PEM, the chain leaf first; `baton deploy certs` makes one).
    #[arg(long, value_name = "FILE", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// The certificate's private key (PEM).
    #[arg(long, value_name = "FILE", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// Users log in: names, roles (viewer, operator, maintenance) and password hashes, as `baton deploy users`
    /// writes them.
    #[arg(long, value_name = "FILE")]
    pub users: Option<PathBuf>,
    /// Write the console's own trace here: logins, refused logins, commands refused for a user's role.
    #[arg(long, value_name = "FILE")]
    pub trace: Option<PathBuf>,
    /// Finished runs' Rerun recordings (`.rrd`, as `baton run --rerun save:PATH` writes them) in this folder: the
    /// page lists them and opens each in its timeline.
    #[arg(long, value_name = "DIR")]
    pub recordings: Option<PathBuf>,
    /// Name the run's coordinators in the page — the active one, its term, and those standing by — read from its
    /// election on etcd (as `baton run --election` names it).
    #[arg(long, value_name = "etcd://…/PREFIX")]
    pub election: Option<crate::election::Election>,
}

impl Console {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let Console { reach, listen, tls_cert, tls_key, users, trace, recordings, election } = self;
        if let Some(dir) = &recordings {
            anyhow::ensure!(dir.is_dir(), "--recordings {}: not a folder", dir.display());
        }
        let access = crate::console::Access { tls: tls_cert.zip(tls_key), users, trace, recordings, election };
        block_on(async move {
            let listener = crate::console::bind(listen, &access).await?;
            // Only an interrupt ends it.
            let (_never, stop) = tokio::sync::watch::channel(false);
            crate::console::serve(listener, &reach.connect, reach.zenoh_config.as_deref(), access, stop).await?;
            Ok(ExitCode::SUCCESS)
        })
    }
}
