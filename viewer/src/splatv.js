// The export's `.splatv` played by gsplat.js's own `.splatv` renderer: a check that the
// file plays in a third-party player (splaTV-style), not the way to view a model — the
// main page (index.html) draws the native 4D model. The time slider drives the player's
// clock; the view is a training camera's exact pose and intrinsics.
//
// URL parameters: ?splatv=URL (default ../scene.splatv), ?camera=K, ?frame=N (the
// export's N-th time step) or ?t=0..1, ?ui=0 (canvas only). window.viewerState.ready
// once the splats are loaded, drawn and depth-sorted.
import * as SPLAT from "gsplat";
import { patchGsplat } from "./gsplat_patches.js";
import { floatTarget } from "./float_target.js";
import { centreOf, rowsToQuat } from "./camera.js";

const $ = (id) => document.getElementById(id);
const setStatus = (text) => ($("status").textContent = text);

async function main() {
  const params = new URLSearchParams(location.search);
  if (params.get("ui") === "0") document.body.classList.add("bare");
  const sceneInfo = await (await fetch("scene.json")).json();
  const times = sceneInfo.times && sceneInfo.times.length ? sceneInfo.times : [0];
  const [t0, t1] = [Math.min(...times), Math.max(...times)];
  const duration = sceneInfo.time.duration > 0 ? sceneInfo.time.duration : 1;
  const cameras = sceneInfo.cameras || [];
  const url = params.get("splatv") || "../scene.splatv";

  const canvas = $("canvas");
  const background = (sceneInfo.background || [0, 0, 0]).map((v) => Math.min(1, Math.max(0, v)));
  patchGsplat();
  const renderer = new SPLAT.WebGLRenderer(canvas, []);
  const gl = renderer.gl;
  const target = floatTarget(gl, background);
  const scene = new SPLAT.Scene();
  const camera = new SPLAT.Camera();
  camera.data.near = 0.01; // the engine's near plane
  camera.data.far = 1000;
  const video = new SPLAT.VideoRenderProgram(renderer);
  renderer.addProgram(video);
  const programs = [renderer.renderProgram, video];
  await SPLAT.SplatvLoader.LoadAsync(url, scene, null, (f) => {
    $("progress").value = f;
    setStatus(`loading ${url} (${Math.round(100 * f)} %)`);
  });
  document.body.classList.add("loaded");
  setStatus("");

  // gsplat's player takes its time from the clock (sin(Date.now()/1000)/2 + 1/2 in
  // [0, 1], the whole clip); the page sets it instead.
  let tau = 0;
  Date.now = () => 1000 * Math.asin(Math.max(-1, Math.min(1, 2 * tau - 1)));
  let time = t0;
  if (params.has("frame")) time = times[Math.max(0, Math.min(times.length - 1, Number(params.get("frame")) | 0))];
  else if (params.has("t")) time = t0 + Number(params.get("t")) * (t1 - t0);
  const slider = $("time");
  slider.min = "0";
  slider.max = "1";
  slider.step = "any";
  let sortCount = 0;
  const sortMark = 0;
  let quiet = 0;
  const setTime = (t) => {
    time = Math.max(t0, Math.min(t1, t));
    tau = time / duration;
    slider.value = String(t1 > t0 ? (time - t0) / (t1 - t0) : 0);
    $("label").textContent = `t = ${time.toFixed(3)} (.splatv in gsplat)`;
    quiet = 0;
  };
  slider.oninput = () => setTime(t0 + Number(slider.value) * (t1 - t0));
  setTime(time);

  // The training camera's pose and intrinsics (fitted into the canvas).
  const k = cameras.length ? Math.max(0, Math.min(cameras.length - 1, Number(params.get("camera") ?? 0) | 0)) : null;
  let intrinsics = null;
  if (k !== null) {
    const cam = cameras[k];
    const c2w = [0, 1, 2].map((r) => [0, 1, 2].map((c) => cam.rotation[c][r]));
    const [w, x, y, z] = rowsToQuat(c2w);
    camera.position = new SPLAT.Vector3(...centreOf(cam));
    camera.rotation = new SPLAT.Quaternion(x, y, z, w);
    const [W, H] = [canvas.width, canvas.height];
    const s = Math.min(W / cam.width, H / cam.height);
    intrinsics = { fx: cam.fx * s, fy: cam.fy * s, cx: W / 2 + (cam.cx - cam.width / 2) * s, cy: H / 2 + (cam.cy - cam.height / 2) * s };
  } else {
    const f = (0.5 * canvas.height) / Math.tan((25 * Math.PI) / 180);
    intrinsics = { fx: f, fy: f, cx: canvas.width / 2, cy: canvas.height / 2 };
  }
  /// Focal lengths and principal point into gsplat's camera (and its shaders).
  let focalUploaded = null;
  const applyIntrinsics = () => {
    const d = camera.data;
    if (d.fx !== intrinsics.fx) d.fx = intrinsics.fx;
    if (d.fy !== intrinsics.fy) d.fy = intrinsics.fy;
    // The principal point goes into the projection's third column (gsplat centres it).
    const b = d.projectionMatrix.buffer;
    b[8] = (2 * intrinsics.cx) / canvas.width - 1;
    b[9] = 1 - (2 * intrinsics.cy) / canvas.height;
    // gsplat uploads the focal lengths only when a program starts.
    const key = `${d.fx},${d.fy}`;
    if (key !== focalUploaded) {
      focalUploaded = key;
      for (const p of programs) {
        gl.useProgram(p.program);
        gl.uniform2fv(gl.getUniformLocation(p.program, "focal"), new Float32Array([d.fx, d.fy]));
      }
    }
  };
  // Count the sort worker's answers: the view is ready once one came after the last change.
  let hooked = null;
  const hookSortWorker = () => {
    const w = renderer.renderProgram.worker;
    if (!w || w === hooked || !w.onmessage) return;
    const inner = w.onmessage;
    w.onmessage = (e) => {
      inner(e);
      if (e.data && e.data.depthIndex) sortCount++;
    };
    hooked = w;
  };
  const frame = () => {
    applyIntrinsics();
    target.begin();
    renderer.render(scene, camera);
    target.end();
    hookSortWorker();
    if (sortCount > sortMark) quiet++;
    const ready = sortCount > sortMark && quiet >= 3;
    window.viewerState = { ready, time, camera: k, mode: "splatv" };
    requestAnimationFrame(frame);
  };
  requestAnimationFrame(frame);
}

function fail(e) {
  setStatus(`error: ${e.message}`);
  window.viewerState = { ready: false, error: e.message };
  console.error(e);
}

main().catch(fail);
