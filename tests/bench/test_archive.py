"""Committed results: a sweep's records in one archive, and the report rebuilt from it byte for byte."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from bench.archive import ARCHIVE, ArchiveError, pack, records_restored

ROOT = Path(__file__).resolve().parents[2]


def _files(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _bench(*args, cwd):
    env_path = f"{ROOT}"  # this checkout, also in a worktree
    proc = subprocess.run([sys.executable, "-m", *args], cwd=cwd, capture_output=True, text=True, timeout=600,
                          env={**__import__("os").environ, "PYTHONPATH": env_path})
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    return proc


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    root = tmp_path_factory.mktemp("archive")
    sweep = root / "small"
    _bench("bench", "problem=sphere", "optimizer=random,cmaes", "instance=range(3)", "budget.evals=24", "progress=false",
           f"hydra.sweep.dir={sweep}", cwd=root)
    return sweep


def test_the_report_is_rebuilt_byte_for_byte_from_the_archive_alone(sweep, tmp_path):
    records = {k: v for k, v in _files(sweep).items() if not k.startswith("report/") and not k.endswith(".lock")}
    assert any(k.endswith("evals.jsonl") for k in records)
    _bench("bench.report", str(sweep), "--pack", cwd=sweep.parent)  # the committed results' step: build, then pack
    report = _files(sweep / "report")
    left = _files(sweep)
    assert ARCHIVE in left and not any(k.endswith(("record.json", "evals.jsonl")) for k in left), sorted(left)
    (sweep / "report").rename(tmp_path / "first")
    _bench("bench.report", str(sweep), cwd=sweep.parent)
    assert _files(sweep / "report") == report
    assert set(_files(sweep)) == {ARCHIVE} | {f"report/{k}" for k in report}  # the records were removed again
    with records_restored([sweep]):
        assert {k: v for k, v in _files(sweep).items() if not k.startswith("report/") and k != ARCHIVE} == records


def test_packing_twice_gives_the_same_bytes(tmp_path):
    for name in ("a", "b"):
        job = tmp_path / name / "sphere" / "random" / "seed0"
        job.mkdir(parents=True)
        (job / "record.json").write_text('{"status": "ok"}\n')
        (job / "evals.jsonl").write_text('{"f": [1.0]}\n')
    assert pack(tmp_path / "a").read_bytes() == pack(tmp_path / "b").read_bytes()


def test_a_folder_with_both_records_and_an_archive_that_disagree_is_not_overwritten(tmp_path):
    job = tmp_path / "s" / "job"
    job.mkdir(parents=True)
    (job / "evals.jsonl").write_text("mine\n")
    pack(tmp_path / "s")
    (job / "record.json").unlink(missing_ok=True)
    with pytest.raises(ArchiveError, match="exists; a folder holds either its records or their archive"):
        with records_restored([tmp_path / "s"]):
            pass
    assert (job / "evals.jsonl").read_text() == "mine\n"


def test_job_records_read_the_same_from_files_and_from_the_archive(tmp_path):
    from bench.archive import job_records

    for k, optimizer in enumerate(("random", "cmaes")):
        job = tmp_path / "s" / "sphere" / optimizer / f"i{k}"
        job.mkdir(parents=True)
        (job / "record.json").write_text(f'{{"optimizer": "{optimizer}", "instance": {k}}}')
        (job / "evals.jsonl").write_text("{}\n")
    files = job_records(tmp_path / "s")
    assert [r["optimizer"] for _, r in files] == ["cmaes", "random"]
    pack(tmp_path / "s", remove=True)
    assert not (tmp_path / "s" / "sphere").exists()
    assert job_records(tmp_path / "s") == files
    assert job_records(tmp_path / "s", "sphere/random/*/record.json") == files[1:]
    assert job_records(tmp_path / "nothing") == []


def test_a_study_may_leave_the_logs_out_of_its_archive(tmp_path):
    from bench.archive import job_records

    job = tmp_path / "c" / "synthetic" / "cmaes" / "i0"
    job.mkdir(parents=True)
    (job / "record.json").write_text('{"best_f": 1.0}')
    (job / "evals.jsonl").write_text("{}\n")
    pack(tmp_path / "c", remove=True, logs=False)
    assert sorted(p.name for p in (tmp_path / "c").rglob("*") if p.is_file()) == [ARCHIVE]  # the log is gone too
    assert [r for _, r in job_records(tmp_path / "c")] == [{"best_f": 1.0}]
    with records_restored([tmp_path / "c"]):
        assert (job / "record.json").is_file() and not (job / "evals.jsonl").exists()


def test_unpack_restores_what_pack_removed_and_the_folder_packs_to_the_same_bytes(tmp_path):
    from bench.archive import unpack

    job = tmp_path / "c" / "synthetic" / "cmaes" / "seed0"
    job.mkdir(parents=True)
    (job / "record.json").write_text('{"best_f": 1.0}')
    (tmp_path / "c" / "multirun.yaml").write_text("hydra: {}\n")
    packed = pack(tmp_path / "c", remove=True).read_bytes()
    restored = unpack(tmp_path / "c")
    assert sorted(p.as_posix() for p in restored) == ["multirun.yaml", "synthetic/cmaes/seed0/record.json"]
    assert not (tmp_path / "c" / ARCHIVE).exists() and (job / "record.json").read_text() == '{"best_f": 1.0}'
    assert pack(tmp_path / "c").read_bytes() == packed  # nothing changed on the way
    with pytest.raises(ArchiveError, match="no archive to unpack"):
        unpack(tmp_path / "nothing")
