"""The evaluator's tests run on the session's start-to-finish scene (tests/conftest.py: ``built_scene``)."""

import pytest


@pytest.fixture(scope="session")
def tiny_scene(built_scene):
    """``(Workspace, Params)`` of a workspace whose scene 'tiny' has every artifact and manifest."""
    return built_scene
