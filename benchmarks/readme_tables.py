"""Every results table of the README, written between markers and checked against the code.

    python benchmarks/readme_tables.py            # rewrite every table in README.md
    python benchmarks/readme_tables.py --check    # fail, naming the cell, where README drifts
    python benchmarks/readme_tables.py --check scenarios calibration   # some tables only

The tables, their kinds (recomputed here, or rendered from a benchmark's JSON under
benchmarks/results/) and the comparison of cells are :mod:`qpik.app.readme_tables`; this
is their command line on the repository's README.md and results folder.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from qpik.app.readme_tables import TABLES, check, update

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
RESULTS = ROOT / "benchmarks" / "results"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", metavar="TABLE", help=f"tables (default: all): {', '.join(TABLES)}")
    parser.add_argument("--check", action="store_true", help="compare instead of writing; exit 1 on a difference")
    parser.add_argument("--readme", type=Path, default=README)
    args = parser.parse_args(argv)
    unknown = [n for n in args.names if n not in TABLES]
    if unknown:
        parser.error(f"unknown table(s) {', '.join(unknown)}; known: {', '.join(TABLES)}")
    names = args.names or list(TABLES)
    if args.check:
        problems = check(names, args.readme, RESULTS)
        for line in problems:
            print(line, file=sys.stderr)
        print(f"{len(names)} table(s) checked: {'in step with the code' if not problems else f'{len(problems)} cell(s) differ'}")
        return 1 if problems else 0
    update(names, args.readme, RESULTS)
    print(f"wrote {len(names)} table(s) into {args.readme}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
