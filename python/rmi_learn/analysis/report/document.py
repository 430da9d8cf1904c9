"""The report's document model: an ordered list of blocks (headings, paragraphs, tables,
figures, code) rendered to Markdown and to one self-contained HTML page whose figures are
embedded as ``data:`` URIs."""

from __future__ import annotations

import base64
import html
import mimetypes
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


@dataclass
class Doc:
    """An ordered list of blocks rendered to Markdown and HTML."""

    blocks: list[tuple[str, Any]] = field(default_factory=list)

    def h(self, level: int, text: str) -> None:
        self.blocks.append((f"h{level}", text))

    def p(self, text: str) -> None:
        self.blocks.append(("p", text))

    def table(
        self,
        header: Sequence[str],
        rows: Sequence[Sequence[str]],
        note: str = "",
        text: bool = False,
    ) -> None:
        """A table; ``text`` left-aligns every column (for prose cells rather than numbers)."""
        self.blocks.append(("table", (list(header), [list(r) for r in rows], note, text)))

    def img(self, rel: str, caption: str) -> None:
        self.blocks.append(("img", (rel, caption)))

    def code(self, text: str) -> None:
        self.blocks.append(("code", text))

    def markdown(self) -> str:
        out: list[str] = []
        for kind, val in self.blocks:
            if kind.startswith("h"):
                out += ["#" * int(kind[1]) + " " + val, ""]
            elif kind == "p":
                out += [val, ""]
            elif kind == "code":
                out += ["```", val.rstrip("\n"), "```", ""]
            elif kind == "img":
                rel, cap = val
                out += [f"![{cap}]({rel})", "", f"*{cap}*", ""]
            else:
                header, rows, note, text = val
                align = "---" if text else ":---:"
                out.append("| " + " | ".join(header) + " |")
                out.append("|" + "|".join(["---"] + [align] * (len(header) - 1)) + "|")
                out += ["| " + " | ".join(r) + " |" for r in rows]
                out.append("")
                if note:
                    out += [f"*{note}*", ""]
        return "\n".join(out)

    def html(self, title: str, embed_from: Path | None = None) -> str:
        """The document as one HTML page. With ``embed_from``, each figure is read from that
        directory (its path is relative to it) and embedded as a ``data:`` URI, so the page
        needs no other file; without it, figures are linked by their relative paths."""

        def inline(text: str) -> str:
            # Markdown-style `code` and **bold** only: the report writes nothing else inline.
            t = html.escape(text)
            t = re.sub(r"`([^`]+)`", r"<code>\1</code>", t)
            return re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", t)

        body: list[str] = []
        toc: list[str] = []
        for kind, val in self.blocks:
            if kind.startswith("h"):
                level = int(kind[1])
                anchor = re.sub(r"[^a-z0-9]+", "-", val.lower()).strip("-")
                body.append(f'<h{level} id="{anchor}">{inline(val)}</h{level}>')
                if level == 2:
                    toc.append(f'<li><a href="#{anchor}">{inline(val)}</a></li>')
            elif kind == "p":
                body.append(f"<p>{inline(val)}</p>")
            elif kind == "code":
                body.append(f"<pre>{html.escape(val)}</pre>")
            elif kind == "img":
                rel, cap = val
                src = rel if embed_from is None else data_uri(embed_from / rel)
                body.append(
                    f'<figure><img src="{html.escape(src)}" alt="{html.escape(cap)}">'
                    f"<figcaption>{inline(cap)}</figcaption></figure>"
                )
            else:
                header, rows, note, text = val
                t = ['<table class="text">' if text else "<table>", "<thead><tr>"]
                t += [f"<th>{inline(c)}</th>" for c in header]
                t.append("</tr></thead><tbody>")
                for r in rows:
                    cls = ' class="paper"' if r and r[0].startswith("paper") else ""
                    t.append(f"<tr{cls}>" + "".join(f"<td>{inline(c)}</td>" for c in r) + "</tr>")
                t.append("</tbody></table>")
                if note:
                    t.append(f'<p class="note">{inline(note)}</p>')
                body.append("".join(t))
        nav = "<nav><b>Contents</b><ol>" + "".join(toc) + "</ol></nav>"
        return (
            '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>"
            + body[0]
            + nav
            + "\n".join(body[1:])
            + "</body></html>\n"
        )


def data_uri(path: Path) -> str:
    """The file at ``path`` as a ``data:`` URI (base64; media type from its suffix)."""
    kind = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
    return f"data:{kind};base64," + base64.b64encode(path.read_bytes()).decode("ascii")


_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;max-width:1100px;
margin:2em auto;padding:0 1em;color:#222;line-height:1.45}
h1{border-bottom:2px solid #444}h2{border-bottom:1px solid #bbb;margin-top:2em}
table{border-collapse:collapse;margin:.6em 0;font-size:.9em}
th,td{border:1px solid #ccc;padding:.25em .55em;text-align:center}
td:first-child,th:first-child{text-align:left}table.text td,table.text th{text-align:left}
thead{background:#f0f0f0}tr.paper td{color:#666;font-style:italic;background:#fafafa}
figure{margin:1em 0}img{max-width:100%;border:1px solid #ddd}
figcaption{font-size:.9em;color:#444}
.note{font-size:.85em;color:#555;margin-top:-.2em}
pre{background:#f6f6f6;padding:.6em;overflow-x:auto;font-size:.85em}
nav{background:#f7f7f7;border:1px solid #ddd;padding:.5em 1em;margin:1em 0}
code{background:#f3f3f3;padding:0 .2em}
"""
