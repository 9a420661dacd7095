// Validates .glb files with the Khronos glTF validator (npm gltf-validator) and prints one
// JSON line per file: its error, warning and info counts and every message (code, JSON
// pointer, severity: 0 error, 1 warning, 2 info, 3 hint). Usage: node
// test/validate-gltf.mjs FILE.glb... The caller judges the messages: this validator
// release predates KHR_gaussian_splatting, so it calls that extension's attribute names
// invalid.
import { readFile } from 'node:fs/promises';
import { validateBytes } from 'gltf-validator';

for (const path of process.argv.slice(2)) {
  const report = await validateBytes(new Uint8Array(await readFile(path)));
  const { numErrors, numWarnings, numInfos, messages } = report.issues;
  console.log(JSON.stringify({
    path,
    errors: numErrors,
    warnings: numWarnings,
    infos: numInfos,
    messages: messages.map(({ code, pointer, severity, message }) => ({ code, pointer, severity, message })),
  }));
}
