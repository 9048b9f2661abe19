#!/usr/bin/env python3
"""Speed against accuracy: bakes the Cornell box with each progressive scheme
at several resolutions, measures every snapshot (passes 1, 2, 4, …) against
the Blender Cycles reference, writes a CSV and draws error-versus-time with
gnuplot (one curve per scheme and resolution).

    bench/error_vs_time.py [--res 64 128 256 512] [--passes 1024] [--out bench/out]

The bake time is lightfarm's own per-pass time (`seconds` in each snapshot's
header), without process start-up or file writing.
"""
import argparse
import csv
import glob
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LIGHTFARM = os.path.join(ROOT, "build", "client_cli", "lightfarm")
SCENES = os.environ.get("LIGHTFARM_SCENES", os.path.join(ROOT, "..", "shared", "scenes"))


def run(cmd):
    return subprocess.run(cmd, check=True, capture_output=True, text=True).stdout


def bake_and_measure(scheme, res, passes, out, device):
    d = os.path.join(out, f"cornell-{scheme}-{res}")
    lines = run([LIGHTFARM, "bake", os.path.join(SCENES, "cornell_box.gltf"), "--out", d, "--res", str(res),
                 "--passes", str(passes), "--scheme", scheme, "--device", device, "--json"]).splitlines()
    start = json.loads(lines[0])
    rows = []
    for f in sorted(glob.glob(os.path.join(d, "lightmap.pass-*.exr"))):
        e = json.loads(run([LIGHTFARM, "compare", f, os.path.join(SCENES, "cornell_box.ref256.exr"),
                            "--mask", os.path.join(SCENES, "cornell_box.mask256.pfm")]))
        rows.append({"scheme": scheme, "res": res, "pass": int(e["pass"]), "rays": int(e["rays"]),
                     "seconds": e["seconds"], "relative_rmse": e["relative_rmse"], "bias": e["bias"],
                     "error_estimate": e["errorEstimate"], "renderer": start["renderer"]})
    return rows


# Blender Cycles on the same kind of machine (2 cores, no GPU), Cornell box
# 256², relative RMSE against its own 32768-sample bake: shared/scenes/SOURCES.md.
CYCLES_256 = [(0.83, 0.201), (2.88, 0.0948), (9.14, 0.0453), (38.8, 0.0226), (155, 0.0118)]


def plot(csv_path, png_path, series):
    script = [
        "set terminal pngcairo size 1000,700",
        f"set output '{png_path}'",
        "set datafile separator ','",
        "set logscale xy",
        "set xlabel 'bake seconds'",
        "set ylabel 'relative RMSE vs Cycles (32768 spp)'",
        "set key outside right",
        "set grid",
    ]
    plots = []
    for scheme, res in series:
        plots.append(f"'{csv_path}' using (strcol(1) eq '{scheme}' && $2 == {res} ? $5 : 1/0):6 "
                     f"with linespoints title '{scheme} {res}²'")
    plots.append("'-' using 1:2 with linespoints lw 2 dt 2 title 'Cycles 256² (SOURCES.md)'")
    script.append("plot " + ", ".join(plots))
    script += [f"{t},{e}" for t, e in CYCLES_256] + ["e"]
    subprocess.run(["gnuplot"], input="\n".join(script), text=True, check=True)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--res", type=int, nargs="+", default=[64, 128, 256, 512])
    p.add_argument("--schemes", nargs="+", default=["epochs", "thesis"])
    p.add_argument("--passes", type=int, default=1024)
    p.add_argument("--device", default="auto")
    p.add_argument("--out", default=os.path.join(ROOT, "bench", "out"))
    p.add_argument("--plot-only", action="store_true", help="redraw the chart from the CSV in --out")
    a = p.parse_args()
    os.makedirs(a.out, exist_ok=True)
    csv_path = os.path.join(a.out, "cornell_error_vs_time.csv")
    if a.plot_only:
        plot(csv_path, os.path.join(a.out, "cornell_error_vs_time.png"), [(s, r) for r in a.res for s in a.schemes])
        return
    rows = []
    for res in a.res:
        for scheme in a.schemes:
            rows += bake_and_measure(scheme, res, a.passes, a.out, a.device)
            print(f"{scheme} {res}²: {rows[-1]}", file=sys.stderr)
    with open(csv_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)
    plot(csv_path, os.path.join(a.out, "cornell_error_vs_time.png"), [(s, r) for r in a.res for s in a.schemes])
    print(csv_path)


if __name__ == "__main__":
    main()
