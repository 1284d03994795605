"""How much of its input an error message repeats (`scenes.excerpts`, where the
loaders use it too)."""

from scenes.excerpts import EXCERPT_CHARS, cut, quoted

__all__ = ["EXCERPT_CHARS", "cut", "quoted"]
