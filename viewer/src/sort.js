// The depth order of the Gaussians for a view and time, computed in a Web Worker so that
// drawing never waits for it: the page draws with the last order it got (nearly right
// while the view or time moves) and asks for a new one whenever the view, the time or the
// loaded data change.

/// Back-to-front order of the first `count` Gaussians seen from a camera whose third
/// rotation row is `r2` and translation z is `tz`, at model time `time`: those culled in
/// time or too faint (`(t − μt)² ≥ reach2`) and those nearer than `near` are left out.
/// A 16-bit counting sort on camera depth; returns the number written to `out`.
/// Self-contained: it runs inside the worker from its source text.
export function depthSort(f, count, r2, tz, near, time, out, s) {
  const { position: P, velocity: V, tMean, reach2 } = f;
  const { depth, ids, key, buckets } = s;
  let n = 0;
  let lo = Infinity;
  let hi = -Infinity;
  for (let i = 0; i < count; i++) {
    const dt = time - tMean[i];
    if (!(dt * dt < reach2[i])) continue;
    const j = 3 * i;
    const z = r2[0] * (P[j] + V[j] * dt) + r2[1] * (P[j + 1] + V[j + 1] * dt) + r2[2] * (P[j + 2] + V[j + 2] * dt) + tz;
    if (!(z >= near)) continue;
    depth[n] = z;
    ids[n] = i;
    n++;
    if (z < lo) lo = z;
    if (z > hi) hi = z;
  }
  buckets.fill(0);
  const scale = hi > lo ? 65535 / (hi - lo) : 0;
  for (let k = 0; k < n; k++) {
    // Far first: the largest depth gets key 0.
    const b = ((hi - depth[k]) * scale) | 0;
    key[k] = b;
    buckets[b]++;
  }
  let sum = 0;
  for (let b = 0; b < 65536; b++) {
    const c = buckets[b];
    buckets[b] = sum;
    sum += c;
  }
  for (let k = 0; k < n; k++) out[buckets[key[k]]++] = ids[k];
  return n;
}

/// Work arrays for `depthSort` on `n` Gaussians.
export function sortScratch(n) {
  return { depth: new Float32Array(n), ids: new Uint32Array(n), key: new Uint16Array(n), buckets: new Uint32Array(65536) };
}

const FIELDS = [
  ["position", 3],
  ["velocity", 3],
  ["tMean", 1],
  ["reach2", 1],
];

// The worker's body; its helpers come in as arguments, since minified code renames them.
function worker(fields, depthSort, sortScratch) {
  let f = null;
  let s = null;
  self.onmessage = (e) => {
    const m = e.data;
    if (m.type === "init") {
      f = {};
      for (const [name, k] of fields) f[name] = new Float32Array(k * m.n);
      s = sortScratch(m.n);
    } else if (m.type === "data") {
      for (const [name, k] of fields) f[name].set(m[name], k * m.from);
    } else if (m.type === "sort") {
      const out = new Uint32Array(Math.max(1, m.count));
      const n = f ? depthSort(f, m.count, m.r2, m.tz, m.near, m.time, out, s) : 0;
      self.postMessage({ version: m.version, order: out, n }, [out.buffer]);
    }
  };
}

/// Start the sort worker; `onSorted({ version, order, n })` receives each order.
export function createSorter(onSorted) {
  const source = `(${worker.toString()})(${JSON.stringify(FIELDS)}, ${depthSort.toString()}, ${sortScratch.toString()});`;
  const w = new Worker(URL.createObjectURL(new Blob([source], { type: "text/javascript" })));
  let busy = false;
  let pending = null;
  let sent = 0;
  const post = (m) => {
    busy = true;
    w.postMessage(m);
  };
  w.onmessage = (e) => {
    busy = false;
    onSorted(e.data);
    if (pending) {
      post(pending);
      pending = null;
    }
  };
  w.onerror = (e) => console.error("sort worker:", e.message);
  return {
    /// Send the worker the sort fields of records `sent..upTo` (those the GPU has).
    feed(model, upTo) {
      if (sent === 0 && upTo > 0) w.postMessage({ type: "init", n: model.count });
      if (upTo <= sent) return;
      const m = { type: "data", from: sent };
      for (const [name, k] of FIELDS) m[name] = model[name].slice(k * sent, k * upTo);
      w.postMessage(m);
      sent = upTo;
    },
    /// Start over with another model: `feed` sends it from its first record.
    reset() {
      sent = 0;
    },
    /// Ask for the order of the fed records for `view` at `time` (the latest request wins).
    request(version, view, time, near) {
      const m = { type: "sort", version, count: sent, r2: view.rotation[2], tz: view.translation[2], near, time };
      if (busy) pending = m;
      else post(m);
    },
  };
}
