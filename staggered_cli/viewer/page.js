// staggered view: plays the figures laid in this page (see
// staggered_cli/viewer/__init__.py for the data) with three.js, and draws the
// staggered timing of a document under the timeline.
(function () {
  "use strict";

  const THREE = window.THREE;
  const meta = JSON.parse(document.getElementById("staggered-meta").textContent);
  const timing = meta.timing;
  const poseT = timing ? timing.pose_t : [];
  const posePart = timing && timing.pose_part ? timing.pose_part : poseT.map(() => null);
  const PARTIAL = "#7b4fa0"; // a partial pose: its line dashed, as plot --kind timing draws it
  const duration = Math.max(meta.duration, 1e-6);
  const COLORS = ["#1f5fbf", "#e0701a", "#2a9d4b", "#8e44ad", "#c0392b", "#16a085"];
  const HIDDEN = 1e7; // where a point not seen is put: beyond the camera's far plane
  const $ = (id) => document.getElementById(id);

  // --- data --------------------------------------------------------------
  function decode(i, f) {
    const n = f.frames * f.points * 3;
    const bytes = new Uint8Array(n * 4);
    let off = 0;
    for (const el of document.querySelectorAll(`script[data-figure="${i}"]`)) {
      const bin = atob(el.textContent.trim());
      for (let k = 0; k < bin.length; k++) bytes[off + k] = bin.charCodeAt(k);
      off += bin.length;
      el.textContent = ""; // the text is no longer needed
    }
    if (off !== bytes.length) throw new Error(`figure ${i}: ${off} bytes of points, expected ${bytes.length}`);
    return new Float32Array(bytes.buffer);
  }

  // --- state -------------------------------------------------------------
  const state = { t: 0, playing: false, speed: 1, loop: true, last: null };
  const figures = meta.figures.map((f, i) => Object.assign({}, f, { data: decode(i, f), color: COLORS[i % COLORS.length] }));
  const lead = figures[0];

  function frameOf(f, t) {
    return Math.min(f.frames - 1, Math.max(0, Math.round(t / f.frame_time)));
  }
  function poseAt(t) {
    let k = -1;
    for (let i = 0; i < poseT.length; i++) if (poseT[i] <= t + 1e-6) k = i;
    return k;
  }

  // the lead figure's centre per frame (mean of the points seen), and the
  // bounds of its path: the camera follows the centre, the grid spans the path
  const centre = new Float32Array(lead.frames * 3);
  const box = { x0: Infinity, x1: -Infinity, z0: Infinity, z1: -Infinity, y1: -Infinity };
  {
    const d = lead.data, P = lead.points;
    let lastSeen = null, firstSeen = -1;
    for (let fr = 0; fr < lead.frames; fr++) {
      let sx = 0, sy = 0, sz = 0, n = 0;
      for (let p = 0; p < P; p++) {
        const o = (fr * P + p) * 3, x = d[o], y = d[o + 1], z = d[o + 2];
        if (x === x && y === y && z === z) {
          sx += x; sy += y; sz += z; n++;
          if (x < box.x0) box.x0 = x; if (x > box.x1) box.x1 = x;
          if (z < box.z0) box.z0 = z; if (z > box.z1) box.z1 = z;
          if (y > box.y1) box.y1 = y;
        }
      }
      if (n) { lastSeen = [sx / n, sy / n, sz / n]; if (firstSeen < 0) firstSeen = fr; }
      if (lastSeen) centre.set(lastSeen, fr * 3);
    }
    for (let fr = 0; fr < firstSeen; fr++) centre.set(centre.subarray(firstSeen * 3, firstSeen * 3 + 3), fr * 3);
    if (!isFinite(box.x0)) Object.assign(box, { x0: -1, x1: 1, z0: -1, z1: 1, y1: meta.floor + 1.7 });
  }
  // the figure's height: the median over frames of its top above the floor
  const height = (() => {
    const d = lead.data, P = lead.points, tops = [];
    const step = Math.max(1, Math.floor(lead.frames / 400));
    for (let fr = 0; fr < lead.frames; fr += step) {
      let top = -Infinity;
      for (let p = 0; p < P; p++) { const y = d[(fr * P + p) * 3 + 1]; if (y > top) top = y; }
      if (isFinite(top)) tops.push(top - meta.floor);
    }
    tops.sort((a, b) => a - b);
    const h = tops.length ? tops[tops.length >> 1] : 1.7;
    return h > 0.05 ? h : 1.7;
  })();

  // --- scene -------------------------------------------------------------
  const canvas = $("scene");
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color("#f4f4f1");
  const camera = new THREE.PerspectiveCamera(40, 1, 0.01, 5000);
  const controls = new THREE.OrbitControls(camera, canvas);
  controls.enableDamping = false;

  // the floor grid, 0.5 m cells (coarser on a long path), made of one
  // segment per cell edge: a long line crossing the camera's near plane is
  // lost by some software renderers
  const span = Math.min(400, Math.max(4, Math.ceil(Math.max(box.x1 - box.x0, box.z1 - box.z0) + 2 * height)));
  const cells = Math.min(80, Math.round(span / 0.5));
  const grid = (() => {
    const cx = (box.x0 + box.x1) / 2, cz = (box.z0 + box.z1) / 2, cell = span / cells, h0 = -span / 2;
    const pos = [], col = [];
    const dark = new THREE.Color(0x9a9a9a), light = new THREE.Color(0xd0d0d0);
    for (let i = 0; i <= cells; i++) {
      const c = 2 * i === cells ? dark : light;
      for (let j = 0; j < cells; j++) {
        const a = h0 + i * cell, b0 = h0 + j * cell, b1 = b0 + cell;
        pos.push(cx + a, meta.floor, cz + b0, cx + a, meta.floor, cz + b1, cx + b0, meta.floor, cz + a, cx + b1, meta.floor, cz + a);
        for (let k = 0; k < 4; k++) col.push(c.r, c.g, c.b);
      }
    }
    const g = new THREE.BufferGeometry();
    g.setAttribute("position", new THREE.Float32BufferAttribute(pos, 3));
    g.setAttribute("color", new THREE.Float32BufferAttribute(col, 3));
    return new THREE.LineSegments(g, new THREE.LineBasicMaterial({ vertexColors: true }));
  })();
  scene.add(grid);

  function tint(hex, amount) { // towards white
    return new THREE.Color(hex).lerp(new THREE.Color("#ffffff"), amount);
  }

  for (const f of figures) {
    const nb = f.bones.length / 2;
    f.linePos = new Float32Array(nb * 6);
    const lineCol = new Float32Array(nb * 6);
    const c = new THREE.Color(f.color), cl = tint(f.color, 0.45);
    for (let b = 0; b < nb; b++) {
      const col = f.left[b] ? cl : c;
      for (let e = 0; e < 2; e++) lineCol.set([col.r, col.g, col.b], b * 6 + e * 3);
    }
    f.geom = new THREE.LineSegmentsGeometry();
    f.geom.setPositions(f.linePos);
    f.geom.setColors(lineCol);
    f.mat = new THREE.LineMaterial({ vertexColors: true, linewidth: f.kind === "markers" ? 2 : 3, worldUnits: false });
    f.lines = new THREE.LineSegments2(f.geom, f.mat);
    f.lines.frustumCulled = false;
    f.lines.renderOrder = f === lead ? 2 : 1; // the lead figure over the others where they coincide
    scene.add(f.lines);
    f.pointPos = new Float32Array(f.points * 3);
    const pg = new THREE.BufferGeometry();
    pg.setAttribute("position", new THREE.BufferAttribute(f.pointPos, 3));
    const size = f.kind === "markers" ? 0.04 : 0.025;
    f.dots = new THREE.Points(pg, new THREE.PointsMaterial({ color: new THREE.Color(f.color), size, sizeAttenuation: true }));
    f.dots.frustumCulled = false;
    f.dots.renderOrder = f.lines.renderOrder;
    scene.add(f.dots);
  }

  function placeFigures(t) {
    for (const f of figures) {
      const fr = frameOf(f, t), d = f.data, base = fr * f.points * 3;
      for (let p = 0; p < f.points; p++) {
        const o = base + p * 3, x = d[o], y = d[o + 1], z = d[o + 2];
        const seen = x === x && y === y && z === z;
        f.pointPos[p * 3] = seen ? x : HIDDEN;
        f.pointPos[p * 3 + 1] = seen ? y : HIDDEN;
        f.pointPos[p * 3 + 2] = seen ? z : HIDDEN;
      }
      const nb = f.bones.length / 2;
      for (let b = 0; b < nb; b++) {
        const a = f.bones[2 * b] * 3, c = f.bones[2 * b + 1] * 3;
        const hide = f.pointPos[a] === HIDDEN || f.pointPos[c] === HIDDEN;
        for (let k = 0; k < 3; k++) {
          f.linePos[b * 6 + k] = hide ? HIDDEN : f.pointPos[a + k];
          f.linePos[b * 6 + 3 + k] = hide ? HIDDEN : f.pointPos[c + k];
        }
      }
      const buf = f.geom.attributes.instanceStart.data; // (both ends of every segment)
      buf.array.set(f.linePos);
      buf.needsUpdate = true;
      f.dots.geometry.attributes.position.needsUpdate = true;
    }
  }

  // camera: across the direction of travel (or the clip's widest
  // horizontal spread), far enough to see the figure whole; then it follows
  // the lead figure's centre on the floor, keeping the user's orbit
  const followed = new THREE.Vector3();
  function followPoint(t, out) {
    const fr = frameOf(lead, t);
    return out.set(centre[fr * 3], meta.floor + 0.5 * height, centre[fr * 3 + 2]);
  }
  function frameCamera(t) {
    const first = lead.frames - 1;
    let dx = centre[first * 3] - centre[0], dz = centre[first * 3 + 2] - centre[2];
    if (Math.hypot(dx, dz) < 0.5 * height) { dx = box.x1 - box.x0; dz = box.z1 - box.z0; }
    if (Math.hypot(dx, dz) < 1e-6) { dx = 1; dz = 0; }
    const len = Math.hypot(dx, dz);
    const side = new THREE.Vector3(-dz / len, 0, dx / len); // across the travel, level
    const dist = (0.7 * height) / Math.tan(THREE.MathUtils.degToRad(camera.fov / 2)) + 0.3 * height;
    followPoint(t, followed);
    controls.target.copy(followed);
    camera.position.copy(followed).addScaledVector(side, dist).add(new THREE.Vector3(0, 0.35 * height, 0));
    controls.update();
  }
  const moved = new THREE.Vector3();
  function follow(t) {
    followPoint(t, moved);
    const delta = moved.clone().sub(followed);
    if (delta.lengthSq() > 0) {
      camera.position.add(delta);
      controls.target.add(delta);
      followed.copy(moved);
      controls.update();
    }
  }

  function resize() {
    const r = canvas.parentElement.getBoundingClientRect();
    renderer.setSize(Math.max(1, r.width), Math.max(1, r.height), false);
    camera.aspect = Math.max(1, r.width) / Math.max(1, r.height);
    camera.updateProjectionMatrix();
    for (const f of figures) f.mat.resolution.set(Math.max(1, r.width), Math.max(1, r.height));
    drawTimeline();
    drawStrip();
  }

  // --- hover: each point's name -------------------------------------------
  const tip = $("tip");
  const raycaster = new THREE.Raycaster();
  canvas.addEventListener("pointermove", (ev) => {
    const r = canvas.getBoundingClientRect();
    const ndc = new THREE.Vector2(((ev.clientX - r.left) / r.width) * 2 - 1, -((ev.clientY - r.top) / r.height) * 2 + 1);
    raycaster.setFromCamera(ndc, camera);
    raycaster.params.Points.threshold = 0.03 * height;
    let best = null;
    for (const f of figures) {
      f.dots.geometry.computeBoundingSphere();
      for (const hit of raycaster.intersectObject(f.dots)) {
        if (hit.point.x === HIDDEN) continue;
        if (!best || hit.distanceToRay < best.hit.distanceToRay) best = { f, hit };
      }
    }
    if (!best) { tip.hidden = true; return; }
    const label = best.f.labels[best.hit.index] || `point ${best.hit.index}`;
    tip.textContent = figures.length > 1 ? `${label} · ${best.f.name}` : label;
    tip.style.left = `${ev.clientX - r.left + 12}px`;
    tip.style.top = `${ev.clientY - r.top + 8}px`;
    tip.hidden = false;
  });
  canvas.addEventListener("pointerleave", () => { tip.hidden = true; });

  // --- time --------------------------------------------------------------
  function setTime(t, opts) {
    state.t = Math.min(duration, Math.max(0, t));
    if (!(opts && opts.keepPlaying)) setPlaying(false);
    show();
  }
  function setPlaying(on) {
    state.playing = on;
    state.last = null;
    $("play").textContent = on ? "❚❚" : "▶";
  }
  function stepFrame(n) { setTime((frameOf(lead, state.t) + n) * lead.frame_time); }
  function jumpPose(k) {
    if (!poseT.length) return;
    k = Math.min(poseT.length - 1, Math.max(0, k));
    setTime(poseT[k]);
  }
  function nextPose(dir) {
    if (!poseT.length) return;
    const eps = 0.5 * lead.frame_time;
    if (dir > 0) { for (let k = 0; k < poseT.length; k++) if (poseT[k] > state.t + eps) return jumpPose(k); jumpPose(poseT.length - 1); }
    else { for (let k = poseT.length - 1; k >= 0; k--) if (poseT[k] < state.t - eps) return jumpPose(k); jumpPose(0); }
  }

  function show() {
    placeFigures(state.t);
    follow(state.t);
    const k = poseAt(state.t);
    const onPose = k >= 0 && Math.abs(poseT[k] - state.t) < 0.5 * lead.frame_time;
    $("clock").textContent = `${state.t.toFixed(3)} s / ${duration.toFixed(3)} s · frame ${frameOf(lead, state.t)}` +
      (poseT.length ? ` · ${onPose ? "at" : "after"} pose ${Math.max(k, 0)}${posePart[Math.max(k, 0)] ? " (" + posePart[Math.max(k, 0)] + ")" : ""} of ${poseT.length}` : "");
    drawTimeline();
    drawStrip();
  }

  // --- timeline (the whole clip) and the timing strip (a window of it) -------
  const LABELS = 150; // pixels of row labels left of the strip, and of the timeline's margin
  function sizeCanvas(c, cssHeight) {
    const dpr = window.devicePixelRatio || 1, w = c.clientWidth || c.parentElement.clientWidth;
    c.style.height = `${cssHeight}px`;
    if (c.width !== Math.round(w * dpr) || c.height !== Math.round(cssHeight * dpr)) {
      c.width = Math.round(w * dpr); c.height = Math.round(cssHeight * dpr);
    }
    const g = c.getContext("2d");
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    return { g, w, h: cssHeight };
  }

  const tl = $("timeline");
  function tlX(t, w) { return LABELS + (t / duration) * (w - LABELS - 12); }
  function tlT(x, w) { return ((x - LABELS) / (w - LABELS - 12)) * duration; }
  function drawTimeline() {
    const { g, w, h } = sizeCanvas(tl, 34);
    g.clearRect(0, 0, w, h);
    g.fillStyle = "#555"; g.font = "11px system-ui, sans-serif"; g.textBaseline = "middle";
    g.fillText(poseT.length ? `${poseT.length} poses` : "no poses (a clip)", 10, h / 2);
    g.fillStyle = "#e6e6e2"; g.fillRect(LABELS, 12, w - LABELS - 12, 10);
    g.fillStyle = "#9fb6d9"; g.fillRect(LABELS, 12, tlX(state.t, w) - LABELS, 10);
    g.strokeStyle = "#333"; g.lineWidth = 1;
    poseT.forEach((t, k) => {
      const x = Math.round(tlX(t, w)) + 0.5;
      g.strokeStyle = posePart[k] ? PARTIAL : "#333"; g.setLineDash(posePart[k] ? [3, 2] : []);
      g.beginPath(); g.moveTo(x, 6); g.lineTo(x, 28); g.stroke();
    });
    g.setLineDash([]);
    const x = tlX(state.t, w);
    g.fillStyle = "#d62728"; g.fillRect(x - 1.5, 2, 3, 30);
  }
  function scrubAt(ev, c, toTime) {
    const r = c.getBoundingClientRect();
    const x = ev.clientX - r.left;
    let best = -1, bestD = 5;
    for (let k = 0; k < poseT.length; k++) { const d = Math.abs(xOfTime(c, poseT[k], r.width) - x); if (d < bestD) { best = k; bestD = d; } }
    if (best >= 0) jumpPose(best); else setTime(toTime(x, r.width));
  }
  function xOfTime(c, t, w) { return c === tl ? tlX(t, w) : stX(t, w); }
  let dragging = false;
  tl.addEventListener("pointerdown", (ev) => { dragging = true; tl.setPointerCapture(ev.pointerId); scrubAt(ev, tl, tlT); });
  tl.addEventListener("pointermove", (ev) => { if (dragging) setTime(tlT(ev.clientX - tl.getBoundingClientRect().left, tl.getBoundingClientRect().width)); });
  tl.addEventListener("pointerup", () => { dragging = false; });

  const strip = $("strip");
  const WINDOW = duration <= 20 ? duration : 10; // seconds shown by the strip
  function stWindow() {
    if (WINDOW >= duration) return [0, duration];
    const lo = Math.min(Math.max(0, state.t - 0.4 * WINDOW), duration - WINDOW);
    return [lo, lo + WINDOW];
  }
  function stX(t, w) { const [lo, hi] = stWindow(); return LABELS + ((t - lo) / (hi - lo)) * (w - LABELS - 12); }
  function stT(x, w) { const [lo, hi] = stWindow(); return lo + ((x - LABELS) / (w - LABELS - 12)) * (hi - lo); }
  const HEAD = 16;
  const nRows = timing ? timing.rows.length + timing.layers.length : 0;
  let rowH = 0; // pixels a row: the strip takes at most about a third of the window
  function drawStrip() {
    if (!timing) return;
    rowH = Math.max(4, Math.min(13, Math.floor((0.3 * window.innerHeight) / Math.max(nRows, 1))));
    const { g, w } = sizeCanvas(strip, HEAD + nRows * rowH + 4);
    const [lo, hi] = stWindow(), pad = 2 * lead.frame_time;
    const inWin = (t) => t >= lo - pad && t <= hi + pad;
    g.clearRect(0, 0, w, strip.height);
    const y = (r) => HEAD + r * rowH;
    timing.rows.forEach((row, r) => { if (row.shade) { g.fillStyle = "#ececec"; g.fillRect(0, y(r), w, rowH); } });
    g.save(); g.beginPath(); g.rect(LABELS - 10, 0, w - LABELS + 10, strip.height); g.clip();
    g.strokeStyle = "#c4c4c4"; g.lineWidth = 1;
    g.fillStyle = "#444"; g.font = "10px system-ui, sans-serif"; g.textAlign = "center"; g.textBaseline = "top";
    let lastLabel = -1e9;
    poseT.forEach((t, k) => {
      if (!inWin(t)) return;
      const x = Math.round(stX(t, w)) + 0.5;
      g.strokeStyle = posePart[k] ? PARTIAL : "#c4c4c4"; g.setLineDash(posePart[k] ? [4, 3] : []);
      g.beginPath(); g.moveTo(x, HEAD - 3); g.lineTo(x, y(nRows)); g.stroke();
      g.fillStyle = posePart[k] ? PARTIAL : "#444";
      if (x - lastLabel > 18) { g.fillText(String(k), x, 2); lastLabel = x; }
    });
    g.setLineDash([]); g.strokeStyle = "#c4c4c4"; g.fillStyle = "#444";
    g.fillStyle = "rgba(44, 160, 44, 0.3)";
    for (const c of timing.contacts) for (const [s, e] of c.spans) {
      if (e < lo - pad || s > hi + pad) continue;
      g.fillRect(stX(s, w), y(c.row) + 1, Math.max(1, stX(e, w) - stX(s, w)), rowH - 2);
    }
    const rad = Math.max(1.5, Math.min(3, rowH / 3));
    timing.rows.forEach((row, r) => {
      const cy = y(r) + rowH / 2;
      for (const [tk, te] of row.ext) {
        if (!inWin(tk) && !inWin(te)) continue;
        const col = te < tk - 1e-9 ? "#1f77b4" : te > tk + 1e-9 ? "#d62728" : "#737373";
        g.strokeStyle = col; g.fillStyle = col; g.lineWidth = 1.4;
        if (te !== tk) { g.beginPath(); g.moveTo(stX(tk, w), cy); g.lineTo(stX(te, w), cy); g.stroke(); }
        g.beginPath(); g.arc(stX(te, w), cy, rad, 0, 2 * Math.PI); g.fill();
      }
      g.strokeStyle = "#000"; g.fillStyle = "#fff"; g.lineWidth = 0.8;
      for (const te of row.edit) {
        if (!inWin(te)) continue;
        const x = stX(te, w), d = rad + 0.5;
        g.beginPath(); g.moveTo(x, cy - d); g.lineTo(x + d, cy); g.lineTo(x, cy + d); g.lineTo(x - d, cy); g.closePath(); g.fill(); g.stroke();
      }
    });
    timing.layers.forEach((times, n) => {
      const cy = y(timing.rows.length + n) + rowH / 2;
      g.fillStyle = "#8e44ad";
      for (const t of times) if (inWin(t)) { g.beginPath(); g.arc(stX(t, w), cy, rad, 0, 2 * Math.PI); g.fill(); }
    });
    const xn = stX(state.t, w);
    g.fillStyle = "#000"; g.fillRect(xn - 1, 0, 2, y(nRows));
    g.restore();
    // row labels (every n-th when the rows are thin)
    g.fillStyle = "#333"; g.font = `${Math.min(10, Math.max(7, rowH - 1))}px system-ui, sans-serif`;
    g.textAlign = "right"; g.textBaseline = "middle";
    const every = Math.max(1, Math.ceil(8 / rowH));
    const names = timing.rows.map((r) => r.name).concat(timing.layers.map((_, n) => `layer ${n + 1} poses`));
    names.forEach((name, r) => { if (r % every === 0) g.fillText(name, LABELS - 6, y(r) + rowH / 2); });
    g.textAlign = "left"; g.textBaseline = "top"; g.fillStyle = "#777"; g.font = "10px system-ui, sans-serif";
    g.fillText(WINDOW < duration ? `${lo.toFixed(1)}-${hi.toFixed(1)} s` : "pose", 6, 2);
  }
  strip.addEventListener("pointerdown", (ev) => scrubAt(ev, strip, stT));

  // --- controls ----------------------------------------------------------
  $("play").addEventListener("click", () => {
    if (!state.playing && state.t >= duration - 1e-9) state.t = 0;
    setPlaying(!state.playing);
  });
  $("back").addEventListener("click", () => stepFrame(-1));
  $("next").addEventListener("click", () => stepFrame(1));
  $("prevpose").addEventListener("click", () => nextPose(-1));
  $("nextpose").addEventListener("click", () => nextPose(1));
  $("speed").addEventListener("change", (ev) => { state.speed = Number(ev.target.value); });
  $("loop").addEventListener("change", (ev) => { state.loop = ev.target.checked; });
  document.addEventListener("keydown", (ev) => {
    if (ev.target instanceof HTMLSelectElement || ev.target instanceof HTMLInputElement) return;
    if (ev.key === " ") { ev.preventDefault(); $("play").click(); }
    else if (ev.key === "ArrowLeft") { ev.preventDefault(); stepFrame(-1); }
    else if (ev.key === "ArrowRight") { ev.preventDefault(); stepFrame(1); }
    else if (ev.key === "[") nextPose(-1);
    else if (ev.key === "]") nextPose(1);
  });

  // #t=SECONDS or #pose=K: open paused there
  function fromHash() {
    const m = /^#(t|pose)=(-?[0-9.]+)$/.exec(location.hash);
    if (!m) return false;
    const v = Number(m[2]);
    if (!isFinite(v)) return false;
    if (m[1] === "t") setTime(v);
    else if (poseT.length) jumpPose(Math.round(v));
    else { setTime(0); message(`#pose=${m[2]}: this clip has no poses (view a document for them)`); }
    return true;
  }
  function message(text) { const el = $("message"); el.textContent = text; el.hidden = false; }
  window.addEventListener("hashchange", fromHash);

  // the header: title and one swatch per figure
  $("title").textContent = meta.title;
  document.title = `${meta.title} · staggered view`;
  const legend = $("legend");
  for (const f of figures) {
    const s = document.createElement("span"); s.className = "swatch"; s.style.background = f.color;
    legend.append(s, document.createTextNode(`${f.name} (${f.kind === "markers" ? `${f.points} markers` : "skeleton"})`));
  }
  if (!timing) $("timing").hidden = true;

  // --- go ----------------------------------------------------------------
  window.addEventListener("resize", resize);
  const paused = fromHash();
  frameCamera(state.t);
  resize();
  show();
  if (!paused) setPlaying(true);
  function tick(now) {
    if (state.playing) {
      if (state.last !== null) {
        let t = state.t + ((now - state.last) / 1000) * state.speed;
        if (t > duration) {
          if (state.loop) t %= duration; else { t = duration; setPlaying(false); }
        }
        state.t = t;
        show();
      }
      state.last = now;
    }
    renderer.render(scene, camera);
    if (document.body.dataset.ready !== "1") document.body.dataset.ready = "1";
    requestAnimationFrame(tick);
  }
  requestAnimationFrame(tick);
  // for scripts and tests: the state and the time of each pose
  const stripX = (t) => stX(t, strip.clientWidth);
  // where point p of figure i is drawn, in CSS pixels of the 3D view (null: hidden)
  function screenOf(i, p) {
    const f = figures[i], v = new THREE.Vector3().fromArray(f.pointPos, p * 3);
    if (v.x === HIDDEN) return null;
    v.project(camera);
    const r = canvas.getBoundingClientRect();
    return { x: ((v.x + 1) / 2) * r.width, y: ((1 - v.y) / 2) * r.height };
  }
  window.staggeredView = { state, poseT, setTime, jumpPose, stripX, screenOf, camera, controls, height, box, figures: figures.map((f) => ({ name: f.name, color: f.color })) };
})();
