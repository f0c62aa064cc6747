"""Controllers: the QP, and the classical laws on the same task objects."""

from .pinv import JacobianTransposeController, PseudoinverseController
from .qp import QPController

__all__ = ["JacobianTransposeController", "PseudoinverseController", "QPController"]
