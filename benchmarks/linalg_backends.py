"""Per-step time of compute_velocity on SciPy's LAPACK and on NumPy's (qpik.linalg), in
one run: each back-end rolls out its own copy of the scenario, blocks of 50 steps
alternate between them with the order rotated, the garbage collector off; the median
step of each back-end for each of 3 repeats, in µs.

    python benchmarks/linalg_backends.py hexapod-circle:qp scipy,numpy
"""
import gc, sys, time, json
import numpy as np
from qpik.scenario import build_scenario
try:
    from qpik import linalg
    backends = sys.argv[2].split(",") if len(sys.argv) > 2 else ["scipy"]
except ImportError:  # a checkout from before qpik.linalg: its only path
    linalg, backends = None, ["direct"]
scenario, kind = sys.argv[1].split(":")
BLOCK, BLOCKS, REPEATS = 50, 40, 3
out = {}
for repeat in range(REPEATS):
    setups = {b: build_scenario(scenario) for b in backends}
    ctrls = {b: s.controller(kind) for b, s in setups.items()}
    steps = {b: 0 for b in backends}
    times = {b: [] for b in backends}
    n = int(round(next(iter(setups.values())).duration / next(iter(setups.values())).dt))
    gc.collect(); gc.disable()
    for block in range(BLOCKS):
        order = backends[block % len(backends):] + backends[:block % len(backends)]
        for b in order:
            if linalg is not None:
                linalg.use(b)
            s, c = setups[b], ctrls[b]
            for _ in range(BLOCK):
                k = steps[b] % n
                s.reference.apply(k * s.dt)
                t0 = time.perf_counter_ns(); x = c.compute_velocity(); t1 = time.perf_counter_ns()
                s.robot.integrate(x, s.dt)
                times[b].append(t1 - t0); steps[b] += 1
    gc.enable()
    for b in backends:
        out.setdefault(b, []).append(float(np.median(times[b])) / 1000)
print(json.dumps({"scenario": scenario, "kind": kind, "median_us_per_repeat": out}))
