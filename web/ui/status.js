// The status page's jobs table (status.html), served at /ui/status.js: the
// caller's jobs, the selected one's files and preview; status-view3d.js draws
// its 3D view.
"use strict";
// The jobs as the server had them when it sent this page (GET /v1/jobs's
// body, which it fills into the page's #initial-jobs block), so they show at
// once; then refreshed every 2 s.
const initial = JSON.parse(document.getElementById("initial-jobs").textContent);
// #job=ID selects a job (a link to one job's view).
let selected = new URLSearchParams(location.hash.slice(1)).get("job"), shownFilesOf = null;

function cell(row, text) {
  const td = document.createElement("td");
  td.textContent = text;
  row.appendChild(td);
  return td;
}

function fmt(x, digits) { return x === null || x === undefined ? "–" : Number(x).toFixed(digits); }
function when(t) { return t ? new Date(t * 1000).toLocaleString() : "–"; }

// How far the job is, preparation included: the server's fraction, from its
// ETA, which takes every stop (passes, time, target error) into account.
function fraction(job) {
  if (job.state === "succeeded") return 1;
  return job.progress.fraction || 0;
}

function scene(job) {
  if (!job.scene_name) return job.scene.slice(0, 12);
  return job.scene_name + (job.scene_triangles ? " (" + job.scene_triangles.toLocaleString() + " triangles)" : "");
}

function render(jobs) {
  document.getElementById("note").textContent = jobs.length ? "" : "No jobs yet.";
  // #job= takes the 12-character id the page shows (any unique prefix) as well as the whole one.
  const named = selected ? jobs.filter(j => j.id.startsWith(selected)) : [];
  if (named.length === 1) selected = named[0].id;
  if (jobs.length && !jobs.some(j => j.id === selected)) selected = jobs[0].id;
  const body = document.querySelector("#jobs tbody");
  body.replaceChildren();
  for (const job of jobs) {
    const row = document.createElement("tr");
    row.className = "job" + (job.id === selected ? " selected" : "");
    row.onclick = () => {
      selected = job.id;
      shownFilesOf = null;
      if (window.lightfarmView) window.lightfarmView.state.file = null;  // back from an opened file
      render(jobs);
    };
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
    // Before the first pass: the stage preparing (load, atlas, methods ...)
    // and preparation's time left; the job's own ETA comes with its passes.
    const preparing = job.state === "running" && !job.progress.pass;
    const stage = job.progress.preparing ? ": " + job.progress.preparing : "";
    // A queued job: where it stands (its status says, issue #54).
    const place = job.state === "queued" && job.queue
                      ? "queued: " + job.queue.ahead + " ahead, " + job.queue.running + " running"
                      : null;
    const progress = cell(row, place || (preparing ? "preparing" + stage : percent + "%"));
    progress.prepend(bar);
    const known = (seconds) => seconds !== null && seconds !== undefined;
    const starts = place && known(job.queue.starts_in_seconds) ? job.queue.starts_in_seconds : null;
    const eta = starts !== null ? "starts in " + fmt(starts, 0) + " s"
                : preparing && known(job.progress.prepare_eta_seconds)
                    ? fmt(job.progress.prepare_eta_seconds, 0) + " s (preparing)"
                    : known(job.progress.eta_seconds) ? fmt(job.progress.eta_seconds, 0) + " s" : "–";
    cell(row, eta);
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
  // The 3D view (status-view3d.js, a module: it runs after this script) once
  // it has loaded, else when it does.
  if (window.lightfarmView) window.lightfarmView.show(job); else window.lightfarmPendingJob = job;
  const preview = document.getElementById("preview");
  // The server's preview shows the job's first image output (lightmap, else
  // ambient occlusion: the output registry's order).
  const image = job.latest && (job.latest.lightmap || job.latest.ao);
  if (image) {
    let img = preview.querySelector("img");
    if (!img) { img = document.createElement("img"); img.alt = "preview"; preview.replaceChildren(img); }
    img.src = job.links.preview + "?pass=" + image.pass;
  } else {
    preview.replaceChildren();
    const p = document.createElement("p");
    p.className = "muted";
    p.textContent = "No lightmap or ambient occlusion snapshot yet.";
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
