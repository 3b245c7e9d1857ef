// faceretarget live: the character (/character.glb) driven by the session's WebSocket (/ws).
//
// Messages from the session (JSON, one per WebSocket message):
//   {"type": "hello", "source", "character", "names", "params": {...}}
//   {"type": "frame", "frame", "t", "weights": [...], "names": [...], "head": [qx, qy, qz, qw],
//    "calibrating": bool}
//   {"type": "params", "head_amplitude", "emotion_amount"}
//   {"type": "end", "summary"}
// Messages to the session: {"type": "params", "head_amplitude": x} / {"type": "params", "emotion_amount": x}.
// `window.live` exposes the state (and `snapshot()`, `probe()`) for scripted checks.
// `?render=0` skips WebGL (the scene is still updated).
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";

const query = new URLSearchParams(location.search);
const statusEl = document.getElementById("status");
const BACKGROUND = 0x202428;

const live = (window.live = {
  ready: false, frames: 0, last: null, hello: null, params: {}, paramsFrames: -1,
  closed: false, ended: false, summary: "", error: null, renderer: false, renderError: null,
});

function setStatus(text) {
  statusEl.textContent = text;
}

// ------------------------------------------------------------------------------------ scene
const scene = new THREE.Scene();
scene.background = new THREE.Color(BACKGROUND);
scene.add(new THREE.HemisphereLight(0xffffff, 0x3a3a3a, 1.5));
const keyLight = new THREE.DirectionalLight(0xffffff, 2.0);
keyLight.position.set(0.4, 0.8, 2.0);
scene.add(keyLight);
const camera = new THREE.PerspectiveCamera(28, 1, 0.01, 100);

let renderer = null;
if (query.get("render") !== "0") {
  try {
    renderer = new THREE.WebGLRenderer({ canvas: document.getElementById("view"), antialias: true });
    renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    live.renderer = true;
  } catch (e) {
    live.renderError = String((e && e.message) || e);
  }
}

let dirty = true;
function resize() {
  const w = window.innerWidth || 800;
  const h = window.innerHeight || 600;
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
  if (renderer) renderer.setSize(w, h, false);
  dirty = true;
}
window.addEventListener("resize", resize);

function loop() {
  requestAnimationFrame(loop);
  if (renderer && dirty) {
    renderer.render(scene, camera);
    dirty = false;
  }
}

// ------------------------------------------------------------------------------------ character
let face = null;
let head = null;
let morphNames = [];
let index = [];
let indexKey = null;

function indexFor(names) {
  const key = names.join("\n");
  if (key !== indexKey) {
    const dict = (face && face.morphTargetDictionary) || {};
    index = names.map((n) => (n in dict ? dict[n] : -1));
    indexKey = key;
  }
  return index;
}

function frameTheFace(root) {
  root.updateMatrixWorld(true);
  const box = new THREE.Box3().setFromObject(face || root);
  const c = box.getCenter(new THREE.Vector3());
  const size = box.getSize(new THREE.Vector3());
  const r = 0.5 * Math.max(size.x, size.y, 1e-3);
  const dist = (1.35 * r) / Math.tan(THREE.MathUtils.degToRad(camera.fov / 2));
  camera.position.set(c.x, c.y, c.z + 0.5 * size.z + dist);
  camera.near = dist / 20;
  camera.far = dist * 20;
  camera.lookAt(c);
  camera.updateProjectionMatrix();
}

// ------------------------------------------------------------------------------------ stream
const received = [];
function onFrame(m) {
  if (face && Array.isArray(m.weights) && Array.isArray(m.names)) {
    const idx = indexFor(m.names);
    const inf = face.morphTargetInfluences;
    for (let i = 0; i < idx.length; i++) if (idx[i] >= 0) inf[idx[i]] = m.weights[i];
  }
  if (head && Array.isArray(m.head) && m.head.length === 4) head.quaternion.fromArray(m.head);
  live.frames += 1;
  live.last = m;
  dirty = true;
  const now = performance.now();
  received.push(now);
  while (received.length && received[0] < now - 2000) received.shift();
  if (live.frames % 10 === 1) {
    const fps = received.length > 1 ? (1000 * (received.length - 1)) / (now - received[0]) : 0;
    setStatus(`frame ${m.frame}, t ${Number(m.t).toFixed(2)} s, ${fps.toFixed(1)} fps` +
      (m.calibrating ? "\ncalibrating: hold a neutral face" : ""));
  }
}

const sliders = {
  head_amplitude: [document.getElementById("head"), document.getElementById("head-out")],
  emotion_amount: [document.getElementById("emotion"), document.getElementById("emotion-out")],
};

function showParams(p) {
  for (const [name, [input, out]] of Object.entries(sliders)) {
    if (typeof p[name] === "number") {
      if (document.activeElement !== input) input.value = String(p[name]);
      out.textContent = Number(p[name]).toFixed(2);
    }
  }
}

function onMessage(m) {
  if (m.type === "frame") onFrame(m);
  else if (m.type === "params") {
    live.params = m;
    live.paramsFrames = live.frames;
    showParams(m);
  } else if (m.type === "hello") {
    live.hello = m;
    if (m.params) {
      live.params = m.params;
      showParams(m.params);
    }
    setStatus(`connected: ${m.source} onto ${m.character}`);
  } else if (m.type === "end") {
    live.ended = true;
    live.summary = m.summary || "";
  }
}

let ws = null;
function connect() {
  ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`);
  ws.onopen = () => {
    live.ready = true;
  };
  ws.onmessage = (ev) => {
    try {
      onMessage(JSON.parse(ev.data));
    } catch (e) {
      live.error = String((e && e.message) || e);
    }
  };
  ws.onclose = () => {
    live.closed = true;
    setStatus(live.ended ? `session ended\n${live.summary}` : "disconnected from the session");
  };
}

for (const [name, [input, out]] of Object.entries(sliders)) {
  input.addEventListener("input", () => {
    const v = Number(input.value);
    out.textContent = v.toFixed(2);
    if (ws && ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify({ type: "params", [name]: v }));
  });
}

// ------------------------------------------------------------------------------------ checks
live.snapshot = () => ({
  frames: live.frames,
  t: live.last ? live.last.t : null,
  frame: live.last ? live.last.frame : null,
  calibrating: live.last ? !!live.last.calibrating : null,
  names: morphNames,
  influences: face ? Array.from(face.morphTargetInfluences) : [],
  quaternion: head ? head.quaternion.toArray() : null,
  params: live.params,
  paramsFrames: live.paramsFrames,
  last: live.last,
});

// Render now and measure the share of pixels that are not background (null without WebGL).
live.probe = () => {
  if (!renderer) return null;
  renderer.render(scene, camera);
  const gl = renderer.getContext();
  const w = gl.drawingBufferWidth;
  const h = gl.drawingBufferHeight;
  const px = new Uint8Array(w * h * 4);
  gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
  const ref = [(BACKGROUND >> 16) & 255, (BACKGROUND >> 8) & 255, BACKGROUND & 255]; // sRGB output
  let covered = 0;
  let sum = 0;
  for (let i = 0; i < px.length; i += 4) {
    const d = Math.abs(px[i] - ref[0]) + Math.abs(px[i + 1] - ref[1]) + Math.abs(px[i + 2] - ref[2]);
    if (d > 24) covered += 1;
    sum += px[i] + px[i + 1] + px[i + 2];
  }
  return { width: w, height: h, coverage: covered / (w * h), checksum: sum };
};

// ------------------------------------------------------------------------------------ start
try {
  const gltf = await new GLTFLoader().loadAsync("/character.glb");
  scene.add(gltf.scene);
  gltf.scene.traverse((o) => {
    if (!face && o.morphTargetInfluences) face = o;
  });
  head = gltf.scene.getObjectByName("head") || null;
  if (face) {
    const dict = face.morphTargetDictionary || {};
    morphNames = face.morphTargetInfluences.map((_, i) => `target${i}`);
    for (const [n, i] of Object.entries(dict)) morphNames[i] = n;
  }
  frameTheFace(gltf.scene);
  resize();
  loop();
  setStatus(live.renderer ? "connecting…" : `connecting… (no WebGL: ${live.renderError || "off"})`);
  connect();
} catch (e) {
  live.error = String((e && e.message) || e);
  setStatus(`cannot load the character: ${live.error}`);
}
