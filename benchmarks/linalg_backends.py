"""The control step on SciPy's LAPACK and on NumPy's (qpik.linalg), in one run: each
back-end rolls out its own copy of the scenario, block-interleaved by the timing harness
(:mod:`timing`; the back-end selected before each of its blocks, outside the timed step);
the median step of each back-end for each of 3 repeats, in µs.

    python benchmarks/linalg_backends.py hexapod-circle:qp scipy,numpy
"""

from __future__ import annotations

import argparse
import json
import sys

from timing import Contestant, ControllerRun, interleave

from qpik import linalg
from qpik.scenario import build_scenario


class BackendRun(ControllerRun):
    """A controller's run on one linear-algebra back-end."""

    def __init__(self, backend: str, scenario: str, kind: str):
        setup = build_scenario(scenario)
        super().__init__(setup.controller(kind), setup)
        self.backend = backend

    def begin_block(self) -> None:
        linalg.use(self.backend)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", metavar="SCENARIO:CONTROLLER", help="e.g. hexapod-circle:qp")
    parser.add_argument("backends", nargs="?", default="scipy", help="comma-separated: scipy, numpy")
    args = parser.parse_args(argv)
    if args.run.count(":") != 1:
        parser.error(f"expected SCENARIO:CONTROLLER, got {args.run!r}")
    scenario, kind = args.run.split(":")
    backends = args.backends.split(",")
    timing = interleave([Contestant(b, lambda b=b: BackendRun(b, scenario, kind)) for b in backends], repeats=3)
    medians = {b: [float(m) for m in timing.contestants[b].repeat_medians_us] for b in backends}
    print(json.dumps({"scenario": scenario, "kind": kind, "median_us_per_repeat": medians}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
