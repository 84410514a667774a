"""The pipeline's hysteresis-compensation step (nanosim.pipeline.compensation) on the linear twin: physics of the
inverse-PI feedforward and the charge drive, compensation.json's units, the report's section."""
import json

import numpy as np
import pytest

from nanosim import constants as C
from nanosim.pipeline import artifacts as A


@pytest.fixture(scope="module")
def controller_npz(twin, tmp_path_factory):
    """The paper's mixed-sensitivity design on the reduced linear twin, written as ``controller.npz``."""
    from nanosim.design import design_hinf, discretize_controller, reduce_model

    red = reduce_model(twin.sys_V, order=10)
    kd = discretize_controller(design_hinf(red.G_reduced, G_full=twin.sys_V).K, dt=C.CONTROL_PERIOD_S).Kd
    path = tmp_path_factory.mktemp("ctrl") / A.CONTROLLER_NPZ
    np.savez(path, Akd=kd.A, Bkd=kd.B, Ckd=kd.C, Dkd=kd.D, dt=np.array(C.CONTROL_PERIOD_S))
    return path


@pytest.fixture(scope="module")
def cases(controller_npz):
    from nanosim.pipeline.compensation import compensation_cases

    return {c.key: c for c in compensation_cases(controller_npz, seed=0)}


@pytest.fixture(scope="module")
def run(cases, tmp_path_factory):
    """A run folder with the step's files, written as the pipeline writes them."""
    from nanosim.pipeline.run import write_compensation_results

    out = tmp_path_factory.mktemp("run")
    write_compensation_results(out, [(c, 1.0) for c in cases.values()], seed=0)
    return out


def test_feedforward_leaves_at_most_a_quarter_of_the_open_loop_fig14_loop(cases):
    v, ff = cases["voltage"].hysteresis, cases["voltage_feedforward"].hysteresis
    assert 10.0 < v.open_loop_percent < 20.0                       # the calibrated Fig. 14 loop (~15 %)
    assert ff.open_loop_percent <= 0.25 * v.open_loop_percent      # the fitted operator, inverted
    assert ff.open_loop_input_percent <= 0.25 * v.open_loop_input_percent
    assert ff.open_loop_percent <= 3.0                             # what is left: the operators' creep


def test_charge_drive_leaves_about_its_residual_fraction_of_the_loop(cases):
    """Above the crossover a fraction rho survives; the 2 s loop from rest adds its part below the 0.1 Hz
    crossover (voltage-driven), so the ratio lies in (rho, rho + 0.2); the travel is the voltage drive's."""
    v, q = cases["voltage"].hysteresis, cases["charge"].hysteresis
    rho = C.CHARGE_RESIDUAL_HYSTERESIS
    assert rho < q.open_loop_percent / v.open_loop_percent < rho + 0.2
    assert rho < q.open_loop_input_percent / v.open_loop_input_percent < rho + 0.2
    assert q.open_travel_um[0] == pytest.approx(v.open_travel_um[0], rel=0.03)


def test_feedforward_on_the_charge_drive_removes_most_of_what_the_charge_amplifier_leaves(cases):
    """The operator identified on the charge-driven twin inverts the hysteresis the charge amplifier leaves
    (its residual above the crossover, all of it below): the loop narrows further, the travel stays."""
    q, qf = cases["charge"].hysteresis, cases["charge_feedforward"].hysteresis
    assert qf.open_loop_percent <= 0.5 * q.open_loop_percent
    assert qf.open_loop_percent <= 3.0
    assert qf.open_travel_um[0] == pytest.approx(q.open_travel_um[0], rel=0.1)


def test_closed_loop_errors_with_the_compensations(cases):
    """The fast contour error is mostly rate-dependent hysteresis: the charge drive lowers it; the feedforward
    linearises the actuator behind the controller, so the slow triangle is tracked better."""
    v, ff, q = cases["voltage"], cases["voltage_feedforward"], cases["charge"]
    assert v.contour.speed_um_s == 1000.0
    assert q.contour.mean_error_nm < 0.8 * v.contour.mean_error_nm
    rms = {k: {(t.waveform, t.freq_hz): t.rms_error_nm for t in c.tracking} for k, c in cases.items()}
    assert rms["voltage_feedforward"][("triangle", 5.0)] < 0.95 * rms["voltage"][("triangle", 5.0)]
    for c in (v, ff, q):                                  # every closed-loop record from the stated protocol
        assert np.isfinite(c.contour.max_error_nm) and c.contour.max_error_nm >= c.contour.mean_error_nm


def _numbers(obj, key=None):
    """(key, value) of every number in a JSON document; a list's numbers carry the list's key."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            if k != "units":
                yield from _numbers(v, k)
    elif isinstance(obj, list):
        for v in obj:
            yield from _numbers(v, key)
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool):
        yield key, obj


def test_json_states_the_twin_and_a_unit_for_every_number(run, cases):
    doc = json.loads((run / A.COMPENSATION_JSON).read_text())
    assert "linear twin" in doc["plant"] and "every effect on" in doc["plant"]
    assert doc["seed"] == 0 and doc["loop_protocol"]["hold_s"] > 0
    assert list(doc["cases"]) == ["voltage", "voltage_feedforward", "charge", "charge_feedforward"]
    keys = {k for k, _ in _numbers(doc)}
    assert keys and not keys - set(doc["units"]), keys - set(doc["units"])
    assert doc["cases"]["voltage"]["open_loop_output_ratio"] == 1.0
    assert doc["cases"]["charge"]["open_loop_output_percent"] == cases["charge"].hysteresis.open_loop_percent
    timing = json.loads((run / A.TIMINGS_JSON).read_text())["files"][A.COMPENSATION_JSON]["case_seconds"]
    assert set(timing) == {"voltage", "voltage_feedforward", "charge", "charge_feedforward", "write"}
    assert (run / A.FIG_COMPENSATION).is_file() and A.figure(A.FIG_COMPENSATION).step == "compensation"


def test_report_renders_the_section_with_its_table_and_figure_once(run):
    from nanosim.pipeline.report import write_report

    md, html = write_report(run)
    text, page = md.read_text(), html.read_text()
    assert "## Hysteresis compensation" in text and "<h2>Hysteresis compensation</h2>" in page
    section = text.split("\n## Hysteresis compensation\n")[1].split("\n## ")[0]
    for label in ("| voltage drive |", "| voltage drive + inverse-PI feedforward |", "| charge drive |",
                  "| charge drive + inverse-PI feedforward |"):
        assert label in section
    assert "open-loop output hysteresis (%)" in section and "contour mean at 1000 um/s (nm)" in section
    assert f"]({A.FIG_COMPENSATION})" in section
    assert text.count(f"]({A.FIG_COMPENSATION})") == 1 and page.count(f"src='{A.FIG_COMPENSATION}'") == 1


def test_no_section_without_the_file(tmp_path):
    from nanosim.pipeline.compensation import report_blocks

    assert report_blocks(tmp_path) == []
