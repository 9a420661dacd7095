// Unit tests of the viewer's pure parts (Node's test runner: `node --test test/unit/`):
// pose math, orbiting, the depth sort and the time reach, against direct computations.
import { test } from "node:test";
import assert from "node:assert/strict";
import { centreOf, orbitControls, poseFrom, quatToRows, rowsToQuat } from "../../src/camera.js";
import { depthSort, sortScratch } from "../../src/sort.js";
import { reach2 } from "../../src/web4d.js";
import { mergeModels, neededSegments, wantedSegments } from "../../src/segments.js";

let seed = 7;
const rand = () => ((seed = (seed * 1103515245 + 12345) % 2147483648) / 2147483648);
const randomQuat = () => {
  const q = [rand() - 0.5, rand() - 0.5, rand() - 0.5, rand() - 0.5];
  const n = Math.hypot(...q);
  return q.map((v) => v / n);
};
const close = (a, b, tol, what) => assert.ok(Math.abs(a - b) <= tol, `${what}: ${a} vs ${b}`);
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];

test("quaternions and rotation rows convert both ways, in every branch", () => {
  // Random rotations, plus half turns (trace −1) about each axis for the non-trace branches.
  const quats = Array.from({ length: 200 }, randomQuat).concat([
    [0, 1, 0, 0],
    [0, 0, 1, 0],
    [0, 0, 0, 1],
  ]);
  for (const q of quats) {
    const R = quatToRows(q);
    for (let r = 0; r < 3; r++) {
      for (let c = 0; c < 3; c++) close(dot(R[r], R[c]), r === c ? 1 : 0, 1e-12, "orthonormal");
    }
    const back = quatToRows(rowsToQuat(R));
    for (let r = 0; r < 3; r++) for (let c = 0; c < 3; c++) close(back[r][c], R[r][c], 1e-12, `R[${r}][${c}]`);
    assert.ok(rowsToQuat(R)[0] >= 0);
  }
});

test("a pose made from rows and a centre has that centre", () => {
  const R = quatToRows(randomQuat());
  const eye = [1.5, -2, 0.25];
  const c = centreOf(poseFrom(R, eye));
  for (let k = 0; k < 3; k++) close(c[k], eye[k], 1e-12, "centre");
});

test("orbiting keeps the distance to the target and a level horizon", () => {
  const handlers = {};
  const canvas = {
    addEventListener: (type, f) => (handlers[type] = f),
    setPointerCapture: () => {},
  };
  const up = [0, 0, 1];
  let changes = 0;
  const controls = orbitControls(canvas, up, () => {}, () => changes++);
  // A level camera 4 m from the origin looking at it along +y (OpenCV: y down = −z world).
  const R = [
    [1, 0, 0],
    [0, 0, -1],
    [0, 1, 0],
  ];
  controls.setFrom(poseFrom(R, [0, -4, 0]), [0, 0, 0], 500);
  handlers.pointerdown({ clientX: 100, clientY: 100, button: 0, pointerId: 1 });
  handlers.pointermove({ clientX: 160, clientY: 80 });
  handlers.pointermove({ clientX: 220, clientY: 120 });
  const pose = controls.pose;
  close(Math.hypot(...centreOf(pose)), 4, 1e-9, "distance to the target");
  // Still looking at the target, with no roll: the camera's x axis stays horizontal.
  const forward = pose.rotation[2];
  const toTarget = centreOf(pose).map((v) => -v / 4);
  close(dot(forward, toTarget), 1, 1e-9, "looks at the target");
  close(pose.rotation[0][2], 0, 1e-9, "x axis horizontal");
  assert.equal(changes, 2);
  // The wheel moves along the axis towards the target.
  handlers.wheel({ deltaY: -200, preventDefault: () => {} });
  const d = Math.hypot(...centreOf(controls.pose));
  assert.ok(d < 4 && d > 0.4, `distance after zooming in: ${d}`);
});

test("the depth sort draws back to front and leaves out what the engine culls", () => {
  const n = 3000;
  const f = {
    position: Float32Array.from({ length: 3 * n }, () => 6 * rand() - 3),
    velocity: Float32Array.from({ length: 3 * n }, () => rand() - 0.5),
    tMean: Float32Array.from({ length: n }, () => rand()),
    reach2: new Float32Array(n),
  };
  const opacity = Array.from({ length: n }, () => rand());
  const sigma = Array.from({ length: n }, () => 0.02 + 0.3 * rand());
  for (let i = 0; i < n; i++) f.reach2[i] = reach2(opacity[i], sigma[i]);
  const view = { r2: [0.3, 0.2, Math.sqrt(1 - 0.13)], tz: 2 };
  const time = 0.4;
  const out = new Uint32Array(n);
  const count = depthSort(f, n, view.r2, view.tz, 0.01, time, out, sortScratch(n));
  // Direct: the engine's cull (ω > 0.05, σ(o)·ω ≥ 1/255, depth ≥ near), depth of the slice.
  const depth = (i) => {
    const dt = time - f.tMean[i];
    return [0, 1, 2].reduce((z, k) => z + view.r2[k] * (f.position[3 * i + k] + f.velocity[3 * i + k] * dt), view.tz);
  };
  const kept = [];
  for (let i = 0; i < n; i++) {
    const dt = time - f.tMean[i];
    const omega = Math.exp((-0.5 * dt * dt) / (sigma[i] * sigma[i]));
    if (omega > 0.05 && opacity[i] * omega >= 1 / 255 && depth(i) >= 0.01) kept.push(i);
  }
  // Float32 rounding of reach2 may move a borderline Gaussian; none here.
  assert.equal(count, kept.length);
  assert.deepEqual([...out.subarray(0, count)].sort((a, b) => a - b), kept);
  const span = Math.max(...kept.map(depth)) - Math.min(...kept.map(depth));
  for (let k = 1; k < count; k++) {
    assert.ok(depth(out[k - 1]) >= depth(out[k]) - span / 65535, `entry ${k} is nearer than the one after it`);
  }
});

test("the page holds the segments at the playhead and just ahead, wrapping round", () => {
  // Three 2-s segments of a 6-s clip, each reaching 0.5 s past its own part.
  const segments = [
    { reach: [0, 2.5] },
    { reach: [1.5, 4.5] },
    { reach: [3.5, 6] },
  ];
  assert.deepEqual(neededSegments(segments, 0.2), [0]);
  assert.deepEqual(neededSegments(segments, 2.0), [0, 1]);
  assert.deepEqual(neededSegments(segments, 6), [2]);
  assert.deepEqual(wantedSegments(segments, 0.2, 1, [0, 6]), [0]);
  assert.deepEqual(wantedSegments(segments, 1.0, 1, [0, 6]), [0, 1]);
  assert.deepEqual(wantedSegments(segments, 4.8, 1, [0, 6]), [2]);
  // Near the end, the start of the clip comes next.
  assert.deepEqual(wantedSegments(segments, 5.5, 1, [0, 6]), [0, 2]);
  for (let t = 0; t <= 6; t += 0.25) {
    const wanted = wantedSegments(segments, t, 1, [0, 6]);
    for (const k of neededSegments(segments, t)) assert.ok(wanted.includes(k), `t = ${t}: segment ${k}`);
    assert.ok(wanted.length <= 3);
  }
});

test("merged files keep every record and field in order", () => {
  const perRow = 2;
  const texels = 3;
  const file = (count, base) => {
    const m = { header: { count, texels }, count, texels, perRow, rows: Math.ceil(count / perRow), loaded: count };
    m.data = new Uint32Array(m.rows * perRow * texels * 4);
    for (let i = 0; i < count * texels * 4; i++) m.data[i] = base + i;
    for (const [name, k] of [["position", 3], ["velocity", 3], ["tMean", 1], ["tSigma", 1], ["opacity", 1], ["reach2", 1]]) {
      m[name] = Float32Array.from({ length: k * count }, (_, i) => base + 0.5 * i);
    }
    return m;
  };
  const a = file(3, 1000);
  const b = file(2, 5000);
  const m = mergeModels([a, b], perRow);
  assert.equal(m.count, 5);
  assert.equal(m.header.count, 5);
  assert.equal(m.rows, 3);
  assert.equal(m.loaded, 5);
  const words = texels * 4;
  assert.deepEqual(Array.from(m.data.subarray(0, 3 * words)), Array.from(a.data.subarray(0, 3 * words)));
  assert.deepEqual(Array.from(m.data.subarray(3 * words, 5 * words)), Array.from(b.data.subarray(0, 2 * words)));
  assert.deepEqual(Array.from(m.position), [...a.position, ...b.position]);
  assert.deepEqual(Array.from(m.reach2), [...a.reach2, ...b.reach2]);
});
