#!/usr/bin/env bash
# Runs examples/robot_cell.st on loopback against three servers Baton did not write: a Fibonacci action server
# written with hiroz (tests/ros2-peer, built on first use), a SetBool service server from zenoh-ros2-sdk and an
# OPC UA server written with asyncua (both installed on first use), with the two agents `arm1` and `cell1`.
# Run it from a checkout after `cargo build --release`:
#
#     examples/robot_cell.sh [--rerun SINK]
set -euo pipefail
cd "$(dirname "$0")/.."
bin=target/release
[ -x "$bin/baton" ] && [ -x "$bin/baton-agent" ] || { echo "build first: cargo build --release" >&2; exit 2; }
peer=tests/ros2-peer/target/release/ros2-peer
if [ ! -x "$peer" ]; then
  echo "building the test action server (tests/ros2-peer, once)..." >&2
  cargo build --release --locked --quiet --manifest-path tests/ros2-peer/Cargo.toml
fi
python3 -c "import zenoh_ros2_sdk" 2>/dev/null ||
  python3 -m pip install --quiet 'zenoh-ros2-sdk==0.1.8' 'eclipse-zenoh==1.10.2' 'rosbags==0.11.9'
python3 -c "import asyncua" 2>/dev/null || python3 -m pip install --quiet 'asyncua==2.1.0'
free_port() { python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }
port=$(free_port)
ua_port=$(free_port)
endpoint="tcp/127.0.0.1:$port"
logs=$(mktemp -d)
# The chart names the machine's endpoint; this copy names the test server's port.
sed "s|127.0.0.1:4840/|127.0.0.1:$ua_port/|" examples/robot_cell.st > "$logs/robot_cell.st"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
}
trap cleanup EXIT
# The coordinator embeds the router the servers and agents join; it waits for its agents.
"$bin/baton" run "$logs/robot_cell.st" --listen "$endpoint" "$@" &
coordinator=$!
sleep 0.3
# Each server serves until its stdin closes: their stdin is a FIFO this script holds open, so they also go when
# it does.
mkfifo "$logs/hold"
exec 3<> "$logs/hold"
"$peer" "$endpoint" 0 /arm/move_to succeed < "$logs/hold" > "$logs/action_server.log" &
pids+=($!)
python3 tests/scripts/ros2_service_server.py "$port" 0 /gripper/close < "$logs/hold" > "$logs/service_server.log" &
pids+=($!)
python3 tests/scripts/opcua_server.py "$ua_port" < "$logs/hold" > "$logs/opcua_server.log" 2>&1 &
pids+=($!)
"$bin/baton-agent" --connect "$endpoint" --name arm1 2> "$logs/arm1.log" &
pids+=($!)
"$bin/baton-agent" --connect "$endpoint" --name cell1 2> "$logs/cell1.log" &
pids+=($!)
wait "$coordinator"
echo "servers and agents said (in $logs):"
tail -n +1 "$logs"/*.log
