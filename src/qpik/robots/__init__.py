"""The bundled robots: each one a folder with its kinematics and its named scenarios,
and an MJCF scene in the top-level ``scenes/`` folder (installed as ``qpik.scenes``).
Adding a robot = one folder, one scene + one line in ``qpik.scenes.SCENES`` and one in
``BUNDLED``."""

from __future__ import annotations

from pathlib import Path

from ..scenes import SCENES

# Robot name -> (MJCF scene, module whose import registers the robot's scenarios).
BUNDLED: dict[str, tuple[Path, str]] = {
    "arm": (SCENES["arm"], "qpik.robots.arm.scenarios"),
    "hexapod": (SCENES["hexapod"], "qpik.robots.hexapod.scenarios"),
}
