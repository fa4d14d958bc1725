"""The report's paired verdicts: the verdict box says what the numbers say, the reference is a
tested row, the page leaderboard fits, old records still build, bad settings exit 2."""

import json

import numpy as np
import pandas as pd
import pytest
from record_factory import write_job

from bench.records import load_records
from bench.report.__main__ import main
from bench.report.build import build_report
from bench.report.leaderboard import runs_table, verdict_box
from bench.report.paired import (
    PAGE_COLUMNS,
    REFERENCE,
    SEED_NOTE,
    SettingsError,
    add_reference_errors,
    check_settings,
    page_leaderboard,
    paired_verdicts,
    reference_errors,
)


def sweep(root, n: int, shifts: dict[str, float], *, reference: float | None = None, errors: dict | None = None,
          ref_errors: dict | None = None, noise: float = 0.05, seed: int = 0):
    """n instances; optimiser o scores base_i + shifts[o] + its own noise on instance i."""
    rng = np.random.default_rng(seed)
    base = rng.uniform(1.0, 2.0, n)
    for i in range(n):
        for k, (name, shift) in enumerate(sorted(shifts.items())):
            f = float(base[i] + shift + noise * rng.standard_normal())
            metrics = {e: [float(v + 0.01 * rng.standard_normal())] for e, v in (errors or {}).get(name, {}).items()}
            write_job(root, "p", name, 100 * i + k, [[f]], instance=i, f_truth=0.9,
                      f_reference=None if reference is None else float(base[i] + reference),
                      metrics_batches=[metrics] if metrics else None, reference_metrics=ref_errors)
    return root


def paired_of(root, **settings):
    records = load_records([root])
    runs = add_reference_errors(runs_table(records), records)
    return paired_verdicts(runs, check_settings(settings)), runs


def test_a_planted_difference_is_reported_worse(tmp_path):
    paired, runs = paired_of(sweep(tmp_path, 12, {"good": 0.0, "bad": 0.5, "also": 0.02}))
    box = " ".join(verdict_box(paired, runs)["p"])
    assert "Significantly worse than the leader" in box
    worse = box.split("Significantly worse than the leader good (Holm-adjusted p): ")[1].split(".")[0]
    assert worse.startswith("bad (p = ") and "also" not in worse
    page = page_leaderboard(paired, runs, "p").set_index("optimizer")
    assert page.loc["bad", "verdict vs leader"] == "worse" and page.loc["good", "verdict vs leader"] == "leader"


@pytest.mark.parametrize("seed", range(4))
def test_two_identical_optimisers_are_never_reported_different(tmp_path, seed):
    root = tmp_path / "s"
    rng = np.random.default_rng(seed)
    for i in range(10):
        f = float(rng.uniform(0, 1))
        for name in ("a", "b"):  # the same values on every instance
            write_job(root, "p", name, i, [[f]], instance=i)
        write_job(root, "p", "c", i, [[f + float(rng.normal(0, 0.1))]], instance=i)
    paired, runs = paired_of(root, family="all")
    comp = paired.by_question["best_f"].comparisons
    same = comp[comp.apply(lambda r: {r["a"], r["b"]} == {"a", "b"}, axis=1)]
    assert same["verdict"].iloc[0] not in ("better", "worse") and same["p_adjusted"].iloc[0] == 1.0
    assert "a vs b" not in " ".join(verdict_box(paired, runs)["p"]).split("Undecided")[0]


def test_a_design_below_the_floor_says_so_in_its_first_lines(tmp_path):
    paired, runs = paired_of(sweep(tmp_path, 5, {o: 0.1 * k for k, o in enumerate("abcdef")}))
    lines = verdict_box(paired, runs)["p"]
    assert lines[0] == ("5 instances cannot reach p < 0.05 with Holm over 5 tests: the smallest reachable p is "
                        "0.312; 8 instances could.")  # 5 * 2 / 2^5
    assert not any("Significantly" in line for line in lines)


def test_the_reference_is_a_row_compared_on_instances(tmp_path):
    root = sweep(tmp_path, 10, {"good": 0.0, "bad": 1.0}, reference=0.5,
                 errors={"good": {"focal_error_px": 6.0}, "bad": {"focal_error_px": 9.0}},
                 ref_errors={"focal_error_px": 1.5})
    paired, runs = paired_of(root)
    vs = paired.vs_reference["best_f"].comparisons.set_index("a")
    assert vs.loc["good", "verdict"] == "better" and vs.loc["bad", "verdict"] == "worse"
    assert vs.loc["good", "p_adjusted"] == pytest.approx(2 * 2 / 2 ** 10)  # Holm over 2, every pair one sign
    cal = paired.vs_reference["focal_error_px"].comparisons.set_index("a")
    assert (cal["verdict"] == "worse").all()  # both optimisers' focal lengths are farther from the truth
    box = " ".join(verdict_box(paired, runs)["p"])
    assert "On the objective, better than the reference calibration: good." in box
    assert "focal_error_px 6 (reference 1.5; good worse than the reference, p = 0.00391)" in box  # 2*2/2^10
    assert "The two rankings disagree" in box  # the reference is last on f, first on the focal error
    page = page_leaderboard(paired, runs, "p")
    assert REFERENCE in set(page["optimizer"]) and len(page.columns) <= 10
    assert list(page.columns) == PAGE_COLUMNS


def test_reference_errors_from_the_space_when_the_record_has_none():
    record = {"space.names": ["fx", "fy", "cx", "cy", "rx", "ry", "rz", "dx", "dy", "dz"],
              "space.reference": [700.0, 700.0, 600.0, 180.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
              "truth_x": [701.5, 699.0, 600.5, 181.0, 0.0, 0.0, 3.0, 0.03, 0.0, 0.04]}
    errs = reference_errors(record)
    assert errs["focal_error_px"] == 1.5 and errs["principal_point_error_px"] == 1.0
    assert errs["rotation_error_deg"] == pytest.approx(3.0) and errs["translation_error_cm"] == pytest.approx(5.0)
    assert reference_errors({**record, "reference_metrics.focal_error_px": 2.0}) == {"focal_error_px": 2.0}
    assert reference_errors({"space.names": ["a"], "truth_x": None}) == {}


def test_instance_settings_do_not_split_a_problem(tmp_path):
    for i in range(3):
        for name in ("a", "b"):
            write_job(tmp_path, "p", name, i, [[1.0 + i]], instance=i, problem_params={"data_seed": 10 + i})
    runs = runs_table(load_records([tmp_path]))
    assert set(runs["problem"]) == {"p"} and runs["instance"].tolist() == [0, 1, 2, 0, 1, 2]


def test_old_records_without_instances_build_paired_on_seeds(tmp_path):
    for seed in range(4):
        for name, shift in (("a", 0.0), ("b", 1.0)):
            write_job(tmp_path, "p", name, seed, [[seed + shift]], f_reference=9.0)
    text = build_report([tmp_path], tmp_path / "out", paper_tables=False, log=None).read_text()
    first = text.split("## Verdict", 1)[1].lstrip().splitlines()
    assert first[2] == f"- {SEED_NOTE[0].upper() + SEED_NOTE[1:]}."
    html = (tmp_path / "out" / "report.html").read_text()
    assert html.index(SEED_NOTE[1:]) < html.index('id="leaderboard"')


def test_the_page_leaderboard_has_at_most_ten_columns(tmp_path):
    root = sweep(tmp_path, 6, {o: 0.1 * k for k, o in enumerate("abcdefgh")}, reference=0.3,
                 errors={o: {"rotation_error_deg": 0.1, "focal_error_px": 2.0} for o in "abcdefgh"})
    build_report([root], tmp_path / "out", paper_tables=False, log=None)
    html = (tmp_path / "out" / "report.html").read_text()
    section = html.split('<section id="leaderboard">')[1].split("</section>")[0]
    header = section.split("<thead>")[1].split("</thead>")[0]
    assert header.count("<th") == len(PAGE_COLUMNS) <= 10
    assert len(pd.read_csv(tmp_path / "out" / "leaderboard.csv").columns) > 10  # the CSV keeps every column


@pytest.mark.parametrize(("args", "key"), [
    (["--test", "ttest"], "verdict.test"), (["--family", "some"], "verdict.family"),
    (["--rope", "-0.1"], "verdict.rope"), (["--rope", "nosuch=0.1"], "verdict.rope.nosuch"),
    (["--key", "camera"], "verdict.key"), (["--key", "instance"], "verdict.key"),
    (["--alpha", "1.5"], "verdict.alpha")])
def test_bad_verdict_settings_exit_2_naming_the_key_before_any_work(tmp_path, capsys, args, key):
    for seed in range(2):
        write_job(tmp_path / "runs", "p", "a", seed, [[1.0]])
    out = tmp_path / "never"
    assert main([str(tmp_path / "runs"), "--out", str(out), "--no-tables", *args]) == 2
    err = capsys.readouterr().err
    assert key in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()


def test_settings_come_from_the_sweep_and_the_options_override(tmp_path):
    root = tmp_path / "runs"
    for i in range(6):
        for name, shift in (("a", 0.0), ("b", 0.3)):
            write_job(root, "p", name, i, [[i + shift]], instance=i)
    (root / "multirun.yaml").write_text(json.dumps({"verdict": {"family": "all", "rope": {"p": 1.0}}}))
    build_report([root], tmp_path / "o1", paper_tables=False, log=None)
    comp = pd.read_csv(tmp_path / "o1" / "verdicts.csv")
    assert (comp["rope"] == 1.0).all() and comp.loc[0, "verdict"] == "practically equal"
    build_report([root], tmp_path / "o2", verdict={"rope": "0"}, paper_tables=False, log=None)
    assert (pd.read_csv(tmp_path / "o2" / "verdicts.csv")["rope"] == 0.0).all()
    with pytest.raises(SettingsError, match="verdict.key"):
        build_report([root], tmp_path / "o3", verdict={"key": "camera"}, paper_tables=False, log=None)


def test_a_problem_without_a_shared_instance_still_reports_and_says_why(tmp_path):
    for seed in range(2):
        write_job(tmp_path, "p", "a", seed, [[1.0 + seed]])
        write_job(tmp_path, "p", "b", seed + 2, [[2.0 + seed]])
    text = build_report([tmp_path], tmp_path / "out", paper_tables=False, log=None).read_text()
    assert "No seed is shared by every row of this problem: no paired verdict" in text
