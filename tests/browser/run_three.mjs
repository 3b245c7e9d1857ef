// Play a .glb in headless Chromium with three.js and print what three.js's AnimationMixer gives.
//
// usage: node tests/browser/run_three.mjs FILE.glb [--times T0,T1,...] [--times-file F.json]
//                                         [--timeout SECONDS] [--face NODE] [--head NODE]
//
// A static HTTP server on 127.0.0.1 (ephemeral port) serves a page, three.js (the npm package at
// $THREE_DIR, else .tools/node_modules/three at the repository root, where `make tools` puts it) and
// the .glb's folder.  Chromium ($CHROMIUM, else /usr/bin/chromium) is launched headless through
// puppeteer-core ($PUPPETEER_CORE_DIR, else .tools/node_modules/puppeteer-core) with --no-sandbox;
// nothing is rendered (no WebGL, no GPU): the page imports `three` and `GLTFLoader` through an import
// map, parses the .glb, builds an AnimationMixer for the first clip and, for each requested time
// (seconds from the clip's start), does `action.reset().play(); mixer.setTime(t)` (LoopOnce, clamped
// at the end, so the last keyframe time gives the last key rather than wrapping to the first) and
// reads
//   * the face mesh's morphTargetInfluences, ordered by the names of its morphTargetDictionary
//     (the first mesh with morph targets, or the object named by --face), and
//   * the head node's quaternion (x, y, z, w) and position (the object named "head" or --head).
//
// stdout: one JSON object {three, browser, clip: {name, duration, tracks}, face, names, times,
// influences: [[...] per time], head: {node, quaternion: [[x,y,z,w] per time],
// position: [[x,y,z] per time]} | null}.
//
// Characters (a user's .glb / .vrm with the animation written back): the loader always has three.js's
// MeshoptDecoder (EXT_meshopt_compression); --clip NAME plays the clip of that name; --morphs all adds
// "morphs": {node name: [[influences] per time]} for every node whose meshes have morph targets (a
// multi-primitive mesh's primitives are three.js child meshes: the first one's influences); --world
// N1,N2 adds "world": {node: [[x,y,z,w] world quaternion per time]}; --vrm loads through three-vrm's
// VRMLoaderPlugin ($THREE_VRM_DIR, else .tools/node_modules/@pixiv/three-vrm) and calls vrm.update(0)
// after each setTime, as an app does, so what the VRM runtime shows is what is read; with --vrma F.vrma it
// plays that VRM Animation instead of the file's clip (three-vrm-animation's createVRMAnimationClip), the way
// three-vrm apps animate expressions and the humanoid.
// Morph target data (a character with new shapes, no animation needed): --morph-data N1,N2 prints instead
// {three, browser, meshes: [{object, mesh, primitive, count, position: [x,y,z,...], targets: {N: [dx,dy,dz,...]}}]}
// for every three.js mesh whose morphTargetDictionary has one of the names: the glTF mesh and primitive it
// came from (parser.associations), its POSITION attribute and each named target's morphAttributes.position
// as three.js decoded them (sparse, quantized, meshopt- and Draco-compressed data alike: the loader has
// three.js's MeshoptDecoder and DRACOLoader), in the primitive's own space.
// Exit status: 0 on success, 2 on bad arguments or missing tools, 3 when loading or playing fails,
// 4 on timeout (default 60 s).
import { createServer } from "node:http";
import { readFileSync, existsSync, statSync } from "node:fs";
import { createRequire } from "node:module";
import { dirname, resolve, basename, extname, sep } from "node:path";
import { fileURLToPath } from "node:url";

const here = dirname(fileURLToPath(import.meta.url));
const repo = resolve(here, "..", "..");

function fail(code, msg) {
  console.error(`run_three: ${msg}`);
  process.exit(code);
}

// ------------------------------------------------------------------------------------- arguments
const args = process.argv.slice(2);
let glb = null;
let times = null;
let timeoutS = 60;
let faceName = null;
let headName = "head";
let clipName = null;
let morphsAll = false;
let worldNodes = [];
let vrm = false;
let vrma = null;
let morphData = null;
for (let i = 0; i < args.length; i++) {
  const a = args[i];
  const next = () => {
    if (i + 1 >= args.length) fail(2, `${a} needs a value`);
    return args[++i];
  };
  if (a === "--times") times = next().split(",").filter((s) => s.trim() !== "").map(Number);
  else if (a === "--times-file") {
    const f = next();
    try {
      times = JSON.parse(readFileSync(f, "utf8"));
    } catch (e) {
      fail(2, `${f}: cannot read the times (${e.message})`);
    }
  } else if (a === "--timeout") timeoutS = Number(next());
  else if (a === "--face") faceName = next();
  else if (a === "--head") headName = next();
  else if (a === "--clip") clipName = next();
  else if (a === "--morphs") morphsAll = next() === "all";
  else if (a === "--morph-data") morphData = next().split(",").filter((s) => s !== "");
  else if (a === "--world") worldNodes = next().split(",").filter((s) => s !== "");
  else if (a === "--vrm") vrm = true;
  else if (a === "--vrma") { vrm = true; vrma = resolve(next()); }
  else if (a.startsWith("--")) fail(2, `unknown option ${a}`);
  else if (glb === null) glb = resolve(a);
  else fail(2, `unexpected argument ${a}`);
}
if (!glb) fail(2, "usage: node run_three.mjs FILE.glb [--times T0,T1,...] [--times-file F.json] [--timeout S]");
if (!existsSync(glb) || !statSync(glb).isFile()) fail(2, `${glb}: file not found`);
if (times === null) times = [0];
if (!Array.isArray(times) || !times.every((t) => typeof t === "number" && Number.isFinite(t))) {
  fail(2, "times must be a list of finite numbers (seconds)");
}
if (!(timeoutS > 0)) fail(2, "--timeout must be a positive number of seconds");

const threeDir = resolve(process.env.THREE_DIR || resolve(repo, ".tools", "node_modules", "three"));
if (!existsSync(resolve(threeDir, "build", "three.module.js"))) {
  fail(2, `three.js not found at ${threeDir} (run \`make tools\`)`);
}
const puppeteerDir = resolve(process.env.PUPPETEER_CORE_DIR || resolve(repo, ".tools", "node_modules", "puppeteer-core"));
if (!existsSync(resolve(puppeteerDir, "package.json"))) {
  fail(2, `puppeteer-core not found at ${puppeteerDir} (run \`make tools\`)`);
}
const vrmDir = resolve(process.env.THREE_VRM_DIR || resolve(repo, ".tools", "node_modules", "@pixiv", "three-vrm"));
const vrmaDir = resolve(repo, ".tools", "node_modules", "@pixiv", "three-vrm-animation");
if (vrm && !existsSync(resolve(vrmDir, "lib", "three-vrm.module.js"))) {
  fail(2, `three-vrm not found at ${vrmDir} (run \`make tools\`)`);
}
const chromium = process.env.CHROMIUM || "/usr/bin/chromium";
if (!existsSync(chromium)) fail(2, `Chromium not found at ${chromium} (run \`make browser\` or set CHROMIUM)`);

// ------------------------------------------------------------------------------------- the page
const PAGE = `<!doctype html>
<html><head><meta charset="utf-8"><title>faceretarget three.js check</title>
<script type="importmap">
{"imports": {"three": "/three/build/three.module.js", "three/addons/": "/three/examples/jsm/",
 "@pixiv/three-vrm": "/vrm/lib/three-vrm.module.js",
 "@pixiv/three-vrm-animation": "/vrma-lib/lib/three-vrm-animation.module.js"}}
</script>
<script type="module">
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { MeshoptDecoder } from "three/addons/libs/meshopt_decoder.module.js";
import { DRACOLoader } from "three/addons/loaders/DRACOLoader.js";

function attributeArray(a) {
  const out = new Array(a.count * 3);
  for (let i = 0; i < a.count; i++) {
    out[3 * i] = a.getX(i);
    out[3 * i + 1] = a.getY(i);
    out[3 * i + 2] = a.getZ(i);
  }
  return out;
}

function morphData(gltf, names) {
  const meshes = [];
  gltf.scene.traverse((o) => {
    if (!o.isMesh || !o.morphTargetDictionary) return;
    const here = names.filter((n) => n in o.morphTargetDictionary);
    if (!here.length) return;
    const assoc = gltf.parser.associations.get(o) || {};
    const g = o.geometry;
    const targets = {};
    for (const n of here) targets[n] = attributeArray(g.morphAttributes.position[o.morphTargetDictionary[n]]);
    meshes.push({ object: o.name, mesh: assoc.meshes ?? null, primitive: assoc.primitives ?? null,
      count: g.attributes.position.count, relative: g.morphTargetsRelative,
      position: attributeArray(g.attributes.position), targets });
  });
  return { three: THREE.REVISION, meshes };
}

window.playGlb = async (url, times, faceName, headName, opts) => {
  const loader = new GLTFLoader();
  loader.setMeshoptDecoder(MeshoptDecoder);
  loader.setDRACOLoader(new DRACOLoader().setDecoderPath("/three/examples/jsm/libs/draco/gltf/"));
  if (opts.vrm) {
    const { VRMLoaderPlugin } = await import("@pixiv/three-vrm");
    loader.register((parser) => new VRMLoaderPlugin(parser));
  }
  const gltf = await loader.loadAsync(url);
  const scene = gltf.scene;
  const theVrm = gltf.userData.vrm || null;
  if (opts.morphData) return morphData(gltf, opts.morphData);
  if (!gltf.animations.length) throw new Error(url + ": no animation");
  let clip = opts.clip ? gltf.animations.find((c) => c.name === opts.clip) : gltf.animations[0];
  if (!clip) throw new Error(url + ": no clip named " + opts.clip);
  if (opts.vrma) {
    const { VRMAnimationLoaderPlugin, createVRMAnimationClip } = await import("@pixiv/three-vrm-animation");
    const al = new GLTFLoader();
    al.register((parser) => new VRMAnimationLoaderPlugin(parser));
    const va = await al.loadAsync(opts.vrma);
    clip = createVRMAnimationClip(va.userData.vrmAnimations[0], theVrm);
  }
  let face = null;
  if (faceName) {
    face = scene.getObjectByName(faceName) || null;
    if (!face) throw new Error(url + ": no object named " + faceName);
  } else {
    scene.traverse((o) => { if (!face && o.morphTargetInfluences) face = o; });
  }
  const head = headName ? scene.getObjectByName(headName) || null : null;
  const names = [];
  if (face) {
    if (!face.morphTargetInfluences) throw new Error(url + ": " + faceName + " has no morph targets");
    const dict = face.morphTargetDictionary || {};
    for (let i = 0; i < face.morphTargetInfluences.length; i++) names.push("target" + i);
    for (const [n, i] of Object.entries(dict)) names[i] = n;
  }
  const mixer = new THREE.AnimationMixer(scene);
  const action = mixer.clipAction(clip);
  action.setLoop(THREE.LoopOnce, 1);
  action.clampWhenFinished = true;
  const out = { three: THREE.REVISION, clip: { name: clip.name, duration: clip.duration,
      tracks: clip.tracks.map((t) => t.name) },
    face: face ? face.name : null, names, times, influences: [],
    head: head ? { node: head.name, quaternion: [], position: [] } : null };
  const morphObjs = {};
  if (opts.morphsAll) {
    out.morphs = {};
    scene.traverse((o) => {
      if (!o.morphTargetInfluences) return;
      // a multi-primitive glTF mesh is a Group (the node) of meshes, one per primitive
      const node = o.isMesh && o.parent && o.parent.isGroup && !o.parent.isScene && o.parent.name &&
        o.geometry && o.parent.children.every((c) => c.isMesh) ? o.parent.name : o.name;
      if (!(node in morphObjs)) { morphObjs[node] = o; out.morphs[node] = []; }
    });
  }
  const worldObjs = {};
  if (opts.world.length) {
    out.world = {};
    for (const n of opts.world) {
      const o = scene.getObjectByName(n);
      if (!o) throw new Error(url + ": no object named " + n);
      worldObjs[n] = o;
      out.world[n] = [];
    }
  }
  for (const t of times) {
    action.reset().play();
    mixer.setTime(t);
    if (theVrm) theVrm.update(0);
    scene.updateMatrixWorld(true);
    for (const [n, o] of Object.entries(morphObjs)) out.morphs[n].push(Array.from(o.morphTargetInfluences));
    for (const [n, o] of Object.entries(worldObjs)) out.world[n].push(o.getWorldQuaternion(new THREE.Quaternion()).toArray());
    if (face) out.influences.push(Array.from(face.morphTargetInfluences));
    if (head) {
      out.head.quaternion.push(head.quaternion.toArray());
      out.head.position.push(head.position.toArray());
    }
  }
  return out;
};
window.threeReady = true;
</script></head><body></body></html>`;

// ------------------------------------------------------------------------------ static server
const TYPES = { ".js": "text/javascript", ".mjs": "text/javascript", ".html": "text/html",
  ".glb": "model/gltf-binary", ".vrm": "model/gltf-binary", ".json": "application/json",
  ".wasm": "application/wasm", ".vrma": "model/gltf-binary" };
const glbDir = dirname(glb);
const roots = { "/three/": threeDir, "/glb/": glbDir, "/vrm/": vrmDir, "/vrma-lib/": vrmaDir,
  "/vrma/": vrma ? dirname(vrma) : glbDir };

function serveFile(res, root, rel) {
  const p = resolve(root, decodeURIComponent(rel));
  if (p !== root && !p.startsWith(root + sep)) {
    res.writeHead(403).end();
    return;
  }
  if (!existsSync(p) || !statSync(p).isFile()) {
    res.writeHead(404).end();
    return;
  }
  res.writeHead(200, { "Content-Type": TYPES[extname(p)] || "application/octet-stream" });
  res.end(readFileSync(p));
}

const server = createServer((req, res) => {
  const url = new URL(req.url, "http://127.0.0.1");
  if (url.pathname === "/favicon.ico") {
    res.writeHead(204).end();
    return;
  }
  if (url.pathname === "/" || url.pathname === "/index.html") {
    res.writeHead(200, { "Content-Type": "text/html" }).end(PAGE);
    return;
  }
  for (const [prefix, root] of Object.entries(roots)) {
    if (url.pathname.startsWith(prefix)) return serveFile(res, root, url.pathname.slice(prefix.length));
  }
  res.writeHead(404).end();
});

// ------------------------------------------------------------------------------------------ run
let browser = null;
const pageErrors = [];

async function cleanup() {
  try {
    if (browser) await browser.close();
  } catch (e) {
    // the browser is already gone
  }
  server.close();
}

const timer = setTimeout(async () => {
  console.error(`run_three: timed out after ${timeoutS} s playing ${glb}` +
    (pageErrors.length ? ` (page errors: ${pageErrors.join("; ")})` : ""));
  if (browser) {
    const proc = browser.process();
    if (proc) proc.kill("SIGKILL");
  }
  server.close();
  process.exit(4);
}, timeoutS * 1000);

try {
  const require = createRequire(resolve(puppeteerDir, "package.json"));
  const mod = require(puppeteerDir);
  const puppeteer = mod.default && mod.default.launch ? mod.default : mod;
  await new Promise((ok, err) => server.listen(0, "127.0.0.1", ok).on("error", err));
  const port = server.address().port;
  browser = await puppeteer.launch({
    executablePath: chromium,
    headless: true, // Chrome's new headless mode (--headless=new)
    args: ["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run"],
    timeout: timeoutS * 1000,
  });
  const page = await browser.newPage();
  page.on("pageerror", (e) => pageErrors.push(String(e.message || e)));
  page.on("console", (m) => {
    if (m.type() === "error" || m.type() === "warn") console.error(`browser ${m.type()}: ${m.text()}`);
  });
  page.on("requestfailed", (r) => pageErrors.push(`request failed: ${r.url()}`));
  page.setDefaultTimeout(timeoutS * 1000);
  await page.goto(`http://127.0.0.1:${port}/`);
  await page.waitForFunction(() => window.threeReady === true);
  const url = `/glb/${encodeURIComponent(basename(glb))}`;
  const opts = { clip: clipName, morphsAll, world: worldNodes, vrm, morphData,
    vrma: vrma ? `/vrma/${encodeURIComponent(basename(vrma))}` : null };
  const out = await page.evaluate((u, ts, f, h, o) => window.playGlb(u, ts, f, h, o), url, times, faceName,
    headName, opts);
  out.browser = await browser.version();
  clearTimeout(timer);
  await cleanup();
  // wait for the pipe to take everything (process.exit would cut a large report at 64 KiB)
  await new Promise((ok) => process.stdout.write(JSON.stringify(out) + "\n", ok));
  process.exit(0);
} catch (e) {
  clearTimeout(timer);
  console.error(`run_three: ${glb}: ${e && e.message ? e.message : e}` +
    (pageErrors.length ? ` (page errors: ${pageErrors.join("; ")})` : ""));
  await cleanup();
  process.exit(3);
}
