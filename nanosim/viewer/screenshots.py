"""Render the docs screenshots with headless Chromium (Debian's /usr/bin/chromium).

    python -m nanosim.viewer.screenshots [OUTDIR]

Writes viewer_rest.png, viewer_contour_2000x.png, viewer_mode1.png (800x600).
"""
from __future__ import annotations

import socket
import sys
import time
from pathlib import Path

__all__ = ["CHROMIUM", "CHROMIUM_ARGS", "free_port", "wait_until", "main"]

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless=new", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
                 "--use-angle=swiftshader", "--disable-background-networking", "--disable-component-update",
                 "--no-first-run", "--disable-sync"]


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free now (chosen by the OS)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(cond, timeout=30.0, poll=0.01) -> bool:
    """Poll ``cond()`` every ``poll`` s until it is true (True) or ``timeout`` s pass (False)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if cond():
            return True
        time.sleep(poll)
    return False


def main(outdir="docs") -> int:
    from playwright.sync_api import sync_playwright

    from nanosim.viewer.server import ViewerApp

    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    app = ViewerApp(port=free_port()).start()
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
            page = browser.new_page(viewport={"width": 800, "height": 600})
            page.goto(f"http://127.0.0.1:{app.port}/")
            page.wait_for_selector("canvas")
            page.get_by_role("button", name="reset").wait_for()
            # hide viser's "software WebGL" toast (headless Chromium renders with SwiftShader)
            page.add_style_tag(content="[class*='Notifications-root'], [class*='Notification-root'] "
                                       "{display: none !important}")
            # 1. at rest
            app.set_exaggeration(1000.0)
            page.wait_for_timeout(2500)
            page.screenshot(path=str(out / "viewer_rest.png"))
            # 2. mid-contour at 2000x: (0,0)->(20,20) um at 20 um/s, paused at (10,10) on the way out
            app.set_waveform("contour", amplitude_um=20.0, speed_um_s=20.0)
            app.reset()
            app.set_exaggeration(2000.0)
            wait_until(lambda: app._snap["ref_um"][0] >= 10.0 and app._snap["t"] < 1.3)
            app.paused = True
            page.wait_for_timeout(2500)
            page.screenshot(path=str(out / "viewer_contour_2000x.png"))
            # 3. first mode shape
            page.get_by_role("tab", name="Modes").click()
            app.set_exaggeration(10000.0)
            app.mode_amp_um = 0.5
            app._gui_mode.value = app._gui_mode.options[1]
            app.mode_index = 0
            page.wait_for_timeout(1000)
            wait_until(lambda: abs(__import__("math").sin(2 * 3.14159 * 0.5 * time.perf_counter())) > 0.97, 5)
            page.wait_for_timeout(150)
            page.screenshot(path=str(out / "viewer_mode1.png"))
            browser.close()
    finally:
        app.stop()
    print("wrote", *(str(out / n) for n in ("viewer_rest.png", "viewer_contour_2000x.png", "viewer_mode1.png")))
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
