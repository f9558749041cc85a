// The 3D view of the salient page: a small GLB parser and a hand-written WebGL renderer that
// draws the query and a chosen result side by side, their salient points, and the matches of
// the explanation as lines. No libraries: the page must work offline under a strict CSP.

// Region colours (feature index i uses PALETTE[i % 6]); the server bakes the same ones into
// the preview GLBs and thumbnails, so the page, the PNGs and the 3D view agree.
export const PALETTE = [
  [1.0, 0.85, 0.2], [0.25, 0.75, 0.95], [0.45, 0.85, 0.35],
  [0.7, 0.5, 0.95], [1.0, 0.6, 0.2], [0.3, 0.9, 0.8],
];
export const SURFACE = [0.78, 0.78, 0.8];
const POINT_RED = [0.9, 0.08, 0.08];
const PIECE = [0.96, 0.5, 0.12]; // a part search's piece, laid where it fits in a result
const BACKGROUND = [0.973, 0.976, 0.984];
const NO_REGION = 65535;
const OFFSET = 1.1; // query at x = -1.1, result at x = +1.1, each fitted into a unit sphere

// ---------------------------------------------------------------------------------------------
// GLB (binary glTF 2.0): just what the server's previews use. One mesh, one primitive.

const GLB_MAGIC = 0x46546c67, CHUNK_JSON = 0x4e4f534a, CHUNK_BIN = 0x004e4942;
const COMPONENT = { 5120: Int8Array, 5121: Uint8Array, 5122: Int16Array, 5123: Uint16Array,
  5125: Uint32Array, 5126: Float32Array };
const WIDTH = { SCALAR: 1, VEC2: 2, VEC3: 3, VEC4: 4 };

// One accessor as a tightly packed typed array. byteOffset (of the view and the accessor) and
// byteStride may be absent; strided or unaligned data is copied element by element (glTF is
// little-endian, as is every platform a browser runs on).
function readAccessor(gltf, bin, index) {
  const acc = gltf.accessors?.[index];
  const Type = acc && COMPONENT[acc.componentType];
  const n = acc && WIDTH[acc.type];
  if (!Type || !n) throw new Error(`GLB: unsupported accessor ${index}`);
  if (acc.sparse) throw new Error('GLB: sparse accessors are not supported');
  const out = new Type(acc.count * n);
  if (acc.bufferView === undefined) return out; // glTF: no view means all zeros
  const view = gltf.bufferViews[acc.bufferView];
  if (!bin || (view.buffer ?? 0) !== 0) throw new Error('GLB: accessor outside the BIN chunk');
  const elem = Type.BYTES_PER_ELEMENT * n;
  const stride = view.byteStride || elem;
  const start = (view.byteOffset || 0) + (acc.byteOffset || 0);
  const end = acc.count ? start + stride * (acc.count - 1) + elem : start;
  if (end > (view.byteOffset || 0) + view.byteLength || end > bin.byteLength) {
    throw new Error('GLB: accessor runs past its buffer view');
  }
  const src = new Uint8Array(bin.buffer, bin.byteOffset + start, end - start);
  const dst = new Uint8Array(out.buffer);
  if (stride === elem) dst.set(src);
  else for (let k = 0; k < acc.count; k++) dst.set(src.subarray(k * stride, k * stride + elem), k * elem);
  return out;
}

// -> { positions: Float32Array (xyz), colors: Float32Array (rgb) | null, regions: Uint16Array |
//      null, indices: Uint32Array, points: [[x, y, z]], up: 'y' | 'z' }; positions turned +y up,
//      points in the model's own coordinates (see upright).
export function parseGlb(buffer) {
  const dv = new DataView(buffer);
  if (buffer.byteLength < 20 || dv.getUint32(0, true) !== GLB_MAGIC) throw new Error('not a GLB file');
  if (dv.getUint32(4, true) !== 2) throw new Error('GLB: only glTF 2.0 is supported');
  const total = Math.min(dv.getUint32(8, true), buffer.byteLength);
  let gltf = null, bin = null;
  for (let off = 12; off + 8 <= total;) {
    const len = dv.getUint32(off, true), type = dv.getUint32(off + 4, true);
    if (off + 8 + len > total) throw new Error('GLB: truncated chunk');
    const bytes = new Uint8Array(buffer, off + 8, len);
    if (type === CHUNK_JSON && !gltf) gltf = JSON.parse(new TextDecoder().decode(bytes));
    else if (type === CHUNK_BIN && !bin) bin = bytes;
    off += 8 + ((len + 3) & ~3); // chunks are padded to 4 bytes
  }
  if (!gltf) throw new Error('GLB: no JSON chunk');
  const prim = gltf.meshes?.[0]?.primitives?.[0];
  if (!prim || prim.attributes?.POSITION === undefined) throw new Error('GLB: no mesh');
  if ((prim.mode ?? 4) !== 4) throw new Error('GLB: only TRIANGLES are supported');
  const positions = Float32Array.from(readAccessor(gltf, bin, prim.attributes.POSITION));
  const count = positions.length / 3;
  let colors = null;
  if (prim.attributes.COLOR_0 !== undefined) {
    const acc = gltf.accessors[prim.attributes.COLOR_0];
    const raw = readAccessor(gltf, bin, prim.attributes.COLOR_0);
    const n = WIDTH[acc.type], scale = acc.componentType === 5126 ? 1 : (2 ** (8 * raw.BYTES_PER_ELEMENT) - 1);
    colors = new Float32Array(count * 3);
    for (let v = 0; v < count; v++) for (let c = 0; c < 3; c++) colors[v * 3 + c] = raw[v * n + c] / scale;
  }
  const regions = prim.attributes._REGION !== undefined
    ? Uint16Array.from(readAccessor(gltf, bin, prim.attributes._REGION)) : null;
  const indices = prim.indices !== undefined
    ? Uint32Array.from(readAccessor(gltf, bin, prim.indices))
    : Uint32Array.from({ length: count }, (_, i) => i);
  for (const i of indices) if (i >= count) throw new Error('GLB: index out of range');
  const points = gltf.asset?.extras?.salient?.points ?? [];
  // A library whose models stand on +z (the server's --up-axis z) says so; the view is +y up.
  const up = gltf.asset?.extras?.salient?.up === 'z' ? 'z' : 'y';
  if (up === 'z') {
    for (let i = 0; i < positions.length; i += 3) {
      const y = positions[i + 1];
      positions[i + 1] = positions[i + 2];
      positions[i + 2] = -y;
    }
  }
  return { positions, colors, regions, indices, points, up };
}

// A point in a model's own coordinates (salient points, explanations) turned as its mesh was.
export function upright(mesh, p) {
  return mesh.up === 'z' ? [p[0], p[2], -p[1]] : p;
}

// The query's piece where a part search registered it in `model` (placement: the 4 × 4
// column-major matrix taking the piece's coordinates as uploaded to the model's as stored):
// its preview's positions turned back to those coordinates, placed, then turned upright as the
// model's mesh was; framed by the model (`fit`), one colour.
function placed(piece, model, m) {
  const own = (p) => (piece.up === 'z' ? [p[0], -p[2], p[1]] : p); // upright's inverse
  const positions = new Float32Array(piece.positions.length);
  for (let i = 0; i < positions.length; i += 3) {
    const [x, y, z] = own(piece.positions.subarray(i, i + 3));
    const p = [0, 1, 2].map((r) => m[r] * x + m[4 + r] * y + m[8 + r] * z + m[12 + r]);
    positions.set(upright(model, p), i);
  }
  const mesh = { positions, indices: piece.indices, regions: null, points: [], up: model.up,
    colors: Float32Array.from({ length: positions.length }, (_, i) => PIECE[i % 3]) };
  mesh.fit = { ...prepare(mesh), center: model.fit.center, radius: model.fit.radius };
  return mesh;
}

// Area-weighted vertex normals, and the bounding box's centre and half diagonal (the fit).
function prepare(mesh) {
  const p = mesh.positions, idx = mesh.indices, normals = new Float32Array(p.length);
  for (let t = 0; t + 2 < idx.length; t += 3) {
    const a = idx[t] * 3, b = idx[t + 1] * 3, c = idx[t + 2] * 3;
    const ux = p[b] - p[a], uy = p[b + 1] - p[a + 1], uz = p[b + 2] - p[a + 2];
    const vx = p[c] - p[a], vy = p[c + 1] - p[a + 1], vz = p[c + 2] - p[a + 2];
    const nx = uy * vz - uz * vy, ny = uz * vx - ux * vz, nz = ux * vy - uy * vx;
    for (const v of [a, b, c]) { normals[v] += nx; normals[v + 1] += ny; normals[v + 2] += nz; }
  }
  const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (let i = 0; i < p.length; i += 3) {
    for (let c = 0; c < 3; c++) { lo[c] = Math.min(lo[c], p[i + c]); hi[c] = Math.max(hi[c], p[i + c]); }
  }
  const center = lo.map((l, c) => (l + hi[c]) / 2);
  const radius = Math.hypot(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]) / 2 || 1;
  return { normals, center, radius };
}

// Vertex colours from the regions: region r gets colourOf(r) (null = surface grey). Without a
// _REGION attribute the baked COLOR_0 is used as it is.
function regionColors(mesh, colourOf) {
  if (!mesh.regions) return mesh.colors ?? new Float32Array(mesh.positions.length).fill(SURFACE[0]);
  const out = new Float32Array(mesh.positions.length);
  mesh.regions.forEach((r, v) => out.set((r !== NO_REGION && colourOf(r)) || SURFACE, v * 3));
  return out;
}

// ---------------------------------------------------------------------------------------------
// Minimal column-major 4x4 matrices.

function perspective(fovy, aspect, near, far) {
  const f = 1 / Math.tan(fovy / 2), nf = 1 / (near - far);
  return [f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0];
}
function lookAt(eye, up) { // looking at the origin
  const z = norm(eye), x = norm(cross(up, z)), y = cross(z, x);
  return [x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0,
    -dot(x, eye), -dot(y, eye), -dot(z, eye), 1];
}
function multiply(a, b) {
  const o = new Array(16).fill(0);
  for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) for (let k = 0; k < 4; k++) o[c * 4 + r] += a[k * 4 + r] * b[c * 4 + k];
  return o;
}
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a) => { const l = Math.hypot(...a) || 1; return a.map((v) => v / l); };

// ---------------------------------------------------------------------------------------------
// Shaders: GLSL ES 1.00, so that WebGL1 and WebGL2 both run them.

const MESH_VS = `attribute vec3 a_pos; attribute vec3 a_normal; attribute vec3 a_color;
uniform mat4 u_vp; uniform vec3 u_center; uniform float u_scale; uniform vec3 u_offset;
varying vec3 v_normal; varying vec3 v_color; varying vec3 v_world;
void main() { v_world = (a_pos - u_center) * u_scale + u_offset; v_normal = a_normal; v_color = a_color;
  gl_Position = u_vp * vec4(v_world, 1.0); }`;
// Headlight: the light sits at the eye. abs() lights both sides: meshes may be open or
// inconsistently wound.
const MESH_FS = `precision mediump float; uniform vec3 u_eye;
varying vec3 v_normal; varying vec3 v_color; varying vec3 v_world;
void main() { vec3 n = normalize(v_normal); vec3 l = normalize(u_eye - v_world);
  float lambert = abs(dot(n, l)); gl_FragColor = vec4(v_color * (0.32 + 0.68 * lambert), 1.0); }`;
const POINT_VS = `attribute vec3 a_pos; uniform mat4 u_vp; uniform float u_size;
void main() { gl_Position = u_vp * vec4(a_pos, 1.0); gl_Position.z -= 0.02 * gl_Position.w; gl_PointSize = u_size; }`;
const POINT_FS = `precision mediump float; uniform vec3 u_color;
void main() { vec2 d = gl_PointCoord - 0.5; float r = dot(d, d); if (r > 0.25) discard;
  gl_FragColor = vec4(mix(u_color, vec3(1.0), step(0.16, r) * 0.7), 1.0); }`;
// Match lines as screen-space quads, so their width (by mass) does not depend on
// gl.lineWidth, which most implementations cap at 1 pixel.
const LINE_VS = `attribute vec3 a_pos; attribute vec3 a_other; attribute float a_side; attribute float a_width;
attribute vec4 a_color; uniform mat4 u_vp; uniform vec2 u_res; varying vec4 v_color;
void main() { vec4 p = u_vp * vec4(a_pos, 1.0); vec4 o = u_vp * vec4(a_other, 1.0);
  vec2 d = (o.xy / o.w - p.xy / p.w) * u_res; d = length(d) > 1e-4 ? normalize(d) : vec2(1.0, 0.0);
  p.xy += vec2(-d.y, d.x) * a_side * a_width / u_res * p.w; gl_Position = p; v_color = a_color; }`;
const LINE_FS = `precision mediump float; varying vec4 v_color; void main() { gl_FragColor = v_color; }`;

// ---------------------------------------------------------------------------------------------

export class View {
  // labelHost: an element over the canvas where the "Query" / "Result" labels go.
  constructor(canvas, labelHost) {
    this.canvas = canvas;
    const opts = { antialias: true, preserveDrawingBuffer: true }; // the browser test reads pixels
    const gl = canvas.getContext('webgl2', opts) || canvas.getContext('webgl', opts);
    if (!gl) throw new Error('this browser has no WebGL');
    this.gl = gl;
    this.uint32 = typeof WebGL2RenderingContext !== 'undefined' && gl instanceof WebGL2RenderingContext
      || !!gl.getExtension('OES_element_index_uint');
    this.programs = {
      mesh: this.program(MESH_VS, MESH_FS), point: this.program(POINT_VS, POINT_FS),
      line: this.program(LINE_VS, LINE_FS),
    };
    this.models = [null, null]; // query, result
    // Frames drawn since the last layout, in #view[data-drawn]: what the canvas shows is
    // the current scene once it is set (the browser test waits on it, not on time).
    this.frames = 0;
    this.lines = null;
    this.labels = [0, 1].map(() => labelHost.appendChild(document.createElement('span')));
    this.labels.forEach((l) => { l.className = 'view-label'; l.hidden = true; });
    this.resetCamera();
    this.orbit();
    new ResizeObserver(() => this.redraw()).observe(canvas);
  }

  program(vs, fs) {
    const gl = this.gl, p = gl.createProgram();
    for (const [type, src] of [[gl.VERTEX_SHADER, vs], [gl.FRAGMENT_SHADER, fs]]) {
      const s = gl.createShader(type);
      gl.shaderSource(s, src);
      gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(`shader: ${gl.getShaderInfoLog(s)}`);
      gl.attachShader(p, s);
    }
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(`program: ${gl.getProgramInfoLog(p)}`);
    const loc = {};
    const n = gl.getProgramParameter(p, gl.ACTIVE_ATTRIBUTES), u = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
    for (let i = 0; i < n; i++) { const a = gl.getActiveAttrib(p, i).name; loc[a] = gl.getAttribLocation(p, a); }
    for (let i = 0; i < u; i++) { const a = gl.getActiveUniform(p, i).name; loc[a] = gl.getUniformLocation(p, a); }
    return { p, loc };
  }

  buffer(data, target = this.gl.ARRAY_BUFFER) {
    const gl = this.gl, b = gl.createBuffer();
    gl.bindBuffer(target, b);
    gl.bufferData(target, data, gl.STATIC_DRAW);
    return b;
  }

  // Uploads a parsed mesh to slot 0 (query) or 1 (result); null empties the slot.
  setModel(slot, mesh, label, colourOf) {
    const gl = this.gl, old = this.models[slot];
    if (old) for (const b of old.buffers) gl.deleteBuffer(b);
    this.models[slot] = null;
    if (mesh) {
      let indices = mesh.indices;
      if (!this.uint32) {
        if (mesh.positions.length / 3 > 65536) throw new Error('mesh too large for this browser\'s WebGL');
        indices = Uint16Array.from(indices);
      }
      const fit = mesh.fit ?? (mesh.fit = prepare(mesh));
      const m = {
        mesh, fit, label, count: indices.length, indexType: this.uint32 ? gl.UNSIGNED_INT : gl.UNSIGNED_SHORT,
        pos: this.buffer(mesh.positions), normal: this.buffer(fit.normals),
        color: this.buffer(regionColors(mesh, colourOf)),
        index: this.buffer(indices, gl.ELEMENT_ARRAY_BUFFER),
      };
      m.buffers = [m.pos, m.normal, m.color, m.index];
      this.models[slot] = m;
    }
    this.layout();
  }

  // The query with its own region colours; clears the result.
  setQuery(mesh, label) {
    this.query = mesh ? { mesh, label } : null;
    this.matches = [];
    this.overlay = false;
    this.setModel(1, null);
    this.setModel(0, mesh, label, (r) => PALETTE[r % PALETTE.length]);
  }

  // A part search's result with the query's piece laid where it was registered (placement,
  // see placed()): the model alone and grey, the piece on it in orange.
  setPlaced(mesh, label, placement) {
    if (!this.query) return this.setResult(mesh, label);
    this.matches = [];
    this.overlay = true;
    this.setModel(1, mesh, label, () => null);
    this.setModel(0, placed(this.query.mesh, mesh, placement), null, () => null);
  }

  // A result beside the query. matches: the hit's explanation ({query, result, mass,
  // query_position, result_position}). The result's region j takes the colour of the query
  // region it received most mass from, so matched regions look alike; unmatched ones stay grey.
  setResult(mesh, label, matches = []) {
    if (this.overlay) { // the piece laid on the last result: the query again, beside
      this.overlay = false;
      this.setModel(0, this.query.mesh, this.query.label, (r) => PALETTE[r % PALETTE.length]);
    }
    const best = new Map();
    for (const m of matches) if (!(best.get(m.result)?.mass >= m.mass)) best.set(m.result, m);
    this.matches = mesh ? matches : [];
    this.setModel(1, mesh, label, (r) => best.has(r) ? PALETTE[best.get(r).query % PALETTE.length] : null);
  }

  // Placement: the query alone is centred; with a result, the two sit at -1.1 and +1.1.
  // On a tall canvas (a phone held upright) the query goes above the result instead. A piece
  // laid on its result (overlay) shares the result's place.
  layout() {
    const [q, r] = this.models;
    const apart = q && r && !this.overlay;
    const at = (sign) => (this.stacked ? [0, -sign * OFFSET, 0] : [sign * OFFSET, 0, 0]);
    if (q) q.offset = apart ? at(-1) : [0, 0, 0];
    if (r) r.offset = apart ? at(1) : [0, 0, 0];
    for (const m of this.models) if (m) m.points = m.mesh.points.map((p) => this.place(m, p));
    this.buildLines();
    this.canvas.dataset.models = String(this.models.filter(Boolean).length);
    if (!r) delete this.canvas.dataset.result; // app.js names the result it shows
    if (this.overlay) this.canvas.dataset.placed = '1'; else delete this.canvas.dataset.placed;
    delete this.canvas.dataset.drawn;
    this.redraw();
  }

  place(m, own) {
    const p = upright(m.mesh, own);
    return [0, 1, 2].map((c) => (p[c] - m.fit.center[c]) / m.fit.radius + m.offset[c]);
  }

  buildLines() {
    const gl = this.gl, [q, r] = this.models;
    if (this.lines) gl.deleteBuffer(this.lines.buffer);
    this.lines = null;
    const matches = q && r ? (this.matches || []) : [];
    this.canvas.dataset.matches = String(matches.length);
    if (!matches.length) return;
    const maxMass = Math.max(...matches.map((m) => m.mass)) || 1;
    // 6 vertices (two triangles) per line; each: pos3 other3 side1 width1 rgba4 = 12 floats.
    const data = new Float32Array(matches.length * 6 * 12);
    let o = 0;
    for (const m of matches) {
      const a = this.place(q, m.query_position), b = this.place(r, m.result_position);
      const t = m.mass / maxMass, width = 1.5 + 4.5 * t;
      const rgba = [...PALETTE[m.query % PALETTE.length].map((c) => c * 0.8), 0.35 + 0.6 * t];
      for (const [end, side] of [[0, 1], [0, -1], [1, 1], [0, -1], [1, -1], [1, 1]]) {
        const [p, other] = end ? [b, a] : [a, b];
        data.set([...p, ...other, end ? -side : side, width, ...rgba], o);
        o += 12;
      }
    }
    this.lines = { buffer: this.buffer(data), count: matches.length * 6 };
  }

  resetCamera() {
    this.yaw = 0.35; this.pitch = 0.25; this.zoom = 1;
    this.redraw();
  }

  // Orbit control: drag rotates, wheel (or pinch) zooms, double-click or Home resets.
  orbit() {
    const c = this.canvas, pointers = new Map();
    let pinch = 0;
    c.addEventListener('pointerdown', (e) => { c.setPointerCapture(e.pointerId); pointers.set(e.pointerId, e); });
    const up = (e) => { pointers.delete(e.pointerId); pinch = 0; };
    c.addEventListener('pointerup', up);
    c.addEventListener('pointercancel', up);
    c.addEventListener('pointermove', (e) => {
      const prev = pointers.get(e.pointerId);
      if (!prev) return;
      pointers.set(e.pointerId, e);
      if (pointers.size === 2) {
        const [a, b] = [...pointers.values()], d = Math.hypot(a.clientX - b.clientX, a.clientY - b.clientY);
        if (pinch) this.zoomBy(pinch / d);
        pinch = d;
      } else this.rotate(e.clientX - prev.clientX, e.clientY - prev.clientY);
    });
    c.addEventListener('wheel', (e) => { e.preventDefault(); this.zoomBy(Math.exp(e.deltaY * 0.0015)); }, { passive: false });
    c.addEventListener('dblclick', () => this.resetCamera());
    c.addEventListener('keydown', (e) => {
      const keys = { ArrowLeft: [-20, 0], ArrowRight: [20, 0], ArrowUp: [0, -20], ArrowDown: [0, 20] };
      if (keys[e.key]) this.rotate(...keys[e.key]);
      else if (e.key === '+' || e.key === '-') this.zoomBy(e.key === '+' ? 0.9 : 1.1);
      else if (e.key === 'Home') this.resetCamera();
      else return;
      e.preventDefault();
    });
  }

  rotate(dx, dy) {
    this.yaw -= dx * 0.008;
    this.pitch = Math.max(-1.5, Math.min(1.5, this.pitch + dy * 0.008));
    this.redraw();
  }

  zoomBy(f) { this.zoom = Math.max(0.3, Math.min(4, this.zoom * f)); this.redraw(); }

  redraw() {
    if (!this.frame) this.frame = requestAnimationFrame(() => { this.frame = 0; this.draw(); });
  }

  draw() {
    const gl = this.gl, c = this.canvas, dpr = window.devicePixelRatio || 1;
    const w = Math.max(1, Math.round(c.clientWidth * dpr)), h = Math.max(1, Math.round(c.clientHeight * dpr));
    if (c.width !== w || c.height !== h) { c.width = w; c.height = h; }
    if ((w < h) !== !!this.stacked) { this.stacked = w < h; this.layout(); }
    gl.viewport(0, 0, w, h);
    gl.clearColor(...BACKGROUND, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    const models = this.models.filter(Boolean);
    // Frame the scene: one unit sphere, or two side by side (or stacked). Slightly tighter
    // than the spheres, which a mesh seldom fills.
    const aspect = w / h, fov = 0.7, tan = Math.tan(fov / 2), two = models.length === 2 && !this.overlay;
    const ex = two && !this.stacked ? OFFSET + 1 : 1, ey = two && this.stacked ? OFFSET + 1 : 1;
    const dist = (Math.max(ey / tan, ex / (tan * aspect)) * 0.9 + 0.7) * this.zoom;
    const eye = [dist * Math.cos(this.pitch) * Math.sin(this.yaw), dist * Math.sin(this.pitch),
      dist * Math.cos(this.pitch) * Math.cos(this.yaw)];
    const vp = multiply(perspective(fov, aspect, dist / 50, dist * 4), lookAt(eye, [0, 1, 0]));
    gl.enable(gl.DEPTH_TEST);
    gl.disable(gl.BLEND);
    let prog = this.use('mesh');
    gl.uniformMatrix4fv(prog.u_vp, false, vp);
    gl.uniform3fv(prog.u_eye, eye);
    for (const m of models) {
      // A laid piece is the model's own surface: drawn a little nearer, so that it shows.
      if (this.overlay && m === this.models[0]) {
        gl.enable(gl.POLYGON_OFFSET_FILL);
        gl.polygonOffset(-1, -4);
      } else gl.disable(gl.POLYGON_OFFSET_FILL);
      gl.uniform3fv(prog.u_center, m.fit.center);
      gl.uniform1f(prog.u_scale, 1 / m.fit.radius);
      gl.uniform3fv(prog.u_offset, m.offset);
      this.attrib(prog.a_pos, m.pos, 3);
      this.attrib(prog.a_normal, m.normal, 3);
      this.attrib(prog.a_color, m.color, 3);
      gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, m.index);
      gl.drawElements(gl.TRIANGLES, m.count, m.indexType, 0);
    }
    gl.disable(gl.POLYGON_OFFSET_FILL);
    this.disableAttribs(prog);
    // Salient points: red markers, pulled slightly towards the eye so the surface does not hide them.
    const pts = models.flatMap((m) => m.points);
    if (pts.length) {
      prog = this.use('point');
      gl.uniformMatrix4fv(prog.u_vp, false, vp);
      gl.uniform1f(prog.u_size, Math.max(5, Math.min(12, w / 90)) * (models.length === 1 ? 1.2 : 1));
      gl.uniform3fv(prog.u_color, POINT_RED);
      const b = this.buffer(new Float32Array(pts.flat()));
      this.attrib(prog.a_pos, b, 3);
      gl.drawArrays(gl.POINTS, 0, pts.length);
      this.disableAttribs(prog);
      gl.deleteBuffer(b);
    }
    // Match lines: on top of everything (no depth test), translucent by mass.
    if (this.lines) {
      prog = this.use('line');
      gl.disable(gl.DEPTH_TEST);
      gl.enable(gl.BLEND);
      gl.blendFunc(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA);
      gl.uniformMatrix4fv(prog.u_vp, false, vp);
      gl.uniform2f(prog.u_res, w, h);
      const F = 4 * 12;
      this.attrib(prog.a_pos, this.lines.buffer, 3, F, 0);
      this.attrib(prog.a_other, this.lines.buffer, 3, F, 12);
      this.attrib(prog.a_side, this.lines.buffer, 1, F, 24);
      this.attrib(prog.a_width, this.lines.buffer, 1, F, 28);
      this.attrib(prog.a_color, this.lines.buffer, 4, F, 32);
      gl.drawArrays(gl.TRIANGLES, 0, this.lines.count);
      this.disableAttribs(prog);
    }
    this.placeLabels(vp, w, h, dpr);
    c.dataset.drawn = String(++this.frames);
  }

  use(name) {
    const { p, loc } = this.programs[name];
    this.gl.useProgram(p);
    return loc;
  }

  attrib(loc, buffer, size, stride = 0, offset = 0) {
    const gl = this.gl;
    if (loc === undefined || loc < 0) return;
    gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
    gl.enableVertexAttribArray(loc);
    gl.vertexAttribPointer(loc, size, gl.FLOAT, false, stride, offset);
  }

  disableAttribs(loc) {
    for (const [k, v] of Object.entries(loc)) if (k.startsWith('a_') && v >= 0) this.gl.disableVertexAttribArray(v);
  }

  // Each label floats above its model: the top of its unit sphere, projected.
  placeLabels(vp, w, h, dpr) {
    this.models.forEach((m, i) => {
      const el = this.labels[i];
      el.hidden = !m?.label;
      if (el.hidden) return;
      el.textContent = m.label;
      const [x, y, z] = [m.offset[0], m.offset[1] + 1.05, 0];
      const cx = vp[0] * x + vp[4] * y + vp[8] * z + vp[12], cy = vp[1] * x + vp[5] * y + vp[9] * z + vp[13];
      const cw = vp[3] * x + vp[7] * y + vp[11] * z + vp[15];
      // CSSOM, not a style attribute: allowed by the page's CSP (style-src 'self').
      el.style.left = `${Math.max(70, Math.min(w / dpr - 70, ((cx / cw + 1) / 2) * w / dpr))}px`;
      el.style.top = `${Math.max(4, ((1 - cy / cw) / 2) * h / dpr - 28)}px`;
    });
  }
}
