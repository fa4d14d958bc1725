"""Longest silence of a command: run it, time-stamp every output line (stdout and stderr, lines
ending in \n or tqdm's \r), and print the longest gap between two of them and what came after it.

    python benchmarks/output_gaps.py -- python -m bench problem=synthetic optimizer=psoga seed=0 budget.evals=100

Prints ``longest gap: S s before: <line>`` and the command's exit code; exits 1 when the gap
exceeds ``--max-gap`` (default 10 s).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max-gap", type=float, default=10.0, help="seconds of silence allowed (default 10)")
    parser.add_argument("command", nargs=argparse.REMAINDER, help="the command, after --")
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("give the command after --")
    t0 = time.perf_counter()
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, bufsize=0)
    last, gaps, pending = t0, [], b""
    while True:
        chunk = os.read(proc.stdout.fileno(), 65536)
        now = time.perf_counter()
        if not chunk:
            break
        pending += chunk
        pieces = re.split(rb"[\r\n]", pending)
        pending = pieces.pop()
        for piece in pieces:
            if piece.strip():
                gaps.append((now - last, piece.decode(errors="replace")[:160]))
                last = now
    code = proc.wait()
    total = time.perf_counter() - t0
    gap, line = max(gaps) if gaps else (total, "<no output>")
    print(f"lines: {len(gaps)}, total {total:.1f} s, exit code {code}")
    print(f"longest gap: {gap:.1f} s before: {line}")
    return 1 if gap > args.max_gap else 0


if __name__ == "__main__":
    sys.exit(main())
