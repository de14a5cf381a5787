"""Screenshots of a web page with headless Chromium, driven over its DevTools pipe (no display, no extra package).

Chromium runs with ``--remote-debugging-pipe``: it reads DevTools commands (JSON, each ended by a NUL
byte) on file descriptor 3 and answers on 4. We attach to its page, navigate, and capture PNGs until
the page is *ready* (by default: past a loading screen and unchanged between two captures), so the
time to a ready page is measured too. WebGL is rendered in software (SwiftShader).
"""

from __future__ import annotations

import base64
import io
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
from typing import Callable

import numpy as np

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    """Path of a Chromium / Chrome executable on PATH, or None."""
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


def png_pixels(png: bytes) -> np.ndarray:
    """A PNG's pixels as (H, W, 3) uint8."""
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def has_colour(pixels: np.ndarray, rgb, tolerance: int = 60, min_pixels: int = 30) -> bool:
    """True if at least ``min_pixels`` pixels lie within ``tolerance`` (sum of |channel differences|) of ``rgb``."""
    near = np.abs(pixels.astype(np.int64) - np.asarray(rgb, dtype=np.int64)).sum(axis=-1) < tolerance
    return int(near.sum()) >= min_pixels


def shows_content(pixels: np.ndarray, max_background: float = 0.9) -> bool:
    """True unless one colour covers more than ``max_background`` of the page (blank or a loading screen)."""
    flat = pixels.reshape(-1, 3).astype(np.int64)
    codes = (flat[:, 0] << 16) | (flat[:, 1] << 8) | flat[:, 2]
    return np.unique(codes, return_counts=True)[1].max() <= max_background * len(codes)


class DevTools:
    """A headless Chromium process and its DevTools pipe."""

    def __init__(self, width: int = 1600, height: int = 1000, executable: str | None = None):
        exe = executable or find_chromium()
        if exe is None:
            raise FileNotFoundError("no chromium on PATH")
        self._profile = tempfile.TemporaryDirectory(prefix="nue-chromium-", ignore_cleanup_errors=True)
        to_child, self._w = os.pipe()
        self._r, from_child = os.pipe()

        def fds() -> None:  # in the child: our pipe ends become fds 3 (commands) and 4 (answers)
            a, b = os.dup(to_child), os.dup(from_child)
            os.dup2(a, 3)
            os.dup2(b, 4)

        self.proc = subprocess.Popen(
            [exe, "--headless", "--no-sandbox", "--remote-debugging-pipe", "--use-angle=swiftshader",
             "--enable-unsafe-swiftshader", "--no-first-run", "--disable-extensions", "--hide-scrollbars",
             "--mute-audio", f"--window-size={width},{height}", f"--user-data-dir={self._profile.name}", "about:blank"],
            preexec_fn=fds, close_fds=False, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL, start_new_session=True)  # its own group: close() ends its helpers too
        os.close(to_child)
        os.close(from_child)
        self._buf, self._id = b"", 0
        targets = self.call("Target.getTargets")["targetInfos"]
        page = next(t for t in targets if t["type"] == "page")
        self.session = self.call("Target.attachToTarget", {"targetId": page["targetId"], "flatten": True})["sessionId"]
        self.call("Emulation.setDeviceMetricsOverride",
                  {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False}, page=True)

    def call(self, method: str, params: dict | None = None, page: bool = False) -> dict:
        """Send one command (to the attached page if ``page``) and return its result."""
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params or {}}
        if page:
            msg["sessionId"] = self.session
        os.write(self._w, json.dumps(msg).encode() + b"\0")
        while True:
            while b"\0" in self._buf:
                line, self._buf = self._buf.split(b"\0", 1)
                answer = json.loads(line)
                if answer.get("id") == self._id:
                    if "error" in answer:
                        raise RuntimeError(f"chromium: {method}: {answer['error'].get('message')}")
                    return answer.get("result", {})
            chunk = os.read(self._r, 1 << 20)
            if not chunk:
                raise RuntimeError("chromium exited")
            self._buf += chunk

    def capture(self) -> bytes:
        """A PNG of the page as it is now."""
        return base64.b64decode(self.call("Page.captureScreenshot", {"format": "png"}, page=True)["data"])

    def close(self) -> None:
        # Kill the whole process group: chromium's renderer / GPU helpers outlive a killed browser process
        # for a moment and keep writing into the profile, which made its removal fail ("Directory not empty").
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.proc.wait()
        os.close(self._w)
        os.close(self._r)
        self._profile.cleanup()


def screenshot_page(url: str, out, ready: Callable[[np.ndarray], bool] | None = None, timeout: float = 120.0,
                    interval: float = 1.0, width: int = 1600, height: int = 1000) -> float:
    """Load ``url`` in headless Chromium and write a PNG to ``out`` once the page shows content, did not change
    over the last two captures and ``ready(pixels)`` holds (if given). Returns the seconds from navigation
    to the ready page; TimeoutError (the last capture still written) if it is not ready within ``timeout``."""
    browser = DevTools(width, height)
    try:
        t0 = time.perf_counter()
        browser.call("Page.navigate", {"url": url}, page=True)
        previous, same = None, 0
        while True:
            try:
                png = browser.capture()
            except RuntimeError:  # the page is still committing its first navigation
                if time.perf_counter() - t0 > timeout:
                    raise
                time.sleep(interval)
                continue
            pixels = png_pixels(png)
            same = same + 1 if previous is not None and np.array_equal(pixels, previous) else 0
            ok = shows_content(pixels) and same >= 2 and (ready is None or ready(pixels))
            elapsed = time.perf_counter() - t0
            if ok or elapsed > timeout:
                with open(out, "wb") as f:
                    f.write(png)
                if not ok:
                    raise TimeoutError(f"{url}: page not ready after {timeout:.0f} s (last capture in {out})")
                return elapsed
            previous = pixels
            time.sleep(interval)
    finally:
        browser.close()
