// Measuring with photos of an object (templates/measure.html; the routes: dualcal.app.measure_photos).
// A point is tapped in one photo; the server finds it in the others along its epipolar line, which is drawn;
// a tap in another photo moves the match by hand; a magnifier shows the photo at full resolution around the
// last tap, and a tap in it places the point exactly. Pixels are the photo's stored frame (pixel (i, j) at
// u = j, v = i): a tap at x of a displayed width w is u = x W / w - 0.5.
"use strict";
const app = document.getElementById("measure-app");
const api = "/api/projects/" + encodeURIComponent(app.dataset.id) + "/measure";
const NS = "http://www.w3.org/2000/svg";
const letters = "ABCDEFGHIJKLMNOPQRSTUVWXYZ";
const LOUPE_RADIUS = 44;                       // photo px each way of the magnifier
// a point: {name, camera, uv, moved: {camera: uv}, matched: {camera: {uv, sigma_px, score}}, unmatched: {camera:
// reason}, epipolar: {camera: [[u, v] | null, ...]}, asked: a counter so that a late answer is not taken}
const m = {cameras: {}, points: [], current: -1, loupe: null, asked: 0};

function status(text) { document.getElementById("m-status").textContent = text; }

async function call(path, options) {
  const response = await fetch(api + path, options);
  const type = response.headers.get("content-type") || "";
  const body = type.includes("json") ? await response.json() : await response.blob();
  if (!response.ok) throw new Error((body && body.error) || response.statusText);
  return body;
}

const post = (path, doc) => call(path, {method: "POST", headers: {"content-type": "application/json"},
                                        body: JSON.stringify(doc)});

function onState(doc) {
  m.cameras = doc.cameras;
  buildPhotos();
  const missing = Object.keys(m.cameras).filter((c) => !m.cameras[c].photo);
  status(missing.length ? "Add the photo of " + missing.join(" and ") + " (the same instant)."
                        : "Tap a point in one photo.");
}

function buildPhotos() {
  const box = document.getElementById("m-photos");
  box.innerHTML = "";
  for (const [camera, info] of Object.entries(m.cameras)) {
    const figure = document.createElement("figure");
    figure.className = "m-photo";
    figure.dataset.camera = camera;
    const stage = document.createElement("div");
    stage.className = "m-stage";
    if (info.photo) {
      const img = document.createElement("img");
      img.src = api + "/photos/" + encodeURIComponent(camera) + "?v=" + encodeURIComponent(info.file + Date.now());
      img.alt = camera + " photo: tap a point";
      img.dataset.camera = camera;
      img.addEventListener("click", (event) => place(camera, photoUv(event, img, camera)));
      img.addEventListener("load", draw);
      const svg = document.createElementNS(NS, "svg");
      svg.setAttribute("viewBox", "-0.5 -0.5 " + info.size[0] + " " + info.size[1]);
      svg.setAttribute("preserveAspectRatio", "none");
      svg.setAttribute("aria-hidden", "true");
      stage.append(img, svg);
    } else {
      const empty = document.createElement("div");
      empty.className = "m-empty";
      empty.textContent = "No " + camera + " photo yet";
      stage.append(empty);
    }
    const input = document.createElement("input");
    input.type = "file";
    input.accept = "image/*,.heic,.heif,.dng";
    input.className = "file";
    input.id = "m-file-" + camera;
    input.addEventListener("change", () => upload(camera, input.files[0]));
    const label = document.createElement("label");
    label.className = "button secondary";
    label.htmlFor = input.id;
    label.textContent = (info.photo ? "Replace the " : "Add the ") + camera + " photo";
    const caption = document.createElement("figcaption");
    caption.textContent = camera + (info.file ? ": " + info.file : "") +
      (info.focus_m ? ", focused at " + info.focus_m.toFixed(2) + " m (its metadata)" : "");
    figure.append(stage, label, input, caption);
    box.appendChild(figure);
  }
  draw();
}

function photoUv(event, img, camera) {
  const r = img.getBoundingClientRect(), size = m.cameras[camera].size;
  return [(event.clientX - r.left) / r.width * size[0] - 0.5, (event.clientY - r.top) / r.height * size[1] - 0.5];
}

function newPoint() {
  if (m.points.length >= letters.length) return;
  m.points.push({name: letters[m.points.length], camera: null, uv: null, moved: {}, matched: {}, unmatched: {},
                 epipolar: {}});
  m.current = m.points.length - 1;
  document.getElementById("m-loupe").hidden = true;
  m.loupe = null;
  list();
  draw();
  status("Point " + letters[m.current] + ": tap it in one photo.");
}

async function place(camera, uv) {
  if (m.current < 0 || !m.points[m.current]) newPoint();
  const p = m.points[m.current];
  if (!p.camera || p.camera === camera) {
    Object.assign(p, {camera, uv, moved: {}, matched: {}, unmatched: {}, epipolar: {}});
    loupe(camera, uv);
    list();
    draw();
    await findMatch(p);
  } else {
    p.moved[camera] = uv;
    loupe(camera, uv);
    list();
    draw();
    status(p.name + " in " + camera + ": placed by hand.");
  }
}

async function findMatch(p) {
  const asked = ++m.asked;
  p.asked = asked;
  status("Finding " + p.name + " in the other photo…");
  try {
    const doc = await post("/match", {camera: p.camera, uv: p.uv});
    if (p.asked !== asked) return;                   // tapped again since
    Object.assign(p, {matched: doc.matched, unmatched: doc.unmatched, epipolar: doc.epipolar});
    const found = Object.keys(doc.matched).map((c) => "found in " + c);
    const missed = Object.entries(doc.unmatched).map(([c, why]) => "not found in " + c + " (" + why + ")");
    status(p.name + ": " + found.concat(missed).join("; ") +
           ". Tap another photo to move it there by hand, or add a new point.");
  } catch (error) {
    status(error.message);
  }
  list();
  draw();
}

function pointIn(p, camera) {                        // [uv, kind] of point p in camera's photo, or null
  if (p.camera === camera) return [p.uv, "tap"];
  if (p.moved[camera]) return [p.moved[camera], "hand"];
  if (p.matched[camera]) return [p.matched[camera].uv, "match"];
  return null;
}

function svgElement(name, attributes) {
  const element = document.createElementNS(NS, name);
  for (const [key, value] of Object.entries(attributes)) element.setAttribute(key, value);
  return element;
}

function draw() {
  for (const figure of document.querySelectorAll(".m-photo")) {
    const svg = figure.querySelector("svg");
    if (!svg) continue;
    const camera = figure.dataset.camera, size = m.cameras[camera].size;
    const shown = figure.querySelector("img").clientWidth;
    const unit = shown ? 9 * size[0] / shown : Math.max(size[0], size[1]) / 80;   // a marker: 9 px on the screen
    svg.replaceChildren();
    const current = m.points[m.current];
    if (current && current.epipolar[camera]) {              // the line where the current point can be
      let run = [];
      const flush = () => {
        if (run.length > 1) svg.appendChild(svgElement("polyline", {points: run.join(" "), fill: "none",
          stroke: "#ff50c8", "stroke-width": 2, "vector-effect": "non-scaling-stroke", class: "epipolar"}));
        run = [];
      };
      for (const uv of current.epipolar[camera]) { if (uv) run.push(uv[0] + "," + uv[1]); else flush(); }
      flush();
    }
    m.points.forEach((p, i) => {
      const at = pointIn(p, camera);
      if (!at) return;
      const [uv, kind] = at, colour = {tap: "#ffd400", match: "#00e5ff", hand: "#78ff78"}[kind];
      const group = svgElement("g", {class: "m-mark " + kind, "data-point": p.name});
      const width = i === m.current ? 3 : 2;
      for (const [dx, dy] of [[unit, 0], [0, unit]]) {
        for (const [stroke, w] of [["#000", width + 2], [colour, width]]) {
          group.appendChild(svgElement("line", {x1: uv[0] - dx, y1: uv[1] - dy, x2: uv[0] + dx, y2: uv[1] + dy,
            stroke, "stroke-width": w, "vector-effect": "non-scaling-stroke"}));
        }
      }
      if (kind === "match") {
        group.appendChild(svgElement("circle", {cx: uv[0], cy: uv[1], r: Math.max(unit * 0.6, 2 * p.matched[camera].sigma_px),
          fill: "none", stroke: colour, "stroke-width": 2, "vector-effect": "non-scaling-stroke"}));
      }
      const label = svgElement("text", {x: uv[0] + unit * 0.7, y: uv[1] - unit * 0.7, "font-size": unit * 1.6,
        fill: colour, stroke: "#000", "stroke-width": 1, "paint-order": "stroke", "vector-effect": "non-scaling-stroke",
        "font-weight": "bold", "font-family": "system-ui, sans-serif"});
      label.textContent = p.name;
      group.appendChild(label);
      svg.appendChild(group);
    });
  }
  drawLoupe();
}

function describe(p) {
  if (!p.camera) return "not tapped yet";
  const parts = ["tapped in " + p.camera];
  for (const [camera, match] of Object.entries(p.matched)) {
    if (!p.moved[camera]) parts.push("found in " + camera + " (±" + match.sigma_px.toFixed(2) + " px, score " +
                                     match.score.toFixed(2) + ")");
  }
  for (const camera of Object.keys(p.moved)) parts.push("placed by hand in " + camera);
  return parts.join("; ");
}

function list() {
  const ol = document.getElementById("m-points");
  ol.replaceChildren();
  m.points.forEach((p, i) => {
    const li = document.createElement("li");
    li.className = i === m.current ? "current" : "";
    li.dataset.point = p.name;
    li.textContent = p.name + ": " + describe(p);
    for (const [camera, why] of Object.entries(p.unmatched)) {
      if (p.moved[camera]) continue;
      const span = document.createElement("span");
      span.className = "why";
      span.textContent = "; not found in " + camera + ": " + why + " (tap it there by hand)";
      li.appendChild(span);
    }
    li.addEventListener("click", () => { m.current = i; list(); draw(); });
    ol.appendChild(li);
  });
}

// -- the magnifier: the photo at full resolution around (cu, cv), LOUPE_RADIUS px each way
function loupe(camera, uv) {
  const cu = Math.round(uv[0]), cv = Math.round(uv[1]);
  const state = {camera, cu, cv, img: null};
  m.loupe = state;
  document.getElementById("m-loupe").hidden = false;
  document.getElementById("m-loupe-what").textContent = m.points[m.current].name + " in " + camera;
  const img = new Image();
  img.onload = () => { if (m.loupe === state) { state.img = img; drawLoupe(); } };
  img.src = api + "/crop/" + encodeURIComponent(camera) + "?u=" + cu + "&v=" + cv + "&r=" + LOUPE_RADIUS;
}

function drawLoupe() {
  const L = m.loupe, p = m.points[m.current];
  if (!L || !L.img || !p) return;
  const canvas = document.getElementById("m-loupe-canvas"), ctx = canvas.getContext("2d");
  const s = canvas.width / (2 * LOUPE_RADIUS + 1);
  ctx.imageSmoothingEnabled = false;
  ctx.drawImage(L.img, 0, 0, canvas.width, canvas.height);
  const line = p.epipolar[L.camera];
  if (line && p.camera !== L.camera) {
    ctx.strokeStyle = "#ff50c8";
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    let drawing = false;
    for (const uv of line) {
      if (!uv) { drawing = false; continue; }
      const x = (uv[0] - L.cu + LOUPE_RADIUS + 0.5) * s, y = (uv[1] - L.cv + LOUPE_RADIUS + 0.5) * s;
      if (drawing) ctx.lineTo(x, y); else ctx.moveTo(x, y);
      drawing = true;
    }
    ctx.stroke();
  }
  const at = pointIn(p, L.camera);
  if (!at) return;
  const x = (at[0][0] - L.cu + LOUPE_RADIUS + 0.5) * s, y = (at[0][1] - L.cv + LOUPE_RADIUS + 0.5) * s;
  for (const [colour, width] of [["#000", 4], [{tap: "#ffd400", match: "#00e5ff", hand: "#78ff78"}[at[1]], 2]]) {
    ctx.strokeStyle = colour;
    ctx.lineWidth = width;
    ctx.beginPath();
    ctx.moveTo(x - 14, y); ctx.lineTo(x - 4, y); ctx.moveTo(x + 4, y); ctx.lineTo(x + 14, y);
    ctx.moveTo(x, y - 14); ctx.lineTo(x, y - 4); ctx.moveTo(x, y + 4); ctx.lineTo(x, y + 14);
    ctx.stroke();
  }
}

document.getElementById("m-loupe-canvas").addEventListener("click", (event) => {
  const L = m.loupe;
  if (!L) return;
  const canvas = event.currentTarget, r = canvas.getBoundingClientRect();
  const s = r.width / (2 * LOUPE_RADIUS + 1);
  place(L.camera, [L.cu - LOUPE_RADIUS + (event.clientX - r.left) / s - 0.5,
                   L.cv - LOUPE_RADIUS + (event.clientY - r.top) / s - 0.5]);
});

async function upload(camera, file) {
  if (!file) return;
  status("Sending the " + camera + " photo…");
  try {
    onState(await call("/photos/" + encodeURIComponent(camera), {method: "PUT", body: file}));
    for (const p of m.points) if (p.camera) await findMatch(p);
  } catch (error) {
    status(error.message);
  }
}

function pointsDoc() {
  const points = {};
  for (const p of m.points) if (p.camera) points[p.name] = {[p.camera]: p.uv, ...p.moved};
  const names = Object.keys(points), lengths = [];
  for (let i = 0; i < names.length; i++) for (let j = i + 1; j < names.length; j++) lengths.push([names[i], names[j]]);
  const sigma = parseFloat(document.getElementById("m-sigma").value);
  return {points, lengths, pixel_sigma: sigma > 0 ? sigma : 1};
}

document.getElementById("m-new").addEventListener("click", newPoint);
document.getElementById("m-delete").addEventListener("click", () => {
  if (m.current < 0) return;
  m.points.splice(m.current, 1);
  m.points.forEach((p, i) => { p.name = letters[i]; });
  m.current = m.points.length - 1;
  list();
  draw();
});

document.getElementById("m-go").addEventListener("click", async () => {
  const out = document.getElementById("m-result"), body = pointsDoc();
  if (body.lengths.length < 1) { out.textContent = "Tap at least two points."; return; }
  out.textContent = "Measuring…";
  try {
    const doc = await post("/points", body);
    const ul = document.createElement("ul");
    ul.className = "m-lengths";
    for (const L of doc.lengths) {
      const li = document.createElement("li");
      li.dataset.length = L.from + "-" + L.to;
      li.textContent = L.from + "–" + L.to + ": " + L.length_mm.toFixed(1) + " ± " + L.sigma_mm.toFixed(1) + " mm" +
                       (L.warning ? " (" + L.warning + ")" : "");
      ul.appendChild(li);
    }
    for (const L of doc.unmeasured_lengths || []) {
      const li = document.createElement("li");
      li.textContent = L.from + "–" + L.to + ": not measured (" + L.reason + ")";
      ul.appendChild(li);
    }
    const note = document.createElement("p");
    note.className = "muted small";
    note.textContent = "1-sigma, from the calibration and the taps together (taps precise to " +
                       body.pixel_sigma + " px; a point found in another photo has its own sigma there).";
    out.replaceChildren(ul, note);
  } catch (error) {
    out.textContent = error.message;
  }
});

document.getElementById("m-record").addEventListener("click", async () => {
  const out = document.getElementById("m-result"), body = pointsDoc();
  if (!Object.keys(body.points).length) { out.textContent = "Tap a point first."; return; }
  try {
    const blob = await post("/record", body);
    const a = document.createElement("a");
    a.href = URL.createObjectURL(blob);
    a.download = "record.html";
    document.body.appendChild(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(a.href), 10000);
  } catch (error) {
    out.textContent = error.message;
  }
});

window.addEventListener("resize", draw);
call("/state").then(onState, (error) => status(error.message));
