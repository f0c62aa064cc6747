"""Headless rollouts: the simulate loop, the physics plant, references and the log."""

from .log import RolloutLog, RunInfo, RunStop, RunSummary
from .references import PositionReference, Reference, ReferenceRun
from .simulate import MODES, Controller, Rollout, simulate

__all__ = ["MODES", "Controller", "PositionReference", "Reference", "ReferenceRun", "Rollout", "RolloutLog",
           "RunInfo", "RunStop", "RunSummary", "simulate"]
