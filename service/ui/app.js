// spokemesh's page: lists the stored point sets, uploads new ones, and draws a set's
// points, one seed's star and Voronoi cell, the whole mesh, or clipped cells coloured
// by volume. Plain JavaScript over the REST API (the same routes every client uses);
// three.js (Debian's libjs-three, served by the server) draws. No inline script: the
// page runs under a Content-Security-Policy that allows only this origin's files.
//
// The bearer token, when the server asks for one, lives in this tab's sessionStorage
// and is sent only as an Authorization header, never in a URL.
'use strict';

(() => {
  // Sizes the page draws whole: beyond these it says so and offers per-seed views.
  const MESH_LIMIT = 50000;   // points, for the whole mesh's edges
  const CELLS_LIMIT = 20000;  // points, for every clipped cell at once
  const TOKEN_KEY = 'spokemesh-token';

  const { $, el } = window.spokemeshDom;
  const { parseText, parseNpy } = window.spokemeshPointFiles;  // point_files.js: the core's rule
  const state = {
    token: sessionStorage.getItem(TOKEN_KEY) || '',
    set: null,           // the chosen set's info (id, count, dimension, ...)
    coords: null,        // Float32Array, n * d, as fetched from .../points?dtype=float32
    axes: [0, 1, 2],     // the coordinates drawn as x, y, z (z = -1: a 2-d view)
    mode: 'points',
    seed: null,
    loadToken: 0,        // increases on each set change, so late answers are dropped
    timing: {},          // performance.now() marks of the first view (bench/ui.py reads them)
    domain: null,        // a domain of any shape: { format, bytes, info (POST /v1/domains:check) }
  };

  // ---- the REST API -----------------------------------------------------------

  class ApiError extends Error {
    constructor(status, message) { super(message); this.status = status; }
  }

  function authHeaders(extra) {
    const headers = new Headers(extra || {});
    if (state.token) headers.set('Authorization', 'Bearer ' + state.token);
    return headers;
  }

  async function errorOf(response) {
    let message = response.status + ' ' + response.statusText;
    try {
      const body = await response.json();
      if (body && body.error && body.error.message) message = body.error.message;
    } catch (e) { /* not JSON: keep the status line */ }
    if (response.status === 401) showAuth(message);
    return new ApiError(response.status, message);
  }

  async function api(path, options) {
    const o = Object.assign({ cache: 'no-store' }, options || {});
    o.headers = authHeaders(o.headers);
    const response = await fetch(path, o);
    if (!response.ok) throw await errorOf(response);
    return response;
  }

  async function apiJson(path, options) { return (await api(path, options)).json(); }

  const setPath = (id) => '/v1/pointsets/' + encodeURIComponent(id);

  // Reads a streamed body chunk by chunk; onChunk(Uint8Array) for each.
  async function readStream(response, onChunk) {
    const reader = response.body.getReader();
    for (;;) {
      const { done, value } = await reader.read();
      if (done) return;
      onChunk(value);
    }
  }

  // NDJSON lines as they arrive: onLine(object) for each; a server-side failure after
  // the stream began arrives as a last {"error": ...} line and is thrown.
  async function readLines(response, onLine) {
    const decoder = new TextDecoder();
    let rest = '';
    const take = (text) => {
      const lines = (rest + text).split('\n');
      rest = lines.pop();
      for (const line of lines) {
        if (!line) continue;
        const value = JSON.parse(line);
        if (value && value.error) throw new ApiError(value.error.code, value.error.message);
        onLine(value);
      }
    };
    await readStream(response, (chunk) => take(decoder.decode(chunk, { stream: true })));
    take(decoder.decode() + '\n');
  }

  // ---- small helpers -------------------------------------------------------------

  function bytesText(b) {
    if (b < 1024) return b + ' B';
    if (b < 1 << 20) return (b / 1024).toFixed(1) + ' KiB';
    if (b < 1 << 30) return (b / (1 << 20)).toFixed(1) + ' MiB';
    return (b / (1 << 30)).toFixed(2) + ' GiB';
  }
  // Six significant digits, trailing zeros of a fraction dropped (100000 stays 100000).
  function num(x) {
    if (x === null || x === undefined) return '—';
    const t = Number(x).toPrecision(6);
    return t.includes('.') ? t.replace(/0+(e|$)/, '$1').replace(/\.(e|$)/, '$1') : t;
  }
  // A box coordinate: enough digits that rounding cannot move a wall across a point.
  const boxText = (v) => String(Number(v.toPrecision(15)));
  function status(id, text, isError) {
    const node = $(id);
    node.textContent = text;
    node.classList.toggle('error', !!isError);
  }
  function progress(id, fraction) {
    const bar = $(id);
    if (fraction === null) { bar.hidden = true; return; }
    bar.hidden = false;
    bar.value = Math.max(0, Math.min(1, fraction));
  }

  // ---- token ----------------------------------------------------------------------

  function showAuth(message) {
    $('auth').hidden = false;
    status('sets-status', message + ' — give the token above.', true);
    $('token').focus();
  }

  $('auth-form').addEventListener('submit', (event) => {
    event.preventDefault();
    state.token = $('token').value.trim();
    if (state.token) sessionStorage.setItem(TOKEN_KEY, state.token); else sessionStorage.removeItem(TOKEN_KEY);
    $('token').value = '';
    $('auth').hidden = true;
    refreshSets().then(openFromHash);
  });

  // ---- the list of sets -------------------------------------------------------------

  async function refreshSets() {
    status('sets-status', 'loading…');
    const body = $('set-table').tBodies[0];
    try {
      const sets = [];
      let token = '';
      do {
        const page = await apiJson('/v1/pointsets?page_size=1000' + (token ? '&page_token=' + encodeURIComponent(token) : ''));
        sets.push(...page.point_sets);
        token = page.next_page_token;
      } while (token);
      body.replaceChildren();
      for (const info of sets) {
        const bytes = info.count * info.dimension * 8 + (info.weighted ? info.count * 8 : 0);
        const tags = [info.weighted ? 'weighted' : '', info.periodic_box ? 'periodic' : ''].filter(Boolean).join(', ');
        const row = el('tr', { 'data-id': info.id },
          el('td', { text: info.display_name || '—' }),
          el('td', { class: 'id', text: info.id.slice(0, 10), title: info.id }),
          el('td', { class: 'num', text: String(info.count) }),
          el('td', { class: 'num', text: String(info.dimension) }),
          el('td', { class: 'num', text: bytesText(bytes) }),
          el('td', { class: 'muted', text: tags }));
        row.addEventListener('click', () => openSet(info));
        if (state.set && state.set.id === info.id) row.classList.add('chosen');
        body.append(row);
      }
      status('sets-status', sets.length ? sets.length + ' point set' + (sets.length > 1 ? 's' : '') :
        'No point sets yet: upload one.');
    } catch (e) {
      if (e.status !== 401) status('sets-status', 'Could not list point sets: ' + e.message, true);
    }
  }
  $('refresh').addEventListener('click', refreshSets);

  // ---- upload -------------------------------------------------------------------------

  async function uploadFile(file) {
    status('upload-status', 'reading ' + file.name + '…');
    progress('upload-progress', 0);
    let parsed;
    try {
      parsed = file.name.toLowerCase().endsWith('.npy') ? parseNpy(await file.arrayBuffer()) : parseText(await file.text());
    } catch (e) {
      progress('upload-progress', null);
      status('upload-status', file.name + ': ' + e.message, true);
      return;
    }
    const name = file.name.replace(/\.[^.]*$/, '');
    const url = '/v1/pointsets?dimension=' + parsed.d + '&display_name=' + encodeURIComponent(name);
    status('upload-status', 'uploading ' + parsed.n + ' points (d = ' + parsed.d + ')…');
    // XMLHttpRequest: fetch() cannot report upload progress.
    const xhr = new XMLHttpRequest();
    xhr.open('POST', url);
    xhr.setRequestHeader('Content-Type', 'application/octet-stream');
    if (state.token) xhr.setRequestHeader('Authorization', 'Bearer ' + state.token);
    xhr.upload.onprogress = (e) => { if (e.lengthComputable) progress('upload-progress', e.loaded / e.total); };
    xhr.onerror = () => { progress('upload-progress', null); status('upload-status', 'upload failed: the connection broke', true); };
    xhr.onload = async () => {
      progress('upload-progress', null);
      let body = null;
      try { body = JSON.parse(xhr.responseText); } catch (e) { /* keep null */ }
      if (xhr.status !== 200 && xhr.status !== 201) {
        const message = body && body.error ? body.error.message : xhr.status + ' ' + xhr.statusText;
        if (xhr.status === 401) showAuth(message);
        status('upload-status', file.name + ': ' + message, true);
        return;
      }
      status('upload-status', (body.already_existed ? 'already stored: ' : 'stored: ') + body.id.slice(0, 12) + '…');
      await refreshSets();
      openSet(body);
    };
    xhr.send(parsed.values.buffer);
  }

  const drop = $('drop');
  drop.addEventListener('dragover', (e) => { e.preventDefault(); drop.classList.add('over'); });
  drop.addEventListener('dragleave', () => drop.classList.remove('over'));
  drop.addEventListener('drop', (e) => {
    e.preventDefault();
    drop.classList.remove('over');
    if (e.dataTransfer.files.length) uploadFile(e.dataTransfer.files[0]);
  });
  $('file').addEventListener('change', (e) => {
    if (e.target.files.length) uploadFile(e.target.files[0]);
    e.target.value = '';
  });

  // ---- drawing ------------------------------------------------------------------------

  const view = { ready: false };
  const COLORS = { points: 0x4a5560, faded: 0xc5cbd1, seed: 0xd62728, neighbor: 0xff7f0e, star: 0x1f6feb, centre: 0x2ca02c,
    cell: 0x9467bd, box: 0x999999, mesh: 0x1f6feb, wall: 0x555555 };

  function setupRenderer() {
    if (view.ready) return true;
    if (typeof THREE === 'undefined' || typeof THREE.OrbitControls === 'undefined') {
      status('view-status', 'This server has no three.js to draw with (install Debian\'s libjs-three on it, or start it ' +
        'with --ui-three-dir). The lists and numbers still work.', true);
      return false;
    }
    const holder = $('canvas-holder');
    // Antialiasing costs about a second to set up in software WebGL: skipped when the
    // first set drawn is large, where the first view's time matters most.
    view.renderer = new THREE.WebGLRenderer({ antialias: !state.set || state.set.count <= 200000 });
    view.renderer.setPixelRatio(window.devicePixelRatio || 1);
    view.renderer.setClearColor(0xffffff);
    holder.append(view.renderer.domElement);
    view.scene = new THREE.Scene();
    // points: the set; overlay: the whole mesh or all cells; seed: one seed's star and cell.
    view.layers = { points: new THREE.Group(), overlay: new THREE.Group(), seed: new THREE.Group() };
    view.scene.add(view.layers.points, view.layers.overlay, view.layers.seed);
    view.raycaster = new THREE.Raycaster();
    new ResizeObserver(resize).observe(holder);
    let down = null;
    view.renderer.domElement.addEventListener('pointerdown', (e) => { down = [e.clientX, e.clientY]; });
    view.renderer.domElement.addEventListener('pointerup', (e) => {
      if (down && Math.hypot(e.clientX - down[0], e.clientY - down[1]) < 5) pick(e);
      down = null;
    });
    view.ready = true;
    return true;
  }

  function resize() {
    const holder = $('canvas-holder');
    const w = Math.max(1, holder.clientWidth), h = Math.max(1, holder.clientHeight);
    view.renderer.setSize(w, h, false);
    if (view.camera) {
      if (view.camera.isOrthographicCamera) {
        const a = w / h;
        view.camera.left = -1.1 * a; view.camera.right = 1.1 * a; view.camera.top = 1.1; view.camera.bottom = -1.1;
      } else {
        view.camera.aspect = w / h;
      }
      view.camera.updateProjectionMatrix();
    }
    render();
  }

  // Drawing is coalesced to one frame per display refresh: a million points take a while
  // to draw in software, and resizes, control events and new layers come in bursts.
  let renderPending = false;
  function render() {
    if (renderPending) return;
    renderPending = true;
    requestAnimationFrame(() => {
      renderPending = false;
      if (!view.ready || !view.camera) return;
      view.renderer.render(view.scene, view.camera);
      if (state.coords && state.timing.fetched && !state.timing.firstFrame && view.pointsObject) {
        view.renderer.getContext().finish();  // the first frame's time includes the drawing itself
        state.timing.firstFrame = performance.now();
        document.body.dataset.firstFrame = 'true';
      }
    });
  }

  const drawn3d = () => state.axes[2] >= 0;

  // The camera and controls for a 2-d (orthographic, pan and zoom) or 3-d (orbit) view.
  function setupCamera() {
    if (view.controls) view.controls.dispose();
    const holder = $('canvas-holder');
    const a = Math.max(1, holder.clientWidth) / Math.max(1, holder.clientHeight);
    if (drawn3d()) {
      view.camera = new THREE.PerspectiveCamera(40, a, 0.001, 100);
      view.camera.position.set(2.2, 1.6, 3.6);
    } else {
      view.camera = new THREE.OrthographicCamera(-1.1 * a, 1.1 * a, 1.1, -1.1, -10, 10);
      view.camera.position.set(0, 0, 5);
    }
    view.controls = new THREE.OrbitControls(view.camera, view.renderer.domElement);
    view.controls.screenSpacePanning = true;
    if (!drawn3d()) {
      view.controls.enableRotate = false;
      view.controls.mouseButtons = { LEFT: THREE.MOUSE.PAN, MIDDLE: THREE.MOUSE.DOLLY, RIGHT: THREE.MOUSE.PAN };
    }
    view.controls.addEventListener('change', render);
    resize();
  }

  // Set coordinates -> world: the drawn axes, centred on the set's bounding box and
  // scaled to about [-1, 1] (float32 positions then keep their precision).
  function computeFrame() {
    const { coords } = state;
    const d = state.set.dimension, n = state.set.count;
    const lo = new Array(d).fill(Infinity), hi = new Array(d).fill(-Infinity);
    for (let i = 0; i < n; ++i) {
      for (let k = 0; k < d; ++k) {
        const v = coords[i * d + k];
        if (v < lo[k]) lo[k] = v;
        if (v > hi[k]) hi[k] = v;
      }
    }
    state.lo = lo; state.hi = hi;
    let extent = 0;
    for (const k of state.axes) if (k >= 0) extent = Math.max(extent, hi[k] - lo[k]);
    state.scale = extent > 0 ? 2 / extent : 1;
    state.centre = lo.map((l, k) => (l + hi[k]) / 2);
  }

  // One point (any array-like of d numbers) -> [x, y, z] in the world.
  function toWorld(p, out, at) {
    for (let j = 0; j < 3; ++j) {
      const k = state.axes[j];
      out[at + j] = k >= 0 ? (p[k] - state.centre[k]) * state.scale : 0;
    }
  }

  function pointOf(i) { const d = state.set.dimension; return state.coords.subarray(i * d, i * d + d); }

  // A point's image: points[i] + offset * box length (periodic sets), else points[i].
  function imageOf(i, offset) {
    const p = Array.from(pointOf(i));
    if (offset && state.set.periodic_box) {
      const d = state.set.dimension, box = state.set.periodic_box;
      for (let k = 0; k < d; ++k) p[k] += offset[k] * (box[d + k] - box[k]);
    }
    return p;
  }

  function clearLayer(layer) {
    for (const child of [...layer.children]) {
      layer.remove(child);
      if (child.geometry) child.geometry.dispose();
      if (child.material) child.material.dispose();
    }
  }

  function pointsObject(positions, color, size) {
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.BufferAttribute(positions, 3));
    return new THREE.Points(g, new THREE.PointsMaterial({ color, size, sizeAttenuation: false }));
  }
  function segmentsObject(positions, color, opacity, colors) {
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.BufferAttribute(positions, 3));
    if (colors) g.setAttribute('color', new THREE.BufferAttribute(colors, 3));
    return new THREE.LineSegments(g, new THREE.LineBasicMaterial({ color: colors ? 0xffffff : color,
      vertexColors: !!colors, transparent: opacity < 1, opacity }));
  }

  // ---- a domain of any shape --------------------------------------------------------

  // The domain's walls (its faces, as checked by the server): 2-d ring edges as lines,
  // 3-d triangles as a faint surface with its edges.
  function domainWalls(layer) {
    const info = state.domain && state.domain.info;
    if (!info || info.dimension !== state.set.dimension) return;
    const w = info.vertices.map((p) => { const q = [0, 0, 0]; toWorld(p, q, 0); return q; });
    const edges = [], tri = [];
    for (const f of info.faces) {
      if (f.length === 2) { edges.push(...w[f[0]], ...w[f[1]]); continue; }
      tri.push(...w[f[0]], ...w[f[1]], ...w[f[2]]);
      edges.push(...w[f[0]], ...w[f[1]], ...w[f[1]], ...w[f[2]], ...w[f[2]], ...w[f[0]]);
    }
    if (tri.length) layer.add(meshObject(new Float32Array(tri), null, COLORS.wall, 0.12));
    layer.add(segmentsObject(new Float32Array(edges), COLORS.wall, tri.length ? 0.25 : 1));
  }

  // The segments and wall pieces of a cell in a domain of any shape: in 2-d every facet
  // is segments (vertex pairs); in 3-d a wall facet is a loop on the wall (filled), and a
  // neighbour facet of a cell the walls cut is its outline as segments (of a cell inside,
  // its convex loop).
  function shapeCellGeometry(cell, tri, edges, interior = true) {
    const verts = cell.vertices.map((p) => { const w = [0, 0, 0]; toWorld(p, w, 0); return w; });
    if (!verts.length) return;
    const cut = cell.facets.some((f) => f.wall !== undefined);
    for (const f of cell.facets) {
      const v = f.vertices;
      if (state.set.dimension === 2 || (cut && f.wall === undefined)) {
        if (state.set.dimension === 3 && !interior) continue;
        for (let i = 0; i + 1 < v.length; i += 2) edges.push(...verts[v[i]], ...verts[v[i + 1]]);
        continue;
      }
      if (f.wall === undefined && !interior) continue;
      for (let i = 0; i < v.length; ++i) edges.push(...verts[v[i]], ...verts[v[(i + 1) % v.length]]);
      if (f.wall !== undefined) for (let i = 1; i + 1 < v.length; ++i) tri.push(...verts[v[0]], ...verts[v[i]], ...verts[v[i + 1]]);
    }
  }

  // A cell request: GET with the clip box, or POST with the domain file.
  function cellRequest(path, query) {
    if (state.domain) {
      return api(path + '?' + (query ? query + '&' : '') + 'domain=' + state.domain.format,
        { method: 'POST', body: state.domain.bytes, headers: { 'Content-Type': 'application/octet-stream' } });
    }
    const box = clipBox();
    const q = [query, box ? 'box=' + box.join(',') : ''].filter(Boolean).join('&');
    return api(path + (q ? '?' + q : ''));
  }

  const DOMAIN_FORMATS = { off: 'off', obj: 'obj', stl: 'stl', rings: 'rings', geojson: 'geojson', json: 'geojson' };
  async function chooseDomain(file) {
    const ext = (file.name.split('.').pop() || '').toLowerCase();
    const format = DOMAIN_FORMATS[ext] || 'rings';
    $('domain-info').className = 'muted';
    $('domain-info').textContent = 'checking ' + file.name + '…';
    try {
      const bytes = await file.arrayBuffer();
      const info = await apiJson('/v1/domains:check?domain=' + format,
        { method: 'POST', body: bytes, headers: { 'Content-Type': 'application/octet-stream' } });
      state.domain = { format, bytes, info, name: file.name };
      $('domain-info').textContent = info.description.replace(/ from .*$/, '') + ', volume ' + num(info.volume);
      $('domain-info').title = file.name;
      $('box').disabled = true;
    } catch (e) {
      state.domain = null;
      $('domain-info').className = 'error';
      $('domain-info').textContent = file.name + ': ' + e.message;
      if (state.set) $('box').disabled = !!state.set.periodic_box;
    }
    if (state.set && state.coords) {
      redraw();
      if (state.seed !== null) selectSeed(state.seed);
    }
  }

  function drawPoints() {
    if (!setupRenderer()) return;
    const n = state.set.count, d = state.set.dimension, coords = state.coords;
    const positions = new Float32Array(n * 3);
    for (let j = 0; j < 3; ++j) {  // axis by axis: no per-point objects for a million points
      const k = state.axes[j];
      if (k < 0) continue;
      const c = state.centre[k], s = state.scale;
      for (let i = 0; i < n; ++i) positions[3 * i + j] = (coords[i * d + k] - c) * s;
    }
    clearLayer(view.layers.points);
    const size = n > 200000 ? 1.5 : n > 20000 ? 2.5 : 4;
    view.pointsObject = pointsObject(positions, COLORS.points, size);
    view.layers.points.add(view.pointsObject);
    if (!state.timing.built) state.timing.built = performance.now();
    render();
  }

  // The box outline (2-d rectangle or 3-d box) of lo_1..lo_d, hi_1..hi_d.
  function boxOutline(box, color) {
    const d = state.set.dimension;
    if (d > 3 || box.length !== 2 * d) return null;
    const corners = [];
    for (let mask = 0; mask < 1 << d; ++mask) {
      const p = [];
      for (let k = 0; k < d; ++k) p.push(mask & (1 << k) ? box[d + k] : box[k]);
      corners.push(p);
    }
    const out = [];
    for (let a = 0; a < corners.length; ++a) {
      for (let k = 0; k < d; ++k) {
        const b = a | (1 << k);
        if (b !== a) { const w = new Float32Array(6); toWorld(corners[a], w, 0); toWorld(corners[b], w, 3); out.push(...w); }
      }
    }
    return segmentsObject(new Float32Array(out), color, 0.8);
  }

  // A convex polygon's vertices (world coordinates) ordered around their mean, for a
  // triangle fan: the facets of a convex cell come as unordered vertex sets.
  function orderAround(points3, normal) {
    const m = [0, 0, 0];
    for (const p of points3) for (let j = 0; j < 3; ++j) m[j] += p[j] / points3.length;
    const nrm = new THREE.Vector3(...normal).normalize();
    const u = new THREE.Vector3(1, 0, 0);
    if (Math.abs(nrm.x) > 0.9) u.set(0, 1, 0);
    u.sub(nrm.clone().multiplyScalar(u.dot(nrm))).normalize();
    const v = nrm.clone().cross(u);
    const angle = (p) => { const q = new THREE.Vector3(p[0] - m[0], p[1] - m[1], p[2] - m[2]); return Math.atan2(q.dot(v), q.dot(u)); };
    return { centre: m, ordered: [...points3].sort((a, b) => angle(a) - angle(b)) };
  }

  // Triangles (and edges) of one cell, in world coordinates, pushed onto tri / edges.
  // shrink < 1 pulls the drawing toward the cell's centroid (whole-set views).
  function cellGeometry(cell, shrink, tri, edges) {
    const d = state.set.dimension;
    const verts = cell.vertices.map((p) => { const w = [0, 0, 0]; toWorld(p, w, 0); return w; });
    if (!verts.length) return;
    const c = [0, 0, 0];
    for (const p of verts) for (let j = 0; j < 3; ++j) c[j] += p[j] / verts.length;
    const pull = (p) => p.map((x, j) => c[j] + (x - c[j]) * shrink);
    if (d === 2) {
      const { ordered } = orderAround(verts, [0, 0, 1]);
      const o = ordered.map(pull);
      for (let i = 0; i < o.length; ++i) {
        const a = o[i], b = o[(i + 1) % o.length];
        tri.push(...c, ...a, ...b);
      }
      for (const f of cell.facets) if (f.vertices.length === 2) edges.push(...pull(verts[f.vertices[0]]), ...pull(verts[f.vertices[1]]));
      return;
    }
    for (const f of cell.facets) {
      if (f.vertices.length < 3) continue;
      const normal = f.normal ? state.axes.map((k) => f.normal[k]) : [0, 0, 1];
      const { centre, ordered } = orderAround(f.vertices.map((i) => verts[i]), normal);
      const o = ordered.map(pull), m = pull(centre);
      for (let i = 0; i < o.length; ++i) {
        tri.push(...m, ...o[i], ...o[(i + 1) % o.length]);
        edges.push(...o[i], ...o[(i + 1) % o.length]);
      }
    }
  }

  function meshObject(positions, colors, color, opacity) {
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.BufferAttribute(positions, 3));
    if (colors) g.setAttribute('color', new THREE.BufferAttribute(colors, 3));
    return new THREE.Mesh(g, new THREE.MeshBasicMaterial({ color: colors ? 0xffffff : color, vertexColors: !!colors,
      transparent: opacity < 1, opacity, side: THREE.DoubleSide, depthWrite: opacity >= 1 }));
  }

  // ---- opening a set --------------------------------------------------------------------

  function setupProjection() {
    const d = state.set.dimension;
    state.axes = d === 2 ? [0, 1, -1] : [0, 1, 2];
    const show = d > 3;
    $('projection').hidden = !show;
    if (!show) return;
    for (const [j, id] of ['axis-x', 'axis-y', 'axis-z'].entries()) {
      const select = $(id);
      select.replaceChildren();
      if (j === 2) select.append(el('option', { value: '-1', text: 'none (2-d)' }));
      for (let k = 0; k < d; ++k) select.append(el('option', { value: String(k), text: 'x' + (k + 1) }));
      select.value = String(state.axes[j]);
    }
  }
  for (const [j, id] of ['axis-x', 'axis-y', 'axis-z'].entries()) {
    $(id).addEventListener('change', () => {
      state.axes[j] = Number($(id).value);
      computeFrame();
      setupCamera();
      redraw();
      status('view-status', 'Projected on ' + state.axes.filter((k) => k >= 0).map((k) => 'x' + (k + 1)).join(', ') +
        '. Drag to ' + (drawn3d() ? 'orbit' : 'pan') + ', scroll to zoom.');
    });
  }

  function defaultBox() {
    const d = state.set.dimension;
    const pad = state.hi.map((h, k) => 0.05 * (h - state.lo[k]) || 0.5);
    return [...state.lo.map((l, k) => l - pad[k]), ...state.hi.map((h, k) => h + pad[k])].slice(0, 2 * d);
  }

  // The clip box the user set, as numbers (null when periodic: a periodic set's cells
  // live on its torus and take no other domain).
  function clipBox() {
    if (state.set.periodic_box) return null;
    const values = $('box').value.split(/[\s,]+/).filter(Boolean).map(Number);
    const d = state.set.dimension;
    if (values.length !== 2 * d || values.some((v) => !Number.isFinite(v))) {
      throw new Error('clip box: give ' + 2 * d + ' numbers, lo_1..lo_' + d + ', hi_1..hi_' + d);
    }
    return values;
  }

  async function openSet(info) {
    const token = ++state.loadToken;
    state.set = info; state.coords = null; state.seed = null; state.seedAnswer = null;
    for (const row of $('set-table').tBodies[0].rows) row.classList.toggle('chosen', row.dataset.id === info.id);
    history.replaceState(null, '', '#set=' + info.id);
    const tags = [info.weighted ? 'weighted' : '', info.periodic_box ? 'periodic box ' + info.periodic_box.join(',') : '']
      .filter(Boolean).join('; ');
    $('set-title').textContent = (info.display_name || info.id.slice(0, 12)) + ': ' + info.count + ' points in ' +
      info.dimension + '-d' + (tags ? ' (' + tags + ')' : '');
    $('seed-details').textContent = 'Click a point, or type a seed index.';
    $('seed').max = String(info.count - 1);
    state.timing = { fetchStart: performance.now() };
    document.body.dataset.firstFrame = 'false';
    status('view-status', 'fetching ' + info.count + ' points…');
    progress('view-progress', 0);
    try {
      // float32 halves the transfer; the drawing needs no more.
      const response = await api(setPath(info.id) + '/points?dtype=float32');
      const expected = info.count * info.dimension * 4 + 128;
      const chunks = [];
      let received = 0;
      await readStream(response, (chunk) => {
        chunks.push(chunk);
        received += chunk.length;
        if (token === state.loadToken) progress('view-progress', received / expected);
      });
      if (token !== state.loadToken) return;
      const all = new Uint8Array(received);
      let at = 0;
      for (const c of chunks) { all.set(c, at); at += c.length; }
      const headerLength = new DataView(all.buffer).getUint16(8, true);
      state.coords = new Float32Array(all.buffer, 10 + headerLength, info.count * info.dimension);
      state.timing.fetched = performance.now();
    } catch (e) {
      progress('view-progress', null);
      status('view-status', 'Could not fetch the points: ' + e.message, true);
      return;
    }
    progress('view-progress', null);
    setupProjection();
    computeFrame();
    $('box').value = info.periodic_box ? info.periodic_box.join(',') : defaultBox().map(boxText).join(',');
    $('box').disabled = !!info.periodic_box || !!state.domain;
    $('box').title = info.periodic_box ? 'a periodic set\'s cells live on its torus' : 'lo_1..lo_d, hi_1..hi_d';
    if (!setupRenderer()) return;
    setupCamera();
    setMode('points');
    status('view-status', info.count + ' points' + (info.dimension > 3 ? ', projected on the chosen axes' : '') +
      '. Drag to ' + (drawn3d() ? 'orbit' : 'pan') + ', scroll to zoom, click a point for its star and cell.');
  }

  // ---- modes: points, whole mesh, cells ---------------------------------------------------

  function setMode(mode) {
    state.mode = mode;
    for (const m of ['points', 'mesh', 'cells']) $('mode-' + m).classList.toggle('active', m === mode);
    redraw();
  }
  for (const m of ['points', 'mesh', 'cells']) $('mode-' + m).addEventListener('click', () => state.set && state.coords && setMode(m));

  function redraw() {
    if (!view.ready || !state.coords) return;
    drawPoints();
    clearLayer(view.layers.overlay);
    clearLayer(view.layers.seed);
    $('overlay').textContent = '';
    if (state.mode === 'mesh') drawMesh();
    else if (state.mode === 'cells') drawCells();
    if (state.seed !== null && state.seedAnswer) drawSeed(state.seedAnswer);
    render();
  }

  async function drawMesh() {
    const token = state.loadToken, info = state.set;
    if (info.count > MESH_LIMIT) {
      status('view-status', 'The whole mesh is drawn for sets of up to ' + MESH_LIMIT + ' points; this one has ' +
        info.count + '. Pick seeds to see their stars, or stream the mesh with the CLI or Python client.', true);
      return;
    }
    status('view-status', 'streaming the mesh…');
    progress('view-progress', 0);
    const d = info.dimension;
    const expected = Math.max(1, info.expected_simplices || info.count);  // the server's estimate
    const edges = [];
    const seen = new Set();
    let count = 0;
    try {
      const response = await api(setPath(info.id) + '/simplices?shard=0&shards=1');
      const a = new Float32Array(3), b = new Float32Array(3);
      await readLines(response, (line) => {
        const simplex = Array.isArray(line) ? line : line.simplex;
        const offsets = Array.isArray(line) ? null : line.offsets;
        ++count;
        for (let i = 0; i < simplex.length; ++i) {
          for (let j = i + 1; j < simplex.length; ++j) {
            if (!offsets) {
              const key = Math.min(simplex[i], simplex[j]) * info.count + Math.max(simplex[i], simplex[j]);
              if (seen.has(key)) continue;
              seen.add(key);
            }
            toWorld(offsets ? imageOf(simplex[i], offsets[i]) : pointOf(simplex[i]), a, 0);
            toWorld(offsets ? imageOf(simplex[j], offsets[j]) : pointOf(simplex[j]), b, 0);
            edges.push(a[0], a[1], a[2], b[0], b[1], b[2]);
          }
        }
        if (count % 2000 === 0 && token === state.loadToken) {
          progress('view-progress', count / expected);
          status('view-status', 'streaming the mesh: ' + count + ' simplices…');
        }
      });
    } catch (e) {
      progress('view-progress', null);
      status('view-status', 'The mesh stopped: ' + e.message, true);
      return;
    }
    progress('view-progress', null);
    if (token !== state.loadToken || state.mode !== 'mesh') return;
    view.layers.overlay.add(segmentsObject(new Float32Array(edges), COLORS.mesh, 0.45));
    if (info.periodic_box) { const o = boxOutline(info.periodic_box, COLORS.box); if (o) view.layers.overlay.add(o); }
    status('view-status', count + ' simplices, ' + edges.length / 6 + ' edges drawn' +
      (d > 3 ? ' (projected on the chosen axes)' : '') + '.');
    render();
  }

  // Viridis-like ramp: t in [0, 1] -> [r, g, b].
  function ramp(t) {
    const stops = [[0.267, 0.005, 0.329], [0.231, 0.322, 0.545], [0.129, 0.569, 0.549], [0.369, 0.788, 0.384], [0.992, 0.906, 0.145]];
    const x = Math.max(0, Math.min(1, t)) * (stops.length - 1);
    const i = Math.min(stops.length - 2, Math.floor(x)), f = x - i;
    return stops[i].map((v, k) => v + (stops[i + 1][k] - v) * f);
  }

  async function drawCells() {
    const token = state.loadToken, info = state.set, d = info.dimension;
    if (d > 3) {
      status('view-status', 'Cells are drawn for 2-d and 3-d sets; for this ' + d + '-d set, pick a seed to list its ' +
        'cell\'s volume, facets and neighbours.', true);
      return;
    }
    if (info.count > CELLS_LIMIT) {
      status('view-status', 'All cells are drawn for sets of up to ' + CELLS_LIMIT + ' points; this one has ' +
        info.count + '. Pick a seed to see its cell.', true);
      return;
    }
    try { if (!state.domain) clipBox(); } catch (e) { status('view-status', e.message, true); return; }
    status('view-status', 'streaming the cells…');
    progress('view-progress', 0);
    const cells = [];
    try {
      const response = await cellRequest(setPath(info.id) + '/cells', 'shard=0&shards=1');
      await readLines(response, (cell) => {
        cells.push(cell);
        if (cells.length % 500 === 0 && token === state.loadToken) progress('view-progress', cells.length / info.count);
      });
    } catch (e) {
      progress('view-progress', null);
      const hint = /outside the domain/.test(e.message) ? ' To draw every cell, the clip box must hold every point ' +
        '(reset gives the bounding box).' : '';
      status('view-status', 'The cells stopped: ' + e.message + '.' + hint, true);
      return;
    }
    progress('view-progress', null);
    if (token !== state.loadToken || state.mode !== 'cells') return;
    const volumes = cells.map((c) => c.volume).filter((v) => v !== null && Number.isFinite(v));
    const lo = Math.min(...volumes), hi = Math.max(...volumes);
    const tri = [], colors = [], edges = [], edgeColors = [];
    for (const cell of cells) {
      if (cell.volume === null || !cell.vertices.length) continue;
      const before = tri.length, edgesBefore = edges.length;
      // In a domain, 3-d: the cells' pieces of the walls (what one sees from outside).
      if (state.domain) shapeCellGeometry(cell, tri, edges, false);
      else cellGeometry(cell, d === 3 ? 0.6 : 1, tri, edges);  // 3-d: pulled apart, so one sees between
      const rgb = ramp(hi > lo ? (cell.volume - lo) / (hi - lo) : 0.5);
      for (let i = before; i < tri.length; i += 3) colors.push(...rgb);
      for (let i = edgesBefore; i < edges.length; i += 3) edgeColors.push(...rgb);
    }
    view.layers.overlay.add(meshObject(new Float32Array(tri), new Float32Array(colors), 0, d === 3 ? 0.9 : 0.85));
    if (state.domain) {
      // Cells in a domain: outlines coloured as their cells (2-d), dark on the walls (3-d).
      view.layers.overlay.add(d === 2 ? segmentsObject(new Float32Array(edges), 0, 1, new Float32Array(edgeColors))
        : segmentsObject(new Float32Array(edges), 0x333333, 0.25));
      if (d === 2) domainWalls(view.layers.overlay);
    } else {
      view.layers.overlay.add(segmentsObject(new Float32Array(edges), 0x333333, d === 3 ? 0.2 : 0.5));
    }
    $('overlay').replaceChildren(el('div', { text: 'cell volume ' + num(lo) + ' … ' + num(hi) }), el('div', { class: 'legend' }));
    status('view-status', cells.length + ' cells' + (state.domain ? ' in the domain ' + state.domain.name : '') +
      ', coloured by volume (sum ' + num(volumes.reduce((s, v) => s + v, 0)) + ').');
    render();
  }

  // ---- one seed: star, cell, neighbours -------------------------------------------------------

  async function selectSeed(seed) {
    if (!state.set || !state.coords) return;
    const info = state.set, token = state.loadToken;
    if (!Number.isInteger(seed) || seed < 0 || seed >= info.count) {
      $('seed-details').textContent = 'seed: give an index from 0 to ' + (info.count - 1) + '.';
      $('seed-details').className = 'error';
      return;
    }
    state.seed = seed;
    $('seed').value = String(seed);
    history.replaceState(null, '', '#set=' + info.id + '&seed=' + seed);
    $('seed-details').className = 'muted';
    $('seed-details').textContent = 'computing seed ' + seed + '…';
    const base = setPath(info.id) + '/seeds/' + seed;
    const answer = { seed };
    try { if (!state.domain) clipBox(); } catch (e) { answer.cellError = e.message; }
    const settle = (p) => p.then((v) => ({ v }), (e) => ({ e }));
    const [star, neighbors, cell] = await Promise.all([
      settle(apiJson(base + '/star')), settle(apiJson(base + '/neighbors')),
      answer.cellError ? Promise.resolve({ e: new Error(answer.cellError) })
        : settle(cellRequest(base + '/cell').then((r) => r.json()))]);
    if (token !== state.loadToken || state.seed !== seed) return;
    answer.star = star.v; answer.starError = star.e && star.e.message;
    answer.neighbors = neighbors.v; answer.neighborsError = neighbors.e && neighbors.e.message;
    answer.cell = cell.v; answer.cellError = cell.e && cell.e.message;
    state.seedAnswer = answer;
    showSeedDetails(answer);
    drawSeed(answer);
    render();
  }

  function drawSeed(answer) {
    if (!view.ready) return;
    clearLayer(view.layers.seed);
    const layer = view.layers.seed;
    const seedWorld = new Float32Array(3);
    toWorld(pointOf(answer.seed), seedWorld, 0);
    if (answer.star) {
      const s = answer.star, edges = [];
      const a = new Float32Array(3), b = new Float32Array(3);
      s.simplices.forEach((simplex, t) => {
        const offsets = s.offsets ? s.offsets[t] : null;
        for (let i = 0; i < simplex.length; ++i) {
          for (let j = i + 1; j < simplex.length; ++j) {
            toWorld(offsets ? imageOf(simplex[i], offsets[i]) : pointOf(simplex[i]), a, 0);
            toWorld(offsets ? imageOf(simplex[j], offsets[j]) : pointOf(simplex[j]), b, 0);
            edges.push(...a, ...b);
          }
        }
      });
      layer.add(segmentsObject(new Float32Array(edges), COLORS.star, 0.7));
      const centres = new Float32Array(s.circumcenters.length * 3);
      s.circumcenters.forEach((c, i) => toWorld(c, centres, 3 * i));
      layer.add(pointsObject(centres, COLORS.centre, 5));
    }
    if (answer.neighbors) {
      const nb = answer.neighbors.neighbors, offsets = answer.neighbors.offsets;
      const positions = new Float32Array(nb.length * 3);
      nb.forEach((k, i) => toWorld(offsets ? imageOf(k, offsets[i]) : pointOf(k), positions, 3 * i));
      layer.add(pointsObject(positions, COLORS.neighbor, 6));
    }
    const d = state.set.dimension;
    if (state.domain && d <= 3) domainWalls(layer);
    if (answer.cell && answer.cell.vertices.length && d <= 3) {
      const tri = [], edges = [];
      if (state.domain) shapeCellGeometry(answer.cell, tri, edges);
      else cellGeometry(answer.cell, 1, tri, edges);
      layer.add(meshObject(new Float32Array(tri), null, COLORS.cell, 0.25));
      layer.add(segmentsObject(new Float32Array(edges), COLORS.cell, 1));
      if (state.mode === 'points') {
        $('overlay').textContent = 'seed ' + answer.seed + ' (red): its star (blue), circumcentres (green), ' +
          'Delaunay neighbours (orange) and Voronoi cell (purple)';
      }
    } else if (answer.cell && answer.cell.vertices.length) {
      const positions = new Float32Array(answer.cell.vertices.length * 3);
      answer.cell.vertices.forEach((p, i) => toWorld(p, positions, 3 * i));
      layer.add(pointsObject(positions, COLORS.cell, 5));
      $('overlay').textContent = 'A ' + d + '-d cell is shown by its vertices, projected; its facets are listed.';
    }
    if (!state.set.periodic_box && !state.domain) {
      try { const o = boxOutline(clipBox(), COLORS.box); if (o) layer.add(o); } catch (e) { /* no box */ }
    }
    layer.add(pointsObject(seedWorld, COLORS.seed, 9));
    // The seed's drawing stays in front of the cloud, which fades behind it.
    for (const child of layer.children) { child.material.depthTest = false; child.renderOrder = 10; }
    if (view.pointsObject) view.pointsObject.material.color.setHex(COLORS.faded);
  }

  function showSeedDetails(a) {
    const box = $('seed-details');
    box.className = '';
    box.replaceChildren();
    const p = Array.from(pointOf(a.seed)).map(num).join(', ');
    const list = el('dl', {}, el('dt', { text: 'seed' }), el('dd', { id: 'detail-seed', text: String(a.seed) }),
      el('dt', { text: 'point' }), el('dd', { text: p }));
    if (a.star) {
      list.append(el('dt', { text: 'simplices' }), el('dd', { id: 'star-simplices', text: String(a.star.simplices.length) }));
      if (a.star.hidden) list.append(el('dt', { text: 'hidden' }), el('dd', { text: 'yes: its power cell is empty' }));
    }
    if (a.cell) {
      const c = a.cell;
      list.append(el('dt', { text: 'volume' }), el('dd', { id: 'cell-volume', 'data-value': String(c.volume), text: c.volume === null ? 'unbounded' : num(c.volume) }));
      if (c.centroid) list.append(el('dt', { text: 'centroid' }), el('dd', { text: c.centroid.map(num).join(', ') }));
      list.append(el('dt', { text: 'clipped' }), el('dd', { text: c.clipped ? 'yes' : 'no' }));
    }
    box.append(list);
    if (a.starError) box.append(el('p', { class: 'error', text: 'star: ' + a.starError }));
    if (a.cellError) box.append(el('p', { class: 'error', text: 'cell: ' + a.cellError }));
    if (a.neighborsError) box.append(el('p', { class: 'error', text: 'neighbours: ' + a.neighborsError }));
    if (a.neighbors) {
      box.append(el('h2', { text: a.neighbors.neighbors.length + ' Delaunay neighbours' }));
      const buttons = el('div', { class: 'neighbors', id: 'neighbor-list' });
      for (const k of a.neighbors.neighbors) {
        const b = el('button', { 'data-seed': String(k), title: 'show seed ' + k, text: String(k) });
        b.addEventListener('click', () => selectSeed(k));
        buttons.append(b);
      }
      box.append(buttons);
    }
    if (a.cell && a.cell.facets.length) {
      box.append(el('h2', { text: a.cell.facets.length + ' facets' }));
      const rows = a.cell.facets.map((f) => el('tr', {},
        el('td', { text: f.neighbor !== undefined ? 'point ' + f.neighbor + (f.offset ? ' @ ' + f.offset.join(',') : '') : 'wall ' + f.wall }),
        el('td', { class: 'num', text: num(f.area) })));
      box.append(el('table', { id: 'facet-table' }, el('thead', {}, el('tr', {}, el('th', { text: 'across' }), el('th', { class: 'num', text: 'area' }))),
        el('tbody', {}, ...rows)));
    }
  }

  // The nearest drawn point to a click, within a few pixels.
  function pick(event) {
    if (!view.pointsObject) return;
    const rect = view.renderer.domElement.getBoundingClientRect();
    const mouse = new THREE.Vector2(((event.clientX - rect.left) / rect.width) * 2 - 1,
      -((event.clientY - rect.top) / rect.height) * 2 + 1);
    const pixels = 6;
    let worldPerPixel;
    if (view.camera.isOrthographicCamera) {
      worldPerPixel = (view.camera.top - view.camera.bottom) / view.camera.zoom / rect.height;
    } else {
      const distance = view.camera.position.distanceTo(view.controls.target);
      worldPerPixel = 2 * Math.tan((view.camera.fov * Math.PI) / 360) * distance / rect.height;
    }
    view.raycaster.params.Points = { threshold: pixels * worldPerPixel };
    view.raycaster.setFromCamera(mouse, view.camera);
    const hits = view.raycaster.intersectObject(view.pointsObject);
    if (!hits.length) return;
    hits.sort((a, b) => a.distanceToRay - b.distanceToRay || a.distance - b.distance);
    selectSeed(hits[0].index);
  }

  $('show-seed').addEventListener('click', () => selectSeed(Number($('seed').value)));
  // Centres the view on the seed, at a distance that shows its star.
  $('zoom-seed').addEventListener('click', () => {
    if (state.seed === null || !view.camera) return;
    const w = new Float32Array(3);
    toWorld(pointOf(state.seed), w, 0);
    const target = new THREE.Vector3(w[0], w[1], w[2]);
    const shift = target.clone().sub(view.controls.target);
    view.controls.target.copy(target);
    view.camera.position.add(shift);
    // A few mean spacings of the drawn points (the drawing spans about [-1, 1]).
    const reach = 8 / Math.pow(Math.max(1, state.set.count), 1 / (drawn3d() ? 3 : 2));
    if (view.camera.isOrthographicCamera) {
      view.camera.zoom = Math.min(1e4, 1.1 / reach);
      view.camera.updateProjectionMatrix();
    } else {
      const dir = view.camera.position.clone().sub(target).normalize();
      view.camera.position.copy(target.clone().add(dir.multiplyScalar(3 * reach)));
    }
    view.controls.update();
    render();
  });
  $('seed').addEventListener('keydown', (e) => { if (e.key === 'Enter') selectSeed(Number($('seed').value)); });
  $('box-reset').addEventListener('click', () => {
    if (!state.set || !state.coords || state.set.periodic_box) return;
    $('box').value = defaultBox().map(boxText).join(',');
    $('box').dispatchEvent(new Event('change'));
  });
  $('box').addEventListener('change', () => {
    if (state.mode === 'cells') redraw();
    if (state.seed !== null) selectSeed(state.seed);
  });
  $('domain-file').addEventListener('change', () => {
    const file = $('domain-file').files[0];
    if (file) chooseDomain(file);
  });
  $('domain-clear').addEventListener('click', () => {
    state.domain = null;
    $('domain-file').value = '';
    $('domain-info').textContent = '';
    if (!state.set || !state.coords) return;
    $('box').disabled = !!state.set.periodic_box;
    redraw();
    if (state.seed !== null) selectSeed(state.seed);
  });

  // ---- start ---------------------------------------------------------------------------------

  async function openFromHash() {
    const params = new URLSearchParams(location.hash.slice(1));
    const id = params.get('set');
    if (!id) return;
    try {
      const info = await apiJson(setPath(id));
      await openSet(info);
      if (params.has('seed')) await selectSeed(Number(params.get('seed')));
    } catch (e) {
      if (e.status !== 401) status('view-status', 'set ' + id.slice(0, 16) + ': ' + e.message, true);
    }
  }

  // For tests and benchmarks: where point k is drawn (CSS pixels from the canvas' top
  // left), and the first view's timing. Read-only uses; the page does not depend on it.
  window.spokemeshUi = {
    screenPosition(k) {
      const w = new Float32Array(3);
      toWorld(pointOf(k), w, 0);
      const v = new THREE.Vector3(w[0], w[1], w[2]).project(view.camera);
      const rect = view.renderer.domElement.getBoundingClientRect();
      return [(v.x + 1) / 2 * rect.width, (1 - v.y) / 2 * rect.height];
    },
    get timing() { return Object.assign({}, state.timing); },
    get seed() { return state.seed; },
  };

  refreshSets().then(openFromHash);
})();
