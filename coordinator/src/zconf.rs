//! The Zenoh configuration of a `baton` process: Baton's settings, on top of the user's own file when given
//! (`--zenoh-config`, for TLS endpoints, credentials and the like).

use std::path::Path;

use anyhow::{anyhow, Context};
use baton_proto::dist::netconfig::NetConfig;

pub fn load(net: &NetConfig, file: Option<&Path>) -> anyhow::Result<zenoh::Config> {
    let Some(file) = file else {
        return zenoh::Config::from_json5(&net.json5()).map_err(|e| anyhow!("zenoh configuration: {e}"));
    };
    let mut config = zenoh::Config::from_file(file)
        .map_err(|e| anyhow!("{e}"))
        .with_context(|| format!("cannot load {}", file.display()))?;
    for (key, value) in net.overrides() {
        config.insert_json5(key, &value).map_err(|e| anyhow!("zenoh configuration `{key}`: {e}"))?;
    }
    Ok(config)
}
