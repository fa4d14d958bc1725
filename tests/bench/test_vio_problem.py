"""The VIO calibration problem on a short simulated drive, and the tables built from its records."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from bench.problems.base import ProblemError
from bench.problems.vio import Synthetic
from bench.run import Budget, run_job
from bench.tables import build_tables
from optimizers.random_search import RandomSearch

SHORT = {"sim": {"duration_s": 14.0, "n_stops": 0}}


@pytest.fixture(scope="module")
def problem():
    return Synthetic(holdout=None, **SHORT)


def test_truth_has_zero_calibration_error_and_beats_a_wrong_calibration(problem):
    wrong = problem.truth.copy()
    wrong[0] += 15.0  # fx 15 px off
    wrong[3] -= 10.0  # cy 10 px off
    f, metrics = problem.evaluate(np.stack([problem.truth, wrong]))
    assert f.shape == (2,) and np.all(np.isfinite(f))
    assert metrics["rotation_error_deg"][0] == pytest.approx(0.0, abs=1e-6)
    assert metrics["focal_error_px"][0] == pytest.approx(0.0, abs=1e-9)
    assert metrics["focal_error_px"][1] == pytest.approx(15.0)
    assert f[0] < f[1]
    assert problem.f_truth == pytest.approx(f[0], rel=1e-3)  # f_truth uses the exact R, not its Euler round trip


def test_a_batch_equals_its_points_evaluated_alone(problem):
    rng = np.random.default_rng(0)
    X = problem.truth + rng.normal(scale=0.01, size=(3, 10)) * (problem.space.upper - problem.space.lower)
    X = np.clip(X, problem.space.lower, problem.space.upper)
    f, _ = problem.evaluate(X)
    alone = np.array([problem.evaluate(X[i:i + 1])[0][0] for i in range(3)])
    np.testing.assert_allclose(f, alone, rtol=0, atol=1e-9)


@pytest.mark.parametrize("params, message", [
    ({"sim": {"warp": 1}}, "sim:"),
    ({"space": "polar"}, "unknown space 'polar'"),
    ({"filter": {"gain": 2}}, "unknown setting"),
    ({"drive": "moon"}, "unknown drive 'moon'"),
    ({"bounds": {"fx": [740, 700]}}, "lower bound 740.0 is not below"),
])
def test_preflight_names_the_bad_setting(params, message):
    with pytest.raises(ProblemError if "space" not in params and "bounds" not in params else ValueError,
                       match=message):
        Synthetic.preflight(**params)


@pytest.mark.slow
def test_tables_rebuild_from_records(tmp_path, problem):
    cfg = {"problem": {"name": "synthetic", "params": {"holdout": None, **SHORT}},
           "optimizer": {"name": "random", "params": {"batch_size": 4}}, "budget": {"evals": 8}}
    for seed in range(2):
        make = lambda: RandomSearch(problem.space.lower, problem.space.upper, seed=seed, batch_size=4)  # noqa: E731
        run_job(problem, make, Budget(evals=8), tmp_path / "runs" / f"seed{seed}",
                {"problem": "synthetic", "optimizer": "random", "seed": seed}, config={**cfg, "seed": seed})
    written = build_tables([tmp_path / "runs"], tmp_path / "tables", figures=True, profile_points=3)
    names = {p.name for p in written}
    assert {"table1.csv", "table1_errors.csv", "table2.csv", "table2.tex", "profile.png",
            "trajectories_calibration.png", "convergence_random_evals.png"} <= names
    t1 = pd.read_csv(tmp_path / "tables" / "table1.csv", index_col=0)
    np.testing.assert_allclose(t1.loc["truth"].to_numpy(), problem.truth, rtol=1e-5)  # 6 significant digits
    t2 = pd.read_csv(tmp_path / "tables" / "table2.csv")
    ref = t2[(t2["method"] == "VIO reference") & t2["state"].str.startswith("position")]
    assert ref["rmse"].iloc[0] == pytest.approx(problem.f_reference, rel=1e-5)


@pytest.mark.slow
def test_kitti_raw_problem_runs_on_a_simulated_drive_written_in_the_raw_layout(tmp_path):
    """End to end: images rendered by the simulator, written as a KITTI raw drive, tracked by the
    KLT front end (cached), then the VIO objective of the reference calibration."""
    from avio.kitti_raw import write_kitti_raw
    from avio.simulator import SimConfig, simulate
    from bench.problems.vio import KittiRaw

    sim = simulate(SimConfig.paper_540m(duration_s=6.0, n_stops=0, output="images"), 0, image_dir=tmp_path / "img")
    drive = write_kitti_raw(sim, tmp_path / "raw")
    problem = KittiRaw(path=str(drive), cache_dir=str(tmp_path / "cache"), frontend={"max_features": 30})
    assert problem.sequence.tracks.n_features.min() > 0
    f, metrics = problem.evaluate(problem.space.reference[None])
    assert np.isfinite(f[0]) and f[0] == pytest.approx(problem.f_reference, rel=1e-3)
    assert list(metrics) == ["diverged", "velocity_rmse_mps", "attitude_rmse_deg"]  # truth unknown
    assert any((tmp_path / "cache").iterdir())  # the front end's output was cached


def test_time_offset_is_an_eleventh_variable_with_its_error_reported():
    problem = Synthetic(holdout=None, with_time_offset=True,
                        sim={**SHORT["sim"], "time_offset_s": 0.02})
    assert problem.space.names[-1] == "td" and problem.space.dim == 11
    assert problem.truth[-1] == pytest.approx(0.02)
    wrong = problem.truth.copy()
    wrong[-1] = -0.03
    f, metrics = problem.evaluate(np.stack([problem.truth, wrong]))
    np.testing.assert_allclose(metrics["time_offset_error_ms"], [0.0, 50.0], atol=1e-9)
    assert f[0] < f[1]
