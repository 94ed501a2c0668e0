"""Bounded reading of the YAML and JSON files users hand to zipon (params, goal edits, objects files, navchat
JSON, a rosbag2 ``metadata.yaml``, camera JSON): one home for the limits, so a hostile file fails fast with a
message naming it, whatever its shape, and never grows past a few tens of MB.

Limits (:class:`Limits`): the file's size in bytes; the number of YAML nodes *after* alias expansion (a
"billion laughs" document of nine anchors nine times over is refused on its size-as-expanded, counted
without expanding anything); the nesting depth. YAML is first streamed as parser events (counted and
dropped, in libyaml when PyYAML has it), and only a document within every limit is composed into objects.
JSON is parsed by the standard library's C scanner (no aliases; its depth is bounded by the same check).
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from pipeline.errors import InputDataError


@dataclass(frozen=True)
class Limits:
    """What a user file may hold. The defaults keep a worst-case document (every byte a node) under ~1 s
    and ~50 MB of Python objects on a busy machine."""

    max_bytes: int = 4 << 20
    max_nodes: int = 50_000  # YAML scalars, sequences and mappings, counted with aliases expanded
    max_depth: int = 64


DEFAULT_LIMITS = Limits()
_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def read_user_text(path: str | Path, *, limits: Limits = DEFAULT_LIMITS, what: str = "YAML/JSON") -> str:
    """The UTF-8 text of ``path``, refused beyond ``limits.max_bytes`` (at most that many bytes plus one are read)."""
    path = Path(path)
    kind = special_file_kind(path)
    if kind:  # refused before opening: a FIFO would block, /dev/zero never ends, a folder is not a document
        raise InputDataError(f"is {kind}, not a file", path=path, expected=f"a {what} file")
    try:
        with open(path, "rb") as f:
            data = f.read(limits.max_bytes + 1)  # never more: a bigger file (or a pipe that never ends) is refused
    except FileNotFoundError:
        raise InputDataError("file not found", path=path) from None
    except IsADirectoryError:
        raise InputDataError("is a folder", path=path, expected=f"a {what} file") from None
    if len(data) > limits.max_bytes:
        raise InputDataError(f"file holds more than {limits.max_bytes} bytes", path=path,
                             expected=f"a {what} file of at most {limits.max_bytes} bytes")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise InputDataError(f"not UTF-8 text: byte 0x{data[err.start]:02x} at offset {err.start} ({err.reason})",
                             path=path, expected=f"a UTF-8 encoded {what} file") from None


def special_file_kind(path: Path) -> str:
    """What ``path`` is when it is not a regular file (links followed): "a folder", "a FIFO (named pipe)", "a
    character device", "a block device", "a socket"; "" for a regular file or a path that does not exist."""
    import stat

    try:
        mode = os.stat(path).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return ""
    except OSError as err:
        raise InputDataError(f"cannot be read ({err.strerror})", path=path) from None
    for test, kind in ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return kind
    return ""


def _check_yaml_events(loader, origin, limits: Limits) -> None:
    """Stream the parser's events; refuse a document whose alias-expanded node count or depth is over
    ``limits``. ``anchored`` holds each closed anchor's expanded size; an alias to an anchor still open
    is a recursive document."""
    total = 0
    open_counts: list[int] = []  # expanded nodes inside each open collection
    open_anchors: list[str | None] = []
    anchored: dict[str, int] = {}

    def add(n: int) -> None:
        nonlocal total
        total += n
        if open_counts:
            open_counts[-1] += n
        if total > limits.max_nodes:
            raise InputDataError(f"document holds more than {limits.max_nodes} nodes with its aliases expanded",
                                 path=origin, expected=f"at most {limits.max_nodes} nodes (aliases count as copies)")

    while loader.check_event():
        ev = loader.get_event()
        if isinstance(ev, yaml.AliasEvent):
            if ev.anchor not in anchored:
                raise InputDataError(f"alias *{ev.anchor} refers to an anchor that is not closed (a recursive "
                                     "document) or not defined", path=origin, expected="aliases of complete nodes")
            add(anchored[ev.anchor])
        elif isinstance(ev, yaml.ScalarEvent):
            add(1)
            if ev.anchor is not None:
                anchored[ev.anchor] = 1
        elif isinstance(ev, (yaml.SequenceStartEvent, yaml.MappingStartEvent)):
            add(1)
            open_counts.append(1)
            open_anchors.append(ev.anchor)
            if len(open_counts) > limits.max_depth:
                raise InputDataError(f"document is nested deeper than {limits.max_depth} levels", path=origin,
                                     expected=f"at most {limits.max_depth} levels of nesting")
        elif isinstance(ev, (yaml.SequenceEndEvent, yaml.MappingEndEvent)):
            n, anchor = open_counts.pop(), open_anchors.pop()
            if anchor is not None:
                anchored[anchor] = n
        elif isinstance(ev, yaml.DocumentEndEvent):
            anchored.clear()  # anchors are per document


def parse_yaml(text: str, *, origin: str | Path, limits: Limits = DEFAULT_LIMITS) -> Any:
    """One YAML document as plain data (``yaml.safe_load``'s objects) within ``limits``; errors name ``origin``."""
    if len(text.encode("utf-8")) > limits.max_bytes:
        raise InputDataError(f"text is over {limits.max_bytes} bytes", path=origin,
                             expected=f"a YAML document of at most {limits.max_bytes} bytes")
    try:
        loader = _LOADER(text)
        try:
            _check_yaml_events(loader, origin, limits)
        finally:
            loader.dispose()
        loader = _LOADER(text)
        try:
            return loader.get_single_data()
        finally:
            loader.dispose()
    except yaml.YAMLError as err:
        raise InputDataError(f"not valid YAML: {' '.join(str(err).split())}", path=origin) from None
    except InputDataError:  # a limit of the event check (a ValueError too)
        raise
    except ValueError as err:  # an integer of more digits than int() converts (4,300)
        digits = re.search(r"value has (\d+) digits", str(err))
        raise InputDataError(f"holds an integer of {digits.group(1) if digits else 'too many'} digits", path=origin,
                             expected="integers of at most 4,300 digits") from None
    except RecursionError:
        raise InputDataError("document nests too deeply to read", path=origin,
                             expected=f"at most {limits.max_depth} levels of nesting") from None


def parse_json(text: str, *, origin: str | Path, limits: Limits = DEFAULT_LIMITS, finite: bool = False) -> Any:
    """One JSON document within ``limits`` (size, depth); errors name ``origin``. ``finite``: refuse NaN and
    Infinity (JavaScript's JSON has neither)."""
    if len(text.encode("utf-8")) > limits.max_bytes:
        raise InputDataError(f"text is over {limits.max_bytes} bytes", path=origin,
                             expected=f"a JSON document of at most {limits.max_bytes} bytes")
    try:
        data = json.loads(text, parse_constant=_refuse_constant if finite else None)
    except RecursionError:
        raise InputDataError("document nests too deeply to read", path=origin,
                             expected=f"at most {limits.max_depth} levels of nesting") from None
    except ValueError as err:  # JSONDecodeError, or an integer of more digits than int() converts
        raise InputDataError(f"not valid JSON: {err}", path=origin) from None
    depth = _depth(data)
    if depth > limits.max_depth:
        raise InputDataError(f"document is nested {depth} levels deep", path=origin,
                             expected=f"at most {limits.max_depth} levels of nesting")
    return data


def _refuse_constant(name: str):
    raise ValueError(f"{name} is not a number (numbers must be finite)")


def _depth(data: Any) -> int:
    """How deeply lists and dicts nest in ``data`` (walked with a stack, not recursion)."""
    deepest, stack = 0, [(data, 1)]
    while stack:
        node, d = stack.pop()
        if isinstance(node, (list, dict)):
            deepest = max(deepest, d)
            stack.extend((child, d + 1) for child in (node.values() if isinstance(node, dict) else node))
    return deepest


def load_user_file(path: str | Path, *, fmt: str | None = None, limits: Limits = DEFAULT_LIMITS) -> Any:
    """A YAML (``.yaml``/``.yml``) or JSON file (by suffix unless ``fmt`` is 'yaml' or 'json') as plain data,
    within ``limits``; every failure is an :class:`InputDataError` naming the file."""
    path = Path(path)
    fmt = fmt or ("yaml" if path.suffix.lower() in (".yaml", ".yml") else "json")
    text = read_user_text(path, limits=limits, what=fmt.upper())
    return (parse_yaml if fmt == "yaml" else parse_json)(text, origin=path, limits=limits)
