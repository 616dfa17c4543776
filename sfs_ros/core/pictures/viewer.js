"use strict";
const M = JSON.parse(document.getElementById("mesh").textContent);
const {fov_rad: FOV, fit: FIT, ambient: AMBIENT, background: BG, color: COLOR} = M;
const HOME = {az: M.azimuth_rad, el: M.elevation_rad, zoom: 1};

function decode(b64, Type) {
  const s = atob(b64), bytes = new Uint8Array(s.length);
  for (let i = 0; i < s.length; i++) bytes[i] = s.charCodeAt(i);
  return new Type(bytes.buffer);
}
const V = decode(M.vertices, Float32Array), F = decode(M.faces, Uint32Array);
const C = M.colors ? decode(M.colors, Uint8Array) : null;
const T = M.uv ? decode(M.uv, Float32Array) : null;
const nf = F.length / 3, view = Object.assign({}, HOME);
const canvas = document.getElementById("view");

function cross(u, v) { return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]; }
function unit(u) { const l = Math.hypot(u[0], u[1], u[2]) || 1; return [u[0] / l, u[1] / l, u[2] / l]; }

// Camera: column-major 4x4 projection * view matrix, and the unit direction towards the eye.
function camera(width, height) {
  const t = Math.tan(FOV / 2), s = FIT * Math.min(width, height) / height;
  const d = M.radius / Math.sin(Math.atan(s * t)) / view.zoom;
  const toEye = [Math.cos(view.el) * Math.cos(view.az), Math.cos(view.el) * Math.sin(view.az), Math.sin(view.el)];
  const eye = M.center.map((c, k) => c + d * toEye[k]);
  const back = toEye, right = unit(cross([0, 0, 1], back)), up = cross(back, right);
  const near = Math.max(d - 1.01 * M.radius, 0.01 * M.radius), far = d + 1.01 * M.radius;
  const fy = 1 / t, fx = fy * height / width, a = (far + near) / (near - far), b = 2 * far * near / (near - far);
  const dot = (u) => u[0] * eye[0] + u[1] * eye[1] + u[2] * eye[2];
  const R = [right, up, back], tr = R.map((r) => -dot(r));
  const m = new Float32Array(16);
  for (let c = 0; c < 3; c++) {
    m[4 * c] = fx * R[0][c]; m[4 * c + 1] = fy * R[1][c];
    m[4 * c + 2] = a * R[2][c]; m[4 * c + 3] = -R[2][c];
  }
  m[12] = fx * tr[0]; m[13] = fy * tr[1]; m[14] = a * tr[2] + b; m[15] = -tr[2];
  return {m, toEye};
}

function webgl() {
  const opts = {antialias: true, preserveDrawingBuffer: true};
  const gl = canvas.getContext("webgl2", opts) || canvas.getContext("webgl", opts);
  if (!gl || (!gl.getParameter(gl.VERSION).startsWith("WebGL 2") && !gl.getExtension("OES_element_index_uint"))) return null;
  const shader = (type, src) => {
    const s = gl.createShader(type);
    gl.shaderSource(s, src); gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
    return s;
  };
  const prog = gl.createProgram();
  gl.attachShader(prog, shader(gl.VERTEX_SHADER, `
    attribute vec3 p, n, c; attribute vec2 t; uniform mat4 mvp; varying vec3 vn, vc; varying vec2 vt;
    void main() { gl_Position = mvp * vec4(p, 1.0); vn = n; vc = c; vt = t; }`));
  gl.attachShader(prog, shader(gl.FRAGMENT_SHADER, `
    precision mediump float; uniform vec3 light; uniform float ambient, textured; uniform sampler2D atlas;
    varying vec3 vn, vc; varying vec2 vt;
    void main() {
      vec3 albedo = textured > 0.5 ? texture2D(atlas, vt).rgb : vc;
      gl_FragColor = vec4(albedo * (ambient + (1.0 - ambient) * abs(dot(normalize(vn), light))), 1.0);
    }`));
  gl.linkProgram(prog);
  if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(prog));
  gl.useProgram(prog);
  const N = new Float32Array(V.length);  // vertex normals: sums of the adjacent faces' area vectors
  for (let f = 0; f < F.length; f += 3) {
    const [a, b, c] = [3 * F[f], 3 * F[f + 1], 3 * F[f + 2]];
    const n = cross([V[b] - V[a], V[b + 1] - V[a + 1], V[b + 2] - V[a + 2]],
                    [V[c] - V[a], V[c + 1] - V[a + 1], V[c + 2] - V[a + 2]]);
    for (const i of [a, b, c]) for (let k = 0; k < 3; k++) N[i + k] += n[k];
  }
  const attribute = (name, data, type, normalized, size = 3) => {
    const loc = gl.getAttribLocation(prog, name);
    gl.bindBuffer(gl.ARRAY_BUFFER, gl.createBuffer());
    gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
    gl.enableVertexAttribArray(loc);
    gl.vertexAttribPointer(loc, size, type, normalized, 0, 0);
  };
  attribute("p", V, gl.FLOAT, false);
  attribute("n", N, gl.FLOAT, false);
  if (C) attribute("c", C, gl.UNSIGNED_BYTE, true);
  else gl.vertexAttrib3f(gl.getAttribLocation(prog, "c"), ...COLOR.map((v) => v / 255));
  let textured = 0;
  if (T) {  // the atlas: drawn once its PNG is decoded (until then, the vertex colours)
    attribute("t", T, gl.FLOAT, false, 2);
    const image = new Image();
    image.onload = () => {
      gl.bindTexture(gl.TEXTURE_2D, gl.createTexture());
      gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, true);  // v up: row 0 of the PNG at v = 1
      gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGB, gl.RGB, gl.UNSIGNED_BYTE, image);
      for (const [k, v] of [[gl.TEXTURE_MIN_FILTER, gl.LINEAR], [gl.TEXTURE_MAG_FILTER, gl.LINEAR],
                            [gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE], [gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE]])
        gl.texParameteri(gl.TEXTURE_2D, k, v);
      textured = 1;
      document.body.dataset.texture = "drawn";
      redraw();
    };
    image.src = "data:image/png;base64," + M.texture;
  } else gl.vertexAttrib2f(gl.getAttribLocation(prog, "t"), 0, 0);
  gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, gl.createBuffer());
  gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, F, gl.STATIC_DRAW);
  gl.enable(gl.DEPTH_TEST);
  gl.clearColor(...BG.map((v) => v / 255), 1);
  return () => {
    const {m, toEye} = camera(canvas.width, canvas.height);
    gl.viewport(0, 0, canvas.width, canvas.height);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.uniformMatrix4fv(gl.getUniformLocation(prog, "mvp"), false, m);
    gl.uniform3fv(gl.getUniformLocation(prog, "light"), toEye);
    gl.uniform1f(gl.getUniformLocation(prog, "ambient"), AMBIENT);
    gl.uniform1f(gl.getUniformLocation(prog, "textured"), textured);
    gl.drawElements(gl.TRIANGLES, F.length, gl.UNSIGNED_INT, 0);
  };
}

function canvas2d(target) {
  const ctx = target.getContext("2d"), nv = V.length / 3;
  const normal = new Float32Array(3 * nf), color = new Uint8Array(3 * nf);
  for (let f = 0; f < nf; f++) {
    const [a, b, c] = [3 * F[3 * f], 3 * F[3 * f + 1], 3 * F[3 * f + 2]];
    normal.set(unit(cross([V[b] - V[a], V[b + 1] - V[a + 1], V[b + 2] - V[a + 2]],
                          [V[c] - V[a], V[c + 1] - V[a + 1], V[c + 2] - V[a + 2]])), 3 * f);
    for (let k = 0; k < 3; k++) color[3 * f + k] = C ? (C[a + k] + C[b + k] + C[c + k]) / 3 : COLOR[k];
  }
  const x = new Float32Array(nv), y = new Float32Array(nv), w = new Float32Array(nv);
  const depth = new Float32Array(nf), order = new Uint32Array(nf);
  return () => {
    const W = target.width, H = target.height, {m, toEye} = camera(W, H);
    ctx.fillStyle = `rgb(${BG})`;
    ctx.fillRect(0, 0, W, H);
    for (let i = 0; i < nv; i++) {
      const [p, q, r] = [V[3 * i], V[3 * i + 1], V[3 * i + 2]];
      w[i] = m[3] * p + m[7] * q + m[11] * r + m[15];
      x[i] = (1 + (m[0] * p + m[4] * q + m[8] * r + m[12]) / w[i]) * W / 2;
      y[i] = (1 - (m[1] * p + m[5] * q + m[9] * r + m[13]) / w[i]) * H / 2;
    }
    let k = 0;
    for (let f = 0; f < nf; f++) {
      const [a, b, c] = [F[3 * f], F[3 * f + 1], F[3 * f + 2]];
      if (w[a] > 0 && w[b] > 0 && w[c] > 0) { depth[f] = w[a] + w[b] + w[c]; order[k++] = f; }
    }
    ctx.lineWidth = 1;  // stroking each triangle in its own colour hides the seams between them
    ctx.lineJoin = "round";
    for (const f of order.subarray(0, k).sort((i, j) => depth[j] - depth[i])) {
      const [a, b, c] = [F[3 * f], F[3 * f + 1], F[3 * f + 2]];
      const l = AMBIENT + (1 - AMBIENT) * Math.abs(normal[3 * f] * toEye[0] + normal[3 * f + 1] * toEye[1] + normal[3 * f + 2] * toEye[2]);
      ctx.fillStyle = ctx.strokeStyle = `rgb(${color[3 * f] * l},${color[3 * f + 1] * l},${color[3 * f + 2] * l})`;
      ctx.beginPath(); ctx.moveTo(x[a], y[a]); ctx.lineTo(x[b], y[b]); ctx.lineTo(x[c], y[c]); ctx.closePath();
      ctx.fill(); ctx.stroke();
    }
  };
}

let draw, renderer = "WebGL", target = canvas;
try { draw = webgl(); } catch (err) { console.warn("WebGL failed:", err); }
if (!draw) {  // a canvas that had a WebGL context cannot give a 2-D one: replace it
  target = canvas.cloneNode();
  canvas.replaceWith(target);
  draw = canvas2d(target);
  renderer = "Canvas 2D";
}
document.body.dataset.renderer = renderer;
document.getElementById("renderer").textContent = renderer;
let pending = false;
function redraw() {
  if (!pending) { pending = true; requestAnimationFrame(() => { pending = false; paint(); }); }
}
function paint() {  // drawing buffer = CSS size x device pixel ratio (setting it clears it)
  const r = devicePixelRatio || 1, w = Math.round(target.clientWidth * r), h = Math.round(target.clientHeight * r);
  if (target.width !== w || target.height !== h) { target.width = w; target.height = h; }
  draw();
}
function reset() { Object.assign(view, HOME); redraw(); }
let drag = null;
target.addEventListener("pointerdown", (e) => { drag = [e.clientX, e.clientY]; target.setPointerCapture(e.pointerId); });
target.addEventListener("pointerup", () => { drag = null; });
target.addEventListener("pointermove", (e) => {
  if (!drag) return;
  view.az -= 0.01 * (e.clientX - drag[0]);
  view.el = Math.max(-1.55, Math.min(1.55, view.el + 0.01 * (e.clientY - drag[1])));
  drag = [e.clientX, e.clientY];
  redraw();
});
target.addEventListener("wheel", (e) => {
  e.preventDefault();
  view.zoom = Math.max(0.2, Math.min(50, view.zoom * Math.exp(-0.002 * e.deltaY)));
  redraw();
}, {passive: false});
target.addEventListener("dblclick", reset);
document.getElementById("reset").addEventListener("click", reset);
addEventListener("keydown", (e) => { if (e.key === "r" || e.key === "R") reset(); });
addEventListener("resize", redraw);
paint();
