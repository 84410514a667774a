"""Report blocks and their two renderings: markdown and a standalone HTML page.

A report is built as a list of blocks, then rendered twice, so ``report.md`` and ``report.html`` (and
``scan.md``/``scan.html``) always say the same. A block is a tuple:

- ``("h", level, text)``: a heading;
- ``("p", text)``: a paragraph; :data:`EM` around a phrase marks emphasis (the paper's title);
- ``("ul", items)``: a list (the design's warnings);
- ``("table", header, rows, marks)``: ``marks`` is None or one bool per row (acceptance); a failed row's
  last cell ``"NO"`` is bold in markdown and the row red in HTML, a passed row green;
- ``("fig", title, path)``: a figure, ``path`` relative to the page.
"""
from __future__ import annotations

import html

__all__ = ["EM", "to_markdown", "to_html"]

EM = "\x00"     # marks emphasis inside a paragraph block

_STYLE = ("body{font-family:sans-serif;max-width:1200px;margin:auto;padding:1em}"
          "table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ccc;padding:3px 6px}"
          "tr.no{background:#fde2e2}tr.yes{background:#e6f4e6}img{max-width:100%}"
          "ul.warn li{color:#8a3b00}")


def to_markdown(blocks, *, figure_headings: bool = True) -> str:
    """The blocks as markdown (``figure_headings``: a level-3 heading with each figure's title)."""
    md = []
    for b in blocks:
        if b[0] == "h":
            md += ["#" * b[1] + " " + b[2], ""]
        elif b[0] == "p":
            md += [b[1].replace(EM, "*"), ""]
        elif b[0] == "ul":
            md += [f"- {item}" for item in b[1]] + [""]
        elif b[0] == "table":
            _, header, rows, marks = b
            md += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
            for row in rows:
                cells = [("**NO**" if c == "NO" and k == len(row) - 1 and marks else str(c)) for k, c in enumerate(row)]
                md.append("| " + " | ".join(cells) + " |")
            md.append("")
        elif b[0] == "fig":
            md += ([f"### {b[1]}", ""] if figure_headings else []) + [f"![{b[1]}]({b[2]})", ""]
    return "\n".join(md) + "\n"


def to_html(blocks, title: str = "nanosim report", *, figure_headings: bool = True) -> str:
    """The blocks as one HTML page titled ``title``, every text escaped.

    ``figure_headings``: see :func:`to_markdown`.
    """
    e = html.escape
    h = [f"<!doctype html><html><head><meta charset='utf-8'><title>{e(title)}</title>",
         f"<style>{_STYLE}</style></head><body>"]
    for b in blocks:
        if b[0] == "h":
            h.append(f"<h{b[1]}>{e(b[2])}</h{b[1]}>")
        elif b[0] == "p":
            parts = e(b[1]).split(EM)
            h.append("<p>" + "".join(f"<em>{t}</em>" if k % 2 else t for k, t in enumerate(parts)) + "</p>")
        elif b[0] == "ul":
            h.append("<ul class='warn'>" + "".join(f"<li>{e(item)}</li>" for item in b[1]) + "</ul>")
        elif b[0] == "table":
            _, header, rows, marks = b
            h.append("<table><tr>" + "".join(f"<th>{e(c)}</th>" for c in header) + "</tr>")
            for k, row in enumerate(rows):
                ok = marks[k] if marks else None
                cls = "" if ok is None else (" class='yes'" if ok else " class='no'")
                h.append(f"<tr{cls}>" + "".join(f"<td>{e(str(c))}</td>" for c in row) + "</tr>")
            h.append("</table>")
        elif b[0] == "fig":
            head = f"<h3>{e(b[1])}</h3>" if figure_headings else ""
            h.append(f"{head}<img src='{e(b[2])}' alt='{e(b[1])}'>")
    h.append("</body></html>")
    return "\n".join(h) + "\n"
