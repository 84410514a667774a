"""The ablation of the paper's controller, row by row, and its report table."""
from __future__ import annotations

import json

import numpy as np
import pytest

from nanosim.pipeline.ablation import AblationPlant, ablation_rows, markdown_table, run_row
from nanosim.pipeline.config import DesignConfig
from nanosim.pipeline.design import run_design
from nanosim.pipeline.artifacts import ABLATION_JSON
from nanosim.pipeline.predictions import is_paper_design, report_blocks

MODEL = "tests/data/identified_seed0.npz"


@pytest.fixture(scope="module")
def paper_controller(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper_design")
    run_design(MODEL, out, DesignConfig.paper())
    return out / "controller.npz"


def test_noise_rows_move_sigma_and_leave_the_linear_loop(paper_controller):
    """Switching the noise sources off removes most of the open-loop sigma (the slow drift dominates it)
    and leaves the S bandwidth, a property of the linear loop, within 2 %. The row keeps the quantizers,
    which set the closed-loop sigma of the paper's design on their own (the noise budget's rows)."""
    plant = AblationPlant(twin=True)
    rows = {r.name: r for r in ablation_rows()}
    on = run_row(plant, rows["v2"], paper_controller, seed=0)
    off = run_row(plant, rows["no noise"], paper_controller, seed=0)
    assert off["sigma_open_nm"] < 0.5 * on["sigma_open_nm"]
    assert off["bandwidth_S_hz"] == pytest.approx(on["bandwidth_S_hz"], rel=0.02)
    assert np.isfinite(on["contour_mean_nm_1000"]) and on["contour_mean_nm_1000"] > 0


def test_report_shows_the_ablation_table(tmp_path):
    res = {"seed": 3, "mechanics": "twin", "redesign": True,
           "targets": {"settling_ms": 11.0, "sigma_closed_nm": 1.89, "contour_mean_nm_1000": 40.0,
                       "bandwidth_S_hz": 32.0},
           "rows": [{"name": "v2", "change": "every element on", "settling_ms": 150.0, "sigma_closed_nm": 4.2,
                     "sigma_closed_table_nm": 4.1, "contour_mean_nm_1000": 140.0, "bandwidth_S_hz": 27.0}]}
    (tmp_path / ABLATION_JSON).write_text(json.dumps(res))
    blocks = report_blocks(tmp_path)
    tables = [b for b in blocks if b[0] == "table"]
    assert any(t[2][0][0] == "paper" and t[2][1][:2] == ["v2", "every element on"] for t in tables)
    assert "| v2 | every element on | 150.0 |" in markdown_table(res)


def test_paper_design_is_recognized_from_design_json(paper_controller):
    """The validation rows call the closed loop a prediction only for the paper's set-up."""
    des = json.loads((paper_controller.parent / "design.json").read_text())
    assert is_paper_design(des)
    assert not is_paper_design(dict(des, reduced_order=14))
    assert not is_paper_design(dict(des, damping_loop={"zeta_added": 0.1}))
    assert not is_paper_design(dict(des, architecture="lqg"))
