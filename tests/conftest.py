"""Shared fixtures: the third-party test models, read from the installed PyPI packages
(dm_control, gymnasium; the ``test`` extra) and never copied into the repository."""

from __future__ import annotations

from pathlib import Path

import pytest

from qpik.errors import ModelError
from qpik.models import third_party


def third_party_path(name: str) -> Path:
    """The installed MJCF of a third-party model (:func:`qpik.models.third_party`), or a
    skip saying what is missing."""
    try:
        return third_party(name)
    except ModelError as exc:
        pytest.skip(str(exc))


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
