// Validate glTF binaries with the Khronos glTF-Validator (npm `gltf-validator`).
//
//   node tools/browser/gltf_check.mjs FILE.glb [FILE2.glb ...] [--json OUT.json]
//
// Prints each file's error / warning / info counts and the first messages; exits 1 if any file
// has an error (warnings and infos, e.g. an extension the validator does not know, are listed
// but do not fail). With --json the full reports are written to OUT.json.
//
// One exception, listed separately: the validator (2.0.0-dev.3.10, the newest on npm) predates
// KHR_gaussian_splatting and reports each of its attribute semantics
// (`KHR_gaussian_splatting:SCALE`, ...) as MESH_PRIMITIVE_INVALID_ATTRIBUTE. Exactly those
// messages (that code, at an `attributes/KHR_gaussian_splatting:` pointer, in a file whose
// extensionsUsed names the extension) are counted as "extension attributes unknown to the
// validator", not as errors; any other error fails.
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
  const usesSplats = (report.info?.extensionsUsed ?? []).includes('KHR_gaussian_splatting');
  const isSplatAttr = (m) => usesSplats && m.severity === 0 && m.code === 'MESH_PRIMITIVE_INVALID_ATTRIBUTE'
    && /\/attributes\/KHR_gaussian_splatting:[A-Z0-9_]+$/.test(m.pointer ?? '');
  const splatAttrs = i.messages.filter(isSplatAttr);
  const errors = i.messages.filter((m) => m.severity === 0 && !isSplatAttr(m));
  console.log(`${f}: ${errors.length} errors, ${i.numWarnings} warnings, ${i.numInfos} infos, ${i.numHints} hints`
    + (splatAttrs.length ? ` (+ ${splatAttrs.length} KHR_gaussian_splatting attribute names unknown to this validator)` : ''));
  for (const m of i.messages.filter((m) => !isSplatAttr(m)).slice(0, 12)) {
    const sev = ['error', 'warning', 'info', 'hint'][m.severity];
    console.log(`  ${sev} ${m.code} ${m.pointer ?? ''}: ${m.message}`);
  }
  if (errors.length > 0) failed = true;
}
if (jsonOut) fs.writeFileSync(jsonOut, JSON.stringify(reports, null, 1));
console.log(failed ? 'glTF validation FAILED' : `glTF validation passed: ${files.length} file(s), 0 errors`);
process.exit(failed ? 1 : 0);
