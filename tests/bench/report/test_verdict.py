"""Verdicts of a paired design: floors, planted differences, twins, hand-made ranks, CD, bad input."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from bench.report.resolution import (
    design_floor,
    family_size,
    instances_needed,
    min_detectable_difference,
    wilcoxon_floor,
)
from bench.report.stats import StatsError
from bench.report.verdict import (
    block_matrix,
    cd_diagram,
    compare_block,
    critical_difference,
    friedman,
    leader_of,
    mean_ranks,
    posthoc,
    verdicts,
)

ROOT = Path(__file__).resolve().parents[3]


def design(shifts: dict[str, float], n: int, rng: np.random.Generator, noise: float = 1.0,
           spread: float = 5.0, problem: str = "p") -> pd.DataFrame:
    """Tidy runs: value = instance effect + optimiser shift + noise, every optimiser on every instance."""
    effects = rng.normal(0.0, spread, n)
    rows = [(problem, o, i, effects[i] + s + rng.normal(0.0, noise)) for i in range(n) for o, s in shifts.items()]
    return pd.DataFrame(rows, columns=["problem", "optimizer", "instance", "value"])


def block_of(shifts, n, rng, noise=1.0):
    return block_matrix(design(shifts, n, rng, noise))


# --- the design's floor ---------------------------------------------------------------------

def test_floor_of_a_small_design_is_above_alpha():
    floor = design_floor(3, 6)
    assert floor.family_size == 5 and floor.p_floor == 1.0 and not floor.reachable
    assert floor.min_instances == 8  # 5 * 2 / 2^8 = 0.039 < 0.05 <= 5 * 2 / 2^7
    assert wilcoxon_floor(8, 5) < 0.05 <= wilcoxon_floor(7, 5)
    assert design_floor(8, 6).reachable
    assert design_floor(5, 6, family="all").family_size == 15 == family_size(6, "all")
    assert not design_floor(5, 2).reachable and design_floor(6, 2).reachable  # 2/32 > 0.05 > 2/64


def test_small_design_never_decides_and_says_so():
    frame = design({f"o{j}": 3.0 * j for j in range(6)}, 3, np.random.default_rng(0), noise=0.01)
    out = verdicts(frame, rope=None)
    assert not out.friedman.loc[0, "reachable"]
    assert (out.comparisons["p_floor"] >= 0.05).all()
    assert set(out.comparisons["verdict"]) == {"undecided"}
    assert np.isinf(out.comparisons["mdd"]).all()


# --- a planted difference is found at the predicted number of instances ---------------------------

def test_planted_difference_found_at_predicted_n():
    rng = np.random.default_rng(11)
    shifts = {"a": 0.0, "b": 1.0}  # differences ~ N(1, sqrt 2): about 17 pairs for power 0.8
    pilot = block_of(shifts, 30, rng)
    n = int(instances_needed(pilot["b"] - pilot["a"], m=1, seed=0))
    assert 8 <= n <= 40
    detected = [posthoc(block_of(shifts, n, rng))["p_adjusted"].iloc[0] < 0.05 for _ in range(50)]
    assert np.mean(detected) >= 0.6
    mdd = min_detectable_difference(pilot["b"] - pilot["a"], m=1)
    assert 0.5 < mdd < 1.0  # about 0.74 at 30 pairs: below the planted 1.0, which 30 pairs detect


def test_undecided_comparison_gets_an_instance_estimate():
    rng = np.random.default_rng(3)
    block = block_of({"a": 0.0, "b": 0.6}, 8, rng)
    row = compare_block(block, rope=None).iloc[0]
    assert row["verdict"] == "undecided"
    assert np.isfinite(row["n_needed"]) and row["n_needed"] > 8


# --- identical optimisers ---------------------------------------------------------------------

def test_identical_optimisers_rarely_declared_different():
    rng = np.random.default_rng(5)
    rejections = [posthoc(block_of({"a": 0.0, "b": 0.0}, 15, rng))["p_adjusted"].iloc[0] < 0.05
                  for _ in range(100)]
    assert np.mean(rejections) <= 0.1


def test_identical_optimisers_practically_equal_with_a_wide_rope():
    block = block_of({"a": 0.0, "b": 0.0}, 30, np.random.default_rng(6), noise=0.1)
    row = compare_block(block, rope=1.0).iloc[0]
    assert row["verdict"] == "practically equal" and row["p_equal"] >= 0.95
    # without a ROPE nothing is practically equal; this draw is one of the 5 % whose Wilcoxon p
    # falls below 0.05 (p = 0.04), a difference of 0.05 that the ROPE of 1.0 calls irrelevant
    narrow = compare_block(block, rope=0.0).iloc[0]
    assert narrow["verdict"] != "practically equal" and narrow["p_equal"] == 0.0


# --- a clear case, ranks and CD ---------------------------------------------------------------

def test_random_search_is_worse_than_a_clearly_better_optimiser():
    frame = design({"random": 2.0, "cma": 0.0, "de": 0.2}, 20, np.random.default_rng(7), noise=0.3)
    out = verdicts(frame, rope=0.1)
    fr = out.friedman.iloc[0]
    assert fr["leader"] == "cma" and fr["p_value"] < 1e-4 and fr["n_instances"] == 20
    rs = out.comparisons.set_index("a").loc["random"]
    assert rs["b"] == "cma" and rs["verdict"] == "worse" and bool(rs["significant"])
    assert rs["p_adjusted"] < 0.05 and rs["p_worse"] > 0.95 and rs["hl_shift"] > 1.5
    assert out.comparisons.equals(verdicts(frame, rope=0.1).comparisons)  # seeded: the same verdicts


def test_mean_ranks_on_a_hand_made_table():
    block = pd.DataFrame({"x": [1.0, 2.0, 3.0, np.nan], "y": [2.0, 2.0, 1.0, 5.0], "z": [3.0, 1.0, 2.0, np.nan]},
                         index=[0, 1, 2, 3])
    # rows: x<y<z; z<x=y; y<z<x; y, then x and z failed (tie last)
    expected = {"x": (1 + 2.5 + 3 + 2.5) / 4, "y": (2 + 2.5 + 1 + 1) / 4, "z": (3 + 1 + 2 + 2.5) / 4}
    assert mean_ranks(block).to_dict() == pytest.approx(expected)
    assert leader_of(block) == "y"
    stat, p = friedman(block)
    assert np.isfinite(stat) and 0 < p <= 1


def test_critical_difference_matches_demsar_table():
    for k, q in ((6, 2.850), (4, 2.569), (10, 3.164)):
        n = 20
        cd = critical_difference(k, n, 0.05)
        assert cd / np.sqrt(k * (k + 1) / (6 * n)) == pytest.approx(q, abs=1e-3)


def test_library_posthocs_and_all_pairs_family():
    frame = design({"a": 0.0, "b": 0.5, "c": 3.0}, 25, np.random.default_rng(8), noise=0.3)
    block = block_matrix(frame)
    for test in ("nemenyi", "conover", "wilcoxon"):
        table = posthoc(block, family="all", test=test)
        assert len(table) == 3 and table["family_size"].eq(3).all()
        assert table.set_index(["a", "b"]).loc[("a", "c"), "p_adjusted"] < 0.05
    assert len(posthoc(block)) == 2


def test_cd_diagram_is_deterministic(tmp_path):
    ranks = pd.Series({"cma": 1.4, "de": 1.8, "nm": 3.0, "rs": 3.8})
    first = cd_diagram(ranks, 1.05, tmp_path / "a.png").read_bytes()
    second = cd_diagram(ranks, 1.05, tmp_path / "b.png").read_bytes()
    assert first == second and b"Software" not in first


def test_cd_diagram_is_the_same_in_every_process(tmp_path):
    # three optimisers under one crossbar: the library iterates a set of them, whose order follows
    # PYTHONHASHSEED; the committed report's rebuild compares bytes across processes
    code = ("import sys, pandas as pd; from bench.report.verdict import cd_diagram; "
            "cd_diagram(pd.Series({'cmaes': 1.3, 'random': 2.3, 'reference': 2.3, 'tpe': 2.4}), 1.9, sys.argv[1])")
    shots = []
    for seed in ("1", "2", "3", "4"):
        path = tmp_path / f"cd{seed}.png"
        subprocess.run([sys.executable, "-c", code, str(path)], check=True, cwd=ROOT,
                       env={**os.environ, "PYTHONHASHSEED": seed, "PYTHONPATH": str(ROOT)})
        shots.append(path.read_bytes())
    assert all(shot == shots[0] for shot in shots)


# --- bad input ---------------------------------------------------------------------------------

def test_bad_input_names_the_key():
    frame = design({"a": 0.0, "b": 1.0}, 6, np.random.default_rng(9))
    with pytest.raises(StatsError, match="instance"):
        verdicts(frame.drop(index=frame.index[(frame["optimizer"] == "b") & (frame["instance"] == 2)]))
    with pytest.raises(StatsError, match="instance"):
        verdicts(pd.concat([frame, frame.iloc[[0]]]))
    with pytest.raises(StatsError, match="seed"):
        verdicts(frame.rename(columns={"instance": "seed"}).drop(index=[0]), key="seed")
    with pytest.raises(StatsError, match="rope"):
        verdicts(frame, rope=-0.1)
    with pytest.raises(StatsError, match="rope"):
        verdicts(frame, rope={"other": 0.1})
    with pytest.raises(StatsError, match="family"):
        verdicts(frame, family="pairs")
    with pytest.raises(StatsError, match="posthoc"):
        verdicts(frame, posthoc_test="tukey")
    with pytest.raises(StatsError, match="instance"):
        verdicts(frame.drop(columns="instance"))
