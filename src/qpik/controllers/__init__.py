"""Controllers: the QP, the strict hierarchy, SNS and the classical laws, each over N worlds (N = 1: one robot)."""

from .hierarchy import HierarchicalController
from .pinv import JacobianTransposeController, PseudoinverseController
from .qp import QPController
from .sns import SNSController

__all__ = ["HierarchicalController", "JacobianTransposeController", "PseudoinverseController", "QPController",
           "SNSController"]
