"""Viewer speed with a real browser on the same machine.

Run: python tests/bench/bench_viewer.py [SECONDS]

For each physics backend ("mujoco", "linear") and "auto", starts the viewer with
the closed loop running a 10 Hz sine, opens it in headless Chromium (software
WebGL, on the same cores as the simulation), waits, and prints the simulation's
real-time factor (simulated s per wall s; the physics thread is paced, so 1.00
is the ceiling) and the scene update rate. The bare MuJoCo stepping rate,
measured in the same run without the viewer, is the baseline the MuJoCo
backend cannot beat. Targets: real-time factor >= 1, scene >= 20 Hz.
"""
from __future__ import annotations

import sys
import time

import mujoco
import numpy as np


def bare_mujoco_rtf(seconds: float = 1.0) -> float:
    from nanosim.plant.mechanics import home_data
    from nanosim.plant.mjcf import load_model
    m = load_model()
    d = home_data(m)
    n_sub = int(round(2.5e-4 / m.opt.timestep))
    t0 = time.perf_counter()
    for _ in range(int(seconds * 4000)):
        mujoco.mj_step(m, d, n_sub)
    return seconds / (time.perf_counter() - t0)


def viewer_rtf(physics: str, seconds: float, controller=None) -> dict:
    from playwright.sync_api import sync_playwright

    from nanosim.viewer.screenshots import CHROMIUM, CHROMIUM_ARGS, free_port
    from nanosim.viewer.server import ViewerApp

    app = ViewerApp(port=free_port(), controller_path=controller, physics=physics).start()
    try:
        app.set_waveform("sine", amplitude_um=5.0, freq_hz=10.0)
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
            page = browser.new_page(viewport={"width": 800, "height": 600})
            page.goto(f"http://127.0.0.1:{app.port}/")
            page.wait_for_selector("canvas")
            page.wait_for_timeout(3000)                       # auto decides within 2 s of running
            rtf, hz = [], []
            t_end = time.perf_counter() + seconds
            while time.perf_counter() < t_end:
                page.wait_for_timeout(500)
                rtf.append(app.real_time_factor)
                hz.append(app.scene_hz)
            browser.close()
        return {"physics": physics, "running": app.sim.physics, "note": app.physics_note,
                "real_time_factor": float(np.median(rtf)), "scene_hz": float(np.median(hz))}
    finally:
        app.stop()


def main(seconds: float = 6.0, controller=None) -> int:
    base = bare_mujoco_rtf()
    print(f"baseline: bare MuJoCo stepping, no viewer: {base:.2f}x real time")
    for physics in ("mujoco", "linear", "auto"):
        r = viewer_rtf(physics, seconds, controller)
        print(f"viewer + Chromium, physics={r['physics']:6s} (running {r['running']}): "
              f"real-time factor {r['real_time_factor']:.2f} ({r['real_time_factor'] / base:.2f}x the baseline), "
              f"scene {r['scene_hz']:.1f} Hz {r['note']}")
    return 0


if __name__ == "__main__":
    sys.exit(main(*(float(a) if i == 0 else a for i, a in enumerate(sys.argv[1:]))))
