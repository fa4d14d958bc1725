"""How long does a command sit silent? The longest gap between two of its output lines.

    python scripts/longest_gap.py -- python -m bench                      # the default run
    python scripts/longest_gap.py -- python -m bench.report results/synthetic --recompute

Runs the command with stdout and stderr merged (unbuffered Python), echoes every line with its
time since the start, and ends with the longest gap, the line it followed and the total time.
Exits with the command's exit code.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time


def main() -> int:
    argv = sys.argv[1:]
    if argv[:1] == ["--"]:
        argv = argv[1:]
    if not argv:
        print(__doc__.strip(), file=sys.stderr)
        return 2
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    start = last = time.perf_counter()
    gap, after = 0.0, "(start)"
    previous = "(start)"
    with subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1, env=env) as proc:
        for line in proc.stdout:
            now = time.perf_counter()
            if now - last > gap:
                gap, after = now - last, previous
            last, previous = now, line.rstrip()
            print(f"[{now - start:7.1f} s] {previous}", flush=True)
    end = time.perf_counter()
    if end - last > gap:
        gap, after = end - last, previous
    print(f"longest gap between output lines: {gap:.1f} s, after: {after!r}")
    print(f"total: {end - start:.1f} s, exit code {proc.returncode}")
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main())
