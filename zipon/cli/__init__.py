"""The ``zipon`` command line. Only this package turns errors into messages and exit codes.

:mod:`zipon.cli.common` holds the app and what the commands share; importing :mod:`zipon.cli.build`,
:mod:`zipon.cli.inspect` and :mod:`zipon.cli.project` here registers their commands on it.
"""

from __future__ import annotations

import sys

from rich.markup import escape

from zipon.cli import build, inspect, maps, project
from zipon.cli.common import G, app, console
from pipeline.errors import ZiponError

__all__ = ["app", "build", "entry", "inspect", "main", "maps", "project"]


def main(argv: list[str] | None = None) -> int:
    """Console entry: run the app; turn zipon errors and OS errors (disk full, read-only, permissions)
    into a one-line message naming the path and exit code 1; usage errors exit 2 (typer shows them)."""
    from pipeline.errors import os_error_message

    try:
        # standalone mode: typer prints usage errors (exit 2) and turns typer.Exit(n) into SystemExit(n)
        app(args=argv, prog_name="zipon")
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else 0 if e.code is None else 1
    except ZiponError as err:
        console.print(f"[red]error:[/red] {escape(str(err))}", highlight=False, soft_wrap=True)
        return 1
    except OSError as err:  # after ZiponError: MissingInputError is a FileNotFoundError too
        console.print(f"[red]error:[/red] {escape(os_error_message(err, output=_outside_workspace(err)))}",
                      highlight=False, soft_wrap=True)
        return 1
    return 0


def _outside_workspace(err: OSError) -> bool:
    """Whether the path of ``err`` lies outside the data and manifests roots (an output the user named)."""
    from pathlib import Path

    if err.filename is None:
        return False
    try:
        ws = G.workspace()
        path = Path(err.filename).resolve()
    except (ZiponError, OSError, ValueError):
        return False
    return not any(path.is_relative_to(root) for root in (ws.data_dir, ws.manifests_dir))


def entry() -> None:
    sys.exit(main())
