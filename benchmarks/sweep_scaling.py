"""qpik sweep on one machine: in-process against Ray with 1 and 2 workers, per-chunk overhead.

The same sweep (the arm, ``--targets`` worlds in chunks of ``--chunk``, qp and pinv, the
default 1.5 s rollouts) runs in fresh folders, in turn: in-process, ``--ray auto
--workers 1``, ``--ray auto --workers 2``, ``--repeats`` times (block-interleaved, so load
changes on a shared machine hit every runner alike). Each run's ``timing.json`` gives
the wall time, every chunk's compute time inside its worker and, on Ray, the driver's
latency from submitting the chunk to holding its result. Reported:

- wall time per runner (median over repeats), and the 1-worker / 2-worker ratio;
- Ray's per-chunk overhead: latency − compute (scheduling, the result's trip through
  the object store), median over chunks; and wall(Ray, 1 worker) − wall(in-process) per
  chunk, which also holds the cluster's start and the workers' imports;
- bytes per chunk: the result's arrays and the compressed chunk file.

Ray starts its workers at niceness 15 (``RAY_worker_niceness``): on a machine shared with
other jobs they would then get less CPU than the in-process run, whose niceness is 0. The
script runs them at 0 (``--worker-niceness``) so that the runners compete alike.

    python benchmarks/sweep_scaling.py [--targets 16384] [--chunk 2048] [--repeats 1]

writes benchmarks/results/sweep_scaling.{json,md}. Needs the ray extra.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from qpik.rollout.io import write_json, write_text

RESULTS = Path(__file__).resolve().parent / "results"
RUNNERS = {"in-process": [], "ray, 1 worker": ["--ray", "auto", "--workers", "1"],
           "ray, 2 workers": ["--ray", "auto", "--workers", "2"]}


def run(targets: int, chunk: int, extra: list[str], folder: Path) -> dict:
    argv = [sys.executable, "-m", "qpik", "sweep", "arm", "--targets", str(targets), "--chunk", str(chunk),
            "--quiet", "--out", str(folder), *extra]
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL)
    timing = json.loads((folder / "timing.json").read_text())
    timing["summary"] = (folder / "summary.json").read_text()
    return timing


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--targets", type=int, default=16384)
    parser.add_argument("--chunk", type=int, default=2048)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--worker-niceness", type=int, default=0, help="Ray workers' niceness (Ray's default: 15)")
    args = parser.parse_args(argv)
    os.environ["RAY_worker_niceness"] = str(args.worker_niceness)
    runs: dict[str, list[dict]] = {name: [] for name in RUNNERS}
    with tempfile.TemporaryDirectory(prefix="qpik-sweep-scaling-") as tmp:
        for repeat in range(args.repeats):
            for name, extra in RUNNERS.items():
                folder = Path(tmp) / f"{repeat}-{name.replace(' ', '').replace(',', '-')}"
                runs[name].append(run(args.targets, args.chunk, extra, folder))
                print(f"{name}: {runs[name][-1]['wall_s']:.1f} s (load {os.getloadavg()[0]:.1f})", flush=True)
    summaries = {t["summary"] for rs in runs.values() for t in rs}
    rows = {}
    for name, timings in runs.items():
        chunks = [c for t in timings for c in t["per_chunk"]]
        overhead = [c["latency_s"] - c["compute_s"] for c in chunks if "latency_s" in c]
        rows[name] = {"wall_s": float(np.median([t["wall_s"] for t in timings])),
                      "chunk_compute_s_median": float(np.median([c["compute_s"] for c in chunks])),
                      "ray_overhead_per_chunk_s_median": float(np.median(overhead)) if overhead else None,
                      "robot_steps_per_s": float(np.median([t["robot_steps_per_s"] for t in timings])),
                      "load_average": [t["load_average"] for t in timings]}
    chunks = runs["in-process"][0]["per_chunk"]
    n_chunks = len(chunks)
    result = {
        "targets": args.targets, "chunk": args.chunk, "repeats": args.repeats, "chunks": n_chunks,
        "cpus": os.cpu_count(), "ray_worker_niceness": args.worker_niceness, "same_summary": len(summaries) == 1, "runners": rows,
        "ratio_1_to_2_workers": rows["ray, 1 worker"]["wall_s"] / rows["ray, 2 workers"]["wall_s"],
        "ray_1_worker_minus_in_process_per_chunk_s":
            (rows["ray, 1 worker"]["wall_s"] - rows["in-process"]["wall_s"]) / n_chunks,
        "result_bytes_per_chunk": int(np.median([c["result_bytes"] for c in chunks])),
        "file_bytes_per_chunk": int(np.median([c["file_bytes"] for c in chunks])),
    }
    lines = [f"qpik sweep arm, {args.targets} targets in chunks of {args.chunk} (qp and pinv: {n_chunks} chunks), "
             f"{args.repeats} repeat(s) block-interleaved, {os.cpu_count()} CPUs, Ray workers at niceness "
             f"{args.worker_niceness}; the same summary.json from every run: "
             f"{result['same_summary']}.", "",
             "| runner | wall [s] | chunk compute median [s] | Ray overhead per chunk (latency − compute) [s] | "
             "robot-steps/s |", "|---|---:|---:|---:|---:|"]
    for name, r in rows.items():
        overhead = "-" if r["ray_overhead_per_chunk_s_median"] is None else f"{r['ray_overhead_per_chunk_s_median']:.3f}"
        lines.append(f"| {name} | {r['wall_s']:.1f} | {r['chunk_compute_s_median']:.2f} | {overhead} | "
                     f"{r['robot_steps_per_s']:,.0f} |")
    lines += ["", f"1 worker / 2 workers: {result['ratio_1_to_2_workers']:.2f}; Ray with 1 worker − in-process: "
              f"{result['ray_1_worker_minus_in_process_per_chunk_s']:+.2f} s per chunk (cluster start and imports "
              f"included); a chunk's result: {result['result_bytes_per_chunk']:,} bytes of arrays, "
              f"{result['file_bytes_per_chunk']:,} bytes compressed on disk."]
    md = "\n".join(lines) + "\n"
    print(md)
    write_json(args.out / "sweep_scaling.json", result)
    write_text(args.out / "sweep_scaling.md", md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
