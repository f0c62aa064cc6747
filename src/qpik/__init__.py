"""qpik: QP-based differential inverse kinematics on MuJoCo models."""

from __future__ import annotations

__version__ = "0.1.0"
