// Make gsplat 1.2.9's splat shaders draw what the 3DGS rasteriser (and the splat4d engine)
// draws. Without these edits a trained model loses most of its large Gaussians:
//
// - gsplat drops every splat whose *centre* projects outside 1.2 × the view, however far
//   its footprint reaches into it. A trained scene covers the floor and walls near the
//   camera with large Gaussians centred off-screen, so whole regions went missing and the
//   picture came out dark and full of holes. Here a splat is culled only when its
//   footprint misses the view, or when it lies behind the engine's near plane (0.01).
// - The projection Jacobian takes x/z and y/z clamped to the image plus 15 % per side (as
//   in 3DGS and the engine), so those off-screen splats keep their true size.
// - gsplat stores 4·Σ, so its "+ 0.3" low-pass is 0.075 px²; 3DGS and the engine add
//   0.3 px² (its `.splatv` shader adds none). Axis lengths were capped at 1024 (in those
//   4× units), which shrank splats close to the camera.
//
// Each edit names text of gsplat's shader that must occur exactly once; when a gsplat
// update changes it, the page stops with an error instead of drawing something else.
import * as SPLAT from "gsplat";

const NEAR = "0.01";

// The Jacobian from x/z, y/z clamped to the image plus 15 % per side. gsplat has no
// principal point; the viewer puts it into the projection's third column (see main.js).
const CLAMPED_CAMERA = `
    vec2 splat4dPp = vec2((projection[2][0] + 1.0) * 0.5 * viewport.x, (1.0 - projection[2][1]) * 0.5 * viewport.y);
    vec2 splat4dU = clamp(cam.xy / cam.z, (-0.15 * viewport - splat4dPp) / focal, (1.15 * viewport - splat4dPp) / focal);
    vec3 camJ = vec3(splat4dU * cam.z, cam.z);
    mat3 J = mat3(`;

// Cull by footprint: the quad reaches 2 × (major, minor) / viewport in NDC.
const footprintCull = (pos) => `
    vec2 splat4dReach = 2.0 * length(vec2(length(majorAxis), length(minorAxis))) / viewport;
    if (any(greaterThan(abs(${pos}.xy / ${pos}.w), vec2(1.0) + splat4dReach))) {
        gl_Position = vec4(0.0, 0.0, 2.0, 1.0);
        return;
    }
`;

const JACOBIAN_EDITS = [
  ["\n    mat3 J = mat3(", CLAMPED_CAMERA],
  ["-(focal.x * cam.x) / (cam.z * cam.z)", "-(focal.x * camJ.x) / (cam.z * cam.z)"],
  ["(focal.y * cam.y) / (cam.z * cam.z)", "(focal.y * camJ.y) / (cam.z * cam.z)"],
];

const AXIS_EDITS = [
  ["vec2 majorAxis = min(sqrt(2.0 * lambda1), 1024.0)", "vec2 majorAxis = min(sqrt(2.0 * lambda1), 65536.0)"],
  ["vec2 minorAxis = min(sqrt(2.0 * lambda2), 1024.0)", "vec2 minorAxis = min(sqrt(2.0 * lambda2), 65536.0)"],
];

const SPLAT_EDITS = [
  [
    "float clip = 1.2 * pos2d.w;\n    if (pos2d.z < -pos2d.w || pos2d.z > pos2d.w || pos2d.x < -clip || pos2d.x > clip || pos2d.y < -clip || pos2d.y > clip) {",
    `if (cam.z < ${NEAR}) {`,
  ],
  ...JACOBIAN_EDITS,
  ["cov2d[0][0] += 0.3;\n    cov2d[1][1] += 0.3;", "cov2d[0][0] += 1.2;\n    cov2d[1][1] += 1.2;"],
  ...AXIS_EDITS,
  ["\n    uint colorTransformIndex", footprintCull("pos2d") + "\n    uint colorTransformIndex"],
];

const SPLATV_EDITS = [
  [
    "float clip = 1.2 * pos.w;\n    if (pos.z < -clip || pos.x < -clip || pos.x > clip || pos.y < -clip || pos.y > clip) return;",
    `if (cam.z < ${NEAR}) return;`,
  ],
  ...JACOBIAN_EDITS,
  ["mat3 cov2d = transpose(T) * Vrk * T;", "mat3 cov2d = transpose(T) * Vrk * T;\n    cov2d[0][0] += 1.2;\n    cov2d[1][1] += 1.2;"],
  ...AXIS_EDITS,
  ["\n    uint rgba = static1.w;", footprintCull("pos") + "\n    uint rgba = static1.w;"],
];

function patch(cls, name, edits) {
  const original = cls.prototype._getVertexSource;
  let source = original.call(null);
  for (const [from, to] of edits) {
    const at = source.indexOf(from);
    if (at < 0 || source.indexOf(from, at + 1) >= 0) {
      throw new Error(`gsplat's ${name} shader is not the one this viewer was written for (looked for: ${from.trim().slice(0, 60)}…); rebuild the viewer with the gsplat version in package-lock.json`);
    }
    source = source.slice(0, at) + to + source.slice(at + from.length);
  }
  cls.prototype._getVertexSource = () => source;
}

/// Apply the edits; call before creating the renderer (it compiles the shaders).
export function patchGsplat() {
  patch(SPLAT.RenderProgram, "splat", SPLAT_EDITS);
  patch(SPLAT.VideoRenderProgram, "splatv", SPLATV_EDITS);
}
