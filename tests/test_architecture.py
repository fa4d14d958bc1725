"""The shape of the tree (docs: DESIGN "Layout"): one-way dependencies, no cycles between
sub-packages, small folders, modules and functions. Read from the source with ``ast``, lazy
imports inside functions included."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("avio", "bench", "optimizers")
MAX_MODULES_PER_FOLDER = 12
MAX_MODULE_LINES = 400
MAX_FUNCTION_LINES = 80


def _modules() -> dict[str, Path]:
    out = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


MODULES = _modules()


def _imports(path: Path, module: str) -> set[str]:
    """Every module ``module`` imports, absolute names (relative imports resolved)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = module.split(".")[: -node.level] if path.name != "__init__.py" else module.split(".")
                base = ".".join(anchor + ([base] if base else []))
            out.add(base)
            out.update(f"{base}.{alias.name}" for alias in node.names if f"{base}.{alias.name}" in MODULES)
    return out


IMPORTS = {module: _imports(path, module) for module, path in MODULES.items()}


def _offenders(prefix: str, forbidden: tuple[str, ...], allowed: tuple[str, ...] = ()) -> list[str]:
    return sorted(f"{m} imports {i}" for m, imps in IMPORTS.items() if m == prefix or m.startswith(prefix + ".")
                  for i in imps if i.split(".")[0] in forbidden or any(i == f or i.startswith(f + ".") for f in forbidden)
                  if not any(i == a or i.startswith(a + ".") for a in allowed))


def test_avio_knows_nothing_of_the_harness_the_optimisers_or_hydra():
    assert _offenders("avio", ("bench", "optimizers", "hydra", "omegaconf")) == []


def test_optimizers_know_nothing_of_vio_or_the_harness():
    assert _offenders("optimizers", ("avio", "bench", "hydra", "omegaconf")) == []


def test_the_report_reads_records_never_the_run_loop():
    assert _offenders("bench.report", ("bench.run",)) == []


def _component(module: str) -> str:
    """The sub-package a module belongs to (``avio.filter``), or the module itself at a package's top."""
    parts = module.split(".")
    if len(parts) >= 2 and (ROOT / parts[0] / parts[1]).is_dir():
        return ".".join(parts[:2])
    return module


def _cycles(prefix: str) -> list[list[str]]:
    graph = defaultdict(set)
    for module, imps in IMPORTS.items():
        if not module.startswith(prefix):
            continue
        for imported in imps:
            if imported in MODULES and imported.startswith(prefix):
                a, b = _component(module), _component(imported)
                if a != b and a != prefix and b != prefix:
                    graph[a].add(b)
    cycles, state = [], {}

    def visit(node, path):
        state[node] = "open"
        for nxt in sorted(graph[node]):
            if state.get(nxt) == "open":
                cycles.append(path[path.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt, path + [nxt])
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    return cycles


@pytest.mark.parametrize("package", ["avio", "bench"])
def test_no_import_cycle_between_sub_packages(package):
    assert _cycles(package) == []


def test_the_cycle_check_finds_a_planted_cycle(monkeypatch):
    planted = dict(IMPORTS)
    planted["avio.sim.simulator"] = IMPORTS["avio.sim.simulator"] | {"avio.filter.batch"}
    planted["avio.filter.batch"] = IMPORTS["avio.filter.batch"] | {"avio.sim.camera"}
    monkeypatch.setattr(__import__(__name__), "IMPORTS", planted)
    assert any({"avio.sim", "avio.filter"} <= set(cycle) for cycle in _cycles("avio"))


def test_no_folder_holds_more_than_twelve_modules():
    folders = defaultdict(list)
    for path in MODULES.values():
        if path.name not in ("__init__.py", "__main__.py"):
            folders[path.parent.relative_to(ROOT).as_posix()].append(path.name)
    assert {f: len(m) for f, m in folders.items() if len(m) > MAX_MODULES_PER_FOLDER} == {}


def test_no_study_folder_holds_more_than_twelve_scripts():
    # studies/ holds scripts, not a package, so MODULES leaves it out; the same limit holds there
    folders = {f.relative_to(ROOT).as_posix(): len(list(f.glob("*.py"))) for f in (ROOT / "studies").iterdir()
               if f.is_dir() and not f.name.startswith((".", "_"))}
    assert folders and {f: n for f, n in folders.items() if n > MAX_MODULES_PER_FOLDER} == {}


def test_no_module_over_400_lines():
    long = {m: n for m, p in MODULES.items() if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert long == {}


def _compiled(node: ast.FunctionDef) -> bool:
    return any("jit" in ast.unparse(d) for d in node.decorator_list)


def test_no_function_over_80_lines_outside_the_compiled_kernels():
    long = []
    for module, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and not _compiled(node):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long.append(f"{module}.{node.name}: {n} lines")
    assert long == []
