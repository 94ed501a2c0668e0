// zipon annotate: the page. Plain JS, no dependencies; user text is only ever set with textContent.
"use strict";

const $ = (id) => document.getElementById(id);
const S = {
  scene: null, data: null, layers: {}, layer: "color",
  view: { s: 40, ox: 0, oy: 0 },
  doc: null, etag: null, goal: -1, selectedObject: null, kinds: [],
  objects: null, objectsDirty: false, object: -1, proposals: [], heatmap: null,
  drawing: null, mode: null, play: null, route: null, routeFor: -1, clicked: null,
  floor: 0,  // the floor shown (a building's floors: S.data.floors; a single-floor scene is floor 0)
};

function el(tag, text, cls) {
  const e = document.createElement(tag);
  if (text !== undefined && text !== null) e.textContent = String(text);
  if (cls) e.className = cls;
  return e;
}
function status(text) { $("status").textContent = text; }

async function api(path, opts = {}) {
  const init = { method: opts.method || "GET", headers: {} };
  if (opts.body !== undefined) { init.body = JSON.stringify(opts.body); init.headers["Content-Type"] = "application/json"; }
  if (opts.ifMatch) init.headers["If-Match"] = '"' + opts.ifMatch + '"';
  const r = await fetch(path, init);
  const type = r.headers.get("content-type") || "";
  const body = type.includes("json") ? await r.json() : null;
  return { ok: r.ok, status: r.status, body, etag: (r.headers.get("etag") || "").replace(/"/g, "") };
}
const scenePath = (rest) => `/api/scenes/${encodeURIComponent(S.scene)}${rest || ""}`;
// a building's requests name the floor shown; a single-floor scene's are as they always were
const building = () => Boolean(S.data && S.data.floors && S.data.floors.length > 1);
const floorQuery = (sep) => (building() ? `${sep}floor=${S.floor}` : "");
const onFloor = (x) => (x.floor || 0) === S.floor;
const floorName = (k) => { const f = S.data.floors[k]; return f ? `floor ${k} (${f.name}, ${f.floor_z_m.toFixed(2)} m)` : `floor ${k}`; };

// ------------------------------------------------------------------ the map: world metres <-> screen pixels

const canvas = $("map");
const ctx = canvas.getContext("2d");
const toScreen = (x, y) => [S.view.ox + x * S.view.s, S.view.oy - y * S.view.s];
const toWorld = (px, py) => [(px - S.view.ox) / S.view.s, (S.view.oy - py) / S.view.s];

function fit() {
  const [x0, x1, y0, y1] = S.data.grid.observed_xy;
  const w = canvas.clientWidth, h = canvas.clientHeight;
  S.view.s = 0.95 * Math.min(w / (x1 - x0), h / (y1 - y0));
  S.view.ox = w / 2 - S.view.s * (x0 + x1) / 2;
  S.view.oy = h / 2 + S.view.s * (y0 + y1) / 2;
}

function hue(i, n) { return `hsl(${Math.round(360 * i / Math.max(n, 1))} 75% 45%)`; }

function poly(points, close = true) {
  ctx.beginPath();
  points.forEach(([x, y], i) => { const [u, v] = toScreen(x, y); i ? ctx.lineTo(u, v) : ctx.moveTo(u, v); });
  if (close) ctx.closePath();
}

function draw() {
  const dpr = window.devicePixelRatio || 1;
  canvas.width = canvas.clientWidth * dpr; canvas.height = canvas.clientHeight * dpr;
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.clearRect(0, 0, canvas.clientWidth, canvas.clientHeight);
  if (!S.data) return;
  const shown = S.layers[layerKey(S.layer)];  // the layer's picture of (about) the window shown, where it lies
  ctx.imageSmoothingEnabled = false;
  if (shown && shown.img) {
    const [x0, x1, y0, y1] = shown.extent, [u0, v0] = toScreen(x0, y1), [u1, v1] = toScreen(x1, y0);
    ctx.drawImage(shown.img, u0, v0, u1 - u0, v1 - v0);
  }
  scheduleLayer();
  if (S.heatmap && S.heatmap.complete) {
    const [hx0, hx1, hy0, hy1] = S.heatmapExtent, [a0, b0] = toScreen(hx0, hy1), [a1, b1] = toScreen(hx1, hy0);
    ctx.drawImage(S.heatmap, a0, b0, a1 - a0, b1 - b0);
  }
  if ($("show-rooms").checked) {
    S.data.rooms.forEach((r, i) => { if (r.polygon.length < 3 || !onFloor(r)) return; poly(r.polygon); ctx.strokeStyle = hue(i, S.data.rooms.length); ctx.lineWidth = 2; ctx.setLineDash([6, 4]); ctx.stroke(); ctx.setLineDash([]);
      const c = centroid(r.polygon), [u, v] = toScreen(c[0], c[1]); ctx.fillStyle = "#333"; ctx.font = "12px sans-serif"; ctx.fillText(r.name || r.id, u - 20, v); });
  }
  if ($("show-trajectory").checked && S.data.trajectory.length) {
    // a building's poses carry their floor (4th value): the runs on the floor shown
    runs(S.data.trajectory, (p) => (p[3] || 0) === S.floor).forEach((run) => {
      poly(run.map((p) => [p[0], p[1]]), false); ctx.strokeStyle = "#7a3db8"; ctx.lineWidth = 1.5; ctx.stroke(); });
  }
  const goalOf = {};
  if (S.doc) S.doc.goals.forEach((gl, i) => gl.objects.forEach((k) => { goalOf[k] = i; }));
  stairMarks();
  const objects = objectShapes();
  if ($("show-objects").checked) {
    objects.forEach((o) => {
      poly(o.footprint);
      const gi = goalOf[o.key];
      if ($("show-goals").checked && gi !== undefined) { ctx.fillStyle = hue(gi, S.doc.goals.length); ctx.globalAlpha = 0.45; ctx.fill(); ctx.globalAlpha = 1; }
      ctx.strokeStyle = o.key === S.selectedObject ? "#1d6fd8" : "#555"; ctx.lineWidth = o.key === S.selectedObject ? 3 : 1; ctx.stroke();
      if (S.view.s > 25) { const [u, v] = toScreen(o.mass_center[0], o.mass_center[1]); label(o.key, u + 6, v + 12); }
    });
  }
  if ($("show-routes").checked) {
    S.data.routes.forEach((r) => { drawLegs(r.legs || [{ floor: 0, path: r.path }], "#d2691e", 2);
      if ((r.start_floor || 0) === S.floor) startMark(r.start, "#d2691e"); });
  }
  if (S.goal >= 0 && S.doc) highlightLandmarks();
  if (S.route && S.route.path.length) {
    drawLegs(S.route.legs, "#0a7d2c", 3);
    if (S.route.start_floor === S.floor) startMark(S.route.start, "#0a7d2c");
    S.route.stairs.forEach((st) => {  // where the route takes the stairs, on each floor it crosses
      if (st.from_floor === S.floor) stairLabel(st.from_xy, `${st.up ? "up" : "down"} to floor ${st.to_floor}`, "#0a7d2c");
      if (st.to_floor === S.floor) stairLabel(st.to_xy, `from floor ${st.from_floor}`, "#0a7d2c");
    });
  }
  if ($("show-goals").checked && S.doc) {
    const byKey = Object.fromEntries(objects.map((o) => [o.key, o]));
    S.doc.goals.forEach((gl, i) => { const o = byKey[gl.objects[0]]; if (!o) return; marker(String(i + 1), o.mass_center, i === S.goal); });  // the floor's objects only
  }
  S.proposals.forEach((p) => { poly(p.footprint); ctx.strokeStyle = "#ff7f00"; ctx.lineWidth = 2; ctx.setLineDash([5, 3]); ctx.stroke(); ctx.setLineDash([]);
    const [u, v] = toScreen(p.center_xy[0], p.center_xy[1]); ctx.fillStyle = "#ff7f00"; ctx.font = "bold 12px sans-serif"; ctx.fillText(`#${p.rank} ${p.score.toFixed(2)}`, u + 4, v - 4); });
  if (S.drawing && S.drawing.points.length) { poly(S.drawing.points, false); ctx.strokeStyle = "#1d6fd8"; ctx.lineWidth = 2; ctx.stroke();
    S.drawing.points.forEach(([x, y]) => { const [u, v] = toScreen(x, y); ctx.fillStyle = "#1d6fd8"; ctx.fillRect(u - 3, v - 3, 6, 6); }); }
  if (S.play && S.play.poses.length) {
    poly(S.play.poses.map((p) => [p[0], p[1]]), false); ctx.strokeStyle = "#0057b8"; ctx.lineWidth = 3; ctx.stroke();
    startMark(S.play.pose, "#0057b8");
  }
  if (S.clicked) { const [u, v] = toScreen(S.clicked[0], S.clicked[1]); ctx.strokeStyle = "#e00"; ctx.lineWidth = 2; ctx.beginPath(); ctx.arc(u, v, 7, 0, 2 * Math.PI); ctx.stroke(); }
  axes();
  scaleBar();
}

// consecutive items of ``list`` that pass ``keep``, as runs of at least two
function runs(list, keep) {
  const out = []; let run = [];
  list.forEach((p) => { if (keep(p)) run.push(p); else { if (run.length > 1) out.push(run); run = []; } });
  if (run.length > 1) out.push(run);
  return out;
}

function drawLegs(legs, colour, width) {
  legs.filter((l) => l.floor === S.floor && l.path.length > 1).forEach((l) => { poly(l.path, false); ctx.strokeStyle = colour; ctx.lineWidth = width; ctx.stroke(); });
}

function stairLabel(xy, text, colour) {
  const [u, v] = toScreen(xy[0], xy[1]);
  // above the stair's own label (a stair often lies at the edge of the map, where the axis band is)
  ctx.font = "bold 11px sans-serif"; ctx.lineWidth = 3; ctx.strokeStyle = "#fff"; ctx.strokeText(text, u + 10, v - 18);
  ctx.fillStyle = colour; ctx.fillText(text, u + 10, v - 18);
}

// the stairs' ends on the floor shown: a triangle pointing up at a foot, down at a head
function stairMarks() {
  (S.data.stairs || []).forEach((st) => [[st.bottom, true], [st.top, false]].forEach(([end, up]) => {
    if (end.floor !== S.floor) return;
    const [u, v] = toScreen(end.xy[0], end.xy[1]), d = up ? -1 : 1;
    ctx.beginPath(); ctx.moveTo(u, v + 9 * d); ctx.lineTo(u - 8, v - 6 * d); ctx.lineTo(u + 8, v - 6 * d); ctx.closePath();
    ctx.fillStyle = "#ff9800"; ctx.fill(); ctx.strokeStyle = "#000"; ctx.lineWidth = 1; ctx.stroke();
    label(`${st.kind} ${up ? "up" : "down"} to floor ${up ? st.top.floor : st.bottom.floor}`, u + 10, v - 4);
  }));
}

function axes() {
  // metre ticks along the left and bottom edges
  const w = canvas.clientWidth, h = canvas.clientHeight;
  const step = [0.5, 1, 2, 5, 10, 20].find((v) => v * S.view.s > 60) || 50;
  const [xa, ya] = toWorld(0, h), [xb, yb] = toWorld(w, 0);
  ctx.fillStyle = "#fffd"; ctx.fillRect(0, h - 16, w, 16); ctx.fillRect(0, 0, 30, h);
  ctx.fillStyle = "#333"; ctx.font = "10px sans-serif"; ctx.strokeStyle = "#333"; ctx.lineWidth = 1;
  for (let x = Math.ceil(xa / step) * step; x <= xb; x += step) {
    const [u] = toScreen(x, 0); ctx.beginPath(); ctx.moveTo(u, h - 16); ctx.lineTo(u, h - 11); ctx.stroke(); ctx.fillText(`${+x.toFixed(1)}`, u - 6, h - 2);
  }
  for (let y = Math.ceil(ya / step) * step; y <= yb; y += step) {
    const [, v] = toScreen(0, y); ctx.beginPath(); ctx.moveTo(30, v); ctx.lineTo(25, v); ctx.stroke(); ctx.fillText(`${+y.toFixed(1)}`, 2, v + 3);
  }
  ctx.fillText("x, y in metres" + (building() ? ` · ${floorName(S.floor)}` : ""), 34, h - 20);
}

function label(text, u, v) {
  ctx.font = "10px sans-serif"; ctx.lineWidth = 3; ctx.strokeStyle = "#fff"; ctx.strokeText(text, u, v);
  ctx.fillStyle = "#222"; ctx.fillText(text, u, v);
}

function startMark(start, colour) {
  const [u, v] = toScreen(start[0], start[1]);
  ctx.fillStyle = colour; ctx.beginPath(); ctx.arc(u, v, 5, 0, 2 * Math.PI); ctx.fill();
  ctx.strokeStyle = "#000"; ctx.lineWidth = 2; ctx.beginPath(); ctx.moveTo(u, v);
  ctx.lineTo(u + 14 * Math.cos(start[2]), v - 14 * Math.sin(start[2])); ctx.stroke();
}

function marker(text, xy, selected) {
  const [u, v] = toScreen(xy[0], xy[1]);
  ctx.fillStyle = selected ? "#1d6fd8" : "#fff"; ctx.strokeStyle = "#000"; ctx.lineWidth = 1.5;
  ctx.beginPath(); ctx.arc(u, v, 9, 0, 2 * Math.PI); ctx.fill(); ctx.stroke();
  ctx.fillStyle = selected ? "#fff" : "#000"; ctx.font = "bold 11px sans-serif"; ctx.textAlign = "center"; ctx.fillText(text, u, v + 4); ctx.textAlign = "start";
}

function highlightLandmarks() {
  // objects the landmark feedback names (by key, or by class word) are outlined in magenta and linked to the goal
  const gl = S.doc.goals[S.goal], objects = objectShapes(), byKey = Object.fromEntries(objects.map((o) => [o.key, o]));
  const text = (gl.feedback.landmark || "").toLowerCase(), first = byKey[gl.objects[0]];
  if (!first || !text) return;
  // an object named by its key, else the nearest object of each class the text names
  const others = objects.filter((o) => !gl.objects.includes(o.key))
    .sort((a, b) => dist(a.mass_center, first.mass_center) - dist(b.mass_center, first.mass_center));
  const near = others.filter((o) => text.includes(o.key.toLowerCase()));
  new Set(others.map((o) => o.cls)).forEach((cls) => {
    if (new RegExp(`\\b${cls.toLowerCase()}\\b`).test(text)) near.push(others.find((o) => o.cls === cls));
  });
  near.forEach((o) => { poly(o.footprint); ctx.strokeStyle = "#d0008f"; ctx.lineWidth = 3; ctx.stroke();
    const [a, b] = [toScreen(...first.mass_center), toScreen(...o.mass_center)]; ctx.setLineDash([4, 4]); ctx.beginPath(); ctx.moveTo(...a); ctx.lineTo(...b); ctx.stroke(); ctx.setLineDash([]); });
}

const dist = (a, b) => Math.hypot(a[0] - b[0], a[1] - b[1]);
function centroid(p) { let x = 0, y = 0; p.forEach((q) => { x += q[0]; y += q[1]; }); return [x / p.length, y / p.length]; }

function scaleBar() {
  const w = canvas.clientWidth, h = canvas.clientHeight;
  const nice = [0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50, 100];
  const m = nice.find((v) => v * S.view.s > 80) || 100;
  const px = m * S.view.s, x = w - px - 16, y = h - 28;
  ctx.fillStyle = "#fffc"; ctx.fillRect(x - 6, y - 18, px + 12, 24);
  ctx.fillStyle = "#000"; ctx.fillRect(x, y, px, 4); ctx.font = "11px sans-serif"; ctx.fillText(`${m} m`, x + px / 2 - 10, y - 4);
  ctx.fillText("N ↑", w - 34, 18);
}

function allObjects() {
  // the objects: the objects file being edited when it is open, else the built ones (every floor)
  if (S.objects) return S.objects.objects.filter((o) => o.footprint && o.footprint.length >= 3).map((o) => ({ ...o, mass_center: o.mass_center || centroid(o.footprint) }));
  return S.data ? S.data.objects : [];
}
function objectShapes() { return allObjects().filter(onFloor); }  // the objects drawn: the floor shown

function inside(pt, polygon) {
  let c = false;
  for (let i = 0, j = polygon.length - 1; i < polygon.length; j = i++) {
    const [xi, yi] = polygon[i], [xj, yj] = polygon[j];
    if ((yi > pt[1]) !== (yj > pt[1]) && pt[0] < (xj - xi) * (pt[1] - yi) / (yj - yi) + xi) c = !c;
  }
  return c;
}

let drag = null;
canvas.addEventListener("mousedown", (e) => {
  drag = { x: e.offsetX, y: e.offsetY, moved: false, object: null };
  // shift + drag on the selected object of the objects file moves its footprint
  const o = S.objects && S.object >= 0 ? S.objects.objects[S.object] : null;
  if (e.shiftKey && o && inside(toWorld(e.offsetX, e.offsetY), o.footprint)) drag.object = o;
});
canvas.addEventListener("mousemove", (e) => {
  const [x, y] = toWorld(e.offsetX, e.offsetY);
  $("cursor").textContent = `x ${x.toFixed(2)} m, y ${y.toFixed(2)} m`;
  if (!drag) return;
  const dx = e.offsetX - drag.x, dy = e.offsetY - drag.y;
  if (Math.abs(dx) + Math.abs(dy) > 3) drag.moved = true;
  if (drag.moved && drag.object) {
    const mx = dx / S.view.s, my = -dy / S.view.s, r3 = (v) => Math.round(v * 1000) / 1000;
    drag.object.footprint = drag.object.footprint.map(([x, y]) => [r3(x + mx), r3(y + my)]);
    drag.object.mass_center = centroid(drag.object.footprint);
    drag.x = e.offsetX; drag.y = e.offsetY; draw();
  } else if (drag.moved) { S.view.ox += dx; S.view.oy += dy; drag.x = e.offsetX; drag.y = e.offsetY; draw(); }
});
canvas.addEventListener("mouseup", (e) => {
  const d = drag; drag = null;
  if (d && d.object && d.moved) { selectObject(S.object); validateObjects(); return; }
  if (d && !d.moved) click(toWorld(e.offsetX, e.offsetY));
});
canvas.addEventListener("wheel", (e) => {
  e.preventDefault();
  const k = Math.exp(-e.deltaY * 0.0015), [x, y] = toWorld(e.offsetX, e.offsetY);
  S.view.s *= k; S.view.ox = e.offsetX - x * S.view.s; S.view.oy = e.offsetY + y * S.view.s; draw();
}, { passive: false });

function setMode(text, kind) { S.mode = text ? kind || "draw" : null; $("mode").textContent = text || ""; $("mode").style.display = text ? "block" : "none"; }

async function click(pt) {
  const r3 = (v) => Math.round(v * 1000) / 1000;
  pt = [r3(pt[0]), r3(pt[1])];
  if (S.drawing) { S.drawing.points.push(pt); draw(); return; }
  if (S.mode === "route") { setMode(null); await routePreview([pt[0], pt[1], 0], S.floor); return; }
  const hit = objectShapes().find((o) => inside(pt, o.footprint));
  S.selectedObject = hit ? hit.key : null;
  if (hit && S.doc) { const gi = S.doc.goals.findIndex((gl) => gl.objects.includes(hit.key)); if (gi >= 0) selectGoal(gi); }
  if (hit && S.objects) { const oi = S.objects.objects.findIndex((o) => o.key === hit.key); if (oi >= 0) selectObject(oi); }
  S.clicked = pt; draw();
  await showViews(pt);
}

// ------------------------------------------------------------------ frames that saw a place

async function showViews(pt) {
  const box = $("views"); box.replaceChildren(el("p", `frames that saw (${pt[0]}, ${pt[1]}) …`));
  const r = await api(scenePath(`/seen?x=${pt[0]}&y=${pt[1]}${floorQuery("&")}`));
  box.replaceChildren();
  if (!r.ok) { box.append(el("p", r.body.error, "error")); return; }
  box.append(el("p", `${r.body.frames.length} of ${r.body.candidates} frames facing it saw (${pt[0]}, ${pt[1]})${building() ? " on " + floorName(S.floor) : ""}; nearest first`, "note"));
  r.body.frames.forEach((f) => {
    const fig = el("figure"), img = el("img");
    img.alt = `frame ${f.frame}`;
    img.src = scenePath(`/frames/${f.frame}.png?u=${f.pixel[0]}&v=${f.pixel[1]}`);
    fig.append(img, el("figcaption", `frame ${f.frame}: ${f.distance_m} m away, camera at (${f.pose[0]}, ${f.pose[1]}) heading ${Math.round(f.pose[2] * 180 / Math.PI)}°`));
    box.append(fig);
  });
}

// ------------------------------------------------------------------ goals

function goalFloor(gl) {
  const o = allObjects().find((x) => x.key === gl.objects[0]);
  return o ? o.floor || 0 : null;
}

function goalRow(gl, i) {
  const f = building() ? goalFloor(gl) : null;
  const li = el("li", `${gl.name} (${gl.type})` + (f !== null ? ` · floor ${f}` : ""));
  li.dataset.index = i;
  if (i === S.goal) li.className = "selected";
  li.addEventListener("click", () => selectGoal(i));
  return li;
}

function renderGoals() {
  $("goal-list").replaceChildren(...(S.doc ? S.doc.goals.map(goalRow) : []));
}

// ------------------------------------------------------------------ the feedback kinds (the server's registry)

// how each form of a kind's value is shown in its field and read back from it
const FORMS = {
  text: { rows: 3, title: "", show: (v) => v || "", read: (t) => t },
  optional_text: { rows: 2, title: "empty = none", show: (v) => v || "", read: (t) => (t.trim() ? t : null) },
  key_lines: {
    rows: 3, title: "one line per object: key: what the user says",
    show: (v) => Object.entries(v || {}).map(([k, t]) => `${k}: ${t}`).join("\n"),
    read: (t) => {
      const out = {};
      t.split("\n").map((l) => l.trim()).filter(Boolean).forEach((l) => {
        const at = l.indexOf(":"); if (at > 0) out[l.slice(0, at).trim()] = l.slice(at + 1).trim(); else out[l] = "";
      });
      return out;
    },
  },
};

async function loadFeedbackKinds() {
  const r = await api("/api/feedback-kinds");
  if (!r.ok) { status(r.body.error); return false; }
  S.kinds = r.body.kinds;
  $("feedback-fields").replaceChildren(...S.kinds.map((k) => {
    const label = el("label", `${k.name} `), t = el("textarea");
    t.name = k.name; t.rows = FORMS[k.form].rows; t.title = [k.description, FORMS[k.form].title].filter(Boolean).join("; ");
    label.append(t);
    return label;
  }));
  return true;
}

function selectGoal(i) {
  const on = building() ? goalFloor(S.doc.goals[i]) : null;
  if (on !== null && on !== S.floor) setFloor(on);  // a goal is shown on its own floor
  S.goal = i; S.route = null; $("route-text").textContent = ""; $("route-use").hidden = true;
  const f = $("goal-form"), gl = S.doc.goals[i];
  f.hidden = false;
  f.name.value = gl.name; f.type.value = gl.type;
  f.room_id.replaceChildren(el("option", "(none)"), ...Object.entries(S.doc.rooms).map(([id, r]) => { const o = el("option", `${r.name} (${id})`); o.value = id; return o; }));
  f.room_id.options[0].value = "";
  f.room_id.value = gl.room_id || "";
  f.objects.value = gl.objects.join(", ");
  S.kinds.forEach((k) => { f[k.name].value = FORMS[k.form].show(gl.feedback[k.name]); });
  renderGoals(); draw();
}

function readGoalForm() {
  const f = $("goal-form"), gl = S.doc.goals[S.goal];
  gl.name = f.name.value; gl.type = f.type.value;
  gl.room_id = f.room_id.value || null;
  gl.room = gl.room_id && S.doc.rooms[gl.room_id] ? S.doc.rooms[gl.room_id].name : null;
  gl.objects = f.objects.value.split(",").map((k) => k.trim()).filter(Boolean);
  gl.feedback = Object.fromEntries(S.kinds.map((k) => [k.name, FORMS[k.form].read(f[k.name].value)]));
}

let validateTimer = null;
$("goal-form").addEventListener("input", () => {
  if (S.goal < 0) return;
  readGoalForm(); renderGoals(); draw();
  clearTimeout(validateTimer); validateTimer = setTimeout(validateGoals, 250);
});

async function validateGoals() {
  const r = await api(scenePath("/goals/validate"), { method: "POST", body: { document: S.doc } });
  $("goal-error").textContent = r.ok ? "" : (r.body.field ? `${r.body.field}: ` : "") + r.body.error;
  $("goal-warnings").replaceChildren(...((r.ok && r.body.warnings) || []).map((w) => el("li", `${w.field}: ${w.message}`)));
  $("goals-save").disabled = !r.ok;
  return r.ok;
}

$("goal-new").addEventListener("click", () => {
  const key = S.selectedObject;
  if (!key || !S.doc.objects[key]) { $("goal-error").textContent = "select an object on the map first (click inside its outline)"; return; }
  const o = S.doc.objects[key];
  let name = o.identity, n = 2;
  while (S.doc.goals.some((gl) => gl.name.toLowerCase() === name.toLowerCase())) name = `${o.identity} ${n++}`;
  let id = key; n = 2;
  while (S.doc.goals.some((gl) => gl.id === id)) id = `${key}#${n++}`;
  const room = o.room && S.doc.rooms[o.room] ? o.room : null;
  S.doc.goals.push({ id, name, type: "big", room: room ? S.doc.rooms[room].name : null, room_id: room, objects: [key],
    feedback: Object.fromEntries(S.kinds.map((k) => [k.name, k.new_goal ? k.new_goal.replaceAll("{class}", o.class) : k.default])) });
  selectGoal(S.doc.goals.length - 1); validateGoals();
});

$("goal-delete").addEventListener("click", () => {
  if (S.goal < 0) return;
  S.doc.goals.splice(S.goal, 1); S.goal = -1; $("goal-form").hidden = true; renderGoals(); draw(); validateGoals();
});

$("route-pick").addEventListener("click", () => { setMode("click the route's start on the map", "route"); });
$("route-recorded").addEventListener("click", () => routePreview(null));
$("route-use").addEventListener("click", () => {
  if (!S.route || !S.route.text) return;
  $("goal-form").procedural.value = S.route.text; readGoalForm(); validateGoals();
});

// start: [x, y, 0] picked on the map (facing east), or null for the recording's start pose, where the goals
// stage's procedural feedback starts (the server plans both with the one route_to_goal of pipeline.nav.region)
async function routePreview(start, floor) {
  const gl = S.doc.goals[S.goal];
  const at = start ? `x=${start[0]}&y=${start[1]}&yaw_deg=0&` + (building() ? `floor=${floor}&` : "") : "";
  const r = await api(scenePath(`/route?${at}objects=${encodeURIComponent(gl.objects.join(","))}`));
  if (!r.ok) { $("route-text").textContent = r.body.error; return; }
  start = r.body.start;
  S.route = { ...r.body, start };
  const from = `from (${start[0].toFixed(2)}, ${start[1].toFixed(2)})${building() ? " on floor " + r.body.start_floor : ""}, ${(start[2] * 180 / Math.PI).toFixed(0)} deg`;
  if (r.body.reachable && r.body.start_floor !== S.floor) setFloor(r.body.start_floor);
  $("route-text").textContent = r.body.reachable ? `${from}, ${r.body.length_m} m: ${r.body.text || "already there"}` : "the goal cannot be reached from there";
  $("route-use").hidden = !r.body.reachable;
  draw();
}

$("goals-save").addEventListener("click", async () => {
  if (S.goal >= 0) readGoalForm();
  if (!(await validateGoals())) return;
  $("save-result").textContent = "saving: rebuilding goals and routes …";
  const r = await api(scenePath("/goals"), { method: "PUT", body: { document: S.doc }, ifMatch: S.etag });
  if (r.ok) {
    $("save-result").textContent = `saved ${r.body.saved} (digest ${r.body.digest}); ` + r.body.outcomes.map((o) => `${o.stage} ${o.status} ${o.seconds} s`).join(", ");
    $("download").hidden = true;
    const keep = S.goal; await loadScene(S.scene, true); if (keep >= 0 && keep < S.doc.goals.length) selectGoal(keep);
    return;
  }
  $("save-result").textContent = "";
  $("goal-error").textContent = r.body.error;
  const a = $("download");
  a.href = URL.createObjectURL(new Blob([JSON.stringify(S.doc, null, 2)], { type: "application/json" }));
  a.hidden = false;
});

// ------------------------------------------------------------------ history

async function loadHistory() {
  const r = await api(scenePath("/history"));
  const list = $("history"); list.replaceChildren();
  if (!r.ok) { list.append(el("li", r.body.error, "error")); return; }
  if (!r.body.edits.length) list.append(el("li", "no saved edits yet"));
  r.body.edits.forEach((e) => {
    const li = el("li", `${e.digest}  ${e.time}${e.current ? "  (current)" : ""}  `);
    const show = el("button", "diff"), restore = el("button", "restore");
    show.addEventListener("click", async (ev) => { ev.stopPropagation(); const d = await api(scenePath(`/history/${e.digest}`)); showDiff(d.ok ? d.body.diff : d.body.error); });
    restore.addEventListener("click", async (ev) => {
      ev.stopPropagation(); status("restoring: rebuilding goals and routes …");
      const d = await api(scenePath(`/history/${e.digest}/restore`), { method: "POST", body: {}, ifMatch: S.etag });
      status(d.ok ? `restored ${e.digest}` : d.body.error); if (d.ok) await loadScene(S.scene, true);
    });
    li.append(show, restore); list.append(li);
  });
}

function showDiff(text) {
  const pre = $("diff"); pre.replaceChildren();
  (text || "(no difference)").split("\n").forEach((line) => pre.append(el("div", line, line.startsWith("+") ? "add" : line.startsWith("-") ? "del" : "")));
}

// ------------------------------------------------------------------ objects file: draw, edit, proposals

function renderObjects() {
  const list = $("object-list"); list.replaceChildren();
  if (!S.objects) return;
  S.objects.objects.forEach((o, i) => {
    const li = el("li", `${o.key} (${o.cls})` + (building() ? ` · floor ${o.floor || 0}` : "")); if (i === S.object) li.className = "selected";
    li.addEventListener("click", () => selectObject(i)); list.append(li);
  });
}

function selectObject(i) {
  S.object = i; S.selectedObject = S.objects.objects[i].key;
  const f = $("object-form"), o = S.objects.objects[i];
  if (building() && (o.floor || 0) !== S.floor) setFloor(o.floor || 0);  // an object is shown on its own floor
  f.hidden = false;
  f.floor.value = String(o.floor || 0);
  ["key", "cls", "color_name", "material", "size"].forEach((k) => { f[k].value = o[k] || ""; });
  f.room.value = o.room || "";
  f.description.value = (o.description || []).join("\n");
  f.footprint.value = o.footprint.map((p) => `${p[0]}, ${p[1]}`).join("\n");
  renderObjects(); draw();
}

$("object-form").addEventListener("input", () => {
  if (S.object < 0) return;
  const f = $("object-form"), o = S.objects.objects[S.object];
  ["key", "cls", "color_name", "material", "size"].forEach((k) => { o[k] = f[k].value; });
  o.room = f.room.value || null;
  if (building()) o.floor = Number(f.floor.value);
  o.description = f.description.value.split("\n").filter((l) => l.trim());
  o.footprint = f.footprint.value.split("\n").filter((l) => l.trim()).map((l) => l.split(",").map((v) => Number(v.trim())));
  if (o.footprint.length >= 3 && o.footprint.every((p) => p.length === 2 && p.every(Number.isFinite))) o.mass_center = centroid(o.footprint);
  S.selectedObject = o.key; renderObjects();
  if (building() && o.floor !== S.floor) setFloor(o.floor);  // moved to another floor: follow it there
  draw(); validateObjects();
});

$("object-delete").addEventListener("click", () => {
  if (S.object < 0) return; S.objects.objects.splice(S.object, 1); S.object = -1; $("object-form").hidden = true; renderObjects(); draw(); validateObjects();
});

function newKey(cls) {
  let n = 0; const keys = new Set(S.objects.objects.map((o) => o.key));
  while (keys.has(`${cls}_${n}`)) n++;
  return `${cls}_${n}`;
}

function addObject(cls, footprint) {
  const c = centroid(footprint);
  // a new object stands on the floor shown
  S.objects.objects.push({ key: newKey(cls), cls, instance_id: 0, room: roomAt(c), floor: S.floor, footprint, mass_center: c, z_range: [0, 1], size: "big", color_name: "", material: "", description: [] });
  selectObject(S.objects.objects.length - 1); validateObjects();
}

function roomAt(pt) { const r = (S.objects.rooms || []).find((q) => onFloor(q) && q.polygon.length >= 3 && inside(pt, q.polygon)); return r ? r.id : null; }

$("draw").addEventListener("click", () => { S.drawing = { kind: "object", points: [] }; setMode("click the footprint's corners, then Finish polygon"); $("draw-done").hidden = false; });
$("room-draw").addEventListener("click", () => { S.drawing = { kind: "room", points: [] }; setMode("click the room's corners, then Finish polygon"); $("draw-done").hidden = false; });
$("draw-done").addEventListener("click", () => {
  const d = S.drawing; S.drawing = null; setMode(null); $("draw-done").hidden = true;
  if (!d || d.points.length < 3) { $("objects-error").textContent = "a polygon needs at least 3 corners"; draw(); return; }
  if (d.kind === "room") {
    let n = 1; const ids = new Set(S.objects.rooms.map((r) => r.id)); while (ids.has(`room_${n}`)) n++;
    S.objects.rooms.push({ id: `room_${n}`, type: "room", floor: S.floor, polygon: d.points }); draw(); validateObjects(); return;
  }
  addObject(($("propose-text").value.trim() || "object").split(/\s+/).pop(), d.points);
});

$("propose").addEventListener("click", async () => {
  const text = $("propose-text").value.trim();
  status(`asking the ${$("propose-map").value} for "${text}" …`);
  const r = await api(scenePath(`/propose?map=${$("propose-map").value}&text=${encodeURIComponent(text)}${floorQuery("&")}`));
  if (!r.ok) { $("objects-error").textContent = r.body.error; status(""); return; }
  $("objects-error").textContent = "";
  S.proposals = r.body.proposals;
  S.heatmapExtent = r.body.heatmap_extent_xy;
  S.heatmap = new Image(); S.heatmap.onload = draw; S.heatmap.src = r.body.heatmap;
  status(`${r.body.proposals.length} proposals for "${r.body.text}"${building() ? " on " + floorName(r.body.floor) : ""} (${r.body.seconds} s)`);
  renderProposals();
});

function renderProposals() {
  const list = $("proposals"); list.replaceChildren();
  S.proposals.forEach((p, i) => {
    const li = el("li", `#${p.rank} score ${p.score.toFixed(2)}, ${p.area_m2} m²  `);
    const ok = el("button", "accept"), no = el("button", "reject");
    ok.addEventListener("click", (e) => { e.stopPropagation(); S.proposals.splice(i, 1); addObject($("propose-text").value.trim().split(/\s+/).pop() || "object", p.footprint); renderProposals(); if (!S.proposals.length) S.heatmap = null; draw(); });
    no.addEventListener("click", (e) => { e.stopPropagation(); S.proposals.splice(i, 1); renderProposals(); if (!S.proposals.length) S.heatmap = null; draw(); });
    li.append(ok, no); list.append(li);
  });
}

function objectsBody() { return { path: $("objects-path").value, rooms: S.objects.rooms, objects: S.objects.objects }; }

let objectsTimer = null;
function validateObjects() {  // called after every edit of the objects file
  S.objectsDirty = true;
  clearTimeout(objectsTimer);
  objectsTimer = setTimeout(async () => {
    if (!S.objects) return;  // the edit ended (another tab or scene) before the pause did: nothing to check
    const r = await api(scenePath("/objects/validate"), { method: "POST", body: objectsBody() });
    $("objects-error").textContent = r.ok ? "" : r.body.error;
    $("objects-save").disabled = !r.ok;
  }, 200);
}

$("objects-save").addEventListener("click", async () => {
  const r = await api(scenePath("/objects"), { method: "PUT", body: objectsBody() });
  $("objects-error").textContent = r.ok ? "" : r.body.error;
  if (r.ok) S.objectsDirty = false;
  $("objects-result").textContent = r.ok ? `wrote ${r.body.path}: ${r.body.objects} objects, ${r.body.rooms} rooms\nthen ${r.body.next}` : "";
});

async function loadObjects() {
  const r = await api(scenePath("/objects"));
  if (!r.ok) { $("objects-error").textContent = r.body.error; return; }
  S.objects = { rooms: r.body.rooms, objects: r.body.objects }; S.objectsDirty = false;
  $("objects-path").value = r.body.path;
  renderObjects(); draw();
}

// ------------------------------------------------------------------ play as the user

async function loadAgents() {
  if ($("play-agent").options.length) return;
  const r = await api("/api/agents");
  if (!r.ok) { $("play-error").textContent = r.body.error; return; }
  $("play-agent").replaceChildren(...r.body.agents.map((a) => { const o = el("option", a.label); o.value = a.name; return o; }));
  $("play-goal").replaceChildren(...S.data.goals.map((g) => { const o = el("option", `${g.number}. ${g.name}`); o.value = g.id; return o; }));
}

function showPlay(st) {
  S.play = st;
  $("play-error").textContent = st.error || "";
  const ego = $("play-ego"); ego.hidden = false; ego.src = scenePath(`/play/${st.id}/ego.png?step=${st.steps}`);
  const res = st.result;
  $("play-status").textContent = res
    ? `episode over (${res.end}): ${res.success ? "success" : "failure"}, SPL ${res.spl.toFixed(2)}, SIT ${res.sit.toFixed(2)}, ${res.steps} steps, ${res.talk_turns} questions; stored with the human-answered episodes`
    : `${st.instruction} · step ${st.steps} · ${st.status}`;
  $("play-question").hidden = st.status !== "waiting";
  if (st.question) { $("play-asks").textContent = st.question.text; $("play-suggestion").textContent = st.question.suggestion || "(none)"; }
  $("play-dialogue").replaceChildren(...st.dialogue.map((d) => el("li", `${d.speaker} (step ${d.step}): ${d.text}`, d.speaker)));
  draw();
  if (st.status === "running") setTimeout(async () => { const r = await api(scenePath(`/play/${st.id}`)); if (r.ok) showPlay(r.body); }, 700);
}

$("play-start").addEventListener("click", async () => {
  $("play-status").textContent = "the agent is walking …";
  const r = await api(scenePath("/play"), { method: "POST", body: { method: $("play-agent").value, goal: $("play-goal").value, seed: Number($("play-seed").value) } });
  if (!r.ok) { $("play-error").textContent = r.body.error; $("play-status").textContent = ""; return; }
  $("play-reply").value = ""; showPlay(r.body);
});
$("play-suggest").addEventListener("click", () => { $("play-reply").value = $("play-suggestion").textContent; });
$("play-send").addEventListener("click", async () => {
  const text = $("play-reply").value;
  $("play-status").textContent = "the agent is walking …";
  $("play-question").hidden = true; S.play.status = "sent";
  const r = await api(scenePath(`/play/${S.play.id}/reply`), { method: "POST", body: { text } });
  if (!r.ok) { $("play-error").textContent = r.body.error; return; }
  $("play-reply").value = ""; showPlay(r.body);
});

// ------------------------------------------------------------------ tabs, scenes, start

document.querySelectorAll("nav button").forEach((b) => b.addEventListener("click", async () => {
  if (b.dataset.tab !== "objects" && keepObjectsEdit()) return;
  document.querySelectorAll("nav button").forEach((x) => x.classList.toggle("active", x === b));
  ["goals", "objects", "views", "history", "play"].forEach((t) => { $(`tab-${t}`).hidden = t !== b.dataset.tab; });
  if (b.dataset.tab === "objects" && !S.objects) await loadObjects();
  if (b.dataset.tab === "history") await loadHistory();
  if (b.dataset.tab === "play") await loadAgents();
  if (b.dataset.tab !== "objects") closeObjects();
  draw();
}));

// the objects file is edited on its tab only: leaving the tab (or the scene) drops the unsaved copy and its pending check
function closeObjects() {
  clearTimeout(objectsTimer);
  S.objectsDirty = false; S.objects = null; S.object = -1; $("object-form").hidden = true; S.proposals = []; S.heatmap = null;
  renderObjects(); renderProposals(); $("objects-error").textContent = ""; $("objects-result").textContent = "";
}
["show-objects", "show-goals", "show-routes", "show-trajectory", "show-rooms"].forEach((id) => $(id).addEventListener("change", draw));
$("layer").addEventListener("change", async () => { S.layer = $("layer").value; await loadLayer(S.layer); draw(); });
// true when the objects file has edits not saved and the user chose to stay with them
function keepObjectsEdit() {
  return Boolean(S.objects && S.objectsDirty) && !confirm("The objects file has edits that are not saved. Drop them?");
}
window.addEventListener("beforeunload", (e) => { if (S.objects && S.objectsDirty) { e.preventDefault(); e.returnValue = ""; } });
$("scene").addEventListener("change", () => {
  if (keepObjectsEdit()) { $("scene").value = S.scene; return; }
  location.hash = $("scene").value; loadScene($("scene").value);
});
window.addEventListener("resize", draw);

// A layer is asked for the window the map shows (plus half a screen each side, so a small pan needs nothing new), at
// the screen's resolution: the floor at a zoom that fits, a zoomed part at one pixel per cell. The server paints
// it from the recon tiles that window meets (zipon/annotate/layers.py). S.layers[name@floor] = {img, extent
// (x0, x1, y0, y1 metres), stride (cells per pixel), url}; the picture shown stays until the next one arrives.
const layerKey = (name) => `${name}@${S.floor}`;
function wantedLayer() {
  const g = S.data.grid, [gx0, gx1, gy0, gy1] = g.extent_xy, w = canvas.clientWidth, h = canvas.clientHeight;
  const [ax, ay] = toWorld(0, h), [bx, by] = toWorld(w, 0), mx = (bx - ax) / 2, my = (by - ay) / 2;
  const box = [Math.max(gx0, ax - mx), Math.min(gx1, bx + mx), Math.max(gy0, ay - my), Math.min(gy1, by + my)];
  if (!(box[0] < box[1] && box[2] < box[3]) || !(w > 0 && h > 0)) return null;  // the view is off the grid
  const px = Math.ceil(Math.max(box[1] - box[0], box[3] - box[2]) * S.view.s * (window.devicePixelRatio || 1));
  const visible = [Math.max(gx0, ax), Math.min(gx1, bx), Math.max(gy0, ay), Math.min(gy1, by)];
  return { box, px: Math.min(Math.max(px, 16), 16384), visible };
}
function layerFits(shown, want) {
  if (!shown || !shown.img) return false;
  const [ex0, ex1, ey0, ey1] = shown.extent, [vx0, vx1, vy0, vy1] = want.visible, tol = 1e-3;
  const covers = ex0 <= vx0 + tol && ex1 >= vx1 - tol && ey0 <= vy0 + tol && ey1 >= vy1 - tol;
  const screenPx = S.view.s * (window.devicePixelRatio || 1) * S.data.grid.cell_size_m * shown.stride;
  return covers && (shown.stride === 1 || screenPx <= 1.5) && screenPx >= 0.25;  // sharp enough, not too fine
}
function loadLayer(name) {
  const key = layerKey(name), want = S.data ? wantedLayer() : null, shown = S.layers[key];
  if (!want || layerFits(shown, want)) return Promise.resolve();
  const r = (v) => v.toFixed(3), [x0, x1, y0, y1] = want.box;
  const url = scenePath(`/layers/${name}.png?region=${r(x0)},${r(y0)},${r(x1)},${r(y1)}&px=${want.px}${floorQuery("&")}`);
  if (shown && shown.pending === url) return shown.promise;
  const next = { ...(shown || {}), pending: url };
  next.promise = (async () => {
    const resp = await fetch(url);
    if (!resp.ok) { if (S.layers[key] === next) delete next.pending; status((await resp.json()).error); return; }
    const extent = resp.headers.get("X-Zipon-Extent").split(",").map(Number);
    const img = new Image(); img.src = URL.createObjectURL(await resp.blob());
    await img.decode();
    if (S.layers[key] !== next) { URL.revokeObjectURL(img.src); return; }  // another window was asked since
    if (shown && shown.img) URL.revokeObjectURL(shown.img.src);
    S.layers[key] = { img, extent, stride: Number(resp.headers.get("X-Zipon-Stride")), url };
    draw();
  })();
  S.layers[key] = next;
  return next.promise;
}
let layerTimer = null;
function scheduleLayer() {  // after the view stopped moving for a moment: the window it shows, if not loaded
  clearTimeout(layerTimer);
  layerTimer = setTimeout(() => { if (S.data) loadLayer(S.layer); }, 120);
}

// show floor k: its layer, objects, rooms, goals, routes' legs and stairs (the map keeps its place: the floors
// share one grid); the map proposals, made on the floor shown before, are dropped
function setFloor(k) {
  if (!building() || k === S.floor) return;
  S.floor = k; $("floor").value = String(k);
  S.proposals = []; S.heatmap = null; renderProposals();
  renderGoals(); renderObjects();
  loadLayer(S.layer).then(draw);
  draw();
}
$("floor").addEventListener("change", () => setFloor(Number($("floor").value)));

async function loadScene(name, keepView) {
  S.scene = name; status(`loading ${name} …`); delete document.body.dataset.ready;
  closeObjects();  // another scene's objects file, or the same one as it is on disk now (also when the load fails)
  const goalsAsked = api(scenePath("/goals"));  // in parallel with the summary
  const r = await api(scenePath());
  if (!r.ok) { status(r.body.error); S.data = null; draw(); return; }
  S.data = r.body;
  $("layer").replaceChildren(...S.data.layers.map((l) => { const o = el("option", l); o.value = l; return o; }));
  if (!S.data.layers.includes(S.layer)) S.layer = S.data.layers[0];
  $("layer").value = S.layer;
  $("propose-map").replaceChildren(...S.data.maps.map((m) => el("option", m)));
  S.layers = {};
  const floors = S.data.floors || [];
  if (!keepView || S.floor >= floors.length) S.floor = 0;
  $("floor-pick").hidden = floors.length < 2;
  document.querySelectorAll(".on-building").forEach((e) => { e.hidden = floors.length < 2; });
  const floorOptions = () => floors.map((f, k) => { const o = el("option", `${k}: ${f.name} (${f.floor_z_m.toFixed(2)} m)`); o.value = String(k); return o; });
  $("floor").replaceChildren(...floorOptions()); $("floor").value = String(S.floor);
  $("object-form").floor.replaceChildren(...floorOptions());
  if (!$("tab-objects").hidden) await loadObjects();
  if (!keepView) fit();  // the view first: the layer is asked for the window it shows
  const first = loadLayer(S.layer);  // the others are fetched when chosen
  const g = await goalsAsked;
  S.doc = g.ok ? g.body.document : null; S.etag = g.ok ? g.body.digest : null; S.goal = -1;
  $("goal-form").hidden = true; $("goal-error").textContent = g.ok ? "" : g.body.error; $("goal-warnings").replaceChildren();
  $("goals-save").disabled = !g.ok;
  renderGoals();
  await first;
  draw();
  status(`${name}: ${S.data.objects.length} objects, ${S.data.goals.length} goals, ${S.data.routes.length} routes` + (S.data.ground_truth ? " (ground truth)" : "")
    + (building() ? `, ${S.data.floors.length} floors, ${S.data.stairs.length} stairs` : ""));
  document.body.dataset.ready = name;
}

(async function start() {
  if (!(await loadFeedbackKinds())) return;
  const r = await api("/api/scenes");
  if (!r.ok) { status(r.body.error); return; }
  $("scene").replaceChildren(...r.body.scenes.map((s) => { const o = el("option", s.name + (s.locked ? " (being rebuilt)" : "")); o.value = s.name; return o; }));
  const wanted = decodeURIComponent(location.hash.slice(1)) || r.body.default;
  if (wanted) { $("scene").value = wanted; await loadScene(wanted); }
})();
