// Camera poses as the engine has them (world → camera, OpenCV axes: x right, y down,
// z forward; rotation as rows) and the page's orbit controls.

const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const normalize = (a) => scale(a, 1 / Math.hypot(a[0], a[1], a[2]));

/// Camera centre of a pose: −Rᵀ t.
export function centreOf(pose) {
  const [R, t] = [pose.rotation, pose.translation];
  return [0, 1, 2].map((k) => -(R[0][k] * t[0] + R[1][k] * t[1] + R[2][k] * t[2]));
}

/// A pose from its rotation rows and camera centre.
export function poseFrom(rotation, eye) {
  return { rotation, translation: rotation.map((row) => -dot(row, eye)) };
}

/// Rotation matrix (rows) of a unit quaternion (w, x, y, z).
export function quatToRows([w, x, y, z]) {
  const n = Math.hypot(w, x, y, z) || 1;
  [w, x, y, z] = [w / n, x / n, y / n, z / n];
  return [
    [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
    [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
    [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
  ];
}

/// Quaternion (w, x, y, z), w ≥ 0, of a rotation matrix given by rows.
export function rowsToQuat(m) {
  const tr = m[0][0] + m[1][1] + m[2][2];
  let q;
  if (tr > 0) {
    const s = 2 * Math.sqrt(tr + 1);
    q = [0.25 * s, (m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s];
  } else if (m[0][0] > m[1][1] && m[0][0] > m[2][2]) {
    const s = 2 * Math.sqrt(1 + m[0][0] - m[1][1] - m[2][2]);
    q = [(m[2][1] - m[1][2]) / s, 0.25 * s, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s];
  } else if (m[1][1] > m[2][2]) {
    const s = 2 * Math.sqrt(1 + m[1][1] - m[0][0] - m[2][2]);
    q = [(m[0][2] - m[2][0]) / s, (m[0][1] + m[1][0]) / s, 0.25 * s, (m[1][2] + m[2][1]) / s];
  } else {
    const s = 2 * Math.sqrt(1 + m[2][2] - m[0][0] - m[1][1]);
    q = [(m[1][0] - m[0][1]) / s, (m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, 0.25 * s];
  }
  return q[0] < 0 ? q.map((v) => -v) : q;
}

/// Rotation by `angle` about unit `axis`, as rows (Rodrigues).
function axisAngle(axis, angle) {
  const [x, y, z] = axis;
  const c = Math.cos(angle);
  const s = Math.sin(angle);
  const t = 1 - c;
  return [
    [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
    [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
    [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
  ];
}

const apply = (m, v) => [dot(m[0], v), dot(m[1], v), dot(m[2], v)];

/// Orbit controls on `canvas`: drag turns the camera about the target (horizontally about
/// the world's `up`, vertically about the camera's x axis), right-drag or shift-drag pans,
/// the wheel moves towards the target. `onStart()` is called when the user first touches
/// the view, `onChange()` after every move.
export function orbitControls(canvas, up, onStart, onChange) {
  let pose = null; // { rotation, translation }
  let target = [0, 0, 0];
  let focal = 1000;
  let drag = null;
  const setFrom = (newPose, centre, fy) => {
    pose = newPose;
    focal = fy;
    // Orbit about the point on the camera's axis nearest `centre`.
    const eye = centreOf(pose);
    const forward = pose.rotation[2];
    const distance = Math.max(dot(sub(centre, eye), forward), 0.1);
    target = add(eye, scale(forward, distance));
  };
  const turn = (m) => {
    const eye = centreOf(pose);
    const newEye = add(target, apply(m, sub(eye, target)));
    // New camera-to-world = m · old camera-to-world, so rows R' = R · mᵀ.
    const R = pose.rotation.map((row) => [0, 1, 2].map((c) => dot(row, m[c])));
    pose = poseFrom(R, newEye);
  };
  const down = (e) => {
    onStart();
    drag = { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey };
    canvas.setPointerCapture(e.pointerId);
  };
  const move = (e) => {
    if (!drag || !pose) return;
    const dx = e.clientX - drag.x;
    const dy = e.clientY - drag.y;
    drag.x = e.clientX;
    drag.y = e.clientY;
    if (drag.pan) {
      const eye = centreOf(pose);
      const perPixel = Math.hypot(...sub(target, eye)) / focal;
      const shift = add(scale(pose.rotation[0], -dx * perPixel), scale(pose.rotation[1], -dy * perPixel));
      target = add(target, shift);
      pose = poseFrom(pose.rotation, add(eye, shift));
    } else {
      turn(axisAngle(up, -dx * 0.005));
      turn(axisAngle(normalize(pose.rotation[0]), dy * 0.005));
    }
    onChange();
  };
  const wheel = (e) => {
    if (!pose) return;
    onStart();
    e.preventDefault();
    const eye = centreOf(pose);
    const towards = sub(target, eye);
    const k = 1 - Math.exp(-e.deltaY * 0.001);
    pose = poseFrom(pose.rotation, add(eye, scale(towards, Math.max(-4, Math.min(0.9, -k)))));
    onChange();
  };
  canvas.addEventListener("pointerdown", down);
  canvas.addEventListener("pointermove", move);
  canvas.addEventListener("pointerup", () => (drag = null));
  canvas.addEventListener("wheel", wheel, { passive: false });
  canvas.addEventListener("contextmenu", (e) => e.preventDefault());
  return {
    setFrom,
    get pose() {
      return pose;
    },
  };
}
