"""studies/identifiability/identifiability.py: the study's summary, one row per configuration folder; two configurations
compared seed by seed."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest


def _runs(module, config: str, best_f, f_truth, holdout, holdout_truth, evals=400) -> pd.DataFrame:
    n = len(best_f)
    rows = {"config": config, "objective": "innovation_nll", "drives": 4, "noise_realisations": 1, "free": 7,
            "seed": range(n), "evals": evals, "best_f": best_f, "f_truth": f_truth, "holdout_rmse_m": holdout,
            "holdout_rmse_truth_m": holdout_truth, "holdout_rmse_reference_m": 2.5, "ray_error_deg": 0.3,
            "reference_ray_error_deg": 0.37, "decisions": "own"}
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
    assert rows[3].startswith("| innovation_nll | 4 | 7 | 400 | 2 |") and rows[3].endswith("| 2/2 |  |  |  |")  # no bound


def test_a_configuration_with_more_seeds_follows_the_same_one_with_fewer(load_script):
    module = load_script("identifiability")
    more = _runs(module, "ten", best_f=[1.0] * 4, f_truth=[2.0] * 4, holdout=[1.0] * 4, holdout_truth=[1.0] * 4,
                 evals=1600)
    fewer = _runs(module, "five", best_f=[1.0] * 2, f_truth=[2.0] * 2, holdout=[1.0] * 2, holdout_truth=[1.0] * 2,
                  evals=1600)
    summary = module.summarise(pd.concat([more, fewer], ignore_index=True))
    assert list(summary.seeds) == [2, 4] and summary.iloc[1].best_below_truth == "4/4"


def test_each_run_is_held_out_with_its_own_filter_and_simulator_settings(load_script):
    module = load_script("identifiability")
    base = {"space": "local", "drives": ["paper_540m"], "holdout": "paper_928m", "data_seed": 1,
            "sim": {"duration_s": 12.0}, "filter": None, "divergence_penalty_m": 1000.0,
            "tie_focal": False, "bounds": None, "with_time_offset": False}
    other = {**base, "filter": {"max_update_features": 6}}
    problem = module.Synthetic(**{**base, "holdout": None})
    x = problem.truth + 0.5
    runs = pd.DataFrame({"config": ["a", "b"], "data_seed": [1, 1], "params": [base, other], "best_x": [x, x]})
    got = module.held_out(runs)
    for i, params in enumerate((base, other)):  # as a problem built with the run's own settings scores it
        own = module.Synthetic(**{k: v for k, v in params.items() if v is not None})
        batch = module.Calibration.stack([own.calibration_space.decode(x[None]), own.sequence.reference_calibration])
        rmse = module.position_rmse_objective(own.run_filter(batch, own.holdout), own.holdout.truth, 1000.0)
        assert np.isclose(got.loc[i, "holdout_rmse_m"], rmse[0], rtol=0, atol=1e-12)
        assert np.isclose(got.loc[i, "holdout_rmse_reference_m"], rmse[1], rtol=0, atol=1e-12)
    assert got.loc[0, "holdout_rmse_m"] != got.loc[1, "holdout_rmse_m"]  # the filter settings matter


def test_imposed_decisions_are_their_own_row_after_the_filters_own_and_say_so(load_script):
    module = load_script("identifiability")
    imposed = _runs(module, "ref", best_f=[1.0] * 2, f_truth=[2.0] * 2, holdout=[1.0] * 2,
                    holdout_truth=[1.0] * 2).assign(decisions="reference")
    own = _runs(module, "own", best_f=[1.0] * 2, f_truth=[2.0] * 2, holdout=[1.0] * 2, holdout_truth=[1.0] * 2)
    rows = module.markdown(module.summarise(pd.concat([imposed, own], ignore_index=True))).splitlines()
    assert rows[2].startswith("| innovation_nll | 4 |")
    assert rows[3].startswith("| innovation_nll (reference decisions) | 4 |")


def test_compare_pairs_two_configurations_by_seed(load_script):
    module = load_script("identifiability")
    a = _runs(module, "a", best_f=[1.0] * 6, f_truth=[1.0] * 6, holdout=[1.0] * 6, holdout_truth=[1.0] * 6)
    b = _runs(module, "b", best_f=[1.0] * 7, f_truth=[1.0] * 7, holdout=[2.0] * 7, holdout_truth=[1.0] * 7)
    b["rotation_error_deg"] = [0.5, 2.0, 3.0, 4.0, 5.0, 6.0, 0.0]  # a's: 0, 1, ..., 5; seed 6 only in b
    table = module.compare_configs(pd.concat([a, b], ignore_index=True), "a", "b").set_index("quantity")
    rot = table.loc["rotation_error_deg"]
    assert rot.a_lower == "6/6" and rot.median_a == 2.5 and rot.median_b == 3.5
    assert 0.0 < rot.wilcoxon_p < 0.05  # six of six lower: p = 2 / 2^6
    assert table.loc["focal_error_px"].a_lower == "0/6" and table.loc["focal_error_px"].wilcoxon_p == 1.0
    assert table.loc["holdout_rmse_m"].a_lower == "6/6"
    # Holm over the six quantities: the smallest p times 6, and never below the raw p
    assert rot.holm_p == pytest.approx(min(1.0, 6 * table.wilcoxon_p.min()))
    assert (table.holm_p >= table.wilcoxon_p).all() and table.holm_p.max() == 1.0
    with pytest.raises(ValueError, match=r"no runs of \['c'\]"):
        module.compare_configs(a, "a", "c")


def test_compare_without_runs_csv_is_exit_2(load_script, tmp_path, monkeypatch, capsys):
    module = load_script("identifiability")
    monkeypatch.setattr("sys.argv", ["identifiability.py", str(tmp_path), "--compare", "a", "b"])
    with pytest.raises(SystemExit) as e:
        module.main()
    assert e.value.code == 2 and "runs.csv is absent" in capsys.readouterr().err


@pytest.mark.parametrize("identity, params, said", [
    ({"outlier_decisions": "reference_all"}, {"objective": "innovation_nll"}, "reference_all"),  # the record says
    ({}, {"objective": "innovation_nll"}, "own"),  # a record from before the likelihood's default changed
    ({}, {"objective": "innovation_nll", "filter": {"outlier_decisions": "reference"}}, "reference"),
])
def test_a_runs_decisions_are_those_its_record_names_or_its_configuration_set(load_script, identity, params, said):
    study = load_script("identifiability")
    assert study.decisions({"problem_identity": identity, "config": {"problem": {"params": params}}}) == said


def _record(seed: int) -> dict:
    return {"status": "ok", "seed": seed, "n_evals": 400, "best_f": 1.0, "f_truth": 1.5, "best_x": [0.0],
            "best_metrics": {"rotation_error_deg": 0.1 * seed, "focal_error_px": 1.0, "principal_point_error_px": 1.0,
                             "translation_error_cm": 1.0},
            "config": {"problem": {"params": {"objective": "innovation_nll", "drives": ["paper_540m"],
                                              "data_seed": seed, "filter": {"outlier_decisions": "own"}}}}}


def test_a_row_grown_by_added_seeds_reads_its_old_and_new_jobs_as_one_configuration(load_script, tmp_path):
    # make_identifiability --seeds 10 puts jobs i5..i9 beside a configuration's seed0..seed4
    study = load_script("identifiability")
    for name, seed in [*((f"seed{k}", k) for k in range(5)), *((f"i{k}", k) for k in range(5, 10))]:
        job = tmp_path / "cfg" / "synthetic" / "cmaes" / name
        job.mkdir(parents=True)
        (job / "record.json").write_text(json.dumps(_record(seed)))
    runs = study.load(tmp_path)
    assert list(runs.config.unique()) == ["cfg"] and sorted(runs.seed) == list(range(10))
    assert sorted(runs.data_seed) == list(range(10)) and set(runs.decisions) == {"own"}


def test_a_row_to_grow_is_restored_from_its_archive_or_counted_where_an_interrupted_run_left_it(load_script, tmp_path):
    # make_identifiability --seeds: an archive is unpacked; a second call (the run in between was
    # interrupted, the archive already unpacked) counts the same jobs instead of re-running them all
    from bench.archive import ARCHIVE, pack

    study = load_script("identifiability")
    folder = tmp_path / "cfg"
    for k in range(3):
        job = folder / "synthetic" / "cmaes" / f"i{k}"
        job.mkdir(parents=True)
        (job / "record.json").write_text(json.dumps(_record(k)))
    pack(folder, remove=True)
    assert (folder / ARCHIVE).is_file() and not (folder / "synthetic").exists()
    assert study.restored_seeds(folder) == 3 and not (folder / ARCHIVE).exists()
    assert study.restored_seeds(folder) == 3
    assert sorted(study.load(tmp_path).seed) == [0, 1, 2]


@pytest.mark.parametrize("argv, says", [(["--seeds", "x"], "--seeds x: not a positive whole number"),
                                        (["--seeds", "0"], "--seeds 0: not a positive whole number"),
                                        (["--seeds", "10", "400", "nosuch"], "unknown configuration nosuch")])
def test_the_study_script_refuses_bad_input_with_exit_2_before_any_run(argv, says):
    script = Path(__file__).parents[3] / "studies" / "identifiability" / "make_identifiability.sh"
    proc = subprocess.run(["bash", str(script), *argv], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and says in proc.stderr and "Jobs:" not in proc.stdout, proc.stderr


def test_each_rows_efficiency_is_its_bound_over_its_median_error(load_script):
    module = load_script("identifiability")
    runs = _runs(module, "a", best_f=[1.0] * 3, f_truth=[2.0] * 3, holdout=[1.0] * 3, holdout_truth=[1.0] * 3)

    def bound(row):  # the study's own comes from cramer_rao.configuration_bound (tests/.../test_cramer_rao.py)
        return {"information": "opg", "rotation_error_deg": 0.5, "focal_error_px": 0.25,
                "principal_point_error_px": 2.0, "translation_error_cm": None,
                "data": {"rotation_error_deg": 0.1, "focal_error_px": 0.05, "principal_point_error_px": 0.2,
                         "translation_error_cm": None},  # the data's: data_bound.configuration_bound
                "triplets": {"rotation_error_deg": 0.3, "focal_error_px": 0.4, "principal_point_error_px": 0.6,
                             "translation_error_cm": None}}

    summary = module.summarise(runs, bound)
    row = summary.iloc[0]  # the median error of each kind is 1.0
    assert row.efficiency_rotation_error_deg == 0.5 and row.efficiency_focal_error_px == 0.25
    assert row.efficiency_principal_point_error_px == 2.0 and pd.isna(row.efficiency_translation_error_cm)
    assert row.bound_information == "opg"
    assert row.data_efficiency_rotation_error_deg == 0.1 and pd.isna(row.data_efficiency_translation_error_cm)
    assert row.triplets_efficiency_principal_point_error_px == 0.6
    assert module.markdown(summary).splitlines()[2].endswith(
        "| 0.50 / 0.25 / 2.00 / — (OPG) | 0.10 / 0.05 / 0.20 / — | 0.30 / 0.40 / 0.60 / — |")
    # without the tracks' bound its column is blank
    no_data = module.summarise(runs, lambda row: {**bound(row), "data": None})
    assert module.markdown(no_data).splitlines()[2].endswith("| 0.50 / 0.25 / 2.00 / — (OPG) |  | 0.30 / 0.40 / 0.60 / — |")


def test_a_filter_assuming_another_pixel_noise_is_its_own_row_after_the_default_and_says_so(load_script):
    module = load_script("identifiability")
    kw = dict(best_f=[1.0] * 2, f_truth=[2.0] * 2, holdout=[1.0] * 2, holdout_truth=[1.0] * 2)
    runs = pd.concat([_runs(module, "sigma", **kw).assign(filter_sigma_px=1.0),
                      _runs(module, "default", **kw).assign(filter_sigma_px=None)], ignore_index=True)
    rows = module.markdown(module.summarise(runs)).splitlines()
    assert rows[2].startswith("| innovation_nll | 4 |") and rows[3].startswith("| innovation_nll, filter σ 1 px | 4 |")
