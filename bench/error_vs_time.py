#!/usr/bin/env python3
"""Speed against accuracy: bakes a scene with each progressive scheme at
several resolutions, measures bakes of 1, 2, 4, … passes against a
reference, writes a CSV and draws error-versus-time with gnuplot (one curve
per scheme and resolution).

    bench/error_vs_time.py [--res 64 128 256 512] [--passes 1024] [--out bench/out]
    bench/error_vs_time.py --scene monkey.glb --reference-passes 4096 --res 64

The Cornell box is measured against the Blender Cycles reference of
examples; any other scene against the project's own brute-force path
tracer (--scheme pathtrace) at --reference-passes, baked first at each
resolution (DESIGN.md: a reference is analytic, an independent renderer, or
our path tracer at high sample count).

The bake time is lightfarm's own per-pass time (`seconds` in each final file's
header), without process start-up or file writing.
"""
import argparse
import csv
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LIGHTFARM = os.path.join(ROOT, "build", "client_cli", "lightfarm")
SCENES = os.environ.get("LIGHTFARM_SCENES", os.path.join(ROOT, "examples"))


def run(cmd):
    return subprocess.run(cmd, check=True, capture_output=True, text=True).stdout


def stem(scene):
    return os.path.splitext(os.path.basename(scene))[0]


# The reference's seed: not the measured bakes' (the default, 1), so that
# `--schemes pathtrace` is measured against independent samples rather than
# against a longer run of its own first passes.
REFERENCE_SEED = 7919


def bake(scene, scheme, res, passes, out_dir, device, env=None, seed=None):
    """`scheme` is a --scheme, or one with "+denoise" (the same bake, denoised).

    The filter is on by default since 2026-11-28: a plain scheme bakes with
    --no-denoise, so that its curve (and a path-traced reference) stays raw."""
    base, _, variant = scheme.partition("+")
    size = [] if res == "auto" else ["--res", str(res)]
    lines = run([LIGHTFARM, "bake", os.path.join(SCENES, scene), "--out", out_dir] + size
                + ["--passes", str(passes), "--scheme", base, "--device", device, "--json"]
                + (["--denoise"] if variant == "denoise" else ["--no-denoise"]) + (["--env", env] if env else [])
                + (["--seed", str(seed)] if seed is not None else [])).splitlines()
    # The start event (the "prepare" events of preparation's stages come first).
    return next(e for e in map(json.loads, lines) if e["event"] == "start")


def reference_for(scene, res, reference_passes, out, device, env=None):
    """(reference EXR, mask or None) to measure a bake of `scene` at `res` against."""
    if scene == "cornell_box.gltf":
        return os.path.join(SCENES, "cornell_box.ref256.exr"), os.path.join(SCENES, "cornell_box.mask256.pfm")
    d = os.path.join(out, f"{stem(scene)}-reference-{res}-{reference_passes}-seed{REFERENCE_SEED}")
    if not os.path.exists(os.path.join(d, "lightmap.exr")):  # a reference baked before in --out is reused
        bake(scene, "pathtrace", res, reference_passes, d, device, env, REFERENCE_SEED)
    return os.path.join(d, "lightmap.exr"), None


def bake_and_measure(scene, scheme, res, passes, out, device, reference, env=None):
    """One bake per pass count 1, 2, 4, … passes (the same seed: a bake of k
    passes holds what a longer one held after its pass k), each final file
    measured: the snapshots a bake writes follow a time budget, not the
    doublings."""
    ref_exr, mask = reference
    rows = []
    counts = [1 << k for k in range(passes.bit_length()) if 1 << k < passes] + [passes]
    for count in counts:
        d = os.path.join(out, f"{stem(scene)}-{scheme}-{res}-{count}")
        start = bake(scene, scheme, res, count, d, device, env)
        f = os.path.join(d, "lightmap.exr")
        e = json.loads(run([LIGHTFARM, "compare", f, ref_exr] + (["--mask", mask] if mask else [])))
        # A denoised bake's time includes the filter's (upload, filter, read back).
        rows.append({"scene": stem(scene), "scheme": scheme, "res": res, "pass": int(e["pass"]), "rays": int(e["rays"]),
                     "seconds": e["seconds"] + e.get("denoiseSeconds", 0.0), "relative_rmse": e["relative_rmse"],
                     "bias": e["bias"],
                     "error_estimate": e["errorEstimate"], "renderer": start["renderer"]})
    return rows


# Blender Cycles on the same kind of machine (2 cores, no GPU), Cornell box
# 256², relative RMSE against its own 32768-sample bake: examples/SOURCES.md.
CYCLES_256 = [(0.83, 0.201), (2.88, 0.0948), (9.14, 0.0453), (38.8, 0.0226), (155, 0.0118)]


def plot(csv_path, png_path, series, scene):
    script = [
        "set terminal pngcairo size 1000,700",
        f"set output '{png_path}'",
        "set datafile separator ','",
        "set logscale xy",
        "set xlabel 'bake seconds'",
        "set ylabel '%s'" % ("relative RMSE vs Cycles (32768 spp)" if scene == "cornell_box.gltf"
                             else "relative RMSE vs lightfarm path tracing"),
        f"set title '{stem(scene)}' noenhanced",
        "set key outside right",
        "set grid",
    ]
    plots = []
    for scheme, res in series:
        size = "auto atlas" if res == "auto" else f"{res}²"
        plots.append(f"'{csv_path}' using (strcol(2) eq '{scheme}' && strcol(3) eq '{res}' ? $6 : 1/0):7 "
                     f"with linespoints title '{scheme} {size}'")
    if scene == "cornell_box.gltf":
        plots.append("'-' using 1:2 with linespoints lw 2 dt 2 title 'Cycles 256² (SOURCES.md)'")
    script.append("plot " + ", ".join(plots))
    if scene == "cornell_box.gltf":
        script += [f"{t},{e}" for t, e in CYCLES_256] + ["e"]
    subprocess.run(["gnuplot"], input="\n".join(script), text=True, check=True)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--scene", default="cornell_box.gltf", help="a file in examples")
    p.add_argument("--reference-passes", type=int, default=4096, help="path-tracing passes of a reference")
    p.add_argument("--res", nargs="+", default=["64", "128", "256", "512"],
                   help="atlas sides, or auto (the bake's own choice, as a default bake makes it)")
    p.add_argument("--schemes", nargs="+", default=["epochs", "thesis"],
                   help="--scheme values; SCHEME+denoise bakes the same with --denoise")
    p.add_argument("--env", help="a uniform sky R,G,B for scenes lit through windows")
    p.add_argument("--tag", default="", help="appended to the CSV and chart names")
    p.add_argument("--passes", type=int, default=1024)
    p.add_argument("--device", default="auto")
    p.add_argument("--out", default=os.path.join(ROOT, "bench", "out"))
    p.add_argument("--plot-only", action="store_true", help="redraw the chart from the CSV in --out")
    a = p.parse_args()
    os.makedirs(a.out, exist_ok=True)
    name = stem(a.scene)
    csv_path = os.path.join(a.out, f"{name}_error_vs_time{a.tag}.csv")
    png_path = os.path.join(a.out, f"{name}_error_vs_time{a.tag}.png")
    series = [(s, r) for r in a.res for s in a.schemes]
    if a.plot_only:
        plot(csv_path, png_path, series, a.scene)
        return
    rows = []
    for res in a.res:
        reference = reference_for(a.scene, res, a.reference_passes, a.out, a.device, a.env)
        for scheme in a.schemes:
            rows += bake_and_measure(a.scene, scheme, res, a.passes, a.out, a.device, reference, a.env)
            print(f"{scheme} {res}²: {rows[-1]}", file=sys.stderr)
    with open(csv_path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)
    plot(csv_path, png_path, series, a.scene)
    print(csv_path)


if __name__ == "__main__":
    main()
