// Render one frame of a .glb with three.js (WebGL, SwiftShader) in headless Chromium and write it as a PNG.
//
// usage: node tests/browser/render_three.mjs FILE.glb --spec SPEC.json --out OUT.png [--timeout SECONDS]
//
// What a glTF viewer shows, for comparing faceretarget's preview with it (tests/test_preview_look.py,
// bench/preview_look.py): GLTFLoader (with the MeshoptDecoder) reads the file, its first clip (or
// spec.clip) is played to spec.time seconds (LoopOnce, clamped: an AnimationMixer as in run_three.mjs),
// and the scene is drawn once with an OrthographicCamera and the lights the spec gives:
//
//   {"width": W, "height": H, "time": T, "clip": NAME | null, "background": [r, g, b] (sRGB 0..1),
//    "camera": {"right": [x, y, z], "up": [x, y, z], "back": [x, y, z] (world directions: image right,
//               image up, toward the viewer), "center": [x, y, z] (world point at the image centre),
//               "half_width": w, "half_height": h (world units), "depth": d (distance of the camera
//               from the centre along "back"; near 0, far 2 d)},
//    "ambient": a, "lights": [{"direction": [x, y, z] (toward the light, world), "intensity": i}, ...],
//    "lambert": true | false, "highlight": {"halfway": [x, y, z] (view space), "strength": s,
//    "exponent": e} | null}
//
// With "lambert" every material becomes a MeshLambertMaterial keeping its base colour, texture, vertex
// colours, alpha mode (alphaTest, transparent, depthWrite) and side, so the lighting is the preview's
// (three.js's Lambert BRDF divides by pi, so a light of intensity pi * k gives k n.l), with "highlight"
// the preview's Blinn-Phong highlight added to the lit colour.
// Tone mapping is off and the output is sRGB (three.js's defaults); no antialiasing.
// stdout: one JSON object {three, browser, width, height, meshes: [{name, material, alphaMode, side,
// transparent, alphaTest, map}]}.  Exit status: 0 on success, 2 on bad arguments or missing tools,
// 3 when loading or rendering fails, 4 on timeout.
import { createServer } from "node:http";
import { readFileSync, writeFileSync, existsSync, statSync } from "node:fs";
import { createRequire } from "node:module";
import { dirname, resolve, basename, extname, sep } from "node:path";
import { fileURLToPath } from "node:url";

const here = dirname(fileURLToPath(import.meta.url));
const repo = resolve(here, "..", "..");

function fail(code, msg) {
  console.error(`render_three: ${msg}`);
  process.exit(code);
}

const args = process.argv.slice(2);
let glb = null;
let specFile = null;
let outFile = null;
let timeoutS = 90;
for (let i = 0; i < args.length; i++) {
  const a = args[i];
  const next = () => {
    if (i + 1 >= args.length) fail(2, `${a} needs a value`);
    return args[++i];
  };
  if (a === "--spec") specFile = next();
  else if (a === "--out") outFile = resolve(next());
  else if (a === "--timeout") timeoutS = Number(next());
  else if (a.startsWith("--")) fail(2, `unknown option ${a}`);
  else if (glb === null) glb = resolve(a);
  else fail(2, `unexpected argument ${a}`);
}
if (!glb || !specFile || !outFile) fail(2, "usage: node render_three.mjs FILE.glb --spec SPEC.json --out OUT.png");
if (!existsSync(glb) || !statSync(glb).isFile()) fail(2, `${glb}: file not found`);
let spec;
try {
  spec = JSON.parse(readFileSync(specFile, "utf8"));
} catch (e) {
  fail(2, `${specFile}: cannot read the spec (${e.message})`);
}
if (!(timeoutS > 0)) fail(2, "--timeout must be a positive number of seconds");

const threeDir = resolve(process.env.THREE_DIR || resolve(repo, ".tools", "node_modules", "three"));
if (!existsSync(resolve(threeDir, "build", "three.module.js"))) fail(2, `three.js not found at ${threeDir} (run \`make tools\`)`);
const puppeteerDir = resolve(process.env.PUPPETEER_CORE_DIR || resolve(repo, ".tools", "node_modules", "puppeteer-core"));
if (!existsSync(resolve(puppeteerDir, "package.json"))) fail(2, `puppeteer-core not found at ${puppeteerDir} (run \`make tools\`)`);
const chromium = process.env.CHROMIUM || "/usr/bin/chromium";
if (!existsSync(chromium)) fail(2, `Chromium not found at ${chromium} (run \`make browser\` or set CHROMIUM)`);

const PAGE = `<!doctype html>
<html><head><meta charset="utf-8"><title>faceretarget three.js render</title>
<script type="importmap">
{"imports": {"three": "/three/build/three.module.js", "three/addons/": "/three/examples/jsm/"}}
</script>
<script type="module">
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { MeshoptDecoder } from "three/addons/libs/meshopt_decoder.module.js";

window.renderGlb = async (url, spec) => {
  const loader = new GLTFLoader();
  loader.setMeshoptDecoder(MeshoptDecoder);
  const gltf = await loader.loadAsync(url);
  const scene = gltf.scene;
  if (gltf.animations.length) {
    const clip = spec.clip ? gltf.animations.find((c) => c.name === spec.clip) : gltf.animations[0];
    if (!clip) throw new Error(url + ": no clip named " + spec.clip);
    const mixer = new THREE.AnimationMixer(scene);
    const action = mixer.clipAction(clip);
    action.setLoop(THREE.LoopOnce, 1);
    action.clampWhenFinished = true;
    action.reset().play();
    mixer.setTime(spec.time || 0);
  }
  const meshes = [];
  scene.traverse((o) => {
    if (!o.isMesh) return;
    const m = o.material;
    meshes.push({ name: o.name, material: m.name, side: m.side, transparent: m.transparent,
      alphaTest: m.alphaTest, depthWrite: m.depthWrite, map: !!m.map, vertexColors: m.vertexColors });
    if (spec.lambert) {
      o.material = new THREE.MeshLambertMaterial({ name: m.name, color: m.color, map: m.map,
        vertexColors: m.vertexColors, alphaTest: m.alphaTest, transparent: m.transparent, opacity: m.opacity,
        depthWrite: m.depthWrite, side: m.side });
      if (spec.highlight) {
        // the preview's highlight: strength * max(n . h, 0)^exponent added to the lit colour, h the half
        // vector of the key light and the view direction (view space, as three.js's normal)
        const hl = spec.highlight;
        o.material.onBeforeCompile = (shader) => {
          shader.uniforms.hlHalf = { value: new THREE.Vector3(...hl.halfway) };
          shader.uniforms.hlStrength = { value: hl.strength };
          shader.uniforms.hlExponent = { value: hl.exponent };
          shader.fragmentShader = "uniform vec3 hlHalf;\\nuniform float hlStrength;\\nuniform float hlExponent;\\n" +
            shader.fragmentShader.replace("#include <opaque_fragment>",
              "outgoingLight += vec3(hlStrength * pow(max(dot(normalize(normal), hlHalf), 0.0), hlExponent));\\n" +
              "#include <opaque_fragment>");
        };
      }
    }
  });
  scene.updateMatrixWorld(true);
  const bg = new THREE.Color().setRGB(spec.background[0], spec.background[1], spec.background[2],
    THREE.SRGBColorSpace);
  scene.add(new THREE.AmbientLight(0xffffff, spec.ambient));
  for (const l of spec.lights) {
    const d = new THREE.DirectionalLight(0xffffff, l.intensity);
    d.position.set(...l.direction);
    d.target.position.set(0, 0, 0);
    scene.add(d);
    scene.add(d.target);
  }
  const c = spec.camera;
  const cam = new THREE.OrthographicCamera(-c.half_width, c.half_width, c.half_height, -c.half_height,
    0.0, 2.0 * c.depth);
  const basis = new THREE.Matrix4().makeBasis(new THREE.Vector3(...c.right), new THREE.Vector3(...c.up),
    new THREE.Vector3(...c.back));
  cam.quaternion.setFromRotationMatrix(basis);
  cam.position.set(...c.center).addScaledVector(new THREE.Vector3(...c.back), c.depth);
  cam.updateMatrixWorld(true);
  const canvas = document.createElement("canvas");
  canvas.width = spec.width;
  canvas.height = spec.height;
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
  renderer.setPixelRatio(1);
  renderer.setSize(spec.width, spec.height, false);
  renderer.setClearColor(bg, 1.0);
  renderer.render(scene, cam);
  const png = canvas.toDataURL("image/png");
  return { three: THREE.REVISION, width: spec.width, height: spec.height, meshes, png };
};
window.threeReady = true;
</script></head><body></body></html>`;

const TYPES = { ".js": "text/javascript", ".mjs": "text/javascript", ".html": "text/html",
  ".glb": "model/gltf-binary", ".vrm": "model/gltf-binary", ".wasm": "application/wasm" };
const roots = { "/three/": threeDir, "/glb/": dirname(glb) };

function serveFile(res, root, rel) {
  const p = resolve(root, decodeURIComponent(rel));
  if (p !== root && !p.startsWith(root + sep)) return res.writeHead(403).end();
  if (!existsSync(p) || !statSync(p).isFile()) return res.writeHead(404).end();
  res.writeHead(200, { "Content-Type": TYPES[extname(p)] || "application/octet-stream" });
  res.end(readFileSync(p));
}

const server = createServer((req, res) => {
  const url = new URL(req.url, "http://127.0.0.1");
  if (url.pathname === "/favicon.ico") return res.writeHead(204).end();
  if (url.pathname === "/" || url.pathname === "/index.html") {
    return res.writeHead(200, { "Content-Type": "text/html" }).end(PAGE);
  }
  for (const [prefix, root] of Object.entries(roots)) {
    if (url.pathname.startsWith(prefix)) return serveFile(res, root, url.pathname.slice(prefix.length));
  }
  res.writeHead(404).end();
});

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

const timer = setTimeout(() => {
  console.error(`render_three: timed out after ${timeoutS} s rendering ${glb}` +
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
    headless: true,
    // WebGL without a GPU: ANGLE on SwiftShader (Chromium's software Vulkan)
    args: ["--no-sandbox", "--disable-dev-shm-usage", "--no-first-run", "--use-angle=swiftshader",
      "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"],
    timeout: timeoutS * 1000,
  });
  const page = await browser.newPage();
  page.on("pageerror", (e) => pageErrors.push(String(e.message || e)));
  page.on("console", (m) => {
    if (m.type() === "error" || m.type() === "warn") console.error(`browser ${m.type()}: ${m.text()}`);
  });
  page.setDefaultTimeout(timeoutS * 1000);
  await page.goto(`http://127.0.0.1:${port}/`);
  // a page that does not parse never gets ready: fail with its error rather than at the timeout
  let watch = null;
  await Promise.race([page.waitForFunction(() => window.threeReady === true),
    new Promise((_, reject) => {
      watch = setInterval(() => pageErrors.length && reject(new Error(pageErrors.join("; "))), 100);
    })]).finally(() => clearInterval(watch));
  const out = await page.evaluate((u, s) => window.renderGlb(u, s), `/glb/${encodeURIComponent(basename(glb))}`, spec);
  out.browser = await browser.version();
  clearTimeout(timer);
  await cleanup();
  writeFileSync(outFile, Buffer.from(out.png.split(",")[1], "base64"));
  delete out.png;
  await new Promise((ok) => process.stdout.write(JSON.stringify(out) + "\n", ok));
  process.exit(0);
} catch (e) {
  clearTimeout(timer);
  console.error(`render_three: ${glb}: ${e && e.message ? e.message : e}` +
    (pageErrors.length ? ` (page errors: ${pageErrors.join("; ")})` : ""));
  await cleanup();
  process.exit(3);
}
