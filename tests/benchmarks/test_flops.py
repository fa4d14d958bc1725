"""benchmarks/flops.py: the FLOP constants per phase are what the kernel's code does at its loop
bounds (counted by running the kernel's own functions as Python with counting floats), the
counted run computes the kernel's bits, and the per-evaluation and peak arithmetic."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "avio" / "filter"))
from test_filter import make_circle_sequence

from avio.filter import FilterConfig, run


@pytest.fixture
def flops(load_script):
    return load_script("flops")


@pytest.mark.parametrize("F", [5, pytest.param(9, marks=pytest.mark.slow)])
def test_the_constants_are_the_counts_of_the_kernels_code(flops, F):
    """At feature counts the constants were not fitted at (4, 8, 12), per call of each phase."""
    seq = make_circle_sequence(6, seed=3, pixel_noise_px=0.0, n_feat=30)
    counted = flops.count_run(seq, seq.truth_calibration, FilterConfig(max_update_features=F))
    calls = dict(flops._CALLS)
    assert counted["update frames"] == 4 and counted["frames"] == 6
    model = flops.per_update_frame(F)
    phases = {k: v for k, v in counted.items() if k not in ("update frames", "frames", "other", "workspace bytes",
                                                             "transcendental (log, sin, cos)")}
    assert set(phases) == set(model), "a phase appeared or vanished: update benchmarks/flops.py's constants"
    per_call = {k: n / (calls.get(k) or calls["update, selection"]) for k, n in phases.items()}
    assert per_call == pytest.approx(model, abs=0), \
        f"the kernel's loops changed: its counts per call are now {per_call} (python benchmarks/flops.py)"


def test_the_counted_run_computes_the_kernels_bits(flops):
    seq = make_circle_sequence(6, seed=1, pixel_noise_px=0.5, outlier_fraction=0.1)
    cfg = FilterConfig(max_update_features=6)
    counts, args = flops.twin_run(seq, seq.truth_calibration, cfg)
    want = run(seq, seq.truth_calibration, cfg)
    for name, field in (("p", "p_world_imu_m"), ("R", "R_world_imu"), ("sigma", "sigma"), ("nll", "nll")):
        got = np.asarray(getattr(args["out"], name), dtype=float)  # avio/filter/interface.py: Outputs
        assert np.array_equal(got, getattr(want, field)), name
    assert counts["RANSAC"] > 0 and counts["measurement"] > 0
    # The workspaces are allocated once per run, not per frame (what docs/gpu.md quotes per filter).
    shorter = flops.count_run(make_circle_sequence(4, seed=1, pixel_noise_px=0.5), seq.truth_calibration, cfg)
    assert shorter["workspace bytes"] == counts["workspace bytes"] > 0


def test_per_evaluation_counts_frames_until_divergence_and_update_frames(flops):
    class Result:
        p_world_imu_m = np.zeros((2, 10, 3))
        diverged_at_frame = np.array([-1, 4])
        dof = np.zeros((2, 10), int)

    Result.dof[0, 2:10] = 3
    Result.dof[1, 2:4] = 3
    every = sum(a for a, _, _ in flops.EVERY_FRAME.values())
    pred = flops.EVERY_FRAME["propagation"][0] + flops.EVERY_FRAME["covariance prediction"][0]
    upd = sum(v for k, v in flops.per_update_frame(16).items() if k in flops.UPDATE)
    want = ((10 * every - pred + 8 * upd) + (4 * every - pred + 2 * upd)) / 2
    assert flops.per_evaluation(Result, 16) == pytest.approx(want)


def test_the_rate_line_names_the_peaks(flops, monkeypatch):
    monkeypatch.setattr(flops, "cpu_ghz", lambda: 2.0)
    monkeypatch.setattr(flops, "flop_per_cycle", lambda: (4, 16, "test ISA"))
    line = flops.rate_line(4e6, 1e-3)  # 4 GFLOP/s against 8 and 32
    assert line.startswith("4.00 GFLOP/s per core = 50% of scalar, 12% of SIMD FP64 peak") and "test ISA" in line
