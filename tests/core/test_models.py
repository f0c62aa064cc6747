"""qpik.models: third-party models found in the packages that ship them, or a clear error."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from qpik import ModelError, Robot, UnknownName
from qpik import models
from qpik.models import third_party, third_party_names


@pytest.mark.parametrize("name", third_party_names())
def test_each_model_is_the_installed_packages_file(name, model_path):
    path = Path(model_path(name))  # skips with the reason when the package is missing
    entry = models.THIRD_PARTY[name]
    assert path == third_party(name)
    assert path.is_file() and path.as_posix().endswith(entry.path)
    assert entry.package in path.parts  # read where pip put it, not from the repository
    assert Robot.load(path).nv > 0


def test_an_unknown_name_lists_the_close_ones():
    with pytest.raises(UnknownName, match=r"no third-party model named 'jacco'.*close matches: \['jaco'\]"):
        third_party("jacco")


def test_a_missing_package_names_the_extra(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "gymnasium" else real(name, *a))
    with pytest.raises(ModelError, match=r"gymnasium package, which is not installed: pip install -e \"\.\[models\]\" from qpik.s clone"):
        third_party("pusher")


def test_a_package_without_the_file_says_so(monkeypatch, model_path):
    model_path("jaco")  # dm_control installed, or skip
    entry = models.THIRD_PARTY["jaco"]
    monkeypatch.setitem(models.THIRD_PARTY, "jaco", entry._replace(path="third_party/kinova/no_such_arm.xml"))
    with pytest.raises(ModelError, match="has no third_party/kinova/no_such_arm.xml"):
        third_party("jaco")
