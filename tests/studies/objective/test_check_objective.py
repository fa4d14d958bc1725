"""studies/objective/check_objective.py: which seeds the reference wins, set against its ray error."""

from __future__ import annotations

import numpy as np


def test_losers_with_the_smallest_ray_errors_are_significant_and_mixed_ones_are_not(load_script):
    split = load_script("check_objective").losers_by_ray_error
    ray = np.linspace(0.25, 0.6, 20)
    low = split(np.arange(20) >= 4, ray)  # the reference wins exactly the 4 smallest ray errors
    assert list(low["lost"]) == [0, 1, 2, 3]
    assert np.allclose(low["lost_ray_deg"], ray[:4])
    assert low["won_median_ray_deg"] == np.median(ray[4:])
    assert low["p"] < 0.01
    mixed = split(~np.isin(np.arange(20), [0, 7, 12, 19]), ray)
    assert mixed["p"] > 0.2


def test_no_test_without_two_groups(load_script):
    split = load_script("check_objective").losers_by_ray_error
    assert split(np.ones(5, bool), np.arange(5.0))["p"] is None
    assert split(np.zeros(5, bool), np.arange(5.0))["p"] is None


def test_the_ranking_counts_the_seeds_the_truth_wins_under_each_objective(load_script, capsys):
    module = load_script("check_objective")
    rmse = [np.array([1.0, 2.0]), np.array([1.0, 0.5]), np.array([1.0, 3.0])]  # (truth, reference) per seed
    nll = [np.array([1.0, 2.0])] * 3
    module._print_ranking([rmse, nll], np.array([0.3, 0.2, 0.5]))
    out = capsys.readouterr().out.splitlines()
    assert "position_rmse: truth better in 2/3 seeds" in out[0] and "lost in seeds 1," in out[1]
    assert "innovation_nll: truth better in 3/3 seeds" in out[2] and len(out) == 3
