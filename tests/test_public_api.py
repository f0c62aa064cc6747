"""Every public name is documented: a docstring of its own and a mention in docs/library.md."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import qpik

LIBRARY = Path(__file__).resolve().parents[1] / "docs" / "library.md"
PUBLIC = [name for name in qpik.__all__ if name != "__version__"]


def own_docstring(obj) -> str:
    """The object's own docstring (a class's, not one inherited from its base)."""
    doc = obj.__dict__.get("__doc__") if isinstance(obj, type) else getattr(obj, "__doc__", None)
    return (doc or "").strip()


@pytest.mark.parametrize("name", PUBLIC)
def test_every_public_name_has_a_docstring(name):
    assert own_docstring(getattr(qpik, name)), f"qpik.{name} has no docstring"


@pytest.mark.parametrize("name", PUBLIC)
def test_every_public_name_is_in_the_library_page(name):
    assert re.search(rf"`[^`]*\b{name}\b[^`]*`", LIBRARY.read_text()), f"qpik.{name} is not in docs/library.md"
