// Validate glTF binaries with the Khronos glTF-Validator (npm `gltf-validator`).
//
//   node tools/browser/gltf_check.mjs FILE.glb [FILE2.glb ...] [--json OUT.json]
//
// Prints each file's error / warning / info counts and the first messages; exits 1 if any file
// has an error (warnings and infos, e.g. an extension the validator does not know, are listed
// but do not fail). With --json the full reports are written to OUT.json.
import validator from 'gltf-validator';
import fs from 'node:fs';
import path from 'node:path';

const argv = process.argv.slice(2);
let jsonOut = null;
const files = [];
for (let i = 0; i < argv.length; i++) {
  if (argv[i] === '--json') jsonOut = argv[++i];
  else files.push(argv[i]);
}
if (files.length === 0) {
  console.error('usage: node gltf_check.mjs FILE.glb [...] [--json OUT.json]');
  process.exit(2);
}
let failed = false;
const reports = {};
for (const f of files) {
  const bytes = new Uint8Array(fs.readFileSync(f));
  const report = await validator.validateBytes(bytes, {
    uri: path.basename(f),
    maxIssues: 0,
    externalResourceFunction: () => Promise.reject(new Error('external resources are not allowed')),
  });
  const i = report.issues;
  reports[f] = report;
  console.log(`${f}: ${i.numErrors} errors, ${i.numWarnings} warnings, ${i.numInfos} infos, ${i.numHints} hints`);
  for (const m of i.messages.slice(0, 12)) {
    const sev = ['error', 'warning', 'info', 'hint'][m.severity];
    console.log(`  ${sev} ${m.code} ${m.pointer ?? ''}: ${m.message}`);
  }
  if (i.numErrors > 0) failed = true;
}
if (jsonOut) fs.writeFileSync(jsonOut, JSON.stringify(reports, null, 1));
console.log(failed ? 'glTF validation FAILED' : `glTF validation passed: ${files.length} file(s), 0 errors`);
process.exit(failed ? 1 : 0);
