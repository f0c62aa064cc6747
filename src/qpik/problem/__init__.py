"""The problem of a control step, laid out once from (robot, tasks, limits, dt) and
filled every step (:class:`Problem`): hard and soft tasks and their rows (:class:`Stack`),
the cost (:class:`Cost`), the box and general rows (:class:`Inequalities`), and the fast
paths, each chosen once (:mod:`.closed_form`). The controllers only solve it.
"""

from .closed_form import ClosedForm, HeldBounds, closed_form_step, damped_least_squares_step
from .cost import Cost
from .limits import Inequalities
from .problem import Problem, check_dt
from .rows import Stack, group_levels, row_slices

__all__ = ["ClosedForm", "Cost", "HeldBounds", "Inequalities", "Problem", "Stack", "check_dt", "closed_form_step",
           "damped_least_squares_step", "group_levels", "row_slices"]
