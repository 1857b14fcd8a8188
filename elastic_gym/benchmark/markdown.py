"""Text from a card (labels, names, commands) made safe for a markdown page or a figure.

A card is data anyone can write: its strings reach the page only through `text` (plain
text in a paragraph or a table cell: no HTML, no markdown markup, no cell or line break)
or `code` (an inline code span), and reach a figure through `plot_text` (no mathtext).
"""

from __future__ import annotations

import html
import re

_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f\u2028\u2029]+")
_MARKUP = str.maketrans(
    {
        "|": "&#124;",
        "\\": "&#92;",
        "`": "&#96;",
        "*": "&#42;",
        "_": "&#95;",
        "[": "&#91;",
        "]": "&#93;",
        "#": "&#35;",
        "!": "&#33;",
        "~": "&#126;",
    }
)
PLOT_LABEL = 40  # characters of a label in a figure


def one_line(value: object) -> str:
    """``value`` as a string with every run of control characters (line breaks, tabs)
    replaced by one space."""
    return _CONTROL.sub(" ", str(value)).strip()


def text(value: object) -> str:
    """Plain text for markdown: HTML special characters and markdown markup as character
    references, on one line; a table cell stays one cell."""
    return html.escape(one_line(value), quote=True).translate(_MARKUP)


def code(value: object) -> str:
    """An inline code span showing ``value`` literally (as HTML ``<code>`` when a backtick
    or a ``|`` would end the span or the table cell)."""
    shown = one_line(value)
    if "`" in shown or "|" in shown:
        return "<code>" + html.escape(shown, quote=True).replace("|", "&#124;") + "</code>"
    return f"`{shown}`"


def plot_text(value: object, limit: int = PLOT_LABEL) -> str:
    """A label for a matplotlib figure: one line, at most ``limit`` characters, ``$``
    escaped (no mathtext)."""
    shown = one_line(value)
    if len(shown) > limit:
        shown = shown[: limit - 1] + "\N{HORIZONTAL ELLIPSIS}"
    return shown.replace("$", r"\$")
