"""The problem of a control step, laid out once and filled every step.

Built from (robot, tasks, limits, dt): which tasks are hard and which soft (and at which
priority level), the joint-space tasks that go on the Hessian's diagonal, the box
lb ≤ q̇ ≤ ub and the general rows G q̇ ≤ h. Each step :meth:`Problem.fill` updates the
kinematics if q changed, measures every task and writes every limit. The fast paths live
here, each chosen once when the problem is built: the closed-form step and its
exactness argument (:mod:`.closed_form`), the constant parts of H and of the box, and
the small-problem checks in floats. The controllers only solve a filled problem.
"""

from .closed_form import ClosedForm, HeldBounds, closed_form_step, damped_least_squares_step
from .cost import Cost
from .limits import Inequalities
from .problem import Problem, check_dt
from .rows import Stack, group_levels, row_slices

__all__ = ["ClosedForm", "Cost", "HeldBounds", "Inequalities", "Problem", "Stack", "check_dt", "closed_form_step",
           "damped_least_squares_step", "group_levels", "row_slices"]
