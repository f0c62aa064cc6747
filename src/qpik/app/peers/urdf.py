r"""A URDF of a compiled MuJoCo model's kinematic tree, for URDF-based peers (placo).

Kinematics only: every body becomes a link placed by its ``body_pos``/``body_quat``; each
of its joints becomes a URDF joint of the same name (hinge → ``revolute``, slide →
``prismatic``, free → ``floating``), chained through intermediate links when a body has
several (MuJoCo applies a body's joints in order, each about its axis in the frame the
previous ones left, which is what a URDF chain with identity origins does); each site
becomes a link on a ``fixed`` joint, so that pinocchio has a frame of the same name.
Joint ranges and the scene's speed bounds become ``<limit>``. Closed chains stay open:
MuJoCo's equality constraints have no URDF counterpart (a peer closes them with tasks).

Generating from the compiled model rather than writing a second description keeps the
two equal by construction; ``tests/test_peers.py`` still checks frames and Jacobians
against MuJoCo's.
"""

from __future__ import annotations

import mujoco
import numpy as np

from .problem import PeerUnsupported

_TYPES = {int(mujoco.mjtJoint.mjJNT_HINGE): "revolute", int(mujoco.mjtJoint.mjJNT_SLIDE): "prismatic",
          int(mujoco.mjtJoint.mjJNT_FREE): "floating"}
# URDF needs a finite velocity limit on every actuated joint; this stands for "none".
NO_VELOCITY_LIMIT = 1e10
# URDF needs a range on revolute joints; an unlimited hinge gets a turn and more.
NO_RANGE = 1e10


def _rpy(quat: np.ndarray) -> tuple[float, float, float]:
    """URDF's roll-pitch-yaw (R = Rz(y) Ry(p) Rx(r)) of a MuJoCo quaternion (w, x, y, z)."""
    R = np.empty(9)
    mujoco.mju_quat2Mat(R, quat)
    R = R.reshape(3, 3)
    pitch = np.arctan2(-R[2, 0], np.hypot(R[0, 0], R[1, 0]))
    return float(np.arctan2(R[2, 1], R[2, 2])), float(pitch), float(np.arctan2(R[1, 0], R[0, 0]))


def _origin(pos, quat=(1.0, 0.0, 0.0, 0.0)) -> str:
    xyz = " ".join(repr(float(v)) for v in pos)
    rpy = " ".join(repr(v) for v in _rpy(np.asarray(quat, dtype=float)))
    return f'<origin xyz="{xyz}" rpy="{rpy}"/>'


def _name(model: mujoco.MjModel, kind: mujoco.mjtObj, index: int, fallback: str) -> str:
    return mujoco.mj_id2name(model, kind, index) or f"{fallback}{index}"


def mjcf_to_urdf(model: mujoco.MjModel, velocity_limits: np.ndarray, robot_name: str = "robot") -> str:
    """The URDF text of ``model``'s tree (see the module docstring).

    Args:
        model: a compiled MuJoCo model whose joints are hinges, slides or free joints
            with their anchor at the body origin.
        velocity_limits: per-dof speed bound (nv,), inf where none.
    """
    links = ["world"]
    joints = []
    body_link = {0: "world"}
    for body in range(1, model.nbody):
        parent = body_link[int(model.body_parentid[body])]
        name = _name(model, mujoco.mjtObj.mjOBJ_BODY, body, "body")
        ids = [j for j in range(model.njnt) if model.jnt_bodyid[j] == body]
        origin = _origin(model.body_pos[body], model.body_quat[body])
        for k, j in enumerate(ids):
            jtype = _TYPES.get(int(model.jnt_type[j]))
            if jtype is None or np.any(model.jnt_pos[j] != 0.0):
                raise PeerUnsupported("URDF export: only hinge, slide and free joints anchored at the body origin")
            jname = _name(model, mujoco.mjtObj.mjOBJ_JOINT, j, "joint")
            child = name if k == len(ids) - 1 else f"{name}__{jname}"
            links.append(child)
            if jtype == "floating":  # a free joint's qpos is the body's world pose: no offset
                joints.append(f'<joint name="{jname}" type="floating"><parent link="{parent}"/>'
                              f'<child link="{child}"/>{_origin((0, 0, 0))}</joint>')
            else:
                limited = bool(model.jnt_limited[j])
                lower, upper = (float(v) for v in model.jnt_range[j]) if limited else (-NO_RANGE, NO_RANGE)
                vmax = velocity_limits[model.jnt_dofadr[j]]
                vmax = float(vmax) if np.isfinite(vmax) else NO_VELOCITY_LIMIT
                axis = " ".join(repr(float(v)) for v in model.jnt_axis[j])
                joints.append(f'<joint name="{jname}" type="{jtype}"><parent link="{parent}"/><child link="{child}"/>'
                              f'{origin}<axis xyz="{axis}"/><limit lower="{lower!r}" upper="{upper!r}" '
                              f'velocity="{vmax!r}" effort="1"/></joint>')
            parent, origin = child, _origin((0, 0, 0))
        if not ids:
            links.append(name)
            joints.append(f'<joint name="{name}__fixed" type="fixed"><parent link="{parent}"/>'
                          f'<child link="{name}"/>{origin}</joint>')
        body_link[body] = name
    for site in range(model.nsite):
        name = _name(model, mujoco.mjtObj.mjOBJ_SITE, site, "site")
        links.append(name)
        parent = body_link[int(model.site_bodyid[site])]
        joints.append(f'<joint name="{name}__fixed" type="fixed"><parent link="{parent}"/>'
                      f'<child link="{name}"/>{_origin(model.site_pos[site], model.site_quat[site])}</joint>')
    lines = ['<?xml version="1.0"?>', f'<robot name="{robot_name}">']
    lines += [f'  <link name="{link}"/>' for link in links]
    lines += [f"  {joint}" for joint in joints]
    lines.append("</robot>")
    return "\n".join(lines) + "\n"
