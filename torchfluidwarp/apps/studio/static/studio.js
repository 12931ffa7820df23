// torchfluidwarp studio: plain JavaScript, no dependencies, no build step.
//
// Coordinates: image pixels (x right, y down) with pixel centres at integers, as in the library. A pointer at
// clientX maps to x = (clientX - contentLeft) * naturalWidth / contentWidth - 0.5, whatever the canvas's
// display size, border or devicePixelRatio (the canvas backing store only affects drawing).
'use strict';
(() => {
  const token = new URLSearchParams(location.search).get('token') || '';
  const $ = (id) => document.getElementById(id);
  const HIT = 9; // CSS pixels within which a press grabs a point

  // Panes A and B come from one template in index.html; their ids end in the side, as the code below expects
  for (const [side, what] of [['a', 'click to add a point'], ['b', 'click to add the partner point']]) {
    const pane = $('image-pane').content.firstElementChild.cloneNode(true);
    pane.id = `pane-${side}`;
    pane.querySelector('b').textContent = side.toUpperCase();
    pane.querySelector('.name').id = `name-${side}`;
    for (const input of pane.querySelectorAll('input[data-id]')) input.id = `${input.dataset.id}-${side}`;
    const canvas = pane.querySelector('canvas');
    canvas.id = `canvas-${side}`;
    canvas.setAttribute('aria-label', `image ${side.toUpperCase()}: ${what}`);
    $('pane-m').before(pane);
  }

  // ------------------------------------------------------------------------------------- server calls

  function url(path, params = {}) {
    const q = new URLSearchParams({ token, ...params });
    return `${path}?${q}`;
  }

  async function api(path, { method = 'GET', json, body, params, raw = false } = {}) {
    const headers = { 'X-Studio-Token': token };
    if (json !== undefined) { headers['Content-Type'] = 'application/json'; body = JSON.stringify(json); }
    const res = await fetch(params ? `${path}?${new URLSearchParams(params)}` : path, { method, headers, body });
    if (!res.ok) {
      let message = `${res.status} ${res.statusText}`;
      try { message = (await res.json()).error || message; } catch (_) { /* not JSON */ }
      const err = new Error(message); err.status = res.status; throw err;
    }
    if (raw) return res;
    return (res.headers.get('content-type') || '').includes('json') ? res.json() : res;
  }

  function showError(message) {
    const box = $('error');
    box.textContent = message || '';
    box.hidden = !message;
  }

  // 409 and 410: the server saw a newer request (or dropped a stale result), so there is nothing to show
  const isStale = (err) => !!err && (err.status === 409 || err.status === 410);

  function report(err) {
    if (isStale(err)) return;
    showError(err && err.message ? err.message : String(err));
  }

  // The page's requests travel on parallel connections, so the server may number them out of order and call
  // the page's newest request stale. The newest request is then sent again, a few times at most: `state` is
  // `morph` or `anim` (its `seq` numbers the requests), `resend` sends the request again.
  const STALE_RETRIES = 3;
  function resentStale(state, seq, err, resend) {
    if (seq !== state.seq || !isStale(err) || state.staleRetries >= STALE_RETRIES) return false;
    state.staleRetries += 1;
    resend();
    return true;
  }

  function status(text) { $('status').textContent = text; }

  function loadImage(src) {
    return new Promise((resolve, reject) => {
      const img = new Image();
      img.onload = () => resolve(img);
      img.onerror = () => reject(new Error(`cannot load ${src.split('?')[0]}`));
      img.src = src;
    });
  }

  function download(blob, name) {
    const a = document.createElement('a');
    a.href = URL.createObjectURL(blob);
    a.download = name;
    document.body.appendChild(a);
    a.click();
    setTimeout(() => { URL.revokeObjectURL(a.href); a.remove(); }, 1000);
  }

  async function exportFile(path, payload, name) {
    showError('');
    const save = payload.save;
    status(`exporting ${name} …`);
    try {
      const res = await api(path, { method: 'POST', json: { ...payload, name }, raw: true });
      if (save) {
        const info = await res.json();
        status(`saved ${info.saved}`);
      } else {
        download(await res.blob(), name);
        status(`exported ${name}`);
      }
    } catch (err) { status(''); report(err); }
  }

  // ------------------------------------------------------------------------------------------- panes

  // A canvas showing an image at any display size; converts between pointer events and image pixels.
  class Pane {
    constructor(canvas, draw) {
      this.canvas = canvas;
      this.ctx = canvas.getContext('2d');
      this.draw = draw;
      this.W = 0; this.H = 0; this.image = null;
    }
    setSize(W, H) {
      this.W = W; this.H = H;
      this.canvas.style.aspectRatio = `${W} / ${H}`;
      this.resize();
    }
    setImage(img) {
      this.image = img;
      if (img && (img.naturalWidth !== this.W || img.naturalHeight !== this.H)) this.setSize(img.naturalWidth, img.naturalHeight);
      else this.render();
    }
    // the content box in CSS pixels (inside the border and padding), fractional
    box() {
      const r = this.canvas.getBoundingClientRect();
      const cs = getComputedStyle(this.canvas);
      const px = (v) => parseFloat(cs[v]) || 0;
      const left = r.left + px('borderLeftWidth') + px('paddingLeft');
      const top = r.top + px('borderTopWidth') + px('paddingTop');
      const width = r.width - px('borderLeftWidth') - px('borderRightWidth') - px('paddingLeft') - px('paddingRight');
      const height = r.height - px('borderTopWidth') - px('borderBottomWidth') - px('paddingTop') - px('paddingBottom');
      return { left, top, width, height };
    }
    resize() {
      if (!this.W) return;
      const b = this.box();
      const dpr = window.devicePixelRatio || 1;
      const w = Math.max(1, Math.round(b.width * dpr)), h = Math.max(1, Math.round(b.height * dpr));
      if (this.canvas.width !== w || this.canvas.height !== h) { this.canvas.width = w; this.canvas.height = h; }
      this.render();
    }
    // image pixel -> backing-store pixel
    toCanvas([x, y]) { return [(x + 0.5) * this.canvas.width / this.W, (y + 0.5) * this.canvas.height / this.H]; }
    // pointer event -> image pixel (pixel centres at integers)
    fromEvent(e) {
      const b = this.box();
      return [(e.clientX - b.left) * this.W / b.width - 0.5, (e.clientY - b.top) * this.H / b.height - 0.5];
    }
    // CSS pixels per image pixel (for hit tests)
    cssScale() { return this.box().width / this.W; }
    // backing-store pixels per CSS pixel (line widths, label sizes)
    dpr() { return this.canvas.width / Math.max(1, this.box().width); }
    render() {
      const { ctx, canvas } = this;
      ctx.setTransform(1, 0, 0, 1, 0, 0);
      ctx.clearRect(0, 0, canvas.width, canvas.height);
      if (this.image) {
        // show pixels as squares when enlarged, so a point can be put on a chosen pixel
        ctx.imageSmoothingEnabled = canvas.width < this.W * 2;
        ctx.drawImage(this.image, 0, 0, canvas.width, canvas.height);
      }
      if (this.draw) this.draw(this);
    }
    inside([x, y]) { return x >= -0.5 && y >= -0.5 && x <= this.W - 0.5 && y <= this.H - 0.5; }
  }

  const colour = (i, alpha = 1) => `hsla(${(i * 137.508) % 360}, 85%, 45%, ${alpha})`;

  function drawMarker(pane, p, i, { hollow = false, selected = false } = {}) {
    const { ctx } = pane;
    const s = pane.dpr();
    const [cx, cy] = pane.toCanvas(p);
    ctx.lineWidth = 2 * s;
    ctx.strokeStyle = '#fff';
    ctx.fillStyle = colour(i);
    ctx.beginPath(); ctx.arc(cx, cy, (selected ? 7 : 5) * s, 0, 2 * Math.PI);
    if (hollow) { ctx.setLineDash([3 * s, 2 * s]); ctx.strokeStyle = colour(i); ctx.stroke(); ctx.setLineDash([]); }
    else { ctx.fill(); ctx.stroke(); }
    ctx.font = `bold ${12 * s}px system-ui, sans-serif`;
    ctx.lineWidth = 3 * s;
    ctx.strokeStyle = '#fff';
    ctx.strokeText(String(i + 1), cx + 7 * s, cy - 6 * s);
    ctx.fillStyle = colour(i);
    ctx.fillText(String(i + 1), cx + 7 * s, cy - 6 * s);
  }

  // ---------------------------------------------------------------------------------------- history

  class History {
    constructor(get, set) { this.get = get; this.set = set; this.past = []; this.future = []; }
    push() { this.past.push(JSON.stringify(this.get())); if (this.past.length > 200) this.past.shift(); this.future = []; }
    undo() { if (!this.past.length) return false; this.future.push(JSON.stringify(this.get())); this.set(JSON.parse(this.past.pop())); return true; }
    redo() { if (!this.future.length) return false; this.past.push(JSON.stringify(this.get())); this.set(JSON.parse(this.future.pop())); return true; }
  }

  // ----------------------------------------------------------------------------------------- state

  const app = {
    mode: 'morph',
    images: { a: null, b: null },       // server's image info
    saveDir: false,
    lastLatency: null,                    // seconds from a preview request to its frame on screen
    previews: 0,                          // previews drawn (for tests)
    syncs: 0,                             // point syncs settled, sent or not needed (for tests)
    autoRefine: true,                     // keep refining the fit while the points stay put
    animPreviews: 0,
  };
  window.studio = app;

  const morph = {
    pairs: [],        // [{a: [x, y] | null, b: [x, y] | null, proposed: bool}]
    selected: -1,
    alignment: null,  // 3x3, A pixels -> B pixels, for proposing partners
    meta: null,       // the last preview's answer
    frameImage: null, heatImage: null,
    drag: null,
    seq: 0,
    staleRetries: 0,
  };
  const morphHistory = new History(() => morph.pairs, (v) => { morph.pairs = v; morph.selected = -1; pointsChanged(); });

  const paneA = new Pane($('canvas-a'), (p) => drawPoints(p, 'a'));
  const paneB = new Pane($('canvas-b'), (p) => drawPoints(p, 'b'));
  const paneM = new Pane($('canvas-m'), drawPreview);

  const complete = () => morph.pairs.filter((p) => p.a && p.b);

  function settings() {
    const c = $('set-compressible').value;
    return {
      method: $('set-method').value,
      inverse: $('set-inverse').value,
      grid: parseInt($('set-grid').value, 10),
      steps: parseInt($('set-steps').value, 10),
      control: parseInt($('set-control').value, 10),
      align: $('set-align').value,
      compressible: c === 'default' ? null : c === 'true' ? true : c === 'false' ? false : parseFloat(c),
      blend: $('set-blend').value,
    };
  }

  function drawPoints(pane, side) {
    morph.pairs.forEach((pair, i) => {
      const p = pair[side];
      if (!p) return;
      drawMarker(pane, p, i, { hollow: side === 'b' && pair.proposed, selected: i === morph.selected });
    });
  }

  function drawPreview(pane) {
    const { ctx } = pane;
    const meta = morph.meta;
    if (!meta || !morph.frameImage) return;
    if ($('show-heat').checked && morph.heatImage) {
      ctx.globalAlpha = 0.6;
      ctx.imageSmoothingEnabled = false;
      ctx.drawImage(morph.heatImage, 0, 0, pane.canvas.width, pane.canvas.height);
      ctx.globalAlpha = 1;
    }
    if ($('show-traj').checked) {
      const s = pane.dpr();
      const k = frameIndex();
      const t = meta.times[k] * (meta.trajectories[0] ? meta.trajectories[0].length - 1 : 0);
      meta.trajectories.forEach((path, i) => {
        ctx.strokeStyle = colour(i, 0.9);
        ctx.lineWidth = 1.5 * s;
        ctx.beginPath();
        path.forEach((q, j) => { const [cx, cy] = pane.toCanvas(q); if (j) ctx.lineTo(cx, cy); else ctx.moveTo(cx, cy); });
        ctx.stroke();
        const j = Math.min(Math.floor(t), path.length - 2), f = t - j;
        if (j >= 0) {
          const q = [path[j][0] * (1 - f) + path[j + 1][0] * f, path[j][1] * (1 - f) + path[j + 1][1] * f];
          const [cx, cy] = pane.toCanvas(q);
          ctx.fillStyle = colour(i); ctx.beginPath(); ctx.arc(cx, cy, 3 * s, 0, 2 * Math.PI); ctx.fill();
        }
      });
    }
  }

  function frameIndex() { return parseInt($('time').value, 10) || 0; }

  function nearest(pane, side, p) {
    const r = HIT / pane.cssScale();
    let best = -1, bestD = r * r;
    morph.pairs.forEach((pair, i) => {
      const q = pair[side];
      if (!q) return;
      const d = (q[0] - p[0]) ** 2 + (q[1] - p[1]) ** 2;
      if (d <= bestD) { best = i; bestD = d; }
    });
    return best;
  }

  function propose(a) {
    const M = morph.alignment;
    if (!M || complete().length < 3 || !paneB.W) return null;
    const x = M[0][0] * a[0] + M[0][1] * a[1] + M[0][2];
    const y = M[1][0] * a[0] + M[1][1] * a[1] + M[1][2];
    return [Math.min(Math.max(x, 0), paneB.W - 1), Math.min(Math.max(y, 0), paneB.H - 1)];
  }

  function addPoint(side, p) {
    morphHistory.push();
    const other = side === 'a' ? 'b' : 'a';
    // finish a pair started on the other image (or replace a proposed partner) before starting a new one
    let i = -1;
    for (let k = morph.pairs.length - 1; k >= 0; k--) {
      const pair = morph.pairs[k];
      if (!pair[side] || (side === 'b' && pair.proposed)) { i = k; break; }
    }
    if (i >= 0 && (morph.pairs[i][other] || side === 'b')) {
      morph.pairs[i][side] = p;
      if (side === 'b') morph.pairs[i].proposed = false;
    } else if (side === 'a') {
      const guess = propose(p);
      i = morph.pairs.push({ a: p, b: guess, proposed: !!guess }) - 1;
    } else {
      i = morph.pairs.push({ a: null, b: p, proposed: false }) - 1;
    }
    morph.selected = i;
    pointsChanged();
  }

  function deletePair(i) {
    if (i < 0 || i >= morph.pairs.length) return;
    morphHistory.push();
    morph.pairs.splice(i, 1);
    morph.selected = -1;
    pointsChanged();
  }

  function bindPointPane(pane, side) {
    const c = pane.canvas;
    c.addEventListener('pointerdown', (e) => {
      if (e.button !== 0 || !pane.W) return;
      c.focus();
      const p = pane.fromEvent(e);
      const hit = nearest(pane, side, p);
      if (hit >= 0) {
        morph.selected = hit;
        morph.drag = { side, index: hit, moved: false, pane };
        c.setPointerCapture(e.pointerId);
        renderPoints();
        return;
      }
      if (pane.inside(p)) addPoint(side, p);
    });
    c.addEventListener('pointermove', (e) => {
      const d = morph.drag;
      if (!d || d.side !== side) return;
      const p = pane.fromEvent(e);
      const q = [Math.min(Math.max(p[0], -0.5), pane.W - 0.5), Math.min(Math.max(p[1], -0.5), pane.H - 0.5)];
      if (!d.moved) { morphHistory.push(); d.moved = true; }
      morph.pairs[d.index][side] = q;
      if (side === 'b') morph.pairs[d.index].proposed = false;
      renderPoints();
      schedulePreview(250);
    });
    const end = () => {
      const d = morph.drag;
      if (!d || d.side !== side) return;
      morph.drag = null;
      if (d.moved) pointsChanged();
    };
    c.addEventListener('pointerup', end);
    c.addEventListener('pointercancel', end);
    c.addEventListener('contextmenu', (e) => {
      e.preventDefault();
      const hit = nearest(pane, side, pane.fromEvent(e));
      if (hit >= 0) deletePair(hit);
    });
  }

  function renderPoints() { paneA.render(); paneB.render(); }

  let syncTimer = 0;
  function pointsChanged() {
    renderPoints();
    const n = complete().length;
    $('pair-count').textContent = `${n} pair${n === 1 ? '' : 's'}` +
      (morph.pairs.length > n ? ` (+${morph.pairs.length - n} unfinished)` : '');
    updateCommand();
    clearTimeout(syncTimer);
    syncTimer = setTimeout(syncPoints, 0);
    schedulePreview(120);
  }

  async function syncPoints() {
    try {
      // points belong to images: until both are loaded, the server has nothing to check them against
      if (!app.images.a || !app.images.b) return;
      const done = complete();
      const res = await api('api/points', { method: 'PUT', json: { points_a: done.map((p) => p.a), points_b: done.map((p) => p.b), settings: settings() } });
      if (res.alignment) morph.alignment = res.alignment;
    } catch (err) { report(err); } finally { app.syncs += 1; }
  }

  // --------------------------------------------------------------------------------------- preview

  // A preview fit runs a few warm-started iterations only, so that an edit shows within about a second;
  // while the points stay put, the fit goes on from there in further short rounds (superseded by any edit).
  const REFINE_ROUNDS = 6, REFINE_DELAY = 500, GOOD_ENOUGH = 0.5; // rounds, ms, pixels
  let previewTimer = 0;
  let refineRounds = 0;
  function schedulePreview(delay = 150, refine = false) {
    clearTimeout(previewTimer);
    if (!refine) { refineRounds = 0; morph.staleRetries = 0; }
    previewTimer = setTimeout(requestPreview, delay);
  }

  async function requestPreview() {
    const done = complete();
    const need = settings().align === 'affine' ? 3 : 2;
    if (done.length < need || !app.images.a || !app.images.b) return;
    const seq = ++morph.seq;
    const t0 = performance.now();
    document.body.classList.add('busy');
    status('fitting');
    try {
      const meta = await api('api/morph/preview', { method: 'POST', json: { points_a: done.map((p) => p.a), points_b: done.map((p) => p.b), settings: settings() } });
      if (seq !== morph.seq) return; // a newer preview is on its way
      morph.meta = meta;
      if (meta.alignment) morph.alignment = meta.alignment;
      const slider = $('time');
      const last = meta.frames - 1;
      const frac = slider.max > 0 ? frameIndex() / slider.max : 0.5;
      slider.max = String(last);
      slider.value = String(Math.round(frac * last));
      showError('');
      await loadFrame();
      if (seq !== morph.seq) return;
      app.lastLatency = (performance.now() - t0) / 1000;
      app.previews += 1;
      const letGo = (meta.let_go || []).filter(Boolean).length;
      const gone = letGo ? ` over the marks met · ${letGo} let go so as not to fold (they cross)` : "";
      status(`preview ${app.lastLatency.toFixed(2)} s (fit ${meta.seconds.fit.toFixed(2)} s) · mean error ${meta.mean_error.toFixed(2)} px${gone}`);
      const worst = Math.max(0, ...meta.error.filter((e, i) => !(meta.let_go || [])[i]));  // a mark let go stays off
      if (app.autoRefine && worst > GOOD_ENOUGH && refineRounds < REFINE_ROUNDS && !morph.drag) {
        refineRounds += 1;
        schedulePreview(REFINE_DELAY, true);
      }
      morph.staleRetries = 0;
    } catch (err) {
      if (resentStale(morph, seq, err, () => schedulePreview(0, true))) return;
      if (seq === morph.seq) status('');
      report(err);
    } finally {
      if (seq === morph.seq) document.body.classList.remove('busy');
    }
  }

  async function loadFrame() {
    const meta = morph.meta;
    if (!meta) return;
    const k = frameIndex();
    $('frame-label').textContent = `t = ${meta.times[k].toFixed(2)}`;
    const wantHeat = $('show-heat').checked;
    const [frame, heat] = await Promise.all([
      loadImage(url('api/morph/frame', { gen: meta.generation, k, kind: $('view').value })),
      wantHeat ? loadImage(url('api/morph/frame', { gen: meta.generation, k, kind: 'jacobian' })) : null,
    ]);
    if (meta !== morph.meta) return;
    morph.frameImage = frame;
    morph.heatImage = heat;
    paneM.setImage(frame);
    paneM.canvas.dataset.generation = String(meta.generation);
    paneM.canvas.dataset.frame = String(k);
  }

  // ------------------------------------------------------------------------------------- commands

  const stem = (name, fallback) => (name || fallback).replace(/\.[^.]*$/, '') || fallback;

  function updateCommand() {
    const a = app.images.a ? app.images.a.name : 'A.png';
    const b = app.images.b ? app.images.b.name : 'B.png';
    const fmt = $('pts-format').value;
    $('command').value = `torchfluidwarp morph ${a} ${b} --points-a ${stem(a, 'a')}.${fmt} --points-b ${stem(b, 'b')}.${fmt} ` +
      `-o morph.gif --frames ${$('exp-frames').value} --fps ${$('exp-fps').value}`;
  }

  function exportPoints(side) {
    const done = complete();
    const fmt = $('pts-format').value;
    const img = app.images[side];
    const name = `${stem(img && img.name, side)}.${fmt}`;
    exportFile('api/points/export', { points: done.map((p) => p[side]), format: fmt, save: $('save-to-dir').checked }, name);
  }

  function exportMorph(fmt) {
    const done = complete();
    exportFile('api/morph/export', {
      points_a: done.map((p) => p.a), points_b: done.map((p) => p.b), settings: settings(), format: fmt,
      frames: parseInt($('exp-frames').value, 10), fps: parseFloat($('exp-fps').value), save: $('save-to-dir').checked,
    }, `morph.${fmt}`);
  }

  // ---------------------------------------------------------------------------------------- images

  async function refreshImages() {
    const st = await api('api/state');
    app.saveDir = st.save_dir;
    document.querySelectorAll('label.save').forEach((l) => { l.hidden = !st.save_dir; });
    const loads = [];
    for (const side of ['a', 'b']) {
      const info = st.images[side];
      const old = app.images[side];
      app.images[side] = info;
      $(`name-${side}`).textContent = info ? `${info.name} (${info.width}×${info.height})` : 'no image';
      if (side === 'a') $('name-photo').textContent = $('name-a').textContent;
      if (info && (!old || old.version !== info.version)) {
        loads.push(loadImage(url(`api/image/${side}`, { v: info.version })).then((img) => {
          (side === 'a' ? paneA : paneB).setImage(img);
          if (side === 'a') photo.setImage(img);
        }));
      }
    }
    await Promise.all(loads);
    return st;
  }

  async function uploadImage(side, file) {
    showError('');
    status(`loading ${file.name} …`);
    try {
      const loaded = await api(`api/image/${side}`, { method: 'PUT', body: file, params: { name: file.name } });
      await refreshImages();
      // points belong to the image they were placed on
      morphHistory.push();
      morph.pairs = morph.pairs.map((p) => ({ ...p, [side]: null, proposed: false })).filter((p) => p.a || p.b);
      morph.alignment = null; morph.meta = null; morph.frameImage = null;
      paneM.render();
      pointsChanged();
      status(`loaded ${file.name}`);
      // what the reader warned of (an animation's first frame only, a colour profile not applied) stays shown
      if (loaded.warnings && loaded.warnings.length) showError(loaded.warnings.join(' '));
    } catch (err) { status(''); report(err); }
  }

  async function importPoints(side, file) {
    showError('');
    const other = side === 'a' ? 'b' : 'a';
    const count = morph.pairs.filter((p) => p[other]).length;
    try {
      const res = await api(`api/points/${side}/import`, { method: 'POST', body: await file.text(), params: { name: file.name, count } });
      morphHistory.push();
      const pts = res.points;
      if (count === 0) morph.pairs = pts.map((p) => ({ a: side === 'a' ? p : null, b: side === 'b' ? p : null, proposed: false }));
      else {
        const withOther = morph.pairs.filter((p) => p[other]);
        withOther.forEach((p, i) => { p[side] = pts[i]; p.proposed = false; });
        morph.pairs = withOther;
      }
      pointsChanged();
      status(`read ${pts.length} points from ${file.name}`);
    } catch (err) { report(err); }
  }

  // ----------------------------------------------------------------------------------------- animate

  const anim = {
    brushes: [],  // {position, direction, radius, frequency, amplitude, phase}
    regions: [],  // {position, radius, value}
    selected: -1,
    drag: null,
    frames: [], playing: true, frame: 0, timer: 0, seq: 0, staleRetries: 0, meta: null,
  };
  app.morph = morph;
  app.anim = anim;
  const animHistory = new History(() => ({ brushes: anim.brushes, regions: anim.regions }),
    (v) => { anim.brushes = v.brushes; anim.regions = v.regions; anim.selected = -1; animChanged(); });

  const photo = new Pane($('canvas-photo'), drawAnimOverlay);
  const play = new Pane($('canvas-play'), null);

  function animSteps() { return Math.max(1, parseInt($('a-steps').value, 10) || 1); }
  function dt() { return parseFloat($('a-dt').value) || 1; }

  // how far (pixels) a brush moves the picture: about amplitude / (2 pi f)^2 when oscillating,
  // amplitude (T dt)^2 / 2 for a steady push
  function reach(b) {
    const w = 2 * Math.PI * b.frequency;
    return b.frequency > 0 ? Math.abs(b.amplitude) / (w * w) : Math.abs(b.amplitude) * (animSteps() * dt()) ** 2 / 2;
  }
  function amplitudeFor(length, frequency) {
    const w = 2 * Math.PI * frequency;
    return frequency > 0 ? length * w * w : 2 * length / (animSteps() * dt()) ** 2;
  }
  function tip(b) {
    const n = Math.hypot(b.direction[0], b.direction[1]) || 1;
    const L = reach(b) * Math.sign(b.amplitude || 1);
    return [b.position[0] + b.direction[0] / n * L, b.position[1] + b.direction[1] / n * L];
  }

  function drawAnimOverlay(pane) {
    const { ctx } = pane;
    const s = pane.dpr();
    const k = pane.canvas.width / pane.W;
    anim.regions.forEach((r) => {
      const [cx, cy] = pane.toCanvas(r.position);
      ctx.fillStyle = r.value >= 0 ? 'rgba(40, 90, 255, 0.22)' : 'rgba(255, 150, 0, 0.25)';
      ctx.beginPath(); ctx.arc(cx, cy, r.radius * k, 0, 2 * Math.PI); ctx.fill();
    });
    anim.brushes.forEach((b, i) => {
      const [cx, cy] = pane.toCanvas(b.position);
      const [tx, ty] = pane.toCanvas(tip(b));
      ctx.strokeStyle = colour(i);
      ctx.lineWidth = (i === anim.selected ? 3 : 2) * s;
      ctx.setLineDash([4 * s, 3 * s]);
      ctx.beginPath(); ctx.arc(cx, cy, b.radius * k, 0, 2 * Math.PI); ctx.stroke();
      ctx.setLineDash([]);
      const ang = Math.atan2(ty - cy, tx - cx), h = 9 * s;
      const arrow = () => {
        ctx.beginPath(); ctx.moveTo(cx, cy); ctx.lineTo(tx, ty);
        ctx.moveTo(tx - h * Math.cos(ang - 0.5), ty - h * Math.sin(ang - 0.5));
        ctx.lineTo(tx, ty);
        ctx.lineTo(tx - h * Math.cos(ang + 0.5), ty - h * Math.sin(ang + 0.5));
        ctx.stroke();
      };
      ctx.lineCap = 'round'; ctx.lineJoin = 'round';
      ctx.strokeStyle = 'rgba(255, 255, 255, 0.9)'; ctx.lineWidth = 5 * s; arrow(); // a halo: visible on any photo
      ctx.strokeStyle = colour(i); ctx.lineWidth = 2.5 * s; arrow();
      drawMarker(pane, b.position, i, { selected: i === anim.selected });
    });
  }

  function hitBrush(p) {
    const r = HIT / photo.cssScale();
    for (let i = anim.brushes.length - 1; i >= 0; i--) {
      const b = anim.brushes[i];
      const t = tip(b);
      if (Math.hypot(t[0] - p[0], t[1] - p[1]) <= r) return { index: i, part: 'tip' };
      if (Math.hypot(b.position[0] - p[0], b.position[1] - p[1]) <= r) return { index: i, part: 'centre' };
    }
    return null;
  }

  function tool() { return document.querySelector('input[name="tool"]:checked').value; }

  function paint(p) {
    const radius = parseFloat($('paint-radius').value) || 10;
    const last = anim.drag.lastPaint;
    if (last && Math.hypot(last[0] - p[0], last[1] - p[1]) < radius / 2) return;
    anim.drag.lastPaint = p;
    const value = tool() === 'stiff' ? parseFloat($('paint-stiff').value) || 0 : -(parseFloat($('paint-soft').value) || 0);
    anim.regions.push({ position: p, radius, value });
    photo.render();
  }

  function bindPhoto() {
    const c = photo.canvas;
    c.addEventListener('pointerdown', (e) => {
      if (e.button !== 0 || !photo.W) return;
      c.focus();
      const p = photo.fromEvent(e);
      if (!photo.inside(p)) return;
      c.setPointerCapture(e.pointerId);
      animHistory.push();
      if (tool() !== 'brush') { anim.drag = { kind: 'paint' }; paint(p); return; }
      const hit = hitBrush(p);
      if (hit) { anim.selected = hit.index; anim.drag = { kind: hit.part, index: hit.index }; }
      else {
        const radius = Math.max(4, Math.round(Math.min(photo.W, photo.H) / 10));
        anim.brushes.push({ position: p, direction: [0, -1], radius, frequency: 0.05, amplitude: 0, phase: 0 });
        anim.selected = anim.brushes.length - 1;
        anim.drag = { kind: 'new', index: anim.selected, start: p };
      }
      showBrush();
      photo.render();
    });
    c.addEventListener('pointermove', (e) => {
      const d = anim.drag;
      if (!d) return;
      const p = photo.fromEvent(e);
      if (d.kind === 'paint') { if (photo.inside(p)) paint(p); return; }
      const b = anim.brushes[d.index];
      if (d.kind === 'centre') b.position = p;
      else {
        const v = [p[0] - b.position[0], p[1] - b.position[1]];
        const L = Math.hypot(v[0], v[1]);
        if (L > 0.5) { b.direction = v; b.amplitude = amplitudeFor(L, b.frequency); }
      }
      showBrush();
      photo.render();
    });
    const end = () => {
      const d = anim.drag;
      if (!d) return;
      anim.drag = null;
      if (d.kind === 'new') {
        const b = anim.brushes[d.index];
        if (b.amplitude === 0) b.amplitude = amplitudeFor(Math.max(2, b.radius / 3), b.frequency); // a click: a default push
      }
      animChanged();
    };
    c.addEventListener('pointerup', end);
    c.addEventListener('pointercancel', end);
    c.addEventListener('contextmenu', (e) => {
      e.preventDefault();
      const p = photo.fromEvent(e);
      const hit = hitBrush(p);
      if (hit) { animHistory.push(); anim.brushes.splice(hit.index, 1); anim.selected = -1; animChanged(); return; }
      const i = anim.regions.findIndex((r) => Math.hypot(r.position[0] - p[0], r.position[1] - p[1]) <= r.radius);
      if (i >= 0) { animHistory.push(); anim.regions.splice(i, 1); animChanged(); }
    });
  }

  function showBrush() {
    const b = anim.brushes[anim.selected];
    $('brush-panel').disabled = !b;
    $('brush-index').textContent = b ? `#${anim.selected + 1}` : '';
    const round = (v) => Math.round(v * 1e4) / 1e4;
    for (const k of ['radius', 'frequency', 'amplitude', 'phase']) $(`b-${k}`).value = b ? round(b[k]) : '';
  }

  function animConfig() {
    const cfg = {
      brushes: anim.brushes.map((b) => ({ position: b.position, direction: b.direction, radius: b.radius, frequency: b.frequency, amplitude: b.amplitude, phase: b.phase })),
      viscosity: { base: parseFloat($('a-base').value) || 0, regions: anim.regions },
      steps: animSteps(),
      dt: dt(),
      fps: parseFloat($('a-fps').value) || 20,
    };
    const g = parseInt($('a-grid').value, 10);
    if (g > 0 && photo.W) {
      const s = g / Math.max(photo.W, photo.H);
      cfg.grid = [Math.max(2, Math.round(photo.H * s)), Math.max(2, Math.round(photo.W * s))];
    }
    return cfg;
  }

  let animTimer = 0;
  function animChanged() {
    showBrush();
    photo.render();
    const img = app.images.a ? app.images.a.name : 'photo.png';
    $('a-command').value = `torchfluidwarp animate ${img} -o ${stem(img, 'photo')}.gif --config ${stem(img, 'photo')}.json`;
    clearTimeout(animTimer);
    anim.staleRetries = 0;
    animTimer = setTimeout(requestAnimPreview, 200);
  }

  async function requestAnimPreview() {
    if (!anim.brushes.length || !app.images.a) return;
    const seq = ++anim.seq;
    const t0 = performance.now();
    status('simulating');
    try {
      const meta = await api('api/animate/preview', { method: 'POST', json: { config: animConfig() } });
      if (seq !== anim.seq) return;
      const frames = await Promise.all(Array.from({ length: meta.frames },
        (_, k) => loadImage(url('api/animate/frame', { gen: meta.generation, k }))));
      if (seq !== anim.seq) return;
      anim.meta = meta; anim.frames = frames; anim.frame = 0;
      showError('');
      $('anim-info').textContent = `${meta.frames} frames at ${meta.fps} fps`;
      $('anim-info').dataset.frames = String(meta.frames);
      app.animPreviews += 1;
      status(`animation ${((performance.now() - t0) / 1000).toFixed(2)} s`);
      anim.staleRetries = 0;
      startPlaying();
    } catch (err) {
      const resend = () => { clearTimeout(animTimer); animTimer = setTimeout(requestAnimPreview, 0); };
      if (resentStale(anim, seq, err, resend)) return;
      if (seq === anim.seq) status('');
      report(err);
    }
  }

  function startPlaying() {
    clearInterval(anim.timer);
    if (!anim.frames.length) return;
    const show = () => {
      play.setImage(anim.frames[anim.frame]);
      play.canvas.dataset.frame = String(anim.frame);
      if (anim.playing) anim.frame = (anim.frame + 1) % anim.frames.length;
    };
    show();
    anim.timer = setInterval(show, 1000 / (anim.meta ? anim.meta.fps : 20));
  }

  function exportAnim(fmt) {
    const img = app.images.a ? app.images.a.name : 'photo.png';
    exportFile('api/animate/export', { config: animConfig(), format: fmt, save: $('a-save-to-dir').checked }, `${stem(img, 'photo')}.${fmt}`);
  }

  // --------------------------------------------------------------------------------------- wiring

  function setMode(mode) {
    app.mode = mode;
    $('mode-morph').hidden = mode !== 'morph';
    $('mode-animate').hidden = mode !== 'animate';
    $('tab-morph').setAttribute('aria-selected', String(mode === 'morph'));
    $('tab-animate').setAttribute('aria-selected', String(mode === 'animate'));
    resizeAll();
  }

  function resizeAll() { [paneA, paneB, paneM, photo, play].forEach((p) => p.resize()); }

  function onKey(e) {
    if (e.target.matches('input, textarea, select')) return;
    const ctrl = e.ctrlKey || e.metaKey;
    const history = app.mode === 'morph' ? morphHistory : animHistory;
    if (ctrl && e.key.toLowerCase() === 'z' && !e.shiftKey) { e.preventDefault(); history.undo(); }
    else if (ctrl && (e.key.toLowerCase() === 'y' || (e.key.toLowerCase() === 'z' && e.shiftKey))) { e.preventDefault(); history.redo(); }
    else if (e.key === 'Delete' || e.key === 'Backspace') {
      if (app.mode === 'morph' && morph.selected >= 0) { e.preventDefault(); deletePair(morph.selected); }
      if (app.mode === 'animate' && anim.selected >= 0) { e.preventDefault(); animHistory.push(); anim.brushes.splice(anim.selected, 1); anim.selected = -1; animChanged(); }
    }
  }

  function init() {
    document.querySelectorAll('nav button').forEach((b) => b.addEventListener('click', () => setMode(b.dataset.mode)));
    bindPointPane(paneA, 'a');
    bindPointPane(paneB, 'b');
    bindPhoto();
    document.addEventListener('keydown', onKey);
    window.addEventListener('resize', resizeAll);
    if (window.ResizeObserver) new ResizeObserver(resizeAll).observe(document.body);
    for (const side of ['a', 'b']) {
      $(`file-${side}`).addEventListener('change', (e) => { if (e.target.files[0]) uploadImage(side, e.target.files[0]); e.target.value = ''; });
      $(`pts-file-${side}`).addEventListener('change', (e) => { if (e.target.files[0]) importPoints(side, e.target.files[0]); e.target.value = ''; });
      $(`export-pts-${side}`).addEventListener('click', () => exportPoints(side));
    }
    $('file-photo').addEventListener('change', (e) => { if (e.target.files[0]) uploadImage('a', e.target.files[0]).then(animChanged); e.target.value = ''; });
    $('time').addEventListener('input', () => loadFrame().catch(report));
    $('view').addEventListener('change', () => loadFrame().catch(report));
    $('show-heat').addEventListener('change', () => { $('heat-legend').hidden = !$('show-heat').checked; loadFrame().catch(report); });
    $('show-traj').addEventListener('change', () => paneM.render());
    document.querySelectorAll('#mode-morph fieldset:first-of-type select, #mode-morph fieldset:first-of-type input')
      .forEach((el) => el.addEventListener('change', () => { morph.alignment = null; syncPoints(); schedulePreview(50); }));
    ['exp-frames', 'exp-fps', 'pts-format'].forEach((id) => $(id).addEventListener('change', updateCommand));
    $('clear-points').addEventListener('click', () => { morphHistory.push(); morph.pairs = []; morph.selected = -1; pointsChanged(); });
    $('undo').addEventListener('click', () => morphHistory.undo());
    $('redo').addEventListener('click', () => morphHistory.redo());
    $('export-gif').addEventListener('click', () => exportMorph('gif'));
    $('export-mp4').addEventListener('click', () => exportMorph('mp4'));
    $('a-export-gif').addEventListener('click', () => exportAnim('gif'));
    $('a-export-mp4').addEventListener('click', () => exportAnim('mp4'));
    $('a-export-json').addEventListener('click', () => exportAnim('json'));
    $('play').addEventListener('click', () => { anim.playing = !anim.playing; $('play').textContent = anim.playing ? 'pause' : 'play'; });
    $('clear-paint').addEventListener('click', () => { animHistory.push(); anim.regions = []; animChanged(); });
    for (const k of ['radius', 'frequency', 'amplitude', 'phase']) {
      $(`b-${k}`).addEventListener('change', (e) => {
        const b = anim.brushes[anim.selected];
        const v = parseFloat(e.target.value);
        if (!b || !Number.isFinite(v)) return;
        animHistory.push();
        b[k] = v;
        animChanged();
      });
    }
    $('b-delete').addEventListener('click', () => { if (anim.selected >= 0) { animHistory.push(); anim.brushes.splice(anim.selected, 1); anim.selected = -1; animChanged(); } });
    ['a-steps', 'a-grid', 'a-dt', 'a-fps', 'a-base'].forEach((id) => $(id).addEventListener('change', animChanged));

    refreshImages().then((st) => {
      const pa = st.points.a || [], pb = st.points.b || [];
      const n = Math.max(pa.length, pb.length);
      morph.pairs = Array.from({ length: n }, (_, i) => ({ a: pa[i] || null, b: pb[i] || null, proposed: false }));
      pointsChanged();
      showBrush();
      app.ready = true;
      document.body.dataset.ready = 'true';
    }).catch(report);
  }

  init();
})();
