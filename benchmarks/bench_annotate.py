"""``zipon annotate`` timed on a built scene (targets: first paint <= 2 s, a map query's heatmap <= 300 ms, saving a
goals edit <= 10 s including the goals + routes rebuild, on 2 cores).

    .venv/bin/python benchmarks/bench_annotate.py PATH [--scene S] [--text chair] [--no-browser]

PATH is a params.yaml whose scene is built (``zipon demo``, or ``zipon run -s sim_00``). The workspace is copied
to a temporary folder first (saving rewrites goals, routes and the params file there, never in PATH). The server
runs as ``zipon annotate`` runs it: uvicorn on 127.0.0.1, the first scene warmed in a thread while it starts.
Prints one JSON object per line:

- ``start``: seconds until the server answers, and until its warm-up (the scene's summary and layers, the stage
  runner's imports) is done;
- ``first_paint``: headless chromium (Debian's ``/usr/bin/chromium`` through playwright) from navigation to the
  scene drawn (the page sets ``body[data-ready]`` once its summary, goals and first layer image are in); and the
  same three requests over HTTP alone;
- ``query``: the map query's proposals + heatmap endpoint for ``--text`` (default: the class of the first goal):
  the first call (loads the map's features) and the median of five more;
- ``save``: two goals edits saved through the endpoint (If-Match, validation, store, goals + routes rebuilt under
  their locks, params file updated): each one's seconds and its stages' seconds.
"""

from __future__ import annotations

import argparse
import shutil
import socket
import statistics
import tempfile
import threading
import time
from pathlib import Path

from _common import emit


def copy_workspace(params: Path, dst: Path) -> Path:
    from pipeline.paths import Workspace

    ws = Workspace.resolve(params)
    dst.mkdir(parents=True)
    shutil.copy(ws.params_path, dst / "params.yaml")
    skip = shutil.ignore_patterns("renders", ".tmp", "*.lock", ".*.fold", "eval")
    shutil.copytree(ws.data_dir, dst / "data", ignore=skip)
    shutil.copytree(ws.manifests_dir, dst / "manifests")
    if (ws.root / "goals_edits").is_dir():
        shutil.copytree(ws.root / "goals_edits", dst / "goals_edits")
    return dst / "params.yaml"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("params", type=Path, help="params.yaml of a built workspace")
    ap.add_argument("--scene", help="scene (default: the first in the params file)")
    ap.add_argument("--text", help="map query (default: the class of the first goal)")
    ap.add_argument("--no-browser", action="store_true", help="skip the headless chromium measure")
    args = ap.parse_args()

    import httpx
    import uvicorn

    from zipon.annotate import app

    with tempfile.TemporaryDirectory(prefix="bench_annotate_") as tmp:
        params = copy_workspace(args.params, Path(tmp) / "ws")
        t0 = time.perf_counter()
        application = app(params, scene=args.scene)
        wb = application.state.workbench
        warmed = {}
        warm = threading.Thread(target=lambda: (wb.warm(), warmed.setdefault("s", time.perf_counter() - t0)))
        warm.start()
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        server = uvicorn.Server(uvicorn.Config(application, host="127.0.0.1", port=port, log_level="warning"))
        serving = threading.Thread(target=server.run, daemon=True)
        serving.start()
        while not server.started:
            time.sleep(0.01)
        t_up = time.perf_counter() - t0
        warm.join()
        base = f"http://127.0.0.1:{port}"
        try:
            with httpx.Client(base_url=base, timeout=300) as http:
                scene = http.get("/api/scenes").json()["default"]
                emit(bench="annotate", part="start", scene=scene, serving_s=round(t_up, 3),
                     warmed_s=round(warmed["s"], 3))
                paint = first_paint(base, scene) if not args.no_browser else None
                t = time.perf_counter()
                summary = http.get(f"/api/scenes/{scene}").json()
                http.get(f"/api/scenes/{scene}/goals")
                http.get(f"/api/scenes/{scene}/layers/{summary['layers'][0]}.png")
                emit(bench="annotate", part="first_paint", browser_s=paint, http_s=round(time.perf_counter() - t, 3),
                     goal_s=2.0, objects=len(summary["objects"]), goals=len(summary["goals"]),
                     grid=[summary["grid"]["rows"], summary["grid"]["cols"]])
                text = args.text or next(o["cls"] for o in summary["objects"]
                                         if o["key"] == summary["goals"][0]["objects"][0])
                times = []
                for _ in range(6):
                    t = time.perf_counter()
                    r = http.get(f"/api/scenes/{scene}/propose", params={"text": text, "map": "vlmap"})
                    times.append(time.perf_counter() - t)
                    r.raise_for_status()
                emit(bench="annotate", part="query", text=text, first_s=round(times[0], 3),
                     median_s=round(statistics.median(times[1:]), 3), proposals=len(r.json()["proposals"]),
                     query_s=r.json()["seconds"], goal_s=0.3)
                for k in range(2):
                    got = http.get(f"/api/scenes/{scene}/goals")
                    doc, etag = got.json()["document"], got.headers["etag"]
                    doc["goals"][0]["feedback"]["landmark"] = f"It is near the window ({k})."
                    t = time.perf_counter()
                    r = http.put(f"/api/scenes/{scene}/goals", json={"document": doc},
                                 headers={"If-Match": etag, "Origin": base})
                    elapsed = time.perf_counter() - t
                    r.raise_for_status()
                    emit(bench="annotate", part="save", n=k + 1, seconds=round(elapsed, 3), goal_s=10.0,
                         stages={o["stage"]: o["seconds"] for o in r.json()["outcomes"]})
        finally:
            server.should_exit = True
            serving.join(timeout=10)


def first_paint(base: str, scene: str) -> float | None:
    """Seconds from navigation to the page's ``body[data-ready]`` in headless chromium (None without one)."""
    chromium = shutil.which("chromium") or "/usr/bin/chromium"
    if not Path(chromium).exists():
        return None
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=["--no-sandbox"])
        page = browser.new_page(viewport={"width": 1400, "height": 850})
        t = time.perf_counter()
        page.goto(f"{base}/#{scene}")
        page.wait_for_selector(f"body[data-ready={scene}]", timeout=60_000)
        seconds = time.perf_counter() - t
        browser.close()
    return round(seconds, 3)


if __name__ == "__main__":
    main()
