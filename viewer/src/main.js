// splat4d browser viewer: draws the export's whole 4D model (`model.4dgs`, listed in
// scene.json) natively, slicing every Gaussian at the playback time on the GPU and
// colouring it for the viewpoint shown (renderer.js). Opens at the first training camera
// (its exact pose and intrinsics); buttons switch cameras, dragging orbits, the slider
// and play button move through the clip at the capture's pace. The model streams in,
// the most important Gaussians first, and is drawn while it loads.
//
// URL parameters (for links and tests): ?frame=N (the export's N-th time step) or
// ?t=0..1 (fraction of the clip), ?camera=K (training camera, default 0),
// ?pose=qw,qx,qy,qz,tx,ty,tz (a world → camera pose, OpenCV axes, with camera K's
// intrinsics), ?play=0 (start paused), ?goto=N (step to frame N inside the page once
// the first view is drawn), ?ui=0 (canvas only, for screenshots), ?float=0 (blend in 8
// bits). The link button puts the current view and time into the address bar.
//
// window.viewerState = { ready, time, camera, loaded, total } tells a test when the whole
// model is loaded and drawn in the depth order of the current view and time.
import { NEAR, createRenderer, recordsPerRow } from "./renderer.js";
import { createSorter } from "./sort.js";
import { loadModel } from "./web4d.js";
import { mergeModels, neededSegments, wantedSegments } from "./segments.js";
import { floatTarget } from "./float_target.js";
import { centreOf, orbitControls, quatToRows, rowsToQuat } from "./camera.js";

const $ = (id) => document.getElementById(id);
const setStatus = (text) => ($("status").textContent = text);

async function main() {
  const params = new URLSearchParams(location.search);
  if (params.get("ui") === "0") document.body.classList.add("bare");
  const scene = await (await fetch("scene.json")).json();
  if (!scene.model) throw new Error("scene.json names no model (an export older than this viewer: export again)");
  const times = scene.times && scene.times.length ? scene.times : [0];
  const [t0, t1] = [Math.min(...times), Math.max(...times)];
  const cameras = scene.cameras || [];
  const unitsPerSecond = scene.time.units_per_second;
  const seconds = (t) => t / unitsPerSecond + scene.time.start_seconds;

  const canvas = $("canvas");
  const background = (scene.background || [0, 0, 0]).map((v) => Math.min(1, Math.max(0, v)));
  const bg255 = background.map((v) => Math.round(255 * v));
  canvas.style.background = `rgb(${bg255[0]}, ${bg255[1]}, ${bg255[2]})`;
  const gl = canvas.getContext("webgl2", { antialias: false, premultipliedAlpha: true, alpha: false });
  if (!gl) throw new Error("this browser has no WebGL2");
  let backdrop = null; // a learned backdrop (scene.json `backdrop`), drawn instead of `background`
  if (scene.backdrop) {
    const image = new Image();
    image.src = scene.backdrop.file;
    await image.decode();
    backdrop = { ...scene.backdrop, image };
  }
  const target = params.get("float") === "0" ? null : floatTarget(gl, background, backdrop);
  const renderer = createRenderer(gl);

  const state = {
    time: t0,
    camera: null, // training camera shown exactly, or null
    version: 0, // counts changes of view, time or loaded data
    asked: -1, // the version whose depth order was last asked for
    sorted: -1, // the version of the depth order in use
    quiet: 0, // frames drawn with it
    ready: false,
    loaded: 0,
    fresh: 0, // the first version of the model drawn now
  };
  const changed = () => state.version++;
  const sorter = createSorter(({ version, order, n }) => {
    if (version < state.fresh) return; // an order of the model before the last merge
    renderer.setOrder(order, n);
    state.sorted = version;
    state.quiet = 0;
  });

  // ---- view -----------------------------------------------------------------------
  const resize = () => {
    const dpr = window.devicePixelRatio || 1;
    const [w, h] = [Math.round(canvas.clientWidth * dpr), Math.round(canvas.clientHeight * dpr)];
    if (canvas.width !== w || canvas.height !== h) {
      canvas.width = w;
      canvas.height = h;
      changed();
    }
  };
  resize();
  let intrinsics = null; // { fx, fy, cx, cy } of the image, fitted into the canvas
  let imageCamera = null; // the training camera whose intrinsics are shown
  const fitIntrinsics = (cam) => {
    const [W, H] = [canvas.width, canvas.height];
    const s = Math.min(W / cam.width, H / cam.height);
    return { fx: cam.fx * s, fy: cam.fy * s, cx: W / 2 + (cam.cx - cam.width / 2) * s, cy: H / 2 + (cam.cy - cam.height / 2) * s };
  };
  const centre = scene.centre || [0, 0, 0];
  const controls = orbitControls(
    canvas,
    scene.up || [0, 0, -1],
    () => {
      // The first touch leaves the training camera: keep its focal length, centre the image.
      if (state.camera === null) return;
      state.camera = null;
      intrinsics = { ...intrinsics, cx: canvas.width / 2, cy: canvas.height / 2 };
      cameraButtons.forEach((b) => b.classList.remove("active"));
      changed();
    },
    changed,
  );
  const cameraButtons = cameras.map((cam, k) => {
    const b = document.createElement("button");
    b.textContent = cam.name;
    b.title = `training camera ${cam.name} (key ${k + 1})`;
    b.onclick = () => pin(k);
    $("cams").appendChild(b);
    return b;
  });
  /// Show training camera `k` exactly (or `pose` with its intrinsics).
  const pin = (k, pose = null) => {
    const cam = cameras[k];
    imageCamera = cam;
    intrinsics = fitIntrinsics(cam);
    controls.setFrom(pose || { rotation: cam.rotation, translation: cam.translation }, centre, intrinsics.fy);
    state.camera = pose ? null : k;
    cameraButtons.forEach((b, i) => b.classList.toggle("active", i === state.camera));
    changed();
  };
  const clampCamera = (k) => Math.max(0, Math.min(cameras.length - 1, Number(k) | 0));
  const startCamera = cameras.length ? clampCamera(params.get("camera") ?? scene.start_camera ?? 0) : null;
  let startPose = null;
  if (params.has("pose")) {
    const v = params.get("pose").split(",").map(Number);
    if (v.length !== 7 || v.some((x) => !Number.isFinite(x))) throw new Error("?pose= needs 7 numbers: qw,qx,qy,qz,tx,ty,tz");
    startPose = { rotation: quatToRows(v.slice(0, 4)), translation: v.slice(4) };
  }
  if (startCamera !== null) pin(startCamera, startPose);
  else {
    // No cameras listed: look at the centre from −z·3.
    const f = canvas.height;
    intrinsics = { fx: f, fy: f, cx: canvas.width / 2, cy: canvas.height / 2 };
    controls.setFrom({ rotation: [[1, 0, 0], [0, 1, 0], [0, 0, 1]], translation: [-centre[0], -centre[1], 3 - centre[2]] }, centre, f);
  }
  window.addEventListener("resize", () => {
    const height = canvas.height;
    resize();
    if (state.camera !== null || !imageCamera) intrinsics = imageCamera ? fitIntrinsics(imageCamera) : intrinsics;
    else {
      const s = canvas.height / height; // orbiting: keep the vertical field of view
      intrinsics = { fx: intrinsics.fx * s, fy: intrinsics.fy * s, cx: canvas.width / 2, cy: canvas.height / 2 };
    }
    changed();
  });
  const view = () => {
    const pose = controls.pose;
    return { rotation: pose.rotation, translation: pose.translation, eye: centreOf(pose), ...intrinsics };
  };

  // ---- time -----------------------------------------------------------------------
  const slider = $("time");
  slider.min = "0";
  slider.max = "1";
  slider.step = "any";
  const nearestFrame = (t) => times.reduce((best, v, i) => (Math.abs(v - t) < Math.abs(times[best] - t) ? i : best), 0);
  const setTime = (t) => {
    t = Math.max(t0, Math.min(t1, t));
    if (t !== state.time) changed();
    state.time = t;
    slider.value = String(t1 > t0 ? (t - t0) / (t1 - t0) : 0);
    const i = nearestFrame(t);
    $("label").textContent = `t = ${seconds(t).toFixed(3)} s (frame ${i + 1}/${times.length})`;
  };
  const clampFrame = (i) => Math.max(0, Math.min(times.length - 1, Math.round(Number(i)) || 0));
  if (params.has("frame")) setTime(times[clampFrame(params.get("frame"))]);
  else if (params.has("t")) setTime(t0 + Number(params.get("t")) * (t1 - t0));
  else setTime(t0);
  let playing = false;
  let playFrom = { wall: 0, time: t0 };
  const setPlaying = (p) => {
    playing = p && t1 > t0;
    $("play").textContent = playing ? "❚❚" : "▶";
    playFrom = { wall: performance.now(), time: state.time };
  };
  $("play").onclick = () => setPlaying(!playing);
  slider.oninput = () => {
    setPlaying(false);
    setTime(t0 + Number(slider.value) * (t1 - t0));
  };
  $("link").onclick = () => {
    const pose = controls.pose;
    const q = rowsToQuat(pose.rotation);
    const p = new URLSearchParams(location.search);
    p.set("camera", String(cameras.indexOf(imageCamera)));
    p.set("pose", [...q, ...pose.translation].map((v) => +v.toFixed(6)).join(","));
    p.set("t", ((state.time - t0) / Math.max(t1 - t0, 1e-12)).toFixed(6));
    p.delete("frame");
    p.set("play", "0");
    history.replaceState(null, "", `?${p}`);
    navigator.clipboard?.writeText(location.href).catch(() => {});
    setStatus("link to this view in the address bar");
  };
  window.addEventListener("keydown", (e) => {
    if (e.code === "Space") {
      setPlaying(!playing);
      e.preventDefault();
    } else if (e.code === "Period" || e.code === "Comma") {
      setPlaying(false);
      setTime(times[clampFrame(nearestFrame(state.time) + (e.code === "Period" ? 1 : -1))]);
    } else {
      const digit = /^Digit([1-9])$/.exec(e.code);
      if (digit && Number(digit[1]) <= cameras.length) pin(Number(digit[1]) - 1);
    }
  });

  // ---- data -----------------------------------------------------------------------
  // `model.4dgs` streams in and is drawn as it arrives. A long clip's other files (time
  // segments) load once it is in: those at the playhead and the next segment's worth of
  // the clip, the rest dropped (segments.js); `model` is then all loaded files in one.
  const progress = $("progress");
  const layout = (header) => ({ perRow: recordsPerRow(gl, header.texels) });
  const segments = scene.segments || [];
  const ahead = segments.length ? (t1 - t0) / segments.length : 0;
  let model = null; // what is drawn
  let base = null; // `model.4dgs`, once complete
  const held = new Map(); // segment index → { model } (null while it loads)
  let merged = []; // the segments in `model`
  loadModel(scene.model.file, scene.model.bytes, layout, (m) => {
    model = m;
    progress.value = m.loaded / m.count;
    setStatus(`loading ${scene.model.file}: ${m.loaded} / ${m.count} Gaussians`);
  })
    .then((m) => {
      base = m;
      document.body.classList.add("loaded");
      setStatus("");
    })
    .catch(fail);
  /// Load what the playhead wants, drop what it left, and merge when the set changed.
  const holdSegments = () => {
    if (!base || !segments.length) return;
    const wanted = wantedSegments(segments, state.time, ahead, [t0, t1]);
    for (const k of wanted) {
      if (held.has(k)) continue;
      const entry = { model: null };
      held.set(k, entry);
      loadModel(segments[k].file, segments[k].bytes, layout, () => {})
        .then((m) => {
          entry.model = m;
        })
        .catch(fail);
    }
    for (const k of [...held.keys()]) if (!wanted.includes(k)) held.delete(k);
    const ready = [...held.keys()].filter((k) => held.get(k).model).sort((a, b) => a - b);
    const waiting = neededSegments(segments, state.time).filter((k) => !ready.includes(k));
    const text = waiting.length ? `loading ${waiting.map((k) => segments[k].file).join(", ")}` : "";
    if ($("status").textContent !== text && (text || $("status").textContent.startsWith("loading model-"))) setStatus(text);
    if (ready.join() === merged.join()) return;
    merged = ready;
    model = ready.length ? mergeModels([base, ...ready.map((k) => held.get(k).model)], base.perRow) : base;
    renderer.reset();
    sorter.reset();
    state.loaded = 0;
    changed();
    state.fresh = state.version;
  };
  let gotoFrame = params.has("goto") ? clampFrame(params.get("goto")) : null;
  setPlaying(params.get("play") !== "0");

  const frame = (now) => {
    try {
      draw(now);
    } catch (e) {
      fail(e);
      return;
    }
    requestAnimationFrame(frame);
  };
  const draw = (now) => {
    if (playing) {
      const span = t1 - t0;
      const t = playFrom.time - t0 + ((now - playFrom.wall) / 1000) * unitsPerSecond;
      setTime(t0 + (((t % span) + span) % span));
    }
    holdSegments();
    if (model) {
      const uploaded = renderer.upload(model);
      if (uploaded !== state.loaded) {
        state.loaded = uploaded;
        sorter.feed(model, uploaded);
        changed();
      }
      const v = view();
      if (state.asked !== state.version) {
        sorter.request(state.version, v, state.time, NEAR);
        state.asked = state.version;
      }
      if (target) target.begin();
      else gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      gl.viewport(0, 0, canvas.width, canvas.height);
      if (target) gl.clearColor(0, 0, 0, 0);
      else gl.clearColor(background[0], background[1], background[2], 1);
      gl.clear(gl.COLOR_BUFFER_BIT);
      renderer.draw(model, v, state.time, canvas.width, canvas.height);
      if (target) target.end(v);
      state.quiet++;
    }
    const drawn = neededSegments(segments, state.time).every((k) => merged.includes(k));
    const ready = !!model && drawn && state.loaded === model.count && state.sorted === state.version && state.quiet >= 2;
    if (ready && gotoFrame !== null) {
      setTime(times[gotoFrame]); // ?goto: one step inside the page, as the keys do
      gotoFrame = null;
    } else if (ready !== state.ready) {
      state.ready = ready;
      if (ready) document.title = "splat4d viewer: ready";
    }
    window.viewerState = {
      ready: state.ready,
      time: state.time,
      camera: state.camera,
      loaded: state.loaded,
      total: model ? model.count : scene.model.gaussians,
      segments: merged,
    };
  };
  requestAnimationFrame(frame);
}

function fail(e) {
  setStatus(`error: ${e.message}`);
  document.title = "splat4d viewer: error";
  window.viewerState = { ready: false, error: e.message };
  console.error(e);
}

main().catch(fail);
