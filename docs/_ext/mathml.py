"""MkDocs hook: the pages' math as MathML, rendered by the browser itself (no JavaScript, no CDN: offline).

``pymdownx.arithmatex`` (generic mode) finds ``$...$`` and ``$$...$$`` in the Markdown and protects them as
``<span class="arithmatex">\\(...\\)</span>`` and ``<div class="arithmatex">\\[...\\]</div>``; this hook converts the
LaTeX inside to MathML with ``latex2mathml`` when the page's HTML is ready. A formula latex2mathml cannot read fails
the build with its text.
"""

from __future__ import annotations

import html
import re

from latex2mathml.converter import convert

BLOCK = re.compile(r'<div class="arithmatex">\s*\\\[(.*?)\\\]\s*</div>', re.S)
INLINE = re.compile(r'<span class="arithmatex">\\\((.*?)\\\)</span>', re.S)


def _mathml(latex: str, display: str, page) -> str:
    source = html.unescape(latex).strip()
    try:
        return convert(source, display=display)
    except Exception as error:  # latex2mathml raises its own exception types; report the formula whatever it was
        raise ValueError(f"{page.file.src_path}: cannot convert the formula {source!r} to MathML: {error}") from error


def on_page_content(content: str, page, config, files) -> str:
    content = BLOCK.sub(lambda m: _mathml(m.group(1), "block", page), content)
    return INLINE.sub(lambda m: _mathml(m.group(1), "inline", page), content)
