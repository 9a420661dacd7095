// WebGL2 renderer of the native 4D model: one instanced quad per Gaussian, sliced at the
// playback time in the vertex shader with the engine's formulas (src/math/slice.rs,
// project.rs, sh.rs): mean μ + v·(t − μt), the constant conditional covariance, opacity
// σ(o)·ω(t) with ω = exp(−½(t − μt)²/σt²) (culled at ω ≤ 0.05), EWA projection with the
// 0.3 px² low-pass and the Jacobian's guard band, colour from the spherindrical harmonics
// seen from the camera centre towards the canonical mean. Fragments blend back to front
// (the engine's front-to-back sum, reordered), α = min(0.99, opacity·e^power), skipped
// below 1/255. The depth order comes from the CPU per time and view (sort.js).

const VERTEX = `#version 300 es
precision highp float;
precision highp int;
precision highp usampler2D;

uniform usampler2D u_data;
uniform int u_texels;
uniform int u_perRow;
uniform vec3 u_r0, u_r1, u_r2;  // world → camera rotation, rows
uniform vec3 u_trans;
uniform vec3 u_eye;            // camera centre, world
uniform vec4 u_intr;           // fx, fy, cx, cy in canvas pixels (y down)
uniform vec2 u_size;           // canvas pixels
uniform float u_near;
uniform float u_time;
uniform float u_period;
uniform int u_ns;              // spatial SH functions in the file: 1, 4, 9 or 16
uniform int u_nt;              // temporal functions: 1, 2 or 3
uniform float u_scales[47];    // dequantisation of colour coefficients 1..47

in uint a_index;

flat out vec3 v_rgb;
flat out float v_opacity;
flat out vec3 v_conic;
flat out vec2 v_centre;

uvec4 rest[9];

uvec4 fetch(int i, int k) {
  return texelFetch(u_data, ivec2((i % u_perRow) * u_texels + k, i / u_perRow), 0);
}

vec2 halves(uint w) { return unpackHalf2x16(w); }

float coeff(int k, int c) {
  int b = (k - 1) * 3 + c;
  uint w = rest[b >> 4][(b >> 2) & 3];
  int v = int((w >> (8u * uint(b & 3))) & 255u);
  if (v > 127) v -= 256;
  return float(v) * u_scales[k - 1];
}

void cull() { gl_Position = vec4(0.0, 0.0, 2.0, 1.0); }

void main() {
  int i = int(a_index);
  uvec4 t0 = fetch(i, 0), t1 = fetch(i, 1), t2 = fetch(i, 2);
  vec3 mu = uintBitsToFloat(t0.xyz);
  float tMean = uintBitsToFloat(t0.w);
  vec2 vxy = halves(t1.x), vzs = halves(t1.y), sxy = halves(t1.z), szo = halves(t1.w);
  float dt = u_time - tMean;
  float omega = exp(-0.5 * dt * dt / (vzs.y * vzs.y));
  float opacity = szo.y * omega;
  if (!(omega > 0.05) || !(opacity >= 1.0 / 255.0)) { cull(); return; }
  vec3 mean = mu + vec3(vxy, vzs.x) * dt;
  vec3 p = vec3(dot(u_r0, mean), dot(u_r1, mean), dot(u_r2, mean)) + u_trans;
  if (!(p.z >= u_near)) { cull(); return; }

  // Covariance R·diag(s²)·Rᵀ of the slice (quaternion w, x, y, z).
  vec2 qwx = halves(t2.x), qyz = halves(t2.y);
  vec4 q = normalize(vec4(qwx, qyz));
  float w = q.x, x = q.y, y = q.z, z = q.w;
  mat3 rot = mat3(
    1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y),
    2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x),
    2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y));
  mat3 m = rot * mat3(sxy.x, 0.0, 0.0, 0.0, sxy.y, 0.0, 0.0, 0.0, szo.x);

  // EWA: rows of the Jacobian times the camera rotation, the guard band as the engine.
  vec2 f = u_intr.xy, c = u_intr.zw;
  vec2 lo = (-0.15 * u_size - c) / f, hi = (1.15 * u_size - c) / f;
  vec2 u = clamp(p.xy / p.z, lo, hi);
  vec3 j0 = f.x / p.z * (u_r0 - u.x * u_r2);
  vec3 j1 = f.y / p.z * (u_r1 - u.y * u_r2);
  vec3 k0 = j0 * m, k1 = j1 * m;  // row vector × matrix
  float ca = dot(k0, k0) + 0.3, cb = dot(k0, k1), cc = dot(k1, k1) + 0.3;
  float det = ca * cc - cb * cb;
  if (!(det > 0.0)) { cull(); return; }
  v_conic = vec3(cc, -cb, ca) / det;
  v_centre = f * p.xy / p.z + c;
  v_opacity = opacity;

  // Colour: spatial SH towards the canonical mean, temporal cosines of μt − t.
  rest[0] = uvec4(0u);
  for (int k = 0; k < 9; k++) if (3 + k < u_texels) rest[k] = fetch(i, 3 + k);
  vec3 d = normalize(mu - u_eye);
  float X = d.x, Y = d.y, Z = d.z;
  float sh[16];
  sh[0] = 0.28209479177387814;
  if (u_ns > 1) {
    sh[1] = -0.4886025119029199 * Y; sh[2] = 0.4886025119029199 * Z; sh[3] = -0.4886025119029199 * X;
  }
  if (u_ns > 4) {
    float xx = X * X, yy = Y * Y, zz = Z * Z;
    sh[4] = 1.0925484305920792 * X * Y;
    sh[5] = -1.0925484305920792 * Y * Z;
    sh[6] = 0.31539156525252005 * (2.0 * zz - xx - yy);
    sh[7] = -1.0925484305920792 * X * Z;
    sh[8] = 0.5462742152960396 * (xx - yy);
    if (u_ns > 9) {
      sh[9] = -0.5900435899266435 * Y * (3.0 * xx - yy);
      sh[10] = 2.890611442640554 * X * Y * Z;
      sh[11] = -0.4570457994644658 * Y * (4.0 * zz - xx - yy);
      sh[12] = 0.3731763325901154 * Z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
      sh[13] = -0.4570457994644658 * X * (4.0 * zz - xx - yy);
      sh[14] = 1.445305721320277 * Z * (xx - yy);
      sh[15] = -0.5900435899266435 * X * (xx - 3.0 * yy);
    }
  }
  vec2 dc01 = halves(t2.z), dc2 = halves(t2.w);
  vec3 rgb = vec3(0.5) + sh[0] * vec3(dc01, dc2.x);
  for (int j = 0; j < u_nt; j++) {
    float psi = j == 0 ? 1.0 : cos(6.283185307179586 * float(j) * (tMean - u_time) / u_period);
    for (int s = j == 0 ? 1 : 0; s < u_ns; s++) {
      int k = j * u_ns + s;
      rgb += sh[s] * psi * vec3(coeff(k, 0), coeff(k, 1), coeff(k, 2));
    }
  }
  v_rgb = max(rgb, vec3(0.0));

  // A quad over the footprint where α can reach 1/255.
  float r = sqrt(2.0 * log(255.0 * opacity));
  vec2 corner = vec2(float(gl_VertexID & 1), float((gl_VertexID >> 1) & 1)) * 2.0 - 1.0;
  vec2 pixel = v_centre + corner * r * vec2(sqrt(ca), sqrt(cc));
  gl_Position = vec4(2.0 * pixel.x / u_size.x - 1.0, 1.0 - 2.0 * pixel.y / u_size.y, 0.0, 1.0);
}
`;

const FRAGMENT = `#version 300 es
precision highp float;
uniform vec2 u_size;
flat in vec3 v_rgb;
flat in float v_opacity;
flat in vec3 v_conic;
flat in vec2 v_centre;
out vec4 colour;
void main() {
  // Pixel centres at integer + 0.5 with y down, as the engine.
  vec2 d = vec2(gl_FragCoord.x, u_size.y - gl_FragCoord.y) - v_centre;
  float power = -0.5 * (v_conic.x * d.x * d.x + v_conic.z * d.y * d.y) - v_conic.y * d.x * d.y;
  if (power > 0.0) discard;
  float alpha = min(0.99, v_opacity * exp(power));
  if (alpha < 1.0 / 255.0) discard;
  colour = vec4(v_rgb * alpha, alpha);
}
`;

function compile(gl, type, src) {
  const sh = gl.createShader(type);
  gl.shaderSource(sh, src);
  gl.compileShader(sh);
  if (!gl.getShaderParameter(sh, gl.COMPILE_STATUS)) throw new Error(`shader: ${gl.getShaderInfoLog(sh)}`);
  return sh;
}

/// Texels per texture row the renderer uses for records of `texels` texels.
export function recordsPerRow(gl, texels) {
  const width = Math.min(4096, gl.getParameter(gl.MAX_TEXTURE_SIZE));
  return Math.floor(width / texels);
}

export function createRenderer(gl) {
  const program = gl.createProgram();
  gl.attachShader(program, compile(gl, gl.VERTEX_SHADER, VERTEX));
  gl.attachShader(program, compile(gl, gl.FRAGMENT_SHADER, FRAGMENT));
  gl.linkProgram(program);
  if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
  const loc = {};
  for (const name of ["u_data", "u_texels", "u_perRow", "u_r0", "u_r1", "u_r2", "u_trans", "u_eye", "u_intr", "u_size", "u_near", "u_time", "u_period", "u_ns", "u_nt", "u_scales"]) {
    loc[name] = gl.getUniformLocation(program, name);
  }
  const vao = gl.createVertexArray();
  const indexBuffer = gl.createBuffer();
  gl.bindVertexArray(vao);
  gl.bindBuffer(gl.ARRAY_BUFFER, indexBuffer);
  const attr = gl.getAttribLocation(program, "a_index");
  gl.enableVertexAttribArray(attr);
  gl.vertexAttribIPointer(attr, 1, gl.UNSIGNED_INT, 0, 0);
  gl.vertexAttribDivisor(attr, 1);
  gl.bindVertexArray(null);
  const texture = gl.createTexture();
  let uploadedRows = 0;
  let indexCapacity = 0;
  let drawCount = 0;

  return {
    /// Upload the texture rows whose records have all arrived (all rows once complete).
    upload(model) {
      const width = model.perRow * model.texels;
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D, texture);
      if (uploadedRows === 0 && !this.allocated) {
        const max = gl.getParameter(gl.MAX_TEXTURE_SIZE);
        if (model.rows > max) {
          throw new Error(`${model.count} Gaussians need a ${width}×${model.rows} texture; this GPU allows ${max}×${max} (at most ${max * model.perRow} Gaussians): export a smaller model`);
        }
        gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32UI, width, model.rows, 0, gl.RGBA_INTEGER, gl.UNSIGNED_INT, null);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
        gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
        this.allocated = true;
      }
      const complete = model.loaded === model.count ? model.rows : Math.floor(model.loaded / model.perRow);
      if (complete > uploadedRows) {
        const words = width * 4;
        const part = model.data.subarray(uploadedRows * words, complete * words);
        gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, uploadedRows, width, complete - uploadedRows, gl.RGBA_INTEGER, gl.UNSIGNED_INT, part);
        uploadedRows = complete;
      }
      gl.bindTexture(gl.TEXTURE_2D, null);
      return uploadedRows === model.rows ? model.count : uploadedRows * model.perRow;
    },
    /// Start over with another model (the page's loaded time segments changed).
    reset() {
      uploadedRows = 0;
      this.allocated = false;
      drawCount = 0;
    },
    /// The Gaussians to draw, back to front.
    setOrder(order, count) {
      gl.bindBuffer(gl.ARRAY_BUFFER, indexBuffer);
      if (order.length > indexCapacity) {
        gl.bufferData(gl.ARRAY_BUFFER, order.byteLength, gl.DYNAMIC_DRAW);
        indexCapacity = order.length;
      }
      gl.bufferSubData(gl.ARRAY_BUFFER, 0, order, 0, count);
      gl.bindBuffer(gl.ARRAY_BUFFER, null);
      drawCount = count;
    },
    /// Draw into the bound framebuffer (cleared by the caller) with `view`
    /// ({ rotation rows, translation, eye, fx, fy, cx, cy }) at model time `time`.
    draw(model, view, time, width, height) {
      const h = model.header;
      gl.viewport(0, 0, width, height);
      gl.useProgram(program);
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D, texture);
      gl.uniform1i(loc.u_data, 0);
      gl.uniform1i(loc.u_texels, model.texels);
      gl.uniform1i(loc.u_perRow, model.perRow);
      gl.uniform3fv(loc.u_r0, view.rotation[0]);
      gl.uniform3fv(loc.u_r1, view.rotation[1]);
      gl.uniform3fv(loc.u_r2, view.rotation[2]);
      gl.uniform3fv(loc.u_trans, view.translation);
      gl.uniform3fv(loc.u_eye, view.eye);
      gl.uniform4f(loc.u_intr, view.fx, view.fy, view.cx, view.cy);
      gl.uniform2f(loc.u_size, width, height);
      gl.uniform1f(loc.u_near, NEAR);
      gl.uniform1f(loc.u_time, time);
      gl.uniform1f(loc.u_period, h.period);
      gl.uniform1i(loc.u_ns, (h.degrees.spatial + 1) ** 2);
      gl.uniform1i(loc.u_nt, h.degrees.temporal + 1);
      const scales = new Float32Array(47);
      scales.set(h.sh_scales.slice(0, 47));
      gl.uniform1fv(loc.u_scales, scales);
      gl.enable(gl.BLEND);
      gl.blendFunc(gl.ONE, gl.ONE_MINUS_SRC_ALPHA);
      gl.disable(gl.DEPTH_TEST);
      gl.bindVertexArray(vao);
      gl.drawArraysInstanced(gl.TRIANGLE_STRIP, 0, 4, drawCount);
      gl.bindVertexArray(null);
      gl.bindTexture(gl.TEXTURE_2D, null);
      gl.disable(gl.BLEND);
    },
  };
}

/// The engine's near plane: Gaussians nearer the camera than this are culled.
export const NEAR = 0.01;
