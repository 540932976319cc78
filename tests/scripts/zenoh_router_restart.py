"""Zenoh alone, no Baton: does a put cross a router that was restarted? (docs/book/src/benchmarks.md, "Routers in a mesh")

zenohd 1.10.2 routers (ROUTERS, default 3; each connects to those started before it, or with REVERSE=1 to those
after it), a subscriber client on R0, a publisher client on R1 putting every 20 ms. R1 is killed and started
again on its port (NOKILL=1: not, the control). Then: do the old publisher's puts arrive, is its liveliness
token seen, do a fresh session's puts arrive (REDECLARE=1 declares the subscriber again first; FIXED_ID=1 gives
the routers fixed Zenoh ids)? Needs the `eclipse-zenoh==1.10.2` package and zenohd (ZENOHD, or where .ci/run
installs it: ~/.cache/baton-tools/zenohd-1.10.2).

    python3 tests/scripts/zenoh_router_restart.py TRIALS
"""
import json, os, socket, subprocess, sys, tempfile, time, threading
import zenoh

TOOLS = os.environ.get("BATON_TOOLS") or os.path.expanduser("~/.cache/baton-tools")
ZENOHD = os.environ.get("ZENOHD") or os.path.join(TOOLS, "zenohd-1.10.2/bin/zenohd")

def free_port():
    s = socket.socket(); s.bind(("127.0.0.1", 0)); p = s.getsockname()[1]; s.close(); return p

def start_router(d, ports, i):
    cfg = {"mode": "router", "listen": {"endpoints": [f"tcp/127.0.0.1:{ports[i]}"]},
           "connect": {"endpoints": [f"tcp/127.0.0.1:{p}" for p in (ports[i+1:] if os.environ.get("REVERSE") else ports[:i])]},
           "scouting": {"multicast": {"enabled": False}}}
    if os.environ.get("FIXED_ID"):
        cfg["id"] = "%02x" % (0xa0 + i) * 8
    path = os.path.join(d, f"r{i}.json5"); open(path, "w").write(json.dumps(cfg))
    p = subprocess.Popen([ZENOHD, "-c", path], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    for _ in range(500):
        try:
            socket.create_connection(("127.0.0.1", ports[i]), timeout=0.1).close(); return p
        except OSError:
            time.sleep(0.01)
    raise RuntimeError("router did not listen")

def client(port):
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    c.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(c)

def trial():
    d = tempfile.mkdtemp()
    nrouters = int(os.environ.get("ROUTERS", "3"))
    ports = [free_port() for _ in range(nrouters)]
    routers = [start_router(d, ports, i) for i in range(nrouters)]
    sub_s = client(ports[0]); pub_s = client(ports[1])
    got = []
    sub = sub_s.declare_subscriber("repro/report/a", lambda s: got.append((time.time(), bytes(s.payload.to_bytes()))))
    token = pub_s.liveliness().declare_token("repro/alive/a")
    pub = pub_s.declare_publisher("repro/report/a")
    stop = threading.Event()
    def loop():
        while not stop.is_set():
            try: pub.put(b"old")
            except Exception: pass
            time.sleep(0.02)
    t = threading.Thread(target=loop); t.start()
    deadline = time.time() + 5
    while not got and time.time() < deadline: time.sleep(0.01)
    before = len(got) > 0
    if not os.environ.get("NOKILL"):
        routers[1].kill(); routers[1].wait()
        routers[1] = start_router(d, ports, 1)
    restarted = time.time()
    deadline = restarted + 8
    while time.time() < deadline:
        if any(g > restarted + 0.5 for g, _ in got): break
        time.sleep(0.05)
    after = any(g > restarted + 0.5 and b == b"old" for g, b in got)
    alive = len(list(sub_s.liveliness().get("repro/alive/a", timeout=2.0))) > 0
    if os.environ.get("REDECLARE"):
        sub2 = sub_s.declare_subscriber("repro/report/a", lambda s: got.append((time.time(), bytes(s.payload.to_bytes()))))
        time.sleep(0.5)
    fresh = client(ports[1])
    t0 = time.time()
    fp = fresh.declare_publisher("repro/report/a")
    for _ in range(100):
        fp.put(b"fresh"); time.sleep(0.02)
        if any(g > t0 and b == b"fresh" for g, b in got): break
    fresh_ok = any(g > t0 and b == b"fresh" for g, b in got)
    fresh.close()
    print("  after restart: old session's puts arrive:", after, "| its liveliness seen:", alive, "| a fresh session's puts arrive:", fresh_ok)
    stop.set(); t.join()
    token.undeclare()
    for s in (sub_s, pub_s):
        s.close()
    for r in routers:
        r.kill(); r.wait()
    return before, after

n = int(sys.argv[1]) if len(sys.argv) > 1 else 10
lost = 0
for i in range(n):
    before, after = trial()
    if not before: print("trial", i, ": never delivered before the restart")
    if before and not after: lost += 1; print("trial", i, ": LOST after the restart")
print(f"{n} trials, route lost after a restart in {lost}")
