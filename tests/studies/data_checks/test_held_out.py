"""studies/data_checks/held_out.py: paired held-out comparisons against the reference calibration."""

from __future__ import annotations

import numpy as np
import pandas as pd


def _table(values: dict[str, np.ndarray]) -> pd.DataFrame:
    return pd.DataFrame([{"instance": i, "calibration": name, "holdout_rmse_m": float(v)}
                         for name, vs in values.items() for i, v in enumerate(vs)])


def test_a_planted_improvement_is_found_and_a_copy_of_the_reference_is_not(load_script):
    module = load_script("held_out")
    rng = np.random.default_rng(3)
    reference = 2.0 + rng.random(20)
    table = _table({"reference": reference, "truth": reference - 0.5, "better": reference - 0.3 - 0.01 * rng.random(20),
                    "same": reference})
    out = module.against_reference(table).set_index("optimizer")
    assert out.loc["better", "below_reference"] == 20 and out.loc["better", "p_holm"] < 0.01
    assert out.loc["same", "below_reference"] == 0 and out.loc["same", "p_holm"] == 1.0
    assert out.loc["better", "truth_median_m"] == np.median(reference - 0.5)
