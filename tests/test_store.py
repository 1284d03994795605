"""Content-addressed scene store (service/store.py): ids, atomic layout, LRU, robustness."""

from __future__ import annotations

import json
import threading

import pytest

from scenes.builtin import BUILTIN_NAMES
from scenes.loaders import SceneLoadError
from service.store import (
    InvalidBuiltin,
    InvalidSceneId,
    SceneNotFound,
    SceneProtected,
    SceneStore,
    StoreCorrupted,
    TriangleLimitExceeded,
    UnsupportedFormat,
    builtin_canonical,
    builtin_id,
    upload_id,
    validate_id,
)
from tests.helpers import obj_text


@pytest.fixture
def store(tmp_path):
    return SceneStore(tmp_path, cache_size=2, max_triangles=1000)


def test_ids_are_sha256_of_canonical_upload():
    data = obj_text()
    sid = upload_id("obj", data)
    assert validate_id(sid) == sid and len(sid) == 64
    assert upload_id("obj", data) == sid
    assert upload_id("ply", data) != sid  # the format is part of the content address
    assert upload_id("obj", data + b"\n") != sid


def test_builtin_ids_normalise_params():
    name = BUILTIN_NAMES[0]
    assert builtin_id(name) == builtin_id(name, {"detail": 1, "seed": 0}) == builtin_id(name, {"detail": 1.0})
    assert builtin_id(name, {"detail": 0.5}) != builtin_id(name)
    assert builtin_id(name, {"seed": 1}) != builtin_id(name)
    assert builtin_id(BUILTIN_NAMES[1]) != builtin_id(name)
    canon = json.loads(builtin_canonical(name, {"seed": 3}))
    assert canon == {"builtin": name, "params": {"detail": 1.0, "seed": 3}}
    for bad in ({"detail": 0}, {"detail": float("nan")}, {"seed": 1.5}, {"seed": -1}, {"colour": 1}):
        with pytest.raises(InvalidBuiltin):
            builtin_id(name, bad)


@pytest.mark.parametrize("bad", ["", "abc", "A" * 64, "g" * 64, "../" + "a" * 61, "a" * 65, "a" * 63 + "/"])
def test_invalid_ids_never_touch_paths(store, bad):
    with pytest.raises(InvalidSceneId):
        store.get_meta(bad)
    with pytest.raises(InvalidSceneId):
        store.delete(bad)
    assert bad not in store


def test_builtin_defaults_registered_without_building(tmp_path):
    s = SceneStore(tmp_path)
    metas = s.list()
    defaults = [m for m in metas if m.default]
    assert sorted(m.name for m in defaults) == sorted(BUILTIN_NAMES)
    assert all(m.id == builtin_id(m.name) and m.kind == "builtin" for m in defaults)
    assert s.loads == 0  # metadata only
    assert not any((tmp_path / "scenes").iterdir())  # nothing written for defaults
    with pytest.raises(SceneProtected):
        s.delete(builtin_id(BUILTIN_NAMES[0]))


def test_upload_put_layout_and_dedup(store, tmp_path):
    data = obj_text(2)
    meta, created = store.put_upload(data, "OBJ", name="quads.obj")
    assert created and meta.id == upload_id("obj", data) and meta.format == "obj"
    assert meta.triangles == 4 and meta.objects == 1 and meta.size_bytes == len(data)
    d = tmp_path / "scenes" / meta.id
    assert (d / "source.obj").read_bytes() == data
    assert json.loads((d / "meta.json").read_text())["id"] == meta.id
    assert not [p for p in (tmp_path / "scenes").iterdir() if p.name.startswith(".")]  # no temp left
    again, created2 = store.put_upload(data, "obj", name="other name")
    assert not created2 and again.id == meta.id and again.name == meta.name
    assert store.get_scene(meta.id).n_triangles == 4
    assert store.loads == 0  # the upload's parse was cached


def test_concurrent_identical_uploads_agree(store):
    data = obj_text(3)
    results, errors = [], []

    def put():
        try:
            results.append(store.put_upload(data, "obj"))
        except Exception as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=put) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert len({m.id for m, _ in results}) == 1
    assert sum(created for _, created in results) == 1
    assert len([m for m in store.list() if not m.default]) == 1


@pytest.mark.parametrize("kind", ["upload", "builtin"])
def test_a_scene_deleted_while_an_identical_one_is_stored_is_stored_again(store, kind):
    """Identical upload A finds B's copy there (not created) and B deletes it before A
    reads its meta: A stores it again instead of answering 'not found' (a 404 to a POST)."""
    write_new, raced = store._write_new, []

    def racing_write_new(meta, files):
        if raced:
            return write_new(meta, files)
        raced.append(write_new(meta, files))  # the other request's copy
        store.delete(meta.id)  # ... which it deletes at once
        return False  # this request found it there

    store._write_new = racing_write_new
    meta, created = (store.put_upload(obj_text(3), "obj") if kind == "upload"
                     else store.put_builtin("cornell", {"detail": 0.3}))
    assert raced == [True] and created and store.get_meta(meta.id) == meta


def test_bad_uploads(store):
    with pytest.raises(UnsupportedFormat):
        store.put_upload(obj_text(), "stl")
    with pytest.raises(SceneLoadError):
        store.put_upload(b"\x00\x01garbage", "glb")
    with pytest.raises((SceneLoadError, TriangleLimitExceeded), match="limit is 1,000"):
        store.put_upload(obj_text(501), "obj")  # 1002 triangles > 1000
    assert [m for m in store.list() if not m.default] == []


def test_builtin_with_params_is_stored_and_deletable(store, tmp_path):
    name = "nest"
    meta, created = store.put_builtin(name, {"detail": 0.01, "seed": 2})
    assert created and meta.id == builtin_id(name, {"detail": 0.01, "seed": 2}) and not meta.default
    assert (tmp_path / "scenes" / meta.id / "meta.json").exists()
    assert store.put_builtin(name, {"seed": 2, "detail": 0.01})[1] is False
    default, created = store.put_builtin(name)
    assert not created and default.default
    with pytest.raises(InvalidBuiltin):
        store.put_builtin("no_such_scene")
    with pytest.raises(InvalidBuiltin):
        store.put_builtin(name, {"detail": 1e9})
    with pytest.raises(TriangleLimitExceeded, match="limit is 1,000"):
        store.put_builtin(name, {"detail": 2.0})  # ~134k triangles (defaults are exempt)
    scene = store.get_scene(meta.id)
    exact = store.get_meta(meta.id)
    assert exact.triangles == scene.n_triangles and not exact.triangles_estimated
    store.delete(meta.id)
    with pytest.raises(SceneNotFound):
        store.get_meta(meta.id)
    with pytest.raises(SceneNotFound):
        store.delete(meta.id)


def test_restart_and_corrupt_meta(tmp_path):
    s1 = SceneStore(tmp_path)
    good, _ = s1.put_upload(obj_text(1), "obj", name="good")
    bad, _ = s1.put_upload(obj_text(2), "obj", name="bad")
    (tmp_path / "scenes" / bad.id / "meta.json").write_text("{not json")
    (tmp_path / "scenes" / ("f" * 64)).mkdir()  # a directory without meta.json
    (tmp_path / "scenes" / ".tmp-crashed").mkdir()  # left by a crash mid-write
    s2 = SceneStore(tmp_path)
    ids = [m.id for m in s2.list() if not m.default]
    assert ids == [good.id]
    assert not (tmp_path / "scenes" / ".tmp-crashed").exists()
    with pytest.raises(SceneNotFound):
        s2.get_meta(bad.id)
    assert s2.get_scene(good.id).n_triangles == 2
    # Re-uploading the same content repairs the corrupt entry.
    repaired, _ = s2.put_upload(obj_text(2), "obj", name="bad")
    assert repaired.id == bad.id and s2.get_meta(bad.id).triangles == 4
    # A corrupt entry can be deleted.
    (tmp_path / "scenes" / bad.id / "meta.json").write_text("[]")
    s2.delete(bad.id)
    assert not (tmp_path / "scenes" / bad.id).exists()


def test_tampered_source_is_detected(tmp_path):
    s1 = SceneStore(tmp_path)
    meta, _ = s1.put_upload(obj_text(1), "obj")
    (tmp_path / "scenes" / meta.id / "source.obj").write_bytes(obj_text(2))
    s2 = SceneStore(tmp_path)
    with pytest.raises(StoreCorrupted, match="does not match"):
        s2.get_scene(meta.id)


def test_scene_cache_is_lru(tmp_path):
    s = SceneStore(tmp_path, cache_size=2)
    ids = [s.put_upload(obj_text(1, z=float(k)), "obj")[0].id for k in range(3)]
    s2 = SceneStore(tmp_path, cache_size=2)
    a = s2.get_scene(ids[0])
    assert s2.get_scene(ids[0]) is a and s2.loads == 1
    s2.get_scene(ids[1])
    s2.get_scene(ids[0])  # ids[0] most recent
    s2.get_scene(ids[2])  # evicts ids[1]
    assert s2.cached == 2 and s2.loads == 3
    assert s2.get_scene(ids[0]) is a
    s2.get_scene(ids[1])
    assert s2.loads == 4


def test_concurrent_loads_parse_once(tmp_path):
    s = SceneStore(tmp_path)
    sid = s.put_upload(obj_text(50), "obj")[0].id
    s2 = SceneStore(tmp_path)
    out = []
    threads = [threading.Thread(target=lambda: out.append(s2.get_scene(sid))) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(out) == 8 and all(x is out[0] for x in out) and s2.loads == 1
