"""Every stage's config is exactly what its params digest covers: changing any params key outside a stage's
``param_keys`` leaves its config unchanged, changing one inside changes the digest; settings in ``run`` and
``query`` are in no stage's keys; per-scene entries count only for their own scene."""

from pathlib import Path
from types import UnionType
from typing import Any, Literal, Union, get_args, get_origin

import pytest
from pydantic import BaseModel, ValidationError

import yaml

from pipeline.config import GridParams, Params
from pipeline.perception_params import DetectorParams, SimulatedCFParams, SimulatedLSegParams
from pipeline.paramsfile import params_yaml, parse_params
from pipeline.stageconfig import digest_value, project
from stages import STAGES

REPO = Path(__file__).resolve().parents[2]
SCENES = {"s0": {"source": "simulate"}, "r0": {"source": "logs/r0.mcap", "format": "mcap"}}


def _params(**sections) -> Params:
    return parse_params({"scenes": SCENES, **sections})


def _leaves(model: BaseModel, prefix: str = "") -> list[tuple[str, Any, Any]]:
    """(dotted key, value, annotation) of every leaf field under ``model``."""
    out = []
    for name, info in type(model).model_fields.items():
        value = getattr(model, name)
        key = f"{prefix}{name}"
        if isinstance(value, BaseModel):
            out += _leaves(value, key + ".")
        elif key != "scenes":
            out.append((key, value, info.annotation))
    return out


def _other(value: Any, annotation: Any) -> Any:
    """A different value of the same kind (validity beyond the type is not needed: configs are copies)."""
    args = get_args(annotation)
    if get_origin(annotation) in (Union, UnionType):
        lits = [a for a in args if get_origin(a) is Literal]
        choices = [c for lit in lits for c in get_args(lit) if c != value]
        if choices:
            return choices[0]
        if lits:  # the value is the only literal (e.g. 'auto' of int | 'auto'): a value of the other member
            inner = next(a for a in args if get_origin(a) is not Literal and a is not type(None))
            return {float: 0.123, int: 2, str: "x"}[inner]
        if value is None:
            inner = next(a for a in args if a is not type(None))
            if get_origin(inner) is list and issubclass(get_args(inner)[0], BaseModel):  # a list of records
                item = get_args(inner)[0]
                return [item.model_validate({k: 0.123 for k, f in item.model_fields.items() if f.is_required()})]
            return {float: 0.123, int: 7, str: "x.pt", bool: True}.get(inner, ("a", "b"))
        return None
    if get_origin(annotation) is Literal:
        return next(a for a in args if a != value)
    if isinstance(value, bool):
        return not value
    if isinstance(value, (int, float)):
        return value * 1.37 + 1 if isinstance(value, float) else value + 1
    if isinstance(value, str):
        return value + "_other"
    if isinstance(value, tuple):
        return tuple(reversed(value)) if len(set(value)) > 1 else (*value, value[0] if value else 0.5)
    if isinstance(value, dict):
        return {**value, "zz_other_scene": "x.yaml"}
    raise AssertionError(f"no perturbation for {value!r}")


def _replace(params: Params, key: str, value: Any) -> Params:
    head, _, rest = key.partition(".")
    node = getattr(params, head)
    if not rest:
        return params.model_copy(update={head: value})
    return params.model_copy(update={head: _replace(node, rest, value)})


def _covered(key: str, keys: list[str]) -> bool:
    return any(key == k or key.startswith(k + ".") or k.startswith(key + ".") for k in keys)


@pytest.mark.parametrize("scene", ["s0", "r0"])
@pytest.mark.parametrize("stage", list(STAGES))
def test_config_depends_only_on_its_param_keys(stage, scene):
    spec = STAGES[stage]
    base = _params()
    if not spec.applies_to(base, scene):
        pytest.skip("stage does not apply to this scene")
    cls = spec.config_class()
    keys = cls.param_keys(base, scene)
    config = cls.from_params(base, scene).model_dump(mode="json")
    checked = 0
    for key, value, annotation in _leaves(base):
        changed = _replace(base, key, _other(value, annotation))
        try:
            same_config = cls.from_params(changed, scene).model_dump(mode="json", warnings=False) == config
        except ValidationError:  # the perturbed value breaks a cross-field check of its section
            continue
        if not _covered(key, keys):
            assert same_config, f"{stage}/{scene}: {key} changes the config but is not one of its param keys"
            assert key.split(".")[0] not in ("run", "query", "eval") or not any(k.startswith(key.split(".")[0] + ".") for k in keys)
        checked += 1
    assert checked > 100


def test_runtime_and_query_settings_are_in_no_digest():
    base = _params()
    for stage, spec in STAGES.items():
        for scene in SCENES:
            if spec.applies_to(base, scene):
                keys = spec.config_class().param_keys(base, scene)
                assert not [k for k in keys if k.startswith(("run", "query", "eval"))], (stage, keys)


def test_a_map_stage_reads_only_its_own_encoder():
    base = _params(encoders={"simulated": None, "vlmap": "lseg", "cfmap": "conceptfusion"})
    vl = project(base, STAGES["vlmap"].config_class().param_keys(base, "r0"))
    cf = project(base, STAGES["cfmap"].config_class().param_keys(base, "r0"))
    assert "encoders.lseg" in vl and "encoders.conceptfusion" not in vl and "maps.cfmap_voxels" not in vl
    assert "encoders.conceptfusion" in cf and "encoders.lseg" not in cf and "maps.vlmap_weight_sigma_m" not in cf
    crop = _params(encoders={"simulated": None, "lseg": {"crop_size": 320}})
    digest = lambda p, st: digest_value(project(p, STAGES[st].config_class().param_keys(p, "r0")))  # noqa: E731
    assert digest(crop, "vlmap") != digest(base, "vlmap") and digest(crop, "cfmap") == digest(base, "cfmap")


def test_goal_edits_count_only_for_their_scene():
    base = _params()
    edited = _params(goals={"edits": {"s0": "goals/s0-0123456789ab.yaml"}})
    spec = STAGES["goals"]
    for scene, stale in (("s0", True), ("r0", False)):
        before = project(base, spec.config_class().param_keys(base, scene))
        after = project(edited, spec.config_class().param_keys(edited, scene))
        assert (before != after) is stale, scene
    assert spec.config_class().extra_inputs(edited, "s0") == {"goal_edits": "goals/s0-0123456789ab.yaml"}
    assert spec.config_class().extra_inputs(edited, "r0") == {}


def test_a_building_counts_only_for_its_scene_and_an_apartment_keeps_its_digest():
    spec = STAGES["simulate"]
    base = parse_params({"scenes": {"a": {"source": "simulate"}}})
    house = parse_params({"scenes": {"a": {"source": "simulate"},
                                     "h": {"source": "simulate", "building": {"kind": "house", "stories": 3}}}})
    keys = spec.config_class().param_keys
    assert keys(base, "a") == keys(house, "a") == ["simulate"]
    assert project(base, keys(base, "a")) == project(house, keys(house, "a"))  # the apartment is not stale
    assert keys(house, "h") == ["simulate", "scenes.h.building"]
    config = spec.config_class().from_params(house, "h")
    assert config.building.kind == "house" and config.building.stories == 3
    assert spec.config_class().from_params(house, "a").building is None
    assert "building" not in base.scenes["a"].model_dump(mode="json")  # an apartment's entry reads as before


def test_a_minimal_params_file_maps_simulated_scenes_with_simulated_perception():
    params = parse_params({"scenes": {"a": {"source": "simulate"}}})
    assert STAGES["vlmap"].config_class().from_params(params, "a").encoder == "simulated_lseg"
    assert STAGES["cfmap"].config_class().from_params(params, "a").encoder == "simulated_cf"
    oracle = parse_params({"scenes": {"a": {"source": "simulate"}}, "encoders": {"simulated": "oracle"}})
    assert STAGES["vlmap"].config_class().from_params(oracle, "a").encoder == "oracle"  # only when chosen


def test_the_shipped_params_file_is_the_defaults():
    """``zipon params --defaults`` and the shipped params.yaml agree on every key but ``scenes``."""
    shipped = yaml.safe_load((REPO / "params.yaml").read_text())
    defaults = yaml.safe_load(params_yaml(parse_params({"scenes": {"sim_00": {"source": "simulate"}}})))
    shipped.pop("scenes"), defaults.pop("scenes")
    differ = {f"{section}.{key}" for section in shipped.keys() | defaults.keys()
              for key in (shipped.get(section) or {}).keys() | (defaults.get(section) or {}).keys()
              if (shipped.get(section) or {}).get(key, "absent") != (defaults.get(section) or {}).get(key, "absent")}
    assert differ == set()


def test_the_task_facts_have_one_home_read_by_goals_and_routes():
    from pipeline.config import TaskParams

    base = _params()
    task_keys = [f"task.{k}" for k in TaskParams.model_fields]
    routes = STAGES["routes"].config_class().param_keys(base, "s0")
    goals = STAGES["goals"].config_class().param_keys(base, "s0")
    assert set(routes) == {"routes", "task"}  # every task fact: action space, success radius and view, margins
    assert set(goals) >= {"task.success_m", "task.step_m", "task.turn_deg", "task.stop_radius_m", "task.clearance_m"}
    assert "task.hfov_deg" not in goals and not [k for k in goals if k.startswith("routes")]
    # no other section repeats a task fact
    for section in ("routes", "eval"):
        model = type(getattr(base, section))
        assert not set(model.model_fields) & {k.split(".")[1] for k in task_keys}, section
    wide = _params(task={"hfov_deg": 70.0})
    digest = lambda p, st: digest_value(project(p, STAGES[st].config_class().param_keys(p, "s0")))  # noqa: E731
    assert digest(wide, "routes") != digest(base, "routes") and digest(wide, "goals") == digest(base, "goals")


@pytest.mark.parametrize("old, new", [
    ("routes: {step_m: 0.3}", "routes.step_m: moved to task.step_m (the task's facts have one home"),
    ("routes: {turn_deg: 30}", "routes.turn_deg: moved to task.turn_deg"),
    ("routes: {success_m: 1.2}", "routes.success_m: moved to task.success_m"),
    ("routes: {hfov_deg: 79}", "routes.hfov_deg: moved to task.hfov_deg"),
    ("routes: {stop_radius_m: 0.8}", "routes.stop_radius_m: moved to task.stop_radius_m"),
    ("routes: {clearance_m: 0.2}", "routes.clearance_m: moved to task.clearance_m"),
    ("eval: {success_distance_m: 1.5}", "eval.success_distance_m: moved to task.success_m"),
    ("eval: {hfov_deg: 90}", "eval.hfov_deg: moved to task.hfov_deg"),
    ("eval: {clearance_m: 0.1}", "eval.clearance_m: moved to task.clearance_m"),
    ("eval: {stop_radius_m: 1.25}", "eval.stop_radius_m: moved to eval.goto_stop_radius_m (the agents' own stop "
                                    "radius; task.stop_radius_m is where walks to a ground-truth goal aim)"),
])
def test_a_moved_task_key_is_an_error_naming_its_new_home(old, new, tmp_path, capsys):
    from zipon.cli import main

    p = tmp_path / "params.yaml"
    p.write_text("scenes:\n  a: {source: simulate}\n" + old + "\n")
    assert main(["-p", str(p), "status"]) == 1
    err = capsys.readouterr().err.replace("\n", " ")
    assert f"{p}: {new}" in " ".join(err.split())


@pytest.mark.parametrize("section", ["simulate", "ingest", "reconstruct", "maps"])
def test_every_depth_range_is_checked_once_the_same_way(section, tmp_path, capsys):
    from zipon.cli import main
    from pipeline.config import DepthRange

    base = _params()
    sec = getattr(base, section)
    assert isinstance(sec, DepthRange)
    # the keys stay plain fields of the section: what the stages' params digests cover is unchanged
    assert {"depth_min_m", "depth_max_m"} <= set(sec.model_dump())
    p = tmp_path / "params.yaml"
    p.write_text(f"scenes:\n  a: {{source: simulate}}\n{section}: {{depth_min_m: 3.0, depth_max_m: 2.0}}\n")
    assert main(["-p", str(p), "status"]) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert f"{p}: {section}: depth_min_m (3) must be below depth_max_m (2)" in err


@pytest.mark.parametrize("model", [DetectorParams, SimulatedLSegParams, SimulatedCFParams, GridParams])
def test_every_params_model_is_equally_strict(model):
    """One base class for every params model: a number given as a string or a boolean is refused everywhere."""
    field = "seed" if "seed" in model.model_fields else "rows"
    with pytest.raises(ValidationError, match="expected a number, got the string '3'"):
        model(**{field: "3"})
    with pytest.raises(ValidationError, match="expected a number, got true"):
        model(**{field: True})
    with pytest.raises(ValidationError, match="Extra inputs are not permitted"):
        model(unknown_key=1)


def test_the_status_of_a_simulated_scene_loads_no_numpy_zarr_or_torch(tmp_path):
    """``zipon status`` reads every stage's config, code digest and manifests; none of that needs the array
    libraries (their import was most of its second), so a stage module imports its work inside ``run``."""
    import subprocess
    import sys

    probe = (
        "import sys\n"
        "from pipeline.paramsfile import parse_params\n"
        "from pipeline.paths import Workspace\n"
        "from pipeline.engine.stagegraph import plan, staleness\n"
        "from stages import STAGES\n"
        f"ws = Workspace.resolve(None, {str(tmp_path / 'data')!r}, None)\n"
        "params = parse_params({'scenes': {'s0': {'source': 'simulate'}}})\n"
        "reasons = {stage: staleness(ws, params, STAGES, STAGES[stage], scene) for scene, stage in plan(STAGES, params, ['s0'])}\n"
        "assert set(reasons) == set(STAGES) and set(reasons.values()) == {'never run'}, reasons\n"
        "print(sorted(m for m in ('numpy', 'zarr', 'torch', 'open3d', 'scipy') if m in sys.modules))\n"
    )
    done = subprocess.run([sys.executable, "-c", probe], cwd=REPO, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "[]"
