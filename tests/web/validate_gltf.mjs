// node tests/web/validate_gltf.mjs FILE.glb...
// Runs the Khronos glTF validator (npm gltf-validator, installed into web/ by
// the scripts) on each file. Prints one JSON line per file (errors, warnings,
// and the first messages); exits 1 when any file has an error, 2 on bad use.
import { readFile } from "node:fs/promises";
import { createRequire } from "node:module";
import path from "node:path";
import { fileURLToPath } from "node:url";

const here = path.dirname(fileURLToPath(import.meta.url));
const require = createRequire(path.join(here, "../../web/package.json"));
const validator = require("gltf-validator");

const files = process.argv.slice(2);
if (!files.length) {
  console.error("usage: node tests/web/validate_gltf.mjs FILE.glb...");
  process.exit(2);
}
let failed = false;
for (const file of files) {
  const bytes = new Uint8Array(await readFile(file));
  const report = await validator.validateBytes(bytes, {
    uri: path.basename(file),
    maxIssues: 200,
    // A .glb written by lightfarm stands alone: any external reference is a defect.
    externalResourceFunction: (uri) => Promise.reject(new Error(`external resource ${uri} in ${file}`)),
  });
  const issues = report.issues;
  const messages = issues.messages.filter((m) => m.severity <= 1).slice(0, 10)
                     .map((m) => `${m.severity === 0 ? "error" : "warning"} ${m.code} ${m.pointer || ""}: ${m.message}`);
  console.log(JSON.stringify({ file, errors: issues.numErrors, warnings: issues.numWarnings,
                               infos: issues.numInfos, messages }));
  if (issues.numErrors > 0) failed = true;
}
process.exit(failed ? 1 : 0);
