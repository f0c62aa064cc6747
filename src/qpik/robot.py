"""Robot: a MuJoCo model and its data, with the kinematic quantities the controllers need.

The controllers read everything from one :class:`Robot`: the configuration ``q``
(``data.qpos``), site poses and Jacobians, joint limits and joint velocity limits.
:meth:`Robot.update_kinematics` is the single kinematics update of a control step
(``mj_kinematics`` + ``mj_comPos``, what ``mj_jac*`` needs); nothing else runs
MuJoCo's pipeline in the loop.

Joint velocity limits are not part of MJCF; a scene declares them as custom numerics
named ``qpik_velocity_limit_<joint>`` holding one value per degree of freedom.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from .errors import InvalidInput, ModelError, UnknownName
from .robots import BUNDLED

VELOCITY_LIMIT_PREFIX = "qpik_velocity_limit_"

_SCALAR_JOINTS = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))


def scene_path(scene: str | Path) -> Path:
    """Resolve a bundled scene name (``"arm"``, ``"hexapod"``) or an MJCF path."""
    key = str(scene)
    if key in BUNDLED:
        return BUNDLED[key][0]
    path = Path(scene)
    if path.suffix.lower() != ".xml" and not path.exists():
        raise UnknownName(
            f"unknown robot {key!r}: expected one of {sorted(BUNDLED)} or a path to an MJCF file"
        )
    if not path.is_file():
        raise ModelError(f"MJCF file not found: {path}")
    return path


def load_model(scene: str | Path) -> mujoco.MjModel:
    """Load a bundled scene by name, or any MJCF file, with a clear error if it fails."""
    path = scene_path(scene)
    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:  # MuJoCo's parser and compiler errors
        message = " ".join(str(exc).split())
        raise ModelError(f"cannot load MJCF {path}: {message}") from None


@dataclass(frozen=True)
class JointLimits:
    """Position limits of the limited scalar (hinge/slide) joints.

    ``qpos_index`` and ``dof_index`` address the same joints in ``qpos`` and ``qvel``.
    """

    names: tuple[str, ...]
    qpos_index: np.ndarray
    dof_index: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    def violation(self, q: np.ndarray) -> float:
        """Largest excursion beyond a limit (0.0 when all are kept), in joint units."""
        if len(self.names) == 0:
            return 0.0
        values = q[self.qpos_index]
        return float(max(0.0, np.max(self.lower - values), np.max(values - self.upper)))

    def tightened(self, ranges: dict[str, tuple[float, float]]) -> JointLimits:
        """A copy with some joints' ranges replaced (each must lie inside the old one)."""
        lower, upper = self.lower.copy(), self.upper.copy()
        for name, (lo, hi) in ranges.items():
            if name not in self.names:
                raise UnknownName(f"unknown limited joint {name!r}; known: {list(self.names)}")
            if not lo < hi:
                raise InvalidInput(f"joint {name!r}: lower limit {lo} must be below upper {hi}")
            i = self.names.index(name)
            lower[i], upper[i] = lo, hi
        return JointLimits(self.names, self.qpos_index, self.dof_index, lower, upper)


class Robot:
    """A MuJoCo model and one MjData, read and written in place.

    Args:
        model: compiled MuJoCo model.
        name: a label for logs and summaries (defaults to the model's name).
        keyframe: keyframe to start from, if the model has it (``"home"`` by default).
    """

    def __init__(self, model: mujoco.MjModel, name: str | None = None, keyframe: str | None = "home"):
        self.model = model
        self.data = mujoco.MjData(model)
        self.name = name or model.names[: model.names.find(b"\0")].decode() or "robot"
        self.nq = model.nq
        self.nv = model.nv
        self._kinematics_state = b""
        if keyframe is not None:
            key_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, keyframe)
            if key_id >= 0:
                mujoco.mj_resetDataKeyframe(model, self.data, key_id)
        self.joint_limits = self._read_joint_limits()
        self.velocity_limits = self._read_velocity_limits()
        self.update_kinematics()

    @classmethod
    def load(cls, scene: str | Path, keyframe: str | None = "home") -> Robot:
        """Load a bundled scene by name (``"arm"``, ``"hexapod"``) or an MJCF path."""
        name = str(scene) if str(scene) in BUNDLED else None
        return cls(load_model(scene), name=name, keyframe=keyframe)

    # Configuration ---------------------------------------------------------------
    @property
    def q(self) -> np.ndarray:
        """The configuration ``data.qpos`` (a view: writing it changes the robot)."""
        return self.data.qpos

    def set_q(self, q: np.ndarray) -> None:
        """Set the configuration after checking its shape and finiteness."""
        q = np.asarray(q, dtype=float)
        if q.shape != (self.nq,):
            raise InvalidInput(f"configuration must have shape ({self.nq},), got {q.shape}")
        if not np.all(np.isfinite(q)):
            raise InvalidInput("configuration contains NaN or inf")
        self.data.qpos[:] = q

    def update_kinematics(self) -> None:
        """The one kinematics update per control step: frames and Jacobian data."""
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)
        self._kinematics_state = self._state_bytes()

    def ensure_kinematics(self) -> None:
        """Update the kinematics if the configuration (or a mocap pose) changed since the
        last update: what every controller calls first, so forgetting it cannot drift."""
        if self._state_bytes() != self._kinematics_state:
            self.update_kinematics()

    def _state_bytes(self) -> bytes:
        data = self.data
        if self.model.nmocap:
            return data.qpos.tobytes() + data.mocap_pos.tobytes() + data.mocap_quat.tobytes()
        return data.qpos.tobytes()

    def integrate(self, qdot: np.ndarray, dt: float) -> None:
        """q <- q (+) qdot dt on the configuration manifold (``mj_integratePos``)."""
        mujoco.mj_integratePos(self.model, self.data.qpos, qdot, dt)

    # Names -------------------------------------------------------------------------
    @property
    def joint_names(self) -> tuple[str, ...]:
        """Every joint's name, in the model's order (``joint<i>`` for an unnamed one)."""
        m = self.model
        return tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}" for j in range(m.njnt))

    def _id(self, kind: mujoco.mjtObj, name: str, label: str) -> int:
        idx = mujoco.mj_name2id(self.model, kind, name)
        if idx < 0:
            raise UnknownName(f"unknown {label} {name!r} in model {self.name!r}")
        return idx

    def site_id(self, name: str) -> int:
        return self._id(mujoco.mjtObj.mjOBJ_SITE, name, "site")

    def body_id(self, name: str) -> int:
        return self._id(mujoco.mjtObj.mjOBJ_BODY, name, "body")

    def joint_id(self, name: str) -> int:
        return self._id(mujoco.mjtObj.mjOBJ_JOINT, name, "joint")

    def dof_name(self, dof: int) -> str:
        """The joint a dof belongs to (``name[k]`` for the k-th dof of a ball or free joint)."""
        m = self.model
        joint = int(m.dof_jntid[dof])
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, joint) or f"joint{joint}"
        offset = dof - int(m.jnt_dofadr[joint])
        single = int(m.jnt_type[joint]) in _SCALAR_JOINTS
        return name if single else f"{name}[{offset}]"

    def joint_qpos_index(self, name: str) -> int:
        return int(self.model.jnt_qposadr[self.joint_id(name)])

    def joint_dof_index(self, name: str) -> int:
        return int(self.model.jnt_dofadr[self.joint_id(name)])

    # Frames ------------------------------------------------------------------------
    def site_position(self, site_id: int) -> np.ndarray:
        """World position of a site (a view, valid after :meth:`update_kinematics`)."""
        return self.data.site_xpos[site_id]

    def site_rotation(self, site_id: int) -> np.ndarray:
        """World rotation matrix of a site (a 3x3 view of ``site_xmat``)."""
        return self.data.site_xmat[site_id].reshape(3, 3)

    def site_jacobian(self, site_id: int, jacp: np.ndarray | None, jacr: np.ndarray | None = None) -> None:
        """Fill the 3 x nv translational and/or rotational Jacobians of a site."""
        mujoco.mj_jacSite(self.model, self.data, jacp, jacr, site_id)

    # Limits ------------------------------------------------------------------------
    def _read_joint_limits(self) -> JointLimits:
        m = self.model
        ids = [
            j
            for j in range(m.njnt)
            if m.jnt_limited[j] and int(m.jnt_type[j]) in _SCALAR_JOINTS
        ]
        names = tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}" for j in ids)
        rng = m.jnt_range[ids] if ids else np.zeros((0, 2))
        return JointLimits(
            names=names,
            qpos_index=np.asarray(m.jnt_qposadr[ids], dtype=int),
            dof_index=np.asarray(m.jnt_dofadr[ids], dtype=int),
            lower=np.array(rng[:, 0], dtype=float),
            upper=np.array(rng[:, 1], dtype=float),
        )

    def _read_velocity_limits(self) -> np.ndarray:
        """Per-dof velocity bound (inf where the scene declares none)."""
        m = self.model
        vmax = np.full(m.nv, np.inf)
        for k in range(m.nnumeric):
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_NUMERIC, k) or ""
            if not name.startswith(VELOCITY_LIMIT_PREFIX):
                continue
            joint = name[len(VELOCITY_LIMIT_PREFIX):]
            jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, joint)
            if jid < 0 or int(m.jnt_type[jid]) not in _SCALAR_JOINTS:
                raise ModelError(f"numeric {name!r} names no hinge or slide joint")
            adr, size = m.numeric_adr[k], m.numeric_size[k]
            value = float(m.numeric_data[adr]) if size >= 1 else np.nan
            if size != 1 or not value > 0 or not np.isfinite(value):
                raise ModelError(f"numeric {name!r} must hold one positive finite value")
            vmax[m.jnt_dofadr[jid]] = value
        return vmax
