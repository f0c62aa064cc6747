"""Models for the any-robot fuzz: random MJCF chains and trees, and installed third-party models.

:func:`random_mjcf` writes a model of 2–40 joints (hinge, slide, ball, a free base)
whose ranges are present, absent, narrow or one-sided, with collision geoms, a site per
body, fixed and spatial tendons and connect/weld/joint/tendon equalities, all drawn from
a NumPy generator. :func:`third_party_models` lists the MJCF files of dm_control and
gymnasium that load (the packages of the ``models`` extra), :func:`qpik.models.third_party`'s
named ones first.
"""

from __future__ import annotations

import functools
import importlib.util
from pathlib import Path

import numpy as np

from qpik.errors import ModelError
from qpik.models import third_party, third_party_names

# Model folders of the third-party packages, scanned for MJCF files.
PACKAGE_FOLDERS = (("dm_control", "suite"), ("dm_control", "third_party"), ("gymnasium", "envs/mujoco/assets"))
SCALAR = ("hinge", "slide")


def _log_uniform(rng: np.random.Generator, low_exp: float, high_exp: float) -> float:
    return float(10.0 ** rng.uniform(low_exp, high_exp))


def _joint_range(rng: np.random.Generator, kind: str, params: dict) -> str:
    """A range attribute: absent, ordinary, narrow or one-sided (a bound far away)."""
    shape = str(rng.choice(["absent", "present", "narrow", "one-sided"], p=[0.3, 0.4, 0.15, 0.15]))
    params.setdefault("ranges", []).append(shape)
    if kind == "ball":
        return "" if shape == "absent" else f' range="0 {rng.uniform(0.05, 2.0):.6g}"'
    if shape == "absent":
        return ' limited="false"'
    centre = rng.uniform(-0.5, 0.5)
    if shape == "present":
        low, high = centre - rng.uniform(0.1, 2.0), centre + rng.uniform(0.1, 2.0)
    elif shape == "narrow":
        width = _log_uniform(rng, -6, -2)
        low, high = centre - width / 2, centre + width / 2
    elif rng.random() < 0.5:
        low, high = -1e6, centre
    else:
        low, high = centre, 1e6
    return f' limited="true" range="{low:.17g} {high:.17g}"'


def _joint(rng: np.random.Generator, index: int, under_world: bool, params: dict) -> tuple[str, str]:
    kind = str(rng.choice(["hinge", "slide", "ball", "free"], p=[0.55, 0.25, 0.15, 0.05]))
    if kind == "free" and not under_world:
        kind = "hinge"
    params.setdefault("joints", []).append(kind)
    if kind == "free":
        return kind, f'<freejoint name="j{index}"/>'
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    axis_text = "" if kind == "ball" else f' axis="{axis[0]:.6g} {axis[1]:.6g} {axis[2]:.6g}"'
    return kind, f'<joint name="j{index}" type="{kind}"{axis_text}{_joint_range(rng, kind, params)}/>'


def random_mjcf(rng: np.random.Generator, params: dict) -> str:
    """A random model's MJCF text; ``params`` gets its description (joints, ranges, extras)."""
    n_bodies = int(rng.integers(2, 41))
    tree = bool(rng.random() < 0.5)
    params.update(bodies=n_bodies, tree=tree)
    parents = [-1]  # body i's parent (-1: the world)
    for i in range(1, n_bodies):
        parents.append(int(rng.integers(-1, i)) if tree else i - 1)
    kinds, lines_of = [], {}
    for i in range(n_bodies):
        kind, joint = _joint(rng, i, parents[i] == -1, params)
        kinds.append(kind)
        offset = rng.uniform(-0.3, 0.3, 3) + np.array([0.0, 0.0, 0.25])
        pos = "0 0 0" if i == 0 else f"{offset[0]:.6g} {offset[1]:.6g} {offset[2]:.6g}"
        tip = rng.uniform(-0.2, 0.2, 3)
        lines_of[i] = (f'<body name="b{i}" pos="{pos}">{joint}'
                       f'<geom name="g{i}" type="capsule" size="0.02" fromto="0 0 0 {tip[0]:.6g} {tip[1]:.6g} {tip[2]:.6g}"/>'
                       f'<site name="s{i}" pos="{tip[0]:.6g} {tip[1]:.6g} {tip[2]:.6g}"/>')
    children = {i: [c for c in range(n_bodies) if parents[c] == i] for i in range(-1, n_bodies)}

    def body(i: int) -> str:
        return lines_of[i] + "".join(body(c) for c in children[i]) + "</body>"

    world = "".join(body(c) for c in children[-1])
    if rng.random() < 0.3:  # a jointless body: static, a target for welds and collisions
        world += '<body name="static" pos="0.5 0.5 0.2"><geom name="gs" type="box" size="0.05 0.05 0.05"/></body>'
    scalar = [i for i, k in enumerate(kinds) if k in SCALAR]
    tendons = _tendons(rng, scalar, n_bodies, params)
    equalities = _equalities(rng, scalar, n_bodies, tendons, "static" in world, params)
    return ('<mujoco model="fuzz"><compiler angle="radian"/><option timestep="0.002"/>'
            f"<worldbody>{world}</worldbody>"
            + (f"<tendon>{''.join(tendons)}</tendon>" if tendons else "")
            + (f"<equality>{''.join(equalities)}</equality>" if equalities else "") + "</mujoco>")


def _tendons(rng: np.random.Generator, scalar: list[int], n_bodies: int, params: dict) -> list[str]:
    tendons = []
    if len(scalar) >= 2 and rng.random() < 0.3:
        a, b = rng.choice(scalar, 2, replace=False)
        tendons.append(f'<fixed name="t{len(tendons)}"><joint joint="j{a}" coef="1"/>'
                       f'<joint joint="j{b}" coef="{rng.uniform(-2, 2):.6g}"/></fixed>')
    if rng.random() < 0.2:
        a, b = rng.choice(n_bodies, 2, replace=False)
        tendons.append(f'<spatial name="t{len(tendons)}"><site site="s{a}"/><site site="s{b}"/></spatial>')
    params["tendons"] = len(tendons)
    return tendons


def _equalities(rng: np.random.Generator, scalar: list[int], n_bodies: int, tendons: list[str], static: bool,
                params: dict) -> list[str]:
    out = []
    if rng.random() < 0.2:
        out.append(f'<connect name="e_connect" body1="b{rng.integers(n_bodies)}" anchor="0 0 0"/>')
    if rng.random() < 0.15:
        first = f"b{rng.integers(n_bodies)}"
        second = str(rng.choice(["world", "static" if static else "world", f"b{rng.integers(n_bodies)}"]))
        if second != first:
            out.append(f'<weld name="e_weld" body1="{first}"' + ("" if second == "world" else f' body2="{second}"') + "/>")
    if len(scalar) >= 2 and rng.random() < 0.2:
        a, b = rng.choice(scalar, 2, replace=False)
        out.append(f'<joint name="e_joint" joint1="j{a}" joint2="j{b}" polycoef="0 {rng.uniform(-1, 1):.6g} 0 0 0"/>')
    if tendons and rng.random() < 0.4:
        out.append('<tendon name="e_tendon" tendon1="t0"/>')
    if static and rng.random() < 0.2:
        out.append('<weld name="e_static" body1="static"/>')  # acts on no dof
    params["equalities"] = [e.split('"')[1] for e in out]
    return out


@functools.cache
def third_party_models() -> tuple[str, ...]:
    """The installed third-party MJCF files with at least one dof (named models first)."""
    import mujoco

    paths = []
    for name in third_party_names():
        try:
            paths.append(str(third_party(name)))
        except ModelError:
            continue  # its package is not installed
    for package, folder in PACKAGE_FOLDERS:
        spec = importlib.util.find_spec(package)
        if spec is None or spec.origin is None:
            continue
        for path in sorted((Path(spec.origin).parent / folder).rglob("*.xml")):
            if str(path) in paths:
                continue
            try:
                if mujoco.MjModel.from_xml_path(str(path)).nv > 0:
                    paths.append(str(path))
            except ValueError:  # an include-only file (materials, assets)
                continue
    return tuple(paths)


def short_name(path: str) -> str:
    """A third-party model's package and file, for tables."""
    parts = Path(path).parts
    for package, _ in PACKAGE_FOLDERS:
        if package in parts:
            return package + ":" + "/".join(parts[parts.index(package) + 1:])
    return Path(path).name
