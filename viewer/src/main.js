// splat4d browser viewer: plays the per-timestep `.splat` frames listed in scene.json with
// gsplat.js. It opens at the first training camera (its exact pose and intrinsics), a row
// of buttons switches between the training cameras (showing the colours seen from that
// camera), dragging orbits from there, and the time slider / play button move through the
// frames. `?splatv=URL` plays the export's `.splatv` instead, drawn by gsplat's own
// `.splatv` renderer (a check that the file plays in a third-party player).
//
// URL parameters (for links and tests): ?frame=N or ?t=0..1 (fraction of the sequence),
// ?camera=K (training camera, default 0), ?play=0 (start paused), ?goto=N (switch to frame
// N once the first frame is shown), ?ui=0 (canvas only, for screenshots), ?float=0 (blend
// in 8 bits, as gsplat does by itself), ?stock=1 (gsplat's shaders unpatched, 8-bit: what
// gsplat alone would show), ?splatv=../scene.splatv (serve the export folder, not only
// viewer/).
//
// window.viewerState = { ready, frame, camera, mode, loaded, total } tells a test when the
// requested frame is drawn and depth-sorted for the current camera.
import * as SPLAT from "gsplat";
import { patchGsplat } from "./gsplat_patches.js";
import { floatTarget } from "./float_target.js";

const $ = (id) => document.getElementById(id);
const setStatus = (text) => ($("status").textContent = text);

// Quaternions as [x, y, z, w].
const qmul = (a, b) => [
  a[3] * b[0] + a[0] * b[3] + a[1] * b[2] - a[2] * b[1],
  a[3] * b[1] - a[0] * b[2] + a[1] * b[3] + a[2] * b[0],
  a[3] * b[2] + a[0] * b[1] - a[1] * b[0] + a[2] * b[3],
  a[3] * b[3] - a[0] * b[0] - a[1] * b[1] - a[2] * b[2],
];
const qconj = (q) => [-q[0], -q[1], -q[2], q[3]];
const qrotate = (q, v) => qmul(qmul(q, [v[0], v[1], v[2], 0]), qconj(q)).slice(0, 3);

/// Fetch `url` as an ArrayBuffer, reporting received bytes to `onBytes(count)`.
async function fetchBytes(url, onBytes) {
  const res = await fetch(url);
  if (!res.ok) throw new Error(`${url}: HTTP ${res.status}`);
  if (!res.body) {
    const whole = await res.arrayBuffer();
    onBytes(whole.byteLength);
    return whole;
  }
  const reader = res.body.getReader();
  const chunks = [];
  let size = 0;
  for (;;) {
    const { done, value } = await reader.read();
    if (done) break;
    chunks.push(value);
    size += value.length;
    onBytes(value.length);
  }
  const out = new Uint8Array(size);
  let at = 0;
  for (const c of chunks) {
    out.set(c, at);
    at += c.length;
  }
  return out.buffer;
}

// What the page shows and how far it has got; `ready` once the wanted frame is packed,
// uploaded and depth-sorted for the current camera.
const state = {
  frame: -1, // frame in the live splat
  colours: null, // camera whose colours are in the live splat (null: the .splat's own)
  want: 0, // frame asked for
  position: 0, // slider position (fractional in .splatv mode)
  phase: "packing", // packing → sorting → shown
  sortMark: 0,
  quiet: 0,
  ready: false,
};

async function main() {
  const params = new URLSearchParams(location.search);
  if (params.get("ui") === "0") document.body.classList.add("bare");
  const sceneInfo = await (await fetch("scene.json")).json();
  const frames = sceneInfo.frames;
  if (!frames || !frames.length) throw new Error("scene.json lists no frames");
  const cameras = sceneInfo.cameras || [];
  const last = frames.length - 1;
  const splatvUrl = params.get("splatv");
  const mode = splatvUrl ? "splatv" : "frames";
  const fps = sceneInfo.fps || 15;

  const canvas = $("canvas");
  // The colour the model was trained on, behind the splats (as render and eval draw it).
  const background = (sceneInfo.background || [0, 0, 0]).map((v) => Math.min(1, Math.max(0, v)));
  const bg255 = background.map((v) => Math.round(255 * v));
  canvas.style.background = `rgb(${bg255[0]}, ${bg255[1]}, ${bg255[2]})`;
  // ?stock=1: gsplat as published (its culling and low-pass, 8-bit blending), to compare.
  const stock = params.get("stock") === "1";
  if (!stock) patchGsplat();
  // No shader passes: gsplat's default fade-in pass shrinks the splats while it runs.
  const renderer = new SPLAT.WebGLRenderer(canvas, []);
  const gl = renderer.gl;
  const target = stock || params.get("float") === "0" ? null : floatTarget(gl, background);
  const scene = new SPLAT.Scene();
  const camera = new SPLAT.Camera();
  camera.data.near = 0.01; // the engine's near plane (gsplat: 0.1)
  camera.data.far = 1000;
  const programs = [renderer.renderProgram];

  const clampFrame = (i) => Math.max(0, Math.min(last, Math.round(Number(i)) || 0));
  let startFrame = 0;
  if (params.has("frame")) startFrame = clampFrame(params.get("frame"));
  else if (params.has("t")) startFrame = clampFrame(Number(params.get("t")) * last);
  const startCamera = cameras.length
    ? Math.max(0, Math.min(cameras.length - 1, Number(params.get("camera") ?? sceneInfo.start_camera ?? 0) | 0))
    : null;

  // ---- loading, with progress -------------------------------------------------------
  const progress = $("progress");
  const rowBytes = 32 + 3 * cameras.length;
  let received = 0;
  const expected = mode === "frames" ? (sceneInfo.rows || 0) * rowBytes * frames.length : 0;
  const showProgress = (what) => {
    const mb = (v) => (v / 1e6).toFixed(1);
    if (expected > 0) progress.value = Math.min(1, received / expected);
    setStatus(`loading ${what} (${mb(received)}${expected > 0 ? ` / ${mb(expected)}` : ""} MB)`);
  };
  const loaded = new Array(frames.length).fill(null); // { splat, colours: [per camera] }
  let loadedCount = 0;
  let live = null; // the one gsplat Splat whose rows are replaced per frame

  /// The rows of frame `i` as gsplat SplatData, with the colours seen from camera `cam`
  /// (null: the .splat's colours, seen from the mean camera centre).
  const frameData = (i, cam) => {
    const data = SPLAT.SplatData.Deserialize(new Uint8Array(loaded[i].splat.slice(0)));
    const rgb = cam === null ? null : loaded[i].colours[cam];
    if (rgb) {
      const src = new Uint8Array(rgb);
      const dst = data.colors;
      if (src.length !== 3 * data.vertexCount) throw new Error(`${frames[i].colours[cam]}: wrong size`);
      for (let r = 0; r < data.vertexCount; r++) {
        dst[4 * r] = src[3 * r];
        dst[4 * r + 1] = src[3 * r + 1];
        dst[4 * r + 2] = src[3 * r + 2];
      }
    }
    return data;
  };

  if (mode === "frames") {
    const loadFrame = async (i) => {
      const note = () => showProgress(`frame ${loadedCount + 1} / ${frames.length}`);
      const splat = await fetchBytes(frames[i].file, (n) => ((received += n), note()));
      if (sceneInfo.rows && splat.byteLength !== 32 * sceneInfo.rows) {
        throw new Error(`${frames[i].file}: ${splat.byteLength} bytes, scene.json says ${sceneInfo.rows} rows of 32`);
      }
      const colours = [];
      for (const file of frames[i].colours || []) colours.push(await fetchBytes(file, (n) => ((received += n), note())));
      loaded[i] = { splat, colours };
      loadedCount++;
    };
    await loadFrame(startFrame);
    live = new SPLAT.Splat(frameData(startFrame, startCamera));
    scene.addObject(live);
    state.frame = state.want = startFrame;
    state.colours = startCamera;
    // The other frames in the background, a few at a time; playback waits for them.
    (async () => {
      const queue = frames.map((_, i) => i).filter((i) => i !== startFrame);
      await Promise.all(Array.from({ length: 3 }, async () => {
        while (queue.length) await loadFrame(queue.shift());
      }));
      document.body.classList.add("loaded");
      setStatus("");
    })().catch(fail);
  } else {
    const video = new SPLAT.VideoRenderProgram(renderer);
    renderer.addProgram(video);
    programs.push(video);
    await SPLAT.SplatvLoader.LoadAsync(splatvUrl, scene, null, (f) => {
      progress.value = f;
      setStatus(`loading ${splatvUrl} (${Math.round(100 * f)} %)`);
    });
    loadedCount = frames.length;
    document.body.classList.add("loaded");
    setStatus("");
    state.phase = "sorting";
  }
  // gsplat's .splatv renderer takes its time from the clock (sin(Date.now()/1000)/2 + 1/2,
  // in [0, 1]: the whole clip); the slider drives it instead.
  let splatvTime = 0;
  if (mode === "splatv") Date.now = () => 1000 * Math.asin(Math.max(-1, Math.min(1, 2 * splatvTime - 1)));

  // ---- readiness: packed, uploaded and depth-sorted for this view --------------------
  let sortCount = 0;
  let hookedWorker = null;
  const hookSortWorker = () => {
    const w = renderer.renderProgram.worker;
    if (!w || w === hookedWorker || !w.onmessage) return;
    const inner = w.onmessage;
    w.onmessage = (e) => {
      inner(e);
      if (e.data && e.data.depthIndex) sortCount++;
    };
    hookedWorker = w;
  };
  const viewChanged = () => {
    state.sortMark = sortCount;
    if (state.phase !== "packing") state.phase = "sorting";
    state.ready = false;
  };

  // ---- cameras ------------------------------------------------------------------------
  // Training cameras come in viewer space; the .splatv is in world coordinates.
  const space = sceneInfo.space || { centre: [0, 0, 0], rotation: [0, 0, 0, 1] };
  const poseOf = (cam) => {
    if (mode === "frames") return { position: cam.position, rotation: cam.rotation };
    const back = qconj(space.rotation);
    const p = qrotate(back, cam.position);
    return {
      position: [p[0] + space.centre[0], p[1] + space.centre[1], p[2] + space.centre[2]],
      rotation: qmul(back, cam.rotation),
    };
  };
  let intrinsics = null; // { fx, fy, cx, cy } in canvas pixels
  let pinned = null; // the training camera shown exactly, or null while orbiting
  let controls = null;
  let focalUploaded = null;
  const cameraButtons = cameras.map((cam, k) => {
    const b = document.createElement("button");
    b.textContent = cam.name;
    b.title = `training camera ${cam.name} (key ${k + 1})`;
    b.onclick = () => pin(k);
    $("cams").appendChild(b);
    return b;
  });
  /// Show training camera `k` exactly: its pose, its intrinsics fitted into the canvas,
  /// and the colours seen from it.
  const pin = (k) => {
    if (controls) {
      controls.dispose();
      controls = null;
    }
    pinned = k;
    const pose = poseOf(cameras[k]);
    camera.position = new SPLAT.Vector3(...pose.position);
    camera.rotation = new SPLAT.Quaternion(...pose.rotation);
    const cam = cameras[k];
    const [W, H] = [canvas.width, canvas.height];
    const s = Math.min(W / cam.width, H / cam.height);
    intrinsics = {
      fx: cam.fx * s,
      fy: cam.fy * s,
      cx: W / 2 + (cam.cx - cam.width / 2) * s,
      cy: H / 2 + (cam.cy - cam.height / 2) * s,
    };
    cameraButtons.forEach((b, i) => b.classList.toggle("active", i === k));
    viewChanged();
  };
  /// Hand the camera to gsplat's orbit controls, orbiting about the point on its axis
  /// nearest the scene centre (roll is dropped).
  const unpin = () => {
    const p = camera.position;
    const f = camera.forward;
    const c = mode === "frames" ? [0, 0, 0] : space.centre;
    const radius = Math.max((c[0] - p.x) * f.x + (c[1] - p.y) * f.y + (c[2] - p.z) * f.z, 0.1);
    const target = new SPLAT.Vector3(p.x + radius * f.x, p.y + radius * f.y, p.z + radius * f.z);
    // gsplat's orbit puts the camera at target + r·(sin α cos β, −sin β, −cos α cos β).
    const alpha = Math.atan2(-f.x, f.z);
    const beta = Math.asin(Math.max(-1, Math.min(1, f.y)));
    controls = new SPLAT.OrbitControls(camera, canvas, alpha, beta, radius, true, target);
    controls.minZoom = 0.05 * radius;
    controls.maxZoom = Math.max(30, 10 * radius);
    const [W, H] = [canvas.width, canvas.height];
    if (intrinsics) intrinsics = { fx: intrinsics.fx, fy: intrinsics.fy, cx: W / 2, cy: H / 2 };
    pinned = null;
    cameraButtons.forEach((b) => b.classList.remove("active"));
    viewChanged();
  };
  // On the window in the capture phase: runs before the canvas's own listeners, which the
  // new controls add in time to get this very event.
  for (const type of ["mousedown", "wheel", "touchstart"]) {
    window.addEventListener(type, (e) => e.target === canvas && pinned !== null && unpin(), {
      capture: true,
      passive: true,
    });
  }
  /// Focal lengths and principal point into gsplat's camera (and its shaders).
  const applyIntrinsics = () => {
    if (!intrinsics) {
      const f = (0.5 * canvas.height) / Math.tan((25 * Math.PI) / 180);
      intrinsics = { fx: f, fy: f, cx: canvas.width / 2, cy: canvas.height / 2 };
    }
    const d = camera.data;
    if (d.fx !== intrinsics.fx) d.fx = intrinsics.fx;
    if (d.fy !== intrinsics.fy) d.fy = intrinsics.fy;
    // The principal point goes into the projection's third column (gsplat centres it).
    const b = d.projectionMatrix.buffer;
    b[8] = (2 * intrinsics.cx) / canvas.width - 1;
    b[9] = 1 - (2 * intrinsics.cy) / canvas.height;
    // gsplat uploads the focal lengths only when a program starts.
    const key = `${d.fx},${d.fy},${renderer.renderProgram.renderData !== null}`;
    if (key !== focalUploaded) {
      focalUploaded = key;
      for (const p of programs) {
        gl.useProgram(p.program);
        gl.uniform2fv(gl.getUniformLocation(p.program, "focal"), new Float32Array([d.fx, d.fy]));
      }
    }
  };

  // ---- time ---------------------------------------------------------------------------
  const slider = $("time");
  slider.max = String(last);
  if (mode === "splatv") slider.step = "any";
  const setPosition = (x) => {
    x = Math.max(0, Math.min(last, x));
    if (mode === "frames") x = Math.round(x);
    state.position = x;
    slider.value = String(x);
    const i = Math.round(x);
    const tail = mode === "frames" ? `${frames[i].splats} splats` : ".splatv";
    $("label").textContent = `t = ${frames[i].seconds.toFixed(3)} s (frame ${i + 1}/${frames.length}, ${tail})`;
    if (mode === "splatv") {
      // The time is a uniform: no new data or sort, only a few frames drawn at it.
      const tau = last > 0 ? x / last : 0;
      if (tau !== splatvTime) (state.quiet = 0), (state.ready = false);
      splatvTime = tau;
      state.frame = state.want = x;
    } else {
      state.want = i;
    }
  };
  /// Frames mode: put the wanted frame (and colours) into the live splat once it is loaded
  /// and gsplat is not packing the previous one.
  const swapIn = () => {
    if (mode !== "frames") return;
    const colours = pinned;
    if ((state.want === state.frame && colours === state.colours) || !loaded[state.want] || live.data.detached) return;
    const src = frameData(state.want, colours);
    const d = live.data;
    if (src.vertexCount !== d.vertexCount) throw new Error(`frame ${state.want} has ${src.vertexCount} rows, expected ${d.vertexCount}`);
    d.positions.set(src.positions);
    d.rotations.set(src.rotations);
    d.scales.set(src.scales);
    d.colors.set(src.colors);
    d.changed = true;
    live.raiseChangeEvent();
    state.frame = state.want;
    state.colours = colours;
    state.phase = "packing";
    state.ready = false;
  };

  let playing = false;
  let playClock = 0;
  const setPlaying = (p) => {
    playing = p && frames.length > 1;
    $("play").textContent = playing ? "❚❚" : "▶";
    playClock = performance.now() - (state.position / fps) * 1000;
  };
  $("play").onclick = () => setPlaying(!playing);
  slider.oninput = () => {
    setPlaying(false);
    setPosition(Number(slider.value));
  };
  window.addEventListener("keydown", (e) => {
    if (e.code === "Space") {
      setPlaying(!playing);
      e.preventDefault();
    } else if (e.code === "Period" || e.code === "Comma") {
      setPlaying(false);
      setPosition(Math.round(state.position) + (e.code === "Period" ? 1 : -1));
    } else {
      const digit = /^Digit([1-9])$/.exec(e.code);
      if (digit && Number(digit[1]) <= cameras.length) pin(Number(digit[1]) - 1);
    }
  });
  window.addEventListener("resize", () => {
    const height = canvas.height;
    renderer.resize();
    if (pinned !== null) pin(pinned);
    else if (intrinsics) {
      // Orbiting: keep the vertical field of view.
      const s = canvas.height / height;
      intrinsics = { fx: intrinsics.fx * s, fy: intrinsics.fy * s, cx: canvas.width / 2, cy: canvas.height / 2 };
    }
  });

  if (startCamera !== null) pin(startCamera);
  else unpin(); // no training cameras listed: orbit the scene centre
  let gotoFrame = params.has("goto") ? clampFrame(params.get("goto")) : null;
  setPosition(mode === "frames" ? startFrame : params.has("frame") || params.has("t") ? (params.has("frame") ? Number(params.get("frame")) : Number(params.get("t")) * last) : 0);
  setPlaying(params.get("play") !== "0");

  const frame = (now) => {
    if (playing) {
      // Wall-clock playback at the export's rate; frames not loaded yet are skipped.
      const x = (((now - playClock) / 1000) * fps) % frames.length;
      if (mode === "splatv") setPosition(Math.min(x, last));
      else if (loaded[Math.floor(x)]) setPosition(Math.floor(x));
    }
    swapIn();
    if (controls) {
      controls.update();
      viewChanged(); // never "ready" while the orbit controls move the camera
    }
    applyIntrinsics();
    if (target) target.begin();
    renderer.render(scene, camera);
    if (target) target.end();
    hookSortWorker();

    const rd = renderer.renderProgram.renderData;
    if (state.phase === "packing" && (!live || (!live.data.detached && rd && !rd.updating && !rd.needsRebuild && !rd.dataChanged))) {
      state.phase = "sorting";
      state.sortMark = sortCount;
    }
    if (state.phase === "sorting" && sortCount > state.sortMark) {
      state.phase = "shown";
      state.quiet = 0;
    }
    if (state.phase === "shown") state.quiet++;
    const ready = state.phase === "shown" && state.quiet >= 3 && state.want === state.frame;
    if (ready && gotoFrame !== null) {
      setPosition(gotoFrame); // ?goto: one switch inside the page, as the slider does
      gotoFrame = null;
    } else if (ready !== state.ready) {
      state.ready = ready;
      if (ready) document.title = `splat4d viewer: ready frame ${state.frame}`;
    }
    window.viewerState = { ready: state.ready, frame: state.frame, camera: pinned, mode, loaded: loadedCount, total: frames.length };
    requestAnimationFrame(frame);
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
