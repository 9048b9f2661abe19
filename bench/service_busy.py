#!/usr/bin/env python3
"""How busy a queue keeps the device: starts lightfarmd (default workers) on a
fresh data directory, submits N bakes of one scene at once, waits for them,
and prints one JSON line: the jobs' pass seconds summed over the span from
the first start to the last finish (issue #12: >= 0.8 on a GPU for Cornell
512², 800 passes).

    bench/service_busy.py DATA_DIR [--jobs 8] [--res 512] [--passes 800] [--scene cornell_box.gltf]
"""
import argparse
import json
import os
import subprocess
import sys
import time
import urllib.request

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = os.environ.get("LIGHTFARM_SCENES", os.path.join(ROOT, "examples"))


def call(url, token, method="GET", body=None, content_type="application/json"):
    request = urllib.request.Request(url, data=body, method=method,
                                     headers={"Authorization": "Bearer " + token, "Content-Type": content_type})
    with urllib.request.urlopen(request, timeout=60) as r:
        return json.loads(r.read())


def main():
    p = argparse.ArgumentParser()
    p.add_argument("data")
    p.add_argument("--jobs", type=int, default=8)
    p.add_argument("--res", type=int, default=512)
    p.add_argument("--passes", type=int, default=800)
    p.add_argument("--scene", default="cornell_box.gltf", help="a self-contained .gltf or .glb in examples")
    p.add_argument("--workers", type=int, help="lightfarmd's --workers (default: its own choice)")
    a = p.parse_args()
    os.makedirs(a.data, exist_ok=True)
    daemon = [os.path.join(ROOT, "build", "server", "lightfarmd"), "--data", a.data, "--listen", "127.0.0.1:0",
              "--engine", os.path.join(ROOT, "build", "client_cli", "lightfarm")]
    if a.workers:
        daemon += ["--workers", str(a.workers)]
    server = subprocess.Popen(daemon, stdout=subprocess.DEVNULL, stderr=open(os.path.join(a.data, "log"), "w"))
    try:
        url_file = os.path.join(a.data, "lightfarmd.url")
        for _ in range(600):
            if os.path.exists(url_file) and os.path.exists(os.path.join(a.data, "tokens")):
                break
            time.sleep(0.1)
            if server.poll() is not None:
                break
        if not os.path.exists(url_file):
            sys.exit(f"lightfarmd did not start: see {os.path.join(a.data, 'log')}")
        url = open(url_file).read().strip()
        token = next(l.strip() for l in open(os.path.join(a.data, "tokens")) if l.strip() and not l.startswith("#"))
        path = os.path.join(SCENES, a.scene)
        kind = "model/gltf-binary" if path.endswith(".glb") else "model/gltf+json"
        scene = call(url + "/v1/scenes", token, "POST", open(path, "rb").read(), kind)["id"]
        jobs = [call(url + "/v1/jobs", token, "POST", json.dumps(
            {"scene": scene, "outputs": {"lightmap": {"passes": a.passes}}, "atlas": {"res": a.res},
             "seed": seed}).encode())["id"] for seed in range(1, a.jobs + 1)]
        while True:
            status = [call(url + "/v1/jobs/" + j, token) for j in jobs]
            if all(s["state"] in ("succeeded", "failed", "cancelled") for s in status):
                break
            time.sleep(0.2)
        start = min(s["started_at"] for s in status)
        end = max(s["finished_at"] for s in status)
        passes = sum(s["progress"]["seconds"] for s in status)
        workers = next((l for l in open(os.path.join(a.data, "log")) if "worker(s)" in l), "").strip()
        print(json.dumps({"jobs": a.jobs, "states": sorted({s["state"] for s in status}), "res": a.res,
                          "passes": a.passes, "span_seconds": end - start, "pass_seconds": passes,
                          "busy": passes / (end - start) if end > start else None, "lightfarmd": workers}))
    finally:
        server.terminate()
        server.wait()


if __name__ == "__main__":
    sys.exit(main())
