// Drive the live page of `faceretarget live` in headless Chromium and report what it shows.
//
// usage: node tests/browser/run_live.mjs URL [--frames N] [--after N] [--timeout SECONDS] [--render]
//                                        [--screenshot FILE.png] [--passive]
//
// Opens URL (the session's page) in Chromium ($CHROMIUM, else /usr/bin/chromium) through
// puppeteer-core ($PUPPETEER_CORE_DIR, else .tools/node_modules/puppeteer-core), waits for the page
// to load the character and open its WebSocket, then
//   1. samples `window.live.snapshot()` (frames received, the face mesh's morphTargetInfluences by
//      morph name, the head node's quaternion, the last message) every 40 ms until N frames
//      (--frames, default 60) have arrived;
//   2. moves the page's sliders (head amplitude 0, emotion amount 0.5) as a user would (input
//      events), and waits until the session has echoed the new parameters and --after (default 15)
//      more frames have arrived; one more snapshot ("final").
// Without --render the page is opened with ?render=0 (no WebGL: the scene graph is still updated);
// with --render Chromium gets software WebGL (SwiftShader) and `window.live.probe()` (share of
// non-background pixels) is taken with the mouth in two states.  --passive only watches: no slider is
// moved and the script returns when the session closes the WebSocket (final = the last snapshot).
//
// stdout: one JSON object {browser, url, ready_ms, samples: [snapshot...], final: snapshot,
// probes: [...], errors: [...], failed_requests: [...], console: [...], renderer, renderError}.
// Exit status: 0 on success, 2 on bad arguments or missing tools, 3 when the page fails, 4 on timeout.
import { existsSync } from "node:fs";
import { createRequire } from "node:module";
import { dirname, resolve } from "node:path";
import { fileURLToPath } from "node:url";

const here = dirname(fileURLToPath(import.meta.url));
const repo = resolve(here, "..", "..");

function fail(code, msg) {
  console.error(`run_live: ${msg}`);
  process.exit(code);
}

const args = process.argv.slice(2);
let url = null;
let frames = 60;
let after = 15;
let timeoutS = 60;
let render = false;
let screenshot = null;
let passive = false;
for (let i = 0; i < args.length; i++) {
  const a = args[i];
  const next = () => {
    if (i + 1 >= args.length) fail(2, `${a} needs a value`);
    return args[++i];
  };
  if (a === "--frames") frames = Number(next());
  else if (a === "--after") after = Number(next());
  else if (a === "--timeout") timeoutS = Number(next());
  else if (a === "--render") render = true;
  else if (a === "--screenshot") screenshot = next();
  else if (a === "--passive") passive = true;
  else if (a.startsWith("--")) fail(2, `unknown option ${a}`);
  else if (url === null) url = a;
  else fail(2, `unexpected argument ${a}`);
}
if (!url) fail(2, "usage: node run_live.mjs URL [--frames N] [--after N] [--timeout S] [--render]");
if (!(frames > 0 && after > 0 && timeoutS > 0)) fail(2, "--frames, --after and --timeout must be positive");

const puppeteerDir = resolve(process.env.PUPPETEER_CORE_DIR || resolve(repo, ".tools", "node_modules", "puppeteer-core"));
if (!existsSync(resolve(puppeteerDir, "package.json"))) fail(2, `puppeteer-core not found at ${puppeteerDir} (run \`make tools\`)`);
const chromium = process.env.CHROMIUM || "/usr/bin/chromium";
if (!existsSync(chromium)) fail(2, `Chromium not found at ${chromium} (run \`make browser\` or set CHROMIUM)`);

let browser = null;
const errors = [];
const failedRequests = [];
const consoleLines = [];

const timer = setTimeout(() => {
  console.error(`run_live: timed out after ${timeoutS} s on ${url}` + (errors.length ? ` (page errors: ${errors.join("; ")})` : ""));
  if (browser && browser.process()) browser.process().kill("SIGKILL");
  process.exit(4);
}, timeoutS * 1000);

const sleep = (ms) => new Promise((ok) => setTimeout(ok, ms));

try {
  const require = createRequire(resolve(puppeteerDir, "package.json"));
  const mod = require(puppeteerDir);
  const puppeteer = mod.default && mod.default.launch ? mod.default : mod;
  const flags = ["--no-sandbox", "--disable-dev-shm-usage", "--no-first-run"];
  flags.push(...(render ? ["--use-angle=swiftshader", "--enable-unsafe-swiftshader"] : ["--disable-gpu"]));
  browser = await puppeteer.launch({ executablePath: chromium, headless: true, args: flags, timeout: timeoutS * 1000 });
  const page = await browser.newPage();
  await page.setViewport({ width: 640, height: 480 });
  page.on("pageerror", (e) => errors.push(String(e.message || e)));
  // Chromium sometimes reports a fetch that the page read completely as net::ERR_ABORTED: listed, not fatal
  page.on("requestfailed", (r) => failedRequests.push(`${r.url()} (${(r.failure() || {}).errorText})`));
  page.on("console", (m) => consoleLines.push(`${m.type()}: ${m.text()}`));
  page.setDefaultTimeout(timeoutS * 1000);
  const t0 = Date.now();
  const target = new URL(url);
  if (!render) target.searchParams.set("render", "0");
  await page.goto(target.href);
  await page.waitForFunction(() => window.live && (window.live.ready || window.live.error));
  const readyMs = Date.now() - t0;
  const err = await page.evaluate(() => window.live.error);
  if (err) throw new Error(`the page failed: ${err}`);

  const samples = [];
  const probes = [];
  const snap = () => page.evaluate(() => window.live.snapshot());
  let lastFrames = -1;
  for (;;) {
    const s = await snap();
    if (s.frames !== lastFrames) {
      samples.push(s);
      lastFrames = s.frames;
    }
    const closed = await page.evaluate(() => window.live.closed);
    if (passive ? closed : s.frames >= frames) break;
    if (closed) throw new Error(`the session closed after ${s.frames} frames`);
    await sleep(40);
  }
  if (render) probes.push(await page.evaluate(() => window.live.probe()));

  // the sliders, as a user moves them
  if (!passive) await page.evaluate(() => {
    for (const [id, v] of [["head", "0"], ["emotion", "0.5"]]) {
      const el = document.getElementById(id);
      el.value = v;
      el.dispatchEvent(new Event("input", { bubbles: true }));
    }
  });
  if (!passive) {
    await page.waitForFunction(() => {
      const p = window.live.params;
      return p && p.head_amplitude === 0 && p.emotion_amount === 0.5;
    });
    const echoed = await page.evaluate(() => window.live.paramsFrames);
    await page.waitForFunction((n) => window.live.frames >= n || window.live.closed, {}, echoed + after);
  }
  const final = await snap();
  if (render) probes.push(await page.evaluate(() => window.live.probe()));
  if (screenshot) await page.screenshot({ path: screenshot });
  const out = { browser: await browser.version(), url: target.href, ready_ms: readyMs, samples, final, probes,
    errors, failed_requests: failedRequests, console: consoleLines, renderer: await page.evaluate(() => window.live.renderer),
    renderError: await page.evaluate(() => window.live.renderError) };
  clearTimeout(timer);
  await browser.close();
  await new Promise((ok) => process.stdout.write(JSON.stringify(out) + "\n", ok));
  process.exit(0);
} catch (e) {
  clearTimeout(timer);
  console.error(`run_live: ${url}: ${e && e.message ? e.message : e}` + (errors.length ? ` (page errors: ${errors.join("; ")})` : ""));
  for (const line of consoleLines) console.error(`browser ${line}`);
  try {
    if (browser) await browser.close();
  } catch (e2) {
    // already gone
  }
  process.exit(3);
}
