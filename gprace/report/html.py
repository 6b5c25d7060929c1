"""``gprace report``: one self-contained HTML page from every result under a folder.

The page needs nothing but itself: figures are PNG data URIs, the style sheet is inline, there
are no scripts, fonts or links to fetch. Sections (time trial, head-to-head, diagnosis, GP)
appear for the domains found; each lists what it expected and did not find, so a folder from an
interrupted loop still gives a page. An index of every artifact closes the page.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gprace import __version__
from gprace.errors import InputError
from gprace.io.artifacts import check_folder, write_text_atomic
from gprace.report import collect
from gprace.report.collect import Section, table
from gprace.report.figures import png_bytes
from gprace.report.inspect import ODD_PAYLOAD, key_results, open_artifact
from gprace.report.sections.diagnosis import diagnosis_section
from gprace.report.sections.gp import gp_section
from gprace.report.sections.h2h import h2h_section
from gprace.report.sections.timetrial import timetrial_section

CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0;color:#1d2330;background:#f6f7f9}
header{background:#1d2330;color:#fff;padding:14px 28px}
header h1{margin:0;font-size:22px} header p{margin:4px 0 0;color:#c8cdd8;font-size:13px}
nav{padding:8px 28px;background:#e9ecf2;font-size:14px} nav a{margin-right:18px;color:#1d4ed8;text-decoration:none}
main{padding:8px 28px 40px;max-width:1300px}
section{background:#fff;border:1px solid #dde1e8;border-radius:6px;padding:6px 20px 16px;margin:18px 0}
h2{font-size:19px;border-bottom:2px solid #1d4ed8;padding-bottom:4px} h3{font-size:15px;margin:14px 0 4px}
figure{margin:14px 0;display:inline-block;max-width:100%;vertical-align:top}
figure img{max-width:100%;height:auto;border:1px solid #eceef2}
figcaption{font-size:13px;color:#4b5565;max-width:900px}
table{border-collapse:collapse;font-size:13px;margin:8px 0}
th,td{border:1px solid #d5d9e0;padding:3px 8px;text-align:right} th{background:#eef1f6}
td:first-child,th:first-child{text-align:left}
.missing{background:#fff8e6;border-left:4px solid #e0a100;padding:6px 12px;font-size:13px}
.missing li{margin:2px 0} .note{color:#6b4f00;font-size:13px}
"""


MAX_INDEX = 25  # artifacts listed per kind in the index


@dataclass
class Report:
    path: Path
    sections: list[Section] = field(default_factory=list)
    n_figures: int = 0
    missing: list[str] = field(default_factory=list)
    pngs: list[Path] = field(default_factory=list)


def build_report(folder: str | Path, out: str | Path, png_dir: str | Path | None = None, track: str | None = None,
                 features: tuple[str, str] | None = None) -> Report:
    """Scan ``folder``, draw every figure, write the page to ``out`` (and PNGs to ``png_dir``)."""
    from gprace.console import console

    folder, out = Path(folder), Path(out)
    if not folder.exists():
        raise InputError(f"{folder}: no such folder")
    if not folder.is_dir():
        raise InputError(f"{folder}: is a file; `gprace show {folder}` summarises one file")
    if out.parent and not out.parent.exists():
        raise InputError(f"{out}: folder {out.parent} does not exist")
    if png_dir is not None:
        check_folder(png_dir, "--png")
    with console.progress("report: collecting results", total=4) as prog:
        sections, found = _collect_with_progress(folder, track, features, prog)
    rep = Report(out, sections)
    if png_dir is not None:
        png_dir = Path(png_dir)
        png_dir.mkdir(parents=True, exist_ok=True)
    n_fig = sum(1 for s in sections for it in s.items if it.figure is not None)
    body = []
    with console.progress(f"report: rendering {n_fig} figures", total=n_fig) as prog:
        for sec in sections:
            body.append(_section_html(sec, rep, png_dir, prog))
    if not found.files:
        rep.missing.append(f"{folder}: no gprace results found (no artifact .h5 or result .json)")
    body.append(_index_html(found))
    for sec in sections:
        rep.missing += [f"{sec.title}: {m}" for m in sec.missing]
    page = _page(folder, sections, body, rep.missing if not sections else [])
    write_text_atomic(out, page)
    return rep


def _collect_with_progress(folder, track, features, prog):
    found = collect.scan(folder)
    prog.advance()
    sections = []
    for make in (lambda: timetrial_section(found, track), lambda: h2h_section(found),
                 lambda: diagnosis_section(found), lambda: gp_section(found, features)):
        sec = make()
        if sec is not None:
            sections.append(sec)
        prog.advance()
    return sections, found


def _img(png: bytes, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{base64.b64encode(png).decode()}">'


def _section_html(sec: Section, rep: Report, png_dir: Path | None, prog) -> str:
    parts = [f'<section id="{sec.key}" data-section="{sec.key}"><h2>{html.escape(sec.title)}</h2>']
    for it in sec.items:
        if it.figure is not None:
            png = png_bytes(it.figure)
            it.figure.clear()
            rep.n_figures += 1
            if png_dir is not None:
                p = png_dir / f"{sec.key}_{it.name or rep.n_figures}.png"
                p.write_bytes(png)
                rep.pngs.append(p)
            parts.append(f"<figure>{_img(png, it.caption)}<figcaption>{html.escape(it.caption)}</figcaption></figure>")
            prog.advance()
        else:
            parts.append(f"<div class='block'><h3>{html.escape(it.caption)}</h3>{it.html}</div>")
    if sec.missing:
        parts.append("<div class='missing'><b>Missing or not drawn:</b><ul>"
                     + "".join(f"<li>{html.escape(m)}</li>" for m in sec.missing) + "</ul></div>")
    parts.append("</section>")
    return "".join(parts)


def _index_html(found: collect.Found) -> str:
    rows = []
    for kind, paths in sorted(found.files.items()):
        for p in paths[:MAX_INDEX]:
            res: dict[str, Any] = {}
            if p.suffix.lower() in (".h5", ".hdf5"):
                try:
                    res = key_results(open_artifact(p))
                except ODD_PAYLOAD as exc:
                    res = {"error": str(exc)}
            short = ", ".join(f"{k}={_fmt(v)}" for k, v in list(res.items())[:5])
            rows.append([str(p.relative_to(found.root)), kind, short])
        if len(paths) > MAX_INDEX:
            rows.append([f"... and {len(paths) - MAX_INDEX} more", kind, ""])
    if not rows:
        return ("<section id='artifacts' data-section='artifacts'><h2>Artifacts</h2>"
                "<div class='missing'>No gprace results under this folder.</div></section>")
    total = sum(len(v) for v in found.files.values())
    return (f"<section id='artifacts' data-section='artifacts'><h2>Artifacts ({total})</h2>"
            + table(["file", "kind", "key results"], rows) + "</section>")


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_fmt(x) for x in v[:6]) + (", ..." if len(v) > 6 else "") + "]"
    s = str(v)
    return s if len(s) <= 40 else s[:37] + "..."


def _page(folder: Path, sections: list[Section], body: list[str], missing: list[str]) -> str:
    nav = "".join(f'<a href="#{s.key}">{html.escape(s.title)}</a>' for s in sections) + '<a href="#artifacts">Artifacts</a>'
    when = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    top = ""
    if missing:
        top = ("<div class='missing'><ul>" + "".join(f"<li>{html.escape(m)}</li>" for m in missing) + "</ul></div>")
    return (
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>gprace report: {html.escape(folder.name or str(folder))}</title><style>{CSS}</style></head><body>"
        f"<header><h1>gprace report: {html.escape(str(folder))}</h1>"
        f"<p>gprace {__version__}, built {when}</p></header><nav>{nav}</nav><main>{top}"
        + "".join(body) + "</main></body></html>"
    )
