"""The viewer's control panel: the GUI folders of :class:`~nanosim.viewer.server.ViewerApp` and its settings.

:class:`ViewerPanel` builds and refreshes the viser GUI (exaggeration, waveform, physics, bench controller,
scan, plots); its callbacks only set plain attributes of the app, which the physics thread reads
(:mod:`nanosim.viewer.server`, which re-exports the settings).
"""
from __future__ import annotations


import numpy as np
import viser
import viser.uplot as uplot

from nanosim.viewer.bench import add_bench_gui
from nanosim.viewer.labels import VIEW_DIR
from nanosim.viewer.waveforms import PRESETS

__all__ = ["ViewerPanel", "LOOPBACK", "AXES", "HIST", "HIST_DECIM", "TRAIL", "CHUNK", "PHYSICS_CHOICES",
           "PHYSICS_LABELS", "AUTO_WINDOW_S", "AUTO_MIN_RTF", "SCAN_PATTERNS", "SCAN_PIXELS"]

LOOPBACK = ("127.0.0.1", "localhost", "::1")
AXES = "XYZ"
HIST = 1500            # plot samples kept (decimated)
HIST_DECIM = 8         # one plot sample per 8 control steps (500 Hz)
TRAIL = 120            # trail points
CHUNK = 20             # control steps per physics chunk (5 ms)
PHYSICS_CHOICES = ("auto", "mujoco", "linear")
PHYSICS_LABELS = ("auto", "MuJoCo (nonlinear)", "linearized MuJoCo (fast)")
AUTO_WINDOW_S = 2.0    # auto: measure MuJoCo's real-time factor over this much running
AUTO_MIN_RTF = 0.95    # ... and keep it if it reaches this
SCAN_PATTERNS = ("raster", "spiral", "lissajous", "rosette")
SCAN_PIXELS = ("32", "64", "128")


class ViewerPanel:
    """The GUI half of :class:`~nanosim.viewer.server.ViewerApp` (a mixin: it uses the app's state)."""

    def _build_gui(self) -> None:
        gui = self.server.gui
        gui.configure_theme(control_width="large")
        with gui.add_folder("Exaggeration"):
            self._gui_logk = gui.add_slider("log10 factor", min=0.0, max=4.0, step=0.01,
                                            initial_value=float(np.log10(self.k)),
                                            hint="Joint-space exaggeration q0 + k (q - q0), 1x..10000x")
            self._gui_ktext = gui.add_text("factor", f"{self.k:,.0f}x", disabled=True)
            presets = gui.add_button_group("preset", ("1x", "100x", "1000x", "10000x"))

            @self._gui_logk.on_update
            def _(_e):
                self.k = float(10 ** self._gui_logk.value)
                self._gui_ktext.value = f"{self.k:,.0f}x"
                self.events.append(f"k={self.k:.0f}")

            @presets.on_click
            def _(_e):
                self.set_exaggeration(float(presets.value.rstrip("x")))
                self.events.append(f"k={self.k:.0f}")

        tabs = gui.add_tab_group()
        with tabs.add_tab("Live"):
            with gui.add_folder("Simulation"):
                has_ctrl = self.sim.controller is not None
                ctrl = gui.add_checkbox("H-inf controller", has_ctrl, disabled=not has_ctrl,
                                        hint=None if has_ctrl else "no --controller given: open loop through inv(G0)")
                real = gui.add_checkbox("noise + nonlinearities", False)
                pause = gui.add_checkbox("pause", False)
                reset = gui.add_button("reset")
                self._gui_rtf = gui.add_text("real-time factor", "-", disabled=True)
                self._gui_time = gui.add_text("sim time", "0.000 s", disabled=True)
                phys = gui.add_dropdown("physics", PHYSICS_LABELS, initial_value=PHYSICS_LABELS[
                    PHYSICS_CHOICES.index(self.physics_choice)],
                    hint="MuJoCo: the nonlinear integrator, 20 substeps per 4 kHz period. Linearized: "
                         "MuJoCo's own linearization about home (12 states, < 2 % from MuJoCo at um "
                         "strokes), same electronics. auto: MuJoCo if it keeps real time, else linearized")
                self._gui_physics = gui.add_text(
                    "running", self._physics_text(), disabled=True,
                    hint=f"auto measures MuJoCo's real-time factor over its first {AUTO_WINDOW_S:g} s and keeps "
                         f"MuJoCo at >= {AUTO_MIN_RTF:g}x; the live value is the real-time factor above")

                @phys.on_update
                def _(_e):
                    choice = PHYSICS_CHOICES[PHYSICS_LABELS.index(phys.value)]
                    self._pending.append(("physics", choice))
                    self.events.append(f"physics={choice}")

                @ctrl.on_update
                def _(_e):
                    self._pending.append(("controller", bool(ctrl.value)))
                    self.events.append(f"controller={ctrl.value}")

                @real.on_update
                def _(_e):
                    self._pending.append(("realistic", bool(real.value)))
                    self.events.append(f"realistic={real.value}")

                @pause.on_update
                def _(_e):
                    self.paused = bool(pause.value)
                    self.events.append(f"paused={self.paused}")

                @reset.on_click
                def _(_e):
                    self.reset()
                    self.events.append("reset")

            if self.bench:
                with gui.add_folder("Controller bench"):
                    add_bench_gui(self, gui, self.bench)

            with gui.add_folder("Reference"):
                sl = [gui.add_slider(f"{a} offset (um)", min=-20.0, max=20.0, step=0.1, initial_value=0.0)
                      for a in AXES]
                preset = gui.add_dropdown("waveform", PRESETS, initial_value="hold")
                axis = gui.add_dropdown("axis", tuple(AXES), initial_value="X")
                amp = gui.add_slider("amplitude (um)", min=0.0, max=20.0, step=0.1, initial_value=2.0)
                freq = gui.add_slider("frequency (Hz)", min=0.1, max=50.0, step=0.1, initial_value=1.0)
                speed = gui.add_slider("contour speed (um/s)", min=1.0, max=200.0, step=1.0, initial_value=20.0)

                def on_offset(_e):
                    self.offset_um = np.array([s.value for s in sl], float)
                    self.events.append("offset")

                for s in sl:
                    s.on_update(on_offset)

                def on_wave(_e):
                    self.set_waveform(preset.value, amplitude_um=amp.value, freq_hz=freq.value,
                                      axis=axis.value, speed_um_s=speed.value)
                    self.events.append(f"wave={preset.value}")

                for h in (preset, axis, amp, freq, speed):
                    h.on_update(on_wave)
                on_wave(None)
                self._gui_preset = preset
                self._gui_amp = amp

            with gui.add_folder("Readouts"):
                self._gui_piezo = gui.add_text("piezo V (A B C)", "-", disabled=True)
                self._gui_probe = gui.add_text("probe um (X Y Z)", "-", disabled=True)
                self._gui_err = gui.add_text("error nm (X Y Z)", "-", disabled=True)

            with gui.add_folder("Plots", expand_by_default=True):
                empty = tuple(np.zeros(2) for _ in range(3))
                self._plots = []
                for a in AXES:
                    self._plots.append(gui.add_uplot(
                        empty, (uplot.Series(label="t (s)"),
                                uplot.Series(label=f"ref {a} (um)", stroke="#888888", width=2),
                                uplot.Series(label=f"meas {a} (um)", stroke="#d62728", width=1.5)),
                        title=f"{a}: reference vs measured (um)", aspect=2.2))
                self._plot_err = gui.add_uplot(
                    tuple(np.zeros(2) for _ in range(4)),
                    (uplot.Series(label="t (s)"),
                     uplot.Series(label="X (nm)", stroke="#1f77b4", width=1.5),
                     uplot.Series(label="Y (nm)", stroke="#2ca02c", width=1.5),
                     uplot.Series(label="Z (nm)", stroke="#ff7f0e", width=1.5)),
                    title="tracking error (nm)", aspect=2.2)

        with tabs.add_tab("Scan"):
            self._build_scan_gui(gui)

        with tabs.add_tab("Modes"):
            labels = ["(live simulation)"] + [
                f"{i + 1}: {m.freq_hz:.1f} Hz  {m.axis}  zeta {100 * m.damping_ratio:.2f}%"
                for i, m in enumerate(self.modes)]
            rows = "\n".join(f"| {i + 1} | {m.freq_hz:.1f} | {100 * m.damping_ratio:.2f} | {m.axis} |"
                             for i, m in enumerate(self.modes))
            gui.add_markdown("| # | f (Hz) | zeta (%) | axis |\n|---|---|---|---|\n" + rows)
            sel = gui.add_dropdown("show", tuple(labels), initial_value=labels[0])
            mamp = gui.add_slider("table amplitude (um)", min=0.01, max=2.0, step=0.01,
                                  initial_value=self.mode_amp_um)
            gui.add_markdown("Animated at 0.5 Hz (slowed); hinges coloured by rotation "
                             "magnitude: blue small, red large.")

            @sel.on_update
            def _(_e):
                self.mode_index = labels.index(sel.value) - 1
                self.events.append(f"mode={self.mode_index}")

            @mamp.on_update
            def _(_e):
                self.mode_amp_um = float(mamp.value)
            self._gui_mode = sel

    def _build_scan_gui(self, gui) -> None:
        pat = gui.add_dropdown("pattern", SCAN_PATTERNS, initial_value="raster")
        px = gui.add_dropdown("pixels", SCAN_PIXELS, initial_value="64")
        size = gui.add_slider("field (um)", min=1.0, max=30.0, step=0.5, initial_value=10.0)
        rate = gui.add_slider("line rate (Hz)", min=1.0, max=50.0, step=0.5, initial_value=10.0,
                              hint="lines per second; every pattern's frame lasts pixels / line rate")
        start = gui.add_button("start scan")
        stop = gui.add_button("stop scan")
        self._gui_scan_status = gui.add_text("scan", "idle", disabled=True)
        gui.add_markdown("The sample (a grating of square pillars and a rough surface) is seen at the table's "
                         "true position and placed at the sensor reading; raster: trace lines. The image also "
                         "stands beside the stage.")
        blank = np.full((64, 64, 3), 40, np.uint8)
        self._gui_scan_image = gui.add_image(blank, label="image", format="png")

        @start.on_click
        def _(_e):
            self.start_scan(pat.value, int(px.value), float(rate.value), float(size.value))

        @stop.on_click
        def _(_e):
            self.stop_scan()

    def _show_scan(self) -> None:
        """Send the forming image (GUI panel and the scene beside the stage) when it has changed."""
        scan = self.scan
        if scan is None:
            return
        if scan.k != self._scan_shown:
            self._scan_shown = scan.k
            rgb = scan.image_rgb()
            up = max(1, 256 // scan.pixels)                 # nearest-neighbour enlargement: crisp pixels
            self._gui_scan_image.image = np.repeat(np.repeat(rgb, up, axis=0), up, axis=1)
            # the scene image faces the first camera (local +z along VIEW_DIR, local x its screen right,
            # -cross(VIEW_DIR, z)), to the stage's screen left (the GUI panel is on the right); a scene
            # image's first row is its bottom edge, so it gets the rows smallest Y first
            if self._scan_image is None:
                extent_mm = float(self.model.stat.extent) * 1e3
                v = VIEW_DIR / np.linalg.norm(VIEW_DIR)
                right = np.cross(v, [0.0, 0.0, 1.0])
                right /= np.linalg.norm(right)
                up_dir = np.cross(right, v)
                centre = np.asarray(self.model.stat.center, float) * 1e3
                wxyz = viser.transforms.SO3.from_matrix(np.column_stack([-right, up_dir, v])).wxyz
                self._scan_image = self.server.scene.add_image(
                    "/scan/image", rgb[::-1], render_width=0.6 * extent_mm, render_height=0.6 * extent_mm,
                    position=tuple(centre + 0.9 * extent_mm * right), wxyz=tuple(wxyz), format="png")
            else:
                self._scan_image.image = rgb[::-1]
        state = "done" if scan.done else f"{100 * scan.progress:.0f} % run"
        self._gui_scan_status.value = f"{scan.pattern.label}: {state}, {100 * scan.filled:.0f} % of pixels"

    def _update_gui(self) -> None:
        with self._lock:
            snap = self._snap
            n = min(self._hist_n, HIST)
            i0 = self._hist_n % HIST
            h = np.roll(self._hist, -i0, axis=0)[HIST - n:] if n else None
        self._gui_rtf.value = f"{self.real_time_factor:.2f}  (scene {self.scene_hz:.0f} Hz)"
        self._gui_physics.value = self._physics_text()
        self._gui_time.value = f"{snap['t']:.3f} s"
        sat = snap["saturated"]
        self._gui_piezo.value = "  ".join(f"{v:6.1f}{'!SAT' if s else ''}" for v, s in zip(snap["piezo_V"], sat))
        self._gui_probe.value = "  ".join(f"{v:7.3f}" for v in snap["meas_um"])
        self._gui_err.value = "  ".join(f"{1e3 * v:7.1f}" for v in snap["ref_um"] - snap["meas_um"])
        if h is not None and n >= 2:
            t = h[:, 0]
            for a, p in enumerate(self._plots):
                p.data = (t, h[:, 1 + a], h[:, 4 + a])
            err = 1e3 * (h[:, 1:4] - h[:, 4:7])
            self._plot_err.data = (t, err[:, 0], err[:, 1], err[:, 2])
        self._show_scan()

    # ---------------------------------------------------------------- threads
