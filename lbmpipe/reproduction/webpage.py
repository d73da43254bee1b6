"""The reproduction document as a web page that works offline.

:func:`markdown_to_html` turns the Markdown that ``lbmpipe.reproduction.literate.build_document`` writes into
one self-contained HTML page:

- Markdown by markdown-it-py (CommonMark with its pipe-table extension); raw HTML in the Markdown
  is escaped, not passed through.
- Mathematics written as LaTeX, ``$...$`` inline and ``$$...$$`` displayed (``mdit_py_plugins``'
  dollarmath syntax), is converted to MathML by latex2mathml when the page is built, so the browser
  lays it out natively: no script, font or style sheet is fetched when the page is viewed.
- Every heading gets an ``id`` (its text as a slug, made unique) and the page opens with a table
  of contents of the ``##`` and ``###`` headings.
- Anchors per claim: the rows of a table whose first column is ``claim`` get ``id="claim-N"``
  (the first such table; a later one, e.g. an appendix with the full statistics, gets
  ``claim-N-2``, ...). Anchors per figure: each image gets ``id="fig-<file stem>"``.
- Links to a generated document (``reproduction_<level>.md``) point at its ``.html`` rendering (the
  document is built as both); other Markdown files (``paper/reading.md``) have no HTML and keep theirs.
"""

from __future__ import annotations

import html
import re
from pathlib import PurePosixPath

from latex2mathml.converter import convert as _latex_to_mathml
from markdown_it import MarkdownIt
from mdit_py_plugins.dollarmath import dollarmath_plugin

_STYLE = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,"DejaVu Sans",sans-serif;line-height:1.45;
  color:#1b1b1b;margin:0}
main{max-width:62em;margin:0 auto;padding:1em 2em 4em}
nav.toc{background:#fafafa;border:1px solid #e2e2e2;padding:.3em 1em;margin:1em 0}
nav.toc h2{border:0;margin:.3em 0;font-size:1.15em}
nav.toc ol{margin:.2em 0;padding-left:1.2em;list-style:none}
nav.toc ol ol{font-size:92%}
h1{font-size:1.7em;line-height:1.2}h2{border-bottom:1px solid #ddd;padding-bottom:.15em;margin-top:2em}
table{border-collapse:collapse;font-size:88%;margin:.8em 0;display:block;overflow-x:auto;max-width:100%}
td,th{border:1px solid #c8c8c8;padding:3px 7px;vertical-align:top}
th{background:#f3f3f3}
tr:target,img:target{outline:3px solid #e3a21a}
code{background:#f4f4f4;padding:0 .2em;font-size:92%}
pre{background:#f6f6f6;padding:.6em;overflow-x:auto}
img{max-width:100%;height:auto;display:block;margin:.6em auto}
math{font-size:1.08em}math[display=block]{margin:.5em 0}
blockquote{color:#444;border-left:3px solid #ccc;margin-left:0;padding-left:1em}
"""


def latex_to_mathml(latex: str, display: bool = False) -> str:
    """MathML of one LaTeX formula (``display``: a block formula). A formula latex2mathml cannot
    read raises ``ValueError`` naming it, so a typo in the template stops the build."""
    try:
        out = _latex_to_mathml(latex.strip(), display="block" if display else "inline")
    except Exception as exc:  # latex2mathml raises its own exception classes
        raise ValueError(f"cannot convert the formula ${latex}$ to MathML: {type(exc).__name__} {exc}") from exc
    unknown = re.findall(r">(\\[A-Za-z]+)<", out)  # a command latex2mathml does not know stays as text
    if unknown:
        raise ValueError(f"cannot convert the formula ${latex}$ to MathML: unknown command {', '.join(unknown)}")
    return out


def slug(text: str) -> str:
    """A heading's anchor: lower case, runs of other characters as one ``-``."""
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "section"


def _parser() -> MarkdownIt:
    md = MarkdownIt("commonmark", {"html": False, "typographer": False}).enable("table")
    md.use(dollarmath_plugin, allow_space=True, allow_digits=True, double_inline=True,
           renderer=lambda content, opts: latex_to_mathml(content, bool(opts.get("display_mode"))))
    return md


def _unique(base: str, used: set[str]) -> str:
    name, k = base, 2
    while name in used:
        name, k = f"{base}-{k}", k + 1
    used.add(name)
    return name


def _inline_text(tok) -> str:
    return "".join(c.content for c in (tok.children or []) if c.type in ("text", "code_inline")) or tok.content


def _annotate(tokens, used: set[str]) -> list[tuple[int, str, str]]:
    """Give headings, claim rows and images their ids; return the headings (level, id, text)."""
    headings = []
    claim_tables = 0
    i = 0
    while i < len(tokens):
        tok = tokens[i]
        if tok.type == "heading_open":
            text = _inline_text(tokens[i + 1])
            hid = _unique(slug(text), used)
            tok.attrSet("id", hid)
            headings.append((int(tok.tag[1]), hid, text))
        elif tok.type == "table_open":
            # header: table_open thead_open tr_open th_open inline ...
            j = i
            while tokens[j].type != "th_open":
                j += 1
            if _inline_text(tokens[j + 1]).strip().lower() == "claim":
                claim_tables += 1
                suffix = "" if claim_tables == 1 else f"-{claim_tables}"
                k = j
                while tokens[k].type != "table_close":
                    if tokens[k].type == "tr_open" and tokens[k + 1].type == "td_open":
                        key = _inline_text(tokens[k + 2]).strip()
                        if key:
                            tokens[k].attrSet("id", _unique(f"claim-{slug(key)}{suffix}", used))
                    k += 1
        elif tok.type == "inline":
            for child in tok.children or []:
                if child.type == "image":
                    stem = PurePosixPath(child.attrGet("src") or "").stem
                    child.attrSet("id", _unique(f"fig-{slug(stem)}", used))
                elif child.type == "link_open":
                    href = child.attrGet("href") or ""
                    path, sep, frag = href.partition("#")
                    if re.search(r"(^|/)reproduction_[^/]*[.]md$", path) and "://" not in path:
                        child.attrSet("href", path[:-3] + ".html" + sep + frag)
        i += 1
    return headings


def _toc(headings: list[tuple[int, str, str]]) -> str:
    """Contents: the ``##`` headings, each with its ``###`` headings nested."""
    out, open_sub = [], False
    for lvl, hid, text in headings:
        if lvl not in (2, 3) or (lvl == 3 and not out):
            continue
        item = f'<a href="#{hid}">{html.escape(text)}</a>'
        if lvl == 2:
            out.append(("</ol></li>" if open_sub else "</li>" if out else "") + f"<li>{item}")
            open_sub = False
        else:
            out.append(("" if open_sub else "<ol>") + f"<li>{item}</li>")
            open_sub = True
    if not out:
        return ""
    out.append("</ol></li>" if open_sub else "</li>")
    return ('<nav class="toc" id="contents" aria-label="Contents"><h2>Contents</h2><ol>'
            + "".join(out) + "</ol></nav>")


def markdown_to_html(text: str, title: str = "") -> str:
    """The complete HTML page of the Markdown ``text`` (module docstring: what it holds)."""
    md = _parser()
    env: dict = {}
    tokens = md.parse(text, env)
    headings = _annotate(tokens, used={"contents"})
    body = md.renderer.render(tokens, md.options, env)
    # the contents follow the title (the first top-level heading), or open the page
    end = body.find("</h1>")
    cut = end + len("</h1>") if end >= 0 else 0
    body = body[:cut] + "\n" + _toc(headings) + "\n" + body[cut:]
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head>\n<body>\n"
            + "<main>\n" + body + "</main>\n</body></html>\n")
