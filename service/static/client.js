// depthview thin client: server frames over /scenes/{id}/stream, or ("local" mode, the
// thesis's thin-client scenario) a hybrid reconstruction of non-redundant depth images
// around the view, fetched as GLB and rendered here with three.js; server frames swap in
// when they answer the current view. window.depthview exposes the state (tests read it).
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';

// Local mode's region rule (README): the reference viewpoints are the view itself and 3
// eyes on a circle of radius RING·d around it (d: eye–target distance), all looking at the
// target; a new set is fetched when the eye moves farther than LEAVE·d from the set's eye
// or the view direction turns more than LEAVE_DEG from the set's.
const RING = 0.1, LEAVE = 0.3, LEAVE_DEG = 20, SET_RESOLUTION = 256, SET_FOV_MARGIN = 1.25;
// The newest errors kept in state.errors (one may come each second while the service is busy).
const ERRORS_KEPT = 100;

const params = new URLSearchParams(location.search);
const token = params.get('token');
const auth = token ? { Authorization: `Bearer ${token}` } : {};
const $ = (id) => document.getElementById(id);

const state = window.depthview = {
  mode: params.get('mode') === 'local' ? 'local' : 'stream',
  scene: null, hello: null, connected: false, viewScene: null,  // viewScene: the scene the view was framed for
  framesReceived: 0, framesShown: 0, lastSentId: 0, lastStats: null, lastRendered: null, latencyMs: null, errors: [],
  local: { sets: 0, meshes: 0, triangles: 0, loading: false, rendered: 0 },
};

// --- three.js view -----------------------------------------------------------------------
const view = $('view'), glCanvas = $('gl'), frameCanvas = $('frame');
const frameCtx = frameCanvas.getContext('2d');
const renderer = new THREE.WebGLRenderer({ canvas: glCanvas, antialias: true, preserveDrawingBuffer: true });
renderer.setClearColor(0xd3d9e2, 1);  // near the service's sky, so swapped-in frames do not flash
const world = new THREE.Scene();
const camera = new THREE.PerspectiveCamera(50, 1, 0.01, 1000);
const controls = new OrbitControls(camera, view);
controls.enableDamping = false;
controls.screenSpacePanning = true;
let localSet = null;  // {group, eye, dir, d}
let renderQueued = false;

function requestLocalRender() {
  if (renderQueued || state.mode !== 'local') return;
  renderQueued = true;
  requestAnimationFrame(() => {
    renderQueued = false;
    renderer.render(world, camera);
    state.local.rendered += 1;
  });
}

function resize() {
  const w = Math.max(1, view.clientWidth), h = Math.max(1, view.clientHeight);
  renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
  requestLocalRender();
  queueCamera();
}
new ResizeObserver(resize).observe(view);

// --- the stream ------------------------------------------------------------------------
let ws = null, msgId = 0, lastSentId = 0, pendingStats = null, sendQueued = false, retry = null;
// Frames decode in parallel but are shown in the order they came: a decode may finish
// after a later frame's (a large JPEG after a small one, or its own PNG re-send).
let shownFrames = Promise.resolve(), socketNo = 0;
const sentAt = new Map();
const frameTimes = [];

function status(text, isError = false) {
  $('status').textContent = text;
  $('status').classList.toggle('error', isError);
}

function effects() {
  // both sides: a single-sided surface the light sees from behind (a room's walls and
  // ceiling, as in the default cornell scene) still casts its shadow (bench/results/shadow_frames.md)
  if ($('shadows').checked) return { soft_shadows: { samples: 6, resolution: 256, sides: 'both' } };
  return { reflections: $('reflections').value };
}

function frameSize() {
  const scale = Number($('scale').value);
  let w = Math.round(view.clientWidth * scale), h = Math.round(view.clientHeight * scale);
  const limits = state.hello?.limits;
  if (limits) {
    const k = Math.min(1, Math.sqrt(limits.max_pixels / (w * h)), limits.max_width / w, limits.max_height / h);
    w = Math.floor(w * k); h = Math.floor(h * k);
  }
  return [Math.max(16, w), Math.max(16, h)];
}

function queueCamera() {
  if (sendQueued) return;
  sendQueued = true;
  requestAnimationFrame(() => { sendQueued = false; sendCamera(); });
}

function sendCamera() {
  if (!ws || ws.readyState !== WebSocket.OPEN || !state.hello) return;
  const [width, height] = frameSize();
  const id = ++msgId;
  const t = controls.target;
  const msg = {
    id, width, height, effects: effects(),
    camera: { eye: camera.position.toArray(), target: [t.x, t.y, t.z], up: [0, 1, 0], fov: camera.fov },
  };
  sentAt.set(id, performance.now());
  if (sentAt.size > 256) sentAt.delete(sentAt.keys().next().value);
  lastSentId = state.lastSentId = id;
  ws.send(JSON.stringify(msg));
}

function connect() {
  clearTimeout(retry);
  if (ws) { ws.onclose = null; ws.close(); }
  socketNo += 1;  // frames of the old socket still decoding are not shown
  state.connected = false; state.hello = null;
  const proto = location.protocol === 'https:' ? 'wss' : 'ws';
  const q = token ? `?token=${encodeURIComponent(token)}` : '';
  ws = new WebSocket(`${proto}://${location.host}/scenes/${state.scene}/stream${q}`);
  ws.binaryType = 'blob';
  status('connecting…');
  ws.onopen = () => { state.connected = true; };
  ws.onmessage = (ev) => (typeof ev.data === 'string' ? onText(JSON.parse(ev.data)) : onFrame(ev.data));
  ws.onclose = (ev) => {
    state.connected = false;
    // final: refused (1008), no such scene (4404), a scene the service cannot load (1011)
    if ([1008, 1011, 4404].includes(ev.code)) { status(`stream closed: ${ev.reason || ev.code}`, true); return; }
    status(`stream closed (${ev.code}); reconnecting…`, true);
    retry = setTimeout(connect, 2000);
  };
}

function onText(msg) {
  if (msg.type === 'hello') {
    // a reconnect to the same scene keeps the user's view; another scene is framed anew
    const first = state.viewScene !== msg.scene;
    state.hello = msg;
    state.viewScene = msg.scene;
    if (first) resetView(msg);
    status('');
    sendCamera();
    if (state.mode === 'local') ensureLocalSet(true);
  } else if (msg.type === 'frame') {
    pendingStats = msg;
  } else if (msg.type === 'error') {
    const detail = typeof msg.detail === 'string' ? msg.detail : JSON.stringify(msg.detail);
    noteError(msg);
    status(`server: ${msg.status} ${detail}`, true);
    // The service was busy (503) for the newest camera: ask again once it says to, unless the view moved on
    if (msg.status === 503 && msg.id !== null && msg.id === lastSentId) {
      const failed = msg.id;
      setTimeout(() => { if (lastSentId === failed) sendCamera(); }, 1000 * (state.hello?.limits?.retry_after_s ?? 1));
    }
  }
}

function noteError(err) {
  state.errors.push(err);
  if (state.errors.length > ERRORS_KEPT) state.errors.splice(0, state.errors.length - ERRORS_KEPT);
}

function onFrame(blob) {
  const stats = pendingStats;
  pendingStats = null;
  if (!stats) return;
  const decoded = createImageBitmap(blob), socket = socketNo;
  decoded.catch(() => {});  // handled in turn below
  shownFrames = shownFrames.then(async () => {
    const bitmap = await decoded;
    if (socket === socketNo) showFrame(stats, bitmap);
    else bitmap.close();
  }).catch((err) => {  // this frame is lost, the next ones still show
    noteError({ type: 'frame', seq: stats.seq, detail: String(err) });
    console.error(`frame ${stats.seq}:`, err);
  });
}

function showFrame(stats, bitmap) {
  state.framesReceived += 1;
  const now = performance.now();
  frameTimes.push(now);
  while (frameTimes.length && now - frameTimes[0] > 1000) frameTimes.shift();
  if (stats.id != null && sentAt.has(stats.id) && !stats.rest) state.latencyMs = now - sentAt.get(stats.id);
  state.lastStats = stats;
  if (!stats.rest) state.lastRendered = stats;  // a rest frame is the same render, re-encoded as PNG
  const current = stats.id === lastSentId;
  if (state.mode === 'stream' || current) {
    if (frameCanvas.width !== bitmap.width || frameCanvas.height !== bitmap.height) {
      frameCanvas.width = bitmap.width; frameCanvas.height = bitmap.height;
    }
    frameCtx.drawImage(bitmap, 0, 0);
    frameCanvas.classList.remove('hidden');
    state.framesShown += 1;
  }
  bitmap.close();
  if (!stats.rest) status('');
  showStats();
}

function ms(x) { return x == null ? '–' : `${x < 10 ? x.toFixed(1) : Math.round(x)} ms`; }

function showStats() {
  const s = state.lastStats, r = state.lastRendered, now = performance.now();
  while (frameTimes.length && now - frameTimes[0] > 1000) frameTimes.shift();
  $('s-fps').textContent = frameTimes.length ? String(frameTimes.length) : '0';
  $('s-latency').textContent = ms(state.latencyMs);
  if (s) {
    $('s-render').textContent = `${ms(r.render_ms)} + ${ms(r.encode_ms)}`;
    $('s-queue').textContent = ms(r.queue_wait_ms);
    $('s-reused').textContent = `${(100 * s.reused_ratio).toFixed(0)} %${s.keyframe ? ' · key' : ''}`;
    $('s-frame').textContent = `${s.width}×${s.height} ${s.format}`;
  }
  const l = state.local;
  $('s-local').textContent = l.loading ? 'loading…' : l.sets ? `${l.meshes} images · ${(l.triangles / 1e3).toFixed(0)}k tri` : '–';
}
setInterval(showStats, 500);

// --- camera ----------------------------------------------------------------------------
function resetView(hello) {
  const [lo, hi] = hello.bounds.map((b) => new THREE.Vector3(...b));
  const diag = lo.distanceTo(hi) || 1;
  camera.fov = hello.view.fov;
  camera.near = diag * 1e-3; camera.far = diag * 20;
  camera.position.fromArray(hello.view.eye);
  controls.target.fromArray(hello.view.target);
  controls.minDistance = diag * 0.02; controls.maxDistance = diag * 8;
  camera.updateProjectionMatrix();
  controls.update();
  clearLocalSet();
}

controls.addEventListener('change', () => {
  if (state.mode === 'local') {
    frameCanvas.classList.add('hidden');  // the local render answers at once
    requestLocalRender();
    ensureLocalSet(false);
  }
  queueCamera();
});

// --- local mode: reconstruction of NR depth images around the view ----------------------
const loader = new GLTFLoader();

function viewBasis(eye, target) {
  const dir = new THREE.Vector3().subVectors(target, eye).normalize();
  const u = new THREE.Vector3().crossVectors(dir, new THREE.Vector3(0, 1, 0));
  if (u.lengthSq() < 1e-8) u.set(1, 0, 0);
  u.normalize();
  const v = new THREE.Vector3().crossVectors(u, dir).normalize();
  return { dir, u, v };
}

function leftRegion() {
  if (!localSet) return true;
  const d = camera.position.distanceTo(controls.target);
  const dir = new THREE.Vector3().subVectors(controls.target, camera.position).normalize();
  const turned = THREE.MathUtils.radToDeg(dir.angleTo(localSet.dir));
  return camera.position.distanceTo(localSet.eye) > LEAVE * localSet.d || turned > LEAVE_DEG || d > 2 * localSet.d;
}

function clearLocalSet() {
  if (localSet) {
    world.remove(localSet.group);
    localSet.group.traverse((o) => { o.geometry?.dispose(); o.material?.dispose?.(); });
  }
  localSet = null;
  Object.assign(state.local, { meshes: 0, triangles: 0 });
}

let setRequest = 0;
async function ensureLocalSet(force) {
  if (state.mode !== 'local' || !state.hello || state.local.loading || (!force && !leftRegion())) return;
  const scene = state.scene;  // a set that arrives after a switch to another scene is dropped
  const eye = camera.position.clone(), target = controls.target.clone();
  const d = eye.distanceTo(target);
  const { dir, u, v } = viewBasis(eye, target);
  const eyes = [eye];
  for (let k = 0; k < 3; k++) {
    const a = (2 * Math.PI * k) / 3;
    eyes.push(eye.clone().addScaledVector(u, RING * d * Math.cos(a)).addScaledVector(v, RING * d * Math.sin(a)));
  }
  const fov = Math.min(120, camera.fov * SET_FOV_MARGIN * Math.max(1, camera.aspect));
  const body = {
    method: 'non_redundant', reconstruction: 'hybrid', resolution: SET_RESOLUTION,
    cameras: eyes.map((e) => ({ eye: e.toArray(), target: target.toArray(), up: [0, 1, 0], fov })),
  };
  const ticket = ++setRequest;
  let failed = false;
  state.local.loading = true;
  showStats();
  try {
    const t0 = performance.now();
    const r = await fetch(`/scenes/${scene}/reconstruction`, {
      method: 'POST', headers: { 'content-type': 'application/json', ...auth }, body: JSON.stringify(body),
    });
    if (!r.ok) throw new Error(`reconstruction: ${r.status} ${(await r.text()).slice(0, 200)}`);
    const gltf = await loader.parseAsync(await r.arrayBuffer(), '');
    if (ticket !== setRequest || state.mode !== 'local' || scene !== state.scene) return;
    clearLocalSet();
    let meshes = 0, triangles = 0;
    gltf.scene.traverse((o) => {
      if (!o.isMesh) return;
      o.material?.dispose?.();
      o.material = new THREE.MeshBasicMaterial({ vertexColors: true, side: THREE.DoubleSide });
      meshes += 1;
      triangles += (o.geometry.index ? o.geometry.index.count : o.geometry.attributes.position.count) / 3;
    });
    world.add(gltf.scene);
    localSet = { group: gltf.scene, eye, dir, d };
    Object.assign(state.local, { sets: state.local.sets + 1, meshes, triangles, ms: performance.now() - t0 });
    requestLocalRender();
  } catch (err) {
    failed = true;  // asked again when the view moves, not at once (a 422 fails every time)
    console.warn(err);
    if (scene === state.scene) status(String(err.message || err), true);  // not the scene switched from
  } finally {
    state.local.loading = false;
    showStats();
    // the scene switched while this loaded (its set is asked for now, whatever became of this one),
    // or the view left the region of the set just made
    const switched = scene !== state.scene;
    if (ticket === setRequest && state.mode === 'local' && (switched || (!failed && leftRegion()))) {
      ensureLocalSet(switched);
    }
  }
}

// --- controls ----------------------------------------------------------------------------
function setMode(mode) {
  state.mode = mode;
  document.body.classList.toggle('local', mode === 'local');
  for (const b of document.querySelectorAll('.segmented button')) b.classList.toggle('active', b.dataset.mode === mode);
  glCanvas.classList.toggle('hidden', mode !== 'local');
  if (mode === 'local') {
    frameCanvas.classList.add('hidden');
    requestLocalRender();
    ensureLocalSet(!localSet);
  } else {
    frameCanvas.classList.remove('hidden');
  }
  const url = new URL(location.href);
  url.searchParams.set('mode', mode);
  history.replaceState(null, '', url);
  queueCamera();
}

for (const b of document.querySelectorAll('.segmented button')) b.addEventListener('click', () => setMode(b.dataset.mode));
// ?reflections=cluster|raytrace|envmap presets the picker (the README's first link)
if ([...$('reflections').options].some((o) => o.value === params.get('reflections'))) {
  $('reflections').value = params.get('reflections');
}
$('reflections').addEventListener('change', queueCamera);
$('scale').addEventListener('change', queueCamera);
$('shadows').addEventListener('change', () => {
  $('reflections').disabled = $('shadows').checked;  // the service renders one effect per frame
  queueCamera();
});

async function loadScenes() {
  let scenes;
  try {
    const r = await fetch('/scenes', { headers: auth });
    if (!r.ok) { status(`GET /scenes: ${r.status}`, true); return; }
    ({ scenes } = await r.json());
  } catch (err) {  // the network failed (the service restarting): say so, not an unhandled rejection
    status(`GET /scenes: ${err.message || err}`, true);
    return;
  }
  const select = $('scene');
  for (const s of scenes) {
    const o = document.createElement('option');
    o.value = s.id;
    o.textContent = `${s.name} (${(s.triangles / 1e3).toFixed(s.triangles < 1e4 ? 1 : 0)}k)`;
    o.dataset.name = s.name;
    select.append(o);
  }
  const wanted = params.get('scene') || 'cornell';
  const pick = [...select.options].find((o) => o.value === wanted || o.dataset.name === wanted) || select.options[0];
  if (!pick) { status('no scenes', true); return; }
  select.value = pick.value;
  state.scene = pick.value;
  select.addEventListener('change', () => {
    state.scene = select.value;
    const url = new URL(location.href);
    url.searchParams.set('scene', select.selectedOptions[0].dataset.name);
    history.replaceState(null, '', url);
    clearLocalSet();
    connect();
  });
  connect();
}

setMode(state.mode);
resize();
loadScenes();
