"""The bundled robots: each one a folder with its MJCF scene, its kinematics and its
named scenarios. Adding a robot = one folder + one line in ``BUNDLED``."""

from __future__ import annotations

from pathlib import Path

_HERE = Path(__file__).resolve().parent

# Robot name -> (MJCF scene, module whose import registers the robot's scenarios).
BUNDLED: dict[str, tuple[Path, str]] = {
    "arm": (_HERE / "arm" / "arm.xml", "qpik.robots.arm.scenarios"),
    "hexapod": (_HERE / "hexapod" / "hexapod.xml", "qpik.robots.hexapod.scenarios"),
}
