"""One colour per controller, in every figure and video; the QP solver sets the line style.

A run keeps its colour whatever else is in the comparison (qp is blue beside pinv alone or
beside all eight controllers), so a reader can carry it from ``error.png`` to the video.
Grey is left to the references (limits, desired path). Runs of one controller with several
solvers share its colour and differ by line style (figures) or shade (videos).
"""

from __future__ import annotations

from .kinds import KINDS

# Each controller's colour, from the registry (matplotlib's "tab10" colours).
CONTROLLER_COLOURS = {name: kind.colour for name, kind in KINDS.items()}
OTHER_COLOUR = "#bcbd22"  # olive: a controller not listed above
LIMIT_GREY = "0.4"  # limit lines; no controller is grey

# Solver -> line style; a solver not listed gets the next unused one.
SOLVER_LINESTYLES = {"daqp": "-", "osqp": "--", "proxqp": "-.", "quadprog": (0, (1, 1.5)),
                     "clarabel": (0, (5, 1, 1, 1, 1, 1)), "piqp": (0, (8, 2)),
                     "eiquadprog": "-"}  # placo's own, its only one
_SPARE_LINESTYLES = ((0, (3, 1, 1, 1)), (0, (1, 3)), (0, (6, 3)))


def controller_colour(controller: str) -> str:
    """The ``#rrggbb`` colour of a controller's runs."""
    return CONTROLLER_COLOURS.get(controller, OTHER_COLOUR)


def solver_linestyle(solver: str | None):
    """The matplotlib line style of a run's QP solver (solid for none)."""
    if solver in (None, "", "none"):
        return "-"
    if solver in SOLVER_LINESTYLES:
        return SOLVER_LINESTYLES[solver]
    return _SPARE_LINESTYLES[sum(map(ord, solver)) % len(_SPARE_LINESTYLES)]


def lighten(hex_colour: str, amount: float) -> str:
    """``hex_colour`` mixed with white (amount 0: unchanged, 1: white)."""
    rgb = [int(hex_colour[i:i + 2], 16) for i in (1, 3, 5)]
    return "#" + "".join(f"{round(c + (255 - c) * amount):02x}" for c in rgb)
