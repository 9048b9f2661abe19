#!/usr/bin/env python3
"""What a killed worker costs a bake, with and without resuming.

Bakes SCENE once uninterrupted; then again, killed with SIGKILL after
--kill-at seconds of wall time and run a second time, once with --resume (it
continues after its last snapshot) and once without (from pass 0). Prints the
wall times, the pass each second run started after, and whether the resumed
bake's lightmap equals the uninterrupted one (`lightfarm compare`: RMSE 0).

  python3 bench/resume_after_kill.py examples/cornell_box.gltf \\
      --passes 1024 --kill-at 8 -- --res 256
"""
import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time

LIGHTFARM = os.path.join(os.path.dirname(__file__), "..", "build", "client_cli", "lightfarm")


def bake(scene, out, passes, extra, resume=False, kill_at=None):
    """Runs `lightfarm bake --json`; returns (wall seconds, start event, done event or None)."""
    cmd = [LIGHTFARM, "bake", scene, "--out", out, "--passes", str(passes), "--json"] + extra
    if resume:
        cmd.append("--resume")
    # Events go to a file: a pipe nobody reads while the bake runs would fill
    # up and stop it.
    with tempfile.TemporaryFile(mode="w+") as events:
        start = time.monotonic()
        child = subprocess.Popen(cmd, stdout=events, text=True)
        if kill_at is not None:
            try:
                child.wait(timeout=kill_at)
            except subprocess.TimeoutExpired:
                child.send_signal(signal.SIGKILL)
        child.wait()
        seconds = time.monotonic() - start
        events.seek(0)
        started, done = None, None
        for line in events:
            try:
                event = json.loads(line)
            except json.JSONDecodeError:  # the line a kill cut short
                continue
            if event["event"] == "start":
                started = event
            elif event["event"] == "done":
                done = event
    return seconds, started, done


def resumed_after(started):
    return started.get("resumed", {}).get("lightmap", {}).get("pass", 0)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scene")
    parser.add_argument("--passes", type=int, default=1024)
    parser.add_argument("--kill-at", type=float, required=True, help="seconds of wall time before the kill")
    args, extra = parser.parse_known_args()  # the rest: more bake settings, after --
    args.extra = [a for a in extra if a != "--"]

    work = tempfile.mkdtemp(prefix="lf_resume_bench_")
    try:
        whole = os.path.join(work, "whole")
        t_whole, _, done = bake(args.scene, whole, args.passes, args.extra)
        if done is None:
            sys.exit("the uninterrupted bake did not finish")
        rows = [("uninterrupted", t_whole, 0, "")]
        for resume in (True, False):
            out = os.path.join(work, "resume" if resume else "restart")
            t_killed, _, killed_done = bake(args.scene, out, args.passes, args.extra, kill_at=args.kill_at)
            if killed_done is not None:
                sys.exit("the bake finished before --kill-at: kill earlier or bake longer")
            t_again, started, done = bake(args.scene, out, args.passes, args.extra, resume=resume)
            compare = json.loads(subprocess.run(
                [LIGHTFARM, "compare", os.path.join(out, "lightmap.exr"), os.path.join(whole, "lightmap.exr")],
                check=True, capture_output=True, text=True).stdout)
            rows.append(("killed, then " + ("--resume" if resume else "from pass 0"), t_killed + t_again,
                         resumed_after(started), "relative RMSE %.3g" % compare["relative_rmse"]))
        print("| run | wall time, both runs | second run started after pass | against the uninterrupted bake |")
        print("| --- | --- | --- | --- |")
        for name, seconds, after, same in rows:
            print("| %s | %.1f s (%.2f×) | %s | %s |" % (name, seconds, seconds / t_whole, after if name != "uninterrupted" else "", same))
    finally:
        shutil.rmtree(work)


if __name__ == "__main__":
    main()
