#!/usr/bin/env python3
"""SH transfer, speed against accuracy: bakes a scene's per-vertex transfer
once at a high sample count (the reference) and at 1, 2, 4, … passes
(the same seed: a bake of k passes holds what a longer one held after its
pass k; snapshots follow a time budget, not the doublings), measures each
against the reference with
`lightfarm compare` (relative RMSE of the coefficients), and draws
error-versus-time with gnuplot.

    bench/sh_error_vs_time.py [--scene monkey.glb] [--passes 64] [--reference-passes 512] [--out bench/out]

Each pass traces 64 rays per vertex; seconds are the bake's own pass time
(the `progress` events), without start-up or file writing.
"""
import argparse
import csv
import json
import os
import subprocess

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LIGHTFARM = os.path.join(ROOT, "build", "client_cli", "lightfarm")
SCENES = os.environ.get("LIGHTFARM_SCENES", os.path.join(ROOT, "examples"))


def bake(scene, passes, out_dir, device, seed):
    lines = subprocess.run([LIGHTFARM, "bake", os.path.join(SCENES, scene), "--sh", "--sh-passes", str(passes),
                            "--out", out_dir, "--device", device, "--seed", str(seed), "--json"],
                           check=True, capture_output=True, text=True).stdout.splitlines()
    events = [json.loads(l) for l in lines]
    start = next(e for e in events if e["event"] == "start")  # after the "prepare" events
    return {e["pass"]: e for e in events if e["event"] == "progress" and not e.get("again")}, start


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--scene", default="monkey.glb")
    p.add_argument("--passes", type=int, default=64)
    p.add_argument("--reference-passes", type=int, default=512)
    p.add_argument("--device", default="auto")
    p.add_argument("--out", default=os.path.join(ROOT, "bench", "out"))
    a = p.parse_args()
    name = os.path.splitext(os.path.basename(a.scene))[0]
    ref_dir = os.path.join(a.out, f"{name}-sh-reference")
    run_dir = os.path.join(a.out, f"{name}-sh")
    bake(a.scene, a.reference_passes, ref_dir, a.device, 1)
    rows = []
    k = 1
    while k <= a.passes:
        progress, start = bake(a.scene, k, f"{run_dir}-{k}", a.device, 2)  # another seed: independent noise
        result = os.path.join(f"{run_dir}-{k}", "sh_transfer.bin")
        e = json.loads(subprocess.run([LIGHTFARM, "compare", result, os.path.join(ref_dir, "sh_transfer.bin")],
                                      check=True, capture_output=True, text=True).stdout)
        rows.append({"pass": k, "samples_per_vertex": 64 * k, "seconds": progress[k]["seconds"],
                     "rays": progress[k]["rays"], "relative_rmse": e["relative_rmse"],
                     "error_estimate": progress[k]["error_estimate"], "renderer": start["renderer"]})
        k *= 2
    os.makedirs(a.out, exist_ok=True)
    csv_path = os.path.join(a.out, f"{name}_sh_error_vs_time.csv")
    with open(csv_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)
    png = os.path.join(a.out, f"{name}_sh_error_vs_time.png")
    script = "\n".join([
        "set terminal pngcairo size 800,560", f"set output '{png}'", "set datafile separator ','",
        "set logscale xy", "set grid", "set xlabel 'bake seconds'",
        f"set ylabel 'relative RMSE of transfer vs {64 * a.reference_passes} samples/vertex'",
        f"set title '{name}: per-vertex SH transfer, 16 coefficients'",
        f"plot '{csv_path}' using 3:5 every ::1 with linespoints title 'measured', "
        f"'{csv_path}' using 3:6 every ::1 with lines dt 2 title 'reported error estimate'"])
    subprocess.run(["gnuplot"], input=script, text=True, check=True)
    for r in rows:
        print(r)


if __name__ == "__main__":
    main()
