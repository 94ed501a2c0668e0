"""Goals saves through a real server: serialised per scene with the ETag checked inside the lock (two saves sent at
once with one If-Match: one 200, one 412), and all or nothing (a failed dvc.lock record undoes the edit, the
rebuild and the params change, and the answer says which step failed)."""

from __future__ import annotations

import threading

import httpx
import yaml

from tests.zipon.annotate.conftest import SCENE, tree_state


def test_two_saves_with_one_etag_one_is_saved_the_other_412(served):
    base, root = served
    base = base.rstrip("/")
    first = httpx.get(f"{base}/api/scenes/{SCENE}/goals", timeout=60)
    doc, etag = first.json()["document"], first.headers["etag"]
    edits = []
    for text in ("It is near the window.", "It is by the door."):
        edit = yaml.safe_load(yaml.safe_dump(doc))
        edit["goals"][0]["feedback"]["landmark"] = text
        edits.append(edit)
    answers: list = [None, None]
    go = threading.Barrier(2)

    def save(i: int) -> None:
        with httpx.Client(base_url=base, timeout=300) as c:
            go.wait()
            answers[i] = c.put(f"/api/scenes/{SCENE}/goals", json={"document": edits[i]},
                               headers={"Origin": base, "If-Match": etag})

    threads = [threading.Thread(target=save, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(300)
    statuses = sorted(a.status_code for a in answers)
    assert statuses == [200, 412], [a.text for a in answers]
    won = next(a for a in answers if a.status_code == 200).json()
    lost = next(a for a in answers if a.status_code == 412).json()
    assert lost["field"] == "If-Match" and lost["current"] == won["etag"]
    stored = yaml.safe_load((root / "params.yaml").read_text())["goals"]["edits"][SCENE]
    assert stored == won["saved"] and len(list((root / "goals_edits").glob("*.yaml"))) == 1
    now = httpx.get(f"{base}/api/scenes/{SCENE}/goals", timeout=60)
    assert now.headers["etag"].strip('"') == won["etag"]
    landmark = now.json()["document"]["goals"][0]["feedback"]["landmark"]
    assert landmark == edits[answers.index(next(a for a in answers if a.status_code == 200))]["goals"][0]["feedback"][
        "landmark"]


def test_a_failed_dvc_lock_record_undoes_the_whole_save(own_root, monkeypatch):
    import pipeline.engine.dvcfile
    from pipeline.errors import ZiponError
    from tests.zipon.annotate.conftest import ORIGIN, make_client

    def dvc_fails(*args, **kwargs):
        (own_root / "dvc.lock").write_text("half written by a failing dvc commit\n")
        raise ZiponError("recording them in dvc.lock failed (OSError: disk full)")

    monkeypatch.setattr(pipeline.engine.dvcfile, "sync_dvc_lock", dvc_fails)
    client = make_client(own_root)
    got = client.get(f"/api/scenes/{SCENE}/goals")
    doc, etag = got.json()["document"], got.headers["etag"]
    doc["goals"][0]["feedback"]["landmark"] = "It is near the window."
    before = tree_state(own_root)
    manifests_before = {p: p.read_bytes() for p in (own_root / "manifests" / SCENE).glob("*.json")}
    r = client.put(f"/api/scenes/{SCENE}/goals", json={"document": doc}, headers={"Origin": ORIGIN, "If-Match": etag})
    assert r.status_code == 422, r.text
    body = r.json()
    assert body["saved"] is False and body["failed_step"] == "dvc.lock" and body["field"] == "dvc.lock"
    assert "dvc.lock failed" in body["error"] and "params.yaml unchanged" in body["error"]
    assert body["restored"] == ["goals", "routes"]
    assert not (own_root / "dvc.lock").exists() and not (own_root / "goals_edits").exists()
    assert yaml.safe_load((own_root / "params.yaml").read_text()).get("goals", {}).get("edits", {}) == {}
    assert client.get(f"/api/scenes/{SCENE}/goals").headers["etag"] == etag
    after = tree_state(own_root)
    assert sorted(k for k in before if not k.startswith("data/")) == sorted(k for k in after if not k.startswith("data/"))
    assert {p: p.read_bytes() for p in (own_root / "manifests" / SCENE).glob("*.json")}.keys() == manifests_before.keys()
