"""Render computed tables (:class:`~grip_bench.report.tables.TableData`) to Markdown, CSV,
LaTeX (booktabs) and HTML (self-contained, click-to-sort).

Conventions shared by all formats: ↓ / ↑ after a header say lower / higher is better; the
best value per column (per metric, reference rows excluded, ties included) is bold, and so
is every value the best does not beat on the same sequences (``Cell.tied``); a cell
shows ``mean [lo, hi]`` (95% bootstrap interval, omitted when fewer than 2 sequences) or
``before → after [lo, hi]``; "–" marks a cell without results; NaN counts are footnoted.
A seeded table (results of several training seeds, ``TableData.n_seeds`` > 1) adds the
range of the per-seed means, ``{min–max}``, after a cell of two or more seeds, a verdict
column when it judges rows (``TableData.verdict_header``), and seed columns to its CSV.
The output is a pure function of the inputs (no dates, sorted iteration): rendering twice
gives identical bytes.
"""

from __future__ import annotations

import base64
import csv
import html
import io
import os
import posixpath
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from ..core.constants import BOOTSTRAP_N, BOOTSTRAP_SEED
from ..core.errors import InputError
from ..core.io import atomic_write_text
from ..results.schema import format_float, read_results, read_runtime
from ..results.stats import CI
from .tables import TABLES, Cell, Column, Row, TableData, TableSpec, compute_table

if TYPE_CHECKING:
    from ..core.registry import Registry
    from ..metrics.registry import MetricSpec

FORMATS = ("md", "csv", "tex", "html")
MISSING = "–"
WIDE_TABLE_COLUMNS = 6  # LaTeX: more columns than this use table* (full page width)
_UNITS = {"cm3": "cm³", "m/s2": "m/s²", "m3": "m³"}
_SUPERSCRIPT = str.maketrans("0123456789", "⁰¹²³⁴⁵⁶⁷⁸⁹")


# --- shared text helpers --------------------------------------------------------------------
def display_unit(unit: str | None) -> str:
    """Report unit as printed (``cm3`` -> ``cm³``)."""
    return _UNITS.get(unit or "", unit or "")


def arrow(higher_is_better: bool | None) -> str:
    return "" if higher_is_better is None else ("↑" if higher_is_better else "↓")


def _decorate(name: str, unit: str | None, hib: bool | None) -> str:
    """``MPVPE (mm) ↓``: a name with its unit and direction when they are known."""
    text = name + (f" ({display_unit(unit)})" if unit else "")
    return f"{text} {arrow(hib)}".strip()


def flat_header(col: Column) -> str:
    """One-line header for formats without header groups: ``MPVPE R-Hand (mm) ↓``."""
    return _decorate(f"{col.group} {col.label}".strip(), col.unit, col.higher_is_better)


def section_title(row: Row) -> str:
    return _decorate(row.group or "", row.group_unit, row.group_higher_is_better)


def fmt_num(x: float, decimals: int) -> str:
    text = f"{x:.{decimals}f}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text  # no "-0.00"


def _has_ci(ci: CI | None) -> bool:
    return ci is not None and ci.n >= 2 and not np.isnan(ci.mean)


def _shown(ci: CI | None) -> bool:
    return ci is not None and not np.isnan(ci.mean)


def seed_range(cell: Cell) -> tuple[float, float] | None:
    """(min, max) of a cell's finite per-seed means when it has two or more, else None."""
    m = np.asarray(cell.seed_means, dtype=np.float64)
    m = m[np.isfinite(m)]
    return (float(m.min()), float(m.max())) if len(m) >= 2 else None


def seed_text(cell: Cell) -> str:
    """`` {min–max}`` of a seeded cell's per-seed means (empty for a single seed)."""
    r = seed_range(cell)
    if r is None:
        return ""
    return f" {{{fmt_num(r[0], cell.decimals)}–{fmt_num(r[1], cell.decimals)}}}"


def header_spans(columns: Sequence[Column]) -> list[tuple[Column, int, bool]]:
    """Consecutive columns sharing a group name, as (first column, span, unit_on_group).

    ``unit_on_group`` says whether the unit and arrow go on the group header (all columns
    of the span agree) or on each column's own label (Physics: % ↑ next to mm ↓).
    """
    spans: list[list] = []
    for col in columns:
        if spans and spans[-1][0].group == col.group:
            spans[-1][1].append(col)
        else:
            spans.append([col, [col]])
    out = []
    for first, cols in spans:
        same = len({(c.unit, c.higher_is_better) for c in cols}) == 1
        out.append((first, len(cols), same))
    return out


def group_header(col: Column, unit_on_group: bool) -> str:
    return _decorate(col.group, col.unit, col.higher_is_better) if unit_on_group else col.group


def sub_header(col: Column, unit_on_group: bool) -> str:
    return col.label if unit_on_group else _decorate(col.label, col.unit, col.higher_is_better)


def sections(rows: Sequence[Row]) -> list[tuple[Row | None, list[Row]]]:
    """Rows split where ``group`` changes; the first row of each block names the heading."""
    out: list[tuple[Row | None, list[Row]]] = []
    for row in rows:
        if out and out[-1][1][-1].group == row.group:
            out[-1][1].append(row)
        else:
            out.append((row if row.group else None, [row]))
    return out


def footnotes(data: TableData) -> tuple[dict[tuple[int, int], int], list[str]]:
    """Numbered footnotes for cells with NaN sequences: {(row, col): number}, texts.

    Cells with the same counts share one number (a right-hand-only leaderboard would
    otherwise carry a footnote per cell); the mark on each cell says which count applies.
    """
    marks: dict[tuple[int, int], int] = {}
    texts: list[str] = []
    for i, row in enumerate(data.rows):
        for j, cell in enumerate(row.cells):
            parts = []
            for name, ci in (("", cell.ci), ("before: ", cell.before)):
                if ci is not None and ci.n_nan:
                    parts.append(f"{name}{ci.n_nan} of {ci.n + ci.n_nan} sequences gave NaN "
                                 "and are excluded")
            if parts:
                text = "; ".join(parts) + "."
                if text not in texts:
                    texts.append(text)
                marks[(i, j)] = texts.index(text) + 1
    return marks, texts


# --- Markdown -------------------------------------------------------------------------------
def _md_escape(text: str) -> str:
    return text.replace("|", "\\|")


def _md_cell(cell: Cell, mark: int | None) -> str:
    if not _shown(cell.ci) and not (cell.paired and _shown(cell.before)):
        text = MISSING
    else:
        after = MISSING if not _shown(cell.ci) else fmt_num(cell.ci.mean, cell.decimals)
        if cell.best or cell.tied:
            after = f"**{after}**"
        if cell.paired:
            before = fmt_num(cell.before.mean, cell.decimals) if _shown(cell.before) else MISSING
            after = f"{before} → {after}"
        if _has_ci(cell.ci):
            after += (f" [{fmt_num(cell.ci.lo, cell.decimals)}, "
                      f"{fmt_num(cell.ci.hi, cell.decimals)}]")
        text = after + seed_text(cell)
    return text + (str(mark).translate(_SUPERSCRIPT) if mark else "")


def to_markdown(data: TableData, heading_level: int = 3) -> str:
    """GitHub-flavoured Markdown: one header row, section rows in bold, notes below."""
    marks, notes = footnotes(data)
    verdict = [data.verdict_header] if data.verdict_header else []
    ncol = len(data.columns) + 1 + len(verdict)
    lines = [f"{'#' * heading_level} {_md_escape(data.title)}", "",
             f"`{data.id}` v{data.version}: {_md_escape(data.description)}", "",
             "| " + " | ".join([data.row_header] + [_md_escape(flat_header(c))
                                                   for c in data.columns]
                               + [_md_escape(v) for v in verdict]) + " |",
             "|:--" + "|--:" * (ncol - 1 - len(verdict)) + "|:--" * len(verdict) + "|"]
    for i, row in enumerate(data.rows):
        if row.group and (i == 0 or data.rows[i - 1].group != row.group):
            lines.append(f"| **{_md_escape(section_title(row))}** |" + " |" * (ncol - 1))
        cells = [_md_cell(c, marks.get((i, j))) for j, c in enumerate(row.cells)]
        cells += [_md_escape(row.verdict or MISSING)] if verdict else []
        lines.append("| " + " | ".join([_md_escape(row.label)] + cells) + " |")
    lines.append("")
    lines += [f"{str(k).translate(_SUPERSCRIPT)} {_md_escape(t)}  " for k, t in
              enumerate(notes, 1)]
    lines += [f"- {_md_escape(n)}" for n in data.notes]
    return "\n".join(lines).rstrip() + "\n"


# --- CSV (tidy, one line per cell) ----------------------------------------------------------
CSV_COLUMNS = ("table", "version", "row_group", "row", "reference", "column_group", "column",
               "method", "dataset", "split", "perturbation", "metric", "hand", "unit",
               "higher_is_better", "value", "ci_low", "ci_high", "n", "n_nan",
               "before_method", "before_value", "before_ci_low", "before_ci_high",
               "before_n", "before_n_nan", "best", "best_tied")


def _ci_fields(ci: CI | None) -> list[str]:
    if ci is None:
        return ["", "", "", "0", "0"]
    return [format_float(ci.mean), format_float(ci.lo), format_float(ci.hi), str(ci.n),
            str(ci.n_nan)]


def _bool(v: bool | None) -> str:
    return "" if v is None else ("true" if v else "false")


# appended to CSV_COLUMNS in seeded tables (TableData.n_seeds > 1) only
SEED_CSV_COLUMNS = ("n_seeds", "seed_means", "seed_min", "seed_max", "seed_std", "diff",
                    "diff_ci_low", "diff_ci_high", "diff_n", "seed_spread", "verdict")


def _seed_fields(cell: Cell) -> list[str]:
    """A seeded cell's per-seed means (``;``-joined, first seed first), their min, max and
    std (ddof 1; NaN below two seeds) and, when judged, the difference to the reference row,
    its paired interval, the seed spread and the verdict."""
    m = np.asarray(cell.seed_means, dtype=np.float64)
    fin = m[np.isfinite(m)]
    stats = ["", "", ""] if not len(fin) else [
        format_float(fin.min()), format_float(fin.max()),
        format_float(fin.std(ddof=1) if len(fin) > 1 else np.nan)]
    j = cell.judged
    judged = [""] * 6 if j is None else [
        format_float(j.diff), *(_ci_fields(j.ci)[1:4] if j.ci is not None else ["", "", "0"]),
        format_float(j.spread), j.verdict or ""]
    return [str(len(m)), ";".join(format_float(x) for x in m), *stats, *judged]


def to_csv(data: TableData) -> str:
    """Tidy CSV: one line per cell with full-precision values (shortest round-trip floats);
    a seeded table appends :data:`SEED_CSV_COLUMNS`."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    seeded = data.n_seeds > 1
    w.writerow(CSV_COLUMNS + (SEED_CSV_COLUMNS if seeded else ()))
    for row in data.rows:
        for col, cell in zip(data.columns, row.cells, strict=True):
            f = cell.filters
            before = cell.before if cell.paired else None
            w.writerow([data.id, data.version, row.group or "", row.label, _bool(row.reference),
                        col.group, col.label, f.get("method", ""), f.get("dataset", ""),
                        f.get("split", ""), f.get("perturbation", ""), cell.metric or "",
                        f.get("hand", ""), cell.unit, _bool(cell.higher_is_better),
                        *_ci_fields(cell.ci),
                        (cell.before_method or "") if cell.paired else "",
                        *(_ci_fields(before) if cell.paired else [""] * 5),
                        _bool(cell.best), _bool(cell.tied),
                        *(_seed_fields(cell) if seeded else [])])
    return buf.getvalue()


# --- LaTeX (booktabs) -----------------------------------------------------------------------
_TEX_SPECIAL = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
    "↓": r"$\downarrow$",
    "↑": r"$\uparrow$",
    "→": r"$\rightarrow$",
    "–": "--",
    "<": r"$<$",
    ">": r"$>$",
    "³": r"$^3$",
    "²": r"$^2$",
    "×": r"$\times$",
}


def tex_escape(text: str) -> str:
    """Escape LaTeX specials and map the report's Unicode symbols to math."""
    return "".join(_TEX_SPECIAL.get(ch, ch) for ch in text)


def _tex_cell(cell: Cell, mark: int | None) -> str:
    if not _shown(cell.ci) and not (cell.paired and _shown(cell.before)):
        text = "--"
    else:
        after = fmt_num(cell.ci.mean, cell.decimals) if _shown(cell.ci) else "--"
        if cell.best or cell.tied:
            after = rf"\textbf{{{after}}}"
        if cell.paired:
            before = fmt_num(cell.before.mean, cell.decimals) if _shown(cell.before) else "--"
            after = rf"{before} $\rightarrow$ {after}"
        if _has_ci(cell.ci):
            after += (rf" {{\scriptsize [{fmt_num(cell.ci.lo, cell.decimals)}, "
                      rf"{fmt_num(cell.ci.hi, cell.decimals)}]}}")
        r = seed_range(cell)
        if r is not None:
            after += (rf" {{\scriptsize \{{{fmt_num(r[0], cell.decimals)}--"
                      rf"{fmt_num(r[1], cell.decimals)}\}}}}")
        text = after
    return text + (f"$^{{{mark}}}$" if mark else "")


def _tex_header(data: TableData) -> list[str]:
    spans = header_spans(data.columns)
    two_rows = any(c.label for c in data.columns)
    verdict = [tex_escape(data.verdict_header)] if data.verdict_header else []
    if not two_rows:
        heads = [tex_escape(_decorate(c.group, c.unit, c.higher_is_better)) for c in data.columns]
        return [" & ".join([tex_escape(data.row_header)] + heads + verdict) + r" \\"]
    top, rules, bottom, start = [""], [], [tex_escape(data.row_header)], 2
    for col, span, on_group in spans:
        text = tex_escape(group_header(col, on_group))
        top.append(rf"\multicolumn{{{span}}}{{c}}{{{text}}}" if span > 1 else text)
        if span > 1:
            rules.append(rf"\cmidrule(lr){{{start}-{start + span - 1}}}")
        bottom += [
            tex_escape(sub_header(c, on_group)) for c in data.columns[start - 2 : start - 2 + span]
        ]
        start += span
    top += verdict
    bottom += [""] * len(verdict)
    lines = [" & ".join(top) + r" \\"]
    if rules:
        lines.append(" ".join(rules))
    return lines + [" & ".join(bottom) + r" \\"]


def to_latex(data: TableData) -> str:
    """A ``table`` float with a booktabs ``tabular``; needs ``\\usepackage{booktabs}``."""
    marks, notes = footnotes(data)
    judged = data.verdict_header is not None
    ncol = len(data.columns) + 1 + judged
    env = "table*" if ncol > WIDE_TABLE_COLUMNS else "table"  # wide tables span both columns
    lines = [f"% grip-bench table {data.id} v{data.version}; requires \\usepackage{{booktabs}}",
             rf"\begin{{{env}}}[t]", r"\centering", r"\small",
             rf"\caption{{{tex_escape(data.title)}}}", rf"\label{{tab:{data.id}}}",
             rf"\begin{{tabular}}{{l{'c' * (ncol - 1 - judged)}{'l' * judged}}}", r"\toprule",
             *_tex_header(data), r"\midrule"]
    for i, row in enumerate(data.rows):
        if row.group and (i == 0 or data.rows[i - 1].group != row.group):
            if i > 0:
                lines.append(r"\midrule")
            lines.append(
                rf"\multicolumn{{{ncol}}}{{l}}{{\textit{{{tex_escape(section_title(row))}}}}} \\"
            )
        cells = [_tex_cell(c, marks.get((i, j))) for j, c in enumerate(row.cells)]
        cells += [tex_escape(row.verdict or MISSING)] if judged else []
        lines.append(" & ".join([tex_escape(row.label)] + cells) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    foot = [f"$^{{{k}}}$ {tex_escape(t)}" for k, t in enumerate(notes, 1)]
    foot += [tex_escape(n) for n in data.notes]
    if foot:
        lines += [r"\par\smallskip", r"{\footnotesize " + r" \\ ".join(foot) + "}"]
    lines.append(rf"\end{{{env}}}")
    return "\n".join(lines) + "\n"


# --- HTML -----------------------------------------------------------------------------------
_CSS = """body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:2em;color:#222}
table{border-collapse:collapse;margin:1em 0;font-size:14px}
th,td{padding:4px 10px;text-align:right;white-space:nowrap}
thead th{border-bottom:1px solid #444;text-align:center}
thead{border-top:2px solid #222}table{border-bottom:2px solid #222}
th[data-col]{cursor:pointer}th[data-col]:hover{background:#eef}
th[aria-sort=ascending]::after{content:' \\25B2'}th[aria-sort=descending]::after{content:' \\25BC'}
tbody th{text-align:left;font-weight:normal}tr.section th{font-style:italic;text-align:left;
border-top:1px solid #aaa}td .ci{color:#666;font-size:85%}td.best .v{font-weight:bold}
tr.reference{color:#555}.notes{font-size:13px;color:#444}figure{display:inline-block;margin:1em}
figure img{max-width:560px}.views{font-size:85%;margin-left:.4em}"""

# Click a header to sort each section's rows by that column (numbers by data-v, text
# otherwise); cells without a value sort last in both directions.
_JS = """(function(){
function key(r,c){var x=r.cells[c];if(!x)return null;var v=x.getAttribute('data-v');
if(v!==null&&v!=='')return parseFloat(v);return c===0?x.textContent.trim():null;}
function cmp(a,b,asc){if(a===null&&b===null)return 0;if(a===null)return 1;if(b===null)return -1;
var d=(typeof a==='number'&&typeof b==='number')?a-b:String(a).localeCompare(String(b));
return asc?d:-d;}
document.querySelectorAll('table.sortable').forEach(function(t){
var hs=t.querySelectorAll('thead th[data-col]');
hs.forEach(function(h){h.addEventListener('click',function(){
var c=parseInt(h.getAttribute('data-col'),10);var asc=h.getAttribute('aria-sort')!=='ascending';
hs.forEach(function(o){o.removeAttribute('aria-sort');});
h.setAttribute('aria-sort',asc?'ascending':'descending');
Array.prototype.forEach.call(t.tBodies,function(tb){
var rs=Array.prototype.filter.call(tb.rows,function(r){return !r.classList.contains('section');});
rs.sort(function(a,b){return cmp(key(a,c),key(b,c),asc);});
rs.forEach(function(r){tb.appendChild(r);});});});});});})();"""


def _esc(text: str) -> str:
    return html.escape(text, quote=True)


def _html_cell(cell: Cell, mark: int | None) -> str:
    classes = ["best"] if cell.best or cell.tied else []
    if not _shown(cell.ci) and not (cell.paired and _shown(cell.before)):
        body, value = MISSING, ""
    else:
        after = fmt_num(cell.ci.mean, cell.decimals) if _shown(cell.ci) else MISSING
        body = f'<span class="v">{after}</span>'
        if cell.paired:
            before = fmt_num(cell.before.mean, cell.decimals) if _shown(cell.before) else MISSING
            body = f"{before} → {body}"
        if _has_ci(cell.ci):
            body += (f' <span class="ci">[{fmt_num(cell.ci.lo, cell.decimals)}, '
                     f"{fmt_num(cell.ci.hi, cell.decimals)}]</span>")
        if seed_range(cell) is not None:
            body += f' <span class="ci">{_esc(seed_text(cell).strip())}</span>'
        value = format_float(cell.ci.mean) if _shown(cell.ci) else ""
    if mark:
        body += f"<sup>{mark}</sup>"
    cls = f' class="{" ".join(classes)}"' if classes else ""
    dv = f' data-v="{value}"' if value else ""
    return f"<td{cls}{dv}>{body}</td>"


def _html_head(data: TableData) -> list[str]:
    two_rows = any(c.label for c in data.columns)
    rs = ' rowspan="2"' if two_rows else ""
    top = [f'<th data-col="0"{rs}>{_esc(data.row_header)}</th>']
    bottom, j = [], 1
    for col, span, on_group in header_spans(data.columns):
        text = _esc(group_header(col, on_group))
        if span == 1 and not col.label:
            top.append(
                f'<th data-col="{j}"{rs}>'
                f'{_esc(_decorate(col.group, col.unit, col.higher_is_better))}</th>'
            )
        else:
            top.append(f'<th colspan="{span}">{text}</th>' if span > 1 else f"<th>{text}</th>")
            bottom += [f'<th data-col="{j + k}">{_esc(sub_header(c, on_group))}</th>'
                       for k, c in enumerate(data.columns[j - 1:j - 1 + span])]
        j += span
    if data.verdict_header:
        top.append(f'<th data-col="{j}"{rs}>{_esc(data.verdict_header)}</th>')
    rows = ["<tr>" + "".join(top) + "</tr>"]
    if two_rows:
        rows.append("<tr>" + "".join(bottom) + "</tr>")
    return rows


Links = Mapping[str, Sequence[tuple[str, str]]]  # method -> [(text, relative href)]


def row_method(row: Row) -> str | None:
    """The one method a row's cells show (None: none, or several)."""
    methods = {c.filters.get("method") for c in row.cells} - {None, ""}
    return methods.pop() if len(methods) == 1 else None


def _row_label_html(row: Row, links: Links | None) -> str:
    """A row's label, followed by its method's viewer pages when there are any."""
    method = row_method(row) if links else None
    pages = links.get(method, ()) if links and method else ()
    if not pages:
        return _esc(row.label)
    anchors = " ".join(f'<a href="{_esc(href)}">{_esc(text)}</a>' for text, href in pages)
    return f'{_esc(row.label)}<span class="views">[3D: {anchors}]</span>'


def relative_links(links: Mapping[str, Sequence[tuple[str, str | os.PathLike]]] | None,
                   from_dir: str | os.PathLike) -> Links | None:
    """``{method: [(text, page path)]}`` with each path made relative to ``from_dir``
    (forward slashes: a URL)."""
    if not links:
        return None
    return {m: [(text, posixpath.join(*Path(os.path.relpath(p, from_dir)).parts))
                for text, p in pages] for m, pages in links.items()}


def table_html(data: TableData, links: Links | None = None) -> str:
    """An HTML fragment: heading, sortable table, footnotes and notes.

    ``links``: viewer pages per method, shown after the label of the row of that method."""
    marks, notes = footnotes(data)
    ncol = len(data.columns) + 1 + (data.verdict_header is not None)
    out = [f'<section id="{_esc(data.id)}">', f"<h2>{_esc(data.title)}</h2>",
           f'<p class="notes"><code>{_esc(data.id)}</code> v{data.version}: '
           f"{_esc(data.description)}</p>",
           '<table class="sortable">', "<thead>", *_html_head(data), "</thead>"]
    offset = 0
    for head, rows in sections(data.rows):
        out.append("<tbody>")
        if head is not None:
            out.append(f'<tr class="section"><th colspan="{ncol}">'
                       f"{_esc(section_title(head))}</th></tr>")
        for i, row in enumerate(rows, offset):
            cls = ' class="reference"' if row.reference else ""
            cells = "".join(_html_cell(c, marks.get((i, j))) for j, c in enumerate(row.cells))
            if data.verdict_header:
                cells += f'<td style="text-align:left">{_esc(row.verdict or MISSING)}</td>'
            out.append(f'<tr{cls}><th scope="row">{_row_label_html(row, links)}</th>{cells}</tr>')
        offset += len(rows)
        out.append("</tbody>")
    out.append("</table>")
    items = [f"<li><sup>{k}</sup> {_esc(t)}</li>" for k, t in enumerate(notes, 1)]
    items += [f"<li>{_esc(n)}</li>" for n in data.notes]
    if items:
        out += ['<ul class="notes">', *items, "</ul>"]
    out.append("</section>")
    return "\n".join(out)


def _figure_html(path: str | os.PathLike) -> str:
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise InputError(f"cannot read figure: {e.strerror}", where=path) from None
    if not data.startswith(b"\x89PNG\r\n\x1a\n"):
        raise InputError("figure is not a PNG file", where=path)
    b64 = base64.b64encode(data).decode("ascii")
    name = _esc(path.stem.replace("_", " "))
    return (f'<figure><img alt="{name}" src="data:image/png;base64,{b64}">'
            f"<figcaption>{name}</figcaption></figure>")


def html_page(title: str, fragments: Iterable[str],
              figures: Sequence[str | os.PathLike] = ()) -> str:
    """A self-contained page (inline CSS and JS, figures as data URIs, no network)."""
    figs = [_figure_html(p) for p in figures]
    body = [*fragments] + (['<section id="figures">', "<h2>Figures</h2>", *figs, "</section>"]
                           if figs else [])
    return "\n".join(["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
                      f"<title>{_esc(title)}</title>", f"<style>{_CSS}</style>", "</head>",
                      "<body>", f"<h1>{_esc(title)}</h1>", *body, f"<script>{_JS}</script>",
                      "</body>", "</html>"]) + "\n"


def to_html(data: TableData, figures: Sequence[str | os.PathLike] = (),
            links: Links | None = None) -> str:
    """A standalone sortable HTML page for one table (``links``: see :func:`table_html`)."""
    return html_page(data.title, [table_html(data, links)], figures)


RENDERERS = {"md": to_markdown, "csv": to_csv, "tex": to_latex, "html": to_html}


# --- entry points ---------------------------------------------------------------------------
def render(data: TableData, fmt: str) -> str:
    """Text of ``data`` in one of :data:`FORMATS`."""
    if fmt not in RENDERERS:
        raise InputError(f"unknown table format '{fmt}' (known: {', '.join(FORMATS)})")
    return RENDERERS[fmt](data)


def render_table(
    spec: TableSpec | str,
    results: pd.DataFrame | None,
    fmt: str = "md",
    *,
    runtime: pd.DataFrame | None = None,
    dataset: str | None = None,
    metrics_registry: Registry[MetricSpec] | None = None,
    n_boot: int = BOOTSTRAP_N,
    seed: int = BOOTSTRAP_SEED,
    averaging: str = "sequence",
) -> str:
    """Compute one table (by spec or registered id) from results frames and render it."""
    if isinstance(spec, str):
        spec = TABLES.get(spec)
    data = compute_table(spec, results, runtime, dataset=dataset,
                         metrics_registry=metrics_registry, n_boot=n_boot, seed=seed,
                         averaging=averaging)
    return render(data, fmt)


def _write_all_formats(data: TableData, out: Path, formats: Sequence[str],
                       links: Mapping[str, Sequence[tuple[str, Path]]] | None = None
                       ) -> list[Path]:
    return [atomic_write_text(out / f"{data.id}.{fmt}",
                              to_html(data, links=relative_links(links, out))
                              if fmt == "html" and links else render(data, fmt))
            for fmt in formats]


def render_all(results_dir: str | os.PathLike, out_dir: str | os.PathLike, *,
               formats: Sequence[str] = FORMATS,
               metrics_registry: Registry[MetricSpec] | None = None,
               n_boot: int = BOOTSTRAP_N, seed: int = BOOTSTRAP_SEED,
               averaging: str = "sequence",
               links: Mapping[str, Sequence[tuple[str, Path]]] | None = None,
               tables: Sequence[str] | None = None) -> list[Path]:
    """Write the registered tables in every format from ``results_dir`` into ``out_dir``.

    ``tables``: only these table ids (a run's ``--tables`` / ``[run] tables``); None: all.
    ``links``: ``{method: [(text, viewer page path)]}``; the HTML rows of those methods link
    to them (relative URLs).

    Reads ``results.csv`` (required) and ``runtime.csv`` (optional). With results from one
    dataset the files go to ``out_dir/<table>.<fmt>``; with several, results tables go to
    ``out_dir/<dataset>/`` (never pooling datasets) and the runtime table stays in ``out_dir``.
    """
    results_dir, out_dir = Path(results_dir), Path(out_dir)
    results = read_results(results_dir / "results.csv")
    runtime_path = results_dir / "runtime.csv"
    runtime = read_runtime(runtime_path) if runtime_path.is_file() else None
    datasets = sorted(results["dataset"].unique()) or [None]
    written: list[Path] = []
    for t in tables or ():
        TABLES.get(t)  # an unknown id: InputError listing the known tables
    chosen = [spec for spec in TABLES if tables is None or spec.id in tables]
    for spec in chosen:
        targets = [None] if spec.source == "runtime" else datasets
        for ds in targets:
            out = out_dir / ds if ds is not None and len(datasets) > 1 else out_dir
            data = compute_table(spec, results, runtime, dataset=ds,
                                 metrics_registry=metrics_registry, n_boot=n_boot, seed=seed,
                                 averaging=averaging)
            written += _write_all_formats(data, out, formats, links)
    return written
