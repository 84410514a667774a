"""``nanosim scan``: image a synthetic sample with scan patterns in closed loop; metrics, figures, a report.

Every pattern runs at the chosen line rate on MuJoCo or the linear twin, all
patterns at once on the batch engine (:mod:`nanosim.plant.batch`: one member
per pattern, each the numbers of its own single-stage run). The line-rate
sweep runs every pattern at every rate of the sweep, again one batch per rate
(every pattern's frame lasts ``pixels / line_rate`` s, so a rate's members have
one length), and finds the highest rate at which the image error stays under
the limit (:func:`nanosim.experiments.scan.line_rate_at_limit`).

Files: ``scan.json`` (metrics with units), ``scan.npz`` (truth, images, error
and distortion maps per pattern), ``scan_path.png``, ``scan_image.png``,
``scan_error.png``, ``scan_line_rate.png`` (with a sweep), ``scan.md`` and
``scan.html``. In a run folder with a report, ``nanosim report`` adds its Scan
section (:func:`report_blocks`).
"""
from __future__ import annotations

import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from nanosim import constants as C
from nanosim.experiments import scan as S
from nanosim.fileio import save_figure, write_json, write_npz, write_text
from nanosim.pipeline.blocks import to_html, to_markdown

__all__ = ["ScanConfig", "run_scan_folder", "report_blocks", "SCAN_JSON", "SCAN_NPZ", "SCAN_FIGURES",
           "DEFAULT_SWEEP_HZ"]

SCAN_JSON = "scan.json"
SCAN_NPZ = "scan.npz"
SCAN_MD = "scan.md"
SCAN_HTML = "scan.html"
SCAN_FIGURES = {"path": "scan_path.png", "image": "scan_image.png", "error": "scan_error.png",
                "sweep": "scan_line_rate.png"}
DEFAULT_SWEEP_HZ = (2.0, 5.0, 10.0, 20.0, 50.0, 100.0)
UNITS = {"um": "micrometres", "nm": "nanometres", "hz": "Hz", "s": "seconds",
         "fraction": "of the truth's peak-to-peak height over the covered pixels"}


@dataclass(frozen=True)
class ScanConfig:
    """``nanosim scan`` options (the only home of their defaults).

    patterns : patterns to run (:data:`nanosim.experiments.scan.PATTERNS`).
    size_um, pixels, line_rate_hz : the field (um), pixels per side, the line rate of the scans (Hz).
    slow_axis, spiral_velocity, freqs_hz : pattern options (:func:`nanosim.experiments.scan.scan_pattern`).
    placement : where the image puts each record, ``"reference"`` or ``"sensor"``.
    twin : the linear twin instead of MuJoCo.
    seed : noise of the stages and the sample's rough surface.
    limit_fraction : image error limit, fraction of the height range.
    sweep_hz : line rates of the sweep (Hz); empty: no sweep.
    sweep_mujoco : the sweep on MuJoCo too when the scans are (default: the sweep on the linear twin,
        which the batch engine runs compiled; MuJoCo steps four stages a few hundred periods a second
        on one core, so a sweep of 256-line frames down to 2 Hz would take hours).
    """

    patterns: tuple = S.PATTERNS
    size_um: float = 20.0
    pixels: int = 256
    line_rate_hz: float = 10.0
    slow_axis: str = "staircase"
    spiral_velocity: str = "linear"
    freqs_hz: tuple | None = None
    placement: str = "sensor"
    twin: bool = False
    seed: int = 0
    limit_fraction: float = 0.01
    sweep_hz: tuple = field(default=DEFAULT_SWEEP_HZ)
    sweep_mujoco: bool = False

    def check(self) -> "ScanConfig":
        """Raise ValueError naming the field for any invalid option (before any work)."""
        if not self.patterns:
            raise ValueError("patterns: expected at least one pattern")
        for p in self.patterns:
            S._choice("pattern", p, S.PATTERNS)
        if len(set(self.patterns)) != len(self.patterns):
            raise ValueError(f"patterns: expected each pattern once, got {list(self.patterns)}")
        S._choice("placement", self.placement, S.PLACEMENTS)
        if not (isinstance(self.limit_fraction, float) and 0 < self.limit_fraction < 1):
            raise ValueError(f"limit_fraction: expected a fraction in (0, 1), got {self.limit_fraction!r}")
        for r in self.sweep_hz:
            S._positive("sweep_hz", r)
        for p in self.patterns:                      # every pattern option, at every rate
            freqs = self.freqs_hz if p in ("lissajous", "rosette") else None
            for r in (self.line_rate_hz, *self.sweep_hz):
                _pattern(self, p, r, freqs)
        return self


def _pattern(cfg: ScanConfig, name: str, rate_hz: float, freqs=None) -> S.ScanPattern:
    return S.scan_pattern(name, cfg.size_um, cfg.pixels, rate_hz, slow_axis=cfg.slow_axis,
                          spiral_velocity=cfg.spiral_velocity, freqs_hz=freqs)


def _plant(twin: bool, mjcf):
    """(make_batch(seeds), plant description): the batch stage of B members on MuJoCo or the twin."""
    from nanosim.pipeline.characterize import plant_description
    from nanosim.plant.batch import BatchMujocoStage, BatchTwinStage
    from nanosim.plant.floor import floor_model
    from nanosim.plant.runplant import RunPlant
    from nanosim.plant.stage import Stage

    base = Stage(mjcf=mjcf)
    if twin:
        lin = RunPlant.of_model(base.model).twin
        fm = floor_model(base.model, base.dt_s)
        home = base.table_um.copy()
        return (lambda seeds: BatchTwinStage(lin, seeds, home_um=home, floor_models=fm)), plant_description(True)
    model = base.model
    return (lambda seeds: BatchMujocoStage([model] * len(seeds), seeds, nthread=1)), plant_description(False)


def _run_batch(cfg, make, ctrl, rate_hz):
    from nanosim.experiments.batch_loop import BatchController
    from nanosim.plant.noise import stream_seed

    pats = [_pattern(cfg, p, rate_hz, cfg.freqs_hz if p in ("lissajous", "rosette") else None)
            for p in cfg.patterns]
    seed = stream_seed(cfg.seed, "scan")
    stage = make([seed] * len(pats))
    try:
        bank = BatchController(ctrl.config, n=len(pats))
        return S.run_scan_batch(stage, bank, pats, _sample(cfg), cfg.placement)
    finally:
        close = getattr(stage, "close", None)
        if close is not None:
            close()


def _sample(cfg: ScanConfig) -> S.Sample:
    from nanosim.plant.noise import stream_seed
    return S.Sample(seed=stream_seed(cfg.seed, "scan sample"))


def run_scan_folder(out_dir, controller_npz, cfg: ScanConfig, *, mjcf=None, progress: bool = True) -> dict:
    """Run the scans (and the sweep) and write the scan files into ``out_dir`` (a staging folder).

    Returns the ``scan.json`` document.
    """
    from nanosim.design.controller import DiscreteController

    cfg.check()
    out = Path(out_dir)
    ctrl = DiscreteController.from_npz(controller_npz, expected_dt=C.CONTROL_PERIOD_S)
    bar = None
    steps = 2 + len(cfg.sweep_hz)
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=steps, desc="scan", unit="step", file=sys.stderr)

    def say(text):
        if bar is not None:
            bar.set_postfix_str(text)

    def done():
        if bar is not None:
            bar.update(1)

    try:
        say("building the plant")
        make, plant = _plant(cfg.twin, mjcf)
        sweep_twin = cfg.twin or not cfg.sweep_mujoco
        make_sweep, sweep_plant = (make, plant) if sweep_twin == cfg.twin else _plant(True, mjcf)
        say(f"{', '.join(cfg.patterns)} at {cfg.line_rate_hz:g} Hz")
        results = _run_batch(cfg, make, ctrl, cfg.line_rate_hz)
        other = "reference" if cfg.placement == "sensor" else "sensor"
        alt = {r.pattern.name: S.analyse_scan(r.pattern, r.trace, _sample(cfg), other).metrics() for r in results}
        done()
        sweep = {p: [] for p in cfg.patterns}
        for r in cfg.sweep_hz:
            say(f"sweep: every pattern at {r:g} Hz")
            for res in _run_batch(cfg, make_sweep, ctrl, r):
                sweep[res.pattern.name].append(res.metrics())
            done()
        say("figures and report")
        doc = _document(cfg, plant, results, sweep, controller_npz, alt)
        doc["sweep_plant"] = sweep_plant if cfg.sweep_hz else None
        _write(out, cfg, doc, results, sweep)
        done()
    finally:
        if bar is not None:
            bar.close()
    return doc


def _document(cfg, plant, results, sweep, controller_npz, alt) -> dict:
    per = {}
    for res in results:
        m = res.metrics()
        a = alt[res.pattern.name]
        m["other_placement"] = {k: a[k] for k in ("placement", "image_error_rms_nm", "image_error_fraction",
                                                  "position_error_rms_nm", "position_error_max_nm",
                                                  "trace_retrace_offset_nm")}
        rows = sweep.get(res.pattern.name, [])
        if rows:
            rate, status = S.line_rate_at_limit([r["line_rate_hz"] for r in rows],
                                                [r["image_error_fraction"] for r in rows], cfg.limit_fraction)
            m["line_rate_at_limit_hz"], m["line_rate_at_limit_status"] = rate, status
            m["sweep"] = [{k: r[k] for k in ("line_rate_hz", "image_error_rms_nm", "image_error_fraction",
                                              "position_error_rms_nm", "position_error_max_nm",
                                              "trace_retrace_offset_nm", "saturated_fraction")} for r in rows]
        per[res.pattern.name] = m
    return {"plant": plant, "seed": cfg.seed, "controller": str(controller_npz), "placement": cfg.placement,
            "size_um": cfg.size_um, "pixels": cfg.pixels, "line_rate_hz": cfg.line_rate_hz,
            "limit_fraction": cfg.limit_fraction, "sweep_hz": list(cfg.sweep_hz),
            "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(cfg).items()},
            "patterns": per, "units": dict(UNITS)}


def _write(out: Path, cfg, doc, results, sweep) -> None:
    from nanosim.plots import scan as P

    write_json(out / SCAN_JSON, doc)
    arrays = {"truth_nm": results[0].truth_nm}
    for res in results:
        n = res.pattern.name
        arrays.update({f"{n}_image_nm": res.image.image_nm, f"{n}_error_nm": res.image.error_nm,
                       f"{n}_mask": res.mask, f"{n}_distortion_um": res.distortion_um,
                       f"{n}_position_error_rms_nm": res.position_error_rms_nm,
                       f"{n}_position_error_max_nm": res.position_error_max_nm})
        if res.retrace is not None:
            arrays[f"{n}_retrace_image_nm"] = res.retrace.image_nm
    write_npz(out / SCAN_NPZ, **arrays)
    paths = [(r.pattern.label, *P.scan_path_response(r.trace.ref_um, r.trace.table_um, r.pattern.imaged,
                                                       cfg.size_um))
             for r in results]
    save_figure(P.scan_path_plot(paths, cfg.size_um), out / SCAN_FIGURES["path"])
    imgs = [(r.pattern.label, r.image.image_nm,
             f"error {r.image.rms_error_nm:.2f} nm rms ({100 * r.image.error_fraction:.2f} %)") for r in results]
    save_figure(P.scan_image_plot(imgs, results[0].truth_nm, cfg.size_um), out / SCAN_FIGURES["image"])
    rows = [(r.pattern.label, *P.scan_error_response(r.image.error_nm, r.distortion_um, r.mask)) for r in results]
    save_figure(P.scan_error_plot(rows, cfg.size_um), out / SCAN_FIGURES["error"])
    if cfg.sweep_hz:
        curves = [(doc["patterns"][n]["label"], [r["line_rate_hz"] for r in sweep[n]],
                   [r["image_error_fraction"] for r in sweep[n]], doc["patterns"][n]["line_rate_at_limit_hz"])
                  for n in cfg.patterns]
        save_figure(P.line_rate_plot(curves, cfg.limit_fraction, doc["sweep_plant"]), out / SCAN_FIGURES["sweep"])
    blocks = _blocks(doc, level=1) + [("fig", k, v) for k, v in SCAN_FIGURES.items() if (out / v).is_file()]
    write_text(out / SCAN_MD, to_markdown(blocks, figure_headings=False))
    write_text(out / SCAN_HTML, to_html(blocks, "nanosim scan", figure_headings=False))


def _fmt(v, digits=3) -> str:
    if v is None or (isinstance(v, float) and not np.isfinite(v)):
        return "n/a"
    return f"{v:.{digits}g}"


def _pct(v) -> str:
    return _fmt(None if v is None else 100 * v)


def _limit_text(m: dict) -> str:
    st = m.get("line_rate_at_limit_status")
    if st is None:
        return "not swept"
    if st == "below_all":
        return f"> {_fmt(m['line_rate_at_limit_hz'])} (under the limit at every rate)"
    if st == "above_all":
        return "below the lowest rate swept"
    return _fmt(m["line_rate_at_limit_hz"])


def _blocks(doc: dict, level: int = 2) -> list:
    pats = doc["patterns"]
    lim = 100 * doc["limit_fraction"]
    out = [("h", level, "Scan"),
           ("p", f"{doc['pixels']} x {doc['pixels']} pixels over {_fmt(doc['size_um'])} x {_fmt(doc['size_um'])} "
                 f"um at {_fmt(doc['line_rate_hz'])} Hz (every pattern's frame lasts pixels / line rate), "
                 f"{doc['plant']}, seed {doc['seed']}, controller {Path(doc['controller']).name}. The sample (a "
                 "grating of square pillars and a rough surface) is seen at the table's true position and placed "
                 f"at the {'commanded position' if doc['placement'] == 'reference' else 'sensor reading'}; the "
                 "image error is the rms of image - truth over the pixels the pattern covers and the image reaches "
                 "(imaged: not across a gap of more than three pixels between records), as a fraction of the "
                 f"truth's height range; the line rate at the limit is where it reaches {lim:g} % (sweep "
                 f"{', '.join(_fmt(r) for r in doc['sweep_hz'])} Hz on the {doc.get('sweep_plant') or 'n/a'})."),
           ("table", ["pattern", "image error rms (nm)", "of height range (%)", "position error rms / max (nm)",
                      "distortion max (nm)", "trace/retrace offset (nm)", "coverage (%)", "imaged (%)",
                      f"line rate at {lim:g} % (Hz)"],
            [[m["label"], _fmt(m["image_error_rms_nm"]), _pct(m["image_error_fraction"]),
              f"{_fmt(m['position_error_rms_nm'])} / {_fmt(m['position_error_max_nm'])}",
              _fmt(m["distortion_max_nm"]), _fmt(m["trace_retrace_offset_nm"]), _pct(m["coverage_fraction"]),
              _pct(m.get("imaged_fraction")), _limit_text(m)] for m in pats.values()], None)]
    return out


def report_blocks(run) -> list:
    """The run report's Scan section from ``scan.json`` of ``run`` (empty without it)."""
    import json
    p = Path(run) / SCAN_JSON
    if not p.is_file():
        return []
    return _blocks(json.loads(p.read_text()))
