//! zenoh-bridge-ros2dds for Baton's tests: a zenoh peer running Eclipse Zenoh's ROS 2/DDS plugin, as the
//! bridge's own binary does. It connects to one zenoh endpoint and bridges one DDS domain.
//!
//! `ros2dds-bridge <zenoh endpoint to connect to> <DDS domain id>`; Cyclone DDS reads its own settings from
//! `CYCLONEDDS_URI` (the tests keep it on loopback). It prints `READY` once the plugin runs, and ends when its
//! standard input closes, so that a test that dies takes it along.

use tokio::io::AsyncReadExt;
use zenoh::internal::plugins::PluginsManager;
use zenoh::internal::runtime::RuntimeBuilder;

fn config(connect: &str, domain: u32) -> Result<zenoh::Config, String> {
    let mut config = zenoh::Config::default();
    let set = |c: &mut zenoh::Config, key: &str, value: String| {
        c.insert_json5(key, &value).map_err(|e| format!("cannot set {key} to {value}: {e}"))
    };
    set(&mut config, "mode", "\"peer\"".into())?;
    set(&mut config, "connect/endpoints", format!("[\"{connect}\"]"))?;
    set(&mut config, "listen/endpoints", "[]".into())?;
    set(&mut config, "scouting/multicast/enabled", "false".into())?;
    set(&mut config, "scouting/gossip/enabled", "false".into())?;
    // The plugin keeps TRANSIENT_LOCAL topics in a publication cache, which needs timestamps.
    set(&mut config, "timestamping/enabled", "true".into())?;
    set(&mut config, "plugins_loading/enabled", "true".into())?;
    set(&mut config, "plugins/ros2dds", format!("{{ domain: {domain} }}"))?;
    Ok(config)
}

#[tokio::main]
async fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (Some(connect), Some(domain)) = (args.first(), args.get(1).and_then(|d| d.parse::<u32>().ok())) else {
        eprintln!("usage: ros2dds-bridge <zenoh endpoint> <DDS domain id>");
        std::process::exit(2);
    };
    let config = match config(connect, domain) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(2);
        }
    };
    let mut plugins = PluginsManager::static_plugins_only();
    plugins.declare_static_plugin::<zenoh_plugin_ros2dds::ROS2Plugin, &str>("ros2dds", true);
    let mut runtime = match RuntimeBuilder::new(config).plugins_manager(plugins).build().await {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: cannot build the zenoh runtime: {e}");
            std::process::exit(1);
        }
    };
    if let Err(e) = runtime.start().await {
        eprintln!("error: cannot start the zenoh runtime: {e}");
        std::process::exit(1);
    }
    println!("READY");
    let mut rest = Vec::new();
    let _ = tokio::io::stdin().read_to_end(&mut rest).await;
}
