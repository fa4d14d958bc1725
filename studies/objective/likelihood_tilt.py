"""The innovation likelihood's slope at the truth along one variable, split into its parts.

studies/objective/objective_bias.py finds one significant slope of ``innovation_nll`` at the truth, along
fy. This script measures it on fresh drives of the study's 5 cameras (as objective_bias.py
builds them: data seed s, drives ``(s, 100 + i)``) for the truth +- one step along ``--var``,
and prints the mean slope over the drives (+- SE, t) of:

- ``composite``: the objective (avio/objectives.py: per-feature marginal likelihoods, capped);
- ``joint``: the joint likelihood of the updates over the features they used, per residual,
  ``1/2 (sum_k NIS_k + sum_k log det S_k) / sum_k m_k`` over the scored frames
  (FilterResult.nis, log_det_S, dof), and its two parts ``joint_nis`` and ``joint_ldS``;
- ``used``: the number of residuals the updates used (whether the step changes the gate's
  decisions).

A log det part that is the same on every kind of data and a NIS part that balances it only
with some noise sources say where the tilt comes from (studies/objective/README.md: "The likelihood has one small
deterministic tilt, along fy").

    python studies/objective/likelihood_tilt.py [--noise default|pixel|imu|none] [--drives 16] [--var fy]
        [--step 0.5] [--filter '{"imu_noise_scale": 1.4}'] [--sim '{"gyro_bias_radps": [0, 0, 0]}']
        [--imu-scale 2]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import fields
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "studies" / "objective"))

from objective_bias import DRIVE, FRESH_SEED0, NOISE, mean_se

from avio.filter.batch import set_threads
from avio.objectives import scored_frames
from avio.sequence import ImuNoise
from avio.sim.simulator import SimConfig, simulate
from bench.problems.synthetic import Synthetic

PARTS = ("composite", "joint", "joint_nis", "joint_ldS", "used")
#: besides the slopes, the objective's curvature along the variable (per unit^2)
CURVATURE = "composite_curvature"


def slopes(noise: str, n_drives: int, var: str, step: float, filter_overrides: dict | None,
           seeds=range(5), sim_overrides: dict | None = None, tie_focal: bool = False) -> dict[str, np.ndarray]:
    """Per part, the (len(seeds) * n_drives,) central-difference slopes at the truth along var
    (sim_overrides: SimConfig fields over the noise setting's; tie_focal: fy = fx, so ``fx`` is
    the common focal length), and the objective's curvature (CURVATURE)."""
    out = {k: [] for k in (*PARTS, CURVATURE)}
    for seed in seeds:
        problem = Synthetic(drives=[DRIVE], holdout=None, data_seed=seed, space="local", filter=filter_overrides,
                            tie_focal=tie_focal)
        camera = problem.sequence.truth_calibration
        j = problem.space.names.index(var)
        x = np.stack([problem.truth + d * np.eye(len(problem.truth))[j] for d in (-step, 0.0, step)])
        batch = problem.calibration_space.decode(x)
        config = getattr(SimConfig, DRIVE)(**{**NOISE[noise], **(sim_overrides or {})})
        for i in range(n_drives):
            drive = simulate(config, (seed, FRESH_SEED0 + i), true_calibration=camera)
            res = problem.run_filter(batch, drive)
            scored = scored_frames(drive)
            dof = np.where(scored, res.dof, 0).sum(axis=1)
            nis = np.where(scored, res.nis, 0.0).sum(axis=1) / dof
            lds = np.where(scored, res.log_det_S, 0.0).sum(axis=1) / dof
            vals = {"composite": np.where(scored, res.nll, 0.0).sum(axis=1) / np.where(scored, res.nll_slots, 0).sum(axis=1),
                    "joint": 0.5 * (nis + lds), "joint_nis": 0.5 * nis, "joint_ldS": 0.5 * lds,
                    "used": dof.astype(float)}
            for k, v in vals.items():
                out[k].append((v[2] - v[0]) / (2 * step))
            c = vals["composite"]
            out[CURVATURE].append((c[2] + c[0] - 2 * c[1]) / step**2)
    return {k: np.array(v) for k, v in out.items()}


def scaled_imu_noise(scale: float) -> ImuNoise:
    """The simulator's default ImuNoise with every density times ``scale``."""
    return ImuNoise(**{f.name: scale * getattr(ImuNoise(), f.name) for f in fields(ImuNoise)})


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--noise", choices=list(NOISE), default="default")
    parser.add_argument("--drives", type=int, default=16, help="fresh drives per camera")
    parser.add_argument("--var", default="fy", help="local-space variable (fx, fy, cx, cy, rx, ..., dz)")
    parser.add_argument("--step", type=float, default=0.5, help="central-difference step in the variable's unit")
    parser.add_argument("--filter", type=json.loads, default=None, help="FilterConfig overrides as JSON")
    parser.add_argument("--sim", type=json.loads, default=None,
                        help='SimConfig overrides as JSON, e.g. \'{"gyro_bias_radps": [0, 0, 0]}\'')
    parser.add_argument("--tie-focal", action="store_true", help="fy = fx (the problem's tie_focal); --var fx is then both")
    parser.add_argument("--imu-scale", type=float, default=1.0,
                        help="multiply the simulated IMU noise densities (the filter's process noise follows: it "
                             "takes the drive's ImuNoise)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    args = parser.parse_args(argv)
    set_threads(2)
    start = time.perf_counter()
    sim = dict(args.sim or {})
    if args.imu_scale != 1.0:
        sim["imu_noise"] = scaled_imu_noise(args.imu_scale)
    result = slopes(args.noise, args.drives, args.var, args.step, args.filter, args.seeds, sim or None, args.tie_focal)
    n = len(result["joint"])
    print(f"{args.noise}, sim {args.sim or 'default'}, IMU noise x{args.imu_scale:g}, filter {args.filter or 'default'}: slope along {args.var} at the truth per unit, "
          f"mean over {n} drives +- SE (t) ({time.perf_counter() - start:.0f} s)")
    for k in PARTS:
        m, se = mean_se(result[k])
        t = f"{m / se:+6.1f}" if se > 0 else "     -"
        print(f"  {k:>10}: {m:+.3e} +- {se:.2e} ({t})")
    slope, slope_se = mean_se(result["composite"])
    curv, curv_se = mean_se(result[CURVATURE])
    if curv > 2 * curv_se:  # the implied 1-D minimum of the mean objective, only where it is clearly curved
        print(f"  objective's curvature {curv:+.3e} +- {curv_se:.2e} per unit^2: its mean's 1-D minimum lies "
              f"{-slope / curv:+.3g} +- {slope_se / curv:.2g} from the truth")
    else:
        print(f"  objective's curvature {curv:+.3e} +- {curv_se:.2e} per unit^2: not clearly positive (flat along {args.var})")


if __name__ == "__main__":
    main()
