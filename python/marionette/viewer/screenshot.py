"""Screenshots of the viewer page with headless Chromium (Debian ``chromium``).

meshcat renders with WebGL; headless Chromium has no GPU here, so it renders through SwiftShader
(``--use-angle=swiftshader --enable-unsafe-swiftshader``). A fresh page receives the server's
current scene tree, so each screenshot shows the scene as it is when it is taken.
"""

from __future__ import annotations

import shutil
import subprocess
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


def screenshot(url: str, out: Path, size: tuple[int, int] = (800, 600), settle_ms: int = 8000,
               timeout_s: float = 120.0) -> np.ndarray:
    """Loads ``url`` headless, waits ``settle_ms`` of page time (meshes load over the websocket),
    writes the PNG ``out`` and returns it as an (H, W, 3) uint8 array."""
    from PIL import Image

    out = Path(out)
    out.unlink(missing_ok=True)
    argv = [chromium(), "--headless=new", "--no-sandbox", "--disable-gpu-sandbox", "--use-angle=swiftshader",
            "--enable-unsafe-swiftshader", "--hide-scrollbars", "--no-first-run", "--disable-extensions",
            f"--window-size={size[0]},{size[1]}", f"--virtual-time-budget={settle_ms}",
            f"--screenshot={out}", url]
    try:
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        raise ScreenshotError(f"chromium took more than {timeout_s} s on {url}") from None
    if not out.is_file():
        raise ScreenshotError(f"chromium wrote no screenshot of {url} (exit {proc.returncode}): "
                              f"{proc.stderr.strip()[-500:]}")
    return np.asarray(Image.open(out).convert("RGB"))
