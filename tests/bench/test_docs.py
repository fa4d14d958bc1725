"""The front door and the docs site: a short README whose links resolve, a docs site that builds
with warnings as errors, a reference that lists what the code registers, guides whose examples are
the shipped files."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

import optimizers
from bench import problems

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"


def test_the_readme_is_a_front_page_of_at_most_200_lines():
    assert len((ROOT / "README.md").read_text().splitlines()) <= 200


def _relative_links(markdown: str) -> list[str]:
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", markdown)
    return [link for link in links if not re.match(r"^[a-z]+:", link)]


def test_every_link_of_the_readme_resolves():
    readme = (ROOT / "README.md").read_text()
    links = _relative_links(readme)
    assert "docs/guide/running.md" in links and "docs/guide/adding-an-optimiser.md" in links
    assert [link for link in links if not (ROOT / link).exists()] == []


def test_the_link_check_finds_a_broken_link():
    assert _relative_links("see [x](docs/nowhere.md) and [y](https://example.org)") == ["docs/nowhere.md"]


@pytest.mark.slow
def test_the_docs_site_builds_with_warnings_as_errors(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(tmp_path / "site")],
                          cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={**__import__("os").environ, "NO_MKDOCS_2_WARNING": "1"})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert (tmp_path / "site" / "model" / "index.html").is_file()


def _keys(node: dict, prefix: str = "") -> list[str]:
    out = []
    for key, value in node.items():
        name = f"{prefix}{key}"
        out += _keys(value, name + ".") if isinstance(value, dict) and value else [name]
    return out


def test_the_options_reference_lists_every_key_of_the_config():
    config = yaml.safe_load((ROOT / "bench" / "conf" / "config.yaml").read_text())
    keys = [k for k in _keys({k: v for k, v in config.items() if k not in ("defaults", "hydra")})]
    keys += [d if isinstance(d, str) else next(iter(d)) for d in config["defaults"] if d != "_self_"]
    page = (DOCS / "reference" / "options.md").read_text()
    assert [k for k in keys if f"`{k}`" not in page] == []


def test_the_references_list_every_registered_problem_and_optimiser():
    page = (DOCS / "reference" / "problems.md").read_text()
    assert [p for p in problems.available() if f"`{p}`" not in page] == []
    page = (DOCS / "reference" / "optimizers.md").read_text()
    assert [o for o in optimizers.available() if f"`{o}`" not in page] == []


def test_the_guides_show_the_shipped_files():
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "sync_doc_examples.py"), "--check"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, f"run python scripts/sync_doc_examples.py: {proc.stderr}"


def test_the_settings_reference_is_generated_from_the_shipped_yaml_files():
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "make_reference.py"), "--check"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, f"run python scripts/make_reference.py: {proc.stderr}"


def test_every_setting_a_vio_problem_reads_is_in_the_reference():
    import dataclasses

    page = (DOCS / "reference" / "problems.md").read_text()
    missing = {}
    for name in problems.available():
        params = getattr(problems.get(name), "Params", None)
        if params is not None:
            missing[name] = [f.name for f in dataclasses.fields(params) if f"| `{f.name}` |" not in page]
    assert {k: v for k, v in missing.items() if v} == {}
