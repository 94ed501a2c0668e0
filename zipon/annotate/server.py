"""The annotation server: a Starlette app over one workspace (params file + data root).

Every endpoint answers JSON (or a PNG); errors are ``{"error": message, "field": path}`` with a 4xx status and
change nothing. Safety: a token is required when one is set (``zipon annotate`` sets one for any host but
127.0.0.1), writes must come from the page's own origin, request bodies are capped, file paths the page names must
stay inside the workspace, and a scene whose stage lock another run holds is refused with that holder named.
"""

from __future__ import annotations

import difflib
import math
import re
import threading
from pathlib import Path

from starlette.applications import Starlette
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from pipeline.errors import ConfigError, InputDataError
from zipon.annotate.objects import objects_get, objects_save, objects_validate
from zipon.annotate.http import (LOOPBACK, MAX_BODY, TOKEN_COOKIE, HTTPError, client_error, endpoint,
                                 error_response, guard, integer, number, server_error)

STATIC = Path(__file__).resolve().parent / "static"

class Workbench:
    """The server's state: the workspace, the open scenes' views, one lock per scene that serialises its saves (the
    ETag is checked inside it) and one that serialises writes of the params file."""

    def __init__(self, params=None, data_dir=None, manifests_dir=None, *, overrides=(), scene=None, token=None,
                 allowed_hosts=LOOPBACK, max_body=MAX_BODY):
        from pipeline.paths import Workspace

        self.workspace = Workspace.resolve(params, data_dir, manifests_dir)
        self.overrides = tuple(overrides)
        self.token = token
        self.allowed_hosts = tuple(allowed_hosts) if allowed_hosts is not None else None
        self.max_body = max_body
        self._views: dict = {}
        self._plays: dict = {}  # id -> zipon.annotate.play.PlaySession
        self._locks: dict[str, threading.Lock] = {}
        self._locks_guard = threading.Lock()
        self._params_write = threading.Lock()  # every save records its edit in the one params file
        self.default_scene = scene
        if scene is not None:  # an unknown scene fails at start, naming the known ones
            known = self.dataset().params.scenes
            if scene not in known:
                raise ConfigError(f"unknown scene {scene!r}; params scenes: {sorted(known)}")

    def dataset(self):
        from pipeline.paramsfile import load_params
        from zipon.api import Dataset

        return Dataset(self.workspace, load_params(self.workspace.params_path, self.overrides))

    def scene(self, name: str):
        from zipon.annotate.scene import SceneView

        if name not in self._views:
            ds = self.dataset()
            if name not in ds.params.scenes:
                raise HTTPError(404, f"unknown scene {name!r}; params scenes: {sorted(ds.params.scenes)}", "scene")
            self._views[name] = SceneView(ds[name])
        return self._views[name]

    def warm(self) -> None:
        """Read the first scene's summary and what its layers share (:meth:`SceneView.warm`) and import what a save
        imports (torch and open3d, through the stage runner's thread limits), so the first page and the first save
        do not wait for them. ``zipon annotate`` runs it in a thread while the server starts."""
        from pipeline.engine.process import limit_native_threads

        ds = self.dataset()
        name = self.default_scene or next(iter(ds.params.scenes), None)
        if name is not None and self.workspace.artifact("recon", name).exists():
            view = self.scene(name)
            view.summary()
            view.warm()
        limit_native_threads(ds.params.run.threads_per_worker)

    def forget(self, name: str) -> None:
        self._views.pop(name, None)

    def scene_lock(self, name: str) -> threading.Lock:
        with self._locks_guard:
            return self._locks.setdefault(name, threading.Lock())

    def write_policy(self):
        """Where objects files may be written, with the params as they are now (:mod:`zipon.annotate.writes`)."""
        from zipon.annotate.writes import WritePolicy

        return WritePolicy(self.workspace, self.dataset().params.goals.objects_files)

    def lock_holder(self, scene: str) -> str | None:
        """``"pid P on host H holds PATH"`` for a live lock on any of the scene's stages, else None."""
        from pipeline.engine.locks import holder_is_dead, parse_holder

        folder = self.workspace.artifact("frames", scene).parent
        for path in sorted(folder.glob(".*.lock")) if folder.is_dir() else ():
            try:
                holder = parse_holder(path.read_text(encoding="utf-8"))
            except OSError:
                continue
            if not holder_is_dead(holder):
                who = f"pid {holder[0]} on host {holder[1]}" if holder else "a process that did not record itself"
                return f"{who} holds {path}"
        return None

    def refuse_if_locked(self, scene: str) -> None:
        holder = self.lock_holder(scene)
        if holder:
            raise HTTPError(409, f"scene {scene} is being rebuilt by another zipon run: {holder}; try again when it "
                                 f"has finished", "scene")


def _floor(request: Request, view) -> int | None:
    """The ``floor`` query parameter checked against the scene's floors (a 400 naming the floors it has); None when
    absent."""
    from zipon.annotate.floors import floors_named

    if "floor" not in request.query_params:
        return None
    floor, n = integer(request.query_params["floor"], "floor", -10**6, 10**6), len(view.recon.floors)
    if not 0 <= floor < n:
        raise HTTPError(400, f"floor {floor}: scene {view.name} has {n} floor{'s' if n != 1 else ''}: "
                             f"{floors_named(view.recon)}", "floor")
    return floor


def _png(data: bytes) -> Response:
    return Response(data, media_type="image/png", headers={"Cache-Control": "no-store"})


# ----------------------------------------------------------------------------- pages and scene reading

async def index(request: Request):
    try:
        wb = guard(request)
    except HTTPError as err:
        return error_response(err)
    response = FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-store"})
    if wb.token is not None:
        response.set_cookie(TOKEN_COOKIE, wb.token, httponly=True, samesite="strict")
    return response


@endpoint()
def scenes(request, wb, body):
    ds = wb.dataset()
    return {"scenes": [{"name": s, "built": [a for a in ("frames", "recon", "vlmap", "cfmap", "goals", "routes")
                                             if wb.workspace.artifact(a, s).exists()],
                        "locked": wb.lock_holder(s)} for s in ds.params.scenes],
            "default": wb.default_scene or next(iter(ds.params.scenes), None)}


@endpoint()
def scene_summary(request, wb, body):
    view = wb.scene(request.path_params["scene"])
    if not view.has("recon"):
        raise HTTPError(404, f"scene {view.name} has no recon.zarr (build it: zipon run -s {view.name})", "recon")
    return view.summary()


@endpoint()
def layer(request, wb, body):
    """A layer of the floor shown: the whole grid one pixel per cell, or (``region=x0,y0,x1,y1`` metres, ``px``
    the most pixels on the longer side) the window the page shows, painted from the tiles it meets
    (:mod:`zipon.annotate.layers`). Headers say what the picture covers: ``X-Zipon-Extent`` (x0,x1,y0,y1 metres)
    and ``X-Zipon-Stride`` (cells per pixel)."""
    from pipeline.region import parse_region

    view = wb.scene(request.path_params["scene"])
    q = request.query_params
    region = parse_region(q["region"], "region") if "region" in q else None
    px = integer(q["px"], "px", 16, 16384) if "px" in q else None
    data, picture = view.layer(request.path_params["name"], _floor(request, view) or 0, region, px)
    return Response(data, media_type="image/png", headers={
        "Cache-Control": "no-store", "X-Zipon-Stride": str(picture.stride),
        "X-Zipon-Extent": ",".join(f"{v:.4f}" for v in picture.extent_xy)})


@endpoint()
def seen(request, wb, body):
    view = wb.scene(request.path_params["scene"])
    return view.seen(number(request, "x"), number(request, "y"), _floor(request, view) or 0)


@endpoint()
def frame(request, wb, body):
    view = wb.scene(request.path_params["scene"])
    pixel = None
    if "u" in request.query_params or "v" in request.query_params:
        pixel = (integer(number(request, "u"), "u", -10**6, 10**6), integer(number(request, "v"), "v", -10**6, 10**6))
    return _png(view.ego_png(integer(request.path_params["index"], "index", 0, 10**9), pixel))


@endpoint()
def propose(request, wb, body):
    view = wb.scene(request.path_params["scene"])
    which = request.query_params.get("map", "vlmap")
    if which not in ("vlmap", "cfmap"):
        raise HTTPError(400, f"map {which!r}: choose vlmap or cfmap", "map")
    if not view.has(which):
        raise HTTPError(404, f"scene {view.name} has no {which}.zarr (build it: zipon run -s {view.name} --stage "
                             f"{which})", "map")
    text = (request.query_params.get("text") or "").strip()
    if not text or len(text) > 200:
        raise HTTPError(400, "give the class or phrase to look for (1 to 200 characters)", "text")
    return view.propose(which, text, _floor(request, view) or 0)


@endpoint()
def route(request, wb, body):
    view = wb.scene(request.path_params["scene"])
    keys = [k for k in (request.query_params.get("objects") or "").split(",") if k]
    # no x and y: from the recording's start pose (and its floor), where the goals stage's procedural feedback
    # starts; x and y stand on ``floor`` (default 0)
    start = None if "x" not in request.query_params and "y" not in request.query_params else (
        number(request, "x"), number(request, "y"), math.radians(number(request, "yaw_deg", 0.0)))
    return view.route(start, keys, _floor(request, view))


# ----------------------------------------------------------------------------- goals: read, validate, save, history

def _current(view) -> tuple[object, str]:
    from pipeline.goals.schema import document_digest

    goals = view.goals
    if goals is None:
        raise HTTPError(404, f"scene {view.name} has no goals.zarr (build it: zipon run -s {view.name} --stage goals)",
                        "goals")
    return goals.document, document_digest(goals.document)


@endpoint()
def goals_get(request, wb, body):
    from pipeline.goals.schema import document_dict

    doc, digest = _current(wb.scene(request.path_params["scene"]))
    return JSONResponse({"document": document_dict(doc), "digest": digest}, headers={"ETag": f'"{digest}"'})


def _validated(view, body: dict):
    """The body's ``document`` through ``zipon goals import``'s checks (schema, then the scene's objects)."""
    from pipeline.goals.edits import check_document
    from pipeline.goals.schema import document_from_data

    _current(view)
    if "document" not in body:
        raise HTTPError(400, "the body needs a 'document' (the goals document)", "document")
    origin = "the edited goals"
    try:
        return check_document(document_from_data(body["document"], origin), view.goals.path, origin=origin)
    except InputDataError as err:
        raise HTTPError(422, str(err), err.field, ok=False) from None


@endpoint(write=True)
def goals_validate(request, wb, body):
    from pipeline.goals.schema import document_digest

    view = wb.scene(request.path_params["scene"])
    doc = _validated(view, body)
    from zipon.annotate.scene import descriptive_warnings

    return {"ok": True, "digest": document_digest(doc), "warnings": descriptive_warnings(doc, view.goals)}


def _if_match(request: Request, digest: str) -> None:
    given = request.headers.get("if-match")
    if not given:
        raise HTTPError(428, "If-Match is required: send the ETag of the goals you edited", "If-Match")
    if given.strip().strip('"') != digest:
        raise HTTPError(412, "the goals changed since you opened them; download your edit, reload and apply it "
                             "again", "If-Match", current=digest)


def _save(request, wb, doc) -> dict:
    """The goals save transaction, serialised per scene: the ETag is compared inside the scene's lock with the goals
    as stored now, so of two saves sent with the same If-Match one is saved and the other answers 412."""
    from pipeline.goals.edits import EditNotSaved, save_goals_edit
    from stages import STAGES

    scene = request.path_params["scene"]
    with wb.scene_lock(scene):
        wb.forget(scene)  # read the goals as stored now, not as an earlier request saw them
        _, digest = _current(wb.scene(scene))
        _if_match(request, digest)
        wb.refuse_if_locked(scene)
        try:
            with wb._params_write:
                saved = save_goals_edit(wb.workspace, scene, doc, STAGES, overrides=wb.overrides)
        except EditNotSaved as err:
            raise HTTPError(422, f"not saved: {err}", "dvc.lock" if err.step == "dvc.lock" else "rebuild",
                            saved=False, failed_step=err.step, restored=list(err.restored),
                            outcomes=[_outcome(o) for o in err.outcomes]) from None
        finally:
            wb.forget(scene)
        _, etag = _current(wb.scene(scene))
    return {"saved": saved.path, "digest": saved.digest, "etag": etag, "dvc": saved.dvc_note,
            "steps": ["edit stored", "goals and routes rebuilt", f"{wb.workspace.params_path.name} goals.edits."
                      f"{scene} set", saved.dvc_note or "dvc.lock: nothing to record"],
            "outcomes": [_outcome(o) for o in saved.outcomes]}


def _outcome(o) -> dict:
    return {"stage": o.stage, "status": o.status, "seconds": round(o.seconds, 2), "note": o.reason or o.error}


@endpoint(write=True)
def goals_save(request, wb, body):
    result = _save(request, wb, _validated(wb.scene(request.path_params["scene"]), body))
    return JSONResponse(result, headers={"ETag": f'"{result["etag"]}"'})


def _edits(wb, scene: str) -> list[Path]:
    from pipeline.goals.edits import EDITS_DIR

    folder = wb.workspace.root / EDITS_DIR
    return sorted(folder.glob(f"{scene}-*.yaml"), key=lambda p: p.stat().st_mtime) if folder.is_dir() else []


@endpoint()
def history(request, wb, body):
    import datetime

    from pipeline.goals.edits import EDITS_DIR

    scene = request.path_params["scene"]
    wb.scene(scene)
    current = wb.dataset().params.goals.edits.get(scene)
    return {"edits": [{"digest": p.stem.removeprefix(f"{scene}-"), "path": f"{EDITS_DIR}/{p.name}",
                       "time": datetime.datetime.fromtimestamp(p.stat().st_mtime, datetime.timezone.utc)
                       .isoformat(timespec="seconds"), "current": f"{EDITS_DIR}/{p.name}" == current}
                      for p in reversed(_edits(wb, scene))]}


def _stored(wb, scene: str, digest: str):
    from pipeline.goals.schema import load_document

    if not re.fullmatch(r"[0-9a-f]{6,64}", digest):
        raise HTTPError(400, f"{digest!r} is not an edit digest (hex)", "digest")
    for p in _edits(wb, scene):
        if p.stem == f"{scene}-{digest}":
            return p, load_document(p)
    raise HTTPError(404, f"no stored edit {digest} of scene {scene}", "digest")


@endpoint()
def history_show(request, wb, body):
    from pipeline.goals.schema import document_dict, dump_document

    scene, digest = request.path_params["scene"], request.path_params["digest"]
    current, _ = _current(wb.scene(scene))
    path, doc = _stored(wb, scene, digest)
    diff = difflib.unified_diff(dump_document(current, ".yaml").splitlines(), dump_document(doc, ".yaml").splitlines(),
                                "current", path.name, lineterm="")
    return {"digest": digest, "document": document_dict(doc), "diff": "\n".join(diff)}


@endpoint(write=True)
def history_restore(request, wb, body):
    scene, digest = request.path_params["scene"], request.path_params["digest"]
    view = wb.scene(scene)
    _current(view)
    _, doc = _stored(wb, scene, digest)
    from pipeline.goals.edits import check_document

    check_document(doc, view.goals.path, origin=f"stored edit {digest}")
    result = _save(request, wb, doc)
    return JSONResponse(result, headers={"ETag": f'"{result["etag"]}"'})


@endpoint()
def feedback_kinds(request, wb, body):
    """The feedback kinds of the registry (:data:`pipeline.goals.feedback.FEEDBACK_KINDS`), in the goals document's
    order: the page makes one field of each, edited as the kind's ``form`` says."""
    from pipeline.goals.feedback import FEEDBACK_KINDS
    from pipeline.goals.schema import Feedback

    empty = Feedback().model_dump(mode="json")
    return {"kinds": [{"name": name, "form": FEEDBACK_KINDS[name].form, "description": info.description or "",
                       "default": empty[name], "new_goal": FEEDBACK_KINDS[name].new_goal}
                      for name, info in Feedback.model_fields.items()]}


# ----------------------------------------------------------------------------- play as the user

MAX_PLAYS = 8  # episodes kept per server (the oldest finished one is dropped first)


@endpoint()
def agents(request, wb, body):
    from orion_eval.agents import all_agents

    return {"agents": [{"name": name, "label": getattr(cls, "label", "") or name} for name, cls in all_agents().items()]}


@endpoint(write=True)
def play_start(request, wb, body):
    from orion_eval.agents import agent_class
    from pipeline import plugins
    from zipon.annotate.play import PlaySession

    scene = request.path_params["scene"]
    view = wb.scene(scene)
    method, goal, seed = body.get("method"), body.get("goal"), body.get("seed", 0)
    if not isinstance(method, str) or agent_class(method) is None:
        raise HTTPError(400, f"unknown agent {method!r}; choose from {plugins.agent_names()}", "method")
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise HTTPError(400, f"seed {seed!r} is not a non-negative integer", "seed")
    if not isinstance(goal, str):
        raise HTTPError(400, "give the goal id to play", "goal")
    wb.refuse_if_locked(scene)
    if len(wb._plays) >= MAX_PLAYS:
        done = [k for k, p in wb._plays.items() if p.result is not None or p.error is not None]
        if not done:
            raise HTTPError(429, f"{MAX_PLAYS} episodes are running; finish one first", "method")
        wb._plays.pop(done[0])
    session = PlaySession(wb.workspace, view.scene.params, scene, method, goal, seed)
    wb._plays[session.id] = session
    session.wait(20.0)
    return session.state()


def _play(request, wb):
    session = wb._plays.get(request.path_params["play"])
    if session is None or session.scene != request.path_params["scene"]:
        raise HTTPError(404, f"no episode {request.path_params['play']!r} is being played here", "play")
    return session


@endpoint()
def play_state(request, wb, body):
    return _play(request, wb).state()


@endpoint(write=True)
def play_reply(request, wb, body):
    session = _play(request, wb)
    text = body.get("text")
    if not isinstance(text, str) or not text.strip() or len(text) > 2000:
        raise HTTPError(400, "the reply must be text of 1 to 2000 characters", "text")
    session.reply(text.strip())
    session.wait(20.0)
    return session.state()


@endpoint()
def play_ego(request, wb, body):
    return _png(_play(request, wb).ego_png())


# ----------------------------------------------------------------------------- the app

def create_app(params=None, data_dir=None, manifests_dir=None, *, scene=None, overrides=(), token=None,
               allowed_hosts=LOOPBACK, max_body=MAX_BODY) -> Starlette:
    """The ASGI app of ``zipon annotate`` over the workspace of ``params`` (default ./params.yaml).

    ``token``: when set, every request must carry it (``?token=`` once, then a cookie). ``allowed_hosts``: Host
    header values served (None: any; the default guards against DNS rebinding on 127.0.0.1)."""
    s = "/api/scenes/{scene}"
    routes = [
        Route("/", index),
        Route("/api/scenes", scenes),
        Route(s, scene_summary),
        Route(s + "/layers/{name}.png", layer),
        Route(s + "/seen", seen),
        Route(s + "/frames/{index}.png", frame),
        Route(s + "/propose", propose),
        Route(s + "/route", route),
        Route(s + "/goals", goals_get, methods=["GET"]),
        Route(s + "/goals", goals_save, methods=["PUT"]),
        Route(s + "/goals/validate", goals_validate, methods=["POST"]),
        Route(s + "/history", history),
        Route(s + "/history/{digest}", history_show),
        Route(s + "/history/{digest}/restore", history_restore, methods=["POST"]),
        Route(s + "/objects", objects_get, methods=["GET"]),
        Route(s + "/objects", objects_save, methods=["PUT"]),
        Route(s + "/objects/validate", objects_validate, methods=["POST"]),
        Route("/api/agents", agents),
        Route("/api/feedback-kinds", feedback_kinds),
        Route(s + "/play", play_start, methods=["POST"]),
        Route(s + "/play/{play}", play_state),
        Route(s + "/play/{play}/reply", play_reply, methods=["POST"]),
        Route(s + "/play/{play}/ego.png", play_ego),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ]
    app = Starlette(routes=routes, exception_handlers={HTTPException: client_error, Exception: server_error})
    app.state.workbench = Workbench(params, data_dir, manifests_dir, overrides=overrides, scene=scene, token=token,
                                    allowed_hosts=allowed_hosts, max_body=max_body)
    return app
