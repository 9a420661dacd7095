// Time the viewer's per-frame CPU work, the depth sort (sort.js `depthSort`, run in a
// worker by the page), on a
// synthetic model: N Gaussians in a 10 m room, living over parts of a 10 s clip.
// Usage: node bench/sort.mjs [N=200000] [rounds=50]
import { depthSort, sortScratch } from "../src/sort.js";
import { reach2 } from "../src/web4d.js";

const n = Number(process.argv[2] || 200000);
const rounds = Number(process.argv[3] || 50);
let seed = 1;
const rand = () => ((seed = (seed * 1103515245 + 12345) % 2147483648) / 2147483648);
const model = {
  position: Float32Array.from({ length: 3 * n }, () => 10 * rand() - 5),
  velocity: Float32Array.from({ length: 3 * n }, () => 0.2 * rand() - 0.1),
  tMean: Float32Array.from({ length: n }, () => 10 * rand()),
  tSigma: Float32Array.from({ length: n }, () => 0.2 + 5 * rand()),
  opacity: Float32Array.from({ length: n }, () => rand()),
};
model.reach2 = model.opacity.map((o, i) => reach2(o, model.tSigma[i]));
const view = { rotation: [[1, 0, 0], [0, 0, -1], [0, 1, 0]], translation: [0, 0, 8] };
const out = new Uint32Array(n);
const scratch = sortScratch(n);
let drawn = 0;
for (let k = 0; k < 5; k++) drawn = depthSort(model, n, view.rotation[2], view.translation[2], 0.01, 5, out, scratch);
const start = performance.now();
for (let k = 0; k < rounds; k++) drawn = depthSort(model, n, view.rotation[2], view.translation[2], 0.01, (10 * k) / rounds, out, scratch);
const ms = (performance.now() - start) / rounds;
console.log(`depthSort: ${n} Gaussians, ${drawn} drawn at the last time, ${ms.toFixed(2)} ms per sort (node ${process.version})`);
