"""Controllers over N worlds: the QP, the strict hierarchy, SNS and the classical laws."""

from .hierarchy import HierarchicalController
from .pinv import JacobianTransposeController, PseudoinverseController
from .qp import QPController

__all__ = ["HierarchicalController", "JacobianTransposeController", "PseudoinverseController", "QPController"]
