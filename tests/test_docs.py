"""What in the docs can drift from the code, checked without building the site: the README's opening commands and
length, and the generated CLI and params references against the app and the params models."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest
import typer
from pydantic import BaseModel

from zipon.cli import app
from pipeline.config import Params

ROOT = Path(__file__).resolve().parents[1]
README_OPENING = """# zipon

```bash
./setup.sh && .venv/bin/zipon demo      # set up on a fresh machine, then run the main job on the embedded default data
.venv/bin/python -m pytest -q           # run the tests
```
"""


@pytest.fixture(scope="module")
def reference():
    """docs/hooks/reference.py, the mkdocs hook that generates the reference pages, loaded from its file."""
    spec = importlib.util.spec_from_file_location("docs_reference", ROOT / "docs" / "hooks" / "reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_readme_opens_with_the_two_commands():
    assert (ROOT / "README.md").read_text(encoding="utf-8").startswith(README_OPENING)


def test_readme_is_short():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 200, f"README.md has {len(lines)} lines; the rest belongs in docs/"


def _commands(command, path: tuple[str, ...] = ("zipon",)):
    yield " ".join(path)
    for name, sub in (getattr(command, "commands", None) or {}).items():
        if not sub.hidden:
            yield from _commands(sub, (*path, name))


def test_cli_reference_has_every_command_and_option(reference):
    page = reference.cli_reference()
    root = typer.main.get_command(app)
    commands = list(_commands(root))
    assert len(commands) > 15 and "zipon goals export" in commands
    missing = [c for c in commands if f"## `{c}`" not in page]
    assert not missing, f"commands missing from the CLI reference: {missing}"
    assert sorted(reference.cli_commands()) == sorted(commands)
    options = {opt for c in [root, *root.commands.values()] for p in c.params if p.param_type_name == "option"
               for opt in p.opts}
    assert not [o for o in options if f"`{o}`" not in page]


def _keys(model: type[BaseModel], prefix: str):
    for name, info in model.model_fields.items():
        key = f"{prefix}{name}"
        annotation = info.annotation
        nested = [a for a in (annotation, *getattr(annotation, "__args__", ())) if isinstance(a, type)
                  and issubclass(a, BaseModel)]
        if not nested:
            yield key
        elif getattr(annotation, "__origin__", None) is dict:  # {name: section}, as scenes
            yield from _keys(nested[0], f"{key}.<name>.")
        else:  # a section, or an optional one (section | None)
            yield from _keys(nested[0], f"{key}.")


def _documented_keys(page: str) -> set[str]:
    """Every key the page documents: a table row `| `name` |` under the heading of its section `## `section``."""
    found, section = set(), None
    for line in page.splitlines():
        heading = re.match(r"#+ `([^`]+)`$", line)
        if heading:
            section = heading.group(1)
        row = re.match(r"\| `([^`]+)` \|", line)
        if row and section is not None:
            found.add(f"{section}.{row.group(1)}")
    return found


def test_params_reference_has_every_key(reference):
    keys = list(_keys(Params, ""))
    assert len(keys) > 200 and "maps.level_height_m" in keys and "scenes.<name>.source" in keys
    documented = _documented_keys(reference.params_reference())
    missing = [k for k in keys if k not in documented]
    assert not missing, f"params keys missing from the params reference: {missing}"


def test_params_reference_states_defaults_and_constraints(reference):
    page = reference.params_reference()
    assert "| `cell_size_m` | float &gt; 0 (m) | `0.05` | cell edge, metres |" in page
    assert "| `image_transport` | \"raw\" \\| \"compressed\" | `\"raw\"` |" in page


def test_pages_name_nothing_outside_the_repository():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    assert len(pages) > 10
    outside = re.compile(r"\.\./shared|\bDESIGN\.md\b|\bSTYLE\.md\b|\bissue \d+")
    found = [f"{p.relative_to(ROOT)}: {m.group(0)}" for p in pages
             for m in outside.finditer(p.read_text(encoding="utf-8"))]
    assert not found, f"pages citing what a clone does not have: {found}"
