"""scripts/likelihood_tilt.py: the likelihood's slope at the truth, split into its parts."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]


def test_the_joint_slope_is_its_two_parts_and_on_perfect_data_only_log_det_moves():
    spec = importlib.util.spec_from_file_location("likelihood_tilt", REPO / "scripts" / "likelihood_tilt.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    r = module.slopes("none", 1, "fy", 0.5, None, seeds=[0])
    assert np.allclose(r["joint"], r["joint_nis"] + r["joint_ldS"], rtol=1e-9, atol=1e-15)
    assert r["used"][0] == 0  # the step changes no decision of the update on perfect data
    assert abs(r["joint_nis"][0]) < 1e-2 * abs(r["joint_ldS"][0])  # no residuals to speak of
    assert np.isfinite(r["composite"][0])
