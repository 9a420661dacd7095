// Streaming reader of `model.4dgs` (the layout is documented in src/export/web4d.rs):
// records land in a texture-shaped Uint32Array as bytes arrive, and the fields the depth
// sort needs (position, velocity, time centre and width, opacity) are decoded into
// float arrays once per record.

const MAGIC = "4DGSWEB1";

// Half float → float, by table.
const HALF = (() => {
  const t = new Float32Array(65536);
  for (let h = 0; h < 65536; h++) {
    const s = h & 0x8000 ? -1 : 1;
    const e = (h >> 10) & 31;
    const m = h & 1023;
    t[h] = e === 0 ? s * m * 2 ** -24 : e === 31 ? (m ? NaN : s * Infinity) : s * (1 + m / 1024) * 2 ** (e - 15);
  }
  return t;
})();

/// Load `url` (of `bytes` bytes) progressively. `layout(header)` is called once the header
/// is in and returns `{ perRow }` (records per texture row); `onRecords(count)` is called
/// whenever more whole records have arrived. Returns the model once complete.
export async function loadModel(url, bytes, layout, onRecords) {
  const res = await fetch(url);
  if (!res.ok) throw new Error(`${url}: HTTP ${res.status}`);
  const reader = res.body ? res.body.getReader() : null;
  const file = new Uint8Array(bytes);
  let got = 0;
  const put = (chunk) => {
    if (got + chunk.length > file.length) throw new Error(`${url}: longer than scene.json says (${bytes} bytes); export again`);
    file.set(chunk, got);
    got += chunk.length;
  };
  let model = null;
  const tryHeader = () => {
    if (got < 12) return;
    const magic = String.fromCharCode(...file.subarray(0, 8));
    if (magic !== MAGIC) throw new Error(`${url}: not a splat4d web model (starts with ${JSON.stringify(magic)})`);
    const len = new DataView(file.buffer).getUint32(8, true);
    if (got < 12 + len) return;
    const header = JSON.parse(new TextDecoder().decode(file.subarray(12, 12 + len)));
    const start = Math.ceil((12 + len) / 16) * 16;
    model = makeModel(header, start, layout(header));
  };
  const advance = () => {
    if (!model) tryHeader();
    if (!model) return;
    const whole = Math.min(model.count, Math.floor(Math.max(0, got - model.start) / model.recordBytes));
    if (whole > model.loaded) {
      model.take(file, whole);
      onRecords(model);
    }
  };
  if (reader) {
    for (;;) {
      const { done, value } = await reader.read();
      if (done) break;
      put(value);
      advance();
    }
  } else {
    put(new Uint8Array(await res.arrayBuffer()));
    advance();
  }
  if (!model) throw new Error(`${url}: truncated before the end of its header`);
  if (model.loaded < model.count) throw new Error(`${url}: truncated (${model.loaded} of ${model.count} Gaussians); export again`);
  return model;
}

/// The squared time distance within which a Gaussian of opacity `o` and width `s` is
/// drawn: ω = exp(−½Δt²/s²) must exceed 0.05 (the engine's cutoff) and o·ω reach 1/255.
export function reach2(o, s) {
  const cut = Math.min(2 * Math.log(20), o > 1 / 255 ? 2 * Math.log(255 * o) : -1);
  return cut * s * s;
}

function makeModel(header, start, { perRow }) {
  const n = header.count;
  const texels = header.texels;
  const rows = Math.max(1, Math.ceil(n / perRow));
  const words = texels * 4;
  const model = {
    header,
    count: n,
    start,
    texels,
    perRow,
    rows,
    recordBytes: texels * 16,
    loaded: 0,
    // The texture's contents: `rows × perRow` records.
    data: new Uint32Array(rows * perRow * words),
    position: new Float32Array(3 * n),
    velocity: new Float32Array(3 * n),
    tMean: new Float32Array(n),
    tSigma: new Float32Array(n),
    opacity: new Float32Array(n),
    // (t − μt)² below this: drawn at t (ω > 0.05 and σ(o)·ω ≥ 1/255); see `reach2`.
    reach2: new Float32Array(n),
    /// Copy records `loaded..upTo` out of the file's bytes.
    take(file, upTo) {
      const from = this.loaded;
      const src = new Uint32Array(file.buffer, start + from * this.recordBytes, (upTo - from) * words);
      this.data.set(src, from * words);
      const f = new Float32Array(this.data.buffer);
      for (let i = from; i < upTo; i++) {
        const o = i * words;
        this.position[3 * i] = f[o];
        this.position[3 * i + 1] = f[o + 1];
        this.position[3 * i + 2] = f[o + 2];
        this.tMean[i] = f[o + 3];
        const w4 = this.data[o + 4];
        const w5 = this.data[o + 5];
        this.velocity[3 * i] = HALF[w4 & 0xffff];
        this.velocity[3 * i + 1] = HALF[w4 >>> 16];
        this.velocity[3 * i + 2] = HALF[w5 & 0xffff];
        this.tSigma[i] = HALF[w5 >>> 16];
        this.opacity[i] = HALF[this.data[o + 7] >>> 16];
        this.reach2[i] = reach2(this.opacity[i], this.tSigma[i]);
      }
      this.loaded = upTo;
    },
  };
  return model;
}
