#!/usr/bin/env python3
"""How well the "prepare" events' ETA foretells preparation's time.

Runs `lightfarm bake SCENE --json --passes 1` for each scene and prints, per
stage, the ETA said as the stage began against the time preparation then
really took (the start event's prepare_seconds minus the stage's start), as
a Markdown table:

  bench/preparation_eta.py build/client_cli/lightfarm SCENE [SCENE ...]
"""
import json
import subprocess
import sys
import tempfile


def bake_events(lightfarm, scene):
    with tempfile.TemporaryDirectory() as out:
        run = subprocess.run([lightfarm, "bake", scene, "--out", out, "--json", "--passes", "1"],
                             capture_output=True, text=True, check=True)
    return [json.loads(line) for line in run.stdout.splitlines()]


def main():
    lightfarm, scenes = sys.argv[1], sys.argv[2:]
    print("| scene | triangles | preparation (s) | stage: ETA said / time it took (s) |")
    print("|---|---|---|---|")
    for scene in scenes:
        events = bake_events(lightfarm, scene)
        start = next(e for e in events if e["event"] == "start")
        total = start["prepare_seconds"]
        said = []
        for e in events:
            if e["event"] != "prepare":
                continue
            left = total - e["seconds"]
            eta = e.get("eta_seconds")
            said.append(f'{e["stage"]} {eta:.1f} / {left:.1f}' if eta is not None else f'{e["stage"]} - / {left:.1f}')
        name = scene.rsplit("/", 1)[-1]
        print(f'| {name} | {start["triangles"]} | {total:.1f} | {"; ".join(said)} |')


if __name__ == "__main__":
    main()
