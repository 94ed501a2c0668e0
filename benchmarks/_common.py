"""What the benchmarks share: the repository on ``sys.path`` (they import ``tests.fixtures`` and each other), one
JSON line per result stamped with the host and its load, and the process's peak RSS.

A benchmark run as ``.venv/bin/python benchmarks/bench_x.py`` has ``benchmarks/`` on its path, so it imports this
module as ``_common``.
"""

from __future__ import annotations

import json
import os
import socket
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def emit(**fields) -> None:
    """Print ``fields`` as one JSON line with ``host`` and ``load_avg_1m`` (the machine may be shared: a figure is
    read together with the load it was measured under)."""
    print(json.dumps({**fields, "host": socket.gethostname(), "load_avg_1m": round(os.getloadavg()[0], 2)}),
          flush=True)


from pipeline.engine.process import peak_rss_mb  # noqa: E402,F401  (the one implementation; manifests record it too)
