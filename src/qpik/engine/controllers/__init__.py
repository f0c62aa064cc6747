"""Controllers over N worlds: the QP, the strict hierarchy, SNS and the classical laws."""

from .qp import QPController

__all__ = ["QPController"]
