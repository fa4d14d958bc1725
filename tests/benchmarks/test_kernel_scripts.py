"""The kernel's measuring scripts still fit the kernel: benchmarks/profile_kernel.py patches
avio/filter/{update,kernels,batch}.py by anchors on their source text, benchmarks/ab_kernel.py
rewrites another commit's avio (either layout: avio/filter/ a package, or before e67dede
avio/_kernels.py and avio/filter.py) into package avio_base. Both would only fail when someone
runs them, long after the edit that broke them."""

from __future__ import annotations

import ast
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]


def test_every_profile_anchor_is_found_in_the_kernel_and_the_patch_compiles(load_script):
    prof = load_script("profile_kernel")
    patched = {name: patch((REPO / "avio" / name).read_text()) for name, patch in prof.PATCHES.items()}
    for text in patched.values():
        ast.parse(text)  # valid Python
    kernel = patched["filter/update.py"] + patched["filter/kernels.py"]
    for i in range(len(prof.PHASES)):
        assert f"range(rep[{i}])" in kernel or f"range(rep[{i}] - 1)" in kernel, prof.PHASES[i]
    assert "REP = np.ones" in patched["filter/batch.py"]
    # the kernel compiles without numba's reference counting, which a slice assignment needs (a
    # compile error ~70 s into the script)
    assert not re.search(r"\[[:, ]*\] = [A-Za-z_]", patched["filter/kernels.py"])  # an array, not a number


def test_a_changed_kernel_is_a_clear_error_naming_the_anchor(load_script):
    prof = load_script("profile_kernel")
    with pytest.raises(SystemExit, match="anchor not found"):
        prof.patch_kernels("def nothing():\n    pass\n")


def test_the_base_package_imports_only_itself(tmp_path, monkeypatch, load_script):
    if subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True).returncode != 0:
        pytest.skip("not a git checkout")
    ab = load_script("ab_kernel")
    monkeypatch.setattr(ab.tempfile, "gettempdir", lambda: str(tmp_path))
    layouts = [("HEAD", "filter/kernels.py", "from avio_base.filter._linalg import", "avio_base.datasets.kitti00")]
    # a base from before the package layout (e67dede): the kernel in avio/_kernels.py, the filter in avio/filter.py
    if subprocess.run(["git", "cat-file", "-e", "c320580^{commit}"], cwd=REPO, capture_output=True).returncode == 0:
        layouts.append(("c320580", "_kernels.py", "from avio_base._linalg import", "avio_base.kitti00"))
    for commit, kernel, imports, kitti in layouts:
        pkg = ab.extract_base(commit) / "avio_base"
        sources = {p.relative_to(pkg).as_posix(): p.read_text() for p in pkg.rglob("*.py")}
        assert kernel in sources and ("filter.py" in sources or "filter/batch.py" in sources), commit
        for name, text in sources.items():
            assert not re.search(r"^\s*(from|import) avio\b", text, re.MULTILINE), (commit, name)
        assert imports in sources[kernel], commit
        assert ab.module_names("avio_base", pkg)["kitti00"] == kitti, commit
    assert ab.module_names("avio", REPO / "avio")["kitti00"] == "avio.datasets.kitti00"


def test_every_layout_of_the_prediction_gives_the_committed_bits(load_script, capsys):
    """benchmarks/bench_layout.py's variants compute what the kernel computes (else its ratios
    compare different work), and the lanes compiled with the SIMD switches are packed (with AVX)."""
    from llvmlite import binding as llvm

    layout = load_script("bench_layout")
    layout.main(["--lanes", "4", "--runtime-lanes", "8", "--repeats", "1", "--calls", "16"])
    lines = {ln.split(" us/filter")[0].rsplit(None, 1)[0].strip(): ln
             for ln in capsys.readouterr().out.splitlines() if "us/filter" in ln}
    assert list(lines) == ["committed", "rows", "committed +noalias+SLP", "lanes 4", "lanes 4 +noalias+SLP",
                           "lanes 8 (run-time)"]
    assert all("bit-identical=True" in ln for ln in lines.values()), lines
    counts = {name: [int(w) for w in re.findall(r"(\d+) (?:scalar|packed)", ln)] for name, ln in lines.items()}
    assert counts["lanes 4"][1] == 0 and counts["lanes 4"][0] > 0  # numba's defaults: scalar
    if llvm.get_host_cpu_features().get("avx", False):
        assert counts["lanes 4 +noalias+SLP"][0] == 0 and counts["lanes 4 +noalias+SLP"][1] > 0, counts


def test_the_solve_in_lock_step_gives_every_lanes_bits_and_packs(load_script, capsys):
    """--phase solve: L systems with a pivot per lane give each system's bits of the kernel's solve
    (the inputs pivot differently per lane), and the lane code is packed (with AVX)."""
    from llvmlite import binding as llvm

    layout = load_script("bench_layout")
    M, X = layout._systems(8)
    first = np.abs(M[:, :, 0]).argmax(axis=1)
    assert len(set(first.tolist())) > 1  # the lanes' first pivots differ: the per-lane swap is exercised
    layout.main(["--phase", "solve", "--lanes", "4", "8", "--repeats", "1", "--calls", "16"])
    lines = [ln for ln in capsys.readouterr().out.splitlines() if "us/filter" in ln]
    assert [ln.split(" us/filter")[0].rsplit(None, 1)[0].strip() for ln in lines] == [
        "committed", "lanes 4 +noalias+SLP", "lanes 8 +noalias+SLP"]
    assert all("bit-identical=True" in ln for ln in lines), lines
    if llvm.get_host_cpu_features().get("avx", False):
        packed = [int(re.search(r"(\d+) packed", ln).group(1)) for ln in lines[1:]]
        assert min(packed) > 0, lines


def test_the_features_estimate_runs_every_phase_at_every_lane_count(load_script, capsys):
    """--phase features prints both phases with an estimate per lane count (times are not asserted),
    and its premise holds: a feature's results do not depend on how many features share the call."""
    from avio.filter.outliers import feature_innovations

    rng = np.random.default_rng(3)
    J, H, r = rng.normal(size=(20, 12)), rng.normal(size=(3, 12, 24)), rng.normal(size=(3, 24))
    P, Rm = J.T @ J + np.eye(12), np.repeat(np.eye(3)[:, :, None], 24, axis=2)
    alone, together = [(np.empty((3, 12, F)), np.empty((3, F)), np.empty(F)) for F in (8, 24)]
    feature_innovations(r[:, :8].copy(), H[:, :, :8].copy(), P, Rm[:, :, :8].copy(), *alone)
    feature_innovations(r, H, P, Rm, *together)
    assert all(np.array_equal(a, t[..., :8]) for a, t in zip(alone, together))
    layout = load_script("bench_layout")
    layout.main(["--phase", "features", "--features", "8", "--lanes", "2", "4", "--repeats", "1", "--calls", "8"])
    lines = [ln for ln in capsys.readouterr().out.splitlines() if " us " in ln and "lanes" in ln]
    assert [ln.split()[0] for ln in lines[1:]] == ["feature", "noise"], lines
    assert all(re.search(r"2 lanes +[\d.]+ us \([\d.]+x\) +4 lanes +[\d.]+ us \([\d.]+x\)", ln) for ln in lines[1:]), lines


def test_a_tree_override_without_a_value_is_refused_before_any_work(load_script, capsys):
    ab = load_script("ab_kernel")
    with pytest.raises(SystemExit) as stop:
        ab.main(["--tree-set", "jacobian_pixels"])
    assert stop.value.code == 2
    assert "--tree-set 'jacobian_pixels': expected KEY=VALUE" in capsys.readouterr().err
