"""Headless rollouts: the simulate loop, the physics plant, references and the log."""

from .log import RolloutLog
from .references import PositionReference
from .simulate import MODES, Controller, Reference, simulate

__all__ = ["MODES", "Controller", "PositionReference", "Reference", "RolloutLog", "simulate"]
