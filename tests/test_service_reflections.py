"""Frames with reflection effects (thesis Ch. 4) through the service."""

from __future__ import annotations

from reference.image_metrics import mean_abs_error
from reference.reflections import raytrace_reflections
from scenes.builtin import make_builtin, mirror
from scenes.camera import Camera
from service import image_io
from service.image_check import assert_images_close
from tests.helpers import MIRROR_CAMERA, service, service_client

RES = 48


client = service_client("mirror")


def frame(c, sid, method, fmt="exr", rays=8):
    r = c.post(f"/scenes/{sid}/frames", json={"camera": MIRROR_CAMERA, "width": RES, "height": RES, "format": fmt,
                                               "effects": {"reflections": method, "glossy_rays": rays}})
    assert r.status_code == 200, r.text
    return r


def test_raytrace_frame_is_the_reference(client):
    """The service's raytrace method returns exactly reference.reflections."""
    c, sid = client
    ch = image_io.decode_exr(frame(c, sid, "raytrace").content)
    scene = make_builtin("mirror")
    cam = Camera(mirror.VIEW_EYE, mirror.VIEW_TARGET, width=RES, height=RES).fit_clip(scene.bounds)
    ref = raytrace_reflections(scene, cam, supersample=2, glossy_rays=8)
    assert_images_close(ch["RGB"], ref.color, tolerance=1e-6, max_bad_fraction=0.0)


def test_cluster_reflections_on_the_planar_mirror_match_embree(client):
    c, sid = client
    ours = image_io.decode_exr(frame(c, sid, "cluster").content)
    ref = image_io.decode_exr(frame(c, sid, "raytrace").content)
    env = image_io.decode_exr(frame(c, sid, "envmap").content)
    refl = ref["specular"] > 0
    assert refl.mean() > 0.05, "the mirror should be in view"
    assert_images_close(ours["RGB"], ref["RGB"], tolerance=1 / 255, max_bad_fraction=1.0)  # the mean only
    # The env-map baseline misses the reflected objects: clearly worse on the mirror.
    assert mean_abs_error(env["RGB"], ref["RGB"], mask=refl) > 5 * mean_abs_error(ours["RGB"], ref["RGB"], mask=refl)
    assert set(ours) >= {"RGB", "reflected", "diffuse", "specular", "ray_length"}


def test_png_reflection_frame_decodes(client):
    c, sid = client
    png = image_io.decode_png(frame(c, sid, "cluster", fmt="png").content)
    assert png.shape == (RES, RES, 3) and png.std() > 1


def test_a_frame_over_the_streamed_size_leaves_no_pass_of_its_size_behind(tmp_path):
    """The worker keeps its cluster renderer between frames up to stream_max_pixels
    (a stream asks for that every frame) and releases it after a larger one
    (Settings.keep_pixels, GLState.end_job); the next frame makes it again."""
    with service(tmp_path, stream_max_pixels=RES * RES) as c:
        sid = c.post("/scenes", json={"builtin": "mirror"}).json()["id"]
        worker = c.app.state.worker

        def held() -> set[str]:
            return worker.submit(lambda st: st.resource_names).result(timeout=60)

        def render(width: int) -> None:
            r = c.post(f"/scenes/{sid}/frames", json={"camera": MIRROR_CAMERA, "width": width, "height": RES,
                                                       "effects": {"reflections": "cluster"}})
            assert r.status_code == 200, r.text

        render(RES)
        assert "reflections" in held()
        render(RES + 1)
        assert "reflections" not in held()
        render(RES)
        assert "reflections" in held()


def _server_timing(r) -> dict[str, tuple[float, str]]:
    """Server-Timing header → {name: (dur ms, desc)}."""
    out = {}
    for part in r.headers["Server-Timing"].split(","):
        name, *params = (p.strip() for p in part.split(";"))
        kv = dict(p.split("=", 1) for p in params)
        out[name] = (float(kv["dur"]), kv.get("desc", "").strip('"'))
    return out


def test_second_reflective_frame_of_a_scene_hits_the_caches_and_names_each_step(tmp_path, monkeypatch):
    """Server-Timing names every step of a reflective frame; the second frame of a
    scene finds its GPU upload and per-scene chunk records (cluster) or its Embree
    BVH (raytrace) cached, the first does not."""
    from gl_passes.reflections import STEPS
    from service import effects

    monkeypatch.setattr(effects, "CASTERS", effects.CasterCache())  # the process-wide BVH cache, emptied

    with service(tmp_path) as c:
        sid = c.post("/scenes", json={"builtin": "mirror"}).json()["id"]
        first, second = (_server_timing(frame(c, sid, "cluster")) for _ in range(2))
        assert set(first) == {*STEPS, "upload", "encode"}
        for step in ("upload", "scene_setup"):
            assert first[step][1] == "cache miss" and second[step][1] == "cache hit", step
        assert all(ms >= 0 for ms, _ in second.values())
        first, second = (_server_timing(frame(c, sid, "raytrace")) for _ in range(2))
        assert set(first) == {"bvh", "trace", "encode"}
        assert first["bvh"][1] == "cache miss" and second["bvh"] == (0.0, "cache hit")


def test_raytraced_frames_survive_the_scene_cache_evicting_their_scene(tmp_path):
    """The worker's BVH cache keys casters by scene id; a scene the store loads again (its cache
    evicted the old object) gets a caster for the new object, not 422 "caster was built for
    another scene" (found by the full suite: two services in one process shared the cache)."""
    with service(tmp_path, scene_cache_size=1) as c:
        sid = c.post("/scenes", json={"builtin": "mirror"}).json()["id"]
        other = c.post("/scenes", json={"builtin": "cornell"}).json()["id"]
        frame(c, sid, "raytrace", rays=1)
        r = c.post(f"/scenes/{other}/frames", json={"camera": MIRROR_CAMERA, "width": 16, "height": 16})
        assert r.status_code == 200  # the cache of one scene now holds cornell
        frame(c, sid, "raytrace", rays=1)  # mirror loaded again: a new Scene object
        r = c.post(f"/scenes/{sid}/frames", json={"camera": MIRROR_CAMERA, "width": 16, "height": 16, "effects": {
            "soft_shadows": {"samples": 2, "method": "raytrace"}}})
        assert r.status_code == 200, r.text  # the soft-shadow truth shares the cache
