"""The problem of a control step, in every world: laid out once from (robot, tasks,
limits, dt) and filled every step (:class:`Problem`: the tasks measured, the box and the
general rows written), the hard rows (:class:`Stack`), the cost (:class:`Cost`), and the
closed form with bounds held (:class:`HeldBounds`). The controllers only solve it.
"""

from .closed_form import DampedLeastSquares, HeldBounds, active_bounds, inside, rows_met
from .cost import Cost
from .problem import Problem, check_dt
from .rows import Stack, group_levels, row_slices

__all__ = ["Cost", "DampedLeastSquares", "HeldBounds", "Problem", "Stack", "active_bounds", "check_dt", "group_levels", "inside",
           "row_slices", "rows_met"]
