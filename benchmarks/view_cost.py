"""What a live-view frame costs the process that sends it, for the two viewers the project
could feed: Rerun (its gRPC server and web viewer from the `rerun-sdk` wheel) and Foxglove
(foxglove-sdk's WebSocket server, read by the Foxglove app or Lichtblick).

The frames are those of a real run: every scene is run for `--seconds` on the virtual clock
(default device, default user), and its tick rows and installed updates are drawn at 60
frames a second of log time, by `haptic_server.live_view.SceneView` to a Rerun server, and by
`haptic_server.foxglove_view.ViewFrames` (the same scene, device, proxy, forces and contacts
as Foxglove messages) to a Foxglove WebSocket server. Each sink has one client that receives
everything: Rerun's own web viewer in a headless Chromium for Rerun; a WebSocket client that
subscribes to every channel, in the same browser, for Foxglove (the Foxglove app itself needs
the network). The two sinks alternate scene by scene and repetition by repetition. Reports
the CPU time per frame of the sending process (median and p90 over repetitions) and the
bytes sent per frame where the sink says.

    python -m haptic_local_model.benchmarks.view_cost [--scenes testbed ...] [--seconds 5] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from haptic_local_model.shared.config import shipped

if TYPE_CHECKING:
    from haptic_local_model.haptic_server.log import LogContents

FOXGLOVE_CLIENT_JS = """
(url) => new Promise((resolve) => {
  const ws = new WebSocket(url, ["foxglove.sdk.v1"]);
  ws.binaryType = "arraybuffer";
  window.__received = 0;
  let sub = 1;
  ws.onmessage = (ev) => {
    if (typeof ev.data === "string") {
      const msg = JSON.parse(ev.data);
      if (msg.op === "advertise") {
        const subscriptions = msg.channels.map((c) => ({ id: sub++, channelId: c.id }));
        ws.send(JSON.stringify({ op: "subscribe", subscriptions }));
      }
    } else {
      window.__received += ev.data.byteLength;
    }
  };
  ws.onopen = () => resolve(true);
})
"""


def _run_log(scene: str, seconds: float) -> LogContents:
    """The log of a virtual-clock run."""
    import tempfile

    from haptic_local_model.haptic_server.log import read_log

    with tempfile.TemporaryDirectory() as tmp:
        log_path = Path(tmp) / "run.mcap"
        from haptic_local_model.haptic_server.harness.run import main as run_main

        code = run_main(["--clock", "virtual", "--scene", scene, "--duration", str(seconds),
                         "--log", str(log_path)])  # fmt: skip
        if code != 0:
            raise RuntimeError(f"the virtual-clock run of {scene} failed ({code})")
        return read_log(log_path)


def rerun_cost(log: LogContents, page: Any, ports: tuple[int, int]) -> dict[str, float]:
    """CPU s per frame of SceneView to a Rerun server watched by its web viewer in `page`."""
    from haptic_local_model.haptic_server.live_view import (
        RerunServer,
        SceneView,
        ViewAddress,
        open_recording,
    )

    address = ViewAddress("127.0.0.1", *ports)
    server = RerunServer(address)
    try:
        rec = open_recording(address, "view-cost")
        page.goto(address.url)
        page.locator("canvas").filter(visible=True).first.wait_for(timeout=60_000)
        view = SceneView(log.metadata["configs"]["scene"], rec)
        cpu, n = _drive(view.frame, view.update, log)
        rec.flush(timeout_sec=10.0)
        rec.disconnect()  # before its server goes
        return {"cpu_ms_per_frame": 1e3 * cpu / n, "frames": n}
    finally:
        server.stop()


def foxglove_cost(log: LogContents, page: Any, blank_url: str) -> dict[str, float]:
    """CPU s per frame of ViewFrames to a Foxglove WebSocket server with one subscriber."""
    import foxglove
    from foxglove.channels import FrameTransformsChannel, SceneUpdateChannel

    from haptic_local_model.haptic_server.foxglove_view import (
        SCENE_TOPIC,
        TRANSFORMS_TOPIC,
        ViewFrames,
    )

    ctx = foxglove.Context()
    server = foxglove.start_server(host="127.0.0.1", port=0, context=ctx)  # a free port
    port = server.port
    try:
        scene_ch = SceneUpdateChannel(SCENE_TOPIC, context=ctx)
        tf_ch = FrameTransformsChannel(TRANSFORMS_TOPIC, context=ctx)
        page.goto(blank_url)  # a page of an http origin (the server refuses about:blank's)
        page.evaluate(FOXGLOVE_CLIENT_JS, f"ws://127.0.0.1:{port}")
        time.sleep(0.5)  # advertise, subscribe
        frames = ViewFrames(log.metadata["configs"]["scene"])

        def frame(row: np.void) -> None:
            log_ns = int(float(row["t"]) * 1e9)
            transforms, scene = frames.frame(row, log_ns)
            tf_ch.log(transforms, log_time=log_ns)
            scene_ch.log(scene, log_time=log_ns)

        def update(raw: bytes) -> None:
            frames.set_update(raw, True)

        cpu, n = _drive(frame, update, log)
        time.sleep(0.5)
        received = float(page.evaluate("window.__received"))
        return {"cpu_ms_per_frame": 1e3 * cpu / n, "frames": n, "bytes_per_frame": received / n}
    finally:
        server.stop()


def _drive(frame: Any, update: Any, log: LogContents) -> tuple[float, int]:
    """Feed the log's frames (and the updates installed before each) as the live view takes
    them (haptic_server.live_view.log_frames), at the pace of log time; returns the CPU time
    spent in the calls and the frames sent."""
    from haptic_local_model.haptic_server.live_view import log_frames

    cpu = 0.0
    n = 0
    wall0 = time.monotonic()
    for row, updates, _events, _world in log_frames(log):
        t0 = time.process_time()
        for raw in updates:
            update(raw)
        frame(row)
        cpu += time.process_time() - t0
        n += 1
        time.sleep(max(0.0, wall0 + float(row["t"]) - time.monotonic()))
    return cpu, n


def _blank_page_server() -> str:
    """An empty page served on loopback (the Foxglove client's origin)."""
    import http.server
    import threading

    class Blank(http.server.BaseHTTPRequestHandler):
        def do_GET(self) -> None:
            body = b"<!doctype html><title>view cost</title>"
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *_: Any) -> None:
            pass

    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Blank)
    threading.Thread(target=httpd.serve_forever, daemon=True).start()
    return f"http://127.0.0.1:{httpd.server_address[1]}/"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--scenes", nargs="+", default=sorted(shipped("scenes")))
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    from haptic_local_model.benchmarks.browser import chromium, free_ports, open_page

    browser = chromium()
    if browser is None:
        print("view_cost: needs Chromium (apt-get install chromium)", file=sys.stderr)
        return 2
    results: dict[str, dict[str, list[dict[str, float]]]] = {}
    blank = _blank_page_server()
    with open_page(blank, browser, viewer=False) as page:
        for scene in args.scenes:
            log = _run_log(scene, args.seconds)
            runs: dict[str, list[dict[str, float]]] = {"rerun": [], "foxglove": []}
            for k in range(args.repeat):  # alternating, first one then the other
                order = ("rerun", "foxglove") if k % 2 == 0 else ("foxglove", "rerun")
                for sink in order:
                    if sink == "rerun":
                        web, grpc = free_ports(2)
                        runs[sink].append(rerun_cost(log, page, (web, grpc)))
                    else:
                        runs[sink].append(foxglove_cost(log, page, blank))
            results[scene] = runs
            _print(scene, runs)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2))
    return 0


def _print(scene: str, runs: dict[str, list[dict[str, float]]]) -> None:
    for sink, rs in runs.items():
        cpu = [r["cpu_ms_per_frame"] for r in rs]
        extra = ""
        if rs and "bytes_per_frame" in rs[0]:
            extra = f", {np.median([r['bytes_per_frame'] for r in rs]):.0f} B/frame received"
        print(
            f"{scene:<22} {sink:<9} CPU per frame: median {np.median(cpu):.3f} ms, "
            f"max {max(cpu):.3f} ms over {len(rs)} runs of {int(rs[0]['frames'])} frames{extra}"
        )


if __name__ == "__main__":
    sys.exit(main())
