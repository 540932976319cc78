"""A ROS 2 service server for Baton's tests, from an implementation Baton did not write: zenoh-ros2-sdk (ROBOTIS),
speaking rmw_zenoh on a router at 127.0.0.1:PORT. It serves std_srvs/srv/SetBool, its definitions given inline
so that it works offline, and computes the type hash itself. It answers success = the request's data, and
prints READY once it serves and one line per request, for the test to read.

    python3 ros2_service_server.py PORT DOMAIN SERVICE [late]

With `late`, it serves as zenoh-ros2-sdk's declaration order can make it look to a client: its liveliness token
is in the graph while its queryable is not (it prints TOKEN ONLY), until the test writes SERVE on stdin.
"""

import sys
import threading

import zenoh

from zenoh_ros2_sdk import ROS2ServiceServer

REQUEST = "bool data"
RESPONSE = "bool success\nstring message"


def main() -> None:
    port, domain, service = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
    holder = {}

    def answer(request):
        print(f"REQUEST data={request.data}", flush=True)
        cls = holder["server"].response_msg_class
        if request.data:
            return cls(success=True, message="gripper closed")
        return cls(success=False, message="nothing to grip")

    holder["server"] = ROS2ServiceServer(
        service,
        "std_srvs/srv/SetBool",
        callback=answer,
        request_definition=REQUEST,
        response_definition=RESPONSE,
        domain_id=domain,
        router_ip="127.0.0.1",
        router_port=port,
    )
    server = holder["server"]
    if sys.argv[4:] == ["late"]:
        # The SDK declares the tokens before the queryable; hold the queryable back until told.
        server.queryable.undeclare()
        print("TOKEN ONLY", flush=True)
        while sys.stdin.readline().strip() != "SERVE":
            pass
        server.queryable = server.session_mgr.session.declare_queryable(
            zenoh.KeyExpr(server.keyexpr), server._query_handler, complete=True
        )
    print(f"READY {server.keyexpr}", flush=True)
    # Serve until the test closes stdin or kills the process.
    threading.Event().wait() if sys.stdin is None else sys.stdin.read()
    holder["server"].close()


if __name__ == "__main__":
    main()
