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

from nanosim.plant.mjcf import load_model
from nanosim.plant.modes import modal_analysis
from nanosim.viewer import scene as sc
from nanosim.viewer.bench import OPEN_LOOP, apply_bench_choice, bench_setup
from nanosim.viewer.exaggerate import Exaggerator, table_displacement_m
from nanosim.viewer.labels import VIEW_DIR, label_positions
from nanosim.viewer.panel import (  # noqa: F401 (the settings, re-exported)
    AUTO_MIN_RTF,
    AUTO_WINDOW_S,
    AXES,
    CHUNK,
    HIST,
    HIST_DECIM,
    LOOPBACK,
    PHYSICS_CHOICES,
    PHYSICS_LABELS,
    SCAN_PATTERNS,
    SCAN_PIXELS,
    TRAIL,
    ViewerPanel,
)
from nanosim.viewer.scanlive import LiveScan
from nanosim.viewer.sim import LiveSim, load_controller
from nanosim.viewer.waveforms import Waveform

__all__ = ["ViewerApp", "physics_text", "table_displacement_m_cached", "LOOPBACK"]



class ViewerApp(ViewerPanel):
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
