"""The report's every-evaluation table (evaluations.parquet) and its IOHprofiler export (iohprofiler/),
checked against the logs they come from, and rebuilt byte for byte."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from record_factory import write_job

from bench.records import eval_log_frame, read_eval_log, read_record
from bench.report.build import build_report


def make_sweep(root: Path) -> Path:
    for seed in range(2):
        write_job(root, "sphere", "pso", seed, [[3.0 - seed, 2.5, 4.0], [0.5 + seed], [0.75, 0.25 * (seed + 1)]],
                  t_batches=[0.5, 1.25, 2.0 + seed], f_truth=0.0, f_reference=10.0,
                  metrics_batches=[{"distance": [3.0, 2.5, 4.0]}, {"distance": [0.5]}, {"distance": [0.7, 0.2]}])
        write_job(root, "sphere", "cmaes", seed, [[5.0, 1.0 / 3.0], [1e-13 * (seed + 1), 7.0]],
                  f_truth=0.0, f_reference=10.0,
                  metrics_batches=[{"distance": [1.0, 0.1]}, {"distance": [0.0, 2.0]}])
        # a second setting of the problem: its own function in the IOHprofiler export
        write_job(root, "sphere", "pso", seed, [[9.0 - seed], [8.0, 6.5]], name=f"sphere_slow/pso/seed{seed}",
                  problem_params={"delay_s_per_batch": 0.1}, f_truth=0.0, f_reference=10.0)
    write_job(root, "sphere", "random", 0, [], status="failed")  # nothing evaluated: no rows, no run
    return root


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = make_sweep(tmp_path_factory.mktemp("sweep") / "sweep")
    report = build_report([root], paper_tables=False, log=None).parent
    copy = tmp_path_factory.mktemp("elsewhere") / "sweep"
    shutil.copytree(root, copy, ignore=shutil.ignore_patterns("report"))
    again = build_report([copy], tmp_path_factory.mktemp("out2") / "rep", paper_tables=False, log=None).parent
    return root, report, again


def job_dirs(root: Path) -> list[Path]:
    return sorted(p.parent for p in root.rglob("record.json") if "report" not in p.parts)


def test_evaluations_parquet_has_every_evaluation_of_every_job(built):
    root, report, _ = built
    table = pd.read_parquet(report / "evaluations.parquet")
    jobs = job_dirs(root)
    assert len(table) == sum(len(f) for d in jobs for f in (e["f"] for e in read_eval_log(d))) == 26
    assert list(table.columns[:17]) == [
        "problem", "optimizer", "problem_name", "optimizer_name", "seed", "job_key", "config_hash", "job", "status",
        "batch", "batch_size", "index_in_batch", "eval", "f", "t_start_s", "t_end_s", "eval_s"]
    assert {"x.a", "x.b", "m.distance"} <= set(table.columns)
    assert set(table["problem"]) == {"sphere[delay_s_per_batch=0.1]", "sphere[delay_s_per_batch=null]"}
    assert table["config_hash"].isna().all()  # the factory's records have none; real ones do
    for job_dir in jobs:
        record = read_record(job_dir)
        job = f"sweep/{job_dir.relative_to(root).as_posix()}"
        rows = table[table["job"] == job].reset_index(drop=True)
        log = eval_log_frame(job_dir, ["a", "b"])
        assert len(rows) == len(log) == record["n_evals"], job
        if rows.empty:
            continue
        assert set(rows["job_key"]) == {record["job_key"]} and set(rows["seed"]) == {record["seed"]}
        assert set(rows["optimizer_name"]) == {record["optimizer"]} and set(rows["status"]) == {record["status"]}
        for col in ("batch", "eval", "f", "t_end_s", "x.a", "x.b"):
            np.testing.assert_array_equal(rows[col].to_numpy(), log[col].to_numpy(), err_msg=f"{job} {col}")
        if "m.distance" in log:
            np.testing.assert_array_equal(rows["m.distance"].to_numpy(), log["m.distance"].to_numpy())
        entries = read_eval_log(job_dir)
        np.testing.assert_array_equal(rows["batch_size"], np.repeat([e["n"] for e in entries], [e["n"] for e in entries]))
        np.testing.assert_array_equal(rows["t_start_s"], np.repeat([e["t_start_s"] for e in entries], [e["n"] for e in entries]))
        assert rows["f"].min() == record["best_f"]


def read_iohprofiler(folder: Path) -> dict:
    """{(algorithm, function label): [runs]} with each run's json entry and its .dat lines (evaluations, raw_y)."""
    labels = pd.read_csv(folder / "functions.csv").set_index("function_name")["problem"].to_dict()
    out = {}
    for info in sorted(folder.glob("*/IOHprofiler_f*.json")):
        meta = json.loads(info.read_text())
        assert meta["maximization"] is False and meta["attributes"][:2] == ["evaluations", "raw_y"]
        for scenario in meta["scenarios"]:
            text = (info.parent / scenario["path"]).read_text()
            blocks = [b for b in re.split(r"^evaluations raw_y.*\n", text, flags=re.M) if b.strip()]
            assert len(blocks) == len(scenario["runs"])
            for run, block in zip(scenario["runs"], blocks):
                lines = np.array([[float(v) for v in line.split()] for line in block.strip().splitlines()])
                key = (meta["algorithm"]["name"], labels[meta["function_name"]])
                out.setdefault(key, []).append({**run, "lines": lines, "dimension": scenario["dimension"]})
    return out


def test_iohprofiler_export_has_one_run_per_job_with_our_counts_and_best_values(built):
    root, report, _ = built
    data = read_iohprofiler(report / "iohprofiler")
    runs = pd.read_csv(report / "runs.csv")
    logged = runs[runs["n_evals"] > 0]
    assert sorted(data) == sorted(set(zip(logged["optimizer"], logged["problem"])))
    assert len(data) == 3 and sum(len(v) for v in data.values()) == len(logged) == 6
    for (optimizer, problem), ioh_runs in data.items():
        jobs = logged[(logged["optimizer"] == optimizer) & (logged["problem"] == problem)].sort_values("seed")
        assert [r["seed"] for r in ioh_runs] == jobs["seed"].tolist()
        for run, job in zip(ioh_runs, jobs.itertuples()):
            job_dir = root.parent / job.job
            log = eval_log_frame(job_dir)
            record = read_record(job_dir)
            assert run["evals"] == record["n_evals"] == len(run["lines"]) and run["dimension"] == 2
            assert run["best"]["y"] == record["best_f"] and run["best"]["x"] == record["best_x"]
            np.testing.assert_array_equal(run["lines"][:, 0], np.arange(1, record["n_evals"] + 1))
            np.testing.assert_array_equal(run["lines"][:, 1], log["f"])  # each evaluation, full precision
            np.testing.assert_array_equal(np.minimum.accumulate(run["lines"][:, 1]), log["best_f"])
            np.testing.assert_array_equal(run["lines"][:, 2], log["batch"])
            np.testing.assert_array_equal(run["lines"][:, 3], log["t_end_s"])


def test_report_links_the_new_outputs(built):
    _, report, _ = built
    assert "[evaluations.parquet](evaluations.parquet)" in (report / "report.md").read_text()
    assert "[iohprofiler/](iohprofiler/)" in (report / "report.md").read_text()


def test_rebuild_is_byte_identical_and_replaces_the_old_export(built):
    root, report, again = built
    files = sorted(p.relative_to(report) for p in [report / "evaluations.parquet", *(report / "iohprofiler").rglob("*")]
                   if p.is_file())
    assert len(files) > 5
    for rel in files:
        assert (report / rel).read_bytes() == (again / rel).read_bytes(), rel
    assert sorted(p.relative_to(again) for p in [again / "evaluations.parquet", *(again / "iohprofiler").rglob("*")]
                  if p.is_file()) == files
    build_report([root], paper_tables=False, log=None)  # into the same folder again: no "pso-1" beside "pso"
    assert sorted(p.name for p in (report / "iohprofiler").iterdir()) == ["cmaes", "functions.csv", "pso"]
