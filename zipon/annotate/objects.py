"""The annotation server's objects-file endpoints: read the scene's objects file (or its built objects to start
from), check an edited one (the goals stage's checks, and every object and room on a floor the scene has), and
write it where :class:`zipon.annotate.writes.WritePolicy` allows."""

from __future__ import annotations

import json

from starlette.responses import JSONResponse

from pipeline.errors import InputDataError
from zipon.annotate.http import HTTPError, endpoint
from zipon.annotate.writes import OBJECTS_DIR


@endpoint()
def objects_get(request, wb, body):
    """The scene's objects file when it has one, else its built objects (and room outlines) to start from."""
    view = wb.scene(request.path_params["scene"])
    rel = wb.dataset().params.goals.objects_files.get(view.name)
    objset = view.objects_file()
    source = "file"
    if objset is None and view.goals is not None:
        objset, source = view.goals.object_set(), "goals"
    data = {"objects": [], "rooms": []} if objset is None else objset.model_dump(mode="json",
                                                                                   include={"objects", "rooms"})
    if objset is not None and not data["rooms"]:
        data["rooms"] = [{"id": r["id"], "type": r["type"], "polygon": r["polygon"],
                          **({"floor": r["floor"]} if r["floor"] else {})} for r in view._rooms()]
    return {"path": rel or f"{OBJECTS_DIR}/{view.name}.yaml", "objects_dir": f"{OBJECTS_DIR}/", "source": source if objset is not None else "empty", **data}


def _objects(view, body: dict):
    """The body's objects and rooms as an ObjectSet, each on a floor the scene has (when it is reconstructed)."""
    from pipeline.goals.objects import objects_from_data
    from zipon.annotate.floors import check_record_floors

    objset = objects_from_data({"rooms": body.get("rooms", []), "objects": body.get("objects")}, view.name,
                               "the edited objects")
    if view.has("recon"):
        check_record_floors(view.recon, view.name, objset)
    return objset


@endpoint(write=True)
def objects_validate(request, wb, body):
    view = wb.scene(request.path_params["scene"])
    try:
        objset = _objects(view, body)
    except InputDataError as err:
        return JSONResponse({"ok": False, "error": str(err), "field": err.field}, status_code=422)
    return {"ok": True, "objects": len(objset.objects), "rooms": len(objset.rooms)}


@endpoint(write=True)
def objects_save(request, wb, body):
    import yaml

    from pipeline.store import write_text_atomic

    view = wb.scene(request.path_params["scene"])
    path = wb.write_policy().objects_file(body.get("path"), "path")
    try:
        objset = _objects(view, body)
    except InputDataError as err:
        raise HTTPError(422, str(err), err.field) from None
    data = objset.model_dump(mode="json", include={"rooms", "objects"})
    text = (f"# objects of scene {view.name}, written by zipon annotate (the layout zipon goals template starts)\n"
            + (yaml.safe_dump(data, sort_keys=False, allow_unicode=True, width=100) if path.suffix != ".json"
               else json.dumps(data, indent=2)))
    with wb.scene_lock(view.name):
        write_text_atomic(path, text)
        wb.forget(view.name)
    rel = path.relative_to(wb.workspace.root.resolve()).as_posix()
    return {"path": rel, "objects": len(objset.objects), "rooms": len(objset.rooms),
            "next": f"in params.yaml: goals: {{objects: file, objects_files: {{{view.name}: {rel}}}}}"}
