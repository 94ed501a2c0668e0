"""User agents from installed packages: the ``zipon.agents`` entry-point group, by name in the API and the CLI."""

import json

import pytest

import zipon
from zipon.cli import main
from pipeline.errors import ConfigError
from tests.fixtures.user_agents import plugin_distribution
from orion_eval.agents import agent_class
from pipeline import plugins as registry


@pytest.fixture
def plugins(tmp_path, monkeypatch):
    plugin_distribution(tmp_path / "site", {
        "nearest_plugin": "tests.fixtures.user_agents:PluginNearest",
        "broken": "tests.fixtures.no_such_module:Agent",
        "not_an_agent": "json:dumps",
        "misnamed": "tests.fixtures.user_agents:NearestOnly",
    })
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    yield tmp_path
    from orion_eval.agents import AGENTS

    AGENTS.pop("nearest_plugin", None)  # the registry keeps what it loaded: not beyond this package's life


def test_entry_points_resolve_and_bad_ones_are_named(plugins):
    from tests.fixtures.user_agents import PluginNearest

    assert {"nearest_plugin", "broken"} <= set(registry.agent_names()) - set(registry.BUILT_IN_AGENTS)
    assert agent_class("nearest_plugin") is PluginNearest
    assert agent_class("nobody") is None
    with pytest.raises(ConfigError, match=r"agent 'broken': zipon.agents entry point 'broken' \(tests.fixtures."
                                          r"no_such_module:Agent\) of package 'zipon-example-agents': import failed"):
        agent_class("broken")
    with pytest.raises(ConfigError, match="is not a subclass of orion_eval.agents.Agent"):
        agent_class("not_an_agent")
    with pytest.raises(ConfigError, match="whose `name` is 'nearest_only'; they must agree"):
        agent_class("misnamed")


def test_plugin_agent_evaluates_by_name_from_python_and_the_cli(built_scene, plugins, tmp_path):
    ws, _ = built_scene
    ds = zipon.open(ws.params_path, data_dir=ws.data_dir, manifests_dir=ws.manifests_dir)
    res = zipon.run_eval(ds, tmp_path / "api", agents=["nearest_plugin"], feedback=["yesno"], seeds=1, report=False)
    assert res["overall"]["nearest_plugin"]["yesno"]["episodes"] > 0
    code = main(["-q", "-p", str(ws.params_path), "--data-dir", str(ws.data_dir), "--manifests-dir",
                 str(ws.manifests_dir), "eval", "-o", str(tmp_path / "cli"), "-m", "nearest_plugin", "-f", "yesno",
                 "--seeds", "1"])
    assert code == 0
    cli_res = json.loads((tmp_path / "cli" / "results.json").read_text())
    strip = lambda r: [{k: v for k, v in e.items() if k != "seconds"} for e in r["episodes"]]  # noqa: E731
    assert strip(cli_res) == strip(res)
