"""Text from elsewhere shown in markdown: a model's names, summaries, pages and equations, a server's
reasons. viser renders raw HTML in markdown unsanitised, scripts included, and a model may come from
any simulator host, so every such text passes `escape_html` before it reaches a markdown widget. A
server's reason is plain text, not markdown: `escape_text` shows it as written ("2*pi*f*amplitude"
keeps its stars instead of turning into emphasis).
"""

from __future__ import annotations

import re

CODE_RE = re.compile(r"(```.*?```|`[^`\n]*`)", re.S)  # fenced blocks and code spans: shown as typed
TAG_RE = re.compile(r"<(?=[A-Za-z/!?])")  # what would open an HTML tag, comment or declaration


def escape_html(markdown: str) -> str:
    """Raw HTML shown as text; code (which markdown shows as typed) and every markdown mark stay."""
    parts = CODE_RE.split(markdown)
    return "".join(p if k % 2 else TAG_RE.sub("&lt;", p) for k, p in enumerate(parts))


MARK_RE = re.compile(r"([\\`*_\[\]#|~])")  # what markdown would read as a mark, not a character


def escape_text(text: str) -> str:
    """Plain text (a server's reason, a name) shown exactly as written in a markdown widget."""
    return TAG_RE.sub("&lt;", MARK_RE.sub(r"\\\1", text))
