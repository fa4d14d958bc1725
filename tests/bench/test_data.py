"""``python -m bench.data``: the files each VIO problem reads, and ``--check`` of a data folder."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from bench import data
from bench.data import PROBLEM_DATA, DataFile, check_file, main
from bench.problems import available, get
from bench.problems.vio import VioProblem

ROOT = Path(__file__).resolve().parents[2]


def test_every_registered_vio_problem_is_described():
    vio = {n for n in available() if isinstance(get(n), type) and issubclass(get(n), VioProblem)}
    assert vio == set(PROBLEM_DATA)
    for name, entry in PROBLEM_DATA.items():
        assert bool(entry.files) == (name != "synthetic"), name
        if entry.files:
            assert entry.origin and entry.licence, name


def test_listing_works_without_data(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("AVIO_DATA", str(tmp_path / "nowhere"))
    assert main([]) == 0
    out = capsys.readouterr().out
    for name in PROBLEM_DATA:
        assert f"{name}: " in out
    assert "kitti00/VO_stereo_factors00.txt" in out and "euroc_v1_01/eqvio_processed_30s.csv" in out
    assert "cvlibs.net" in out and "CC BY-NC-SA 3.0" in out and str(tmp_path / "nowhere") in out


def test_module_runs_as_a_command(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "AVIO_DATA": str(tmp_path)}
    proc = subprocess.run([sys.executable, "-m", "bench.data", "kitti00"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "kitti00/KittiEquivBiasedImu.txt" in proc.stdout and "euroc" not in proc.stdout


def test_unknown_problem_exits_2(capsys):
    assert main(["nope", "--check"]) == 2
    assert "unknown problem(s) ['nope']" in capsys.readouterr().err


def test_check_reports_missing_wrong_size_and_wrong_hash(tmp_path, monkeypatch, capsys):
    good, wrong_hash = b"0123456789\n", b"0123456780\n"
    files = (DataFile("tiny/good.txt", len(good), hashlib.sha256(good).hexdigest(), "a good file"),
             DataFile("tiny/short.txt", 99, hashlib.sha256(good).hexdigest(), "a file of the wrong size"),
             DataFile("tiny/other.txt", len(good), hashlib.sha256(good).hexdigest(), "another version"),
             DataFile("tiny/absent.txt", 1, "0" * 64, "missing"))
    (tmp_path / "tiny").mkdir()
    (tmp_path / "tiny" / "good.txt").write_bytes(good)
    (tmp_path / "tiny" / "short.txt").write_bytes(good)
    (tmp_path / "tiny" / "other.txt").write_bytes(wrong_hash)
    monkeypatch.setattr(data, "PROBLEM_DATA", {"tiny": data.ProblemData("test", "here", "none", files),
                                               "fine": data.ProblemData("test", "here", "none", files[:1]),
                                               "synthetic": data.ProblemData("needs none")})
    assert check_file(tmp_path, files[0]) is None
    assert main(["--check", str(tmp_path)]) == 2
    captured = capsys.readouterr()
    (message,) = captured.err.strip().splitlines()  # one message per problem that fails
    assert message.startswith("tiny: 3 of 4 files wrong")
    assert f"{tmp_path / 'tiny' / 'short.txt'}: {len(good)} bytes, expected 99" in message
    assert f"{tmp_path / 'tiny' / 'other.txt'}: SHA-256 differs" in message
    assert f"{tmp_path / 'tiny' / 'absent.txt'}: missing" in message
    assert "fine: ok (1 files)" in captured.out and "synthetic: ok (needs no data)" in captured.out
    assert main(["fine", "synthetic", "--check", str(tmp_path)]) == 0
    monkeypatch.setenv("AVIO_DATA", str(tmp_path))
    assert main(["--check", "fine"]) == 0  # a problem name after --check is a problem, not DIR


def test_check_of_a_copied_real_file_and_a_truncated_one(shared_data, tmp_path, capsys):
    """A folder holding the real small Kalibr files passes them and names the truncated copy."""
    euroc = tmp_path / "euroc_v1_01"
    euroc.mkdir()
    for name in ("kalibr_imucam_chain.yaml", "kalibr_imu_chain.yaml"):
        shutil.copyfile(shared_data / "euroc_v1_01" / name, euroc / name)
    (euroc / "V1_01_easy_groundtruth.csv").write_bytes((shared_data / "euroc_v1_01" /
                                                        "V1_01_easy_groundtruth.csv").read_bytes()[:1000])
    assert main(["euroc", "--check", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("euroc: 2 of 4 files wrong") and "V1_01_easy_groundtruth.csv: 1000 bytes" in err
    assert "eqvio_processed_30s.csv: missing" in err and "kalibr" not in err


def test_check_of_an_absent_folder_says_so(tmp_path, capsys):
    assert main(["kitti00", "euroc", "synthetic", "--check", str(tmp_path / "absent")]) == 2
    captured = capsys.readouterr()
    assert captured.err.splitlines() == [f"{n}: data folder {tmp_path / 'absent'} not found (pass DIR, or set AVIO_DATA; "
                                         "docs/guide/data.md)" for n in ("kitti00", "euroc")]
    assert "synthetic: ok" in captured.out


def test_check_of_a_group_counts_its_files(tmp_path):
    entry = DataFile("d/*.txt", 2, hashlib.sha256(b"ab").hexdigest(), "two files", count=2)
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "1.txt").write_bytes(b"a")
    assert "1 files, expected 2" in check_file(tmp_path, entry)
    (tmp_path / "d" / "2.txt").write_bytes(b"b")
    assert check_file(tmp_path, entry) is None


@pytest.mark.data
def test_check_passes_on_the_real_data(shared_data, capsys):
    assert main(["--check", str(shared_data)]) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    assert all(f"{name}: ok" in out for name in PROBLEM_DATA)
