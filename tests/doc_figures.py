"""Figure markers: a figure in README.md or docs/*.md names the results file and key it comes from, and this
module checks that the figure still equals what the file holds (pure: json, re, pathlib).

A marker is an HTML comment (invisible once rendered) placed after the figure, on the same line::

    both 960.6 N <!-- fig: results/paper_table/maps_25ms.json#/plants/rigid/stats/both/backward/mean -->

The figure is the last number before the marker on its line (other markers skipped; units and words may stand
between them). A marker inside code (a fenced block or an inline span) is an example, not a marker. The body is ``PATH#QUERY`` followed by optional ``fmt=SPEC`` and ``scale=X``:

- ``PATH``: a JSON file, relative to the repository root.
- ``QUERY``: slash-separated steps, as in a JSON pointer (``~1`` stands for ``/`` in a key, ``~0`` for ``~``):

  - a dict key (``mean``, ``0.95``) or a list index (``3``);
  - ``*``: every item of a list (or every value of a dict);
  - ``[k=v,k2=v2]``: the items of a list of dicts whose fields equal those values (numbers compared as numbers);

  a space, comma, ``%`` or ``|`` inside a key or value is written URL-encoded (``%20``, ``%2C``, ``%25``, ``%7C``);

  after a ``*`` or a ``[...]`` the following steps apply to each selected item. The query may end with
  ``|len``, ``|sum``, ``|min``, ``|max`` or ``|mean`` (chainable) over the selected values; without one the
  selection must be exactly one value.
- ``scale=X`` multiplies the value (``scale=100`` for a percentage).
- ``fmt=SPEC``: the figure must equal ``format(value, SPEC)`` exactly. Without it the figure must equal the
  value rounded to the figure's own decimals (``696.4`` matches 696.4375, ``0.2555`` does not match 0.256,
  ``6.4e-4`` matches 6.38e-4).

``python tests/doc_figures.py`` lists every marker that does not hold; ``tests/test_doc_figures.py`` runs the
same check over README.md and docs/*.md.
"""
from __future__ import annotations

import json
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import unquote

ROOT = Path(__file__).resolve().parents[1]
MARKER = re.compile(r"<!--\s*fig:(?P<body>.*?)-->", re.S)
#: a figure: digits with an optional fraction; a minus sign counts at the start of a word only ("11.4-78.4" is a range)
FIGURE = re.compile(r"-?\d+(?:\.\d+)?(?:e[-+]?\d+)?")
CODE = re.compile(r"^(```|~~~).*?^\1[^\n]*$|`[^`\n]*`", re.M | re.S)
OPS = {"len": len, "sum": sum, "min": min, "max": max, "mean": lambda xs: sum(xs) / len(xs)}


class MarkerError(ValueError):
    """A marker that cannot be read or resolved: bad syntax, no figure before it, a missing file or key."""


@dataclass(frozen=True)
class Marker:
    doc: str        #: the document, relative to the root
    line: int       #: 1-based line of the marker
    figure: str     #: the figure's text in the document
    path: str       #: the results file
    query: str      #: the query in the file
    fmt: str | None = None
    scale: float = 1.0

    def where(self) -> str:
        return f"{self.doc}:{self.line}: {self.figure} <- {self.path}#{self.query}"


def _last_figure(before: str) -> str | None:
    """The last number of ``before`` (the line up to the marker, other markers removed)."""
    text = MARKER.sub("", before)
    found = None
    for m in FIGURE.finditer(text):
        start = m.start()
        s = m.group()
        if s.startswith("-") and not (start == 0 or text[start - 1] in " \t(["):
            s, start = s[1:], start + 1          # a range's dash, not a minus sign
        if start > 0 and (text[start - 1].isalnum() or text[start - 1] in "_."):
            continue                             # part of a word or of a longer token (p_d, v2, x.5)
        found = s
    return found


def _mask_code(text: str) -> str:
    """``text`` with code (fenced blocks, inline spans) blanked, line breaks kept: a marker there is an example."""
    return CODE.sub(lambda m: re.sub(r"[^\n]", " ", m.group()), text)


def parse(text: str, doc: str = "") -> list[Marker]:
    """The markers of a document, in order (none inside code); :class:`MarkerError` for one that is malformed or
    has no figure."""
    out = []
    text = _mask_code(text)
    for m in MARKER.finditer(text):
        line_no = text.count("\n", 0, m.start()) + 1
        line_start = text.rfind("\n", 0, m.start()) + 1
        parts = m.group("body").split()
        if not parts or "#" not in parts[0]:
            raise MarkerError(f"{doc}:{line_no}: marker needs PATH#QUERY, got {m.group(0)!r}")
        path, query = parts[0].split("#", 1)
        opts = {}
        for p in parts[1:]:
            k, sep, v = p.partition("=")
            if not sep or k not in ("fmt", "scale"):
                raise MarkerError(f"{doc}:{line_no}: unknown marker option {p!r} (fmt=SPEC, scale=X)")
            opts[k] = v
        figure = _last_figure(text[line_start:m.start()])
        if figure is None:
            raise MarkerError(f"{doc}:{line_no}: no figure before the marker {m.group(0)!r}")
        try:
            scale = float(opts.get("scale", 1.0))
        except ValueError as exc:
            raise MarkerError(f"{doc}:{line_no}: scale must be a number, got {opts['scale']!r}") from exc
        out.append(Marker(doc, line_no, figure, path, query, opts.get("fmt"), scale))
    return out


def _same(a, b) -> bool:
    if isinstance(a, (int, float)) and not isinstance(a, bool):
        try:
            return float(b) == float(a)
        except ValueError:
            return False
    return str(a) == b


def _step(node, step: str):
    if isinstance(node, dict):
        if step in node:
            return node[step]
    elif isinstance(node, list) and re.fullmatch(r"\d+", step):
        if int(step) < len(node):
            return node[int(step)]
    raise KeyError(step)


def resolve(doc: object, query: str):
    """The value (or, after a ``*`` / ``[...]`` with an operation, the aggregate) that ``query`` names in ``doc``."""
    pointer, *ops = query.split("|")
    if not pointer.startswith("/"):
        raise MarkerError(f"query {query!r} must start with '/'")
    nodes, many = [doc], False
    for raw in pointer[1:].split("/") if pointer != "/" else []:
        step = unquote(raw.replace("~1", "/").replace("~0", "~"))
        nxt = []
        for node in nodes:
            if step == "*":
                if not isinstance(node, (list, dict)):
                    raise MarkerError(f"'*' over a {type(node).__name__} in {query!r}")
                nxt.extend(node if isinstance(node, list) else node.values())
                many = True
            elif step.startswith("[") and step.endswith("]"):
                if not isinstance(node, list):
                    raise MarkerError(f"{step} over a {type(node).__name__} in {query!r}")
                conds = [[unquote(x) for x in c.split("=", 1)] for c in raw[1:-1].split(",") if c]
                if any(len(c) != 2 for c in conds):
                    raise MarkerError(f"a filter is [key=value,...], got {step!r} in {query!r}")
                nxt.extend(x for x in node if isinstance(x, dict)
                           and all(k in x and _same(x[k], v) for k, v in conds))
                many = True
            else:
                try:
                    nxt.append(_step(node, step))
                except KeyError:
                    raise MarkerError(f"no key {step!r} in {query!r}") from None
        nodes = nxt
    value = nodes if many else nodes[0]
    for op in ops:
        if op not in OPS:
            raise MarkerError(f"unknown operation |{op} in {query!r} (one of {', '.join(OPS)})")
        if not isinstance(value, list):
            raise MarkerError(f"|{op} needs a selection ('*' or '[...]') in {query!r}")
        if op != "len" and not value:
            raise MarkerError(f"|{op} of an empty selection in {query!r}")
        value = OPS[op](value)
    if isinstance(value, list):
        if len(value) != 1:
            raise MarkerError(f"{query!r} selects {len(value)} values; end it with |len, |sum, |min, |max or |mean")
        value = value[0]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise MarkerError(f"{query!r} gives {value!r}, not a number")
    return value


def matches(figure: str, value: float, fmt: str | None = None) -> bool:
    """Whether a document's figure shows ``value``: ``format(value, fmt)`` when a format is given, else the value
    rounded to the figure's decimals (half a unit of its last digit)."""
    if fmt is not None:
        return format(value, fmt) == figure
    mantissa, _e, exponent = figure.partition("e")
    decimals = (len(mantissa.split(".", 1)[1]) if "." in mantissa else 0) - int(exponent or 0)
    return math.isfinite(value) and abs(value - float(figure)) <= 0.5 * 10.0 ** -decimals * (1 + 1e-9)


def check_marker(marker: Marker, root: Path = ROOT, cache: dict | None = None) -> str | None:
    """None when the marker holds, else the reason it does not."""
    cache = {} if cache is None else cache
    path = root / marker.path
    if marker.path not in cache:
        try:
            cache[marker.path] = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            cache[marker.path] = MarkerError(f"cannot read {marker.path}: {exc}")
    doc = cache[marker.path]
    if isinstance(doc, MarkerError):
        return str(doc)
    try:
        value = resolve(doc, marker.query) * marker.scale
    except MarkerError as exc:
        return f"{marker.path}: {exc}"
    if not matches(marker.figure, value, marker.fmt):
        shown = format(value, marker.fmt) if marker.fmt else repr(value)
        return f"the document says {marker.figure}, the file gives {shown}"
    return None


def documents(root: Path = ROOT) -> list[Path]:
    """README.md and docs/*.md."""
    return [p for p in [root / "README.md"] if p.exists()] + sorted((root / "docs").glob("*.md"))


def check(root: Path = ROOT) -> tuple[list[Marker], list[str]]:
    """Every marker of the documents and the problems found (one line each: where, then why)."""
    markers, problems, cache = [], [], {}
    for p in documents(root):
        rel = p.relative_to(root).as_posix()
        try:
            found = parse(p.read_text(encoding="utf-8"), rel)
        except MarkerError as exc:
            problems.append(str(exc))
            continue
        markers.extend(found)
        for mk in found:
            why = check_marker(mk, root, cache)
            if why is not None:
                problems.append(f"{mk.where()}: {why}")
    return markers, problems


def main() -> int:
    markers, problems = check()
    for line in problems:
        print(line)
    print(f"{len(markers)} markers in {len({m.doc for m in markers})} documents, {len(problems)} problems")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
