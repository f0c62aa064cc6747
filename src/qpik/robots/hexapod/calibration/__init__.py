"""Kinematic calibration of the hexapod: identification of geometric errors from strokes."""

from .identification import (
    IMPOSED_UM,
    METHODS,
    MIN_MANIPULABILITY,
    PARAMETER_SETS,
    POSE_BOX_POSITION_M,
    POSE_BOX_RPY_DEG,
    SEED_POSES,
    UM,
    Calibration,
    Fit,
    Identifiability,
    ParameterSet,
    StrokeModel,
    calibrate,
    fit,
    identifiability,
    resolve_poses,
    sample_poses,
    validate_poses,
)

__all__ = [
    "IMPOSED_UM", "METHODS", "MIN_MANIPULABILITY", "PARAMETER_SETS", "POSE_BOX_POSITION_M", "POSE_BOX_RPY_DEG",
    "SEED_POSES", "UM", "Calibration", "Fit", "Identifiability", "ParameterSet", "StrokeModel", "calibrate", "fit",
    "identifiability", "resolve_poses", "sample_poses", "validate_poses",
]
