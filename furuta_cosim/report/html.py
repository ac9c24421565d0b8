"""Self-contained HTML pages: the project's Markdown (summaries, reports) rendered with its
figures inline (SVG as markup, PNG as base64), no script, no network, no external file.

Only the Markdown the project writes is rendered: headings, paragraphs, bullet lists, pipe
tables, fenced code, `code`, **bold** and [links](...). Everything else is escaped text, links
go only to http, https, mailto or a place in the page (a ``javascript:`` or ``data:`` link
stays text), control characters are dropped, SVG figures keep only drawing elements and
attributes (no script, no event handler, no external reference), and the page's content
security policy forbids scripts and anything fetched.
"""

from __future__ import annotations

import base64
import html
import re
import xml.etree.ElementTree as ET
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


# C0 and C1 control characters but tab and newline: they have no place in a page
_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]")
_SAFE_LINK = re.compile(r"(?:https?://|mailto:|#)[^\s\"'<>]*", re.I)
POLICY = "default-src 'none'; img-src data:; style-src 'unsafe-inline'"


def clean_text(text: str) -> str:
    """Text with its control characters removed (tab and newline kept)."""
    return _CONTROL.sub("", text)


def _link(m: re.Match) -> str:
    label, target = m.group(1), html.unescape(m.group(2))
    if not _SAFE_LINK.fullmatch(target):
        return f"{label} ({m.group(2)})"  # a javascript:, data: or file link stays text
    return f'<a href="{html.escape(target)}">{label}</a>'


def _inline(text: str) -> str:
    out = html.escape(clean_text(text), quote=False)
    out = re.sub(r"`([^`]+)`", r"<code>\1</code>", out)
    out = re.sub(r"\*\*([^*]+)\*\*", r"<strong>\1</strong>", out)
    out = re.sub(r"\[([^\]]+)\]\(([^)\s]+)\)", _link, out)
    for verdict, css in _VERDICTS.items():
        if out.strip() == verdict:
            return f'<span class="{css}">{out}</span>'
    return out


def markdown_to_html(text: str) -> str:
    """The subset of Markdown the project writes, as HTML."""
    lines = clean_text(text).splitlines()
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
            items: list[tuple[str, list[str]]] = []   # (text, nested items)
            while k < len(lines) and lines[k].startswith(("- ", "* ", "  ")):
                text = lines[k]
                if text.startswith(("- ", "* ")):
                    items.append((text[2:], []))
                elif text.lstrip().startswith(("- ", "* ")):     # an indented item: nested
                    items[-1][1].append(text.lstrip()[2:])
                elif items[-1][1]:                                # continues the nested item
                    items[-1][1][-1] += " " + text.strip()
                else:
                    items[-1] = (items[-1][0] + " " + text.strip(), items[-1][1])
                k += 1
            out.append("<ul>" + "".join(
                f"<li>{_inline(text)}" + ("<ul>" + "".join(f"<li>{_inline(c)}</li>" for c in nested)
                                          + "</ul>" if nested else "") + "</li>"
                for text, nested in items) + "</ul>")
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
        body = clean_svg(path.read_text(errors="replace"))
    else:
        data = base64.b64encode(path.read_bytes()).decode()
        body = f'<img alt="{html.escape(caption or path.stem)}" src="data:image/png;base64,{data}">'
    note = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
    return f"<figure>{body}{note}</figure>"


_SVG = "http://www.w3.org/2000/svg"
_XLINK = "http://www.w3.org/1999/xlink"
# what a figure is drawn with; anything else (script, foreignObject, image, iframe, ...) goes
_DRAWING = {"svg", "g", "defs", "clipPath", "path", "rect", "circle", "ellipse", "line",
            "polyline", "polygon", "text", "tspan", "use", "style", "title", "desc",
            "linearGradient", "radialGradient", "stop", "pattern", "mask", "symbol", "marker"}
_OUTSIDE = re.compile(r"url\(\s*(?!['\"]?#)|@import|javascript:|expression\(", re.I)


def clean_svg(text: str) -> str:
    """An SVG document reduced to drawing: only the elements of ``_DRAWING`` (matched exactly:
    ``SCRIPT`` is no SVG element either), no ``on*`` attribute, references only within the
    figure (``#id``), no style that loads anything. A figure that does not parse is left out
    with a note."""
    try:
        root = ET.fromstring(text.encode() if text.lstrip().startswith("<?xml") else text)
    except (ET.ParseError, ValueError):
        return "<p>(a figure that is not valid SVG was left out)</p>"
    if _local(root.tag) != "svg":
        return "<p>(a figure that is not SVG was left out)</p>"
    _prune(root)
    ET.register_namespace("", _SVG)
    ET.register_namespace("xlink", _XLINK)
    return ET.tostring(root, encoding="unicode")


def _local(tag) -> str:
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""


def _prune(element) -> None:
    for name in list(element.attrib):
        value = element.attrib[name]
        local = _local(name).lower()
        if (local.startswith("on") or (local == "href" and not value.startswith("#"))
                or _OUTSIDE.search(value) or _CONTROL.search(value)):
            del element.attrib[name]
    if _local(element.tag) == "style" and element.text and _OUTSIDE.search(element.text):
        element.text = ""
    for child in list(element):
        if not (isinstance(child.tag, str) and child.tag.startswith("{" + _SVG + "}")
                and _local(child.tag) in _DRAWING):
            element.remove(child)
        else:
            _prune(child)


def page(title: str, body: str) -> str:
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<meta http-equiv=\"Content-Security-Policy\" content=\"{POLICY}\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<title>{html.escape(clean_text(title))}</title><style>{STYLE}</style></head>\n"
            f"<body>\n{body}\n</body></html>\n")
