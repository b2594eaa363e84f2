"""Benchmark of the twin viewer: loading a twin, starting the server, first data at a client, slider latency.

Per synthetic scene and Gaussian count: reading the twin from files (3DGS ``.ply`` + labels + joints
JSON, as ``artitwin view twin.ply --joints ...``), ``build_viewer`` (server start and scene
upload), start-to-first-frame (from starting the server until a websocket client speaking viser's
protocol has received the whole scene: what the browser needs before its first full frame), the
bytes it received, and the slider round trip (client sends a slider value, receives the part's new
pose). Rendering in the browser itself is not timed here (see tests/viewer/test_viewer_browser.py).

Run: ``python bench/bench_viewer.py [--scenes tiny door+drawer] [--gaussians 10000 100000] [--repeats 5]``;
prints a table and writes ``bench/results/viewer.json``.
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import print_table, write_results  # noqa: E402

from artitwin._viewer import build_viewer, load_twin  # noqa: E402
from artitwin_core.reconstruction import write_ply  # noqa: E402
from artitwin_core.synth import BENCHMARK_SCENES, generate_scene  # noqa: E402
from artitwin_core.viewer import synthetic_twin  # noqa: E402


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _Client:
    def __init__(self, url: str):
        import viser
        from websockets.sync.client import connect

        self.ws = connect(url.replace("http", "ws"), subprotocols=[f"viser-v{viser.__version__}"], max_size=None)
        self.bytes = 0

    def until(self, message_type: str, timeout_s: float = 60.0) -> list[dict]:
        import msgspec
        import zstandard

        out: list[dict] = []
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            raw = self.ws.recv(timeout=max(end - time.monotonic(), 0.01))
            self.bytes += len(raw)
            size, n = int.from_bytes(raw[:8], "little"), int.from_bytes(raw[8:16], "little")
            msgs = msgspec.msgpack.decode(zstandard.ZstdDecompressor().decompress(raw[16 : 16 + n], max_output_size=size))
            out.extend(msgs["messages"])
            if any(m["type"] == message_type for m in out):
                return out
        raise TimeoutError(f"no {message_type} in {timeout_s} s")

    def send(self, message: dict) -> None:
        import msgspec

        self.ws.send(msgspec.msgpack.encode(message))


def _twin_files(twin, folder: Path) -> tuple[Path, Path, Path]:
    write_ply(folder / "twin.ply", twin.gaussians)
    np.save(folder / "labels.npy", twin.gaussians.labels)
    joints = [{"name": n, "type": j.joint_type, "axis": j.axis.tolist(), "pivot": j.pivot.tolist(),
               "range": j.q_range.tolist(), "pitch": j.pitch} for j, n in zip(twin.joints, twin.joint_names, strict=True)]
    (folder / "joints.json").write_text(json.dumps({"joints": joints}))
    return folder / "twin.ply", folder / "joints.json", folder / "labels.npy"


def _one(twin, repeats: int) -> dict:
    loads, starts, firsts, rounds, nbytes = [], [], [], [], 0
    with tempfile.TemporaryDirectory() as tmp:
        ply, joints, labels = _twin_files(twin, Path(tmp))
        for _ in range(repeats):
            t0 = time.perf_counter()
            loaded = load_twin(ply, joints=joints, labels=labels)
            loads.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            viewer = build_viewer(loaded, port=_free_port())
            starts.append(time.perf_counter() - t0)
            try:
                client = _Client(viewer.url)
                init = client.until("ReplayDoneMessage")
                firsts.append(time.perf_counter() - t0)
                nbytes = client.bytes
                client.send({"type": "ViewerCameraMessage", "wxyz": [1.0, 0, 0, 0], "position": [0.0, 0, 3],
                             "fov": 1.0, "near": 0.01, "far": 100.0, "image_height": 480, "image_width": 640,
                             "look_at": [0.0, 0, 0], "up_direction": [0.0, 1, 0]})
                time.sleep(0.2)
                sliders = [m for m in init if m["type"] == "GuiSliderMessage"]
                for i in range(10):
                    value = sliders[0]["props"]["max"] * (i + 1) / 10
                    t1 = time.perf_counter()
                    client.send({"type": "GuiUpdateMessage", "uuid": sliders[0]["uuid"], "updates": {"value": value}})
                    client.until("SetOrientationMessage" if loaded.joints[0].joint_type != "prismatic"
                                 else "SetPositionMessage")
                    rounds.append(time.perf_counter() - t1)
                client.ws.close()
            finally:
                viewer.close()
    return {"load_s": float(np.median(loads)), "server_start_s": float(np.median(starts)),
            "start_to_first_frame_s": float(np.median(firsts)), "scene_mb": nbytes / 1e6,
            "slider_round_trip_ms": float(np.median(rounds) * 1e3), "slider_p90_ms": float(np.percentile(rounds, 90) * 1e3)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["tiny", "door+drawer"])
    parser.add_argument("--gaussians", nargs="+", type=int, default=[10_000, 100_000])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    rows = []
    for name in args.scenes:
        scene = generate_scene(BENCHMARK_SCENES[name])
        for count in args.gaussians:
            t0 = time.perf_counter()
            twin = synthetic_twin(scene, num_views=8, width=256, height=192, max_gaussians=count)
            row = {"scene": name, "gaussians": twin.gaussians.num_gaussians, "joints": twin.num_parts,
                   "synthetic_twin_s": time.perf_counter() - t0, **_one(twin, args.repeats)}
            rows.append(row)
            print(row, flush=True)
    print_table(rows)
    path = write_results("viewer", rows, {"repeats": args.repeats})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
