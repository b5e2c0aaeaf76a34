"""A small parser for PVL / ODL labels (PDS3 ``.IMG``/``.LBL``/``.QUB`` and ISIS3 ``.cub`` labels).

Grammar handled (what real MOC, HiRISE, THEMIS, HRSC and ISIS3 products use)::

    statement  := key '=' value [unit] | OBJECT '=' name | END_OBJECT ['=' name]
                | GROUP '=' name | END_GROUP ['=' name] | END
    value      := number | radix#digits# | "quoted" | 'quoted' | bare-word
                | '(' value {',' value} ')' | '{' value {',' value} '}'
    unit       := '<' text '>'

Comments ``/* ... */`` (also spanning lines) and ISIS ``#`` lines are skipped. Keys keep their
spelling (``LINES``, ``Samples``, ``^IMAGE``, ``MRO:BINNING``); :func:`lookup` finds them
case-insensitively. A key repeated in one scope (ISIS ``Table`` objects) becomes a list.

The parser works on text decoded as Latin-1, so character offsets equal byte offsets: the end of
the ``END`` statement is where an attached label stops.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any


class LabelSyntaxError(ValueError):
    """The label text is not valid PVL (message: what was expected and the byte offset)."""


@dataclass(frozen=True)
class Quantity:
    """A number with its unit, e.g. ``4.676 <meters/pixel>`` -> Quantity(4.676, 'meters/pixel')."""

    value: float | int
    unit: str


@dataclass(frozen=True)
class ParsedLabel:
    """A parsed label: the nested statement dictionary and the byte offset just after ``END``."""

    tree: dict[str, Any]
    end_offset: int


_SPACE = re.compile(r"(?:[ \t\r\n\f\v]+|/\*.*?\*/|#[^\n]*)*", re.S)
_KEY = re.compile(r"\^?[A-Za-z_][A-Za-z0-9_:\-]*")
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?(?![A-Za-z0-9_:/.\-])")
_RADIX = re.compile(r"(\d+)#([+-]?[0-9A-Fa-f]+)#")
_BARE = re.compile(r"[^\s,(){}=\"'<>]+")
_UNIT = re.compile(r"<([^>\n]*)>")
_BLOCK_OPEN = {"OBJECT": "END_OBJECT", "GROUP": "END_GROUP", "BEGIN_OBJECT": "END_OBJECT",
               "BEGIN_GROUP": "END_GROUP"}
_BLOCK_CLOSE = {"END_OBJECT", "END_GROUP"}


def parse_label(text: str, start: int = 0) -> ParsedLabel:
    """Parse PVL statements from ``text[start:]`` up to and including ``END``.

    Parameters
    ----------
    text : str
        Label text decoded as Latin-1 (one character per byte).
    start : int
        Offset at which the label begins.

    Returns
    -------
    ParsedLabel

    Raises
    ------
    LabelSyntaxError
        Malformed statement, unbalanced OBJECT/GROUP, non-text byte or no ``END`` before the text ends.
    """
    parser = _Parser(text, start)
    tree = parser.block(closing=None, name=None)
    return ParsedLabel(tree, parser.pos)


class _Parser:
    def __init__(self, text: str, pos: int):
        self.text = text
        self.pos = pos

    def fail(self, message: str) -> LabelSyntaxError:
        snippet = self.text[self.pos:self.pos + 24]
        printable = "".join(c if " " <= c <= "~" else f"\\x{ord(c):02x}" for c in snippet)
        return LabelSyntaxError(f"{message} at byte {self.pos} (text there: \"{printable}\")")

    def skip_space(self) -> None:
        space = _SPACE.match(self.text, self.pos)
        assert space is not None   # the pattern matches the empty string
        self.pos = space.end()

    def block(self, closing: str | None, name: str | None) -> dict[str, Any]:
        scope: dict[str, Any] = {}
        while True:
            self.skip_space()
            if self.pos >= len(self.text):
                what = f"{closing} for {name!r}" if closing else "END statement"
                raise self.fail(f"label ended without its {what}")
            match = _KEY.match(self.text, self.pos)
            if match is None:
                raise self.fail("expected a keyword")
            key = match.group(0)
            upper = key.upper()
            self.pos = match.end()
            if upper == "END":
                if closing is not None:
                    raise self.fail(f"END reached inside {name!r} (missing {closing})")
                self._skip_end_line()
                return scope
            if upper in _BLOCK_CLOSE:
                if closing is None or upper != closing:
                    raise self.fail(f"unexpected {key} (no open {upper[4:]})")
                if self._peek_equals():
                    self._expect_equals()
                    self._value()  # closing name: optional and not checked strictly (ISIS omits it)
                return scope
            self._expect_equals()
            if upper in _BLOCK_OPEN:
                child_name = self._value()
                if not isinstance(child_name, str):
                    raise self.fail(f"{key} needs a name")
                child = self.block(_BLOCK_OPEN[upper], child_name)
                _insert(scope, child_name, child)
            else:
                _insert(scope, key, self._value_with_unit())

    def _skip_end_line(self) -> None:
        # The END statement ends the label; consume the rest of its line (spaces, CR, LF).
        match = re.compile(r"[ \t]*(?:\r\n|\n\r|\n|\r)?").match(self.text, self.pos)
        assert match is not None   # the pattern matches the empty string
        self.pos = match.end()

    def _peek_equals(self) -> bool:
        saved = self.pos
        self.skip_space()
        found = self.text.startswith("=", self.pos)
        self.pos = saved
        return found

    def _expect_equals(self) -> None:
        self.skip_space()
        if not self.text.startswith("=", self.pos):
            raise self.fail("expected '='")
        self.pos += 1

    def _value_with_unit(self) -> Any:
        value = self._value()
        saved = self.pos
        self.skip_space()
        unit = _UNIT.match(self.text, self.pos)
        if unit is not None:
            self.pos = unit.end()
            if isinstance(value, (int, float)):
                return Quantity(value, unit.group(1).strip())
            return value
        self.pos = saved
        return value

    def _value(self) -> Any:
        self.skip_space()
        text, pos = self.text, self.pos
        if pos >= len(text):
            raise self.fail("expected a value")
        char = text[pos]
        if char in "({":
            closer = ")" if char == "(" else "}"
            self.pos += 1
            items: list[Any] = []
            while True:
                self.skip_space()
                if self.text.startswith(closer, self.pos):
                    self.pos += 1
                    return items
                items.append(self._value_with_unit())
                self.skip_space()
                if self.text.startswith(",", self.pos):
                    self.pos += 1
                elif not self.text.startswith(closer, self.pos):
                    raise self.fail(f"expected ',' or '{closer}' in a sequence")
        if char in "\"'":
            end = text.find(char, pos + 1)
            if end < 0:
                raise self.fail("unterminated quoted string")
            self.pos = end + 1
            body = text[pos + 1:end]
            if any(ord(c) < 9 or 13 < ord(c) < 32 or ord(c) > 126 for c in body):
                raise self.fail("non-text byte inside a quoted string")
            return " ".join(body.split()) if "\n" in body else body
        match = _RADIX.match(text, pos)
        if match is not None:
            self.pos = match.end()
            try:
                return int(match.group(2), int(match.group(1)))
            except ValueError:
                raise self.fail("invalid radix integer") from None
        match = _NUMBER.match(text, pos)
        if match is not None:
            self.pos = match.end()
            token = match.group(0)
            if re.fullmatch(r"[+-]?\d+", token):
                return int(token)
            return float(token)
        match = _BARE.match(text, pos)
        if match is None:
            raise self.fail("expected a value")
        token = match.group(0)
        if any(ord(c) < 32 or ord(c) > 126 for c in token):
            raise self.fail("non-text byte in the label")
        self.pos = match.end()
        return token


def _insert(scope: dict[str, Any], key: str, value: Any) -> None:
    if key in scope:
        existing = scope[key]
        if isinstance(existing, _Repeated):
            existing.append(value)
        else:
            scope[key] = _Repeated([existing, value])
    else:
        scope[key] = value


class _Repeated(list):
    """Values of a key that occurs more than once in the same scope (in file order)."""


def lookup(scope: dict[str, Any], *names: str, default: Any = None) -> Any:
    """Value of the first of ``names`` present in ``scope`` (case-insensitive), else ``default``."""
    lowered = {key.lower(): key for key in scope}
    for name in names:
        key = lowered.get(name.lower())
        if key is not None:
            return scope[key]
    return default


def to_plain(tree: Any) -> Any:
    """The label as plain Python containers (repeated keys as lists, quantities as (value, unit))."""
    if isinstance(tree, dict):
        return {key: to_plain(value) for key, value in tree.items()}
    if isinstance(tree, list):
        return [to_plain(value) for value in tree]
    return tree
