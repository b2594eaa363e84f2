"""The viewer page in a real browser: headless Chromium opens it, a slider is moved, the part moves on screen.

Chromium is driven over the DevTools protocol (a websocket; no playwright needed) with WebGL on
SwiftShader, so no GPU or display is used. The changed pixels between the screenshots before and
after moving the slider must lie where the door is projected at either state, with the camera
the page itself reports. Needs Debian's ``chromium`` (``apt-get install -y chromium``) or
``ARTITWIN_CHROMIUM`` pointing at a Chromium binary; skips, saying so, without one.
"""

from __future__ import annotations

import base64
import dataclasses
import io
import json
import os
import shutil
import subprocess
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from artitwin._viewer import build_viewer
from artitwin_core.gaussians import LABEL_PART, GaussianParams
from artitwin_core.viewer import part_poses, quat_wxyz_to_matrix
from tests.viewer.conftest import free_port

CHROMIUM = os.environ.get("ARTITWIN_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(
    CHROMIUM is None,
    reason="Chromium not found: install Debian's package (apt-get install -y chromium) or set ARTITWIN_CHROMIUM",
)
WIDTH, HEIGHT = 900, 560


class _Browser:
    """One headless Chromium with one page, driven by DevTools protocol commands."""

    def __init__(self, profile: Path):
        from websockets.sync.client import connect

        self.proc = subprocess.Popen(
            [CHROMIUM, "--headless", "--no-sandbox", "--remote-debugging-port=0", f"--user-data-dir={profile}",
             f"--window-size={WIDTH},{HEIGHT}", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
             "--hide-scrollbars", "--mute-audio", "--no-first-run", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )
        port_file = profile / "DevToolsActivePort"  # Chromium writes its chosen port here
        self._wait(lambda: port_file.is_file() and port_file.read_text().strip(), 20, "Chromium's DevTools port")
        port = int(port_file.read_text().split()[0])
        pages = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=5).read())
        url = next(p["webSocketDebuggerUrl"] for p in pages if p["type"] == "page")
        self.ws = connect(url, max_size=None)
        self._id = 0

    def _wait(self, ready, timeout_s: float, what: str):
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if self.proc.poll() is not None:
                raise RuntimeError(f"Chromium exited ({self.proc.returncode}) while waiting for {what}")
            if out := ready():
                return out
            time.sleep(0.1)
        raise TimeoutError(f"no {what} after {timeout_s} s")

    def call(self, method: str, **params) -> dict:
        self._id += 1
        self.ws.send(json.dumps({"id": self._id, "method": method, "params": params}))
        while True:  # events arrive in between; skip them
            reply = json.loads(self.ws.recv(timeout=30))
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]

    def evaluate(self, expression: str):
        return self.call("Runtime.evaluate", expression=expression, returnByValue=True)["result"].get("value")

    def screenshot(self) -> np.ndarray:
        from PIL import Image

        png = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), np.int16)

    def close(self) -> None:
        self.ws.close()
        self.proc.terminate()
        self.proc.wait(10)


def _project(points: np.ndarray, camera, size: tuple[int, int]) -> np.ndarray:
    """``[N, 2]`` pixel coordinates of world points in a screenshot ``size = (h, w)``, from the
    camera the page reported (viser: OpenCV axes, vertical ``fov`` in radians)."""
    rot = quat_wxyz_to_matrix(np.asarray(camera.wxyz)[None])[0]
    cam = (points - np.asarray(camera.position)) @ rot  # world -> camera: R^T (x - t)
    cam = cam[cam[:, 2] > 1e-3]
    h, w = size
    f = h / 2 / np.tan(camera.fov / 2)
    return np.stack([f * cam[:, 0] / cam[:, 2] + w / 2, f * cam[:, 1] / cam[:, 2] + h / 2], 1)


def _region(pixels: np.ndarray, size: tuple[int, int], grow: int) -> np.ndarray:
    from scipy.ndimage import binary_dilation

    mask = np.zeros(size, bool)
    ij = np.round(pixels).astype(int)
    ok = (ij[:, 0] >= 0) & (ij[:, 0] < size[1]) & (ij[:, 1] >= 0) & (ij[:, 1] < size[0])
    mask[ij[ok, 1], ij[ok, 0]] = True
    return binary_dilation(mask, iterations=grow)


# Rectangles of the page's floating widgets (GUI panel, notifications, slider tooltip): they are
# not the 3D view, and a toast's animation or the slider's own thumb must not count as a change.
_OVERLAYS_JS = """(() => {
  const canvas = document.querySelector('canvas'), out = [];
  for (const e of document.querySelectorAll('body *')) {
    const p = getComputedStyle(e).position;
    if ((p === 'fixed' || p === 'absolute') && e !== canvas && !e.contains(canvas)) {
      const r = e.getBoundingClientRect();
      if (r.width * r.height > 0 && r.width * r.height < 0.5 * innerWidth * innerHeight)
        out.push([r.left, r.top, r.right, r.bottom]);
    }
  }
  return out;
})()"""


def _scene_pixels(browser: _Browser, size: tuple[int, int]) -> np.ndarray:
    keep = np.ones(size, bool)
    for left, top, right, bottom in browser.evaluate(_OVERLAYS_JS):
        keep[max(int(top) - 2, 0) : int(np.ceil(bottom)) + 2, max(int(left) - 2, 0) : int(np.ceil(right)) + 2] = False
    return keep


def _settled(browser: _Browser, timeout_s: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
    """A screenshot once two taken 0.5 s apart agree (all but 0.2 % of the 3D view's pixels), and
    the mask of the 3D view's pixels not covered by the GUI."""
    shot = browser.screenshot()
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        time.sleep(0.5)
        nxt = browser.screenshot()
        scene = _scene_pixels(browser, nxt.shape[:2])
        if (np.abs(nxt - shot).max(2) > 40)[scene].mean() < 0.002:
            return nxt, scene
        shot = nxt
    raise TimeoutError(f"the page did not settle within {timeout_s} s")


@pytest.mark.slow  # ~35 s on 2 busy cores, most of it SwiftShader's first frame
def test_moving_a_slider_moves_the_door_on_screen(tmp_path, door_twin):
    keep = np.random.default_rng(0).permutation(door_twin.gaussians.num_gaussians)[:5000]  # SwiftShader is slow
    g = door_twin.gaussians
    door_twin = dataclasses.replace(door_twin, gaussians=GaussianParams(
        g.means[keep], g.quats_wxyz[keep], g.log_scales[keep], g.opacity_logits[keep], g.sh[keep], g.labels[keep]))
    viewer = build_viewer(door_twin, port=free_port())
    browser = None
    try:
        browser = _Browser(tmp_path / "profile")
        browser.call("Page.navigate", url=viewer.url)
        client = browser._wait(lambda: next(iter(viewer.server.get_clients().values()), None), 20,
                               "viewer client connection")
        browser._wait(lambda: browser.evaluate("document.querySelectorAll('canvas').length"), 10, "canvas")
        # The first screenshot waits for the first frame (~20 s of shader compiling on SwiftShader);
        # then the camera eases into place.
        before, scene_before = _settled(browser)
        assert before.std() > 5, "the first screenshot is blank: WebGL did not draw"

        # Move the slider in the page as a user would: focus its thumb and press End (to the maximum).
        browser.evaluate("document.querySelector('[role=slider]').focus()")
        for kind in ("keyDown", "keyUp"):
            browser.call("Input.dispatchKeyEvent", type=kind, key="End", code="End", windowsVirtualKeyCode=35)
        slider = viewer.sliders[0]
        browser._wait(lambda: abs(slider.value - slider.max) < 1e-9, 10, "the slider update at the server")
        after, scene_after = _settled(browser)

        size = before.shape[:2]
        changed = (np.abs(after - before).max(2) > 40) & scene_before & scene_after
        part = np.asarray(door_twin.gaussians.means[door_twin.gaussians.labels == LABEL_PART], np.float64)
        where = np.zeros(size, bool)
        for q in (0.0, slider.max):
            pose = part_poses(door_twin.joints, [q])[0]
            where |= _region(_project(part @ pose[:3, :3].T + pose[:3, 3], client.camera, size), size, grow=6)
        if os.environ.get("ARTITWIN_DEBUG_DIR"):
            from PIL import Image
            d = Path(os.environ["ARTITWIN_DEBUG_DIR"])
            Image.fromarray(before.astype(np.uint8)).save(d / "before.png")
            Image.fromarray(after.astype(np.uint8)).save(d / "after.png")
            Image.fromarray((np.stack([changed, where, np.zeros_like(where)], 2) * 255).astype(np.uint8)).save(d / "diff.png")
        assert changed.mean() > 0.005, f"only {changed.mean():.2%} of the pixels changed"
        inside = changed[where].sum() / changed.sum()
        assert inside > 0.9, f"{1 - inside:.1%} of the changed pixels are away from the door"
    finally:
        if browser is not None:
            browser.close()
        viewer.close()
