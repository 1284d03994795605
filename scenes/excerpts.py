"""How much of its input an error message repeats: a value is quoted whole when
short, else its start and its length (so that no error echoes a large input)."""

from __future__ import annotations

from typing import Any

#: Longest excerpt of an input value an error message repeats (characters).
EXCERPT_CHARS = 80


def cut(text: str, limit: int = EXCERPT_CHARS) -> str:
    """`text` when at most `limit` characters, else its first `limit` characters,
    an ellipsis and the full length."""
    return text if len(text) <= limit else f"{text[:limit]}… ({len(text):,} characters)"


def quoted(value: Any, limit: int = EXCERPT_CHARS) -> str:
    """repr(value), `cut` to `limit` characters."""
    return cut(repr(value), limit)
