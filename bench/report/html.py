"""``report.html``: the whole report as one self-contained page.

Every figure is embedded as base64 PNG data, the style sheet and the few lines of script are
inline; the page loads nothing from the network or the disk. Tables sort by a click on their
header. On load, the script writes into ``<div id="check">`` how many images decoded and which
sections are present (``data-images-loaded``, ``data-images-total``, ``data-sections``), which a
headless browser's ``--dump-dom`` reveals (``tests/bench/report/test_report_vio.py``).

Same inputs, same bytes: nothing here depends on the time, the machine or the folder.
"""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

import jinja2
import pandas as pd

from bench.report.paired import ERROR_ROPES

# (id, title) of every section, in page order; the browser test checks each is present
SECTIONS = (
    ("verdict", "Verdict"),
    ("leaderboard", "Leaderboard"),
    ("anytime", "Anytime performance"),
    ("calibration-errors", "Calibration errors"),
    ("statistics", "Paired comparisons"),
    ("targets", "Fixed targets, ERT and ECDF"),
    ("paper-tables", "The paper's tables beside ours"),
    ("figures", "Figures"),
    ("failed", "Failed runs"),
    ("provenance", "Provenance"),
    ("definitions", "Definitions"),
)

_STYLE = """
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;margin:0 auto;max-width:1400px;padding:0 1.2em 3em;
color:#1b1b1b;line-height:1.4}
nav{position:sticky;top:0;background:#fff;border-bottom:1px solid #ccc;padding:.4em 0;z-index:2;font-size:.9em}
nav a{margin-right:1em;text-decoration:none;color:#0b57d0}
h1{margin-top:.6em}h2{border-bottom:2px solid #ddd;padding-bottom:.2em;margin-top:2em}h3{margin-top:1.4em}
table{border-collapse:collapse;font-size:.82em;margin:.5em 0 1em;display:block;overflow-x:auto;max-width:100%}
th,td{border:1px solid #ddd;padding:.25em .5em;text-align:right;white-space:nowrap}
th{background:#f3f3f3;cursor:pointer;position:sticky;top:0}th:hover{background:#e3e9f7}
td:first-child,th:first-child{text-align:left}tbody tr:nth-child(even){background:#fafafa}
th.asc::after{content:" \\25B2"}th.desc::after{content:" \\25BC"}
figure{margin:1em 0}figure img{max-width:100%;height:auto;border:1px solid #eee}
figcaption{font-size:.85em;color:#555}.note{color:#555;font-size:.9em}.label{font-weight:600}
code{background:#f4f4f4;padding:0 .2em}#check{font-size:.8em;color:#777;margin-top:2em}
.box{border:2px solid #0b57d0;border-radius:6px;padding:.2em 1em;margin:1em 0;background:#f6f9ff}
.box li{margin:.25em 0}.pair{display:flex;flex-wrap:wrap;gap:1em}.pair figure{flex:1 1 560px}
details{margin:.6em 0}summary{cursor:pointer;font-weight:600}
"""

# Sort a table by a header click (numbers numerically, text alphabetically; click again to
# reverse), and report which images decoded and which sections exist.
_SCRIPT = """
document.querySelectorAll("table.sortable th").forEach(function(th){
  th.addEventListener("click",function(){
    var table=th.closest("table"),body=table.tBodies[0],i=Array.prototype.indexOf.call(th.parentNode.children,th);
    var asc=!th.classList.contains("asc");
    table.querySelectorAll("th").forEach(function(h){h.classList.remove("asc","desc");});
    th.classList.add(asc?"asc":"desc");
    var rows=Array.prototype.slice.call(body.rows);
    rows.sort(function(a,b){
      var x=a.cells[i].textContent.trim(),y=b.cells[i].textContent.trim(),nx=parseFloat(x),ny=parseFloat(y);
      var c=(!isNaN(nx)&&!isNaN(ny))?nx-ny:x.localeCompare(y);return asc?c:-c;});
    rows.forEach(function(r){body.appendChild(r);});
  });
});
window.addEventListener("load",function(){
  var imgs=document.images,ok=0;
  for(var k=0;k<imgs.length;k++){if(imgs[k].complete&&imgs[k].naturalWidth>0){ok++;}}
  var ids=[];document.querySelectorAll("section[id]").forEach(function(s){ids.push(s.id);});
  var check=document.getElementById("check");
  check.setAttribute("data-images-loaded",ok);check.setAttribute("data-images-total",imgs.length);
  check.setAttribute("data-svgs",document.querySelectorAll("svg").length);
  check.setAttribute("data-sections",ids.join(","));
  check.textContent="page check: "+ok+" of "+imgs.length+" figures loaded; sections: "+ids.join(", ");
});
"""

_TEMPLATE = jinja2.Environment(autoescape=True, undefined=jinja2.StrictUndefined).from_string("""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{{ title }}</title>
<style>{{ style | safe }}</style>
</head>
<body>
<nav>{% for id, name in sections %}<a href="#{{ id }}">{{ name }}</a>{% endfor %}</nav>
<h1>{{ title }}</h1>
{% for id, name in sections %}
<section id="{{ id }}">
<h2>{{ name }}</h2>
{{ bodies[id] | safe }}
</section>
{% endfor %}
<div id="check">page check: script did not run</div>
<script>{{ script | safe }}</script>
</body>
</html>
""")


def table_html(frame: pd.DataFrame, index: bool = False) -> str:
    """A sortable HTML table of ``frame`` (floats to 4 significant digits), or a "(none)" note."""
    if frame is None or frame.empty:
        return '<p class="note">(none)</p>'
    return frame.to_html(index=index, classes="sortable", border=0, na_rep="",
                         float_format=lambda v: f"{v:.4g}", escape=True)


def figure_html(png: Path, caption: str) -> str:
    """The PNG at ``png`` embedded as data, with a caption (and the file's name, for papers)."""
    data = base64.b64encode(Path(png).read_bytes()).decode("ascii")
    return (f'<figure><img alt="{html.escape(caption)}" src="data:image/png;base64,{data}">'
            f'<figcaption>{html.escape(caption)} <code>{html.escape(Path(png).name)}</code> '
            + ("(PDF beside it)" if Path(png).with_suffix(".pdf").exists() else "") + "</figcaption></figure>")


def paragraph(text: str, cls: str | None = None) -> str:
    """``text`` as a paragraph; `code` spans and **bold** from the Markdown report are kept."""
    body = inline(text)
    return f'<p class="{cls}">{body}</p>' if cls else f"<p>{body}</p>"


def inline(text: str) -> str:
    # The report's prose uses only `code` and **bold**: two substitutions, no Markdown library.
    body = html.escape(text)
    body = re.sub(r"`([^`]+)`", r"<code>\1</code>", body)
    return re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", body)


def bullets(markdown_list: str) -> str:
    """A Markdown bullet list (``- item`` lines, continuation lines indented) as <ul>."""
    items, current = [], []
    for line in markdown_list.splitlines():
        if line.startswith("- "):
            if current:
                items.append(" ".join(current))
            current = [line[2:].strip()]
        elif line.strip() and current:
            current.append(line.strip())
    if current:
        items.append(" ".join(current))
    return "<ul>" + "".join(f"<li>{inline(i)}</li>" for i in items) + "</ul>"


def render(title: str, bodies: dict[str, str]) -> str:
    """The page: ``bodies`` maps every section id of ``SECTIONS`` to its HTML."""
    missing = [s for s, _ in SECTIONS if s not in bodies]
    if missing:
        raise ValueError(f"report.html: no content for section(s) {missing}")
    return _TEMPLATE.render(title=title, style=_STYLE, script=_SCRIPT, sections=SECTIONS, bodies=bodies)


# --- the report's sections ------------------------------------------------------------------

def _problems(runs: pd.DataFrame) -> list[str]:
    return sorted(runs["problem"].unique())


def _sweep_commands(roots: list[Path]) -> list[str]:
    """The sweep command of each root that holds Hydra's ``multirun.yaml`` (its task overrides)."""
    import yaml

    commands = []
    for root in roots:
        path = Path(root) / "multirun.yaml"
        if not path.is_file():
            continue
        try:
            overrides = (yaml.safe_load(path.read_text()) or {}).get("hydra", {}).get("overrides", {}).get("task", [])
        except yaml.YAMLError:
            continue
        commands.append("python -m bench " + " ".join(str(o) for o in overrides))
    return commands


def _distinct(records: pd.DataFrame, column: str) -> list[str]:
    if column not in records.columns:
        return []
    return sorted({str(v) for v in records[column].dropna()})


def provenance_html(roots: list[Path], records: pd.DataFrame) -> str:
    """Command, commit, versions and machine, as the records state them (not this machine)."""
    parts = []
    commands = _sweep_commands(roots)
    rebuild = "python -m bench.report " + " ".join(Path(r).name for r in roots)
    parts.append("<h3>Commands</h3><ul>" + "".join(f"<li>sweep: <code>{html.escape(c)}</code></li>" for c in commands)
                 + f"<li>this report: <code>{html.escape(rebuild)}</code> (from the folder holding it)</li></ul>")
    commits = _distinct(records, "git_commit")
    listed = ", ".join(f"<code>{html.escape(c)}</code>" for c in commits) or "unknown"
    parts.append(f"<h3>Code</h3><p>git commit(s) of the records: {listed}</p>")
    if {"started_utc", "ended_utc"} <= set(records.columns):
        start, end = records["started_utc"].dropna().astype(str), records["ended_utc"].dropna().astype(str)
        if len(start) and len(end):
            parts.append(f"<p>jobs ran from {html.escape(start.min())} to {html.escape(end.max())} (UTC)</p>")
    version_cols = sorted(c for c in records.columns if c.startswith("versions."))
    if version_cols:
        rows = [(c[len("versions."):], ", ".join(_distinct(records, c))) for c in version_cols]
        versions = pd.DataFrame(rows, columns=["package", "version(s) in the records"])
        parts.append("<h3>Versions</h3>" + table_html(versions))
    machine_cols = sorted(c for c in records.columns if c.startswith("machine."))
    if machine_cols:
        rows = [(c[len("machine."):], ", ".join(_distinct(records, c))) for c in machine_cols]
        parts.append("<h3>Machine</h3>" + table_html(pd.DataFrame(rows, columns=["field", "value(s) in the records"])))
    return "".join(parts)


def _tables_by_stem(paths: list[Path]) -> dict[str, list[Path]]:
    out: dict[str, list[Path]] = {}
    for path in paths:
        if path.suffix == ".csv" and path.parent.name != "figures":
            out.setdefault(path.stem, []).append(path)
    return out


def _paper_table(path: Path, index: bool) -> str:
    caption_file = path.with_suffix(".md")
    caption = caption_file.read_text().split("\n\n", 1)[0] if caption_file.exists() else path.stem
    frame = pd.read_csv(path, index_col=0 if index else None)
    return paragraph(caption, "label") + table_html(frame, index=index)


def collapsed(summary: str, body: str) -> str:
    """``body`` folded under a one-line ``summary`` (long tables and figure grids)."""
    return f"<details><summary>{html.escape(summary)}</summary>{body}</details>"


def calibration_table(runs: pd.DataFrame, problem: str) -> pd.DataFrame:
    """Median calibration errors per optimiser of one problem, the reference calibration's as a
    row (from ``ref.<error>``), from the runs' final best points; empty without truth."""
    rows = runs[(runs["problem"] == problem) & runs["valid"]]
    errors = [f"m.{e}" for e in ERROR_ROPES if f"m.{e}" in rows.columns and rows[f"m.{e}"].notna().any()]
    if not errors:
        return pd.DataFrame()
    table = rows.groupby("optimizer")[errors].median().rename(columns=lambda c: c[2:]).reset_index()
    ref = {c[2:]: rows[f"ref.{c[2:]}"].median() for c in errors if f"ref.{c[2:]}" in rows.columns}
    if ref:
        table = pd.concat([table, pd.DataFrame([{"optimizer": "reference", **ref}])], ignore_index=True)
    return table


def _figure(fig: dict, name: str, caption: str) -> str:
    return figure_html(fig[name], caption) if name in fig else ""


def build_page(*, roots, records, runs, box, pages, board, avg, comparisons, ert, targets, figures, tables,
               definitions: str) -> str:
    """The HTML of report.html from the report's frames and files (see ``bench.report``)."""
    problems = _problems(runs)
    n_failed = int((~runs["valid"]).sum())
    bodies = {}
    verdict = [paragraph(
        f"{len(runs)} job records: {len(problems)} problem(s) ({', '.join(problems)}), "
        f"{runs['optimizer'].nunique()} optimiser(s), {n_failed} failed or without result. Every sentence "
        "below is generated from the numbers in the CSV files beside this page.", "note")]
    lead, stats, targ, anytime, calerr = [], [], [], [], []
    for problem in problems:
        fig = figures[problem]
        items = "".join(f"<li>{inline(s)}</li>" for s in box.get(problem, []))
        verdict.append(f'<div class="box"><h3>{html.escape(problem)}</h3><ul>{items}</ul></div>'
                       + '<div class="pair">' + _figure(fig, "cd", f"{problem}: critical-difference diagram "
                       "(mean ranks; a bar joins rows closer than the CD)")
                       + _figure(fig, "final", f"{problem}: final best f per optimiser and the reference")
                       + "</div>")
        lead.append(f"<h3>{html.escape(problem)}</h3>" + paragraph(
            "Ten columns; every column of every row is in leaderboard.csv. Verdicts are paired on instances "
            "against the leader (and against the reference calibration).", "note") + table_html(pages[problem]))
        comp = comparisons[comparisons["problem"] == problem] if len(comparisons) else comparisons
        stats.append(collapsed(f"{problem}: {len(comp)} paired comparisons (all questions)",
                               table_html(comp.drop(columns="problem") if len(comp) else comp)))
        targ.append(collapsed(f"{problem}: fixed targets, ERT and the runtime ECDF",
                              table_html(targets[targets["problem"] == problem].drop(columns="problem"))
                              + table_html(ert[ert["problem"] == problem][["optimizer", "target", "n_runs", "n_hit",
                                                                           "success_rate", "ert_evals",
                                                                           "ert_seconds"]])
                              + figure_html(fig["ecdf"], f"{problem}: runtime ECDF over all fixed targets")))
        anytime.append(figure_html(fig["anytime"], f"{problem}: best-so-far objective, median and IQR over runs"))
        cal = calibration_table(runs, problem)
        if not cal.empty:
            calerr.append(f"<h3>{html.escape(problem)}: calibration errors of the final best points</h3>"
                          + paragraph("median over valid runs; the reference calibration's own errors as a row",
                                      "note") + table_html(cal)
                          + _figure(fig, "scatter", f"{problem}: objective against calibration error"))
    bodies["verdict"] = "".join(verdict) + "<h3>Average rank over problems</h3>" + table_html(avg)
    bodies["leaderboard"] = "".join(lead)
    bodies["statistics"] = "".join(stats)
    bodies["targets"] = "".join(targ)
    bodies["anytime"] = "".join(anytime)
    paths, note = tables
    paths = [Path(p) for p in paths]
    by_stem = _tables_by_stem(paths)
    paper = [paragraph(note, "note")] if note else []
    for stem in ("table1", "table2", "table3"):
        for path in by_stem.get(stem, []):
            paper.append(_paper_table(path, index=(stem == "table1")))
    bodies["paper-tables"] = "".join(paper) or paragraph("(none)", "note")
    for path in by_stem.get("table1_errors", []):
        calerr.insert(0, _paper_table(path, index=True))
    bodies["calibration-errors"] = "".join(calerr) or paragraph("No calibration errors: the truth is unknown.", "note")

    figs = []
    pngs = [p for p in paths if p.suffix == ".png"]
    for prefix, caption in (("trajectories_", "top-down trajectories coloured by position error"),
                            ("errors_", "errors over time"), ("profile", "objective profile"),
                            ("convergence_", "best-so-far calibration per seed")):
        for png in (p for p in pngs if p.name.startswith(prefix)):
            figs.append(figure_html(png, caption))
    bodies["figures"] = (collapsed(f"{len(figs)} figures of the paper's tables", "".join(figs)) if figs
                         else paragraph(note or "(no figures)", "note"))

    failed = runs[~runs["valid"]][["job", "problem", "optimizer", "seed", "status", "error_type", "error_message"]]
    bodies["failed"] = paragraph("Counted in n_failed, excluded from tests and medians, included in ERT and ECDF "
                                 "as unsuccessful with what they spent.", "note") + table_html(failed)
    bodies["provenance"] = provenance_html(roots, records)
    bodies["definitions"] = bullets(definitions)
    return render("Benchmark report", bodies)
