"""The report: complete, rebuilt byte for byte from the same records, and clear about bad input."""

import importlib.machinery
import json
import re
import shutil
import subprocess
import sys
import types
from pathlib import Path

import pandas as pd
import pytest
from record_factory import write_job

from bench.report.__main__ import main
from bench.report.build import ReportError, build_report

OUTPUTS = ["leaderboard.csv", "runs.csv", "verdicts.csv", "friedman.csv", "ranks.csv",
           "targets.csv", "ert.csv", "ecdf.csv", "curves.csv", "report.md", "report.html"]


def make_runs(root: Path) -> Path:
    for seed in range(3):
        for optimizer, scale in (("pso", 1.0), ("cmaes", 0.5)):
            write_job(root, "vio/drive 27", optimizer, seed,
                      [[scale * (9 - seed), 8.0], [scale * (2 + seed)], [scale * (1 + seed / 3)]],
                      t_batches=[0.5, 1.0 + seed, 2.0 + seed], f_truth=1.0, f_reference=4.0,
                      metrics_batches=[{"rotation_error_deg": [2.0, 1.0]}, {"rotation_error_deg": [0.3]},
                                       {"rotation_error_deg": [0.05 * (seed + 1)]}])
        write_job(root, "sphere", "pso", seed, [[3.0 - seed, 2.0], [0.1 * seed]], f_truth=0.0, f_reference=10.0)
    write_job(root, "sphere", "cmaes", 0, [[5.0]], status="failed")
    return root


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    root = make_runs(tmp_path_factory.mktemp("sweep") / "sweep")
    first = build_report([root], paper_tables=False)
    copy = tmp_path_factory.mktemp("elsewhere") / "sweep"
    shutil.copytree(root, copy, ignore=shutil.ignore_patterns("report"))
    second = build_report([copy], tmp_path_factory.mktemp("out2") / "rep", paper_tables=False)
    return root, first, second


def test_default_output_is_the_first_dir_report_folder_with_every_file(built):
    root, first, _ = built
    assert first == root / "report" / "report.md"
    for name in OUTPUTS:
        assert (first.parent / name).stat().st_size > 0, name
    text = first.read_text()
    for link in ("figures/anytime_vio_drive_27.png", "figures/ecdf_sphere.png"):
        assert f"({link})" in text and (first.parent / link).exists()
    assert "## Paper tables (Tables 1–3)" in text and "## Failed runs" in text


def test_rebuild_from_the_same_records_is_byte_identical(built):
    _, first, second = built
    for name in OUTPUTS + ["figures/anytime_sphere.png", "figures/ecdf_vio_drive_27.png", "figures/cd_sphere.png",
                           "figures/final_sphere.png", "figures/scatter_vio_drive_27.png"]:
        assert (first.parent / name).read_bytes() == (second.parent / name).read_bytes(), name


def test_report_names_failed_runs_and_keeps_them_in_the_counts(built):
    _, first, _ = built
    text = first.read_text()
    assert "sweep/sphere/cmaes/seed0" in text and "RuntimeError" in text
    board = (first.parent / "leaderboard.csv").read_text().splitlines()
    sphere_cmaes = next(line for line in board if line.startswith("sphere,cmaes,"))
    assert sphere_cmaes.split(",")[3:5] == ["1", "1"]  # n_runs, n_failed


def test_missing_dir_exits_2_with_one_clear_message(tmp_path, capsys):
    assert main([str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err
    assert "nope: no such file or folder" in err and "Traceback" not in err


def test_folder_without_records_exits_2(tmp_path, capsys):
    assert main([str(tmp_path)]) == 2
    assert "no job records" in capsys.readouterr().err


def test_corrupt_record_exits_2_naming_the_file(tmp_path, capsys):
    job = write_job(tmp_path, "p", "a", 0, [[1.0]])
    (job / "record.json").write_text('{"status": "ok", ')
    assert main([str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "record.json: corrupt record" in err and err.count("\n") == 1


def test_record_that_is_not_an_object_or_lacks_fields_exits_2(tmp_path, capsys):
    job = write_job(tmp_path, "p", "a", 0, [[1.0]])
    (job / "record.json").write_text("[1, 2]")
    assert main([str(tmp_path)]) == 2
    assert "not a JSON object" in capsys.readouterr().err
    (job / "record.json").write_text(json.dumps({"status": "ok", "problem": "p", "seed": 0}))
    assert main([str(tmp_path)]) == 2
    assert "missing the field 'optimizer'" in capsys.readouterr().err


def test_corrupt_eval_log_exits_2_naming_the_line(tmp_path, capsys):
    job = write_job(tmp_path, "p", "a", 0, [[1.0], [0.5]])
    lines = (job / "evals.jsonl").read_text().splitlines()
    (job / "evals.jsonl").write_text(lines[0] + "\n{oops\n")
    assert main([str(tmp_path)]) == 2
    assert "evals.jsonl:2: not a JSON line" in capsys.readouterr().err


def test_build_report_rejects_an_empty_list():
    with pytest.raises(ReportError):
        build_report([])


@pytest.mark.slow  # two interpreter start-ups importing scipy, pandas and matplotlib
def test_module_entry_point_runs_as_documented(built, tmp_path):
    root, _, _ = built
    done = subprocess.run([sys.executable, "-m", "bench.report", str(root), "--out", str(tmp_path / "r"),
                           "--family", "all", "--no-tables"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert Path(done.stdout.strip()) == tmp_path / "r" / "report.md"
    verdicts = pd.read_csv(tmp_path / "r" / "verdicts.csv")
    # all pairs of pso, cmaes and the reference on the objective of each problem
    assert (verdicts.query("question == 'best_f' and family == 'posthoc'")["family_size"] == 3).all()
    bad = subprocess.run([sys.executable, "-m", "bench.report", str(tmp_path / "missing")],
                         capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr


def test_a_problem_where_every_run_failed_still_reports(tmp_path):
    write_job(tmp_path, "p", "a", 0, [], status="failed")
    write_job(tmp_path, "p", "b", 0, [[1.0]], status="failed")
    write_job(tmp_path, "q", "b", 0, [[1.0], [0.5]])
    report = build_report([tmp_path], tmp_path / "out", paper_tables=False)
    board = pd.read_csv(report.parent / "leaderboard.csv").set_index(["problem", "optimizer"])
    assert board.loc[("p", "a"), ["rank", "n_runs", "n_failed"]].tolist() == [1.5, 1, 1]
    assert board.loc[("p", "a"), "verdict"] == "untestable"  # no valid run: it leads nothing
    assert board.loc[("q", "b"), ["best_f_median", "verdict"]].tolist() == [0.5, "leader"]
    assert (report.parent / "figures" / "ecdf_p.png").exists()


def fake_tables_module(fail: bool) -> types.ModuleType:
    """A stand-in for bench/report/paper/tables.py honouring the hook's contract (build_tables, TablesError)."""
    module = types.ModuleType("bench.report.paper.tables")
    module.__spec__ = importlib.machinery.ModuleSpec("bench.report.paper.tables", None)

    class TablesError(ValueError):
        pass

    def build_tables(dirs, out, **options):
        if fail:
            raise TablesError("no VIO problem among the finished jobs")
        out.mkdir(parents=True)
        (out / "table1.md").write_text("| var | value |\n|---|---|\n| fx | 718.9 |\n")
        (out / "table1.csv").write_text("var,value\nfx,718.9\n")
        return [out / "table1.csv", out / "table1.md"]

    module.TablesError, module.build_tables = TablesError, build_tables
    return module


def test_paper_tables_hook_links_and_includes_the_tables(tmp_path, monkeypatch):
    write_job(tmp_path / "runs", "p", "a", 0, [[1.0]])
    monkeypatch.setitem(sys.modules, "bench.report.paper.tables", fake_tables_module(fail=False))
    text = build_report([tmp_path / "runs"], tmp_path / "out").read_text()
    assert "- [tables/table1.csv](tables/table1.csv)" in text and "| fx | 718.9 |" in text
    monkeypatch.setitem(sys.modules, "bench.report.paper.tables", fake_tables_module(fail=True))
    text = build_report([tmp_path / "runs"], tmp_path / "out2").read_text()
    assert "_Not built: no VIO problem among the finished jobs._" in text


@pytest.mark.parametrize("alpha", ["2", "0", "-0.1", "1", "nan", "abc"])
def test_alpha_outside_0_1_exits_2_with_one_message(built, alpha, capsys):
    root, _, _ = built
    assert main([str(root), "--alpha", alpha, "--no-tables", "--out", str(root / "never")]) == 2
    err = capsys.readouterr().err
    assert "verdict.alpha must be" in err and err.count("\n") == 1 and "Traceback" not in err
    assert not (root / "never").exists()  # refused before any work


def test_html_page_is_self_contained_with_every_section_and_figure(built):
    from bench.report.html import SECTIONS

    _, first, _ = built
    page = (first.parent / "report.html").read_text()
    for section, _ in SECTIONS:
        assert f'<section id="{section}">' in page, section
    # every figure embedded as data; nothing fetched from anywhere
    # anytime, ECDF, final values and CD diagram of both problems; the scatter where the truth is known
    assert page.count('src="data:image/png;base64,') == 9
    assert not re.search(r'(src|href)="(?!data:|#)', page)
    assert "http://" not in page and "https://" not in page
    assert 'class="dataframe sortable"' in page and "sweep/sphere/cmaes/seed0" in page


def test_figures_are_150_dpi_with_a_pdf_beside_and_redrawn_only_when_their_data_change(built, tmp_path):
    from PIL import Image

    _, first, _ = built
    png = first.parent / "figures" / "anytime_sphere.png"
    with Image.open(png) as image:
        assert round(image.info["dpi"][0]) == 150
    assert png.with_suffix(".pdf").read_bytes().startswith(b"%PDF")
    # a figure whose stored key no longer matches its data is redrawn (same bytes as a fresh one)
    copy = tmp_path / "sweep"
    shutil.copytree(first.parent.parent, copy)
    stale = copy / "report" / "figures" / "anytime_sphere.png"
    stale.write_bytes(b"not a png")
    build_report([copy], paper_tables=False, log=None)
    assert stale.read_bytes() == png.read_bytes()
