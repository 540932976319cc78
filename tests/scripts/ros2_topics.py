"""ROS 2 topics for Baton's tests, from an implementation Baton did not write: zenoh-ros2-sdk (ROBOTIS), speaking
rmw_zenoh on a router at 127.0.0.1:PORT, its message definitions given inline so that it works offline.

    python3 ros2_topics.py PORT DOMAIN

It plays a cell's sensors and indicators:
- publishes /door (std_msgs/msg/Bool) and /level (std_msgs/msg/Int32) every 50 ms, as sensor drivers do, with
  the values stdin sets: `PUBLISH door true`, `PUBLISH level 7` (answered `PUBLISHED door true`);
- subscribes to /lamp (std_msgs/msg/Bool) and /beacon (std_msgs/msg/ColorRGBA), and prints `LAMP <data>` and
  `BEACON <r> <g> <b> <a>` for every message whose content differs from the last one.

It prints READY once its publishers and subscriptions are declared, and runs until stdin closes.
"""

import sys
import threading
import time

from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber

BOOL = "bool data"
INT32 = "int32 data"
COLOR = "float32 r\nfloat32 g\nfloat32 b\nfloat32 a"


SAY = threading.Lock()


def say(line):
    # Zenoh calls back on threads of its own: one line at a time, whole.
    with SAY:
        sys.stdout.write(line + "\n")
        sys.stdout.flush()


def main() -> None:
    port, domain = int(sys.argv[1]), int(sys.argv[2])
    where = dict(domain_id=domain, router_ip="127.0.0.1", router_port=port)
    door = ROS2Publisher("/door", "std_msgs/msg/Bool", msg_definition=BOOL, node_name="door_sensor", **where)
    level = ROS2Publisher("/level", "std_msgs/msg/Int32", msg_definition=INT32, node_name="level_sensor", **where)
    last = {}

    def shown(topic, text):
        if last.get(topic) != text:
            last[topic] = text
            say(f"{topic} {text}")

    lamp = ROS2Subscriber("/lamp", "std_msgs/msg/Bool", lambda m: shown("LAMP", str(m.data).lower()),
                          msg_definition=BOOL, node_name="lamp", **where)
    beacon = ROS2Subscriber("/beacon", "std_msgs/msg/ColorRGBA",
                            lambda m: shown("BEACON", f"{m.r:g} {m.g:g} {m.b:g} {m.a:g}"),
                            msg_definition=COLOR, node_name="beacon", **where)
    values = {"door": False, "level": 0}
    lock = threading.Lock()
    stop = threading.Event()

    def publish():
        while not stop.is_set():
            with lock:
                door.publish(data=values["door"])
                level.publish(data=values["level"])
            time.sleep(0.05)

    threading.Thread(target=publish, daemon=True).start()
    say("READY")
    for line in sys.stdin:
        words = line.split()
        if len(words) != 3 or words[0] != "PUBLISH" or words[1] not in values:
            say(f"UNKNOWN COMMAND {line.strip()}")
            continue
        with lock:
            values[words[1]] = words[2].lower() == "true" if words[1] == "door" else int(words[2])
        say(f"PUBLISHED {words[1]} {words[2]}")
    stop.set()
    for endpoint in (door, level, lamp, beacon):
        endpoint.close()


if __name__ == "__main__":
    main()
