"""Zenoh alone, no Baton: does a client's mutual-TLS session to zenohd survive traffic in both directions at once?

zenohd 1.10.2 listening on mutual TLS (certificates made here with openssl), and a client W answering every put on
`race/out` with one on `race/in`. For SECONDS (default 20), client sessions A open one after another, each declaring
a liveliness token and writing at once (while its TLS 1.3 session tickets arrive and are read), then putting on
`race/out` while W's answers come in: reads and writes overlap. A token of A that vanishes and comes back for W
before its session closes is a session zenoh dropped and took back. TCP=1 runs the same over plain TCP, the control.
It prints the drops, and the zenohd log's `TX task failed` / `RX task failed` lines. Needs `eclipse-zenoh==1.10.2`, zenohd
(ZENOHD, or where .ci/run installs it) and openssl.

    python3 tests/scripts/zenoh_tls_race.py [SECONDS]

Seen on 2026-12-04 (2-core development machine, idle): over TLS, sessions dropped with `TX task failed: handshake
not complete` (zenoh-link-tls 1.10.2 reads and writes one rustls connection from two tasks through an `UnsafeCell`,
and rustls's `process_new_packets` parks its state as `Err(HandshakeNotComplete)` while it reads); over TCP, none.
"""
import json, os, socket, subprocess, sys, tempfile, threading, time
import zenoh

HOME = os.path.expanduser("~")
TOOLS = os.environ.get("BATON_TOOLS") or os.path.join(HOME, ".cache/baton-tools")
ZENOHD = os.environ.get("ZENOHD") or os.path.join(TOOLS, "zenohd-1.10.2/bin/zenohd")
TLS = not os.environ.get("TCP")


def free_port():
    s = socket.socket(); s.bind(("127.0.0.1", 0)); p = s.getsockname()[1]; s.close(); return p


def certs(d):
    def run(*args):
        subprocess.run(["openssl", *args], check=True, cwd=d, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    run("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes", "-keyout", "ca.key",
        "-out", "ca.pem", "-days", "2", "-subj", "/CN=race CA")
    for name in ["router", "a", "w"]:
        run("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes", "-keyout", f"{name}.key",
            "-out", f"{name}.csr", "-subj", f"/CN={name}")
        ext = os.path.join(d, f"{name}.ext")
        open(ext, "w").write("subjectAltName=IP:127.0.0.1,DNS:localhost\nextendedKeyUsage=serverAuth,clientAuth\n")
        run("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial",
            "-out", f"{name}.pem", "-days", "2", "-extfile", ext)


def client(d, port, name):
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("scouting/multicast/enabled", "false")
    if TLS:
        c.insert_json5("connect/endpoints", json.dumps([f"tls/127.0.0.1:{port}"]))
        tls = {"root_ca_certificate": f"{d}/ca.pem", "connect_certificate": f"{d}/{name}.pem",
               "connect_private_key": f"{d}/{name}.key", "enable_mtls": True}
        c.insert_json5("transport/link/tls", json.dumps(tls))
    else:
        c.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    return zenoh.open(c)


def main():
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else 20.0
    d = tempfile.mkdtemp()
    port = free_port()
    cfg = {"mode": "router", "scouting": {"multicast": {"enabled": False}}}
    if TLS:
        certs(d)
        cfg["listen"] = {"endpoints": [f"tls/127.0.0.1:{port}"]}
        cfg["transport"] = {"link": {"tls": {"root_ca_certificate": f"{d}/ca.pem", "listen_certificate": f"{d}/router.pem",
                                             "listen_private_key": f"{d}/router.key", "enable_mtls": True}}}
    else:
        cfg["listen"] = {"endpoints": [f"tcp/127.0.0.1:{port}"]}
    path = os.path.join(d, "router.json5"); open(path, "w").write(json.dumps(cfg))
    log = open(os.path.join(d, "zenohd.log"), "w")
    router = subprocess.Popen([ZENOHD, "-c", path], stdout=log, stderr=log,
                              env={**os.environ, "RUST_LOG": "zenoh_transport=debug"})
    try:
        for _ in range(500):
            try:
                socket.create_connection(("127.0.0.1", port), timeout=0.1).close(); break
            except OSError:
                time.sleep(0.01)
        w = client(d, port, "w")
        events = []
        w.liveliness().declare_subscriber("race/alive/*", lambda s: events.append((str(s.key_expr), s.kind)))
        answers = w.declare_publisher("race/in")
        w.declare_subscriber("race/out", lambda s: answers.put(s.payload))
        # Sessions opened one after another, each writing at once — while its TLS 1.3 session tickets arrive
        # and are read — and for a moment after, answered all the while.
        end, rounds, sent = time.time() + seconds, 0, 0
        while time.time() < end:
            rounds += 1
            a = client(d, port, "a")
            token = a.liveliness().declare_token(f"race/alive/{rounds}")
            got = [0]
            a.declare_subscriber("race/in", lambda s: got.__setitem__(0, got[0] + 1))
            out = a.declare_publisher("race/out")
            for _ in range(200):
                out.put(b"x" * 64); sent += 1
            time.sleep(0.05)
            del token
            a.close()
        time.sleep(0.5)
        link = "tls" if TLS else "tcp"
        # A token that vanished and came back before its session closed: a session zenoh dropped and took back.
        drops = 0
        for k in {k for k, _ in events}:
            kinds = [kind for key, kind in events if key == k]
            drops += max(0, kinds.count(zenoh.SampleKind.PUT) - 1)
        failed = [l.strip() for l in open(os.path.join(d, "zenohd.log")) if "task failed" in l]
        print(f"{link}: {rounds} sessions, {sent} puts; sessions dropped and taken back: {drops}")
        for l in failed[:10]:
            print("  zenohd:", l[-160:])
    finally:
        router.kill()


if __name__ == "__main__":
    main()
