"""benchmarks/bench_sweep_scale.py still runs and prints its line (the figure itself is not a test)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_the_preflight_benchmark_prints_its_figure():
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_sweep_scale.py"), "--jobs", "12"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.startswith("preflight: 12 jobs, wall ") and "ms CPU per job" in proc.stdout
