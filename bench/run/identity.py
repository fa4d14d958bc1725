"""A job's identity: the hashes of its resolved config, its data and the code that asks and
scores points (``job.json``), and why a folder's identity is not this job's.

The code hash covers the source files that decide what the optimiser asks and what the problem
returns (:func:`code_version`), named by their path in the repository: moving a file changes it,
so records made before a move are refused on resume with the reason; their reports still build
(``python -m bench.report DIR`` reads records, not code)."""

from __future__ import annotations

import functools
import hashlib
import inspect
import json
import sys
from pathlib import Path

from bench.problems.base import Problem
from bench.provenance import provenance

SCHEMA = 2



ROOT = Path(__file__).resolve().parents[2]  # the repository



_SITE = Path(sys.prefix).resolve()



def _hash(payload) -> str:
    text = json.dumps(payload, sort_keys=True, default=str, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]



def config_hash(identity: dict) -> str:
    """Short stable hash of the resolved job config (``identity``)."""
    return _hash(identity)



def job_key(identity: dict) -> str:
    """Short stable hash of a job's config alone (kept for scripts; records key on ``job_header``)."""
    return config_hash(identity)



@functools.lru_cache(maxsize=64)
def _file_digest(path: str, mtime_ns: int, size: int) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()



def _code_files(classes) -> set[Path]:
    """The source files of ``classes`` (their whole MRO) and of every module of this repository they
    import, transitively (module globals that are modules or objects defined in one)."""
    files: set[Path] = set()
    seen: set[str] = set()
    stack = [sys.modules.get(c.__module__) for cls in classes for c in inspect.getmro(cls) if c is not object]
    first = {id(m) for m in stack}
    while stack:
        module = stack.pop()
        if module is None or module.__name__ in seen:
            continue
        seen.add(module.__name__)
        path = Path(getattr(module, "__file__", None) or "").resolve() if getattr(module, "__file__", None) else None
        if path is None or path.suffix != ".py":
            continue
        ours = path.is_relative_to(ROOT) and not path.is_relative_to(_SITE)
        if not ours and id(module) not in first:  # a library: its version is in the record's provenance
            continue
        files.add(path)
        for value in vars(module).values():
            name = value.__name__ if inspect.ismodule(value) else getattr(value, "__module__", None)
            if isinstance(name, str) and name in sys.modules:
                stack.append(sys.modules[name])
    return files



def code_version(*classes: type) -> dict:
    """``{"sources": hash, "git_commit": ...}``. The hash covers the code that decides what the
    optimiser asks and what the problem returns: the files defining ``classes`` and every module of
    this repository they import (``_code_files``); so an edit elsewhere (the report, the README, an
    unused module) does not block a resume. Data a problem builds lazily is covered by its
    ``identity``. The commit is informative only."""
    digest = hashlib.sha256()
    for path in sorted(_code_files(classes)):
        st = path.stat()
        rel = path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else path.name
        digest.update(f"{rel}\0{_file_digest(str(path), st.st_mtime_ns, st.st_size)}\n".encode())
    return {"sources": digest.hexdigest()[:16], "git_commit": provenance()["git_commit"]}



def job_header(identity: dict, problem: Problem, optimizer_class: type | None = None) -> dict:
    """What ``job.json`` holds: schema, job_key, config_hash, identity (the resolved config),
    data (``problem.identity``), code (``code_version`` of the problem's and optimiser's classes)."""
    classes = [type(problem)] + ([optimizer_class] if optimizer_class is not None else [])
    header = {"schema": SCHEMA, "config_hash": config_hash(identity), "identity": identity,
              "data": problem.identity, "code": code_version(*classes)}
    header["job_key"] = _hash([header["config_hash"], header["data"], header["code"]["sources"]])
    return json.loads(json.dumps(header, default=str))  # as it reads back from disk



def _canonical(value) -> str:
    return json.dumps(value, sort_keys=True, default=str)



def _flatten(node, prefix: str = "") -> dict:
    if isinstance(node, dict):
        out = {}
        for key, value in node.items():
            out.update(_flatten(value, f"{prefix}.{key}" if prefix else str(key)))
        return out or {prefix: {}}
    if isinstance(node, list) and node and all(isinstance(item, dict) for item in node):
        # e.g. a problem's drives: name the one that differs, not the whole list
        out = {}
        for i, item in enumerate(node):
            out.update(_flatten(item, f"{prefix}[{i}]"))
        return out
    return {prefix: node}



def identity_differences(old: dict, new: dict, limit: int = 6) -> str:
    """``key: old -> new`` for the settings that differ between two identities (at most ``limit``)."""
    a, b = _flatten(old), _flatten(new)
    keys = sorted(k for k in set(a) | set(b) if a.get(k, "<unset>") != b.get(k, "<unset>"))
    parts = [f"{k}: {a.get(k, '<unset>')!r} -> {b.get(k, '<unset>')!r}" for k in keys[:limit]]
    return ", ".join(parts) + (f" (+{len(keys) - limit} more)" if len(keys) > limit else "")



def header_mismatch(old: dict, new: dict) -> str | None:
    """Why a folder's ``job.json`` (old) is not this job (new), or None when it is."""
    if old.get("config_hash") != new["config_hash"]:
        return "its config differs: " + (identity_differences(old.get("identity") or {}, new["identity"])
                                         or f"hash {old.get('config_hash')} != {new['config_hash']}")
    if _canonical(old.get("data")) != _canonical(new["data"]):  # as text: NaN != NaN in a dict compare
        return f"its data differ: {identity_differences(old.get('data') or {}, new['data'])}"
    if (old.get("code") or {}).get("sources") != new["code"]["sources"]:
        return (f"the code that asks and scores points changed (sources {(old.get('code') or {}).get('sources')} "
                f"at {(old.get('code') or {}).get('git_commit')} -> {new['code']['sources']} at "
                f"{new['code']['git_commit']}; a job made by other code, e.g. before the package move of 0.2.0, is "
                f"not resumed in place, and its report still builds from its records: python -m bench.report DIR)")
    return None
