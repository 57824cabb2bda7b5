"""`cbdam.open(REPO).read()` timed (docs/RESULTS.md, "Decode speed: like for like"): one untimed
read, then RUNS reads, each one's CPU time (time.process_time(): every thread of the process)
and wall time; prints "LABEL cpu_s wall_s sha256-prefix" per read. One core:
`RAYON_NUM_THREADS=1 taskset -c 0 python read_cpu.py …`.
usage: read_cpu.py LABEL REPO RUNS [float32|float64]"""
import hashlib
import sys
import time
import cbdam
label, repo, runs = sys.argv[1], sys.argv[2], int(sys.argv[3])
dt = sys.argv[4] if len(sys.argv) > 4 else "float32"
r = cbdam.open(repo)
z = r.read(out_dtype=dt)
sha = hashlib.sha256(z.tobytes()).hexdigest()[:16]
del z
for _ in range(runs):
    t0, w0 = time.process_time(), time.perf_counter()
    z = r.read(out_dtype=dt)
    c, w = time.process_time() - t0, time.perf_counter() - w0
    print(f"{label} {c:.4f} {w:.4f} {sha}", flush=True)
    del z
