"""Fuzz qpik's promises as an outside tester would: random rollouts and mutated models.

The promises checked and the case kinds (``arm``, ``hexapod``, ``physics``, ``model``, each
case reproducible from its seed as ``kind:seed``) are described in
:mod:`benchmarks.fuzz.bundled`; this is their command line.

The sweep runs in chunks of cases in worker subprocesses; the parent times every case
and kills a worker whose case runs past ``--cap`` seconds: that case is a *hang* (its
seed recorded), the rest of the chunk goes to a fresh worker. A step over 50 ms is a
*slow step*; slow cases are re-run once at the end (a busy machine can stall one step)
and reported as confirmed only if slow again.

    nice -n 10 python benchmarks/fuzz_bundled.py --arm 1000 --hexapod 200 --physics 50 --model 50 --seed 0
    python benchmarks/fuzz_bundled.py --case arm:17        # one case, in this process, with details

writes benchmarks/results/fuzz.json (every failing case with its command) and fuzz.md
(the counts of every outcome class, per kind and per solver).
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

from benchmarks.fuzz.bundled import DEFECTS, KINDS, build_case, installed_solvers, run_case  # noqa: E402
from benchmarks.fuzz.bundled_sweep import jsonable, summarise, sweep, to_markdown  # noqa: E402
from tools.results import refresh  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arm", type=int, default=1000)
    parser.add_argument("--hexapod", type=int, default=200)
    parser.add_argument("--physics", type=int, default=50)
    parser.add_argument("--model", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0, help="first seed of every kind")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes at once")
    parser.add_argument("--chunk", type=int, default=25, help="cases per worker process")
    parser.add_argument("--cap", type=float, default=20.0, help="seconds a case may run before it is a hang")
    parser.add_argument("--case", help="run one case KIND:SEED here and print it")
    parser.add_argument("--all-results", action="store_true",
                        help="every case's result in fuzz.json, not only the failures")
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.case:
        kind, seed = args.case.split(":")
        with tempfile.TemporaryDirectory(prefix="qpik_fuzz_") as folder:
            result = run_case(kind, int(seed), Path(folder))
        print(json.dumps(result, indent=1, default=float))
        return 1 if DEFECTS & set(result["classes"]) else 0
    from tqdm import tqdm

    case_ids = [f"{kind}:{args.seed + i}" for kind in KINDS for i in range(getattr(args, kind))]
    started = time.monotonic()
    with tqdm(total=len(case_ids), desc="fuzz", unit="case", file=sys.stderr) as bar:
        results = sweep(case_ids, args.jobs, args.chunk, args.cap, progress=bar.update)
        slow = [cid for cid, r in results.items() if "slow" in r["classes"]][:40]
        if slow:  # a busy machine can stall one step: confirm on a re-run
            bar.set_description("re-running slow cases")
            again = sweep(slow, 1, len(slow), args.cap)
            for cid in slow:
                if "slow" not in again.get(cid, {}).get("classes", []):
                    results[cid]["classes"].remove("slow")
                    results[cid]["details"]["slow_once"] = True
                    if not DEFECTS & set(results[cid]["classes"]) and "typed" not in results[cid]["classes"]:
                        results[cid]["classes"].append("ok")
    with tempfile.TemporaryDirectory(prefix="qpik_fuzz_") as folder:
        for result in results.values():  # a killed case's description: built again here, not run
            if not result["params"]:
                kind, seed = result["case"].split(":")
                try:
                    build_case(kind, int(seed), Path(folder), result["params"])
                except Exception:  # noqa: BLE001 - its description is all we want
                    pass
    summary = summarise(results)
    meta = {"seed": args.seed, "cap_s": args.cap, "jobs": args.jobs, "chunk": args.chunk,
            "elapsed_s": time.monotonic() - started, "solvers": installed_solvers(), "python": sys.version.split()[0],
            "command": "python benchmarks/fuzz_bundled.py " + " ".join(f"--{k} {getattr(args, k)}" for k in KINDS)
                       + f" --seed {args.seed}"}
    md = to_markdown(summary, meta)
    print(md)
    from qpik.rollout.io import write_json, write_text

    everything = {"results": sorted(results.values(), key=lambda r: r["case"])} if args.all_results else {}
    write_json(args.out / "fuzz.json", jsonable({"meta": meta, **summary, **everything}))
    write_text(args.out / "fuzz.md", md)
    return refresh(args.out)


if __name__ == "__main__":
    sys.exit(main())
