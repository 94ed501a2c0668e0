"""CLI start-up: process wall time (median of N runs) of ``zipon --help``, ``status``, ``params`` and ``query``.

Each command runs as its own process (``.venv/bin/zipon`` or ``python -m``-free entry: the console
script of this environment), in a workspace folder holding ``params.yaml`` and, for the query, a built
vlmap (``zipon demo`` makes one). Per command it prints the median and all wall times, the median
CPU seconds (user + sys of the child), the target (``--help``/``status``/``params`` 1 s,
``query`` 1.5 s) and the machine's load average, which on a shared machine inflates wall times.
In the same run it times two references the commands cannot beat, so a figure reads on a loaded machine
too: the bare interpreter (``python -c pass``) and the third-party imports every command needs (typer,
rich, pydantic, yaml); each command's row gives its CPU above the second (``cpu_over_imports_s``).
With ``--importtime`` it also prints the slowest top-level imports of each command
(``python -X importtime``). One JSON object per line on stdout.

The children write and reuse bytecode (``__pycache__``) as an installed zipon does, whatever
``PYTHONDONTWRITEBYTECODE`` says here (``--no-bytecode`` keeps it: every run then compiles each module).

    .venv/bin/python benchmarks/bench_cli.py --workspace . [--scene sim_00] [--text chair] [--repeats 5]
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

from _common import ROOT, emit

TARGETS_S = {"--help": 1.0, "status": 1.0, "params": 1.0, "query": 1.5}
ENTRY = "import sys; from zipon.cli import main; sys.exit(main(sys.argv[1:]))"
REFERENCES = {"python -c pass": "pass", "import typer, rich, pydantic, yaml": "import typer, rich.console, pydantic, yaml"}
KEEP_BYTECODE_SETTING = False  # --no-bytecode sets it


def run_once(cmd: list[str], cwd: Path, extra: tuple[str, ...] = (), code: str = ENTRY,
             ) -> tuple[float, float, subprocess.CompletedProcess]:
    """(wall seconds, child CPU seconds, the finished process) of ``zipon CMD`` (or of python running ``code``)."""
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "DVC_NO_ANALYTICS": "1", "PYTHONPATH": str(ROOT)}
    if not KEEP_BYTECODE_SETTING:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, *extra, "-c", code, *cmd], cwd=cwd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, proc


def slowest_imports(stderr: str, top: int) -> list[list]:
    """``[[module, cumulative seconds], ...]`` of the ``top`` slowest imports directly under ``pipeline``/``zipon``
    or third-party roots (``python -X importtime`` lines)."""
    rows = []
    for line in stderr.splitlines():
        if not line.startswith("import time:") or "|" not in line:
            continue
        _, cum, name = (part.strip() for part in line[len("import time:"):].split("|"))
        if cum.isdigit() and "." not in name.strip():
            rows.append([name.strip(), round(int(cum) / 1e6, 3)])
    return sorted(rows, key=lambda r: -r[1])[:top]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workspace", type=Path, default=Path.cwd(), help="folder with params.yaml (and built maps)")
    ap.add_argument("--scene", default=None, help="scene to query (default: the first with a vlmap)")
    ap.add_argument("--text", default="chair")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--importtime", action="store_true", help="also list the slowest imports of each command")
    ap.add_argument("--no-bytecode", action="store_true", help="keep PYTHONDONTWRITEBYTECODE for the children")
    args = ap.parse_args()
    global KEEP_BYTECODE_SETTING
    KEEP_BYTECODE_SETTING = args.no_bytecode
    ws = args.workspace.resolve()
    if not (ws / "params.yaml").is_file():
        sys.exit(f"{ws}: no params.yaml (pass --workspace, e.g. the folder where you ran zipon demo)")
    scene = args.scene
    if scene is None:
        maps = sorted((ws / "data" / "artifacts").glob("*/vlmap.zarr"))
        scene = maps[0].parent.name if maps else None
    commands = {"--help": ["--help"], "status": ["status"], "params": ["params"]}
    if scene is not None:
        commands["query"] = ["query", scene, args.text]
    else:
        emit(bench="cli", kind="skipped", command="query", why=f"no vlmap under {ws}/data/artifacts (run zipon demo)")
    emit(bench="cli", kind="setup", workspace=str(ws), scene=scene, repeats=args.repeats,
         bytecode_cache=not (args.no_bytecode and os.environ.get("PYTHONDONTWRITEBYTECODE")))
    run_once(["status"], ws)  # a first run writes the bytecode the timed ones read
    floor_cpu = 0.0
    for name, code in REFERENCES.items():
        walls, cpus = zip(*(run_once([], ws, code=code)[:2] for _ in range(args.repeats)))
        floor_cpu = round(statistics.median(cpus), 3)
        emit(bench="cli", kind="reference", command=name, median_wall_s=round(statistics.median(walls), 3),
             median_cpu_s=floor_cpu)
    for name, cmd in commands.items():
        walls, cpus = [], []
        for _ in range(args.repeats):
            wall, cpu, proc = run_once(cmd, ws)
            if proc.returncode != 0:
                sys.exit(f"zipon {' '.join(cmd)} exited {proc.returncode}: {proc.stderr[-2000:]}")
            walls.append(wall)
            cpus.append(cpu)
        row = {"bench": "cli", "kind": "command", "command": f"zipon {' '.join(cmd)}",
               "median_wall_s": round(statistics.median(walls), 3), "walls_s": [round(w, 3) for w in walls],
               "median_cpu_s": round(statistics.median(cpus), 3), "target_s": TARGETS_S[name],
               "cpu_over_imports_s": round(statistics.median(cpus) - floor_cpu, 3)}
        if args.importtime:
            _, _, proc = run_once(cmd, ws, extra=("-X", "importtime"))
            row["slowest_imports_s"] = slowest_imports(proc.stderr, 8)
        emit(**row)


if __name__ == "__main__":
    main()
