"""Shared fixtures: the third-party test models, read from the installed PyPI packages
(dm_control, gymnasium; the ``test`` extra) and never copied into the repository."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

# name -> (package, path of the MJCF inside the installed package)
THIRD_PARTY = {
    "jaco": ("dm_control", "third_party/kinova/jaco_arm.xml"),  # Kinova Jaco arm, 6 hinges
    "humanoid": ("dm_control", "suite/humanoid_CMU.xml"),  # CMU humanoid: free joint + 56 hinges
    "pusher": ("gymnasium", "envs/mujoco/assets/pusher.xml"),  # 7-DoF arm, no site
}


def third_party_path(name: str) -> Path:
    """The installed MJCF of a third-party model, or a skip saying what is missing."""
    package, relative = THIRD_PARTY[name]
    spec = importlib.util.find_spec(package)
    if spec is None or spec.origin is None:
        pytest.skip(f"the {name} model comes with {package}, which is not installed (pip install -e '.[test]')")
    path = Path(spec.origin).parent / relative
    if not path.is_file():
        pytest.skip(f"the installed {package} has no {relative}")
    return path


@pytest.fixture(scope="session")
def jaco_path() -> Path:
    return third_party_path("jaco")


@pytest.fixture(scope="session")
def humanoid_path() -> Path:
    return third_party_path("humanoid")


@pytest.fixture(scope="session")
def pusher_path() -> Path:
    return third_party_path("pusher")


@pytest.fixture(scope="session")
def model_path():
    """``model_path(name)``: a bundled robot's name as is, a third-party model's path."""

    def get(name: str) -> str:
        return name if name in ("arm", "hexapod") else str(third_party_path(name))

    return get
