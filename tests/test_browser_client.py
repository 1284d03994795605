"""End-to-end: the thin client at /client in a real browser (Debian's chromium-headless-shell
or chromium, driven by Playwright from PyPI with `executable_path`: never
`playwright install`), WebGL on the CPU through SwiftShader. The page is loaded from a live
uvicorn server that wants a token (the page passes `?token=` on), orbited with the mouse;
streamed frames must arrive and change, the canvases must not be blank (pixels read back),
local mode must render the reconstruction at once on orbit, fetch a new set when the view
leaves the region, and swap the server's frame in, and drop a set that arrives after a switch to
another scene; frames must show in the order they came
even when a decode finishes late; the soft-shadow toggle must switch the stream to soft
shadows that answer an orbit; a reconnect must keep the orbited view; the page must log no errors. A failure
names a screenshot (failure.png in the test's tmp dir) and the page's state."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from collections.abc import Iterator

import pytest

from service.config import Settings
from tests.helpers import live_server

CHROMIUM_NAMES = ("chromium-headless-shell", "chromium", "chromium-browser")
CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-sandbox"]
VIEWPORT = {"width": 640, "height": 440}
TOKEN = "browser-s3cret"  # the page passes ?token= on to its API calls and the stream

#: The canvas `id` drawn into a 2D canvas and summarised: mean, spread, share of pixels
#: unlike the top-left pixel (a blank or clear-coloured canvas has none), a checksum.
CANVAS_STATS = """(id) => {
  const src = document.getElementById(id);
  const c = document.createElement('canvas');
  c.width = src.width; c.height = src.height;
  const g = c.getContext('2d');
  g.drawImage(src, 0, 0);
  const d = g.getImageData(0, 0, c.width, c.height).data;
  let sum = 0, sum2 = 0, differ = 0, hash = 0;
  for (let i = 0; i < d.length; i += 4) {
    const y = (d[i] + d[i + 1] + d[i + 2]) / 3;
    sum += y; sum2 += y * y;
    if (Math.abs(d[i] - d[0]) + Math.abs(d[i + 1] - d[1]) + Math.abs(d[i + 2] - d[2]) > 12) differ++;
    hash = (hash * 31 + d[i] + 7 * d[i + 1] + 13 * d[i + 2]) >>> 0;
  }
  const n = d.length / 4, mean = sum / n;
  return {w: c.width, h: c.height, mean, std: Math.sqrt(Math.max(0, sum2 / n - mean * mean)),
          differ: differ / n, hash};
}"""


def chromium() -> str | None:
    exe = os.environ.get("DEPTHVIEW_CHROMIUM")
    if exe:
        return exe
    return next((p for p in map(shutil.which, CHROMIUM_NAMES) if p), None)


@pytest.fixture(scope="module")
def server(tmp_path_factory) -> Iterator[str]:
    with live_server(tmp_path_factory.mktemp("browser"), token=TOKEN) as (host, port):
        yield f"http://{host}:{port}"


@pytest.fixture
def page():
    exe = chromium()
    if exe is None:
        pytest.skip("no Chromium on this machine (apt-get install chromium-headless-shell; make setup does)")
    modules = Settings().node_modules  # what the live server serves
    assert (modules / "three" / "build").is_dir(), f"three.js missing in {modules}: run `npm ci` (make setup does)"
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, headless=True, args=CHROMIUM_ARGS)
        pg = browser.new_page(viewport=VIEWPORT)
        problems: list[str] = []
        pg.on("console", lambda m: problems.append(f"console.{m.type}: {m.text}") if m.type == "error" else None)
        pg.on("pageerror", lambda e: problems.append(f"page error: {e}"))
        pg.on("requestfailed", lambda r: problems.append(f"request failed: {r.url} {r.failure}"))
        pg.problems = problems
        try:
            yield pg
        finally:
            browser.close()


def drag(page, dx: float, dy: float) -> None:
    box = page.locator("#view").bounding_box()
    x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
    page.mouse.move(x, y)
    page.mouse.down()
    page.mouse.move(x + dx, y + dy, steps=8)
    page.mouse.up()


def state(page) -> dict:
    return page.evaluate("() => JSON.parse(JSON.stringify(window.depthview))")


@contextlib.contextmanager
def reported(page, tmp_path) -> Iterator[None]:
    """On failure: a screenshot (failure.png in tmp_path), named in the message with the
    page's state and problems."""
    try:
        yield
    except BaseException as exc:
        page.screenshot(path=str(tmp_path / "failure.png"))
        raise AssertionError(f"{exc}\nscreenshot: {tmp_path / 'failure.png'}; page state: {state(page)}; "
                             f"page problems: {page.problems}") from exc


def test_client_streams_orbits_and_renders_the_reconstruction_locally(page, server, tmp_path):
    with reported(page, tmp_path):
        _scenario(page, server)


def _scenario(page, server: str) -> None:
    page.goto(f"{server}/client?scene=cornell&token={TOKEN}")
    # stream mode: frames arrive, the frame canvas shows the scene
    page.wait_for_function("() => window.depthview && window.depthview.framesShown >= 1", timeout=30_000)
    first = page.evaluate(CANVAS_STATS, "frame")
    assert first["w"] >= 200 and first["std"] > 10 and first["differ"] > 0.2, first
    s = state(page)
    assert s["lastStats"]["format"] in ("jpeg", "png") and s["lastStats"]["keyframe"] is True
    assert s["lastStats"]["reused_ratio"] == 0 and s["latencyMs"] > 0
    # orbit with the mouse: new frames answer the new view, and they differ
    received = s["framesReceived"]
    drag(page, 140, 30)
    page.wait_for_function(
        f"() => window.depthview.framesReceived > {received} && window.depthview.lastStats.id >= 2", timeout=30_000)
    page.wait_for_timeout(300)
    second = page.evaluate(CANVAS_STATS, "frame")
    assert second["hash"] != first["hash"] and second["std"] > 10, (first, second)
    assert page.text_content("#s-fps") not in ("", "–") and "ms" in page.text_content("#s-latency")
    # local mode: the reconstruction of NR depth images around the view, rendered by three.js
    page.click("#mode-local")
    page.wait_for_function("() => window.depthview.local.sets >= 1 && window.depthview.local.rendered >= 1",
                           timeout=40_000)
    s = state(page)
    assert s["local"]["meshes"] >= 2 and s["local"]["triangles"] > 1000, s["local"]
    page.wait_for_timeout(200)
    local = page.evaluate(CANVAS_STATS, "gl")
    assert local["std"] > 10 and local["differ"] > 0.2, local
    rendered = s["local"]["rendered"]
    drag(page, -60, 0)  # answered locally at once, before any server frame
    page.wait_for_function(f"() => window.depthview.local.rendered > {rendered}", timeout=5_000)
    moved = page.evaluate(CANVAS_STATS, "gl")
    assert moved["hash"] != local["hash"] and moved["differ"] > 0.2, (local, moved)
    # ... the view left the set's region (turned > 20°): a new set is fetched
    page.wait_for_function("() => window.depthview.local.sets >= 2 && !window.depthview.local.loading",
                           timeout=40_000)
    # ... and the server's frame of the new view swaps in when it arrives
    page.wait_for_function("() => window.depthview.lastStats.id === window.depthview.lastSentId"
                           " && !document.getElementById('frame').classList.contains('hidden')", timeout=30_000)
    assert page.problems == []


def test_a_new_user_orbits_a_built_in_scene_with_reflections_streaming(page, server, tmp_path):
    """The issue's done-when in the browser, by the README's first link: the built-in mirror
    scene with reflections by the cluster method, orbited with the mouse; reflective frames
    stream and the stream's reflection reuse (Ch. 5) answers the orbit (not keyframes only)."""
    with reported(page, tmp_path):
        page.goto(f"{server}/client?scene=mirror&reflections=cluster&token={TOKEN}")
        page.wait_for_function("() => window.depthview && window.depthview.framesShown >= 1", timeout=60_000)
        assert page.input_value("#reflections") == "cluster"
        sent = state(page)["lastSentId"]
        page.select_option("#scale", "0.5")  # smaller frames: quicker on this CPU (and a new keyframe)
        # lastRendered: the latest rendered frame's stats (lastStats may be its PNG re-send at rest)
        page.wait_for_function(f"() => window.depthview.lastRendered.id > {sent}", timeout=60_000)
        key = state(page)["lastRendered"]
        assert key["keyframe"] is True and key["reused_ratio"] == 0, key  # the first frame of this size
        before = page.evaluate(CANVAS_STATS, "frame")
        for _ in range(4):  # a slow orbit, a few pixels a drag: reflections reused from the keyframe
            sent = state(page)["lastSentId"]
            drag(page, 5, 0)
            page.wait_for_function(f"() => window.depthview.lastRendered.id > {sent}", timeout=60_000)
            if state(page)["lastRendered"]["reused_ratio"] > 0:
                break
        stats = state(page)["lastRendered"]
        assert stats["keyframe"] is False and stats["reused_ratio"] > 0.3, stats
        page.wait_for_timeout(300)
        after = page.evaluate(CANVAS_STATS, "frame")
        assert after["std"] > 10 and after["differ"] > 0.2 and after["hash"] != before["hash"], (before, after)
        assert page.problems == []


#: Init script: the second frame's decode (createImageBitmap) finishes `DECODE_DELAY_MS` late,
#: after the frames that came after it (as a large JPEG can after a small one or its PNG re-send).
DECODE_DELAY_MS = 3000
SLOW_SECOND_DECODE = """(() => {
  const decode = window.createImageBitmap.bind(window);
  let calls = 0;
  window.createImageBitmap = (...args) => {
    window.decodes = calls += 1;
    const bitmap = decode(...args);
    return calls === 2 ? bitmap.then((b) => new Promise((done) => setTimeout(() => done(b), DELAY))) : bitmap;
  };
})();""".replace("DELAY", str(DECODE_DELAY_MS))


#: Keeps the page's sockets (window.sockets) and what each sent (socket.sent).
WATCH_SOCKETS = """(() => {
  const Native = window.WebSocket;
  window.sockets = [];
  window.WebSocket = class extends Native {
    constructor(...args) { super(...args); this.sent = []; window.sockets.push(this); }
    send(data) { this.sent.push(data); return super.send(data); }
  };
})();"""


def test_a_reconnect_keeps_the_users_view(page, server, tmp_path):
    """When the socket drops, the client reconnects after a while and sends the view the
    user had orbited to, not the hello's default view again."""
    with reported(page, tmp_path):
        page.add_init_script(WATCH_SOCKETS)
        page.goto(f"{server}/client?scene=cornell&token={TOKEN}")
        page.wait_for_function("() => window.depthview && window.depthview.framesShown >= 1", timeout=30_000)
        first_eye = json.loads(page.evaluate("() => window.sockets[0].sent[0]"))["camera"]["eye"]
        drag(page, 80, 30)
        page.wait_for_function("() => window.depthview.lastRendered?.id === window.depthview.lastSentId",
                               timeout=30_000)
        orbited = json.loads(page.evaluate("() => window.sockets[0].sent.at(-1)"))["camera"]
        assert max(abs(a - b) for a, b in zip(orbited["eye"], first_eye, strict=True)) > 0.1, (orbited, first_eye)
        page.evaluate("() => window.sockets[0].close(4000)")  # as a dropped connection: reconnect
        page.wait_for_function("() => window.sockets.length === 2 && window.sockets[1].sent.length >= 1",
                               timeout=30_000)
        again = json.loads(page.evaluate("() => window.sockets[1].sent[0]"))["camera"]
        assert again["eye"] == pytest.approx(orbited["eye"]) and again["target"] == pytest.approx(orbited["target"]), \
            (again, orbited)
        assert page.problems == []


def test_frames_show_in_the_order_they_came_when_a_decode_finishes_late(page, server, tmp_path):
    """A frame whose decode finishes after a later frame's must not replace it: the canvas
    and the stats end on the newest frame (seq), every frame of the socket shown in turn."""
    with reported(page, tmp_path):
        page.add_init_script(SLOW_SECOND_DECODE)
        page.goto(f"{server}/client?scene=cornell&token={TOKEN}")
        # frame 2 decodes late; frame 3 (a new view, or the PNG re-send at rest) comes meanwhile
        page.wait_for_function("() => window.depthview && window.depthview.framesShown >= 1", timeout=30_000)
        drag(page, 40, 0)
        page.wait_for_function("() => window.decodes >= 3", timeout=30_000)
        page.wait_for_timeout(DECODE_DELAY_MS + 1000)  # the late decode has finished
        s, decodes = state(page), page.evaluate("() => window.decodes")  # one decode per frame that came
        assert s["lastStats"]["seq"] == decodes and s["framesReceived"] == decodes, (decodes, s)
        assert s["lastRendered"]["id"] == s["lastSentId"] and s["errors"] == [], s
        assert page.problems == []


def test_soft_shadows_stream_while_orbiting(page, server, tmp_path):
    """The soft-shadow toggle: the stream's frames switch to soft shadows (thesis Ch. 3, the
    service keeping the light's reconstruction and shadow maps between frames) and answer an
    orbit; the shadowed frames differ from the plain one and from each other."""
    sent_effects: list[dict] = []
    page.on("websocket", lambda ws: ws.on("framesent", lambda payload: sent_effects.append(
        json.loads(payload).get("effects", {})) if isinstance(payload, str) else None))
    with reported(page, tmp_path):
        page.goto(f"{server}/client?scene=city&token={TOKEN}")
        page.wait_for_function("() => window.depthview && window.depthview.framesShown >= 1", timeout=30_000)
        page.wait_for_timeout(300)
        plain = page.evaluate(CANVAS_STATS, "frame")
        sent = state(page)["lastSentId"]
        page.check("#shadows")
        assert page.is_disabled("#reflections")  # one effect per frame
        page.wait_for_function(f"() => window.depthview.lastRendered.id > {sent}", timeout=60_000)
        page.wait_for_timeout(300)
        shadowed = page.evaluate(CANVAS_STATS, "frame")
        assert shadowed["std"] > 10 and shadowed["hash"] != plain["hash"], (plain, shadowed)
        for _ in range(2):
            sent = state(page)["lastSentId"]
            drag(page, 60, 0)
            page.wait_for_function(f"() => window.depthview.lastRendered.id > {sent}", timeout=60_000)
        page.wait_for_timeout(300)
        moved = page.evaluate(CANVAS_STATS, "frame")
        assert moved["std"] > 10 and moved["hash"] != shadowed["hash"], (shadowed, moved)
        assert sent_effects[0].get("soft_shadows") is None and "soft_shadows" in sent_effects[-1], sent_effects
        assert sent_effects[-1]["soft_shadows"]["sides"] == "both"  # the rooms' walls occlude too
        assert state(page)["errors"] == [] and page.problems == []


@pytest.mark.parametrize("old_fails", [False, True])
def test_a_scene_switch_while_a_local_set_loads_never_shows_the_old_scenes_set(page, server, tmp_path, old_fails):
    """Local mode: the user picks another scene while the set of the first one is still
    loading; when that set arrives it belongs to a scene no longer shown and is dropped,
    and the new scene's set is fetched and shown (one set in all); so it is when the
    old scene's request fails instead (its error is not shown for the new scene)."""
    from service.store import builtin_id

    cornell, mirror = builtin_id("cornell"), builtin_id("mirror")
    held, finished = [], []
    page.route("**/reconstruction", lambda route: held.append(route) if cornell in route.request.url
               else route.continue_())
    page.on("requestfinished", lambda r: finished.append(r.url) if r.url.endswith("/reconstruction") else None)
    with reported(page, tmp_path):
        page.goto(f"{server}/client?scene=cornell&mode=local&token={TOKEN}")
        page.wait_for_function("() => window.depthview && window.depthview.local.loading", timeout=30_000)
        for _ in range(200):
            if held:
                break
            page.wait_for_timeout(50)
        assert len(held) == 1
        page.select_option("#scene", mirror)
        page.wait_for_function(f"() => window.depthview.hello?.scene === '{mirror}'", timeout=30_000)
        if old_fails:  # the old scene's request fails now
            held[0].fulfill(status=503, body='{"detail": "render queue is full"}', content_type="application/json")
        else:  # the old scene's set arrives now
            held[0].continue_()
        for _ in range(1200):
            done = any(mirror in u for u in finished) and not state(page)["local"]["loading"]
            if done:
                break
            page.wait_for_timeout(50)
        assert done, finished
        page.wait_for_timeout(300)
        s = state(page)
        assert s["local"]["sets"] == 1 and s["local"]["meshes"] >= 1, s["local"]
        assert "503" not in page.text_content("#status")
        assert [p for p in page.problems if not (old_fails and "503" in p)] == [], page.problems


def test_a_failed_scene_list_is_shown_not_an_unhandled_rejection(page, server, tmp_path):
    """GET /scenes failing at the network level (the service restarting just after the
    page loaded): the page says so in its status line instead of throwing an unhandled
    promise rejection and staying blank."""
    page.route("**/scenes", lambda route: route.abort())
    with reported(page, tmp_path):
        page.goto(f"{server}/client?scene=cornell&token={TOKEN}")
        page.wait_for_function("() => document.getElementById('status').textContent !== ''", timeout=10_000)
        assert "/scenes" in page.text_content("#status") and "error" in page.get_attribute("#status", "class")
        assert [p for p in page.problems if not p.startswith(("request failed", "console.error: Failed to load"))] \
            == [], page.problems


def test_a_failed_local_set_is_not_asked_for_again_and_again(page, server, tmp_path):
    """Local mode: a reconstruction request that fails (here 503; a 422 for a scene over
    the budget fails every time) is asked again when the view moves, not re-sent
    at once in a loop that hammers the service while the view stands still."""
    asked = []

    def busy(route):
        asked.append(route.request.url)
        route.fulfill(status=503, body='{"detail": "render queue is full"}', content_type="application/json")

    page.route("**/reconstruction", busy)
    with reported(page, tmp_path):
        page.goto(f"{server}/client?scene=cornell&mode=local&token={TOKEN}")
        page.wait_for_function("() => window.depthview && window.depthview.hello", timeout=30_000)
        page.wait_for_timeout(2000)
        assert len(asked) == 1, len(asked)
        drag(page, 60, 0)  # the view moved: asked again
        page.wait_for_timeout(500)
        assert len(asked) >= 2


def test_the_page_keeps_only_the_newest_errors(page, server, tmp_path):
    """A stream that answers with errors for hours (a busy service: about one a second)
    must not grow the page's error list without bound: the newest ERRORS_KEPT stay."""
    def errors(ws):
        for n in range(150):
            ws.send(json.dumps({"type": "error", "status": 422, "detail": f"bad camera {n}", "id": None}))

    page.route_web_socket("**/stream*", errors)
    with reported(page, tmp_path):
        page.goto(f"{server}/client?scene=cornell&token={TOKEN}")
        page.wait_for_function("() => window.depthview?.errors.at(-1)?.detail === 'bad camera 149'", timeout=30_000)
        kept = state(page)["errors"]
        assert len(kept) == 100 and kept[-1]["detail"] == "bad camera 149" and kept[0]["detail"] == "bad camera 50"
        assert "bad camera 149" in page.text_content("#status")
