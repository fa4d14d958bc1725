"""The C of the lock-step blocks (covariance.c, update.c beside this module), built by the system's C
compiler on first use and loaded with ctypes.

Built once per machine and source: ``$CC`` (else ``cc``) with :data:`FLAGS` into
``<cache>/lanes-<key>.so``, the key a hash of the sources, the flags, the compiler's version and the
host CPU (``-march=native``: a library built on one CPU is never loaded on another). The cache is
``$AVIO_NATIVE_CACHE``, else numba's ``$NUMBA_CACHE_DIR`` (beside the compiled kernel), else
avio/filter/lanes/__pycache__ where it is writable, else ``~/.cache/avio``. The library is written
under a temporary name and renamed, so processes building at once (pytest-xdist, a SLURM array)
never load a half-written file. Where it cannot be built
(no compiler, a failed compile) or ``AVIO_NATIVE=0``, :func:`unavailable` says why and the filter runs
numba's per-filter kernel (avio/filter/kernels.py), with the same bits, more slowly at large batches.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import NamedTuple

HERE = Path(__file__).resolve().parent
SOURCES = ("covariance.c", "update.c")
#: -ffp-contract=off and no fast-math: the operations of numba's code in its order, so the same bits;
#: -fno-trapping-math: no FP exception is ever read (LLVM's, so numba's, default), which lets gcc turn a
#: lane's select into a blend instead of a branch.
FLAGS = ("-O3", "-march=native", "-ffp-contract=off", "-fno-fast-math", "-fno-trapping-math", "-shared", "-fPIC")
#: The block sizes the C is instantiated for (the ``lanes_*_<L>`` functions).
BLOCK_SIZES = (2, 4, 8)  # a block of one filter is numba's per-filter kernel (avio/filter/kernels.py)
_PTR = ctypes.c_void_p


class LaneFunctions(NamedTuple):
    """The dense phases for L filters in lock-step (arrays lanes last: avio.filter.interface.DenseLanes),
    each a ctypes function of data pointers."""

    pred: object  #: (P, Phi, Qd, T, U): P <- F P F^T + Q (Eq. 18), Qd (15, 15) shared by the lanes
    proj: object  #: (C, P, CP, PCt, Sig): C P, its transpose and Sigma = C P C^T (Eq. 37)
    solve: object  #: (Mx, X, ra, rb): X <- Mx^-1 X, a pivot per lane (Eqs. 41-42)
    gain: object  #: (P, PCt, X, CP, K): P -= (PCt X[:, :12]) CP (Eq. 42)
    stats: object  #: (Sig, X, PCt, beta, sums, dx, res): NIS, pose trace (Eqs. 44, 55b), dx (Eq. 41)
    slide: object  #: (P, J, NR): the window's move (Eq. 50)
    finite: object  #: (P, bad): bad[l] = 1 where lane l's P has a non-finite entry (Eq. 51)


_NARGS = {"pred": 5, "proj": 5, "solve": 4, "gain": 5, "stats": 7, "slide": 3, "finite": 2}
_loaded: dict = {}  # "lib": the CDLL or None, "why": the reason it is None


def _compiler() -> str | None:
    cc = os.environ.get("CC", "cc")
    return shutil.which(cc)


def _cache_dir() -> Path:
    """Where the library is kept (module docstring)."""
    for candidate in (os.environ.get("AVIO_NATIVE_CACHE"), os.environ.get("NUMBA_CACHE_DIR"), HERE / "__pycache__",
                      Path.home() / ".cache" / "avio"):
        if candidate:
            path = Path(candidate)
            try:
                path.mkdir(parents=True, exist_ok=True)
            except OSError:
                continue
            if os.access(path, os.W_OK):
                return path
    return Path(tempfile.gettempdir())


def _key(cc: str) -> str:
    import llvmlite.binding as llvm  # numba's: the host CPU's name and features

    version = subprocess.run([cc, "--version"], capture_output=True, text=True).stdout
    digest = hashlib.sha256()
    for source in SOURCES:
        digest.update((HERE / source).read_bytes())
    for text in (" ".join(FLAGS), version, llvm.get_host_cpu_name(), llvm.get_host_cpu_features().flatten()):
        digest.update(text.encode())
    return digest.hexdigest()[:16]


def build() -> Path:
    """The library's path, compiled first when it is not in the cache; RuntimeError naming what failed."""
    cc = _compiler()
    if cc is None:
        raise RuntimeError(f"no C compiler: {os.environ.get('CC', 'cc')!r} is not on PATH (set CC)")
    target = _cache_dir() / f"lanes-{_key(cc)}.so"
    if target.exists():
        return target
    fd, tmp = tempfile.mkstemp(prefix=target.stem + ".", suffix=".so", dir=target.parent)
    os.close(fd)
    command = [cc, *FLAGS, "-o", tmp, *(str(HERE / s) for s in SOURCES), "-lm"]
    print(f"building the VIO filter's lock-step C kernel (first run only, ~5 s; cached in {target.parent})",
          file=sys.stderr, flush=True)
    done = subprocess.run(command, capture_output=True, text=True)
    if done.returncode:
        os.unlink(tmp)
        raise RuntimeError(f"{' '.join(command)} failed:\n{done.stderr.strip()}")
    os.replace(tmp, target)
    return target


def library() -> ctypes.CDLL | None:
    """The loaded library, built on the first call of the process; None where it cannot be
    (:func:`unavailable` says why; the first such call says so on stderr)."""
    if "lib" not in _loaded:
        _loaded["lib"], _loaded["why"] = None, None
        if os.environ.get("AVIO_NATIVE", "1") == "0":
            _loaded["why"] = "AVIO_NATIVE=0"
            return None
        try:
            _loaded["lib"] = ctypes.CDLL(str(build()))
        except (RuntimeError, OSError) as err:
            _loaded["why"] = str(err)
            print(f"avio: the filter's lock-step C kernel is not available ({err}); running numba's per-filter "
                  "kernel instead: the same results, slower at large batches. Install a C compiler (or set CC) to "
                  "build it; AVIO_NATIVE=0 chooses the fallback without this message.", file=sys.stderr, flush=True)
    return _loaded["lib"]


def unavailable() -> str | None:
    """Why the C kernel cannot be used in this process, or None."""
    library()
    return _loaded["why"]


def functions(L: int) -> LaneFunctions | None:
    """The C functions for blocks of L filters (L in :data:`BLOCK_SIZES`), or None (:func:`unavailable`)."""
    lib = library()
    if lib is None:
        return None
    if L not in BLOCK_SIZES:
        raise ValueError(f"block size {L} is not one of {BLOCK_SIZES}")
    found = {}
    for name, nargs in _NARGS.items():
        fn = getattr(lib, f"lanes_{name}_{L}")
        fn.restype, fn.argtypes = None, [_PTR] * nargs
        found[name] = fn
    return LaneFunctions(**found)
