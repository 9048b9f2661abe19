// GET /: a read-only page with the token's jobs (scene, times, progress, a
// failure's cause), the selected job's files and its latest preview. Plain HTML and JavaScript, nothing fetched from
// elsewhere. It authenticates with the lightfarm_token cookie that GET /?token=T sets, because <img> and fetch from a
// page cannot be given a bearer header by a person typing a URL.
#pragma once

namespace lf::server {

inline constexpr const char* kStatusPage = R"html(<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>lightfarm</title>
<style>
  body { font: 14px/1.4 system-ui, sans-serif; margin: 2em; color: #222; }
  table { border-collapse: collapse; }
  th, td { padding: 4px 10px; border-bottom: 1px solid #ddd; text-align: left; vertical-align: top; }
  tr.job { cursor: pointer; }
  tr.selected { background: #eef; }
  tr.cause td { color: #b00; border-bottom: 1px solid #ddd; padding-top: 0; }
  .bar { width: 120px; height: 8px; background: #ddd; display: inline-block; margin-right: 6px; }
  .bar > div { height: 8px; background: #4a7; }
  #preview img { max-width: 512px; image-rendering: pixelated; border: 1px solid #ccc; }
  .failed { color: #b00; } .succeeded { color: #070; }
  .muted { color: #777; }
</style>
</head>
<body>
<h1>lightfarm</h1>
<p id="note"></p>
<table id="jobs">
  <thead><tr><th>job</th><th>scene</th><th>state</th><th>submitted</th><th>started</th><th>finished</th>
  <th>pass</th><th>error estimate</th><th>progress</th><th>ETA</th><th>attempts</th></tr></thead>
  <tbody></tbody>
</table>
<h2>Job <span id="selected-job"></span></h2>
<div id="files"></div>
<div id="preview"></div>
<script>
"use strict";
// The jobs as the server had them when it sent this page (GET /v1/jobs's
// body), so they show at once; then refreshed every 2 s.
const initial = /*JOBS*/null;
let selected = null, shownFilesOf = null;

function cell(row, text) {
  const td = document.createElement("td");
  td.textContent = text;
  row.appendChild(td);
  return td;
}

function fmt(x, digits) { return x === null || x === undefined ? "–" : Number(x).toFixed(digits); }
function when(t) { return t ? new Date(t * 1000).toLocaleString() : "–"; }

// How far the job is: passes or time, whichever stop comes first (the ETA is
// the server's, which takes every stop into account).
function fraction(job) {
  if (job.state === "succeeded") return 1;
  const p = job.progress, eta = p.eta_seconds;
  if (eta === null || eta === undefined || !(p.seconds > 0)) return 0;
  return p.seconds / (p.seconds + eta);
}

function scene(job) {
  if (!job.scene_name) return job.scene.slice(0, 12);
  return job.scene_name + (job.scene_triangles ? " (" + job.scene_triangles.toLocaleString() + " triangles)" : "");
}

function render(jobs) {
  document.getElementById("note").textContent = jobs.length ? "" : "No jobs yet.";
  if (selected === null && jobs.length) selected = jobs[0].id;
  const body = document.querySelector("#jobs tbody");
  body.replaceChildren();
  for (const job of jobs) {
    const row = document.createElement("tr");
    row.className = "job" + (job.id === selected ? " selected" : "");
    row.onclick = () => { selected = job.id; shownFilesOf = null; render(jobs); };
    cell(row, job.id.slice(0, 12)).title = job.id;
    cell(row, scene(job));
    cell(row, job.state).className = job.state;
    cell(row, when(job.created_at));
    cell(row, when(job.started_at));
    cell(row, when(job.finished_at));
    cell(row, job.progress.pass);
    cell(row, fmt(job.progress.error_estimate, 4));
    const percent = Math.round(100 * fraction(job));
    const bar = document.createElement("div");
    bar.className = "bar";
    const fill = document.createElement("div");
    fill.style.width = percent + "%";
    bar.appendChild(fill);
    const progress = cell(row, percent + "%");
    progress.prepend(bar);
    cell(row, job.progress.eta_seconds === null || job.progress.eta_seconds === undefined ? "–"
                                                                                     : fmt(job.progress.eta_seconds, 0) + " s");
    cell(row, job.attempts + " / " + job.max_attempts);
    body.appendChild(row);
    if (job.state === "failed") {  // the cause in plain sight, under its job
      const cause = document.createElement("tr");
      cause.className = "cause";
      const td = cell(cause, job.error + (job.cause ? ": " + job.cause : ""));
      td.colSpan = 11;
      body.appendChild(cause);
    }
  }
  const job = jobs.find(j => j.id === selected);
  if (job) show(job);
}

// The selected job: links to every file it has, and its preview where a
// snapshot exists (no broken image for a job that has none).
async function show(job) {
  document.getElementById("selected-job").textContent = job.id.slice(0, 12) + " · " + scene(job);
  const preview = document.getElementById("preview");
  const hasImage = job.latest && job.latest.lightmap;
  if (hasImage) {
    let img = preview.querySelector("img");
    if (!img) { img = document.createElement("img"); img.alt = "preview"; preview.replaceChildren(img); }
    img.src = job.links.preview + "?pass=" + job.latest.lightmap.pass;
  } else {
    preview.replaceChildren();
    const p = document.createElement("p");
    p.className = "muted";
    p.textContent = "No lightmap snapshot yet.";
    preview.appendChild(p);
  }
  const key = job.id + ":" + job.state + ":" + JSON.stringify(job.latest || {});
  if (shownFilesOf === key) return;
  shownFilesOf = key;
  const files = document.getElementById("files");
  try {
    const r = await fetch(job.links.artifacts, { credentials: "same-origin" });
    if (!r.ok) throw new Error(r.statusText);
    const list = (await r.json()).artifacts;
    files.replaceChildren();
    if (!list.length) { files.textContent = "No files yet."; return; }
    const ul = document.createElement("ul");
    for (const a of list) {
      const li = document.createElement("li");
      const link = document.createElement("a");
      link.href = a.url;
      link.textContent = a.name;
      li.appendChild(link);
      if (a.size !== undefined) li.append(" (" + Number(a.size).toLocaleString() + " bytes)");
      ul.appendChild(li);
    }
    files.appendChild(ul);
  } catch (e) {
    files.textContent = "Cannot list the files: " + e.message;
  }
}

async function refresh() {
  try {
    const r = await fetch("/v1/jobs", { credentials: "same-origin" });
    if (!r.ok) throw new Error((await r.json()).error || r.statusText);
    render((await r.json()).jobs);
  } catch (e) {
    document.getElementById("note").textContent = "Cannot read jobs: " + e.message;
  }
}

if (initial) render(initial.jobs);
setInterval(refresh, 2000);
</script>
</body>
</html>
)html";

inline constexpr const char* kLoginPage = R"html(<!doctype html>
<html lang="en">
<head><meta charset="utf-8"><title>lightfarm: token needed</title></head>
<body style="font: 14px system-ui, sans-serif; margin: 2em">
<h1>lightfarm</h1>
<p>This page needs a token (lightfarmd prints where it keeps them when it starts).</p>
<form method="get" action="/">
  <input name="token" type="password" size="70" placeholder="token" autofocus>
  <button>Open</button>
</form>
</body>
</html>
)html";

}  // namespace lf::server
