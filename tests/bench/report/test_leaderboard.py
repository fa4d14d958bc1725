"""The leaderboard: counts (failed seeds never dropped), ranks, metrics, ERT and the leader test."""

import json

import numpy as np
import pandas as pd
import pytest
from record_factory import write_job

from bench.records import load_records
from bench.report.curves import run_traces
from bench.report.leaderboard import LeaderboardError, leaderboard, runs_table
from bench.report.paired import add_reference_errors, check_settings, paired_verdicts
from bench.report.stats import summary
from bench.report.targets import ert_table, hitting_times, problem_targets


def board_from(root) -> pd.DataFrame:
    records = load_records([root])
    runs = add_reference_errors(runs_table(records), records)
    traces = run_traces(runs)
    targets = problem_targets(runs, traces)
    objective = paired_verdicts(runs, check_settings({})).by_question["best_f"]
    return leaderboard(runs, summary(runs), objective.comparisons, objective.friedman,
                       ert_table(hitting_times(runs, traces, targets), targets))


@pytest.fixture(scope="module")
def board(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    for seed in range(5):
        # "good" reaches f = seed/10 at its second batch, "bad" stays at 10 + seed
        write_job(root, "vio", "good", seed, [[20.0, 15.0], [seed / 10]], f_truth=1.0,
                  metrics_batches=[{"rotation_error_deg": [3.0, 2.0], "diverged": [0, 0]},
                                   {"rotation_error_deg": [0.1 * seed], "diverged": [seed % 2]}])
        write_job(root, "vio", "bad", seed, [[10.0 + seed], [50.0]], f_truth=1.0,
                  metrics_batches=[{"rotation_error_deg": [5.0], "diverged": [1]},
                                   {"rotation_error_deg": [9.0], "diverged": [1]}])
    write_job(root, "vio", "good", 7, [[30.0]], status="failed")
    write_job(root, "vio", "crash", 0, [], status="failed")
    write_job(root, "vio", "crash", 1, [], status="failed")
    return board_from(root).set_index("optimizer")


def test_failed_seeds_are_counted_not_dropped(board):
    assert board.loc["good", "n_runs"] == 6 and board.loc["good", "n_failed"] == 1
    assert board.loc["crash", "n_runs"] == 2 and board.loc["crash", "n_failed"] == 2
    assert board.loc["bad", "n_failed"] == 0


def test_medians_quartiles_and_ranks(board):
    assert board.loc["good", "best_f_median"] == pytest.approx(0.2)
    assert (board.loc["good", "best_f_q25"], board.loc["good", "best_f_q75"]) == pytest.approx((0.1, 0.3))
    assert board.loc["bad", "best_f_median"] == 12.0
    assert board["rank"].to_dict() == {"good": 1.0, "bad": 2.0, "crash": 3.0}
    assert np.isnan(board.loc["crash", "best_f_median"])


def test_calibration_metrics_are_medians_and_divergence_a_rate(board):
    assert board.loc["good", "rotation_error_deg_median"] == pytest.approx(0.2)
    assert board.loc["good", "diverged_rate"] == pytest.approx(2 / 5)
    assert board.loc["bad", "diverged_rate"] == 1.0


def test_ert_of_the_main_target_and_budget_used(board):
    # main target f <= 1.05: "good" hits at evaluation 3 in 5 of its 6 runs (the failed one spent 1)
    assert board.loc["good", "main_target"] == "f_truth+5%"
    assert board.loc["good", "ert_main_evals"] == pytest.approx((5 * 3 + 1) / 5)
    assert board.loc["bad", "ert_main_evals"] == np.inf
    assert board.loc["good", "evals_median"] == 3 and board.loc["crash", "evals_median"] == 0


def test_leader_comparison_is_paired_holm_corrected_and_labelled(tmp_path):
    for instance in range(8):  # "bad" worse than "good" on every one of 8 shared instances
        write_job(tmp_path, "vio", "good", instance, [[instance / 10]], instance=instance)
        write_job(tmp_path, "vio", "bad", instance, [[5.0 + instance / 100]], instance=instance)
    board = board_from(tmp_path).set_index("optimizer")
    assert board.loc["good", "verdict"] == "leader" and np.isnan(board.loc["good", "p_holm_vs_leader"])
    # 8 pairs of one sign: exact two-sided signed-rank p = 2 / 2^8; one test in the family
    assert board.loc["bad", "p_holm_vs_leader"] == pytest.approx(2 / 256)
    assert board.loc["bad", "verdict"] == "worse" and (board["p_holm_family"] == 1).all()


def test_ties_in_median_share_the_rank(tmp_path):
    for seed in range(3):
        write_job(tmp_path, "p", "a", seed, [[1.0 + seed]])
        write_job(tmp_path, "p", "b", seed, [[1.0 + seed]])
    board = board_from(tmp_path).set_index("optimizer")
    assert board["rank"].tolist() == [1.5, 1.5]
    assert board.loc["b", "p_holm_vs_leader"] == 1.0 and board.loc["b", "verdict"] == "undecided"


def test_a_record_missing_a_required_field_is_named(tmp_path):
    job = write_job(tmp_path, "p", "a", 0, [[1.0]])
    record = json.loads((job / "record.json").read_text())
    del record["optimizer"]
    (job / "record.json").write_text(json.dumps(record))
    write_job(tmp_path, "p", "b", 0, [[1.0]])
    with pytest.raises(LeaderboardError, match=r"p/a/seed0/record.json: missing the field 'optimizer'"):
        runs_table(load_records([tmp_path]))


def test_sweeps_with_different_budgets_are_split_not_pooled(tmp_path):
    # defect 4: a 2000- and a 500-evaluation sweep reported together gave one row with seed 0 counted twice
    for seed in range(3):
        write_job(tmp_path / "long", "sphere", "random", seed, [[1.0 + seed], [0.1 * seed]], budget_evals=2000)
        write_job(tmp_path / "short", "sphere", "random", seed, [[5.0 + seed]], budget_evals=500)
    board = board_from(tmp_path).set_index("problem")
    assert sorted(board.index) == ["sphere[budget.evals=2000]", "sphere[budget.evals=500]"]
    assert (board["n_runs"] == 3).all()
    assert board.loc["sphere[budget.evals=500]", "best_f_median"] == 6.0
    runs = runs_table(load_records([tmp_path]))
    assert set(runs["problem_name"]) == {"sphere"} and runs.groupby("problem")["seed"].apply(list).tolist() == \
        [[0, 1, 2], [0, 1, 2]]


def test_data_seeds_and_optimizer_settings_are_split(tmp_path):
    for seed in range(2):
        for data_seed in (0, 1):
            write_job(tmp_path / f"d{data_seed}", "synthetic", "pso", seed, [[1.0 + data_seed]],
                      problem_params={"data_seed": data_seed}, optimizer_params={"pop_size": 20})
        write_job(tmp_path / "small", "synthetic", "pso", seed, [[3.0]], problem_params={"data_seed": 0},
                  optimizer_params={"pop_size": 10})
    board = board_from(tmp_path)
    assert sorted(zip(board["problem"], board["optimizer"])) == [
        ("synthetic[data_seed=0]", "pso[pop_size=10]"), ("synthetic[data_seed=0]", "pso[pop_size=20]"),
        ("synthetic[data_seed=1]", "pso")]


def test_a_seed_recorded_twice_is_refused_naming_both_folders(tmp_path):
    write_job(tmp_path / "a", "sphere", "random", 0, [[1.0]], budget_evals=500)
    write_job(tmp_path / "b", "sphere", "random", 0, [[2.0]], budget_evals=500)
    with pytest.raises(LeaderboardError, match=r"seed 0 of sphere/random is in 2 records .*a/sphere/random/seed0.*"
                                               r"b/sphere/random/seed0.*counted twice"):
        runs_table(load_records([tmp_path]))


def test_columns_carry_unit_ci_level_correction_verdict_and_threshold(tmp_path):
    for seed in range(8):
        write_job(tmp_path, "vio", "good", seed, [[0.1 + 0.01 * seed]], f_truth=0.1, f_unit="m")
        write_job(tmp_path, "vio", "bad", seed, [[9.0 + seed]], f_truth=0.1, f_unit="m")
        write_job(tmp_path, "vio", "same", seed, [[0.1 + 0.01 * seed]], f_truth=0.1, f_unit="m")
    board = board_from(tmp_path).set_index("optimizer")
    assert (board["f_unit"] == "m").all() and (board["ci_level"] == 0.95).all() and (board["alpha"] == 0.05).all()
    assert board.loc["good", "main_target_threshold"] == pytest.approx(0.105)
    assert board[["verdict"]].to_dict()["verdict"] == {"good": "leader", "bad": "worse", "same": "undecided"}
    assert board.loc["bad", "p_holm_vs_leader"] == pytest.approx(2 * 2 / 256)  # Holm over the 2 tests
    assert (board["p_holm_family"] == 2).all()  # each against the leader


def test_the_schema_is_the_same_for_every_problem(tmp_path):
    write_job(tmp_path / "a", "sphere", "random", 0, [[1.0]])
    write_job(tmp_path / "b", "vio", "random", 0, [[1.0]], metrics_batches=[{"rotation_error_deg": [0.3]}],
              f_unit="m")
    alone = {p: list(board_from(tmp_path / p).columns) for p in ("a", "b")}
    both = board_from(tmp_path)
    assert set(alone["a"]) - {"distance_to_optimum_median"} <= set(alone["b"]) <= set(both.columns)
    for col in ("f_unit", "ci_level", "main_target_threshold", "p_holm_vs_leader", "p_holm_family", "verdict"):
        assert col in alone["a"] and col in alone["b"]
