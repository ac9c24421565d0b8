"""Self-contained HTML pages: the project's Markdown (summaries, reports) rendered with its
figures inline (SVG as markup, PNG as base64), no script, no network, no external file.

Only the Markdown the project writes is rendered: headings, paragraphs, bullet lists, pipe
tables, fenced code, `code`, **bold** and [links](...). Everything else is escaped text.
"""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

STYLE = """
body { font: 15px/1.45 system-ui, sans-serif; max-width: 72rem; margin: 2rem auto; padding: 0 1rem;
       color: #1b1b1b; background: #fff; }
h1 { font-size: 1.6rem; } h2 { font-size: 1.25rem; margin-top: 2rem; } h3 { font-size: 1.05rem; }
table { border-collapse: collapse; margin: 0.8rem 0; font-size: 0.9rem; }
th, td { border: 1px solid #ccc; padding: 0.25rem 0.55rem; text-align: left; vertical-align: top; }
th { background: #f2f2f2; } code, pre { font-family: ui-monospace, monospace; font-size: 0.88rem; }
pre { background: #f6f6f6; padding: 0.6rem; overflow-x: auto; }
figure { margin: 1rem 0; } figure svg, figure img { max-width: 100%; height: auto; }
.holds { color: #146c2e; font-weight: 600; } .reading { color: #8a5a00; font-weight: 600; }
.fails { color: #a4161a; font-weight: 600; }
"""
_VERDICTS = {"holds": "holds", "holds under a reading": "reading", "does not hold": "fails",
             "PASS": "holds", "FAIL": "fails", "pass": "holds", "fail": "fails", "missing": "fails"}


def _inline(text: str) -> str:
    out = html.escape(text, quote=False)
    out = re.sub(r"`([^`]+)`", r"<code>\1</code>", out)
    out = re.sub(r"\*\*([^*]+)\*\*", r"<strong>\1</strong>", out)
    out = re.sub(r"\[([^\]]+)\]\(([^)\s]+)\)",
                 lambda m: f'<a href="{html.escape(m.group(2))}">{m.group(1)}</a>', out)
    for verdict, css in _VERDICTS.items():
        if out.strip() == verdict:
            return f'<span class="{css}">{out}</span>'
    return out


def markdown_to_html(text: str) -> str:
    """The subset of Markdown the project writes, as HTML."""
    lines = text.splitlines()
    out, k = [], 0
    while k < len(lines):
        line = lines[k]
        if line.startswith("```"):
            end = k + 1
            while end < len(lines) and not lines[end].startswith("```"):
                end += 1
            out.append("<pre>" + html.escape("\n".join(lines[k + 1:end])) + "</pre>")
            k = end + 1
        elif m := re.match(r"(#{1,4}) (.*)", line):
            level = len(m.group(1))
            out.append(f"<h{level}>{_inline(m.group(2))}</h{level}>")
            k += 1
        elif line.startswith("|"):
            rows = []
            while k < len(lines) and lines[k].startswith("|"):
                cells = [c.strip() for c in lines[k].strip().strip("|").split("|")]
                if not all(re.fullmatch(r":?-+:?", c) for c in cells):
                    rows.append(cells)
                k += 1
            head, body = rows[0], rows[1:]
            out.append("<table><thead><tr>" + "".join(f"<th>{_inline(c)}</th>" for c in head)
                       + "</tr></thead><tbody>"
                       + "".join("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in row) + "</tr>"
                                 for row in body) + "</tbody></table>")
        elif line.startswith(("- ", "* ")):
            items = []
            while k < len(lines) and lines[k].startswith(("- ", "* ", "  ")):
                if lines[k].startswith(("- ", "* ")):
                    items.append(lines[k][2:])
                else:
                    items[-1] += " " + lines[k].strip()
                k += 1
            out.append("<ul>" + "".join(f"<li>{_inline(i)}</li>" for i in items) + "</ul>")
        elif not line.strip():
            k += 1
        else:
            paragraph = []
            while k < len(lines) and lines[k].strip() and not re.match(r"(#{1,4} |\||- |\* |```)", lines[k]):
                paragraph.append(lines[k])
                k += 1
            out.append("<p>" + _inline(" ".join(paragraph)) + "</p>")
    return "\n".join(out)


def figure(path: str | Path, caption: str = "") -> str:
    """A figure file inline: SVG as markup (its XML prologue dropped), PNG as a data URI."""
    path = Path(path)
    if path.suffix == ".svg":
        text = path.read_text()
        start = text.find("<svg")
        body = text[start:] if start >= 0 else ""
        body = re.sub(r"<script.*?</script>", "", body, flags=re.S)  # a figure needs none
    else:
        data = base64.b64encode(path.read_bytes()).decode()
        body = f'<img alt="{html.escape(caption or path.stem)}" src="data:image/png;base64,{data}">'
    note = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
    return f"<figure>{body}{note}</figure>"


def page(title: str, body: str) -> str:
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<title>{html.escape(title)}</title><style>{STYLE}</style></head>\n"
            f"<body>\n{body}\n</body></html>\n")
