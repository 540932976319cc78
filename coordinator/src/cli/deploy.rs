//! `baton deploy`: what a cell needs before it runs.

use std::path::PathBuf;
use std::process::ExitCode;

/// The subcommands of `baton deploy`.
#[derive(clap::Subcommand)]
pub enum Deploy {
    /// Make a certificate authority in DIR (or reuse the one there) and a certificate and key per NAME, signed by
    /// it, the name as the certificate's common name: DIR/ca.pem, DIR/ca.key, DIR/NAME.pem, DIR/NAME.key (PEM).
    /// Give each process its own: an agent's name, the coordinator's, each operator's.
    Certs(Certs),
}

#[derive(clap::Args)]
pub struct Certs {
    /// The folder of the cell's CA and certificates.
    #[arg(long = "ca", value_name = "DIR")]
    pub dir: PathBuf,
    /// The processes to certify: agents' names, the coordinator's, operators'.
    #[arg(value_name = "NAME", required = true)]
    pub names: Vec<String>,
    /// A further host name or address these certificates answer at (a router's), repeatable:
    /// --san router.cell4.local --san 10.0.4.2.
    #[arg(long, value_name = "HOST")]
    pub san: Vec<String>,
    /// Issue again the certificates of names that have one (the CA stays).
    #[arg(long)]
    pub renew: bool,
}

impl Deploy {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        match self {
            Deploy::Certs(c) => {
                let made = crate::deploy::certs::certs(&c.dir, &c.names, &c.san, c.renew)?;
                let what = if made.ca_made { "made" } else { "kept" };
                println!("CA {what}: {}", made.ca.display());
                for i in &made.issued {
                    let what = if i.made { "issued" } else { "kept (--renew to issue again)" };
                    println!("{}: {what}: {} {}", i.name, i.cert.display(), i.key.display());
                }
                Ok(ExitCode::SUCCESS)
            }
        }
    }
}
