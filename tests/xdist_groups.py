"""Tests that share a long build run on one pytest-xdist worker, so that it is built once a run, not once a worker.

The suite runs on every core (``-n auto --dist loadgroup`` in pyproject.toml); each worker is its own process with
its own session fixtures. A test joins a group through the builds it uses: one of :data:`SHARED_BUILDS` (conftest
fixtures serving several files), or a module- or session-scoped fixture of its own module (its module's tests, then,
share a worker as they share that fixture). Tests joined through any build they share are one group; the rest are
handed out one at a time.

xdist's own ``loadgroup`` reads ``xdist_group`` marks and appends the group to each test's node id, which pytest 9.2
no longer lets a plugin change (pytest-xdist issue #1386: the groups are silently lost). Here each worker writes the
groups it collected to a file in a folder the controller names, and the controller's scheduler reads them: xdist's
load-by-scope scheduling (largest group first, then more work as a worker runs low) with a test's scope its group.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

import pytest
from xdist.scheduler import LoadScopeScheduling

# conftest builds that take long and serve tests in several files, as (module, fixture)
SHARED_BUILDS = {("tests.conftest", "built_house"), ("tests.conftest", "two_storey_maps"),
                 ("tests.orion_eval.conftest", "tiny_house"), ("tests.pipeline.project.conftest", "dataset_versions"),
                 ("tests.pipeline.recon.conftest", "house"), ("tests.fixtures.s3", "s3_endpoint")}
WORKER_KEY = "zipon_groups_dir"  # the folder, handed to each worker in its workerinput


def builds_used(item) -> list[str]:
    """The builds ``item`` uses: each of :data:`SHARED_BUILDS` as ``module:fixture``, its own module's module- or
    session-scoped fixtures as the module's name."""
    info = getattr(item, "_fixtureinfo", None)
    module = getattr(item, "module", None)
    if info is None or module is None:
        return []
    used = []
    for name in item.fixturenames:
        defs = info.name2fixturedefs.get(name)
        if not defs:
            continue
        where = defs[-1].func.__module__  # the definition this item sees (the innermost)
        if (where, name) in SHARED_BUILDS:
            used.append(f"{where}:{name}")
        elif where == module.__name__ and defs[-1].scope in ("module", "session"):
            used.append(where)
    return used


def groups(items) -> dict[str, str]:
    """``node id -> group`` for the items that use a build: the tests joined through any build they share are one
    group, named by one of its builds."""
    parent: dict[str, str] = {}

    def root(key: str) -> str:
        while parent.setdefault(key, key) != key:
            key = parent[key]
        return key

    uses = [(item.nodeid, builds_used(item)) for item in items]
    for _, builds in uses:
        for other in builds[1:]:
            parent[root(other)] = root(builds[0])
    return {nodeid: root(builds[0]) for nodeid, builds in uses if builds}


class GroupScheduling(LoadScopeScheduling):
    """xdist's scheduling by scope, a test's scope being its group (or the test alone)."""

    def __init__(self, config, log, folder: Path):
        super().__init__(config, log)
        self.folder = folder
        self.groups: dict[str, str] | None = None

    def schedule(self) -> None:
        if self.groups is None:  # every worker has collected (and written its groups) by now; all collected alike
            written = sorted(self.folder.glob("*.json"))
            self.groups = json.loads(written[0].read_text()) if written else {}
        super().schedule()

    def _split_scope(self, nodeid: str) -> str:
        return self.groups.get(nodeid, nodeid) if self.groups else nodeid


class SharedBuilds:
    """The plugin: the controller names the folder and schedules, each worker writes its groups there."""

    def __init__(self):
        self.folder: Path | None = None

    def pytest_configure_node(self, node) -> None:
        if self.folder is None:
            self.folder = Path(tempfile.mkdtemp(prefix="zipon-xdist-groups-"))
        node.workerinput[WORKER_KEY] = str(self.folder)

    def pytest_xdist_make_scheduler(self, config, log):
        if config.getvalue("dist") == "loadgroup" and self.folder is not None:
            return GroupScheduling(config, log, self.folder)
        return None

    @pytest.hookimpl(trylast=True)  # after -k / -m deselection: the ids this worker reports
    def pytest_collection_modifyitems(self, config, items) -> None:
        folder = getattr(config, "workerinput", {}).get(WORKER_KEY)
        if folder:
            path = Path(folder) / f"{config.workerinput['workerid']}.json"
            path.with_suffix(".tmp").write_text(json.dumps(groups(items)))
            os.replace(path.with_suffix(".tmp"), path)

    def pytest_unconfigure(self, config) -> None:
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)
