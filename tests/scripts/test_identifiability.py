"""scripts/identifiability.py: the study's summary, one row per configuration folder."""

from __future__ import annotations

import numpy as np
import pandas as pd

def _runs(module, config: str, best_f, f_truth, holdout, holdout_truth, evals=400) -> pd.DataFrame:
    n = len(best_f)
    rows = {"config": config, "objective": "innovation_nll", "drives": 4, "noise_realisations": 1, "free": 7,
            "seed": range(n), "evals": evals, "best_f": best_f, "f_truth": f_truth, "holdout_rmse_m": holdout,
            "holdout_rmse_truth_m": holdout_truth, "holdout_rmse_reference_m": 2.5, "ray_error_deg": 0.3,
            "reference_ray_error_deg": 0.37}
    for k in module.ERRORS:
        rows[k] = np.arange(n, dtype=float)
        rows[f"reference_{k}"] = 1.0
    return pd.DataFrame(rows)


def test_each_folder_is_a_row_and_says_whether_the_optimiser_reached_the_truths_level(load_script):
    module = load_script("identifiability")
    runs = pd.concat([
        _runs(module, "a", best_f=[1.0, 2.0, 3.0], f_truth=[1.5, 1.5, 3.5], holdout=[1.0, 1.4, 1.1],
              holdout_truth=[1.2, 1.2, 1.2]),
        # the same settings but for the budget: another folder, another row
        _runs(module, "b", best_f=[2.0, 2.0, 2.0], f_truth=[1.0, 1.0, 1.0], holdout=[3.0, 3.0, 3.0],
              holdout_truth=[1.0, 1.0, 1.0], evals=1600),
    ], ignore_index=True)
    summary = module.summarise(runs)
    assert list(summary.evals) == [400, 1600]
    a, b = summary.iloc[0], summary.iloc[1]
    assert a.best_below_truth == "2/3" and b.best_below_truth == "0/3"
    assert a.holdout_better_than_truth == "2/3" and a.rotation_error_deg == 1.0
    assert np.isclose(a.holdout_minus_truth_m, -0.1) and np.isclose(b.holdout_minus_truth_m, 2.0)


def test_the_markdown_table_orders_the_rows_and_names_noise_realisations(load_script):
    module = load_script("identifiability")
    runs = pd.concat([
        _runs(module, "nll", best_f=[1.0, 1.0], f_truth=[2.0, 2.0], holdout=[1.0, 1.0], holdout_truth=[1.0, 1.0]),
        _runs(module, "rmse", best_f=[1.0, 1.0], f_truth=[2.0, 2.0], holdout=[1.0, 1.0], holdout_truth=[1.0, 1.0]).assign(
            objective="position_rmse", drives=1, noise_realisations=4),
    ], ignore_index=True)
    rows = module.markdown(module.summarise(runs)).splitlines()
    assert len(rows) == 4 and rows[0].startswith("| objective |")
    assert rows[2].startswith("| position_rmse | 1 × 4 noise | 7 | 400 | 2 | 0.50 |")  # the paper's objective first
    assert rows[3].startswith("| innovation_nll | 4 | 7 | 400 | 2 |") and rows[3].endswith("| 2/2 |")


def test_a_configuration_with_more_seeds_follows_the_same_one_with_fewer(load_script):
    module = load_script("identifiability")
    more = _runs(module, "ten", best_f=[1.0] * 4, f_truth=[2.0] * 4, holdout=[1.0] * 4, holdout_truth=[1.0] * 4,
                 evals=1600)
    fewer = _runs(module, "five", best_f=[1.0] * 2, f_truth=[2.0] * 2, holdout=[1.0] * 2, holdout_truth=[1.0] * 2,
                  evals=1600)
    summary = module.summarise(pd.concat([more, fewer], ignore_index=True))
    assert list(summary.seeds) == [2, 4] and summary.iloc[1].best_below_truth == "4/4"
