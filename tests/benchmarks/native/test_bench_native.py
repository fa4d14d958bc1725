"""benchmarks/native/bench_native.py measures the C route of issue 30 against the kernel's numba code: its
C variants must do the kernel's work (the same bits), its numba copy of the gain and downdate must be the
kernel's lines, and its lock-step lanes must compile packed, or its ratios compare different work."""

from __future__ import annotations

import ast
import inspect
import os
import re
import shutil
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[3]
needs_cc = pytest.mark.skipif(shutil.which(os.environ.get("CC", "cc")) is None,
                              reason="no C compiler (cc or $CC) on this machine: bench_native.py needs one")


@needs_cc
def test_every_c_variant_gives_the_kernels_bits_and_the_lanes_pack(load_script, capsys):
    native = load_script("bench_native")
    native.main(["--repeats", "1", "--calls", "8", "--features", "11"])  # 11: a partial SIMD block of features
    out = capsys.readouterr().out
    rows = {}
    phase = None
    for line in out.splitlines():
        if line.endswith(":") and not line.startswith(" "):
            phase = line[:-1]
        elif "us/filter" in line:
            rows[phase, line.split(" us/filter")[0].rsplit(None, 1)[0].strip()] = line
    lanes = ["numba", "C", "C lanes 4", "C lanes 8"]
    assert [name for p, name in rows if p == "prediction"] == lanes
    assert [name for p, name in rows if p == "gain"] == lanes
    assert [name for p, name in rows if p == "solve"] == lanes
    assert [name for p, name in rows if p == "innovations"] == ["numba", "C"]
    assert all("bit-identical=True" in line for line in rows.values()), out
    counts = {key: [int(w) for w in re.findall(r"(\d+) (?:scalar|packed)", line)] for key, line in rows.items()}
    assert all(sum(c) > 0 for c in counts.values()), counts  # each variant's code was found in the assembly
    for p in ("prediction", "gain", "solve"):
        assert counts[p, "C lanes 8"][1] > 0, counts  # the lanes are packed


def test_the_numba_copy_of_the_gain_and_downdate_is_the_kernels_code(load_script):
    """The copy's statements appear, in order, in avio.filter.update.update (else the phase measured is not
    the kernel's)."""
    native = load_script("bench_native")
    copy = ast.parse(textwrap.dedent(inspect.getsource(native.gain_downdate))).body[0]
    update = next(node for node in ast.parse((REPO / "avio/filter/update.py").read_text()).body
                  if isinstance(node, ast.FunctionDef) and node.name == "update")
    kernel = [ast.dump(s) for s in ast.walk(update) if isinstance(s, ast.For)]
    loops = [ast.dump(s) for s in copy.body if isinstance(s, ast.For)]
    assert len(loops) == 2 and all(loop in kernel for loop in loops)


def test_a_missing_compiler_is_one_message_naming_it(load_script, monkeypatch):
    native = load_script("bench_native")
    monkeypatch.setenv("CC", "no-such-cc")
    with pytest.raises(SystemExit, match="needs a C compiler: 'no-such-cc' is not on PATH"):
        native.main(["--repeats", "1", "--calls", "1"])
