"""Bounded YAML/JSON (pipeline.userfiles): hostile documents of every shape fail in under a second with a message
naming the file, holding well under 200 MB; ordinary documents (anchors and merge keys included) read exactly as
``yaml.safe_load`` / ``json.loads`` read them."""

from __future__ import annotations

import json
import time
import tracemalloc
from pathlib import Path

import pytest
import yaml

from pipeline.paramsfile import load_params
from pipeline.errors import ConfigError, InputDataError
from pipeline.userfiles import DEFAULT_LIMITS, Limits, load_user_file, parse_json, parse_yaml

REPO = Path(__file__).resolve().parents[2]


def laughs(levels: int = 9, width: int = 9) -> str:
    lines = [f"a0: &a0 [{', '.join(['lol'] * width)}]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * width)}]" for i in range(1, levels + 1)]
    return "\n".join(lines) + "\n"


HOSTILE_YAML = {
    "billion-laughs": laughs(),
    "laughs-nested": "scenes: {}\ningest:\n  topics:\n" + "".join(f"    {ln}\n" for ln in laughs().splitlines()),
    "laughs-in-keys": laughs(6) + "k: {? *a6 : 1}\n",
    "recursive-alias": "a: &a [1, *a]\n",
    "undefined-alias": "a: *nowhere\n",
    "deep-flow": "[" * 50_000 + "]" * 50_000,
    "deep-block": "".join("  " * i + f"k{i}:\n" for i in range(200)) + "  " * 200 + "v\n",
    "flat-list-under-byte-limit": "[" + "0," * 1_900_000 + "0]",  # 3.8 MB: the node budget stops it
    "wide-mapping": "{" + ", ".join(f"k{i}: {i}" for i in range(200_000)) + "}",
    "many-documents": "---\na: 1\n" * 50_000,
}


def _measure(fn) -> tuple[BaseException | None, float, float]:
    """(the error ``fn`` raised, seconds, peak MB of Python allocations): timed on its own, then run again under
    tracemalloc (which slows allocation-heavy code several times over)."""
    def run():
        try:
            fn()
        except BaseException as e:  # noqa: BLE001 - returned to the test, which asserts its type
            return e
        return None

    t0 = time.perf_counter()
    err = run()
    seconds = time.perf_counter() - t0
    tracemalloc.start()
    try:
        run()
        peak = tracemalloc.get_traced_memory()[1] / 1e6
    finally:
        tracemalloc.stop()
    return err, seconds, peak


@pytest.mark.parametrize("name", list(HOSTILE_YAML))
def test_hostile_params_fail_fast_and_small(name, tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text(HOSTILE_YAML[name])
    err, seconds, peak_mb = _measure(lambda: load_params(path))
    assert isinstance(err, ConfigError), repr(err)
    assert str(path) in str(err) and "\n" not in str(err)
    assert seconds < 1.0 and peak_mb < 200, (name, seconds, peak_mb)


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_hostile_user_files_fail_fast_and_small(suffix, tmp_path):
    path = tmp_path / f"objects{suffix}"
    text = laughs() if suffix == ".yaml" else "[" * 200_000 + "]" * 200_000
    path.write_text(text)
    err, seconds, peak_mb = _measure(lambda: load_user_file(path))
    assert isinstance(err, InputDataError) and err.path == path, repr(err)
    assert seconds < 1.0 and peak_mb < 200, (seconds, peak_mb)


def test_size_limit_reads_no_more_than_the_limit(tmp_path):
    path = tmp_path / "big.json"
    with open(path, "wb") as f:
        f.truncate(64 * DEFAULT_LIMITS.max_bytes)  # a sparse 256 MiB file: only the first 4 MiB + 1 byte are read
    err, seconds, peak_mb = _measure(lambda: load_user_file(path))
    assert isinstance(err, InputDataError) and f"more than {DEFAULT_LIMITS.max_bytes} bytes" in str(err)
    assert peak_mb < 2 * DEFAULT_LIMITS.max_bytes / 1e6 + 1


def test_limits_are_the_callers_choice():
    tight = Limits(max_bytes=100, max_nodes=10, max_depth=2)
    with pytest.raises(InputDataError, match="more than 10 nodes"):
        parse_yaml("[" + ", ".join("1" * 1 for _ in range(20)) + "]", origin="x.yaml", limits=tight)
    with pytest.raises(InputDataError, match="deeper than 2"):
        parse_yaml("[[[1]]]", origin="x.yaml", limits=tight)
    with pytest.raises(InputDataError, match="nested 3 levels"):
        parse_json("[[[1]]]", origin="x.json", limits=tight)
    with pytest.raises(InputDataError, match="over 100 bytes"):
        parse_json(" " * 101, origin="x.json", limits=tight)


def test_ordinary_documents_read_as_safe_load_reads_them():
    text = "base: &b {voxel: 0.05, frames: 40}\nscene:\n  <<: *b\n  frames: 60\nlist: [*b, *b]\nnum: 1e3\nflag: yes\n"
    assert parse_yaml(text, origin="x.yaml") == yaml.safe_load(text)
    params = (REPO / "params.yaml").read_text()
    assert parse_yaml(params, origin="params.yaml") == yaml.safe_load(params)
    doc = {"a": [1, 2.5, None, True, "ü"], "b": {"c": [[]]}}
    assert parse_json(json.dumps(doc), origin="x.json") == doc


def test_aliases_within_the_budget_are_fine():
    """Seven anchors of three (3**7 = 2,187 leaves in the last one): about 5,000 nodes expanded, under the budget."""
    assert json.dumps(parse_yaml(laughs(7, 3), origin="x.yaml")).count("lol") == sum(3 ** k for k in range(1, 9))


def test_errors_name_the_file_and_what_is_wrong(tmp_path):
    bad = tmp_path / "edit.yaml"
    bad.write_bytes(b"goals: [\n")
    with pytest.raises(InputDataError, match="not valid YAML") as e:
        load_user_file(bad)
    assert e.value.path == bad
    bad.write_bytes(b"a: caf\xe9\n")
    with pytest.raises(InputDataError, match="not UTF-8"):
        load_user_file(bad)
    with pytest.raises(InputDataError, match="file not found"):
        load_user_file(tmp_path / "absent.yaml")
    with pytest.raises(InputDataError, match="is a folder"):
        load_user_file(tmp_path)
    huge = tmp_path / "n.json"
    huge.write_text("1" * 5000)  # more digits than int() converts
    with pytest.raises(InputDataError, match="not valid JSON"):
        load_user_file(huge)
