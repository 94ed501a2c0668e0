"""``zipon annotate``: a local web workbench for a scene's objects, personalized goals and feedback.

:func:`app` returns the ASGI app (for a notebook: ``uvicorn.run(zipon.annotate.app("params.yaml"))``); the command
serves it with uvicorn. The page is plain HTML/JS/CSS shipped in ``static/`` (nothing is loaded from elsewhere)."""

from __future__ import annotations

from zipon.annotate.server import create_app as app

__all__ = ["app"]
