"""viser browser viewer for the nanopositioner.

Threads: viser's own (GUI callbacks: they only set plain attributes), the
physics thread (steps the stage at 4 kHz, paced to real time) and the scene
thread (exaggerated kinematics + batched scene updates inside
``server.atomic()`` at ~30 Hz). The simulator is touched by the physics
thread only.
"""
from __future__ import annotations

import collections
import threading
import time

import numpy as np
import viser
import viser.uplot as uplot

from nanosim.plant.mjcf import load_model
from nanosim.plant.modes import modal_analysis
from nanosim.viewer import scene as sc
from nanosim.viewer.bench import OPEN_LOOP, add_bench_gui, apply_bench_choice, bench_setup
from nanosim.viewer.exaggerate import Exaggerator, table_displacement_m
from nanosim.viewer.labels import VIEW_DIR, label_positions
from nanosim.viewer.scanlive import LiveScan
from nanosim.viewer.sim import LiveSim, load_controller
from nanosim.viewer.waveforms import PRESETS, Waveform

__all__ = ["ViewerApp", "physics_text", "table_displacement_m_cached", "LOOPBACK"]

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


class ViewerApp:
    """Browser viewer of the stage.

    Construct (loads model and controller, may raise FileNotFoundError /
    ValueError with one-line messages), then ``start()``; ``stop()`` shuts
    everything down. ``scene_hz`` and ``real_time_factor`` are measured live.
    """

    def __init__(self, model_path=None, controller_path=None, host: str = "127.0.0.1",
                 port: int = 8080, seed: int = 0, realtime: bool = True, physics: str = "auto", bench=None):
        if physics not in PHYSICS_CHOICES:
            raise ValueError(f"physics: expected one of {PHYSICS_CHOICES}, got {physics!r}")
        self.host, self.port = host, int(port)
        self.model = load_model(model_path)
        controller = load_controller(controller_path) if controller_path else None
        self.bench, controller = bench_setup(bench, controller)
        self.physics_choice = physics
        self.sim = LiveSim(model=self.model, mjcf=model_path, controller=controller, seed=seed,
                           physics="linear" if physics == "linear" else "mujoco")
        self.physics_note = ""
        self.auto_rtf: float | None = None     # MuJoCo's real-time factor over its first AUTO_WINDOW_S (auto)
        self.modal = modal_analysis(self.model)
        self.modes = self.modal.physical
        self.realtime = realtime
        self.exag = Exaggerator(self.model)
        self.geoms = sc.geom_specs(self.model)
        self.hinges = sc.hinge_specs(self.model)
        self.tendons = sc.tendon_specs(self.model)
        self._table_site = self.model.site("table_center").id
        # shared state (written by GUI callbacks, read by threads)
        self.k = 1000.0
        self.paused = False
        self.wave = Waveform("hold")
        self.offset_um = np.zeros(3)
        self.mode_index = -1          # -1: live simulation, else index into self.modes
        self.mode_amp_um = 0.2
        self._wave_t0 = 0.0
        self.scan: LiveScan | None = None       # the scan being run (physics thread), shown by the GUI thread
        self._scan_shown = -1
        self._scan_image = None
        self._pending = collections.deque()
        self._lock = threading.Lock()
        self._snap = self.sim.snapshot()
        self._hist = np.full((HIST, 7), np.nan)     # t, ref xyz, meas xyz
        self._hist_n = 0
        self._trail = collections.deque(maxlen=TRAIL)
        # measurements
        self.scene_hz = 0.0
        self.real_time_factor = 0.0
        self.scene_frames = 0
        self.events: list[str] = []   # GUI changes seen by the server (for tests)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.server = None

    # ---------------------------------------------------------------- control
    def set_exaggeration(self, k: float) -> None:
        self.k = float(np.clip(k, 1.0, 1e4))
        if self.server is not None:
            self._gui_logk.value = float(np.log10(self.k))
            self._gui_ktext.value = f"{self.k:,.0f}x"

    def set_waveform(self, kind: str, amplitude_um: float | None = None, freq_hz: float | None = None,
                     axis: str | None = None, speed_um_s: float | None = None) -> None:
        w = self.wave
        d = {"X": (1.0, 0, 0), "Y": (0, 1.0, 0), "Z": (0, 0, 1.0)}
        self.wave = Waveform(kind, amplitude_um=w.amplitude_um if amplitude_um is None else amplitude_um,
                             freq_hz=w.freq_hz if freq_hz is None else freq_hz,
                             direction=w.direction if axis is None else d[axis],
                             speed_um_s=w.speed_um_s if speed_um_s is None else speed_um_s)
        self._pending.append("wave_t0")

    def reset(self) -> None:
        self._pending.append("reset")

    def start_scan(self, pattern: str = "raster", pixels: int = 64, line_rate_hz: float = 10.0,
                   size_um: float = 10.0) -> None:
        """Run ``pattern`` (centred on home) from the current reference; its image forms in the Scan tab."""
        LiveScan(pattern, size_um, pixels, line_rate_hz)          # errors here, in the caller's thread
        self._pending.append(("scan", (pattern, int(pixels), float(line_rate_hz), float(size_um))))
        self.events.append(f"scan={pattern}")

    def stop_scan(self) -> None:
        """Back to the Live tab's reference (the image stays until the next scan)."""
        self._pending.append(("scan", None))
        self.events.append("scan stopped")

    def select_bench_controller(self, name: str) -> None:
        """Switch to the bench controller ``name`` (or :data:`~nanosim.viewer.bench.OPEN_LOOP`) without a kick."""
        if name not in self.bench and name != OPEN_LOOP:
            raise ValueError(f"name: expected one of {[OPEN_LOOP, *self.bench]}, got {name!r}")
        self._pending.append(("bench", name))
        self.events.append(f"bench={name}")

    # ---------------------------------------------------------------- lifecycle
    def start(self) -> "ViewerApp":
        if self.host not in LOOPBACK:
            print(f"warning: serving on {self.host}:{self.port}, reachable from other machines "
                  f"(no authentication)", flush=True)
        self.server = viser.ViserServer(host=self.host, port=self.port, label="nanosim", verbose=False)
        self.server.scene.set_up_direction("+z")
        self._build_scene()
        self._build_gui()
        self.server.on_client_connect(self._on_connect)
        for target, name in ((self._physics_loop, "nanosim-physics"), (self._scene_loop, "nanosim-scene")):
            t = threading.Thread(target=target, name=name, daemon=True)
            t.start()
            self._threads.append(t)
        return self

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=5.0)
        self._threads.clear()
        if self.server is not None:
            self.server.stop()
            self.server = None

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()

    def _on_connect(self, client) -> None:
        client.camera.up_direction = (0.0, 0.0, 1.0)
        # stage centre shifted right of the look-at point so the GUI panel (right) does not hide it; framed on
        # the model's <statistic> centre and extent (the v2 stage stands 97 mm tall)
        size = float(self.model.stat.extent) / 0.1
        shift = np.array([0.76, 0.65, 0.0]) * 40.0 * size
        look_at = np.array([0.0, 0.0, float(self.model.stat.center[2]) * sc.MM]) + shift
        client.camera.position = tuple(look_at + 0.95 * size * VIEW_DIR)
        client.camera.look_at = tuple(look_at)
        client.camera.near = 1.0
        client.camera.far = 5000.0

    # ---------------------------------------------------------------- scene
    def _build_scene(self) -> None:
        s = self.server.scene
        s.add_grid("/grid", width=200.0, height=200.0, cell_size=10.0, section_size=50.0,
                   position=(0.0, 0.0, -4.1))
        s.add_light_directional("/sun", intensity=1.5, position=(0, 0, 300))
        self._body_frames = {}
        bodies = sorted({g.body for g in self.geoms} | {h.body for h in self.hinges})
        d = self.exag.pose(self.sim.qpos, 1.0)
        for b in bodies:
            self._body_frames[b] = s.add_frame(f"/stage/b{b}", show_axes=False,
                                               position=d.xpos[b] * sc.MM, wxyz=d.xquat[b])
        for g in self.geoms:
            name = f"/stage/b{g.body}/{g.name}"
            kw = dict(color=g.color, position=g.pos_mm, wxyz=g.wxyz)
            if g.kind == "box":
                s.add_box(name, dimensions=tuple(g.dims_mm), **kw)
            elif g.kind == "cylinder":
                s.add_cylinder(name, radius=g.dims_mm[0], height=g.dims_mm[1], **kw)
            elif g.kind == "capsule":
                v, f = sc.capsule_mesh(g.dims_mm[0], g.dims_mm[1])
                s.add_mesh_simple(name, v, f, **kw)
            elif g.kind == "sphere":
                s.add_icosphere(name, radius=g.dims_mm[0], **kw)
            elif g.kind == "ellipsoid":
                s.add_icosphere(name, radius=1.0, scale=tuple(g.dims_mm), **kw)
            else:
                s.add_mesh_simple(name, g.vertices_mm, g.faces, flat_shading=True, **kw)
        self._body_ids = np.array(sorted(self._body_frames), int)
        self._sent_pos = d.xpos[self._body_ids] * sc.MM
        self._sent_quat = d.xquat[self._body_ids].copy()
        self._sent_colors = [sc.HINGE_COLOR] * len(self.hinges)
        self._hinge_handles = [s.add_cylinder(f"/stage/b{h.body}/hinge_{h.name}", radius=h.radius_mm,
                                              height=h.length_mm, color=sc.HINGE_COLOR,
                                              position=h.pos_mm, wxyz=h.wxyz) for h in self.hinges]
        segs = sc.tendon_segments_mm(self.tendons, d.site_xpos)
        self._tendon_handle = s.add_line_segments("/stage/piezos", segs, colors=sc.TENDON_COLOR,
                                                  thickness=5.0, thickness_units="screen")
        self._trail_handle = None
        # labels for a first-time user, placed apart (label_positions)
        anchors = label_positions(self.model, d)
        for t in self.tendons:
            s.add_label(f"/labels/{t.name}", f"piezo {t.name[0].upper()}", position=anchors[t.name])
        for ax in "xyz":
            s.add_label(f"/labels/probe_{ax}", f"probe {ax.upper()}", position=anchors[f"probe_{ax}"])
        self._table_label_offset = anchors["table"] - d.site_xpos[self._table_site] * sc.MM
        self._table_label = s.add_label("/labels/table", "table + target cube", position=anchors["table"])

    def _update_scene(self) -> None:
        with self._lock:
            snap = self._snap
        if self.mode_index >= 0 and self.mode_index < len(self.modes):
            mode = self.modes[self.mode_index]
            scale = self.mode_amp_um * 1e-6 / max(table_displacement_m_cached(self, self.mode_index), 1e-30)
            phase = np.sin(2 * np.pi * 0.5 * time.perf_counter())
            d = self.exag.pose_delta(mode.shape_q * scale * phase, self.k)
            rot = np.abs(mode.shape_q)
        else:
            d = self.exag.pose(snap["qpos"], self.k)
            rot = np.abs(snap["qpos"] - self.exag.q0)
        rmax = float(rot.max()) if rot.size else 0.0
        pos, quat = sc.body_poses_mm(d)
        tpos = d.site_xpos[self._table_site] * sc.MM
        self._trail.append(tpos.copy())
        segs = sc.tendon_segments_mm(self.tendons, d.site_xpos)
        ids = self._body_ids
        moved = (np.abs(pos[ids] - self._sent_pos).max(axis=1) > 1e-4) | \
                (np.abs(quat[ids] - self._sent_quat).max(axis=1) > 1e-7)
        colors = [sc.heat_color(rot[self.model.jnt_dofadr[hs.joint]] / rmax) if rmax > 1e-15 and hs.joint >= 0
                  else sc.HINGE_COLOR for hs in self.hinges]
        with self.server.atomic():
            for i in np.flatnonzero(moved):
                h = self._body_frames[ids[i]]
                h.position = pos[ids[i]]
                h.wxyz = quat[ids[i]]
            self._sent_pos[moved] = pos[ids][moved]
            self._sent_quat[moved] = quat[ids][moved]
            if moved.any():
                self._tendon_handle.points = segs
            for j, (hh, c) in enumerate(zip(self._hinge_handles, colors)):
                if c != self._sent_colors[j]:
                    hh.color = c
                    self._sent_colors[j] = c
            self._table_label.position = tpos + self._table_label_offset
            if len(self._trail) >= 2:
                pts = np.asarray(self._trail, np.float32)
                seg = np.stack([pts[:-1], pts[1:]], axis=1)
                a = np.linspace(0.0, 1.0, len(seg))[:, None]
                col = (255 * (1 - a) + np.array([230, 30, 30]) * a).astype(np.uint8)
                col = np.repeat(col[:, None, :], 2, axis=1)
                if self._trail_handle is None:
                    self._trail_handle = self.server.scene.add_line_segments(
                        "/trail", seg, colors=col, thickness=3.0, thickness_units="screen")
                else:
                    self._trail_handle.points = seg
                    self._trail_handle.colors = col

    # ---------------------------------------------------------------- GUI
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
    def _apply_pending(self) -> None:
        while self._pending:
            item = self._pending.popleft()
            if item == "reset":
                self.sim.reset()
                self._clear_traces()
            elif item == "wave_t0":
                self._wave_t0 = self.sim.time_s
            elif item[0] == "controller":
                self.sim.controller_on = item[1] and self.sim.controller is not None
                self.sim.reset_controller()
            elif item[0] == "realistic":
                self.sim.set_realistic(item[1])
                self._pace_reset = True
            elif item[0] == "scan":
                if item[1] is None:
                    self.scan = None
                else:
                    pattern, px, rate, size = item[1]
                    self.scan = LiveScan(pattern, size, px, rate, start_um=self.sim.ref_um)
                    self._scan_shown = -1
            elif item[0] == "bench":
                apply_bench_choice(self.sim, self.bench, item[1])
            elif item[0] == "physics":
                self.physics_choice = item[1]
                self.physics_note = ""
                self.auto_rtf = None
                self._auto_t0 = None
                self._switch_physics("linear" if item[1] == "linear" else "mujoco")

    def _physics_text(self) -> str:
        return physics_text(self.sim.physics, self.auto_rtf)

    def _clear_traces(self) -> None:
        """After the simulation restarts at t = 0: empty plots and trail, restart pacing."""
        self._hist[:] = np.nan
        self._hist_n = 0
        self._trail.clear()
        self._wave_t0 = 0.0
        self._pace_reset = True

    def _switch_physics(self, physics: str) -> None:
        if physics != self.sim.physics:
            self.sim.set_physics(physics)
            self._clear_traces()
        self._pace_reset = True

    def _auto_physics(self, now: float) -> None:
        """auto: after AUTO_WINDOW_S of unpaused running, keep MuJoCo if it kept real time."""
        if self.physics_choice != "auto" or self.sim.physics != "mujoco" or self.physics_note:
            return
        if self._auto_t0 is None:
            self._auto_t0, self._auto_sim0 = now, self.sim.time_s
            return
        if now - self._auto_t0 < AUTO_WINDOW_S:
            return
        rtf = self.auto_rtf = (self.sim.time_s - self._auto_sim0) / (now - self._auto_t0)
        self.physics_note = f"auto: MuJoCo ran at {rtf:.2f}x real time over {AUTO_WINDOW_S:g} s"
        if rtf < AUTO_MIN_RTF:
            self.events.append(f"physics auto -> linear (MuJoCo {rtf:.2f}x)")
            self._switch_physics("linear")

    def _physics_loop(self) -> None:
        dt = self.sim.dt_s
        self._auto_t0 = None
        self._pace_reset = True
        win_wall, win_sim = time.perf_counter(), self.sim.time_s
        step_count = 0
        while not self._stop.is_set():
            self._apply_pending()
            now = time.perf_counter()
            if self.paused:
                self._pace_reset = True
                self._auto_t0 = None
                win_wall, win_sim = now, self.sim.time_s
                self.real_time_factor = 0.0
                time.sleep(0.02)
                continue
            self._auto_physics(now)
            if self._pace_reset:
                wall0, sim0 = now, self.sim.time_s
                win_wall, win_sim = now, sim0
                self._pace_reset = False
            if self.realtime:
                lag = (now - wall0) - (self.sim.time_s - sim0)
                if lag < 0:
                    time.sleep(min(-lag, 0.005))
                    continue
                if lag > 0.25:        # cannot keep up: run flat out, drop the debt
                    wall0, sim0 = now, self.sim.time_s
            scan = self.scan
            if scan is not None:
                k = scan.k
                refs = scan.ref_um[np.minimum(np.arange(k, k + CHUNK), len(scan.ref_um) - 1)]
                scan_meas, scan_table = np.empty((CHUNK, 3)), np.empty((CHUNK, 3))
            else:
                t = self.sim.time_s + dt * np.arange(1, CHUNK + 1)
                refs = self.wave(t - self._wave_t0) + self.offset_um
            rows = []
            for i, r in enumerate(refs):
                meas = self.sim.step(r)
                if scan is not None:
                    scan_meas[i] = meas
                    scan_table[i] = self.sim.table_from_home_um
                step_count += 1
                if step_count % HIST_DECIM == 0:
                    rows.append((self.sim.time_s, *r, *meas))
            if scan is not None:
                scan.record(scan_meas, scan_table)
            snap = self.sim.snapshot()
            with self._lock:
                for row in rows:
                    self._hist[self._hist_n % HIST] = row
                    self._hist_n += 1
                self._snap = snap
            if now - win_wall >= 0.5:
                self.real_time_factor = (self.sim.time_s - win_sim) / (now - win_wall)
                win_wall, win_sim = now, self.sim.time_s

    def _scene_loop(self) -> None:
        period = 1.0 / 30.0
        frames, t_win = 0, time.perf_counter()
        next_gui = 0.0
        while not self._stop.is_set():
            t0 = time.perf_counter()
            try:
                self._update_scene()
                if t0 >= next_gui:
                    self._update_gui()
                    next_gui = t0 + 0.2
            except Exception as exc:  # noqa: BLE001 - keep the viewer alive, report once per kind
                msg = f"scene update failed: {type(exc).__name__}: {exc}"
                if msg not in self.events:
                    self.events.append(msg)
                    print(msg, flush=True)
            frames += 1
            self.scene_frames += 1
            now = time.perf_counter()
            if now - t_win >= 1.0:
                self.scene_hz = frames / (now - t_win)
                frames, t_win = 0, now
            self._stop.wait(max(0.0, period - (now - t0)))


_TABLE_DISP_CACHE: dict = {}


PHYSICS_TEXT_MAX = 38     # characters the "running" field shows whole (control_width="large")


def physics_text(physics: str, auto_rtf: float | None = None) -> str:
    """The "running" field: the backend and, for ``auto``, the real-time factor it decided on
    (over MuJoCo's first :data:`AUTO_WINDOW_S`; the live factor may differ later). Fits the field.
    """
    if auto_rtf is None:
        return "MuJoCo (nonlinear)" if physics == "mujoco" else "linearized MuJoCo"
    rtf = f"{min(auto_rtf, 9.99):.2f}x"
    if physics == "mujoco":
        return f"MuJoCo (auto: {rtf} in first {AUTO_WINDOW_S:g} s)"
    return f"linearized (auto: MuJoCo {rtf} in {AUTO_WINDOW_S:g} s)"


def table_displacement_m_cached(app: ViewerApp, i: int) -> float:
    key = (id(app), i)
    if key not in _TABLE_DISP_CACHE:
        _TABLE_DISP_CACHE[key] = table_displacement_m(app.model, app.modes[i].shape_q)
    return _TABLE_DISP_CACHE[key]
