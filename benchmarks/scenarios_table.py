"""Every named scenario, qp (DAQP) beside the classical laws and the peers: the README's results table.

    python benchmarks/scenarios_table.py           # run, write the table into README.md and results/
    python benchmarks/scenarios_table.py --check   # run, compare with README.md cell by cell

writes benchmarks/results/scenarios.md and scenarios.json (tracking numbers; the step
times in them are single runs — for timing use step_time.py / compare_peers.py) and the
README block ``<!-- table:scenarios -->``. ``--check`` exits 1, naming every cell where
the README differs from what the code gives on the installed versions (numbers compared
to one unit in their last printed digit). About 30 s.

The chaotic rows (their numbers depend on rounding) are run under every OpenBLAS kernel
this machine can load, recorded in results/scenarios_chaotic.json and printed as a
range; ``--check`` compares them with the recording. The table itself is
:mod:`qpik.app.scenarios_table`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from qpik.app.progress import wanted
from qpik.app.readme_tables import check, update
from qpik.app.scenarios_table import CHAOTIC, compute_rows, load_chaotic, record_chaotic, to_markdown
from qpik.io import write_json, write_text

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
CHAOTIC_RECORD = "scenarios_chaotic.json"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--check", action="store_true", help="compare with README.md instead of writing")
    parser.add_argument("--readme", type=Path, default=ROOT / "README.md")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)
    rows = compute_rows(progress=wanted(args.quiet))
    if args.check:
        return _check(to_markdown(rows, load_chaotic(RESULTS / CHAOTIC_RECORD)), args.readme)
    chaotic = record_chaotic(args.out / CHAOTIC_RECORD)
    md = to_markdown(rows, chaotic)
    print(md)
    write_json(args.out / "scenarios.json", {"runs": [s.to_json() for s in rows]})
    write_text(args.out / "scenarios.md", md)
    update(["scenarios"], args.readme, RESULTS, rendered={"scenarios": md})
    print(f"wrote {args.out / 'scenarios.md'}, {args.out / 'scenarios.json'} and the table in {args.readme}")
    return 0


def _check(md: str, readme: Path) -> int:
    problems = check(["scenarios"], readme, RESULTS, rendered={"scenarios": md})
    for line in problems:
        print(line, file=sys.stderr)
    chaotic = [f"{' / '.join(k)} ({why})" for k, why in CHAOTIC.items()]
    print(f"scenarios table: {'in step with the code' if not problems else f'{len(problems)} cell(s) differ'}; "
          f"compared with its recorded range over BLAS kernels: {'; '.join(chaotic)}")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
