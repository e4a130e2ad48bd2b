// illum service page: polls the REST API; no framework, no build step.
// Everything user-supplied (stage names, errors, logs) is written with textContent, never as HTML.
"use strict";

const POLL_MS = 1000;
const $ = (id) => document.getElementById(id);
let selected = location.hash.slice(1) || null;
let lastPreviewKey = null;   // spp/state of the preview on screen, to fetch only when it changes
let previewUrl = null;       // object URL of the image on screen
let previewBusy = false;
let jobsCache = new Map();
const thumbs = new Map();    // job id -> {key, url}: the row thumbnails fetched so far
let thumbsBusy = false;
let pollSeq = 0;             // answers to older list requests (filters changed since) are dropped
let frameShown = null;       // the frame index whose image the preview shows (a range job), or null: the latest
let framesBusy = false;

function token() { return localStorage.getItem("illumToken") || ""; }

// Every request carries the token when one is set: on a server with ILLUM_TOKEN, reads need it
// as much as writes. Images, logs and downloads are fetched too (never plain links), for that.
function authHeaders(extra) {
  const headers = Object.assign({}, extra || {});
  if (token()) headers["Authorization"] = "Bearer " + token();
  return headers;
}

async function authFetch(path, init) {
  const r = await fetch(path, Object.assign({ cache: "no-store" }, init || {}, { headers: authHeaders() }));
  if (r.status === 401) $("token-row").hidden = false;
  return r;
}

async function api(method, path, body) {
  const headers = authHeaders(body !== undefined ? { "Content-Type": "application/json" } : {});
  const r = await fetch(path, { method, headers, body: body === undefined ? undefined : JSON.stringify(body) });
  let data = null;
  const ct = r.headers.get("content-type") || "";
  if (ct.includes("application/json")) data = await r.json();
  if (!r.ok) {
    if (r.status === 401) $("token-row").hidden = false;
    const msg = (data && (data.message || JSON.stringify(data.detail))) || r.statusText;
    const err = new Error(msg + " (HTTP " + r.status + ")");
    err.status = r.status;
    throw err;
  }
  return data;
}

// Opens a job's file (log, EXR) fetched with the token, as a blob: URL of this page.
async function openFile(path, filename) {
  try {
    const r = await authFetch(path);
    if (!r.ok) { say("cannot fetch " + path + " (HTTP " + r.status + ")", true); return; }
    const url = URL.createObjectURL(await r.blob());
    if (filename) {
      const a = document.createElement("a");
      a.href = url;
      a.download = filename;
      document.body.appendChild(a);
      a.click();
      a.remove();
    } else {
      window.open(url, "_blank");
    }
    setTimeout(() => URL.revokeObjectURL(url), 60000);
  } catch (e) {
    say("cannot fetch " + path + ": " + e.message, true);
  }
}

function say(text, isError) {
  const m = $("message");
  m.textContent = text;
  m.className = isError ? "error" : "";
}

function fmtEta(s) {
  if (s === null || s === undefined) return "–";
  if (s < 90) return Math.round(s) + " s";
  if (s < 5400) return Math.round(s / 60) + " min";
  return (s / 3600).toFixed(1) + " h";
}

function fmtDuration(s) {
  if (s === null || s === undefined) return "–";
  if (s < 60) return s.toFixed(1) + " s";
  if (s < 3600) return Math.floor(s / 60) + " min " + String(Math.floor(s % 60)).padStart(2, "0") + " s";
  return Math.floor(s / 3600) + " h " + String(Math.floor((s % 3600) / 60)).padStart(2, "0") + " min";
}

function fmtBytes(n) {
  if (!n) return "–";
  const units = ["B", "KiB", "MiB", "GiB", "TiB"];
  let i = 0;
  while (n >= 1024 && i < units.length - 1) { n /= 1024; i += 1; }
  return (i ? n.toFixed(n < 10 ? 1 : 0) : String(n)) + " " + units[i];
}

function fmtAttempts(j) {
  const run = j.attempts;
  return j.requeues ? run + " (requeued " + j.requeues + "×)" : run + "/" + j.max_attempts;
}

function thumbKey(j) { return j.state + ":" + j.spp_done + ":" + (j.links && j.links.thumbnail ? 1 : 0); }

// Fetches the thumbnails whose job changed (new samples, new state), one at a time, with the
// token; rows show them as blob: URLs.
async function refreshThumbs(jobs) {
  if (thumbsBusy) return;
  thumbsBusy = true;
  try {
    for (const j of jobs) {
      if (!(j.links && j.links.thumbnail)) continue;
      const key = thumbKey(j);
      const have = thumbs.get(j.id);
      if (have && have.key === key) continue;
      const r = await authFetch(j.links.thumbnail + "?t=" + Date.now());
      if (!r.ok) continue;
      const url = URL.createObjectURL(await r.blob());
      if (have) URL.revokeObjectURL(have.url);
      thumbs.set(j.id, { key, url });
      const img = document.querySelector('#jobs-body tr[data-id="' + j.id + '"] td.thumb img');
      if (img) { img.src = url; img.hidden = false; }
    }
  } catch (e) {
    /* the next poll retries */
  } finally {
    thumbsBusy = false;
  }
}

function cell(tr, text, cls) {
  const td = document.createElement("td");
  if (cls) td.className = cls;
  td.textContent = text;
  tr.appendChild(td);
  return td;
}

function renderJobs(jobs) {
  const body = $("jobs-body");
  body.textContent = "";
  $("jobs-empty").hidden = jobs.length > 0;
  jobsCache = new Map(jobs.map((j) => [j.id, j]));
  for (const j of jobs) {
    const tr = document.createElement("tr");
    tr.dataset.id = j.id;
    tr.dataset.state = j.state;
    if (j.id === selected) tr.classList.add("selected");
    const th = cell(tr, "", "thumb");
    const img = document.createElement("img");
    img.alt = "";
    const t = thumbs.get(j.id);
    if (t) img.src = t.url; else img.hidden = true;
    th.appendChild(img);
    cell(tr, j.id.slice(0, 8));
    cell(tr, j.stage, "stage").title = j.stage;
    const st = cell(tr, "");
    const badge = document.createElement("span");
    badge.className = "state " + j.state;
    badge.textContent = j.state;
    st.appendChild(badge);
    cell(tr, String(j.priority), "priority");
    const pc = cell(tr, "");
    const bar = document.createElement("div");
    bar.className = "bar";
    bar.title = (j.progress || 0).toFixed(0) + "%";
    const fill = document.createElement("div");
    fill.style.width = Math.min(100, j.progress || 0) + "%";
    bar.appendChild(fill);
    pc.appendChild(bar);
    if (j.frame_counts) {   // a frame range: frames ended / frames
      const fc = j.frame_counts, total = Object.values(fc).reduce((a, b) => a + b, 0);
      const span = document.createElement("span");
      span.className = "frames-done";
      span.textContent = (fc.succeeded + fc.failed) + "/" + total + " frames";
      pc.appendChild(span);
    }
    cell(tr, String(j.spp_done || 0));
    cell(tr, j.samples_per_second ? (j.samples_per_second / 1000).toFixed(1) : "–");
    cell(tr, fmtDuration(j.elapsed_seconds), "elapsed");
    cell(tr, j.state === "running" ? fmtEta(j.eta_seconds) : "–");
    cell(tr, fmtBytes(j.peak_memory), "memory").title = j.peak_memory ? j.peak_memory + " bytes" : "not measured yet";
    cell(tr, fmtAttempts(j), "attempts");
    tr.addEventListener("click", () => select(j.id));
    body.appendChild(tr);
  }
  for (const id of [...thumbs.keys()]) {   // jobs gone from the list (deleted, filtered out)
    if (!jobsCache.has(id)) { URL.revokeObjectURL(thumbs.get(id).url); thumbs.delete(id); }
  }
  refreshThumbs(jobs);
}

function select(id) {
  selected = id;
  lastPreviewKey = null;
  frameShown = null;
  history.replaceState(null, "", "#" + id);
  for (const tr of $("jobs-body").children) tr.classList.toggle("selected", tr.dataset.id === id);
  showSelected();
}

function showSelected() {
  const j = selected ? jobsCache.get(selected) : null;
  $("sel-id").textContent = j ? j.id : "";
  $("sel-state").textContent = j ? j.state + (j.state === "running" && j.worker ? " on " + j.worker : "") : "–";
  $("sel-spp").textContent = j ? String(j.spp_done || 0) + (j.spp_target ? " / " + j.spp_target : "") : "–";
  $("sel-progress").textContent = j ? (j.progress || 0).toFixed(1) + "%" +
    (j.state === "running" && j.eta_seconds != null ? ", ETA " + fmtEta(j.eta_seconds) : "") : "–";
  $("sel-error").textContent = j && j.error ? j.error : "–";
  const active = !!j && (j.state === "queued" || j.state === "running");
  $("cancel-btn").disabled = !active;
  $("priority-btn").disabled = !active;
  $("sel-priority").disabled = !active;
  if (j && document.activeElement !== $("sel-priority") && $("sel-priority").dataset.job !== j.id + ":" + j.priority) {
    $("sel-priority").value = String(j.priority);    // not while the user is typing a new one
    $("sel-priority").dataset.job = j.id + ":" + j.priority;
  }
  $("requeue-btn").disabled = !j || !(j.state === "failed" || j.state === "canceled");
  $("delete-btn").disabled = !j;
  $("log-link").hidden = !j;
  $("exr-link").hidden = !(j && j.links && j.links.image_exr);
  $("denoised-row").hidden = !(j && j.links && j.links.image_denoised_png);
  if (j) {
    $("log-link").href = "/jobs/" + j.id + "/log";
    $("exr-link").href = "/jobs/" + j.id + "/image?format=exr";
    $("exr-link").dataset.filename = j.id + ".exr";
  }
  $("sel-frames-label").hidden = $("sel-frames").hidden = !(j && j.frame_counts);
  if (!j) {
    $("preview").hidden = true;
    $("preview-none").hidden = false;
    return;
  }
  if (j.frame_counts) refreshFrames(j);
  if (frameShown !== null) {   // a chosen frame's final image stays until another is chosen
    const c = $("frame-strip").children[frameShown];
    const key = "frame:" + j.id + ":" + frameShown;
    if (c && c.dataset.png && key !== lastPreviewKey) refreshPreview(j, key, c.dataset.png);
    return;
  }
  // The live preview, or (a job that denoises, the box ticked) its OIDN-denoised version.
  const denoised = !!(j.links && j.links.image_denoised_png) && $("show-denoised").checked;
  const key = j.id + ":" + j.state + ":" + j.spp_done + ":" + (j.links && j.links.image_png ? 1 : 0) + ":" + denoised;
  if (j.links && j.links.image_png && key !== lastPreviewKey) {
    refreshPreview(j, key, denoised ? j.links.image_denoised_png : null);
  }
}

// A frame range's tasks: one cell per frame, filled to its progress and coloured by its state;
// clicking a rendered frame shows its image, clicking it again goes back to the latest.
async function refreshFrames(j) {
  if (framesBusy) return;
  framesBusy = true;
  try {
    const full = await api("GET", "/jobs/" + j.id);
    if (j.id !== selected || !full.frames) return;
    const fc = full.frame_counts, total = full.frames.length;
    $("sel-frames-text").textContent = fc.succeeded + " of " + total + " done" +
      (fc.running ? ", " + fc.running + " running" : "") + (fc.failed ? ", " + fc.failed + " failed" : "") +
      (fc.queued ? ", " + fc.queued + " queued" : "");
    const strip = $("frame-strip");
    while (strip.children.length > total) strip.lastChild.remove();
    while (strip.children.length < total) {
      const cellEl = document.createElement("span");
      cellEl.appendChild(document.createElement("div"));
      cellEl.addEventListener("click", () => showFrame(Number(cellEl.dataset.index)));
      strip.appendChild(cellEl);
    }
    full.frames.forEach((f, i) => {
      const c = strip.children[i];
      c.className = "frame " + f.state + (frameShown === f.index ? " shown" : "");
      c.dataset.index = String(f.index);
      c.dataset.state = f.state;
      c.dataset.png = f.links.image_png || "";
      c.title = "frame " + f.frame + ": " + f.state + (f.state === "running" ? " " + f.progress.toFixed(0) + "%" : "") +
        ", " + f.spp_done + " spp, attempt " + f.attempts + (f.error ? " — " + f.error : "");
      c.firstChild.style.height = (f.state === "running" ? Math.min(100, f.progress) : f.state === "queued" ? 0 : 100) + "%";
    });
  } catch (e) {
    /* the next poll retries */
  } finally {
    framesBusy = false;
  }
}

function showFrame(index) {
  const c = $("frame-strip").children[index];
  if (!selected || !c) return;
  if (frameShown === index || !c.dataset.png) {   // back to the latest image
    frameShown = null;
    lastPreviewKey = null;
    showSelected();
    return;
  }
  frameShown = index;
  lastPreviewKey = null;
  for (const el of $("frame-strip").children) el.classList.toggle("shown", el === c);
  showSelected();
}

async function refreshPreview(j, key, path) {
  if (previewBusy) return;
  previewBusy = true;
  try {
    // A new query string each time: the preview file is replaced in place as the render refines.
    const r = await authFetch((path || "/jobs/" + j.id + "/image?format=png") + "&t=" + Date.now());
    if (!r.ok || j.id !== selected) return;
    const blob = await r.blob();
    const url = URL.createObjectURL(blob);
    const img = $("preview");
    img.onload = () => { if (previewUrl && previewUrl !== url) URL.revokeObjectURL(previewUrl); previewUrl = url; };
    img.src = url;
    img.dataset.spp = r.headers.get("X-Illum-Spp") || "";
    img.dataset.kind = r.headers.get("X-Illum-Image") || "";
    img.hidden = false;
    $("preview-none").hidden = true;
    lastPreviewKey = key;
  } catch (e) {
    /* the next poll retries */
  } finally {
    previewBusy = false;
  }
}

async function refreshLog() {
  if (!selected) { $("log").textContent = ""; return; }
  try {
    const r = await authFetch("/jobs/" + selected + "/log?tail=40");
    if (r.ok) $("log").textContent = await r.text();
  } catch (e) { /* retry next time */ }
}

function listQuery() {
  const q = new URLSearchParams({ limit: "100" });
  if ($("filter-state").value) q.append("state", $("filter-state").value);
  const stage = $("filter-stage").value.trim();
  if (stage) q.append("stage", stage);
  return "/jobs?" + q.toString();
}

async function poll() {
  const seq = ++pollSeq;
  try {
    const data = await api("GET", listQuery());
    if (seq !== pollSeq) return;   // the filters changed while this was on its way
    renderJobs(data.jobs);
    $("jobs-count").textContent = data.count < data.total ? data.count + " of " + data.total : String(data.total);
    $("jobs-empty").textContent = ($("filter-state").value || $("filter-stage").value.trim())
      ? "No job matches the filters." : "No jobs yet.";
    showSelected();
  } catch (e) {
    if (seq !== pollSeq) return;
    if (e.status === 422) say(e.message, true);   // a filter the server refuses (too long, control characters)
    else if (e.status !== 401) $("health").textContent = "server unreachable: " + e.message;
  }
}

async function pollHealth() {
  try {
    const h = await api("GET", "/health");
    if (h.auth) $("token-row").hidden = false;
    if (h.authorized === false) {
      $("health").textContent = h.status + " · this server needs its access token";
      return;
    }
    const w = h.workers;
    $("health").textContent = h.status + " · " + (w.alive ?? 0) + "/" + w.configured + " " + h.backend +
      " workers · " + h.jobs.queued + " queued, " + h.jobs.running + " running";
  } catch (e) {
    $("health").textContent = "server unreachable";
  }
}

async function loadStages() {
  const data = await api("GET", "/stages");
  const sel = $("stage");
  sel.textContent = "";
  for (const s of data.stages) {
    const o = document.createElement("option");
    o.value = s;
    o.textContent = s;
    sel.appendChild(o);
  }
}

function numberOrNull(id) {
  const v = $(id).value.trim();
  return v === "" ? null : Number(v);
}

$("submit-form").addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const settings = {};
  const spp = numberOrNull("spp"), tb = numberOrNull("time-budget");
  const w = numberOrNull("res-w"), h = numberOrNull("res-h");
  if (spp !== null) settings.spp = spp;
  if (tb !== null && tb > 0) settings.time_budget = tb;
  if (w !== null || h !== null) settings.resolution = [w, h];
  if ($("light-sampler").value !== "auto") settings.light_sampler = $("light-sampler").value;
  if ($("estimator").value) settings.estimator = $("estimator").value;
  if ($("frames").value.trim()) settings.frames = $("frames").value.trim();
  const body = { kind: "render", stage: $("stage").value, settings, priority: numberOrNull("priority") ?? 50 };
  $("submit-btn").disabled = true;
  try {
    const job = await api("POST", "/jobs", body);
    say("Submitted job " + job.id + " (" + job.state + ")", false);
    await poll();
    select(job.id);
  } catch (e) {
    say(e.message, true);
  } finally {
    $("submit-btn").disabled = false;
  }
});

$("cancel-btn").addEventListener("click", async () => {
  if (!selected) return;
  try {
    const job = await api("POST", "/jobs/" + selected + "/cancel");
    say("Canceled job " + job.id, false);
    await poll();
  } catch (e) {
    say(e.message, true);
  }
});

$("priority-btn").addEventListener("click", async () => {
  if (!selected) return;
  const v = $("sel-priority").value.trim();
  const p = Number(v);
  if (v === "" || !Number.isInteger(p) || p < 0 || p > 100) { say("priority: a whole number from 0 to 100", true); return; }
  try {
    const job = await api("PATCH", "/jobs/" + selected, { priority: p });
    $("sel-priority").dataset.job = "";
    say("Job " + job.id + " now has priority " + job.priority, false);
    await poll();
  } catch (e) {
    say(e.message, true);
  }
});

$("requeue-btn").addEventListener("click", async () => {
  if (!selected) return;
  try {
    const job = await api("POST", "/jobs/" + selected + "/requeue");
    say("Requeued job " + job.id + " (" + job.state + ")", false);
    lastPreviewKey = null;
    await poll();
  } catch (e) {
    say(e.message, true);
  }
});

// Delete asks first, in a dialog of the page, naming the job.
$("delete-btn").addEventListener("click", () => {
  if (!selected) return;
  const j = jobsCache.get(selected);
  $("delete-what").textContent = selected + (j ? " (" + j.stage + ", " + j.state + ")" : "");
  $("delete-dialog").dataset.id = selected;
  $("delete-dialog").showModal();
});
$("delete-keep").addEventListener("click", () => $("delete-dialog").close());
$("delete-confirm").addEventListener("click", async () => {
  const id = $("delete-dialog").dataset.id;
  $("delete-dialog").close();
  if (!id) return;
  try {
    await api("DELETE", "/jobs/" + id);
    say("Deleted job " + id, false);
    if (selected === id) {
      selected = null;
      history.replaceState(null, "", location.pathname);
    }
    await poll();
  } catch (e) {
    say(e.message, true);
  }
});

let filterTimer = null;
$("filter-state").addEventListener("change", () => poll());
$("filter-stage").addEventListener("input", () => { clearTimeout(filterTimer); filterTimer = setTimeout(poll, 250); });

$("show-denoised").addEventListener("change", () => { lastPreviewKey = null; showSelected(); });

$("exr-link").addEventListener("click", (ev) => {
  ev.preventDefault();
  openFile($("exr-link").getAttribute("href"), $("exr-link").dataset.filename || "image.exr");
});
$("log-link").addEventListener("click", (ev) => {
  ev.preventDefault();
  openFile($("log-link").getAttribute("href"), null);
});

function refreshAll() {
  loadStages().then(() => {
    if ($("message").textContent.startsWith("cannot list stages")) say("", false);
  }).catch((e) => say("cannot list stages: " + e.message, true));
  poll();
  pollHealth();
}

$("token").value = token();
$("token").addEventListener("change", () => {
  localStorage.setItem("illumToken", $("token").value.trim());
  lastPreviewKey = null;
  refreshAll();
});

refreshAll();
setInterval(poll, POLL_MS);
setInterval(pollHealth, 3000);
setInterval(refreshLog, 2000);
