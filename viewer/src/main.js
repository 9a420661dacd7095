// splat4d browser viewer: plays the per-timestep `.splat` frames listed in scene.json with
// gsplat.js; a time slider picks the frame, orbit controls move the camera.
// URL parameters (for links and tests): ?frame=N or ?t=0..1 (fraction of the sequence),
// ?play=0 to start paused.
import * as SPLAT from "gsplat";

const $ = (id) => document.getElementById(id);
const status = (text) => ($("status").textContent = text);

async function main() {
  const params = new URLSearchParams(location.search);
  const sceneInfo = await (await fetch("scene.json")).json();
  const frames = sceneInfo.frames;
  if (!frames.length) throw new Error("scene.json lists no frames");

  const splats = [];
  for (let i = 0; i < frames.length; i++) {
    status(`loading frame ${i + 1} / ${frames.length}`);
    const res = await fetch(frames[i].file);
    if (!res.ok) throw new Error(`${frames[i].file}: HTTP ${res.status}`);
    const data = SPLAT.SplatData.Deserialize(new Uint8Array(await res.arrayBuffer()));
    splats.push(new SPLAT.Splat(data));
  }

  const canvas = $("canvas");
  const renderer = new SPLAT.WebGLRenderer(canvas);
  const scene = new SPLAT.Scene();
  const camera = new SPLAT.Camera();
  // gsplat's orbit puts the camera at target + r·(sin α cos β, −sin β, −cos α cos β).
  const [x, y, z] = sceneInfo.camera_position;
  const radius = Math.hypot(x, y, z) || 4;
  const alpha = Math.atan2(x, -z);
  const beta = Math.asin(Math.max(-1, Math.min(1, -y / radius)));
  const controls = new SPLAT.OrbitControls(camera, canvas, alpha, beta, radius, true, new SPLAT.Vector3(0, 0, 0));
  controls.maxZoom = Math.max(30, 4 * radius);
  controls.minZoom = 0.05 * radius;

  const slider = $("time");
  slider.max = String(frames.length - 1);
  let current = -1;
  let settled = 0;
  let switchedAt = 0;
  const show = (i) => {
    i = Math.max(0, Math.min(frames.length - 1, i | 0));
    if (i === current) return;
    if (current >= 0) scene.removeObject(splats[current]);
    scene.addObject(splats[i]);
    current = i;
    settled = 0;
    switchedAt = performance.now();
    slider.value = String(i);
    const f = frames[i];
    $("label").textContent = `t = ${f.seconds.toFixed(3)} s (frame ${i + 1}/${frames.length}, ${f.splats} splats)`;
    window.viewerState = { ready: false, frame: i };
  };

  let start = 0;
  if (params.has("frame")) start = Number(params.get("frame"));
  else if (params.has("t")) start = Math.round(Number(params.get("t")) * (frames.length - 1));
  show(start);
  let gotoFrame = params.has("goto") ? Number(params.get("goto")) : null;

  let playing = params.get("play") !== "0" && frames.length > 1;
  const setPlaying = (p) => {
    playing = p;
    $("play").textContent = p ? "❚❚" : "▶";
  };
  setPlaying(playing);
  $("play").onclick = () => setPlaying(!playing);
  slider.oninput = () => {
    setPlaying(false);
    show(Number(slider.value));
  };
  window.addEventListener("keydown", (e) => {
    if (e.code === "Space") { setPlaying(!playing); e.preventDefault(); }
    if (e.code === "Period") { setPlaying(false); show(current + 1); }
    if (e.code === "Comma") { setPlaying(false); show(current - 1); }
  });
  window.addEventListener("resize", () => renderer.resize());

  const fovY = sceneInfo.fov_y_deg || 50;
  const period = 1000 / (sceneInfo.fps || 15);
  let last = performance.now();
  status("");
  const frame = (now) => {
    if (playing && now - last >= period) {
      last = now;
      show((current + 1) % frames.length);
    }
    // Keep the first camera's vertical field of view whatever the canvas size.
    const focal = (0.5 * canvas.height) / Math.tan((0.5 * fovY * Math.PI) / 180);
    if (camera.data.fy !== focal) {
      camera.data.fx = focal;
      camera.data.fy = focal;
    }
    controls.update();
    renderer.render(scene, camera);
    // Rendered for a while after a switch: gsplat's data and sort workers have answered.
    if (++settled >= 30 && now - switchedAt > 1000 && !window.viewerState.ready) {
      if (gotoFrame !== null) {
        // ?goto=N: switch once after the first frame is shown (tests the in-page switch).
        const g = gotoFrame;
        gotoFrame = null;
        show(g);
      } else {
        window.viewerState = { ready: true, frame: current, camera: [camera.position.x, camera.position.y, camera.position.z] };
        document.title = `splat4d viewer: ready frame ${current}`;
      }
    }
    requestAnimationFrame(frame);
  };
  requestAnimationFrame(frame);
}

main().catch((e) => {
  status(`error: ${e.message}`);
  document.title = "splat4d viewer: error";
  console.error(e);
});
