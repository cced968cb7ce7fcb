"""A headless browser on the live view: Debian's Chromium driven by Playwright.

Used by the live-view test and by `benchmarks.loop_timing --view` (a view with a browser
watching it, as a user's would). Chromium renders the Rerun viewer's WebGL through its
software rasteriser (SwiftShader): no GPU or screen needed. The flags keep it off the
network (this machine's closed network refuses its background connections).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

CHROMIUM_PATHS = ("/usr/bin/chromium", "/usr/bin/chromium-browser")
FLAGS = (
    "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--no-first-run", "--disable-quic",
)  # fmt: skip
VIEWPORT = {"width": 1200, "height": 800}


def chromium() -> str | None:
    """The browser to drive (HAPTIC_CHROMIUM, else Debian's), or None if there is none."""
    env = os.environ.get("HAPTIC_CHROMIUM")
    if env:
        return env
    for path in CHROMIUM_PATHS:
        if Path(path).exists():
            return path
    return shutil.which("chromium")


@contextlib.contextmanager
def open_page(url: str, executable: str, viewer: bool = True) -> Iterator[Any]:
    """A page on `url` in a fresh headless Chromium (its own empty profile); with `viewer`,
    once the Rerun viewer's canvas shows."""
    with open_pages([url], executable, viewer) as pages:
        yield pages[0]


@contextlib.contextmanager
def open_pages(urls: list[str], executable: str, viewer: bool = True) -> Iterator[list[Any]]:
    """A page on each of `urls`, in one fresh headless Chromium (open_page's)."""
    from playwright.sync_api import sync_playwright

    # the profile's cache may still be written to as the browser closes
    with tempfile.TemporaryDirectory(ignore_cleanup_errors=True) as profile, sync_playwright() as p:
        browser = p.chromium.launch_persistent_context(
            profile, executable_path=executable, headless=True, args=list(FLAGS),
            viewport=VIEWPORT,
        )  # fmt: skip
        try:
            pages = []
            for url in urls:
                pages.append(browser.new_page())
                pages[-1].goto(url)
            if viewer:  # its canvas shown (a hidden one precedes it while it loads)
                for page in pages:
                    page.locator("canvas").filter(visible=True).first.wait_for(timeout=60_000)
            yield pages
        finally:
            browser.close()


def free_ports(n: int) -> list[int]:
    """`n` ports free on loopback now (for a view's web and data ports)."""
    import socket

    socks = [socket.socket() for _ in range(n)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def pixels(png: bytes) -> np.ndarray:
    """A screenshot as an (h, w, 3) uint8 array."""
    import io

    from matplotlib.image import imread

    img = imread(io.BytesIO(png), format="png")
    rgb = img[..., :3]
    return np.asarray(np.round(rgb * 255) if rgb.dtype != np.uint8 else rgb, np.uint8)


def colour_count(img: np.ndarray, rgb: tuple[int, int, int], tol: int = 6) -> int:
    """Pixels within `tol` of `rgb` in every channel."""
    diff = np.abs(img.astype(np.int16) - np.array(rgb, np.int16))
    return int(np.count_nonzero(diff.max(axis=-1) <= tol))
