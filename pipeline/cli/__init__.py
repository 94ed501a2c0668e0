"""The ``zipon`` command line. Only this package turns errors into messages and exit codes.

:mod:`pipeline.cli.common` holds the app and what the commands share; importing :mod:`pipeline.cli.build` and
:mod:`pipeline.cli.inspect` here registers their commands on it.
"""

from __future__ import annotations

import sys

import typer
from rich.markup import escape

from pipeline.cli import build, inspect
from pipeline.cli.common import app, console
from pipeline.errors import ZiponError

__all__ = ["app", "build", "entry", "inspect", "main"]


def main(argv: list[str] | None = None) -> int:
    """Console entry: run the app; turn zipon errors and OS errors (disk full, read-only, permissions)
    into a one-line message naming the path and exit code 1; usage errors exit 2."""
    from typer._click.exceptions import ClickException

    from pipeline.errors import os_error_message

    try:
        # standalone_mode=False: typer RETURNS the code of typer.Exit(n) instead of raising it.
        code = app(args=argv, standalone_mode=False, prog_name="zipon")
    except ZiponError as err:
        console.print(f"[red]error:[/red] {escape(str(err))}", highlight=False, soft_wrap=True)
        return 1
    except OSError as err:  # after ZiponError: MissingInputError is a FileNotFoundError too
        console.print(f"[red]error:[/red] {escape(os_error_message(err, output=_outside_workspace(err)))}",
                      highlight=False, soft_wrap=True)
        return 1
    except typer.Exit as e:
        return e.exit_code
    except typer.Abort:
        console.print("aborted")
        return 130
    except ClickException as e:  # usage errors: typer's own message and exit code 2
        e.show()
        return e.exit_code
    return code if isinstance(code, int) else 0


def _outside_workspace(err: OSError) -> bool:
    """Whether the path of ``err`` lies outside the data and manifests roots (an output the user named)."""
    from pathlib import Path

    from pipeline.cli.common import G

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
