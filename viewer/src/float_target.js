// An offscreen half-float render target for gsplat (see floatTarget).

/// An offscreen half-float target for gsplat to draw into, shown on the canvas afterwards.
/// gsplat blends its splats front to back into whatever framebuffer is bound; straight
/// into the canvas (8 bits per channel) every blend step rounds to 1/255, and the faint
/// splats of a trained model (small opacity × temporal weight, thousands per pixel) lose
/// their share: on the demo model the same splats came out 44 dB from the engine's render
/// of them in 8 bits, 51 dB in half floats. Here they add up in half floats and the result
/// is rounded once, over `background` (RGB in [0, 1], the colour the model was trained on:
/// colour + (1 − coverage) · background, as the engine composites). `null` when the
/// browser cannot render to half floats (then gsplat draws to the canvas directly, and the
/// page's background shows through). With a learned `backdrop` ({ image, centre, radius,
/// axes } of scene.json, its image loaded) the uncovered part shows it instead: each
/// pixel's ray leaves the backdrop's sphere at a point whose direction from the centre
/// picks the texel, as the engine draws it (render::backdrop); `end(view)` then needs the
/// view's pose and intrinsics.
export function floatTarget(gl, background, backdrop = null) {
  if (!gl.getExtension("EXT_color_buffer_float") && !gl.getExtension("EXT_color_buffer_half_float")) {
    console.warn("no float render targets: splats blend in 8 bits (darker, speckled)");
    return null;
  }
  const compile = (type, src) => {
    const sh = gl.createShader(type);
    gl.shaderSource(sh, src);
    gl.compileShader(sh);
    if (!gl.getShaderParameter(sh, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(sh));
    return sh;
  };
  const program = gl.createProgram();
  gl.attachShader(program, compile(gl.VERTEX_SHADER, `#version 300 es
void main() {
  vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
  gl_Position = vec4(2.0 * p - 1.0, 0.0, 1.0);
}`));
  gl.attachShader(program, compile(gl.FRAGMENT_SHADER, `#version 300 es
precision highp float;
uniform sampler2D image;
uniform vec3 background;
uniform bool hasBackdrop;
uniform sampler2D backdrop;
uniform vec3 centre;
uniform float radius;
uniform mat3 axes;     // columns: longitude 0, longitude 90°, up
uniform mat3 toWorld;  // camera → world rotation
uniform vec3 eye;
uniform vec4 lens;     // fx, fy, cx, cy (pixels, from the top left)
uniform float height;
out vec4 colour;
const float PI = 3.14159265358979;
vec3 behind() {
  if (!hasBackdrop) return background;
  vec2 p = vec2(gl_FragCoord.x, height - gl_FragCoord.y);
  vec3 d = normalize(toWorld * vec3((p - lens.zw) / lens.xy, 1.0));
  vec3 o = eye - centre;
  float b = dot(o, d);
  float disc = b * b - (dot(o, o) - radius * radius);
  vec3 n = d;
  if (disc >= 0.0 && -b + sqrt(disc) > 0.0) n = normalize(o + d * (-b + sqrt(disc)));
  vec3 local = n * axes; // (n·axes[0], n·axes[1], n·up)
  float lon = atan(local.y, local.x);
  float lat = asin(clamp(local.z, -1.0, 1.0));
  return texture(backdrop, vec2(lon / (2.0 * PI) + 0.5, 0.5 - lat / PI)).rgb;
}
void main() {
  vec4 c = clamp(texelFetch(image, ivec2(gl_FragCoord.xy), 0), 0.0, 1.0);
  colour = vec4(clamp(c.rgb + (1.0 - c.a) * behind(), 0.0, 1.0), 1.0);
}`));
  gl.linkProgram(program);
  if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
  const UNIT = 7;
  const BACKDROP_UNIT = 6;
  // The sampler must always see a float texture on its unit (WebGL refuses the draw when
  // an unused sampler's unit holds gsplat's integer data): a black texel without a backdrop.
  const backdropTexture = gl.createTexture();
  gl.activeTexture(gl.TEXTURE0 + BACKDROP_UNIT);
  gl.bindTexture(gl.TEXTURE_2D, backdropTexture);
  if (backdrop) {
    gl.pixelStorei(gl.UNPACK_COLORSPACE_CONVERSION_WEBGL, gl.NONE);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGB8, gl.RGB, gl.UNSIGNED_BYTE, backdrop.image);
  } else {
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGB8, 1, 1, 0, gl.RGB, gl.UNSIGNED_BYTE, new Uint8Array(3));
  }
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.REPEAT);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
  for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, p, gl.LINEAR);
  gl.bindTexture(gl.TEXTURE_2D, null);
  gl.activeTexture(gl.TEXTURE0);
  const vao = gl.createVertexArray();
  const fbo = gl.createFramebuffer();
  let texture = null;
  let size = [0, 0];
  return {
    /// Bind the target (resized to the canvas) for gsplat to draw into.
    begin() {
      const [w, h] = [gl.drawingBufferWidth, gl.drawingBufferHeight];
      if (!texture || size[0] !== w || size[1] !== h) {
        if (texture) gl.deleteTexture(texture);
        texture = gl.createTexture();
        gl.activeTexture(gl.TEXTURE0 + UNIT);
        gl.bindTexture(gl.TEXTURE_2D, texture);
        gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA16F, w, h, 0, gl.RGBA, gl.HALF_FLOAT, null);
        for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, p, gl.NEAREST);
        gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
        gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, texture, 0);
        if (gl.checkFramebufferStatus(gl.FRAMEBUFFER) !== gl.FRAMEBUFFER_COMPLETE) throw new Error("half-float framebuffer incomplete");
        gl.bindTexture(gl.TEXTURE_2D, null);
        gl.activeTexture(gl.TEXTURE0);
        size = [w, h];
      }
      gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
    },
    /// Show what was drawn (premultiplied colour and alpha, as gsplat leaves them) over
    /// the background, or over the backdrop seen from `view` ({ rotation (world → camera
    /// rows), eye, fx, fy, cx, cy }).
    end(view = null) {
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      gl.viewport(0, 0, size[0], size[1]);
      gl.disable(gl.BLEND);
      gl.useProgram(program);
      // A texture unit of its own: gsplat leaves its splat data bound on units 0–4 and
      // rebinds them only when the data changes.
      gl.activeTexture(gl.TEXTURE0 + UNIT);
      gl.bindTexture(gl.TEXTURE_2D, texture);
      gl.uniform1i(gl.getUniformLocation(program, "image"), UNIT);
      gl.uniform3fv(gl.getUniformLocation(program, "background"), background);
      const use = !!(backdrop && view);
      const u = (name) => gl.getUniformLocation(program, name);
      gl.uniform1i(u("hasBackdrop"), use ? 1 : 0);
      gl.activeTexture(gl.TEXTURE0 + BACKDROP_UNIT);
      gl.bindTexture(gl.TEXTURE_2D, backdropTexture);
      gl.uniform1i(u("backdrop"), BACKDROP_UNIT);
      gl.activeTexture(gl.TEXTURE0 + UNIT);
      if (use) {
        gl.uniform3fv(u("centre"), backdrop.centre);
        gl.uniform1f(u("radius"), backdrop.radius);
        // Column-major: the columns are the axes; the camera → world rotation's columns
        // are the world → camera rotation's rows.
        gl.uniformMatrix3fv(u("axes"), false, backdrop.axes.flat());
        gl.uniformMatrix3fv(u("toWorld"), false, view.rotation.flat());
        gl.uniform3fv(u("eye"), view.eye);
        gl.uniform4fv(u("lens"), [view.fx, view.fy, view.cx, view.cy]);
        gl.uniform1f(u("height"), size[1]);
      }
      gl.bindVertexArray(vao);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
      gl.bindVertexArray(null);
      gl.bindTexture(gl.TEXTURE_2D, null);
      gl.activeTexture(gl.TEXTURE0 + BACKDROP_UNIT);
      gl.bindTexture(gl.TEXTURE_2D, null);
      gl.activeTexture(gl.TEXTURE0);
    },
  };
}
