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
/// page's background shows through).
export function floatTarget(gl, background) {
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
out vec4 colour;
void main() {
  vec4 c = clamp(texelFetch(image, ivec2(gl_FragCoord.xy), 0), 0.0, 1.0);
  colour = vec4(clamp(c.rgb + (1.0 - c.a) * background, 0.0, 1.0), 1.0);
}`));
  gl.linkProgram(program);
  if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
  const UNIT = 7;
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
    /// the background.
    end() {
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
      gl.bindVertexArray(vao);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
      gl.bindVertexArray(null);
      gl.bindTexture(gl.TEXTURE_2D, null);
      gl.activeTexture(gl.TEXTURE0);
    },
  };
}
