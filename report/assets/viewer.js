// slshadow report page: the 3D view of deviations (three.js r111 + OrbitControls, embedded).
// The layers' data are base64 typed arrays in <script type="application/octet-stream"> blocks,
// described by the JSON block #slshadow-meta (report/html_report.cc). Colours are indices into
// the colour table written by the report (the heat map of the PNG charts); this script computes
// no figure, it only draws and reads back per-point values.
(function () {
  'use strict';
  var state = {ready: false, active: null, timings: {start_ms: performance.now()}, error: null};
  window.slshadow = state;
  var meta = JSON.parse(document.getElementById('slshadow-meta').textContent);
  var emptyMsg = document.getElementById('empty-msg');
  var pickBox = document.getElementById('pick');
  var canvas = document.getElementById('gl');
  var viewer = document.getElementById('viewer');

  function bytes(id) {
    var s = document.getElementById(id).textContent;
    if (typeof Uint8Array.fromBase64 === 'function') return Uint8Array.fromBase64(s);
    var bin = atob(s);
    var n = bin.length;
    var out = new Uint8Array(n);
    for (var i = 0; i < n; i++) out[i] = bin.charCodeAt(i);
    return out;
  }
  function say(text) {
    emptyMsg.textContent = text;
    emptyMsg.hidden = !text;
  }
  function markReady() {
    state.timings.ready_ms = performance.now();
    state.ready = true;
    document.documentElement.setAttribute('data-ready', '1');
  }

  // Clouds are decoded when first shown (the first one at once); meshes at once.
  var lut = meta.lut;
  var clouds = meta.clouds.map(function (c) {
    return {meta: c, n: c.shown, built: false, pos: null, object: null};
  });
  function decodeCloud(c) {
    var m = c.meta;
    c.q = new Uint16Array(bytes(m.blocks.pos).buffer);
    c.dev = new Float32Array(bytes(m.blocks.dev).buffer);
    c.uv = m.blocks.uv ? new Uint16Array(bytes(m.blocks.uv).buffer) : null;
    c.view = m.blocks.view ? new Uint16Array(bytes(m.blocks.view).buffer) : null;
  }
  var meshes = meta.meshes.map(function (m) {
    var q = new Uint16Array(bytes(m.blocks.vertices).buffer), v = new Float32Array(q.length);
    for (var i = 0; i < q.length; i++) v[i] = m.min[i % 3] + q[i] * m.step[i % 3];
    var ib = bytes(m.blocks.indices).buffer;
    return {meta: m, vertices: v, object: null,
            indices: m.index_bytes === 2 ? new Uint16Array(ib) : new Uint32Array(ib)};
  });

  // Centre of the view: the first non-empty cloud's box, else the first mesh's.
  var centre = [0, 0, 0];
  var first = clouds.filter(function (c) { return c.n > 0; })[0];
  if (first) {
    for (var a = 0; a < 3; a++) centre[a] = first.meta.min[a] + 32767.5 * first.meta.step[a];
  } else if (meshes.length && meshes[0].vertices.length) {
    var v = meshes[0].vertices, lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    for (var i = 0; i < v.length; i += 3) {
      for (var b = 0; b < 3; b++) { lo[b] = Math.min(lo[b], v[i + b]); hi[b] = Math.max(hi[b], v[i + b]); }
    }
    for (var c3 = 0; c3 < 3; c3++) centre[c3] = 0.5 * (lo[c3] + hi[c3]);
  }
  state.centre = centre;

  // The view's radius: the farthest box corner of the clouds (their boxes are in the meta data).
  var radius = 1e-3;
  clouds.forEach(function (c) {
    if (!c.n) return;
    for (var corner = 0; corner < 8; corner++) {
      var r2 = 0;
      for (var a = 0; a < 3; a++) {
        var t = c.meta.min[a] + ((corner >> a) & 1) * 65535 * c.meta.step[a] - centre[a];
        r2 += t * t;
      }
      radius = Math.max(radius, Math.sqrt(r2));
    }
  });
  meshes.forEach(function (m) {
    var v = m.vertices;
    for (var i = 0; i < v.length; i += 3) {
      v[i] -= centre[0]; v[i + 1] -= centre[1]; v[i + 2] -= centre[2];
      if (!first) radius = Math.max(radius, Math.sqrt(v[i] * v[i] + v[i + 1] * v[i + 1] + v[i + 2] * v[i + 2]));
    }
  });

  var renderer;
  try {
    renderer = new THREE.WebGLRenderer({canvas: canvas, antialias: true, preserveDrawingBuffer: true});
  } catch (e) {
    say('WebGL is not available in this browser, so the 3D view cannot be drawn; the tables and ' +
        'charts below are complete.');
    markReady();
    return;
  }
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  var scene = new THREE.Scene();
  scene.background = new THREE.Color(0x23272e);
  var camera = new THREE.PerspectiveCamera(35, 1, radius * 0.01, radius * 100);
  scene.add(camera);
  scene.add(new THREE.AmbientLight(0xffffff, 0.45));
  var headlight = new THREE.DirectionalLight(0xffffff, 0.7);
  headlight.position.set(0.3, -0.4, -1);
  camera.add(headlight);

  // Initial view: from the side of the frame's origin (where a scanner sits), y down as in a
  // camera image.
  var cl = Math.sqrt(centre[0] * centre[0] + centre[1] * centre[1] + centre[2] * centre[2]);
  var dir = cl > 1e-6 ? new THREE.Vector3(centre[0] / cl, centre[1] / cl, centre[2] / cl)
                      : new THREE.Vector3(0, 0, 1);
  var up = new THREE.Vector3(0, -1, 0);
  if (Math.abs(dir.dot(up)) > 0.95) up.set(0, 0, 1);
  camera.up.copy(up);
  camera.position.copy(dir.clone().multiplyScalar(-radius / Math.tan(17.5 * Math.PI / 180) * 1.1));
  camera.lookAt(0, 0, 0);
  var controls = new THREE.OrbitControls(camera, canvas);
  controls.target.set(0, 0, 0);
  controls.screenSpacePanning = true;
  controls.update();
  controls.saveState();

  var pointSize = 2;
  function buildCloud(c) {
    if (c.built || !c.n) return;
    c.built = true;
    decodeCloud(c);
    var n = c.n, q = c.q, m = c.meta, pos = new Float32Array(3 * n);
    var o0 = m.min[0] - centre[0], o1 = m.min[1] - centre[1], o2 = m.min[2] - centre[2];
    var s0 = m.step[0], s1 = m.step[1], s2 = m.step[2];
    for (var k0 = 0; k0 < n; k0++) {
      pos[3 * k0] = o0 + q[3 * k0] * s0;
      pos[3 * k0 + 1] = o1 + q[3 * k0 + 1] * s1;
      pos[3 * k0 + 2] = o2 + q[3 * k0 + 2] * s2;
    }
    c.pos = pos;
    var g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.BufferAttribute(c.pos, 3));
    // Colour: the index into the report's colour table, round(clamp((d - lo) / (hi - lo)) * 254),
    // the PNG maps' heat map over the layer's range.
    var col = new Uint8Array(3 * c.n), lo = c.meta.lo, span = c.meta.hi > lo ? c.meta.hi - lo : 1;
    for (var k = 0; k < c.n; k++) {
      var j = 3 * Math.round(Math.min(Math.max((c.dev[k] - lo) / span, 0), 1) * 254);
      col[3 * k] = lut[j]; col[3 * k + 1] = lut[j + 1]; col[3 * k + 2] = lut[j + 2];
    }
    g.setAttribute('color', new THREE.BufferAttribute(col, 3, true));
    g.computeBoundingSphere();
    c.material = new THREE.PointsMaterial({size: pointSize, sizeAttenuation: false,
                                           vertexColors: THREE.VertexColors});
    c.object = new THREE.Points(g, c.material);
    c.object.visible = false;
    scene.add(c.object);
  }
  meshes.forEach(function (m) {
    var g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.BufferAttribute(m.vertices, 3));
    g.setIndex(new THREE.BufferAttribute(m.indices, 1));
    g.computeVertexNormals();
    m.object = new THREE.Mesh(g, new THREE.MeshPhongMaterial({
      color: 0xc8ccd2, side: THREE.DoubleSide, transparent: true, opacity: 0.55, depthWrite: false}));
    m.object.visible = false;
    scene.add(m.object);
  });
  var marker = new THREE.Points(
      new THREE.BufferGeometry().setAttribute('position', new THREE.BufferAttribute(new Float32Array(3), 3)),
      new THREE.PointsMaterial({size: 11, sizeAttenuation: false, color: 0xffffff, depthTest: false}));
  marker.visible = false;
  marker.renderOrder = 10;
  scene.add(marker);

  var starting = true;  // one render at the end of start-up, not one per step
  function render() { if (!starting) renderer.render(scene, camera); }
  function resize() {
    var w = viewer.clientWidth, h = viewer.clientHeight;
    if (w < 1 || h < 1) return;
    renderer.setSize(w, h, false);
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
    render();
  }
  controls.addEventListener('change', render);

  function setCloud(id) {
    state.active = null;
    clouds.forEach(function (c) { if (c.meta.id === id) buildCloud(c); });
    clouds.forEach(function (c) {
      var on = c.meta.id === id;
      if (c.object) c.object.visible = on;
      if (on) state.active = c;
    });
    document.querySelectorAll('.cbar').forEach(function (el) {
      el.hidden = el.getAttribute('data-layer') !== id;
    });
    var c = state.active;
    say(c && !c.n ? c.meta.empty_reason : (clouds.length || meshes.length ? '' : 'This result has no cloud to show.'));
    marker.visible = false;
    pickBox.hidden = true;
    render();
  }
  function setMesh(id, on) {
    meshes.forEach(function (m) { if (m.meta.id === id) m.object.visible = on; });
    render();
  }

  function fmt(x, digits) { return isFinite(x) ? Number(x).toPrecision(digits) : String(x); }
  // The point under canvas pixel (px, py) (CSS px): of the points within 8 px, the nearest one
  // to the viewer among those within 3 px, else the nearest on screen.
  function pick(px, py) {
    var c = state.active;
    if (!c || !c.n) return null;
    camera.updateMatrixWorld();
    var m = new THREE.Matrix4().multiplyMatrices(camera.projectionMatrix, camera.matrixWorldInverse).elements;
    var w = canvas.clientWidth, h = canvas.clientHeight, p = c.pos;
    var bestNear = -1, bestNearZ = Infinity, best = -1, bestD = 64;
    for (var k = 0; k < c.n; k++) {
      var x = p[3 * k], y = p[3 * k + 1], z = p[3 * k + 2];
      var cw = m[3] * x + m[7] * y + m[11] * z + m[15];
      if (cw <= 0) continue;
      var sx = ((m[0] * x + m[4] * y + m[8] * z + m[12]) / cw * 0.5 + 0.5) * w;
      var sy = (0.5 - (m[1] * x + m[5] * y + m[9] * z + m[13]) / cw * 0.5) * h;
      var d = (sx - px) * (sx - px) + (sy - py) * (sy - py);
      if (d > 64) continue;
      if (d < bestD) { bestD = d; best = k; }
      if (d <= 9 && cw < bestNearZ) { bestNearZ = cw; bestNear = k; }
    }
    var k2 = bestNear >= 0 ? bestNear : best;
    if (k2 < 0) return null;
    var r = {index: k2, deviation_mm: c.dev[k2], field: c.meta.field,
             position_mm: [p[3 * k2] + centre[0], p[3 * k2 + 1] + centre[1], p[3 * k2 + 2] + centre[2]]};
    if (c.uv && c.uv[2 * k2] !== 65535 && c.uv[2 * k2 + 1] !== 65535)
      r.pixel = [c.uv[2 * k2] / 8, c.uv[2 * k2 + 1] / 8];
    if (c.view) r.view = c.view[k2];
    return r;
  }
  function showPick(r) {
    if (!r) { pickBox.hidden = true; marker.visible = false; render(); return; }
    var lines = [state.active.meta.field + ': ' + (r.deviation_mm >= 0 ? '+' : '') + fmt(r.deviation_mm, 5) + ' mm'];
    if (r.pixel) lines.push('camera pixel (u, v): ' + r.pixel[0].toFixed(3) + ', ' + r.pixel[1].toFixed(3) + ' px');
    var names = state.active.meta.view_names;
    if (r.view !== undefined)
      lines.push('view: ' + (names && names[r.view] !== undefined ? names[r.view] + ' (' + r.view + ')' : r.view));
    lines.push('x, y, z: ' + r.position_mm.map(function (t) { return t.toFixed(3); }).join(', ') + ' mm');
    pickBox.textContent = lines.join('\n');
    pickBox.hidden = false;
    var a = marker.geometry.attributes.position;
    a.array[0] = state.active.pos[3 * r.index];
    a.array[1] = state.active.pos[3 * r.index + 1];
    a.array[2] = state.active.pos[3 * r.index + 2];
    a.needsUpdate = true;
    marker.visible = true;
    render();
  }
  var down = null;
  canvas.addEventListener('mousedown', function (e) { down = [e.clientX, e.clientY]; });
  canvas.addEventListener('mouseup', function (e) {
    if (!down || Math.abs(e.clientX - down[0]) + Math.abs(e.clientY - down[1]) > 3) return;
    var rect = canvas.getBoundingClientRect();
    state.lastPick = pick(e.clientX - rect.left, e.clientY - rect.top);
    showPick(state.lastPick);
  });

  document.querySelectorAll('input[name=cloud]').forEach(function (el) {
    el.addEventListener('change', function () { if (el.checked) setCloud(el.value); });
  });
  document.querySelectorAll('input[name=mesh]').forEach(function (el) {
    el.addEventListener('change', function () { setMesh(el.value, el.checked); });
  });
  document.getElementById('point-size').addEventListener('input', function (e) {
    pointSize = Number(e.target.value);
    clouds.forEach(function (c) { if (c.material) c.material.size = pointSize; });
    render();
  });
  document.getElementById('reset').addEventListener('click', function () { controls.reset(); render(); });

  state.pick = pick;
  state.setCloud = setCloud;
  state.setMesh = setMesh;
  state.render = render;
  state.camera = camera;
  state.controls = controls;
  setCloud(clouds.length ? clouds[0].meta.id : null);
  state.timings.built_ms = performance.now();  // first cloud decoded and drawn once
  if (typeof ResizeObserver !== 'undefined') new ResizeObserver(resize).observe(viewer);
  resize();
  starting = false;
  render();
  requestAnimationFrame(markReady);
})();
