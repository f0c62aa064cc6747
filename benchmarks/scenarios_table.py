"""Every named scenario, qp (DAQP) beside the classical laws and the peers: the scenarios
table's recording.

    python benchmarks/scenarios_table.py           # run, record, generate docs/results.md again
    python benchmarks/scenarios_table.py --check   # run, compare with the recording cell by cell

writes benchmarks/results/scenarios.json (every row's summary: tracking numbers; the
step times in it are single runs — for timing use step_time.py / compare_peers.py) and
scenarios.md, then generates docs/results.md again. ``--check`` writes nothing and exits
1, naming every cell where the code on the installed versions differs from the recording
(numbers compared to one unit in their last printed digit; the tests run the same
comparison, tests/robots/test_recorded_rows.py). About 30 s.

The chaotic rows (their numbers depend on rounding) are run under every OpenBLAS kernel
this machine can load, recorded in results/scenarios_chaotic.json and printed as a
range; ``--check`` compares them with the recording. The rows are
:mod:`tools.scenarios_table`.
"""

from __future__ import annotations

import argparse
import platform
import sys
from importlib.metadata import version
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the rows, the tables and the page: the package tools

from qpik.app.progress import wanted  # noqa: E402
from qpik.rollout.io import write_json, write_text  # noqa: E402
from tools.results import refresh  # noqa: E402
from tools.scenarios_table import CHAOTIC, compute_rows, load_chaotic, record_chaotic, to_markdown  # noqa: E402
from tools.tables import compare, scenarios_table  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
CHAOTIC_RECORD = "scenarios_chaotic.json"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--check", action="store_true", help="compare with the recording instead of writing")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    rows = compute_rows(progress=wanted(args.quiet))
    if args.check:
        return _check(to_markdown(rows, load_chaotic(RESULTS / CHAOTIC_RECORD)))
    chaotic = record_chaotic(args.out / CHAOTIC_RECORD)
    md = to_markdown(rows, chaotic)
    print(md)
    meta = {"python": platform.python_version(), "machine": platform.machine(),
            "versions": {name: version(name) for name in ("mujoco", "numpy", "daqp")},
            "command": "python benchmarks/scenarios_table.py"}
    write_json(args.out / "scenarios.json", {"meta": meta, "runs": [s.to_json() for s in rows]})
    write_text(args.out / "scenarios.md", md)
    print(f"wrote {args.out / 'scenarios.md'} and {args.out / 'scenarios.json'}")
    return refresh(args.out)


def _check(md: str) -> int:
    problems = compare("scenarios", md, scenarios_table(RESULTS), key_columns=3, tolerant=True)
    for line in problems:
        print(line, file=sys.stderr)
    chaotic = [f"{' / '.join(k)} ({why})" for k, why in CHAOTIC.items()]
    print(f"scenarios table: {'in step with the recording' if not problems else f'{len(problems)} cell(s) differ'}; "
          f"compared with its recorded range over BLAS kernels: {'; '.join(chaotic)}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
