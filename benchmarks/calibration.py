"""The hexapod calibration table: `qpik calibrate` on the source's four seed poses with
each method (linear, Gauss–Newton, Levenberg–Marquardt), recorded for docs/results.md.

    python benchmarks/calibration.py [--out benchmarks/results]

writes calibration.{json,md} (about 2 s) and generates docs/results.md again. The tests
recompute the rows on the installed versions and compare them with this recording
(tests/robots/test_recorded_rows.py).
"""

from __future__ import annotations

import argparse
import platform
import sys
from importlib.metadata import version
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the tables and the page: the package tools

from qpik.rollout.io import write_json, write_text  # noqa: E402
from tools.results import refresh  # noqa: E402
from tools.tables import calibration_markdown, calibration_rows  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    rows = calibration_rows()
    meta = {"python": platform.python_version(), "machine": platform.machine(),
            "versions": {name: version(name) for name in ("mujoco", "numpy", "scipy")},
            "command": "python benchmarks/calibration.py"}
    markdown = calibration_markdown(rows)
    write_json(args.out / "calibration.json", {"meta": meta, "rows": rows})
    write_text(args.out / "calibration.md", markdown)
    print(markdown)
    return refresh(args.out)


if __name__ == "__main__":
    sys.exit(main())
