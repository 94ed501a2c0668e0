"""The suite's grouping of tests that share a build (tests/xdist_groups.py), run for real: pytest-xdist on two
workers over a small generated suite."""

import importlib
import re

import pytest

from tests.conftest import REPO
from tests.xdist_groups import SHARED_BUILDS

pytest_plugins = ["pytester"]

SUITE = """
import time

import pytest


@pytest.fixture(scope="module")
def built():
    return object()


@pytest.mark.parametrize("k", range(6))
def test_uses_the_build(built, k):
    time.sleep(0.05)


@pytest.mark.parametrize("k", range(12))
def test_alone(k):
    time.sleep(0.2)
"""


def test_the_tests_sharing_a_modules_build_run_on_one_worker_and_the_rest_on_both(pytester, monkeypatch):
    monkeypatch.setenv("PYTHONPATH", str(REPO))
    pytester.makeconftest("from tests.xdist_groups import SharedBuilds\n\n\n"
                          "def pytest_configure(config):\n"
                          "    config.pluginmanager.register(SharedBuilds(), 'shared-builds')\n")
    pytester.makepyfile(test_suite=SUITE)
    done = pytester.runpytest_subprocess("-n", "2", "--dist", "loadgroup", "-v", "-p", "no:cacheprovider")
    done.assert_outcomes(passed=18)
    ran = {test: worker for worker, test in
           re.findall(r"\[(gw\d)\] \[\s*\d+%\] PASSED test_suite\.py::(\w+\[\d+\])", done.stdout.str())}
    assert len(ran) == 18, done.stdout.str()
    assert len({w for t, w in ran.items() if t.startswith("test_uses_the_build")}) == 1
    assert set(ran.values()) == {"gw0", "gw1"}  # the tests alone were handed to both


@pytest.mark.parametrize("module, fixture", sorted(SHARED_BUILDS))
def test_each_shared_build_names_a_fixture_that_exists(module, fixture):
    assert callable(getattr(importlib.import_module(module), fixture, None)), f"{module} has no fixture {fixture}"
