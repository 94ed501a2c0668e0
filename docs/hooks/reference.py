"""MkDocs hook: the params reference and the CLI reference, generated at build time so they cannot drift.

``params_reference()`` walks the pydantic models of ``params.yaml`` (:class:`pipeline.config.Params` and every
section below it) and ``cli_reference()`` walks the click command tree of the typer app (:data:`zipon.cli.app`).
``on_files`` adds both pages to the site as ``reference/params.md`` and ``reference/cli.md``; ``tests/test_docs.py``
calls the two functions directly.
"""

from __future__ import annotations

import html
import inspect
import json
import re
from types import UnionType
from typing import Annotated, Any, Literal, Union, get_args, get_origin

import typer
from pydantic import BaseModel
from pydantic.fields import FieldInfo

PARAMS_PAGE = "reference/params.md"
CLI_PAGE = "reference/cli.md"

# the unit a key's name ends with (the project's naming rule: cell_size_m, max_pose_gap_s, turn_deg, ...)
_UNIT_SUFFIXES = {"_m": "m", "_m2": "m²", "_mm": "mm", "_s": "s", "_ns": "ns", "_deg": "°", "_rad": "rad",
                  "_hz": "Hz", "_mb": "MB", "_gb": "GB", "_px": "px", "_pixels": "px", "_pct": "%", "_cells": "cells",
                  "_frames": "frames"}
# pydantic's constraint metadata (annotated-types' Gt, Ge, ...): the attribute each one sets, and how it reads
_CONSTRAINTS = (("gt", ">"), ("ge", "≥"), ("lt", "<"), ("le", "≤"), ("multiple_of", "multiple of"),
                ("min_length", "length ≥"), ("max_length", "length ≤"))


# ----------------------------------------------------------------------------- text helpers

def _rst_to_md(text: str) -> str:
    """Docstrings use reST literals and roles (````x````, ``:class:`X```); the pages are Markdown."""
    text = re.sub(r":(?:class|mod|func|meth|data|attr):`~?([^`]+)`", r"`\1`", text)
    return text.replace("``", "`")


def _cell(text: str) -> str:
    """Text safe inside one Markdown table cell: one line, pipes and angle brackets escaped. A code span holding a
    pipe or an angle bracket becomes HTML, since Markdown keeps escapes inside code spans literally."""
    parts = " ".join(str(text).split()).split("`")
    if len(parts) % 2 == 0:  # an unpaired backtick: no code spans
        parts = ["'".join(parts)]
    out = []
    for i, part in enumerate(parts):
        if i % 2 == 0:
            out.append(part.replace("|", "\\|").replace("<", "&lt;").replace(">", "&gt;"))
        elif any(ch in part for ch in "|<>"):
            out.append("<code>" + html.escape(part).replace("|", "&#124;") + "</code>")
        else:
            out.append(f"`{part}`")
    return "".join(out)


def _doc(obj: Any) -> str:
    return _rst_to_md(inspect.cleandoc(obj.__doc__ or "")).strip()


# ----------------------------------------------------------------------------- params

def _constraints(metadata: list[Any]) -> list[str]:
    out = []
    for item in metadata:
        for attr, symbol in _CONSTRAINTS:
            if getattr(item, attr, None) is not None:
                out.append(f"{symbol} {getattr(item, attr)}")
    return out


def _type_name(annotation: Any) -> str:
    """A reader's name for a field type: ``int > 0``, ``'raw' | 'compressed'``, ``[float, float] | null``."""
    origin, args = get_origin(annotation), get_args(annotation)
    if origin is Annotated:
        inner, *metadata = args
        extra = [c for m in metadata for c in (_constraints(m.metadata) if isinstance(m, FieldInfo)
                                                  else _constraints([m]))]
        return " ".join([_type_name(inner), *extra])
    if origin is Literal:
        return " | ".join(json.dumps(a) for a in args)
    if origin in (Union, UnionType):
        names = [_type_name(a) for a in args if a is not type(None)]
        return " | ".join(names + (["null"] if type(None) in args else []))
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"[{_type_name(args[0])}, ...]"
        return "[" + ", ".join(_type_name(a) for a in args) + "]"
    if origin is list:
        return f"[{_type_name(args[0])}, ...]"
    if origin is dict:
        return f"{{{_type_name(args[0])}: {_type_name(args[1])}}}"
    if annotation is Any:
        return "any"
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "section"
    return {bool: "bool", int: "int", float: "float", str: "str"}.get(annotation, getattr(annotation, "__name__",
                                                                                          str(annotation)))


def _plain(value: Any) -> Any:
    if isinstance(value, BaseModel):
        return value.model_dump(mode="json")
    if isinstance(value, (tuple, list)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def _default(info: FieldInfo) -> str:
    if info.is_required():
        return "required"
    value = info.default_factory() if info.default_factory is not None else info.default
    return f"`{json.dumps(_plain(value), ensure_ascii=False)}`"


def _unit(name: str) -> str:
    for suffix in sorted(_UNIT_SUFFIXES, key=len, reverse=True):
        if name.endswith(suffix):
            return _UNIT_SUFFIXES[suffix]
    return ""


def _section_model(annotation: Any) -> type[BaseModel] | None:
    """The section a field holds (``X``, ``X | None``), or None for a plain value."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    if get_origin(annotation) in (Union, UnionType):
        models = [a for a in get_args(annotation) if isinstance(a, type) and issubclass(a, BaseModel)]
        return models[0] if len(models) == 1 else None
    return None


def _mapped_model(annotation: Any) -> type[BaseModel] | None:
    """The section each entry of a ``{name: section}`` field holds (``scenes``), or None."""
    if get_origin(annotation) is dict:
        value = get_args(annotation)[1]
        if isinstance(value, type) and issubclass(value, BaseModel):
            return value
    return None


def _params_section(model: type[BaseModel], path: str, depth: int, out: list[str], optional: bool = False) -> None:
    out += ["", f"{'#' * min(depth, 6)} `{path}`", ""]
    doc = _doc(model)
    if doc:
        out += [doc, ""]
    if optional:
        out += [f"Optional: `{path}` is `null` unless given; when given, these keys apply.", ""]
    rows, subsections = [], []
    for name, info in model.model_fields.items():
        key = f"{path}.{name}"
        section, mapped = _section_model(info.annotation), _mapped_model(info.annotation)
        if section is not None:
            subsections.append((section, key, section is not info.annotation))
            continue
        if mapped is not None:
            subsections.append((mapped, f"{key}.<name>", False))
        kind = " ".join([_type_name(info.annotation), *_constraints(info.metadata)])
        unit = _unit(name)
        kind += f" ({unit})" if unit else ""
        rows.append(f"| `{name}` | {_cell(kind)} | {_cell(_default(info))} | "
                    f"{_cell(_rst_to_md(info.description or ''))} |")
    if rows:
        out += ["| key | type | default | description |", "| --- | --- | --- | --- |", *rows]
    for section, key, is_optional in subsections:
        _params_section(section, key, depth + 1, out, is_optional)


def params_reference() -> str:
    """The params reference page: every section and key of ``params.yaml`` with its type, default, unit,
    constraints and description, read from the pydantic models."""
    from pipeline.config import Params
    from pipeline.paramsfile import MOVED_KEYS

    out = ["# Params reference", "",
           "Every tunable of `params.yaml`, generated from the pydantic models that validate it "
           "(`pipeline.config.Params` and its sections) each time the docs are built. "
           "`zipon params --defaults` prints the same defaults as a commented YAML file, `zipon params --write` "
           "completes a params file in place, and `-S key=value` overrides one key for one run (recorded in the "
           "manifests).", "",
           "Types are strict: `true` is not a number, `\"3\"` is not a number, NaN and infinity are refused, "
           "and an unknown key is an error naming it. Each table lists the keys of the section in its heading "
           "(`grid` → `grid.cell_size_m`); the type column gives the constraints the value must meet and, in "
           "brackets, the unit the key's name states (`_m` metres, `_s` seconds, `_deg` degrees, `_hz` hertz).", ""]
    for name, info in Params.model_fields.items():
        section, mapped = _section_model(info.annotation), _mapped_model(info.annotation)
        if section is not None:
            _params_section(section, name, 2, out)
        elif mapped is not None:
            out += ["", f"## `{name}`", "", _cell(_rst_to_md(info.description or "")), "",
                    f"A mapping; each entry is `{name}.<name>` below.", ""]
            _params_section(mapped, f"{name}.<name>", 3, out)
    out += ["", "## Keys that moved", "",
            "An old key is an error naming its new home, so a params file written for an older zipon fails "
            "loudly instead of being ignored.", "", "| old key | new key |", "| --- | --- |",
            *(f"| `{old}` | `{new}` |" for old, new in MOVED_KEYS.items())]
    return "\n".join(out) + "\n"


# ----------------------------------------------------------------------------- CLI

def _walk(command: Any, path: list[str]) -> list[tuple[list[str], Any]]:
    """The command and every visible command below it, depth first, sub-commands in name order."""
    found = [(path, command)]
    subs = getattr(command, "commands", None) or {}
    for name in sorted(subs):
        if not subs[name].hidden:
            found += _walk(subs[name], [*path, name])
    return found


def _param_rows(command: Any, ctx: typer.Context) -> list[str]:
    """One table row per argument and option: name(s), type, default, help."""
    rows = []
    for param in command.params:
        if getattr(param, "hidden", False):
            continue
        kind = param.display_type(ctx).strip("<>") or "flag"
        if kind.startswith("list[") and kind.endswith("]"):
            kind = f"{kind[5:-1]}, repeatable"
        if kind.endswith(" range"):  # a bounded number: its bounds
            bounds = [f"{symbol} {value}" for symbol, value in (("≥", getattr(param, "min", None)),
                                                                ("≤", getattr(param, "max", None))) if value is not None]
            kind = " ".join([kind.removesuffix(" range"), *bounds])
        if param.param_type_name == "argument":
            name = f"`{param.name.upper()}`"
            kind = f"argument ({kind})" if param.required else f"optional argument ({kind})"
        else:
            name = ", ".join(f"`{n}`" for n in [*param.opts, *param.secondary_opts])
            kind = "flag" if param.is_flag else kind
            if getattr(param, "count", False):  # -v, -vv: a flag counted
                short = min(param.opts, key=len)
                kind = f"flag, repeatable ({short}{short[-1]})"
        help_text = param.help or ""
        if getattr(param, "envvar", None):
            help_text += f" (environment: `{param.envvar}`)"
        shown = None if (callable(param.default) or getattr(param, "is_flag", False)
                         or getattr(param, "count", False)) else param.default
        default = "required" if param.required else ("" if shown in (None, (), []) else f"`{shown}`")
        rows.append(f"| {name} | {_cell(kind)} | {_cell(default)} | {_cell(help_text)} |")
    return rows


def _summary(command: Any) -> str:
    """The first sentence of a command's help, without its examples."""
    first = _rst_to_md(inspect.cleandoc(command.help or "")).split("\n\n", 1)[0]
    first = re.split(r"\bExamples?:", first, maxsplit=1)[0]
    return " ".join(first.split()).rstrip(" .") + "."


def _anchor(words: list[str]) -> str:
    """The id mkdocs' toc gives the heading `` `zipon goals export` ``."""
    return "-".join(w.lower() for w in words)


def cli_commands() -> list[str]:
    """Every command of the ``zipon`` CLI as its full name (``zipon``, ``zipon run``, ``zipon goals export``)."""
    from zipon.cli import app

    return [" ".join(["zipon", *path]) for path, _ in _walk(typer.main.get_command(app), [])]


def cli_reference() -> str:
    """The CLI reference page: every command with its usage, help text and options, read from the typer app."""
    from zipon.cli import app

    root = typer.main.get_command(app)
    out = ["# CLI reference", "",
           "Every `zipon` command with its options, generated from the command-line app itself each time the "
           "docs are built; `zipon COMMAND --help` prints the same help.", "",
           "Exit codes: 0 success; 1 any failure (a stage failed, an artifact does not match its manifest, "
           "something is stale under `--check`, invalid params or input files, a held lock), always with a one-line "
           "message naming the file, key or topic; 2 a usage error (unknown option, missing argument)."]
    commands = _walk(root, [])
    out += ["", "| command | what it does |", "| --- | --- |"]
    out += [f"| [`{' '.join(['zipon', *path])}`](#{_anchor(['zipon', *path])}) | {_cell(_summary(command))} |"
            for path, command in commands[1:]]
    for path, command in commands:
        full = " ".join(["zipon", *path])
        ctx = typer.Context(command, info_name=full)
        pieces = [re.sub(r"\{(\w+)\}", lambda m: m.group(1).upper(), p) for p in command.collect_usage_pieces(ctx)]
        usage = " ".join([full, *pieces])
        out += ["", f"{'#' * min(2 + max(len(path) - 1, 0), 4)} `{full}`", "", "```text", usage, "```", ""]
        doc = _rst_to_md(inspect.cleandoc(command.help or "")).strip()
        if doc:
            out += [doc, ""]
        rows = _param_rows(command, ctx)
        if rows:
            out += ["| option | type | default | description |", "| --- | --- | --- | --- |", *rows]
        if getattr(command, "commands", None):
            subs = [name for name in sorted(command.commands) if not command.commands[name].hidden]
            out += ["", "Commands: " + ", ".join(f"`{full} {name}`" for name in subs) + "."]
    return "\n".join(out) + "\n"


# ----------------------------------------------------------------------------- mkdocs

_ROLE = re.compile(r":(?:class|mod|func|meth|data|attr|exc):(?=<code>)")


def on_page_content(html, page, config, files):
    """Docstrings cite objects with reST roles (``:func:`x```); mkdocstrings renders the literal but keeps the role's
    name before it. Drop the name (mkdocs ``on_page_content`` event)."""
    return _ROLE.sub("", html)


def on_files(files, config):
    """Add the two generated pages to the site (mkdocs ``on_files`` event)."""
    from mkdocs.structure.files import File

    for page, build in ((PARAMS_PAGE, params_reference), (CLI_PAGE, cli_reference)):
        files.append(File.generated(config, page, content=build()))
    return files
