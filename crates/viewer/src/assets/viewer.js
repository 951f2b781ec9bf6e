// pi3det viewer / editor: WebGL2 points and box wireframes. One script for both modes: the
// static page (points embedded) and `pi3det annotate` (points and labels fetched, edits saved).
(function () {
  'use strict';
  const $ = (id) => document.getElementById(id);
  const statusEl = $('status');
  const setStatus = (attrs, text) => {
    for (const [k, v] of Object.entries(attrs)) statusEl.dataset[k] = String(v);
    if (text !== undefined) statusEl.textContent = text;
  };
  // Any failure ends up in the status element, where people and tests look.
  const fail = (msg) => setStatus({ state: 'error', error: msg }, 'error: ' + msg);
  window.addEventListener('error', (e) => fail(String(e.message || e)));
  window.addEventListener('unhandledrejection', (e) => fail(String((e.reason && e.reason.message) || e.reason)));

  const scene = JSON.parse($('scene').textContent);
  const edit = scene.mode === 'edit';
  const frames = scene.frames;
  const params = new URLSearchParams(location.search);

  // ---------------------------------------------------------------- points
  function b64bytes(s) {
    const bin = atob(s);
    const u = new Uint8Array(bin.length);
    for (let i = 0; i < bin.length; i++) u[i] = bin.charCodeAt(i);
    return u;
  }
  function unpack(p) {
    const q = new Uint16Array(b64bytes(p.xyz).buffer);
    const xyz = new Float32Array(3 * p.n);
    for (let i = 0; i < p.n; i++) {
      for (let a = 0; a < 3; a++) xyz[3 * i + a] = p.offset[a] + q[3 * i + a] * p.scale[a];
    }
    return { n: p.n, xyz, inten: b64bytes(p.intensity), zr: p.z_range };
  }
  const pointCache = new Map();
  async function framePoints(k) {
    if (pointCache.has(k)) return pointCache.get(k);
    let packed = frames[k].points;
    if (!packed) {
      const r = await fetch('/api/points/' + frames[k].index);
      if (!r.ok) throw new Error('points of frame ' + frames[k].id + ': HTTP ' + r.status);
      packed = await r.json();
    }
    const p = unpack(packed);
    pointCache.set(k, p);
    return p;
  }

  // ---------------------------------------------------------------- labels
  // layers[k] = { gt: [...], det: [...] }; in edit mode `det` holds the editable labels.
  const layers = frames.map((f) => ({ gt: f.gt, det: f.det }));
  const editable = 'det';
  if (edit) $('detName').textContent = 'labels (editable)';
  if (edit && frames.every((f) => f.gt.length === 0)) $('showGt').parentElement.hidden = true;
  if (!edit && frames.every((f) => f.det.length === 0)) $('showDet').parentElement.hidden = true;

  // ---------------------------------------------------------------- GL
  const canvas = $('gl');
  const gl = canvas.getContext('webgl2', { antialias: true, preserveDrawingBuffer: false });
  if (!gl) {
    fail('WebGL2 is not available in this browser');
    return;
  }
  const TURBO = `
    vec3 turbo(float x) {
      x = clamp(x, 0.0, 1.0);
      const vec4 kR = vec4(0.13572138, 4.61539260, -42.66032258, 132.13108234);
      const vec4 kG = vec4(0.09140261, 2.19418839, 4.84296658, -14.18503333);
      const vec4 kB = vec4(0.10667330, 12.64194608, -60.58204836, 110.36276771);
      const vec2 kR2 = vec2(-152.94239396, 59.28637943);
      const vec2 kG2 = vec2(4.27729857, 2.82956604);
      const vec2 kB2 = vec2(-89.90310912, 27.34824973);
      vec4 v4 = vec4(1.0, x, x * x, x * x * x);
      vec2 v2 = v4.zw * v4.z;
      return vec3(dot(v4, kR) + dot(v2, kR2), dot(v4, kG) + dot(v2, kG2), dot(v4, kB) + dot(v2, kB2));
    }`;
  function program(vs, fs) {
    const sh = (type, src) => {
      const s = gl.createShader(type);
      gl.shaderSource(s, '#version 300 es\nprecision highp float;\n' + src);
      gl.compileShader(s);
      if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error('shader: ' + gl.getShaderInfoLog(s));
      return s;
    };
    const p = gl.createProgram();
    gl.attachShader(p, sh(gl.VERTEX_SHADER, vs));
    gl.attachShader(p, sh(gl.FRAGMENT_SHADER, fs));
    gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error('program: ' + gl.getProgramInfoLog(p));
    return p;
  }
  const pointProg = program(
    `layout(location=0) in vec3 pos; layout(location=1) in float val;
     uniform mat4 mvp; uniform int byIntensity; uniform vec2 zr; uniform float size;
     out vec3 col;` + TURBO + `
     void main() {
       gl_Position = mvp * vec4(pos, 1.0);
       gl_PointSize = size;
       float t = byIntensity == 1 ? sqrt(val) : (pos.z - zr.x) / max(zr.y - zr.x, 1e-3);
       col = turbo(0.1 + 0.85 * t);
     }`,
    `in vec3 col; out vec4 frag; void main() { frag = vec4(col, 1.0); }`
  );
  const lineProg = program(
    `layout(location=0) in vec3 pos; layout(location=1) in vec3 c; uniform mat4 mvp; out vec3 col;
     void main() { gl_Position = mvp * vec4(pos, 1.0); col = c; }`,
    `in vec3 col; out vec4 frag; void main() { frag = vec4(col, 1.0); }`
  );
  // A vertex array of two buffers: attribute 0 (positions, 3 floats) and attribute 1.
  function vertexArray(size1, type1, normalized1) {
    const vao = gl.createVertexArray();
    const buffers = [gl.createBuffer(), gl.createBuffer()];
    gl.bindVertexArray(vao);
    [[3, gl.FLOAT, false], [size1, type1, normalized1]].forEach(([size, type, norm], i) => {
      gl.bindBuffer(gl.ARRAY_BUFFER, buffers[i]);
      gl.enableVertexAttribArray(i);
      gl.vertexAttribPointer(i, size, type, norm, 0, 0);
    });
    return [vao, buffers[0], buffers[1]];
  }
  const [pointVao, pointPos, pointVal] = vertexArray(1, gl.UNSIGNED_BYTE, true);
  const [lineVao, linePos, lineCol] = vertexArray(3, gl.FLOAT, false);
  gl.bindVertexArray(null);

  // ---------------------------------------------------------------- maths
  const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
  const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
  const mul = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const norm = (a) => mul(a, 1 / Math.hypot(a[0], a[1], a[2]));
  // Column-major 4×4 (GL's layout).
  function matMul(a, b) {
    const o = new Float32Array(16);
    for (let c = 0; c < 4; c++)
      for (let r = 0; r < 4; r++) {
        let s = 0;
        for (let k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
        o[c * 4 + r] = s;
      }
    return o;
  }
  function boxCorners(b) {
    const [x, y, z, dx, dy, dz, h] = b;
    const c = Math.cos(h), s = Math.sin(h);
    const out = [];
    for (const [u, v, w] of [[1, 1, -1], [1, -1, -1], [-1, -1, -1], [-1, 1, -1], [1, 1, 1], [1, -1, 1], [-1, -1, 1], [-1, 1, 1]]) {
      const lu = 0.5 * u * dx, lv = 0.5 * v * dy;
      out.push([x + c * lu - s * lv, y + s * lu + c * lv, z + 0.5 * w * dz]);
    }
    return out;
  }
  const EDGES = [[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4], [0, 4], [1, 5], [2, 6], [3, 7]];

  // ---------------------------------------------------------------- camera
  const cam = { mode: 'orbit', target: [15, 0, 0], dist: 45, yaw: Math.PI, pitch: 0.55, followYaw: 0 };
  let view = null; // eye, forward, right, up, ortho half sizes, mvp
  function computeView() {
    const w = canvas.width, h = canvas.height, aspect = w / Math.max(h, 1);
    let eye, target, up, ortho = null;
    if (cam.mode === 'bev') {
      target = cam.target;
      eye = add(target, [0, 0, 200]);
      up = [Math.cos(cam.yaw + Math.PI), Math.sin(cam.yaw + Math.PI), 0];
      ortho = [cam.dist * 0.6 * aspect, cam.dist * 0.6];
    } else if (cam.mode === 'follow') {
      const c = Math.cos(cam.followYaw), s = Math.sin(cam.followYaw);
      eye = [-9 * c, -9 * s, 4.5];
      target = [14 * c, 14 * s, 0];
      up = [0, 0, 1];
    } else {
      const cp = Math.cos(cam.pitch);
      target = cam.target;
      eye = add(target, mul([cp * Math.cos(cam.yaw), cp * Math.sin(cam.yaw), Math.sin(cam.pitch)], cam.dist));
      up = [0, 0, 1];
    }
    const f = norm(sub(target, eye));
    const r = norm(cross(f, up));
    const u = cross(r, f);
    const viewM = new Float32Array([r[0], u[0], -f[0], 0, r[1], u[1], -f[1], 0, r[2], u[2], -f[2], 0,
      -dot(r, eye), -dot(u, eye), dot(f, eye), 1]);
    const near = 0.1, far = 2000;
    let proj;
    const fovY = 55 * Math.PI / 180, t = Math.tan(fovY / 2);
    if (ortho) {
      const [hw, hh] = ortho;
      proj = new Float32Array([1 / hw, 0, 0, 0, 0, 1 / hh, 0, 0, 0, 0, -2 / (far - near), 0, 0, 0, -(far + near) / (far - near), 1]);
    } else {
      proj = new Float32Array([1 / (t * aspect), 0, 0, 0, 0, 1 / t, 0, 0, 0, 0, -(far + near) / (far - near), -1,
        0, 0, -2 * far * near / (far - near), 0]);
    }
    view = { eye, f, r, u, ortho, t, aspect, mvp: matMul(proj, viewM) };
  }
  function project(p) {
    const m = view.mvp;
    const x = m[0] * p[0] + m[4] * p[1] + m[8] * p[2] + m[12];
    const y = m[1] * p[0] + m[5] * p[1] + m[9] * p[2] + m[13];
    const w = m[3] * p[0] + m[7] * p[1] + m[11] * p[2] + m[15];
    if (w <= 1e-6) return null;
    return [(x / w * 0.5 + 0.5) * canvas.clientWidth, (0.5 - y / w * 0.5) * canvas.clientHeight];
  }
  // The ray under a CSS-pixel position.
  function ray(px, py) {
    const nx = px / canvas.clientWidth * 2 - 1, ny = 1 - py / canvas.clientHeight * 2;
    if (view.ortho) {
      const o = add(view.eye, add(mul(view.r, nx * view.ortho[0]), mul(view.u, ny * view.ortho[1])));
      return { o, d: view.f };
    }
    const d = norm(add(view.f, add(mul(view.r, nx * view.t * view.aspect), mul(view.u, ny * view.t))));
    return { o: view.eye, d };
  }
  function hitBox(rr, b) {
    const [x, y, z, dx, dy, dz, h] = b;
    const c = Math.cos(-h), s = Math.sin(-h);
    const rot = (v) => [c * v[0] - s * v[1], s * v[0] + c * v[1], v[2]];
    const o = rot(sub(rr.o, [x, y, z])), d = rot(rr.d);
    let t0 = -Infinity, t1 = Infinity;
    const half = [dx / 2, dy / 2, dz / 2];
    for (let a = 0; a < 3; a++) {
      if (Math.abs(d[a]) < 1e-12) {
        if (Math.abs(o[a]) > half[a]) return null;
        continue;
      }
      let ta = (-half[a] - o[a]) / d[a], tb = (half[a] - o[a]) / d[a];
      if (ta > tb) [ta, tb] = [tb, ta];
      t0 = Math.max(t0, ta);
      t1 = Math.min(t1, tb);
    }
    return t1 >= Math.max(t0, 0) ? Math.max(t0, 0) : null;
  }

  // ---------------------------------------------------------------- state
  let cur = 0;
  let colorBy = scene.color;
  let selected = null; // { layer, index }
  let showLabels = true;
  let uploaded = -1;
  let dirty = false;
  const undoStack = [], redoStack = [];
  $('color').value = colorBy;
  $('frame').max = String(Math.max(frames.length - 1, 0));
  $('title').textContent = edit ? 'pi3det annotate' : 'pi3det view';
  if (edit) $('editTools').hidden = false;

  function visibleLayers() {
    const out = [];
    if ($('showGt').checked) out.push('gt');
    if ($('showDet').checked) out.push('det');
    return out;
  }
  function boxColor(layer, i) {
    if (selected && selected.layer === layer && selected.index === i) return [1, 1, 0.2];
    if (layer === 'gt') return edit ? [0.35, 0.6, 0.35] : [0.2, 0.95, 0.35];
    return edit ? [0.2, 0.85, 1] : [1, 0.45, 0.1];
  }

  let drawPending = false;
  function requestDraw() {
    if (drawPending) return;
    drawPending = true;
    requestAnimationFrame(() => {
      drawPending = false;
      draw();
    });
  }

  // Draws frame `cur`; returns what was submitted to GL.
  function draw() {
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(1, Math.round(canvas.clientWidth * dpr)), h = Math.max(1, Math.round(canvas.clientHeight * dpr));
    if (canvas.width !== w || canvas.height !== h) {
      canvas.width = w;
      canvas.height = h;
    }
    computeView();
    gl.viewport(0, 0, w, h);
    gl.clearColor(0.07, 0.07, 0.08, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    const pts = pointCache.get(cur);
    let nPoints = 0;
    if (pts) {
      if (uploaded !== cur) {
        gl.bindBuffer(gl.ARRAY_BUFFER, pointPos);
        gl.bufferData(gl.ARRAY_BUFFER, pts.xyz, gl.STATIC_DRAW);
        gl.bindBuffer(gl.ARRAY_BUFFER, pointVal);
        gl.bufferData(gl.ARRAY_BUFFER, pts.inten, gl.STATIC_DRAW);
        uploaded = cur;
      }
      gl.useProgram(pointProg);
      gl.uniformMatrix4fv(gl.getUniformLocation(pointProg, 'mvp'), false, view.mvp);
      gl.uniform1i(gl.getUniformLocation(pointProg, 'byIntensity'), colorBy === 'intensity' ? 1 : 0);
      gl.uniform2f(gl.getUniformLocation(pointProg, 'zr'), pts.zr[0], pts.zr[1]);
      gl.uniform1f(gl.getUniformLocation(pointProg, 'size'), Math.max(1.5, 2 * dpr));
      gl.bindVertexArray(pointVao);
      gl.drawArrays(gl.POINTS, 0, pts.n);
      nPoints = pts.n;
    }
    // Boxes: 12 edges and a heading tick from the centre to the front face.
    const pos = [], col = [];
    let nBoxes = 0;
    for (const layer of visibleLayers()) {
      layers[cur][layer].forEach((o, i) => {
        const c = boxColor(layer, i);
        const k = boxCorners(o.box);
        for (const [a, b] of EDGES) {
          pos.push(...k[a], ...k[b]);
          col.push(...c, ...c);
        }
        const front = mul(add(add(k[0], k[1]), add(k[4], k[5])), 0.25);
        pos.push(o.box[0], o.box[1], o.box[2], ...front);
        col.push(...c, ...c);
        nBoxes++;
      });
    }
    if (pos.length) {
      gl.bindBuffer(gl.ARRAY_BUFFER, linePos);
      gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(pos), gl.DYNAMIC_DRAW);
      gl.bindBuffer(gl.ARRAY_BUFFER, lineCol);
      gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(col), gl.DYNAMIC_DRAW);
      gl.useProgram(lineProg);
      gl.uniformMatrix4fv(gl.getUniformLocation(lineProg, 'mvp'), false, view.mvp);
      gl.bindVertexArray(lineVao);
      gl.disable(gl.DEPTH_TEST);
      gl.drawArrays(gl.LINES, 0, pos.length / 3);
    }
    gl.bindVertexArray(null);
    drawLabels();
    const err = gl.getError();
    if (err !== gl.NO_ERROR) throw new Error('WebGL error ' + err);
    return { nPoints, nBoxes, loaded: !!pts };
  }

  function drawLabels() {
    const host = $('labels');
    host.textContent = '';
    if (!showLabels) return;
    for (const layer of visibleLayers()) {
      layers[cur][layer].forEach((o, i) => {
        const b = o.box;
        const p = project([b[0], b[1], b[2] + b[5] / 2]);
        if (!p || p[0] < 0 || p[1] < 0 || p[0] > canvas.clientWidth || p[1] > canvas.clientHeight) return;
        const d = document.createElement('div');
        d.textContent = o.name + (o.score != null && layer === 'det' && !edit ? ' ' + o.score.toFixed(2) : '');
        const c = boxColor(layer, i).map((v) => Math.round(v * 255));
        d.style.color = `rgb(${c[0]},${c[1]},${c[2]})`;
        d.style.left = p[0] + 'px';
        d.style.top = p[1] + 'px';
        host.appendChild(d);
      });
    }
  }

  // Counts pixels that are not the background (a real check that something was drawn).
  function nonBlank() {
    const w = canvas.width, h = canvas.height;
    const px = new Uint8Array(w * h * 4);
    gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
    let n = 0;
    for (let i = 0; i < px.length; i += 4) if (Math.abs(px[i] - 18) > 6 || Math.abs(px[i + 1] - 18) > 6 || Math.abs(px[i + 2] - 20) > 6) n++;
    return n;
  }

  // Loads frame k, draws it synchronously and reports what was drawn.
  async function showFrame(k) {
    k = Math.max(0, Math.min(frames.length - 1, k));
    if (k !== cur) selected = null;
    cur = k;
    $('frame').value = String(k);
    $('frameLabel').textContent = `${k + 1}/${frames.length} · ${frames[k].id}`;
    setStatus({ state: 'loading' }, 'loading frame ' + frames[k].id + '…');
    await framePoints(k);
    if (cur !== k) return;
    const r = draw();
    setStatus({
      state: 'ok', frame: frames[k].id, frameIndex: k, frames: frames.length, points: r.nPoints, boxes: r.nBoxes,
      nonblank: nonBlank(), ms: Math.round(performance.now()), gl: 'webgl2',
    }, `${frames[k].id}: ${r.nPoints} points, ${r.nBoxes} boxes — H for help`);
    renderPanel();
  }

  // ---------------------------------------------------------------- panel
  const FIELDS = ['x', 'y', 'z', 'dx', 'dy', 'dz', 'heading'];
  function renderPanel() {
    const panel = $('panel');
    if (!selected || !layers[cur][selected.layer][selected.index]) {
      selected = null;
      panel.hidden = true;
      return;
    }
    const o = layers[cur][selected.layer][selected.index];
    const canEdit = edit && selected.layer === editable;
    panel.hidden = false;
    panel.textContent = '';
    const head = document.createElement('div');
    head.textContent = `${selected.layer === 'gt' ? 'ground truth' : edit ? 'label' : 'detection'} #${selected.index}`;
    panel.appendChild(head);
    const table = document.createElement('table');
    const row = (k, v, input) => {
      const tr = table.insertRow();
      tr.insertCell().textContent = k;
      const td = tr.insertCell();
      if (input) td.appendChild(input);
      else td.textContent = v;
    };
    const mk = (k, v, step) => {
      if (!canEdit) return null;
      const inp = document.createElement('input');
      inp.id = 'field-' + k;
      inp.value = v;
      if (step) {
        inp.type = 'number';
        inp.step = step;
      }
      inp.addEventListener('change', () => {
        const fields = {};
        fields[k] = step ? Number(inp.value) : inp.value;
        try {
          applyEdit({ op: 'set', fields });
        } catch (e) {
          inp.value = v;
          setStatus({}, 'edit refused: ' + e.message);
        }
      });
      return inp;
    };
    row('class', o.name, mk('name', o.name, null));
    if (o.score != null) row('score', o.score.toFixed(3));
    if (o.num_points != null) row('points', String(o.num_points));
    FIELDS.forEach((k, j) => row(k, o.box[j].toFixed(3), mk(k, o.box[j].toFixed(3), j === 6 ? '0.01' : '0.05')));
    panel.appendChild(table);
  }

  // ---------------------------------------------------------------- editing
  const copyObj = (o) => JSON.parse(JSON.stringify(o));
  function markDirty(v) {
    dirty = v;
    $('saveState').textContent = v ? 'unsaved changes' : '';
    $('saveState').className = v ? 'dirty' : '';
  }
  function finite(v, what) {
    if (typeof v !== 'number' || !Number.isFinite(v)) throw new Error(what + ' must be a finite number');
    return v;
  }
  // The one path every edit takes (keys, panel, buttons and the test hook):
  // op = { op: 'set'|'nudge'|'delete'|'add'|'class'|'copy_next', frame?, index?, fields?, name?, object? }.
  function applyEdit(op) {
    if (!edit) throw new Error('this page is read-only (use pi3det annotate to edit)');
    const k = op.frame == null ? cur : op.frame;
    if (!Number.isInteger(k) || k < 0 || k >= frames.length) throw new Error('no frame ' + k);
    const list = layers[k][editable];
    const idx = op.index != null ? op.index : selected && selected.layer === editable && k === cur ? selected.index : null;
    const needBox = () => {
      if (idx == null || !list[idx]) throw new Error('no box selected');
      return list[idx];
    };
    let target = k;
    let before = copyObj(list);
    let after = copyObj(list);
    let select = idx;
    switch (op.op) {
      case 'set':
      case 'nudge': {
        needBox();
        const o = after[idx];
        for (const [f, v] of Object.entries(op.fields || {})) {
          if (f === 'name') {
            if (typeof v !== 'string' || !v.trim()) throw new Error('class must be a non-empty string');
            o.name = v.trim();
            continue;
          }
          const j = FIELDS.indexOf(f);
          if (j < 0) throw new Error('unknown field ' + f);
          finite(v, f);
          o.box[j] = op.op === 'set' ? v : o.box[j] + v;
          if (j >= 3 && j <= 5) o.box[j] = Math.max(0.05, o.box[j]);
          delete o.num_points; // no longer counted for this box
        }
        break;
      }
      case 'class':
        needBox();
        if (typeof op.name !== 'string' || !op.name.trim()) throw new Error('class must be a non-empty string');
        after[idx].name = op.name.trim();
        break;
      case 'delete':
        needBox();
        after.splice(idx, 1);
        select = null;
        break;
      case 'add': {
        const t = cam.mode === 'follow' ? [10, 0, -1] : cam.target;
        const o = op.object ? copyObj(op.object) : { name: lastClass, box: [t[0], t[1], t[2], 3.9, 1.6, 1.56, 0] };
        if (!Array.isArray(o.box) || o.box.length !== 7) throw new Error('a box has 7 numbers');
        o.box.forEach((v, j) => finite(v, FIELDS[j]));
        after.push({ name: String(o.name || lastClass), box: o.box });
        select = after.length - 1;
        break;
      }
      case 'copy_next': {
        const o = copyObj(needBox());
        if (k + 1 >= frames.length) throw new Error('no next frame');
        target = k + 1;
        before = copyObj(layers[target][editable]);
        after = copyObj(before);
        delete o.num_points;
        after.push(o);
        select = null;
        break;
      }
      default:
        throw new Error('unknown edit ' + op.op);
    }
    if (op.op !== 'delete' && select != null && after[select]) lastClass = after[select].name;
    undoStack.push({ frame: target, before, sel: selected });
    redoStack.length = 0;
    layers[target][editable] = after;
    if (target === cur) selected = select == null ? null : { layer: editable, index: select };
    markDirty(true);
    afterEdit();
    return layers[target][editable].length;
  }
  let lastClass = 'Car';
  function afterEdit() {
    setStatus({ edits: undoStack.length });
    if (pointCache.has(cur)) {
      const r = draw();
      setStatus({ boxes: r.nBoxes });
    }
    renderPanel();
  }
  function undoRedo(from, to) {
    const e = from.pop();
    if (!e) return false;
    to.push({ frame: e.frame, before: copyObj(layers[e.frame][editable]), sel: selected });
    layers[e.frame][editable] = e.before;
    // Back to the selection of that moment (undoing an add selects the box selected before it).
    const sel = e.frame === cur && e.sel && e.sel.layer === editable && e.before[e.sel.index] ? e.sel : null;
    selected = sel;
    markDirty(true);
    afterEdit();
    return true;
  }
  async function save() {
    if (!edit) throw new Error('this page is read-only');
    const body = { frames: frames.map((f, k) => ({ frame_id: f.id, objects: layers[k][editable] })) };
    const r = await fetch('/api/save', { method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body) });
    const j = await r.json();
    if (!r.ok) {
      setStatus({ saveError: j.error || r.status }, 'save failed: ' + (j.error || r.status));
      throw new Error(j.error || 'HTTP ' + r.status);
    }
    markDirty(false);
    setStatus({ saved: j.version }, `saved label set version ${j.version}: ${j.files.join(', ')}`);
    return j;
  }
  window.addEventListener('beforeunload', (e) => {
    if (dirty) e.preventDefault();
  });

  // ---------------------------------------------------------------- input
  function select(layer, index) {
    selected = index == null ? null : { layer, index };
    draw();
    renderPanel();
  }
  function pick(px, py) {
    const rr = ray(px, py);
    let best = null;
    for (const layer of visibleLayers()) {
      layers[cur][layer].forEach((o, i) => {
        const t = hitBox(rr, o.box);
        // Editable boxes win over reference boxes at the same place.
        const score = t == null ? null : t - (layer === editable && edit ? 0.5 : 0);
        if (score != null && (!best || score < best.score)) best = { layer, index: i, score };
      });
    }
    select(best && best.layer, best ? best.index : null);
  }
  let drag = null;
  canvas.addEventListener('contextmenu', (e) => e.preventDefault());
  canvas.addEventListener('mousedown', (e) => {
    drag = { x: e.clientX, y: e.clientY, moved: false, pan: e.button === 2 || e.shiftKey };
  });
  window.addEventListener('mouseup', (e) => {
    if (drag && !drag.moved && e.target === canvas) pick(e.clientX, e.clientY);
    drag = null;
  });
  window.addEventListener('mousemove', (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    if (Math.abs(dx) + Math.abs(dy) > 2) drag.moved = true;
    drag.x = e.clientX;
    drag.y = e.clientY;
    if (drag.pan || cam.mode === 'bev' && !e.altKey) {
      const s = cam.dist * 0.0015 * (cam.mode === 'bev' ? 1.6 : 1);
      const r = [view.r[0], view.r[1], 0], u = cam.mode === 'bev' ? [view.u[0], view.u[1], 0] : [view.f[0], view.f[1], 0];
      cam.target = add(cam.target, add(mul(norm(r), -dx * s), mul(norm(u), dy * s)));
    } else if (cam.mode === 'follow') {
      cam.followYaw -= dx * 0.005;
    } else {
      cam.yaw -= dx * 0.005;
      cam.pitch = Math.max(-0.1, Math.min(1.55, cam.pitch + dy * 0.005));
    }
    requestDraw();
  });
  canvas.addEventListener('wheel', (e) => {
    e.preventDefault();
    cam.dist = Math.max(2, Math.min(500, cam.dist * Math.exp(e.deltaY * 0.001)));
    requestDraw();
  }, { passive: false });
  window.addEventListener('resize', requestDraw);

  function setCamera(mode) {
    cam.mode = mode;
    for (const m of ['orbit', 'bev', 'follow']) $('cam-' + m).classList.toggle('on', m === mode);
    requestDraw();
  }
  const tryEdit = (op) => {
    try {
      applyEdit(op);
    } catch (e) {
      setStatus({}, 'edit refused: ' + e.message);
    }
  };
  const SHORTCUTS = [
    ['Mouse drag', 'orbit (bird\'s-eye: pan; Shift or right drag: pan)'], ['Wheel', 'zoom'], ['Click', 'select a box and show its fields'],
    [', / .', 'previous / next frame'], ['1 / 2 / 3', 'orbit / bird\'s-eye / follow-the-sensor camera'],
    ['I', 'colour by height / intensity'], ['G', 'show / hide ground truth'],
    edit ? ['(checkbox)', 'show / hide the labels being edited'] : ['D', 'show / hide detections'], ['L', 'class labels on / off'],
    ['Tab / Shift+Tab', 'select next / previous box'], ['Esc', 'deselect, close help'], ['H or ?', 'this help'],
  ];
  const EDIT_SHORTCUTS = [
    ['W / S', 'move selected box +x / −x (0.1 m; Shift: 1 m)'], ['A / D', 'move +y / −y'], ['R / F', 'move up / down (z)'],
    ['Q / E', 'rotate heading +/− 1° (Shift: 10°)'], ['[ / ]', 'length dx −/+ 0.1 m'], ['; / \'', 'width dy −/+'],
    ['- / =', 'height dz −/+'], ['N', 'add a box at the view centre'], ['Delete / Backspace', 'delete the selected box'],
    ['K', 'change the class (edit field)'], ['C', 'copy the selected box to the next frame'],
    ['Ctrl+Z', 'undo'], ['Ctrl+Y / Ctrl+Shift+Z', 'redo'], ['Ctrl+S', 'save a new label set (never the original files)'],
  ];
  function buildHelp() {
    const h = $('help');
    const t = document.createElement('table');
    for (const [k, v] of SHORTCUTS.concat(edit ? EDIT_SHORTCUTS : [])) {
      const tr = t.insertRow();
      const kbd = document.createElement('kbd');
      kbd.textContent = k;
      tr.insertCell().appendChild(kbd);
      tr.insertCell().textContent = v;
    }
    const title = document.createElement('h3');
    title.textContent = edit ? 'pi3det annotate — shortcuts' : 'pi3det view — shortcuts';
    const legend = document.createElement('p');
    legend.textContent = edit
      ? 'Cyan: labels being edited; dim green: ground truth for reference; yellow: selected.'
      : 'Green: ground truth; orange: detections (with score); yellow: selected. Boxes show a heading tick.';
    h.append(title, legend, t);
  }
  buildHelp();
  const toggleHelp = (v) => ($('help').hidden = v === undefined ? !$('help').hidden : !v);

  window.addEventListener('keydown', (e) => {
    if (e.target instanceof HTMLInputElement && e.target.type !== 'range' && e.target.type !== 'checkbox' || e.target instanceof HTMLSelectElement) {
      if (e.key === 'Escape') e.target.blur();
      return;
    }
    const ctrl = e.ctrlKey || e.metaKey;
    const big = e.shiftKey ? 10 : 1;
    const cycle = (d) => {
      const layer = selected ? selected.layer : edit ? editable : visibleLayers()[0];
      if (!layer) return;
      const n = layers[cur][layer].length;
      if (!n) return;
      select(layer, selected ? (selected.index + d + n) % n : 0);
    };
    const nudge = (fields) => tryEdit({ op: 'nudge', fields });
    let handled = true;
    if (ctrl && e.code === 'KeyZ' && !e.shiftKey) edit && undoRedo(undoStack, redoStack);
    else if (ctrl && (e.code === 'KeyY' || e.code === 'KeyZ' && e.shiftKey)) edit && undoRedo(redoStack, undoStack);
    else if (ctrl && e.code === 'KeyS') edit && save().catch(() => {});
    else if (ctrl) handled = false;
    else if (e.key === ',') showFrame(cur - 1);
    else if (e.key === '.') showFrame(cur + 1);
    else if (e.key === '1') setCamera('orbit');
    else if (e.key === '2') setCamera('bev');
    else if (e.key === '3') setCamera('follow');
    else if (e.code === 'KeyI') {
      colorBy = colorBy === 'height' ? 'intensity' : 'height';
      $('color').value = colorBy;
      requestDraw();
    } else if (e.code === 'KeyG') {
      $('showGt').checked = !$('showGt').checked;
      requestDraw();
    } else if (e.code === 'KeyL') {
      showLabels = !showLabels;
      requestDraw();
    } else if (e.key === 'Tab') cycle(e.shiftKey ? -1 : 1);
    else if (e.key === 'Escape') {
      toggleHelp(false);
      select(null, null);
    } else if (e.code === 'KeyH' || e.key === '?') toggleHelp();
    else if (!edit && e.code === 'KeyD') {
      $('showDet').checked = !$('showDet').checked;
      requestDraw();
    } else if (!edit) handled = false;
    else if (e.code === 'KeyW') nudge({ x: 0.1 * big });
    else if (e.code === 'KeyS') nudge({ x: -0.1 * big });
    else if (e.code === 'KeyA') nudge({ y: 0.1 * big });
    else if (e.code === 'KeyD') nudge({ y: -0.1 * big });
    else if (e.code === 'KeyR') nudge({ z: 0.1 * big });
    else if (e.code === 'KeyF') nudge({ z: -0.1 * big });
    else if (e.code === 'KeyQ') nudge({ heading: Math.PI / 180 * big });
    else if (e.code === 'KeyE') nudge({ heading: -Math.PI / 180 * big });
    else if (e.code === 'BracketLeft') nudge({ dx: -0.1 });
    else if (e.code === 'BracketRight') nudge({ dx: 0.1 });
    else if (e.code === 'Semicolon') nudge({ dy: -0.1 });
    else if (e.code === 'Quote') nudge({ dy: 0.1 });
    else if (e.code === 'Minus') nudge({ dz: -0.1 });
    else if (e.code === 'Equal') nudge({ dz: 0.1 });
    else if (e.code === 'KeyN') tryEdit({ op: 'add' });
    else if (e.key === 'Delete' || e.key === 'Backspace') tryEdit({ op: 'delete' });
    else if (e.code === 'KeyC') tryEdit({ op: 'copy_next' });
    else if (e.code === 'KeyK') {
      const f = $('field-name');
      if (f) f.focus();
    } else handled = false;
    if (handled) e.preventDefault();
  });
  $('frame').addEventListener('input', () => showFrame(Number($('frame').value)));
  $('prev').addEventListener('click', () => showFrame(cur - 1));
  $('next').addEventListener('click', () => showFrame(cur + 1));
  for (const m of ['orbit', 'bev', 'follow']) $('cam-' + m).addEventListener('click', () => setCamera(m));
  $('color').addEventListener('change', () => {
    colorBy = $('color').value;
    requestDraw();
  });
  $('showGt').addEventListener('change', () => draw());
  $('showDet').addEventListener('change', () => draw());
  $('helpBtn').addEventListener('click', () => toggleHelp());
  $('add').addEventListener('click', () => tryEdit({ op: 'add' }));
  $('undo').addEventListener('click', () => undoRedo(undoStack, redoStack));
  $('redo').addEventListener('click', () => undoRedo(redoStack, undoStack));
  $('save').addEventListener('click', () => save().catch(() => {}));

  // The test hook: the same functions the keys and buttons call.
  window.pi3det = {
    scene, applyEdit, save, showFrame, select: (i) => select(editable, i),
    undo: () => undoRedo(undoStack, redoStack), redo: () => undoRedo(redoStack, undoStack),
    labels: (k) => copyObj(layers[k == null ? cur : k][editable]),
  };

  // ---------------------------------------------------------------- start
  async function start() {
    if (!frames.length) {
      fail('the scene has no frames');
      return;
    }
    if (edit) {
      const r = await fetch('/api/labels');
      if (!r.ok) throw new Error('labels: HTTP ' + r.status);
      const j = await r.json();
      j.frames.forEach((f, k) => {
        if (frames[k] && frames[k].id === f.frame_id) layers[k][editable] = f.objects;
      });
    }
    // ?camera=orbit|bev|follow&frame=K&help=1 pick the start (links, screenshots).
    const camParam = params.get('camera');
    setCamera(['orbit', 'bev', 'follow'].includes(camParam) ? camParam : 'orbit');
    if (params.get('help') === '1') toggleHelp(true);
    await showFrame(Number(params.get('frame')) || 0);
    // ?pick=1: click (the same path as the mouse) at the projected centre of the first box.
    if (params.get('pick') === '1') {
      const layer = visibleLayers().find((l) => layers[cur][l].length);
      const b = layer && layers[cur][layer][0].box;
      const p = b && project([b[0], b[1], b[2]]);
      if (p) pick(p[0], p[1]);
      setStatus({
        picked: selected ? selected.layer + ':' + selected.index : 'none',
        panel: $('panel').hidden ? '' : $('panel').textContent,
      });
    }
    // ?ops=[...]&save=1: apply edits and save once loaded (used by the browser tests).
    if (edit && params.has('ops')) {
      try {
        for (const op of JSON.parse(params.get('ops'))) {
          if (op.op === 'undo') undoRedo(undoStack, redoStack);
          else if (op.op === 'redo') undoRedo(redoStack, undoStack);
          else if (op.op === 'select') select(editable, op.index);
          else if (op.op === 'key') {
            // Through the keyboard handler, as a key press would.
            window.dispatchEvent(new KeyboardEvent('keydown', {
              code: op.code, key: op.key || '', shiftKey: !!op.shift, ctrlKey: !!op.ctrl, bubbles: true, cancelable: true,
            }));
          } else applyEdit(op);
        }
        if (params.get('save') === '1') await save();
        setStatus({ selftest: 'done' });
      } catch (e) {
        setStatus({ selftest: 'error: ' + e.message });
      }
    }
  }
  start().catch((e) => fail(String(e && e.message || e)));
})();
