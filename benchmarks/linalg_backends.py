"""The control step on SciPy's LAPACK and on NumPy's (qpik.linalg), in one run: each
back-end rolls out its own copy of the scenario, block-interleaved by the timing harness
(:mod:`timing`; the back-end selected before each of its blocks, outside the timed step);
the median step of each back-end for each of 3 repeats, in µs.

    python benchmarks/linalg_backends.py hexapod-circle:qp scipy,numpy
"""

from __future__ import annotations

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
    argv = sys.argv[1:] if argv is None else argv
    scenario, kind = argv[0].split(":")
    backends = argv[1].split(",") if len(argv) > 1 else ["scipy"]
    timing = interleave([Contestant(b, lambda b=b: BackendRun(b, scenario, kind)) for b in backends], repeats=3)
    medians = {b: [float(m) for m in timing.contestants[b].repeat_medians_us] for b in backends}
    print(json.dumps({"scenario": scenario, "kind": kind, "median_us_per_repeat": medians}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
