#!/usr/bin/env python3
"""Regenerates the README's picture of the Rerun viewer showing a `baton demo` recording.

    python3 tests/scripts/screenshot.py [OUT.png]      (default: docs/demo-timeline.png)

Needs the release build (`cargo build --release`), `rerun-sdk==0.36.3` (pip) and, without a GPU, Mesa's software
Vulkan (`apt install mesa-vulkan-drivers libvulkan1`).

The demo runs as a newcomer runs it, saving its recording. When the cell has finished its second part, the
recording as it stands on disk is copied: the picture shows the run in progress (the steps active then coloured in
the chart, the timelines up to that moment), as the viewer shows it when the time cursor is there. A headless
viewer, bound to a free port of 127.0.0.1, opens that copy and is asked for screenshots until the picture has
stayed the same for five seconds (everything loaded and laid out, the start-up notice gone). Every process started here is stopped before the script
ends.
"""

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
WAIT_S = 120
STEADY_S = 5


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stop(p: subprocess.Popen | None) -> None:
    if p is not None and p.poll() is None:
        os.killpg(p.pid, signal.SIGTERM)
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()


def record_demo(baton: Path, work: Path) -> Path:
    """Runs the demo; returns the copy of its recording taken after part 2."""
    rrd, snapshot = work / "baton-demo.rrd", work / "snapshot.rrd"
    demo = subprocess.Popen(
        [str(baton), "demo", "--rerun", f"save:{rrd}"], stdout=subprocess.PIPE, text=True, start_new_session=True
    )
    try:
        for line in demo.stdout:
            print(line, end="")
            if "part 2 done" in line:
                shutil.copyfile(rrd, snapshot)
        if demo.wait() != 0:
            sys.exit(f"the demo failed (exit {demo.returncode})")
    finally:
        stop(demo)
    if not snapshot.exists():
        sys.exit("the demo never finished its second part")
    return snapshot


def screenshot(rrd: Path, out: Path, work: Path) -> None:
    from rerun.experimental import ViewerClient

    port = free_port()
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    log = open(work / "viewer.log", "wb")
    # Its own process group: the `rerun` script starts the viewer as a child, and both must go.
    viewer = subprocess.Popen(
        ["rerun", "--headless", "--bind", "127.0.0.1", "--port", str(port), "--window-size", "1600x900", str(rrd)],
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=log,
    )
    try:
        deadline = time.monotonic() + WAIT_S
        # Steady: the same picture for STEADY_S (the viewer's start-up notice has gone by then too).
        client, previous, since, shots = None, None, time.monotonic(), 0
        while True:
            if viewer.poll() is not None:
                sys.exit(f"the viewer stopped (exit {viewer.returncode}):\n{(work / 'viewer.log').read_text()[-4000:]}")
            if time.monotonic() > deadline:
                sys.exit(f"no steady picture from the viewer at {url} after {WAIT_S} s")
            try:
                client = client or ViewerClient.connect(url)
                shot = work / f"shot-{shots}.png"
                client.save_screenshot(str(shot))
                shots += 1
            except Exception:  # the viewer is still starting
                time.sleep(0.2)
                continue
            picture = shot.read_bytes()
            if picture != previous:
                previous, since = picture, time.monotonic()
            elif time.monotonic() - since >= STEADY_S:
                break
            time.sleep(0.5)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(picture)
        print(f"screenshot: {out} (steady after {shots} shots)")
    finally:
        stop(viewer)


def main() -> None:
    out = Path(sys.argv[1] if len(sys.argv) > 1 else ROOT / "docs" / "demo-timeline.png").resolve()
    baton = ROOT / "target" / "release" / "baton"
    if not baton.exists():
        sys.exit(f"{baton} is missing: run `cargo build --release` first")
    if shutil.which("rerun") is None:
        sys.exit("the `rerun` command is missing: pip install 'rerun-sdk==0.36.3'")
    with tempfile.TemporaryDirectory() as work:
        work = Path(work)
        screenshot(record_demo(baton, work), out, work)


if __name__ == "__main__":
    main()
