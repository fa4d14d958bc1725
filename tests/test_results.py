"""The committed results: what a clone downloads, and reports rebuilt byte for byte from what is committed."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LIMIT_BYTES = 30 * 1024 * 1024  # issue 32: results/ in the tree <= 30 MB

pytestmark = pytest.mark.skipif(shutil.which("git") is None or not (ROOT / ".git").exists(),
                                reason="needs a git checkout (the committed files are git's)")


def tracked(path: str) -> list[Path]:
    out = subprocess.run(["git", "ls-files", "-z", path], cwd=ROOT, capture_output=True, check=True).stdout
    return [ROOT / p for p in out.decode().split("\0") if p]


def test_the_committed_results_weigh_at_most_30_mb():
    files = tracked("results")
    size = sum(p.stat().st_size for p in files if p.is_file())
    assert files and size <= LIMIT_BYTES, f"results/ tracks {size / 2**20:.1f} MB in {len(files)} files"
    assert not [p for p in files if p.name in ("evals.jsonl", "report.html", "evaluations.parquet")]


def _committed_copy(name: str, into: Path) -> Path:
    """The set's tracked files, as a fresh clone has them, copied under ``into``."""
    for path in tracked(f"results/{name}"):
        target = into / path.relative_to(ROOT / "results")
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, target)
    return into / name


@pytest.mark.parametrize("name", ["kitti00_tracks_rotation"])  # the smallest set: seconds
def test_a_committed_report_is_rebuilt_byte_for_byte_from_what_is_committed(name, tmp_path):
    committed = {p.relative_to(ROOT / "results" / name): p.read_bytes() for p in tracked(f"results/{name}/report")}
    assert committed and (ROOT / "results" / name / "records.tar.xz").is_file()
    copy = _committed_copy(name, tmp_path)
    shutil.rmtree(copy / "report")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "AVIO_DATA": str(tmp_path / "no-data")}  # records, not data
    proc = subprocess.run([sys.executable, "-m", "bench.report", str(copy)], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rebuilt = {rel: (copy / rel).read_bytes() for rel in committed}
    assert [str(rel) for rel in committed if rebuilt[rel] != committed[rel]] == []
    assert (copy / "report" / "report.html").is_file()  # what is not committed is rebuilt too
    assert sorted(p.name for p in copy.iterdir()) == ["records.tar.xz", "report"]  # the records went back
