"""The filter kernel of the working tree against the one of another commit, timed side by side
in one process, and whether they give the same bits (issue 13's A/B of a kernel change).

    python benchmarks/ab_kernel.py [--base HEAD] [--pairs 15] [--batch 16] [--threads 1] [--data ../shared/data]
                                   [--set KEY=VALUE ...] [--tree-set KEY=VALUE ...]
    python benchmarks/ab_kernel.py --base BASE --blocks 1 4 8    # each lock-step block size of the tree
    python benchmarks/ab_kernel.py --base BASE --compile-pairs 5    # the first-run compile instead

Why in one process: this VM's speed drifts between two states (~27 and ~43 ms for the same
evaluation), so two benchmark runs one after the other can differ by 50 % with the same code.
The script extracts ``avio/`` of ``--base`` (git archive) into a temporary folder as package
``avio_base`` (its imports rewritten, in every subpackage), compiles it once (kept in that folder, reused by the next
run for the same commit) and then times one batch of each kernel per pair, in a new random
order each pair, on kitti00 frames 15–796. It prints the median CPU time (process time: fair on a
shared machine; with several threads it sums them) per evaluation of each,
the median and quartiles of the per-pair ratios (base / working tree: above 1 means the working
tree is faster) and whether the two gave the same positions, velocities, sigmas and innovation
statistics to the bit.

The base commit may predate the package layout of e67dede (the kernel in avio/_kernels.py, the
filter in avio/filter.py, the loaders in avio/kitti00.py ...): each package's layout is read
from its files (``module_names``), so any commit with a KITTI 00 loader can be the base.

``--blocks`` times the working tree at each of these lock-step block sizes (avio.filter.batch.set_block:
1 numba's per-filter kernel, 2, 4 and 8 the C blocks), each in every pair; without it, its default.

``--compile-pairs K`` times the first-run compile instead: K pairs of processes, each with an empty
numba cache, the CPU time of its first filter call (batch 1; the call that compiles the kernel).
"""

from __future__ import annotations

import argparse
import importlib
import io
import os
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "benchmarks"))

_IMPORT = re.compile(r"^(\s*)(from|import) avio\b", re.MULTILINE)


def extract_base(commit: str) -> Path:
    """avio/ of ``commit`` as package avio_base in <tmp>/avio_ab_<sha>/ (made once per commit)."""
    sha = subprocess.run(["git", "rev-parse", commit], cwd=REPO, check=True, capture_output=True,
                         text=True).stdout.strip()
    root = Path(tempfile.gettempdir()) / f"avio_ab_{sha[:12]}"
    pkg = root / "avio_base"
    done = root / "avio_base.rewritten"  # a folder left half-made (or by an older version of this script) is redone
    if not done.is_file():
        shutil.rmtree(root, ignore_errors=True)
        blob = subprocess.run(["git", "archive", sha, "avio"], cwd=REPO, check=True, capture_output=True).stdout
        with tarfile.open(fileobj=io.BytesIO(blob)) as tar:
            tar.extractall(root / "_x", filter="data")
        (root / "_x" / "avio").rename(pkg)
        for path in pkg.rglob("*.py"):
            path.write_text(_IMPORT.sub(r"\1\2 avio_base", path.read_text()))
        done.write_text(sha + "\n")
    return root


def module_names(name: str, pkg: Path) -> dict[str, str]:
    """The modules ab_kernel uses, in package ``name`` at folder ``pkg``, by its layout: from
    e67dede on the loaders live in avio/datasets/ and Calibration in avio/calibration.py (the
    filter, avio/filter/, a package exporting the same names); before, avio/kitti00.py and
    avio/sequence.py (avio/filter.py a module)."""
    grouped = (pkg / "datasets" / "kitti00.py").is_file()
    return {"filter": f"{name}.filter", "geometry": f"{name}.geometry",
            "kitti00": f"{name}.datasets.kitti00" if grouped else f"{name}.kitti00",
            "calibration": f"{name}.calibration" if (pkg / "calibration.py").is_file() else f"{name}.sequence"}


def _load(name: str, data: Path, n: int, overrides: dict | None = None):
    """(filter module, sequence, preparation, calibrations) of package ``name`` (overrides: its
    FilterConfig's)."""
    names = module_names(name, Path(importlib.import_module(name).__file__).parent)
    filt = importlib.import_module(names["filter"])
    kitti = importlib.import_module(names["kitti00"])
    geometry = importlib.import_module(names["geometry"])
    calibration = importlib.import_module(names["calibration"])
    seq = kitti.load_kitti00(data / "kitti00", 15, 796, seed=0)
    cfg = filt.FilterConfig(**(overrides or {}))
    prep = filt.prepare(seq, cfg)
    rng = np.random.default_rng(n)  # bench_filter.py's _candidates, with this package's classes
    out = seq.truth_calibration.repeat(n)
    cals = calibration.Calibration(
        fx_px=out.fx_px + rng.normal(0, 5, n), fy_px=out.fy_px + rng.normal(0, 5, n),
        cx_px=out.cx_px + rng.normal(0, 5, n), cy_px=out.cy_px + rng.normal(0, 5, n),
        R_cam_imu=geometry.so3_exp(rng.normal(0, 0.01, (n, 3))) @ out.R_cam_imu,
        p_imu_cam_m=out.p_imu_cam_m + rng.normal(0, 0.05, (n, 3)), time_offset_s=np.zeros(n))
    return filt, seq, cfg, prep, cals


_COMPARED = ("p_world_imu_m", "R_world_imu", "v_world_imu_mps", "sigma", "b_a_mps2", "b_g_radps", "nis",
             "log_det_S", "dof", "nll", "nll_slots", "n_updates", "n_outliers", "diverged_at_frame")


def same_bits(a, b) -> bool:
    """Every array of the two FilterResults equal to the bit (NaN where NaN)."""
    for name in _COMPARED:
        x, y = getattr(a, name), getattr(b, name)
        if (x is None) != (y is None) or (x is not None and not np.array_equal(x, y, equal_nan=True)):
            return False
    return True


def _overrides(flag: str, items: list[str]) -> dict:
    """KEY=VALUE items as a dict (values parsed as YAML); exit 2 naming the flag on a bad one."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep:
            print(f"ab_kernel: {flag} {item!r}: expected KEY=VALUE", file=sys.stderr)
            raise SystemExit(2)
        out[key] = yaml.safe_load(value)
    return out


_COMPILE_ONE = """import sys, time
sys.path[:0] = [{root!r}, {bench!r}, {repo!r}]
import ab_kernel
filt, seq, cfg, prep, cals = ab_kernel._load({name!r}, ab_kernel.Path({data!r}), 1)
t = time.process_time()
filt.run(seq, cals, cfg, prep)
print(time.process_time() - t)
"""


def compile_pairs(base_root: Path, data: Path, pairs: int) -> None:
    """``pairs`` pairs of cold first calls (CPU s, the call that compiles the kernel) of the base's and the
    working tree's filter, each in its own process with an empty numba cache; the paired ratios."""
    rng = np.random.default_rng(0)
    cpu = {"base": [], "tree": []}
    for _ in range(pairs):
        for label in rng.permutation(["base", "tree"]):
            code = _COMPILE_ONE.format(root=str(base_root), bench=str(REPO / "benchmarks"), repo=str(REPO),
                                       name="avio_base" if label == "base" else "avio", data=str(data))
            with tempfile.TemporaryDirectory(prefix="ab-compile-") as cache:
                done = subprocess.run([sys.executable, "-c", code], env={**os.environ, "NUMBA_CACHE_DIR": cache},
                                      capture_output=True, text=True, check=True)
            cpu[label].append(float(done.stdout.split()[-1]))
            print(f"{label}: first call {cpu[label][-1]:.1f} s CPU", flush=True)
    ratio = np.asarray(cpu["base"]) / np.asarray(cpu["tree"])
    q1, q2, q3 = np.percentile(ratio, [25, 50, 75])
    print(f"first-run compile, {pairs} pairs: base {np.median(cpu['base']):.1f} s, working tree "
          f"{np.median(cpu['tree']):.1f} s CPU (medians); base/tree: median {q2:.3f}x (quartiles {q1:.3f}-{q3:.3f})")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", default="HEAD")
    ap.add_argument("--pairs", type=int, default=15)
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--data", default=os.environ.get("AVIO_DATA", str(REPO.parent / "shared" / "data")))
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                    help="FilterConfig overrides of both filters (a change's bits and speed with an option on), "
                         "e.g. jacobian_pixels=corrected")
    ap.add_argument("--tree-set", nargs="*", default=[], metavar="KEY=VALUE",
                    help="FilterConfig overrides of the working tree's filter only (the cost of an option "
                         "against the base's default; the bits then differ), e.g. jacobian_pixels=corrected")
    ap.add_argument("--blocks", type=int, nargs="*", default=None, metavar="L",
                    help="the working tree's lock-step block sizes to time, each against the base (1: numba's "
                         "per-filter kernel); default: its own rule")
    ap.add_argument("--compile-pairs", type=int, default=0, metavar="K",
                    help="instead of timing evaluations: K pairs of first-run compiles of the two kernels, each in a "
                         "fresh process with an empty NUMBA_CACHE_DIR (the first call at batch 1), in a random order "
                         "per pair")
    args = ap.parse_args(argv)
    if args.compile_pairs < 0:
        print(f"ab_kernel: --compile-pairs {args.compile_pairs}: expected an integer >= 0", file=sys.stderr)
        raise SystemExit(2)
    for block in args.blocks or []:
        if block not in (1, 2, 4, 8):
            print(f"ab_kernel: --blocks {block}: expected 1, 2, 4 or 8", file=sys.stderr)
            raise SystemExit(2)
    both_set, tree_set = _overrides("--set", args.set), _overrides("--tree-set", args.tree_set)
    data = Path(args.data)
    if not (data / "kitti00").is_dir():
        print(f"ab_kernel: no KITTI 00 data at {data / 'kitti00'} (--data or AVIO_DATA)", file=sys.stderr)
        raise SystemExit(2)
    base_root = extract_base(args.base)
    if args.compile_pairs:
        return compile_pairs(base_root, data, args.compile_pairs)
    sys.path.insert(0, str(base_root))
    runs = {}
    for label, name in (("base", "avio_base"), ("tree", "avio")):
        filt, seq, cfg, prep, cals = _load(name, data, args.batch, {**both_set, **(tree_set if label == "tree" else {})})
        filt.set_threads(args.threads)
        t = time.perf_counter()
        first = filt.run(seq, cals, cfg, prep)
        print(f"{label}: {name} from {Path(filt.__file__).parent}, first call {time.perf_counter() - t:.1f} s",
              flush=True)
        runs[label] = (filt, seq, cals, cfg, prep, first)
    blocks = {"tree": None} if args.blocks is None else {f"tree, block {b}": b for b in args.blocks}
    tree_batch = importlib.import_module("avio.filter.batch")
    for label in blocks:
        runs[label] = runs["tree"]
    same = {}
    for label, block in blocks.items():
        tree_batch.set_block(block)
        filt, seq, cals, cfg, prep, _first = runs[label]
        same[label] = same_bits(runs["base"][5], filt.run(seq, cals, cfg, prep))
    rng = np.random.default_rng(0)
    ms = {label: [] for label in ("base", *blocks)}
    for _ in range(args.pairs):
        for label in rng.permutation(list(ms)):
            filt, seq, cals, cfg, prep, _first = runs[label]
            tree_batch.set_block(blocks.get(label))
            t = time.process_time()  # CPU time: fair while other processes share the machine
            filt.run(seq, cals, cfg, prep)
            ms[label].append(1e3 * (time.process_time() - t) / args.batch)
    print(f"kitti00 15-796, batch {args.batch}, {args.threads} thread(s), {args.pairs} pairs: base "
          f"{np.median(ms['base']):.2f} ms CPU per evaluation (median)")
    for label in blocks:
        ratio = np.asarray(ms["base"]) / np.asarray(ms[label])
        q1, q2, q3 = np.percentile(ratio, [25, 50, 75])
        print(f"{label}: {np.median(ms[label]):.2f} ms; speed-up base/tree: median {q2:.3f}x (quartiles "
              f"{q1:.3f}-{q3:.3f}); same bits: {same[label]}")

if __name__ == "__main__":
    main()
