#!/usr/bin/env python3
"""Probes, speed against accuracy: runs `lightfarm probebench` on a scene,
writes its JSON and two CSVs, and draws with gnuplot
  - error against evaluation cost (C++ points/s) for the four estimators (and polygon-to-point as the paper clamps it) at
    M = 1, 2, 4, 8 (one curve per estimator, one point per M), and
  - error against the distance to a wall, the paper's experiment (its
    Figures 4-5): points moving from the probe to the wall, normals facing it.

    bench/probes.py [--scene cornell_box.gltf] [--at X,Y,Z] [--toward X,Y,Z] [--out docs/bench]
    bench/probes.py --plot-only            # redraw from the JSON in --out

The error is lightfarm's own: against a probe captured at each point
(gi/bake/probe_bench.h says how).
"""
import argparse
import csv
import json
import os
import subprocess

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LIGHTFARM = os.path.join(ROOT, "build", "client_cli", "lightfarm")
SCENES = os.environ.get("LIGHTFARM_SCENES", os.path.join(ROOT, "examples"))
ESTIMATORS = ["sh9", "point_to_point", "polygon_to_point", "polygon_to_point_paper", "ddgi"]


def write_csvs(bench, out, name):
    res = max(r["res"] for r in bench["capture"])  # the least noisy capture
    cost = {(t["m"], t["estimator"]): t for t in bench["throughput"]}
    cost_csv = os.path.join(out, f"{name}_probes_error_vs_cost.csv")
    with open(cost_csv, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["estimator", "m", "res", "cpu_points_per_second", "gpu_points_per_second", "error"])
        # One estimator's rows together, so that gnuplot draws them as one line.
        for e in sorted(bench["error"], key=lambda e: (e["estimator"], e["m"])):
            if e["res"] == res:
                t = cost[(e["m"], e["estimator"])]
                w.writerow([e["estimator"], e["m"], res, t["cpu_points_per_second"],
                            t.get("gpu_points_per_second", ""), e["random"]])
    wall_csv = os.path.join(out, f"{name}_probes_error_vs_wall.csv")
    distance = bench["wall"]["distance"]
    with open(wall_csv, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["estimator", "m", "res", "gap_m", "error"])
        for e in bench["error"]:
            if e["res"] == res:
                for gap, err in zip(bench["wall"]["gaps"], e["wall"]):
                    w.writerow([e["estimator"], e["m"], res, gap * distance, err])
    return cost_csv, wall_csv, res


def gnuplot(lines):
    subprocess.run(["gnuplot"], input="\n".join(lines), text=True, check=True)


def plot(bench, out, name):
    cost_csv, wall_csv, res = write_csvs(bench, out, name)
    m = max(bench["throughput"], key=lambda t: t["m"])["m"]
    common = ["set terminal pngcairo size 900,620 noenhanced", "set datafile separator ','", "set key bottom left",
              "set logscale xy", "set grid"]
    curves = ", ".join(
        f"'{cost_csv}' using (strcol(1) eq '{e}' ? 1e6/$4 : 1/0):6 with linespoints lw 2 title '{e}'"
        for e in ESTIMATORS)
    gnuplot(common + [f"set output '{os.path.join(out, name + '_probes_error_vs_cost.png')}'",
                      f"set title '{name}: one probe, R = {res}, M = 1, 2, 4, 8 (M rising left to right)'",
                      "set xlabel 'C++ evaluation cost per point (µs, one core)'",
                      "set ylabel 'normalised mean |error| over random points'",
                      f"plot {curves}"])
    curves = ", ".join(
        f"'{wall_csv}' using (strcol(1) eq '{e}' && $2 == {m} ? $4 : 1/0):5 with linespoints lw 2 title '{e}'"
        for e in ESTIMATORS)
    gnuplot(common + [f"set output '{os.path.join(out, name + '_probes_error_vs_wall.png')}'",
                      f"set title '{name}: points from the probe to a wall, normal facing it (R = {res}, M = {m})'",
                      "set xlabel 'distance to the wall (m)'", "set ylabel 'relative error'",
                      f"plot {curves}"])


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", default="cornell_box.gltf")
    p.add_argument("--at", help="the probe, X,Y,Z (default the scene's centre)")
    p.add_argument("--toward", help="the wall sweep's direction, X,Y,Z (default -x)")
    p.add_argument("--device", default="auto")
    p.add_argument("--out", default=os.path.join(ROOT, "docs", "bench"))
    p.add_argument("--plot-only", action="store_true")
    a = p.parse_args()
    name = os.path.splitext(os.path.basename(a.scene))[0]
    path = os.path.join(a.out, f"{name}_probebench.json")
    if not a.plot_only:
        cmd = [LIGHTFARM, "probebench", os.path.join(SCENES, a.scene), "--device", a.device]
        cmd += ["--at", a.at] if a.at else []
        cmd += ["--toward", a.toward] if a.toward else []
        bench = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)
        os.makedirs(a.out, exist_ok=True)
        with open(path, "w") as f:
            json.dump(bench, f, indent=1)
    with open(path) as f:
        plot(json.load(f), a.out, name)


if __name__ == "__main__":
    main()
