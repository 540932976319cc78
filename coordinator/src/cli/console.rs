//! `baton console`: the operator console in a browser, for the runs behind a router.

use std::net::SocketAddr;
use std::process::ExitCode;

use super::common::block_on;

/// The arguments of `baton console`.
#[derive(clap::Args)]
pub struct Console {
    #[command(flatten)]
    pub reach: super::common::Reach,
    /// Where the page is served: a loopback address (port 0: any free one, printed at start).
    #[arg(long, default_value = "127.0.0.1:8080", value_name = "ADDR")]
    pub listen: SocketAddr,
}

impl Console {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let Console { reach, listen } = self;
        block_on(async move {
            let listener = crate::console::bind(listen).await?;
            crate::console::serve(listener, &reach.connect, reach.zenoh_config.as_deref()).await?;
            Ok(ExitCode::SUCCESS)
        })
    }
}
