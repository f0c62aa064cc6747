"""Controllers over N worlds: the QP, the strict hierarchy, SNS and the classical laws."""

from .hierarchy import HierarchicalController
from .pinv import JacobianTransposeController, PseudoinverseController
from .qp import QPController
from .sns import SNSController

__all__ = ["HierarchicalController", "JacobianTransposeController", "PseudoinverseController", "QPController",
           "SNSController"]
