"""The annotation server's request handling: guards, bounded JSON bodies, and errors as JSON.

Every answer to a request the server cannot serve is ``{"error": message, "field": name}`` with a 4xx status,
whatever the client sent: a body nested too deeply, a header or token that is not ASCII, a path parameter of the
wrong shape. :func:`endpoint` wraps a handler so that nothing a client sends can reach the user as a 500; an
error in the server itself is still a JSON 500 (:func:`server_error`), never a plain-text traceback.
"""

from __future__ import annotations

import math
import secrets
import sys

from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import JSONResponse, Response

from pipeline.errors import InputDataError, LockedError, ZiponError
from pipeline.userfiles import Limits, parse_json

MAX_BODY = 2_000_000  # bytes of a request body (a goals document of a few hundred goals is ~200 kB)
TOKEN_COOKIE = "zipon_annotate_token"
LOOPBACK = ("127.0.0.1", "localhost", "::1", "[::1]")


class HTTPError(Exception):
    """A request refused: ``status`` (4xx), a message, the request field it is about, and extra answer keys."""

    def __init__(self, status: int, message: str, field: str | None = None, **extra):
        super().__init__(message)
        self.status, self.message, self.field, self.extra = status, message, field, extra


def _host(request: Request) -> str:
    host = request.headers.get("host") or ""
    return host.rsplit("]", 1)[0] + "]" if "]" in host else host.rsplit(":", 1)[0]


def guard(request: Request, *, write: bool = False):
    """The workbench, once the request passed the Host, token and (for writes) Origin checks."""
    wb = request.app.state.workbench
    host = _host(request)
    if wb.allowed_hosts is not None and host not in wb.allowed_hosts:
        raise HTTPError(403, f"host {host!r} is not served here (allowed: {', '.join(wb.allowed_hosts)})", "Host")
    if wb.token is not None:
        given = (request.query_params.get("token") or request.headers.get("x-zipon-token")
                 or request.cookies.get(TOKEN_COOKIE) or "")
        # compare_digest refuses str with non-ASCII characters (TypeError): compare bytes, which it always takes
        if not secrets.compare_digest(given.encode("utf-8", "surrogateescape"), wb.token.encode()):
            raise HTTPError(403, "a token is needed: open the URL zipon annotate printed (…?token=…)", "token")
    if write:
        origin = request.headers.get("origin")
        own = f"{request.url.scheme}://{request.headers.get('host', '')}"
        if origin != own:
            raise HTTPError(403, f"cross-origin write refused: Origin {origin!r} is not {own!r}", "Origin")
    return wb


async def json_body(request: Request, max_body: int) -> dict:
    """The request's JSON object, read at most ``max_body`` bytes (+ one chunk) into memory; numbers finite,
    nesting within the user files' depth limit (:class:`pipeline.userfiles.Limits`). Every way it can be wrong is an :class:`HTTPError` naming ``body``."""
    length = request.headers.get("content-length")
    if length is not None and length.isascii() and length.isdigit() and int(length) > max_body:
        raise HTTPError(413, f"request body of {int(length):,} bytes is over the {max_body:,}-byte limit", "body")
    chunks, size = [], 0
    async for chunk in request.stream():
        chunks.append(chunk)
        size += len(chunk)
        if size > max_body:
            raise HTTPError(413, f"request body is over the {max_body:,}-byte limit", "body")
    try:
        text = b"".join(chunks).decode("utf-8")
    except UnicodeDecodeError as err:
        raise HTTPError(400, f"the body is not UTF-8 text (byte {err.start})", "body") from None
    try:
        doc = parse_json(text, origin="body", limits=Limits(max_bytes=max_body), finite=True)
    except InputDataError as err:
        reason = str(err).split(": ", 1)[-1]  # without "file the request body: "
        if "nest" in reason:
            raise HTTPError(413, f"the body: {reason}", "body") from None
        raise HTTPError(400, f"the body is not JSON: {reason}", "body") from None
    if not isinstance(doc, dict):
        raise HTTPError(400, "the body must be a JSON object", "body")
    return doc


def number(request: Request, name: str, default: float | None = None) -> float:
    """The finite number in query parameter ``name`` (``default`` when absent, else a 400 naming it)."""
    text = request.query_params.get(name)
    if text is None:
        if default is not None:
            return default
        raise HTTPError(400, f"missing query parameter {name}", name)
    try:
        value = float(text)
    except ValueError:
        raise HTTPError(400, f"{name}={text[:40]!r} is not a number", name) from None
    if not math.isfinite(value):
        raise HTTPError(400, f"{name}={text!r} is not finite", name)
    return value


def integer(value, name: str, low: int, high: int) -> int:
    """``value`` as an integer in ``[low, high]`` (a 400 naming ``name`` otherwise)."""
    try:
        out = int(value)
    except (TypeError, ValueError, OverflowError):
        raise HTTPError(400, f"{name}={str(value)[:40]!r} is not an integer", name) from None
    if not low <= out <= high:
        raise HTTPError(400, f"{name}={out} is outside {low}..{high}", name)
    return out


def error_response(err: Exception) -> JSONResponse:
    if isinstance(err, HTTPError):
        return JSONResponse({"error": err.message, "field": err.field, **err.extra}, status_code=err.status)
    if isinstance(err, LockedError):
        return JSONResponse({"error": str(err), "field": "scene"}, status_code=409)
    if isinstance(err, InputDataError):
        return JSONResponse({"error": str(err), "field": err.field}, status_code=422)
    return JSONResponse({"error": str(err), "field": getattr(err, "field", None)}, status_code=400)


def endpoint(write: bool = False):
    """Wrap a handler ``(request, workbench, body) -> Response|dict``: guard it, read its JSON body (POST, PUT),
    run it off the event loop, and answer every refusal as a JSON error."""
    def wrap(fn):
        async def handler(request: Request):
            try:
                wb = guard(request, write=write)
                body = await json_body(request, wb.max_body) if request.method in ("POST", "PUT") else None
                result = await run_in_threadpool(fn, request, wb, body)
            except (HTTPError, ZiponError) as err:
                return error_response(err)
            except RecursionError:  # a structure from the request too deep for a check that recurses
                return error_response(HTTPError(413, "the request nests too deeply", "body"))
            return result if isinstance(result, Response) else JSONResponse(result)
        handler.__name__ = fn.__name__
        return handler
    return wrap


async def server_error(request: Request, exc: Exception) -> JSONResponse:
    """A failure of the server itself (a bug, not the request): JSON, naming the error; the traceback to stderr."""
    import traceback

    traceback.print_exception(exc, file=sys.stderr)
    return JSONResponse({"error": f"internal error of zipon annotate ({type(exc).__name__}: {exc}); please report "
                                  f"it", "field": None}, status_code=500)


async def client_error(request: Request, exc) -> JSONResponse:
    """Starlette's own refusals (unknown path, wrong method) as JSON errors naming what was wrong."""
    field = "method" if exc.status_code == 405 else "path"
    return JSONResponse({"error": f"{exc.detail}: {request.method} {request.url.path}", "field": field},
                        status_code=exc.status_code)
