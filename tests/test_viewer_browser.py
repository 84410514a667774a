"""Browser test: the viewer renders in headless Chromium and reacts to the GUI."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from nanosim.viewer.screenshots import CHROMIUM, CHROMIUM_ARGS, free_port, wait_until

pytestmark = pytest.mark.browser


def _need_chromium():
    if not Path(CHROMIUM).is_file():
        msg = f"{CHROMIUM} not found: install Debian's chromium (apt-get install -y chromium)"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(msg)
        pytest.skip(msg)
    return pytest.importorskip("playwright.sync_api")


def _wait(cond, timeout=15.0):
    return wait_until(cond, timeout, poll=0.05)


def test_viewer_in_chromium(tmp_path):
    pw = _need_chromium()
    from nanosim.viewer.server import ViewerApp
    from PIL import Image

    app = ViewerApp(port=free_port()).start()
    try:
        with pw.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
            try:
                page = browser.new_page(viewport={"width": 800, "height": 600})
                page.goto(f"http://127.0.0.1:{app.port}/", timeout=30000)
                page.wait_for_selector("canvas", timeout=30000)
                assert _wait(lambda: len(app.server.get_clients()) >= 1), "client never connected"
                page.get_by_role("button", name="reset").wait_for(timeout=30000)
                page.wait_for_timeout(1500)       # let the scene arrive and render
                shot = tmp_path / "viewer.png"
                page.screenshot(path=str(shot))
                img = np.asarray(Image.open(shot).convert("L"), float)
                assert img.std() > 10.0, f"screenshot looks blank (pixel std {img.std():.1f})"
                # change the GUI through the page; the server must see it
                page.get_by_role("button", name="reset").click()
                page.get_by_role("button", name="10000x").click()
                assert _wait(lambda: "reset" in app.events), app.events
                assert _wait(lambda: abs(app.k - 1e4) < 1e-6), app.k
            finally:
                browser.close()
        assert app.scene_frames > 10
    finally:
        app.stop()
    assert app.server is None and not app._threads
