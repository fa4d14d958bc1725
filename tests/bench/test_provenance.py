"""bench.provenance: the commit a record names, and when it is dirty; the vector extensions it names."""

from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
import sys

import pytest

from bench.provenance import _git_commit, cpu_features


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


#: README's list (numpy ignores the ones a CPU lacks)
AVX512 = "AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR AVX512_KNL AVX512_KNM"


def _features_in(env: dict) -> dict:
    code = "import json; from bench.provenance import cpu_features; print(json.dumps(cpu_features()))"
    out = subprocess.run([sys.executable, "-c", code], env={**os.environ, **env}, capture_output=True, text=True,
                         check=True, timeout=60).stdout
    return json.loads(out)


@pytest.mark.skipif(platform.machine() not in ("x86_64", "AMD64")
                    or not cpu_features()["numpy"].startswith(("AVX2", "AVX512")),
                    reason="the AVX2 recipe is for x86-64 machines with AVX2")
def test_cpu_features_name_what_numpy_and_openblas_dispatch_to():
    # what README's bit-exact reproduction sets: numpy without AVX-512, OpenBLAS's Haswell kernels
    here = cpu_features()
    assert here["numpy"] and here["openblas"] and here["llvm"]
    forced = _features_in({"NPY_DISABLE_CPU_FEATURES": AVX512, "OPENBLAS_CORETYPE": "Haswell"})
    assert forced["numpy"] == "AVX2" and forced["openblas"] == "Haswell", forced
