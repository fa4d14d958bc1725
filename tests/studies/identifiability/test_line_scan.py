"""studies/identifiability/line_scan.py: the objective along the line from the truth to a run's best point."""

from __future__ import annotations

import json

import numpy as np
import pytest

PARAMS = {"space": "local", "drives": ["paper_540m"], "holdout": "paper_928m", "data_seed": 2,
          "sim": {"duration_s": 12.0}, "objective": "innovation_nll", "tie_focal": True, "fixed": ["dy", "dz"]}


def test_the_scan_runs_the_records_own_problem_from_its_truth_to_its_best_point(load_script):
    module = load_script("line_scan")
    problem = module.Synthetic(**{**PARAMS, "holdout": None})
    best = problem.truth + np.array([1.0, -2.0, 1.0, 0.2, -0.1, 0.1, 0.01])
    record = {"config": {"problem": {"params": PARAMS}}, "best_x": best.tolist()}
    out = module.scan(record, [0.0, 0.5, 1.0])
    f, _ = problem.evaluate(np.stack([problem.truth, best]))
    np.testing.assert_allclose(out["f"][[0, 2]], f, rtol=0, atol=1e-12)  # t = 0: the truth; t = 1: the best point
    assert out["used"].shape == (3,) and np.all(out["used"] > 0) and np.all(out["rejected"] >= 0)


def test_a_folder_without_finished_records_is_a_clear_error(load_script, tmp_path):
    module = load_script("line_scan")
    record = tmp_path / "synthetic" / "cmaes" / "seed0" / "record.json"
    record.parent.mkdir(parents=True)
    record.write_text(json.dumps({"status": "failed", "seed": 0}))
    with pytest.raises(SystemExit, match="no finished synthetic record"):
        module.records(tmp_path, None)


def test_the_profile_runs_along_one_variable_through_the_best_point(load_script):
    module = load_script("line_scan")
    problem = module.Synthetic(**{**PARAMS, "holdout": None})
    best = problem.truth + np.array([1.0, -2.0, 1.0, 0.2, -0.1, 0.1, 0.01])
    record = {"config": {"problem": {"params": PARAMS}}, "best_x": best.tolist()}
    out = module.profile(record, "dx", [-0.05, 0.0, 0.05])
    i = list(problem.space.names).index("dx")
    X = np.repeat(best[None], 3, axis=0)
    X[:, i] += [-0.05, 0.0, 0.05]
    f, _ = problem.evaluate(X)
    np.testing.assert_allclose(out["f"], f, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out["error"], X[:, i] - problem.truth[i], rtol=0, atol=1e-15)
    with pytest.raises(SystemExit, match="not a free variable"):
        module.profile(record, "dy", [0.0])  # frozen in this space
