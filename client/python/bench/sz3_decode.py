"""SZ3's decode of a DEM at the bound EPS, the like-for-like peer of `cbdam.open(f).read()`
(docs/RESULTS.md, "Decode speed: like for like"): set up as bench/peers.py does (EPS minus the
float32 representation error), CPU by time.process_time() around `sz.decompress` (into a new
NumPy array), median of RUNS. Run it under `taskset -c 0` for one core.
usage: sz3_decode.py (DEM.tif | RAW.f32 WxH) EPS RUNS"""
import sys
import time
import numpy as np
from pysz import sz, szConfig, szErrorBoundMode
src, rest = sys.argv[1], sys.argv[2:]
if src.endswith(".f32"):
    w, h = map(int, rest.pop(0).split("x"))
    v = np.fromfile(src, dtype="<f4").reshape(h, w).astype(np.float64)
else:
    import tifffile
    v = tifffile.imread(src).astype(np.float64)
eps, runs = float(rest[0]), int(rest[1])
f32 = v.astype(np.float32)
repr32 = float(np.abs(f32.astype(np.float64) - v).max())
conf = szConfig(f32.shape); conf.errorBoundMode = szErrorBoundMode.ABS; conf.absErrorBound = eps - repr32
blob, _ = sz.compress(f32, conf)
cpu, wall = [], []
for _ in range(runs):
    t0, w0 = time.process_time(), time.perf_counter()
    dec, _ = sz.decompress(blob, np.float32, f32.shape)
    cpu.append(time.process_time() - t0); wall.append(time.perf_counter() - w0)
err = float(np.abs(dec.astype(np.float64) - v).max())
med = sorted(cpu)[len(cpu)//2]
print(f"SZ3 {src} eps={eps} bits/sample={blob.nbytes*8/v.size:.3f} maxerr={err:.4f} cpu_med={med*1e3:.1f}ms "
      f"({v.size/med/1e6:.1f} M/s) cpu_all={[round(c*1e3,1) for c in cpu]} wall_med={sorted(wall)[len(wall)//2]*1e3:.1f}ms")
