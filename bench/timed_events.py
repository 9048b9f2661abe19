#!/usr/bin/env python3
"""Runs a `lightfarm bake ... --json` command and prints, for its prepare, start,
snapshot and done events, the wall time at which each arrived (seconds since
the command began): where a bake's wall time goes (docs/BENCHMARKS.md "End to
end"). The stages of preparation are in the bake's manifest.json.

    bench/timed_events.py build/client_cli/lightfarm bake SCENE --out DIR --res 512 --passes 64 --json
"""
import subprocess, sys, time, json
t0=time.time()
p=subprocess.Popen(sys.argv[1:], stdout=subprocess.PIPE, text=True)
last=None
for line in p.stdout:
    t=time.time()-t0
    try:
        e=json.loads(line)
    except Exception:
        print(f"{t:7.2f} {line.strip()[:100]}"); continue
    ev=e.get("event")
    if ev in ("prepare","start","snapshot","done"):
        print(f"{t:7.2f} {ev} pass={e.get('pass', e.get('progress',{}).get('pass'))} secs={e.get('seconds', e.get('progress',{}).get('seconds'))} {str(e.get('files',''))[:60]} prep={e.get('prepare_seconds','')}")
    last=(t,e)
p.wait()
print(f"{time.time()-t0:7.2f} exit {p.returncode}")
if last: print(json.dumps(last[1])[:600])
