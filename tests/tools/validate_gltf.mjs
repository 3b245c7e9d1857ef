// Validate a glTF / GLB file with the Khronos glTF validator and print its JSON report.
//
// usage: node tests/tools/validate_gltf.mjs FILE [VALIDATOR_DIR]
//
// VALIDATOR_DIR is the installed npm package folder (node_modules/gltf-validator); by default
// $GLTF_VALIDATOR_DIR, else .tools/node_modules/gltf-validator at the repository root (where
// `make tools` installs it), else whatever Node resolves from this script or NODE_PATH.
// Exit status: 0 when the report has no errors, 1 when it has errors, 2 when the file cannot be
// read or the validator cannot be loaded.
import { readFileSync, existsSync } from "node:fs";
import { createRequire } from "node:module";
import { dirname, resolve, basename } from "node:path";
import { fileURLToPath } from "node:url";

const here = dirname(fileURLToPath(import.meta.url));
const file = process.argv[2];
if (!file) {
  console.error("usage: node validate_gltf.mjs FILE [VALIDATOR_DIR]");
  process.exit(2);
}
const candidates = [
  process.argv[3],
  process.env.GLTF_VALIDATOR_DIR,
  resolve(here, "..", "..", ".tools", "node_modules", "gltf-validator"),
].filter(Boolean);
const require = createRequire(import.meta.url);
let validator = null;
for (const c of candidates) {
  if (existsSync(resolve(c, "package.json"))) {
    validator = require(resolve(c));
    break;
  }
}
if (!validator) {
  try {
    validator = require("gltf-validator");
  } catch (e) {
    console.error(`gltf-validator not found (looked in ${candidates.join(", ")} and NODE_PATH)`);
    process.exit(2);
  }
}
let bytes;
try {
  bytes = new Uint8Array(readFileSync(file));
} catch (e) {
  console.error(`${file}: cannot read (${e.message})`);
  process.exit(2);
}
try {
  // a .gltf's buffers and images are read from beside it (data URIs the validator reads itself)
  const externalResourceFunction = (uri) => new Promise((ok, err) => {
    try {
      ok(new Uint8Array(readFileSync(resolve(dirname(resolve(file)), decodeURIComponent(uri)))));
    } catch (e) {
      err(e.message);
    }
  });
  const report = await validator.validateBytes(bytes, { uri: basename(file), maxIssues: 1000,
    externalResourceFunction });
  // exitCode, not exit(): a pipe's writes are asynchronous, and exit() would cut the report at 64-128 KB
  process.stdout.write(JSON.stringify(report, null, 2) + "\n");
  process.exitCode = report.issues.numErrors > 0 ? 1 : 0;
} catch (e) {
  console.error(`${file}: validator failed: ${e}`);
  process.exit(2);
}
