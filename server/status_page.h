// GET /: a read-only page with the token's jobs, their live progress and the
// latest preview. Plain HTML and JavaScript, nothing fetched from elsewhere.
// It authenticates with the lightfarm_token cookie that GET /?token=T sets,
// because <img> and fetch from a page cannot be given a bearer header by a
// person typing a URL.
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
  th, td { padding: 4px 10px; border-bottom: 1px solid #ddd; text-align: left; }
  tr.selected { background: #eef; }
  tr { cursor: pointer; }
  .bar { width: 120px; height: 8px; background: #ddd; display: inline-block; }
  .bar > div { height: 8px; background: #4a7; }
  #preview img { max-width: 512px; image-rendering: pixelated; border: 1px solid #ccc; }
  .failed { color: #b00; } .succeeded { color: #070; }
</style>
</head>
<body>
<h1>lightfarm</h1>
<p id="note">Loading jobs…</p>
<table id="jobs">
  <thead><tr><th>job</th><th>state</th><th>pass</th><th>error estimate</th><th>ETA</th><th>progress</th><th>attempts</th></tr></thead>
  <tbody></tbody>
</table>
<h2>Preview <span id="preview-job"></span></h2>
<div id="preview"><img alt="no snapshot yet"></div>
<script>
"use strict";
let selected = null;

function cell(row, text) {
  const td = document.createElement("td");
  td.textContent = text;
  row.appendChild(td);
  return td;
}

function fmt(x, digits) { return x === null || x === undefined ? "–" : Number(x).toFixed(digits); }

function fraction(job) {
  if (job.state === "succeeded") return 1;
  const p = job.progress, eta = p.eta_seconds;
  if (eta === null || eta === undefined || p.seconds <= 0) return 0;
  return p.seconds / (p.seconds + eta);
}

async function refresh() {
  let jobs;
  try {
    const r = await fetch("/v1/jobs", { credentials: "same-origin" });
    if (!r.ok) throw new Error((await r.json()).error || r.statusText);
    jobs = (await r.json()).jobs;
  } catch (e) {
    document.getElementById("note").textContent = "Cannot read jobs: " + e.message;
    return;
  }
  document.getElementById("note").textContent = jobs.length ? "" : "No jobs yet.";
  if (selected === null && jobs.length) selected = jobs[0].id;
  const body = document.querySelector("#jobs tbody");
  body.replaceChildren();
  for (const job of jobs) {
    const row = document.createElement("tr");
    if (job.id === selected) row.className = "selected";
    row.onclick = () => { selected = job.id; refresh(); };
    cell(row, job.id.slice(0, 12));
    cell(row, job.state).className = job.state;
    cell(row, job.progress.pass);
    cell(row, fmt(job.progress.error_estimate, 4));
    cell(row, job.progress.eta_seconds === null ? "–" : fmt(job.progress.eta_seconds, 0) + " s");
    const bar = document.createElement("div");
    bar.className = "bar";
    const fill = document.createElement("div");
    fill.style.width = Math.round(100 * fraction(job)) + "%";
    bar.appendChild(fill);
    cell(row, "").appendChild(bar);
    cell(row, job.attempts + " / " + job.max_attempts);
    if (job.state === "failed") row.title = job.error + ": " + (job.cause || "");
    body.appendChild(row);
  }
  if (selected !== null) {
    document.getElementById("preview-job").textContent = selected.slice(0, 12);
    document.querySelector("#preview img").src = "/v1/jobs/" + selected + "/preview.png?t=" + Date.now();
  }
}

refresh();
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
