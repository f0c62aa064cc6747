"""Geom pairs a collision limit keeps apart: groups of geom (or body) names expanded into
pairs of geom ids, with MuJoCo's own exclusions."""

from __future__ import annotations

import itertools
from typing import Sequence

import mujoco
import numpy as np

from ..errors import InvalidInput, UnknownName
from ..robot import name_hint

GeomGroup = Sequence[str | int]


def geom_pairs(model: mujoco.MjModel, groups: Sequence[tuple[GeomGroup, GeomGroup]]) -> list[tuple[int, int]]:
    """Every (g1, g2), g1 < g2, of a geom of a first group and one of its second group,
    sorted; pairs that MuJoCo's collision detection would never test are left out
    (:func:`may_collide`).

    Raises:
        InvalidInput: a group that is a single name rather than a list.
        UnknownName: a geom or body name the model lacks, or a geom id out of range.
    """
    pairs = set()
    for group1, group2 in groups:
        for g1, g2 in itertools.product(group_geoms(model, group1), group_geoms(model, group2)):
            if g1 != g2 and may_collide(model, g1, g2):
                pairs.add((min(g1, g2), max(g1, g2)))
    return sorted(pairs)


def group_geoms(model: mujoco.MjModel, group: GeomGroup) -> list[int]:
    """The geom ids of a group of geom names, geom ids and body names (a body stands for
    all its geoms)."""
    if isinstance(group, (str, int)):
        raise InvalidInput(f"a geom group is a list of geom (or body) names, got {group!r}")
    ids = []
    for entry in group:
        if isinstance(entry, (int, np.integer)):
            if not 0 <= entry < model.ngeom:
                raise UnknownName(f"geom id {entry} out of range (the model has {model.ngeom} geoms)")
            ids.append(int(entry))
            continue
        geom = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, entry)
        if geom >= 0:
            ids.append(geom)
            continue
        body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, entry)
        if body >= 0:
            ids.extend(int(g) for g in np.flatnonzero(model.geom_bodyid == body))
            continue
        names = [model.geom(g).name for g in range(model.ngeom)] + [model.body(b).name for b in range(model.nbody)]
        raise UnknownName(f"no geom or body named {entry!r} in the model; {name_hint(entry, names, 'geom or body')}")
    return ids


def may_collide(model: mujoco.MjModel, g1: int, g2: int) -> bool:
    """MuJoCo's own exclusions: the same weld; parent and child welds, unless one is the
    world (MuJoCo exempts it) or the model disables the filter (``filterparent``);
    contype/conaffinity."""
    weld1, weld2 = model.body_weldid[model.geom_bodyid[g1]], model.body_weldid[model.geom_bodyid[g2]]
    if weld1 == weld2:
        return False
    parent1 = model.body_weldid[model.body_parentid[weld1]]
    parent2 = model.body_weldid[model.body_parentid[weld2]]
    filter_parent = not model.opt.disableflags & int(mujoco.mjtDisableBit.mjDSBL_FILTERPARENT)
    if filter_parent and weld1 and weld2 and (weld1 == parent2 or weld2 == parent1):
        return False
    return bool(model.geom_contype[g1] & model.geom_conaffinity[g2]) or \
        bool(model.geom_contype[g2] & model.geom_conaffinity[g1])
