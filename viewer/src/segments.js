// A long clip's model in time segments (scene.json `segments`, src/export/viewer.rs): the
// file of what is drawn throughout (`model`) plus one file per segment of the clip. The
// page keeps the segments whose reach holds the playhead or the stretch just ahead of it
// and drops the rest, so it never holds more than a few; what it draws is one model (the
// shape web4d.js makes) of the loaded files, rebuilt whenever the set changes.

/// Indices of the segments whose reach `[a, b]` contains model time `t`: the page draws
/// time `t` correctly only with all of them.
export function neededSegments(segments, t) {
  const out = [];
  segments.forEach((s, k) => {
    if (s.reach[0] <= t && t <= s.reach[1]) out.push(k);
  });
  return out;
}

/// Indices of the segments to hold at time `t` of the clip `[t0, t1]`: those whose reach
/// meets `[t, t + ahead]`, wrapping round to the clip's start as playback does.
export function wantedSegments(segments, t, ahead, [t0, t1]) {
  const meets = (s, a, b) => s.reach[0] <= b && s.reach[1] >= a;
  const over = t + ahead - t1;
  const out = [];
  segments.forEach((s, k) => {
    if (meets(s, t, t + ahead) || (over > 0 && meets(s, t0, t0 + over))) out.push(k);
  });
  return out;
}

/// One model of the records of `models` (each complete, all with the same header but for
/// `count`) in that order, laid out `perRow` records to a texture row.
export function mergeModels(models, perRow) {
  const first = models[0];
  const count = models.reduce((n, m) => n + m.count, 0);
  const texels = first.texels;
  const words = texels * 4;
  const rows = Math.max(1, Math.ceil(count / perRow));
  const merged = {
    header: { ...first.header, count },
    count,
    start: 0,
    texels,
    perRow,
    rows,
    recordBytes: texels * 16,
    loaded: count,
    data: new Uint32Array(rows * perRow * words),
  };
  const fields = [
    ["position", 3],
    ["velocity", 3],
    ["tMean", 1],
    ["tSigma", 1],
    ["opacity", 1],
    ["reach2", 1],
  ];
  for (const [name, k] of fields) merged[name] = new Float32Array(k * count);
  let at = 0;
  for (const m of models) {
    if (m.texels !== texels) throw new Error("the model's files differ in record size: export again");
    merged.data.set(m.data.subarray(0, m.count * words), at * words);
    for (const [name, k] of fields) merged[name].set(m[name].subarray(0, k * m.count), k * at);
    at += m.count;
  }
  return merged;
}
