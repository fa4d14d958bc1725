"""bench.provenance: the commit a record names, and when it is dirty."""

from __future__ import annotations

import shutil
import subprocess

import pytest

from bench.provenance import _git_commit


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_changed_code_is_dirty_and_changed_results_are_not(tmp_path):
    def git(*args):
        subprocess.run(["git", "-c", "user.email=t@t", "-c", "user.name=t", *args], cwd=tmp_path, check=True,
                       capture_output=True)

    (tmp_path / "results").mkdir()
    (tmp_path / "results" / ".provenance").write_text("- a sweep\n")
    (tmp_path / "code.py").write_text("x = 1\n")
    git("init", "-q")
    git("add", "-A")
    git("commit", "-qm", "first")
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=tmp_path, capture_output=True, text=True).stdout.strip()
    assert _git_commit(tmp_path) == head
    (tmp_path / "results" / ".provenance").write_text("- a sweep\n- the next sweep\n")  # an earlier sweep's line
    (tmp_path / "results" / "new_record.json").write_text("{}")
    assert _git_commit(tmp_path) == head
    (tmp_path / "code.py").write_text("x = 2\n")
    assert _git_commit(tmp_path) == head + "-dirty"
