"""The kernel's measuring scripts still fit the kernel: scripts/profile_kernel.py patches
avio/_kernels.py by anchors on its source text, scripts/ab_kernel.py rewrites another commit's
avio into package avio_base. Both would only fail when someone runs them, long after the edit
that broke them."""

from __future__ import annotations

import ast
import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


def test_every_profile_anchor_is_found_in_the_kernel_and_the_patch_compiles(load_script):
    prof = load_script("profile_kernel")
    patched = prof.patch_kernels((REPO / "avio" / "_kernels.py").read_text())
    ast.parse(patched)  # valid Python
    for i in range(len(prof.PHASES)):
        assert f"range(rep[{i}])" in patched or f"range(rep[{i}] - 1)" in patched, prof.PHASES[i]
    ast.parse(prof.patch_filter((REPO / "avio" / "filter.py").read_text()))


def test_a_changed_kernel_is_a_clear_error_naming_the_anchor(load_script):
    prof = load_script("profile_kernel")
    with pytest.raises(SystemExit, match="anchor not found"):
        prof.patch_kernels("def nothing():\n    pass\n")


def test_the_base_package_imports_only_itself(tmp_path, monkeypatch, load_script):
    if subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True).returncode != 0:
        pytest.skip("not a git checkout")
    ab = load_script("ab_kernel")
    monkeypatch.setattr(ab.tempfile, "gettempdir", lambda: str(tmp_path))
    pkg = ab.extract_base("HEAD") / "avio_base"
    sources = {p.name: p.read_text() for p in pkg.glob("*.py")}
    assert "_kernels.py" in sources and "filter.py" in sources
    for name, text in sources.items():
        assert not re.search(r"^\s*(from|import) avio\b", text, re.MULTILINE), name
    assert "from avio_base._linalg import" in sources["_kernels.py"]


def test_every_layout_of_the_prediction_gives_the_committed_bits(load_script, capsys):
    """scripts/bench_layout.py's variants compute what the kernel computes (else its ratios
    compare different work)."""
    layout = load_script("bench_layout")
    layout.main(["--lanes", "4", "--runtime-lanes", "8", "--repeats", "1", "--calls", "16"])
    lines = [ln for ln in capsys.readouterr().out.splitlines() if "us/filter" in ln]
    assert [ln.split()[0] for ln in lines] == ["committed", "rows", "lanes", "lanes"]
    assert all("bit-identical=True" in ln for ln in lines), lines
