"""Logging: the library logs, the CLI renders.

Library code logs to the ``zipon`` logger (a stage's messages to ``zipon.stages``); it never prints. The
``zipon`` command chooses the level once (:func:`configure`): ``-q`` warnings and errors only, default info,
``-v`` debug, ``-vv`` also the info of the libraries zipon drives (DVC, dask.distributed), which are otherwise
kept to their warnings — DVC's "Updating lock file 'dvc.lock'" per stage, a dask cluster's start-up lines.
A dask worker process has no handler of its own: :func:`ensure_configured` gives it the default rendering.
"""

from __future__ import annotations

import logging

from rich.console import Console
from rich.markup import escape

ROOT = "zipon"
#: the libraries whose own loggers follow ``-vv`` (else: warnings only)
DRIVEN = ("dvc", "distributed", "dask", "fsspec", "s3fs", "botocore", "urllib3")


def get_logger(name: str = "") -> logging.Logger:
    """``zipon`` or ``zipon.<name>``."""
    return logging.getLogger(f"{ROOT}.{name}" if name else ROOT)


def level_of(verbosity: int) -> int:
    """``-1`` (``-q``) -> WARNING, ``0`` -> INFO, ``1`` or more (``-v``) -> DEBUG."""
    return logging.WARNING if verbosity < 0 else logging.INFO if verbosity == 0 else logging.DEBUG


class ConsoleHandler(logging.Handler):
    """One line per record on a rich console (stderr): info as it is, warnings and errors with their level."""

    def __init__(self, console: Console | None = None):
        super().__init__()
        self.console = console or Console(stderr=True)

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = escape(record.getMessage())
            if record.levelno >= logging.WARNING:
                colour = "red" if record.levelno >= logging.ERROR else "yellow"
                text = f"[{colour}]{record.levelname.lower()}:[/{colour}] {text}"
            elif record.levelno < logging.INFO:
                text = f"[dim]{text}[/dim]"
            self.console.print(text, highlight=False, soft_wrap=True)
        except Exception:  # noqa: BLE001 - logging's own contract: a failing handler reports, never raises
            self.handleError(record)


_verbosity = 0  # as configure() last set it


def configure(verbosity: int = 0, console: Console | None = None) -> None:
    """Set the ``zipon`` logger's level and its one console handler, and the driven libraries' levels."""
    global _verbosity
    _verbosity = verbosity
    logger = get_logger()
    logger.setLevel(level_of(verbosity))
    logger.handlers = [ConsoleHandler(console)]
    logger.propagate = False
    tame_driven()


def tame_driven() -> None:
    """(Re)apply the driven libraries' levels: DVC sets its own logger to info with its own handlers when it is
    first imported, so whoever imports it calls this afterwards."""
    for name in DRIVEN:
        logging.getLogger(name).setLevel(logging.INFO if _verbosity >= 2 else logging.WARNING)


def ensure_configured(verbosity: int = 0) -> None:
    """:func:`configure` where nothing configured the ``zipon`` logger yet (a dask worker process)."""
    if not get_logger().handlers:
        configure(verbosity)
