// A project's page: follows the project's state (server-sent events), swaps the sections the server
// renders (/projects/ID/part) when they change, uploads photos, leaves photos out, measures.
// Every action is a call of the JSON API (see GET /api).
"use strict";
const root = document.getElementById("project");
const id = root.dataset.id;
const api = "/api/projects/" + encodeURIComponent(id);
const live = document.getElementById("live");
let state = null, lastTicks = null, lastPhotos = null, soon = null, refreshing = false, again = false;

function say(text) { document.getElementById("upload-status").textContent = text; }

function workText(s) {
  const w = s.work, parts = [];
  if (w.uploads) parts.push("receiving photos");
  if (w.detecting) parts.push("finding the board in " + w.detecting + " photo" + (w.detecting > 1 ? "s" : ""));
  if (w.calibrating) parts.push("calibrating");
  if (!parts.length && s.state === "busy") parts.push("waiting for its turn");
  return parts.length ? parts.join(", ") + "…" : "";
}

function verdictText(s) {
  const c = s.calibration;
  if (s.error) return "Not calibrated: " + s.error;
  const said = c ? c.verdict.charAt(0).toUpperCase() + c.verdict.slice(1) : "";
  if (c && c.current) return c.ok ? "Good: " + c.verdict : said;
  if (c) return "Recalculating… (shown: the calibration before the last change) " + said;
  if (!s.photos.length) return "Add the photos of your board.";
  return s.state === "busy" ? "Working on the photos…" : "More photos are needed to calibrate.";
}

function onState(s) {
  state = s;
  const verdict = document.getElementById("verdict"), text = verdictText(s);
  if (verdict.textContent !== text) verdict.textContent = text;
  verdict.className = s.error ? "bad" : (s.calibration && s.calibration.current ? (s.calibration.ok ? "good" : "careful") : "");
  document.getElementById("work").textContent = workText(s);
  live.setAttribute("aria-busy", s.state === "busy" ? "true" : "false");
  const key = JSON.stringify([s.version, s.state, s.calibration, s.error, s.files]);
  const photos = JSON.stringify(s.photos);
  if (key !== lastTicks) { lastTicks = key; lastPhotos = photos; refresh(); }
  else if (photos !== lastPhotos) { lastPhotos = photos; refreshSoon(); }
  if (s.calibration) loadMeasure();
}

// While photos are being detected each one changes the state: the sections are fetched again at most once a
// second then (each fetch has the server render the whole part; it shares the machine with the detection).
function refreshSoon() {
  if (soon) return;
  soon = setTimeout(() => { soon = null; refresh(); }, 1000);
}

async function refresh() {
  if (refreshing) { again = true; return; }
  refreshing = true;
  try {
    const response = await fetch("/projects/" + encodeURIComponent(id) + "/part");
    if (response.ok) swap(await response.text());
  } finally {
    refreshing = false;
    if (again) { again = false; refresh(); }
  }
}

function swap(html) {
  const next = document.createElement("div");
  next.innerHTML = html;
  const focused = document.activeElement && document.activeElement.id;
  const order = Array.from(next.children, (section) => section.id);       // the server's order
  const seen = new Set();
  for (const section of Array.from(next.children)) {
    seen.add(section.id);
    const current = document.getElementById(section.id);
    if (!current) live.appendChild(section);
    else if (current.outerHTML !== section.outerHTML) current.replaceWith(section);
  }
  for (const old of Array.from(live.children)) if (!seen.has(old.id)) old.remove();
  if (Array.from(live.children, (section) => section.id).join() !== order.join())
    for (const key of order) live.appendChild(document.getElementById(key));
  if (focused && document.activeElement !== document.getElementById(focused) && document.getElementById(focused))
    document.getElementById(focused).focus();
}

async function setUse(photos) {
  const response = await fetch(api + "/use", {method: "POST", headers: {"content-type": "application/json"},
                                              body: JSON.stringify({photos: photos, version: state.version})});
  const doc = await response.json();
  if (response.status === 409) say("This project changed in another tab or window: the page shows it now; try again.");
  else if (!response.ok) say(doc.error || "not changed");
  else { say(""); state.version = doc.version; }
  refresh();
}

live.addEventListener("change", (event) => {
  const box = event.target;
  if (box.matches("input[type=checkbox][data-photo]")) setUse({[box.dataset.photo]: box.checked});
});
live.addEventListener("click", (event) => {
  const bar = event.target.closest("button.bar");
  if (bar) setUse({[bar.dataset.photo]: bar.dataset.used !== "true"});
});

// -- uploads
function upload(items) {
  if (!items.length) return;
  const form = new FormData();
  for (const {file, name} of items) form.append("photos", file, name);
  const bar = document.getElementById("upload-progress");
  const xhr = new XMLHttpRequest();
  xhr.open("POST", api + "/photos");
  bar.hidden = false; bar.value = 0;
  say("Uploading " + items.length + " photo" + (items.length > 1 ? "s" : "") + "…");
  xhr.upload.onprogress = (e) => { if (e.lengthComputable) bar.value = 100 * e.loaded / e.total; };
  xhr.onload = () => {
    bar.hidden = true;
    let doc = {};
    try { doc = JSON.parse(xhr.responseText); } catch (e) { doc = {error: xhr.statusText}; }
    if (xhr.status !== 200) { say("Upload refused: " + (doc.error || xhr.status)); return; }
    const skipped = doc.skipped.map((s) => s.name + " (" + s.reason + ")");
    say("Added " + doc.added.length + " photo" + (doc.added.length === 1 ? "" : "s") +
        (skipped.length ? "; not added: " + skipped.join("; ") : "") + ".");
  };
  xhr.onerror = () => { bar.hidden = true; say("The upload was cut off; the photos that arrived whole are kept."); };
  xhr.send(form);
}

function relative(path) {   // "dataset/wide/IMG_01.jpg" -> "wide/IMG_01.jpg": the camera's folder is kept
  const parts = path.split("/").filter(Boolean);
  return parts.length > 1 ? parts.slice(1).join("/") : parts.join("/");
}

document.getElementById("add-photos").addEventListener("change", (event) => {
  upload(Array.from(event.target.files).map((file) => ({file, name: file.name})));
  event.target.value = "";
});
document.getElementById("add-folder").addEventListener("change", (event) => {
  upload(Array.from(event.target.files).map((file) => ({file, name: relative(file.webkitRelativePath || file.name)})));
  event.target.value = "";
});

async function entries(entry, prefix, out) {   // a file, or a folder's files as prefix + "sub/name"
  if (entry.isFile) {
    out.push({file: await new Promise((ok, no) => entry.file(ok, no)), name: prefix + entry.name});
    return;
  }
  const reader = entry.createReader();
  for (;;) {
    const batch = await new Promise((ok, no) => reader.readEntries(ok, no));
    if (!batch.length) break;
    for (const child of batch) await entries(child, prefix + entry.name + "/", out);
  }
}

const drop = document.getElementById("drop");
["dragenter", "dragover"].forEach((t) => drop.addEventListener(t, (e) => { e.preventDefault(); drop.classList.add("over"); }));
["dragleave", "drop"].forEach((t) => drop.addEventListener(t, () => drop.classList.remove("over")));
drop.addEventListener("drop", async (event) => {
  event.preventDefault();
  const out = [];
  for (const item of Array.from(event.dataTransfer.items)) {
    const entry = item.webkitGetAsEntry && item.webkitGetAsEntry();
    if (entry) await entries(entry, "", out);
  }
  // a dropped dataset folder: "dataset/wide/IMG_01.jpg" -> "wide/IMG_01.jpg" (its subfolders are the cameras)
  upload(out.map(({file, name}) => ({file, name: relative(name)})));
});

// -- measuring
const measure = {instant: null, points: [], current: 0, loaded: null};
const letters = "ABCDEFGHIJKLMNOPQRSTUVWXYZ";

async function loadMeasure() {
  const version = state.calibration && state.calibration.version;
  if (measure.loaded === version) return;
  measure.loaded = version;
  const doc = await (await fetch(api + "/result")).json();
  const summary = doc.summary || {};
  measure.summary = summary;
  const select = document.getElementById("measure-instant");
  const instants = Object.keys(summary.instants || {});
  document.getElementById("measure").hidden = !instants.length;
  const keep = select.value;
  select.innerHTML = "";
  for (const key of instants) {
    const option = document.createElement("option");
    option.value = key;
    option.textContent = key + " (" + Object.keys(summary.instants[key]).join(" + ") + ")";
    select.appendChild(option);
  }
  if (instants.includes(keep)) select.value = keep;
  showInstant();
}

function showInstant() {
  const select = document.getElementById("measure-instant");
  const box = document.getElementById("measure-photos");
  measure.instant = select.value;
  measure.points = [{}];
  measure.current = 0;
  box.innerHTML = "";
  const photos = (measure.summary.instants || {})[select.value] || {};
  for (const [camera, photo] of Object.entries(photos)) {
    const figure = document.createElement("figure");
    figure.className = "tap";
    const img = document.createElement("img");
    img.src = api + "/screen/" + encodeURIComponent(photo).replace(/%2F/g, "/");
    img.alt = camera + " photo " + photo + ": tap the point";
    img.dataset.camera = camera;
    img.addEventListener("click", (e) => tap(e, img, figure));
    const caption = document.createElement("figcaption");
    caption.textContent = camera + ": " + photo;
    figure.append(img, caption);
    box.appendChild(figure);
  }
  help();
  drawMarks();
}

function help() {
  document.getElementById("measure-help").textContent =
    "Point " + letters[measure.current] + ": tap it in each photo, then Next point.";
}

function tap(event, img, figure) {
  const rect = img.getBoundingClientRect();
  const size = measure.summary.image_sizes[img.dataset.camera];
  const x = (event.clientX - rect.left) / rect.width, y = (event.clientY - rect.top) / rect.height;
  measure.points[measure.current][img.dataset.camera] = [x * size[0] - 0.5, y * size[1] - 0.5];
  drawMarks();
}

function drawMarks() {
  for (const figure of document.querySelectorAll("#measure-photos figure")) {
    const img = figure.querySelector("img");
    figure.querySelectorAll(".mark").forEach((m) => m.remove());
    const size = measure.summary.image_sizes[img.dataset.camera];
    measure.points.forEach((point, i) => {
      const uv = point[img.dataset.camera];
      if (!uv) return;
      const mark = document.createElement("span");
      mark.className = "mark";
      mark.textContent = letters[i];
      mark.style.left = (100 * (uv[0] + 0.5) / size[0]) + "%";
      mark.style.top = (100 * (uv[1] + 0.5) / size[1]) + "%";
      figure.appendChild(mark);
    });
  }
}

document.getElementById("measure-instant").addEventListener("change", showInstant);
document.getElementById("measure-next").addEventListener("click", () => {
  if (Object.keys(measure.points[measure.current]).length) { measure.points.push({}); measure.current += 1; }
  help();
});
document.getElementById("measure-undo").addEventListener("click", () => {
  if (Object.keys(measure.points[measure.current]).length) measure.points[measure.current] = {};
  else if (measure.current > 0) { measure.points.pop(); measure.current -= 1; measure.points[measure.current] = {}; }
  help(); drawMarks();
});
document.getElementById("measure-clear").addEventListener("click", showInstant);
document.getElementById("measure-go").addEventListener("click", async () => {
  const out = document.getElementById("measure-result");
  const points = {};
  measure.points.forEach((p, i) => { if (Object.keys(p).length >= 2) points[letters[i]] = p; });
  const names = Object.keys(points);
  if (names.length < 2) { out.textContent = "Tap at least two points, each in two or more photos."; return; }
  const lengths = [];
  for (let i = 0; i < names.length; i++) for (let j = i + 1; j < names.length; j++) lengths.push([names[i], names[j]]);
  const body = {points, lengths};
  const given = parseFloat(document.getElementById("measure-sigma").value);
  if (given > 0) body.pixel_sigma = given;
  else {                 // one pixel of the screen, in the photo's pixels
    const img = document.querySelector("#measure-photos img");
    const size = measure.summary.image_sizes[img.dataset.camera];
    body.pixel_sigma = Math.max(1, size[0] / img.getBoundingClientRect().width);
  }
  const response = await fetch(api + "/measure", {method: "POST", headers: {"content-type": "application/json"},
                                                  body: JSON.stringify(body)});
  const doc = await response.json();
  if (!response.ok) { out.textContent = doc.error || "not measured"; return; }
  const list = document.createElement("ul");
  list.className = "lengths";
  for (const L of doc.lengths) {
    const li = document.createElement("li");
    li.textContent = L.from + "–" + L.to + ": " + L.length_mm.toFixed(1) + " ± " + L.sigma_mm.toFixed(1) + " mm" +
                     (L.warning ? " (" + L.warning + ")" : "");
    list.appendChild(li);
  }
  out.innerHTML = "";
  const note = document.createElement("p");
  note.className = "muted small";
  note.textContent = "1-sigma with taps precise to " + body.pixel_sigma.toFixed(1) + " px of the photo.";
  out.append(list, note);
});

// -- follow the project
function follow() {
  const source = new EventSource(api + "/events");
  source.addEventListener("state", (e) => onState(JSON.parse(e.data)));
  source.onerror = () => { document.getElementById("work").textContent = "reconnecting to the app…"; };
}
follow();
