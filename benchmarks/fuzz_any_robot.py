"""Fuzz qpik's promises on any robot: generated and third-party models, every task, limit
and controller (the bundled robots are benchmarks/fuzz_bundled.py's).

Each case (a seed) draws a model — a random MJCF chain or tree of 2–40 hinge, slide,
ball or free joints with ranges present, absent, narrow or one-sided, tendons,
connect/weld/joint/tendon equalities and collision geoms, or a dm_control/gymnasium
model — a start inside, on or outside the ranges, 1–4 tasks, the limits and a controller,
and rolls out 25 steps (see benchmarks.fuzz). Every returned step is checked; a typed error is
checked against an LP on the step's hard rows and box (HiGHS). Failure classes: untyped
exception, non-finite answer, limit crossing, hard task missed, invalid parameter
accepted, typed error on an LP-feasible step, misleading diagnosis, nondeterminism (every
20th case re-run in another process), stray warning, hang (a step over 100 ms of CPU
time, confirmed on a re-run, or a case past --cap seconds of wall time). With --batched K,
every K-th case also runs on N = 4 worlds of a qpik.batch.Robot (other states and targets),
each world against its own one-world run step by step (benchmarks/fuzz/batched.py): a
world that differs is a defect (``batch_differs``).

    nice -n 10 python benchmarks/fuzz_any_robot.py --cases 10000 --seed 0 --jobs 2
    python benchmarks/fuzz_any_robot.py --case 17       # one case here, with details
    python benchmarks/fuzz_any_robot.py --case 17 --batched 1    # ... and on N = 4 worlds

writes benchmarks/results/fuzz_any_robot.json (the counts, where each defect arose,
examples with their command) and fuzz_any_robot.md; finished chunks go to
benchmarks/results/fuzz_any_robot_chunks/ so an interrupted run resumes.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the fuzz harness (benchmarks.fuzz) and the results page (tools)

from benchmarks.fuzz.cases import DEFECTS, run_case  # noqa: E402
from benchmarks.fuzz.sweep import batched, summarise, sweep, to_markdown  # noqa: E402
from qpik.rollout.io import write_json, write_text  # noqa: E402
from tools.results import refresh  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=10000)
    parser.add_argument("--seed", type=int, default=0, help="the first case's seed")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes at once")
    parser.add_argument("--chunk", type=int, default=100, help="cases per chunk file")
    parser.add_argument("--cap", type=float, default=60.0, help="seconds a case may run before it is a hang")
    parser.add_argument("--case", type=int, help="run one case here and print it")
    parser.add_argument("--batched", type=int, default=10, metavar="K",
                        help="every K-th case (seed divisible by K) also on N = 4 worlds against their one-world "
                             "runs (0: none, 1: every case)")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.case is not None:
        with tempfile.TemporaryDirectory(prefix="qpik_fuzz_") as folder:
            result = run_case(args.case, Path(folder), batched=batched(args.case, args.batched))
        print(json.dumps(result, indent=1, default=str))
        return 1 if set(DEFECTS) & set(result["classes"]) else 0
    from tqdm import tqdm

    seeds = list(range(args.seed, args.seed + args.cases))
    stored = sum(len(json.loads(f.read_text())) for f in (args.out / "fuzz_any_robot_chunks" / "chunks").glob("*.json"))
    started = time.monotonic()
    with tqdm(total=len(seeds), desc="any-robot fuzz", unit="case", file=sys.stderr) as bar:
        results = sweep(seeds, args.jobs, args.chunk, args.cap, args.out / "fuzz_any_robot_chunks",
                        progress=bar.update, batched_every=args.batched)
    summary = summarise(results)
    meta = {"first_seed": args.seed, "cases": args.cases, "elapsed_s": time.monotonic() - started,
            "jobs": args.jobs, "cap_s": args.cap, "python": sys.version.split()[0], "cases_from_chunk_files": stored,
            "batched_every": args.batched,
            "command": f"python benchmarks/fuzz_any_robot.py --cases {args.cases} --seed {args.seed} --jobs {args.jobs}"
                       f" --batched {args.batched}"}
    md = to_markdown(summary, meta)
    print(md)
    write_json(args.out / "fuzz_any_robot.json", {"meta": meta, **summary})
    write_text(args.out / "fuzz_any_robot.md", md)
    return refresh(args.out)


if __name__ == "__main__":
    sys.exit(main())
