"""Screenshots of the viewer page with headless Chromium (Debian ``chromium``).

meshcat renders with WebGL; headless Chromium has no GPU here, so it renders through SwiftShader
(``--use-angle=swiftshader --enable-unsafe-swiftshader``). A fresh page receives the server's
current scene tree, so each screenshot shows the scene as it is when it is taken.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome")


class ScreenshotError(RuntimeError):
    """Chromium is missing or did not write the screenshot."""


def chromium() -> str:
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            return path
    raise ScreenshotError("no Chromium found (scripts/setup installs Debian's `chromium`)")


def scene_loaded(img: np.ndarray) -> bool:
    """True when the page shows the viewer's FSM panel (unlit grey 240, drawn with the scene):
    the page has applied the scene, not only meshcat's empty default."""
    panel = np.all(np.abs(img[25:].astype(int) - 240) <= 2, axis=-1)
    return int(panel.sum()) > 1500


def screenshot(
    url: str,
    out: Path,
    size: tuple[int, int] = (800, 600),
    settle_ms: int = 10000,
    timeout_s: float = 120.0,
    ready: Callable[[np.ndarray], bool] | None = scene_loaded,
    attempts: int = 3,
) -> np.ndarray:
    """Loads ``url`` headless, waits ``settle_ms`` of page time (meshes load over the websocket),
    writes the PNG ``out`` and returns it as an (H, W, 3) uint8 array. The page's virtual time
    does not wait for the websocket: a heavy scene (a humanoid's meshes) may not be applied yet, so
    the
    page is loaded again (up to ``attempts`` times, settling longer) until ``ready(image)``."""
    img = _screenshot(url, Path(out), size, settle_ms, timeout_s)
    for k in range(1, attempts):
        if ready is None or ready(img):
            break
        img = _screenshot(url, Path(out), size, settle_ms * (k + 1), timeout_s)
    if ready is not None and not ready(img):
        raise ScreenshotError(f"the page {url} showed no scene after {attempts} loads ({out})")
    return img


def _screenshot(
    url: str, out: Path, size: tuple[int, int], settle_ms: int, timeout_s: float
) -> np.ndarray:
    from PIL import Image

    out.unlink(missing_ok=True)
    argv = [
        chromium(),
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu-sandbox",
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        "--hide-scrollbars",
        "--no-first-run",
        "--disable-extensions",
        f"--window-size={size[0]},{size[1]}",
        f"--virtual-time-budget={settle_ms}",
        f"--screenshot={out}",
        url,
    ]
    # A profile of its own: Chromium instances sharing one (other tests, a user's browser) hand
    # the URL to the first instance and exit without a screenshot.
    with tempfile.TemporaryDirectory(prefix="marionette-chromium-") as profile:
        try:
            proc = subprocess.run(
                argv[:1] + [f"--user-data-dir={profile}"] + argv[1:],
                capture_output=True,
                text=True,
                timeout=timeout_s,
            )
        except subprocess.TimeoutExpired:
            raise ScreenshotError(f"chromium took more than {timeout_s} s on {url}") from None
    if not out.is_file():
        raise ScreenshotError(
            f"chromium wrote no screenshot of {url} (exit {proc.returncode}): "
            f"{proc.stderr.strip()[-500:]}"
        )
    return np.asarray(Image.open(out).convert("RGB"))
