"""Robot: a MuJoCo model and its data, with the kinematic quantities the controllers need.

The controllers read everything from one :class:`Robot`: the configuration ``q``
(``data.qpos``), site poses and Jacobians, joint limits and joint velocity limits.
:meth:`Robot.update_kinematics` is the single kinematics update of a control step
(``mj_kinematics`` + ``mj_comPos``, what ``mj_jac*`` needs); nothing else runs
MuJoCo's pipeline in the loop.

Joint velocity limits are not part of MJCF; a scene declares them as custom numerics
named ``qpik_velocity_limit_<joint>`` holding one value per degree of freedom.

At load a :class:`Robot` checks what MuJoCo's compiler lets through silently and raises
:class:`~qpik.errors.ModelError` for it: a timestep that is not positive and finite, a
joint range with a NaN or with its lower bound not below its upper one (MuJoCo then
drops the limit without a word), the start keyframe outside the joint ranges (beyond
:data:`KEYFRAME_TOLERANCE`) or not finite, and non-finite kinematics at the start.
"""

from __future__ import annotations

import difflib
import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from .errors import InvalidInput, ModelError, UnknownName
from .robots import BUNDLED

VELOCITY_LIMIT_PREFIX = "qpik_velocity_limit_"

_SCALAR_JOINTS = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
# A keyframe may sit this far (joint units) outside a range: the rounding of a range
# written in degrees and a keyframe written in radians, not a start outside the limits.
KEYFRAME_TOLERANCE = 1e-9


def close_matches(name: str, known) -> str:
    """``"; did you mean 'a', 'b'?"`` (difflib), or ``""`` when nothing is close."""
    matches = difflib.get_close_matches(str(name), [k for k in known if k], n=3)
    return f"; did you mean {', '.join(repr(m) for m in matches)}?" if matches else ""


def _names(model: mujoco.MjModel, kind: mujoco.mjtObj, count: int) -> list[str]:
    return [mujoco.mj_id2name(model, kind, i) or "" for i in range(count)]


def check_model(model: mujoco.MjModel, label: str = "model") -> None:
    """Raise :class:`ModelError` for a model MuJoCo compiles but qpik cannot trust.

    Checks the timestep (positive, finite) and every joint range: a NaN, or a written
    range whose lower bound is not below its upper one, makes MuJoCo drop the limit
    silently (with ``autolimits``) or keep a NaN bound.
    """
    timestep = float(model.opt.timestep)
    if not (math.isfinite(timestep) and timestep > 0.0):
        raise ModelError(f"{label}: the timestep must be positive and finite, got {timestep}")
    for j in range(model.njnt):
        lower, upper = (float(v) for v in model.jnt_range[j])
        joint = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}"
        if math.isnan(lower) or math.isnan(upper):
            raise ModelError(f"{label}: joint {joint!r} has a NaN in its range [{lower}, {upper}]")
        written = (lower, upper) != (0.0, 0.0)  # MuJoCo's default: no range given
        if written and int(model.jnt_type[j]) in _SCALAR_JOINTS and not lower < upper:
            raise ModelError(f"{label}: joint {joint!r} has range [{lower}, {upper}]: the lower bound must be "
                             "below the upper one (MuJoCo ignores such a range, leaving the joint unlimited)")


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

    def violations(self, qs: np.ndarray) -> np.ndarray:
        """:meth:`violation` of each row of ``qs`` (steps x nq), in one vectorised pass.

        A row with a NaN counts 0.0, as :meth:`violation` does.
        """
        qs = np.asarray(qs, dtype=float)
        if len(self.names) == 0 or len(qs) == 0:
            return np.zeros(len(qs))
        values = qs[:, self.qpos_index]
        below = np.max(self.lower - values, axis=1)
        above = np.max(values - self.upper, axis=1)
        return np.fmax(np.fmax(0.0, below), above) + 0.0  # + 0.0: never -0.0, as max(0.0, ...)

    def tightened(self, ranges: dict[str, tuple[float, float]]) -> JointLimits:
        """A copy with some joints' ranges replaced, each inside the old one.

        Raises:
            UnknownName: a joint that has no limit here.
            InvalidInput: a range that is empty, not finite where the old one is, or
                reaches outside the old one.
        """
        lower, upper = self.lower.copy(), self.upper.copy()
        for name, (lo, hi) in ranges.items():
            if name not in self.names:
                raise UnknownName(f"unknown limited joint {name!r}; known: {list(self.names)}"
                                  + close_matches(name, self.names))
            if not lo < hi:
                raise InvalidInput(f"joint {name!r}: lower limit {lo} must be below upper {hi}")
            i = self.names.index(name)
            if not (self.lower[i] <= lo and hi <= self.upper[i]):
                raise InvalidInput(f"joint {name!r}: range [{lo}, {hi}] reaches outside the joint's range "
                                   f"[{self.lower[i]}, {self.upper[i]}]")
            lower[i], upper[i] = lo, hi
        return JointLimits(self.names, self.qpos_index, self.dof_index, lower, upper)


class Robot:
    """A MuJoCo model and one MjData, read and written in place.

    Args:
        model: compiled MuJoCo model.
        name: a label for logs and summaries (defaults to the model's name).
        keyframe: keyframe to start from. ``"home"`` (the default) is used if the model
            has it, else the model's reference configuration ``qpos0``; any other name
            must exist. ``None``: start from ``qpos0``.

    Raises:
        ModelError: the model fails :func:`check_model`, or the start keyframe is not
            finite or lies outside the joint ranges, or the start kinematics are not
            finite (e.g. a NaN body position).
        UnknownName: ``keyframe`` names no keyframe of the model (other than ``"home"``).
    """

    def __init__(self, model: mujoco.MjModel, name: str | None = None, keyframe: str | None = "home"):
        self.model = model
        self.data = mujoco.MjData(model)
        self.name = name or model.names[: model.names.find(b"\0")].decode() or "robot"
        check_model(model, f"model {self.name!r}")
        self.nq = model.nq
        self.nv = model.nv
        self._velocity_shape = (model.nv,)
        self.joint_limits = self._read_joint_limits()
        self.velocity_limits = self._read_velocity_limits()
        if keyframe is not None:
            self._reset_to_keyframe(keyframe)
        self.update_kinematics()
        if not (np.all(np.isfinite(self.data.xpos)) and np.all(np.isfinite(self.data.xmat))):
            raise ModelError(f"model {self.name!r}: the kinematics at the start are not finite "
                             "(a NaN or inf in a body, joint or site placement?)")

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

    def integrate(self, qdot: np.ndarray, dt: float) -> None:
        """q <- q (+) qdot dt on the configuration manifold (``mj_integratePos``).

        Args:
            qdot: joint velocity, shape (nv,), finite.
            dt: time step, positive and finite.

        Raises:
            InvalidInput: a wrong shape, a non-finite velocity, or a time step that is not
                positive and finite (the configuration is left unchanged).
        """
        # On every step of every rollout, so a few hundred nanoseconds: MuJoCo's sum is NaN
        # or inf when an entry is; the exact tests run only when a cheap one fails.
        try:
            ok = 0.0 < dt < math.inf and qdot.shape == self._velocity_shape and math.isfinite(mujoco.mju_sum(qdot))
        except (AttributeError, TypeError):  # not a number, or not a writable contiguous float array
            ok = False
        if not ok:
            qdot = self._checked_velocity(qdot, dt)
        mujoco.mj_integratePos(self.model, self.data.qpos, qdot, dt)

    def _checked_velocity(self, qdot, dt) -> np.ndarray:
        """The slow path of :meth:`integrate`: raise the precise error, or return a clean copy."""
        try:
            dt_ok = 0.0 < dt < math.inf
        except TypeError:
            dt_ok = False
        if not dt_ok:
            raise InvalidInput(f"integration step dt must be positive and finite, got {dt!r}")
        try:
            qdot = np.array(qdot, dtype=float)
        except (TypeError, ValueError):
            raise InvalidInput(f"joint velocity must be an array of numbers, got {qdot!r}") from None
        if qdot.shape != self._velocity_shape:
            raise InvalidInput(f"joint velocity must have shape ({self.nv},), got {qdot.shape}")
        if not np.all(np.isfinite(qdot)):
            raise InvalidInput(f"joint velocity contains NaN or inf: {qdot}")
        return qdot

    # Names -------------------------------------------------------------------------
    @property
    def joint_names(self) -> tuple[str, ...]:
        """Every joint's name, in the model's order (``joint<i>`` for an unnamed one)."""
        m = self.model
        return tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j) or f"joint{j}" for j in range(m.njnt))

    _COUNTS = {mujoco.mjtObj.mjOBJ_SITE: "nsite", mujoco.mjtObj.mjOBJ_BODY: "nbody",
               mujoco.mjtObj.mjOBJ_JOINT: "njnt", mujoco.mjtObj.mjOBJ_KEY: "nkey"}

    def _id(self, kind: mujoco.mjtObj, name: str, label: str) -> int:
        idx = mujoco.mj_name2id(self.model, kind, name)
        if idx < 0:
            count = getattr(self.model, self._COUNTS.get(kind, ""), 0)
            raise UnknownName(f"unknown {label} {name!r} in model {self.name!r}"
                              + close_matches(name, _names(self.model, kind, count)))
        return idx

    def _reset_to_keyframe(self, keyframe: str) -> None:
        m = self.model
        key_id = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, keyframe)
        if key_id < 0:
            if keyframe == "home":
                return  # the default: a model without "home" starts from qpos0
            self._id(mujoco.mjtObj.mjOBJ_KEY, keyframe, "keyframe")
        qpos = m.key_qpos[key_id]
        if not np.all(np.isfinite(qpos)):
            raise ModelError(f"model {self.name!r}: keyframe {keyframe!r} has a non-finite qpos: {qpos}")
        limits = self.joint_limits
        values = qpos[limits.qpos_index]
        outside = (values < limits.lower - KEYFRAME_TOLERANCE) | (values > limits.upper + KEYFRAME_TOLERANCE)
        if np.any(outside):
            bad = ", ".join(f"{limits.names[i]} = {values[i]:.6g} not in [{limits.lower[i]:.6g}, {limits.upper[i]:.6g}]"
                            for i in np.flatnonzero(outside))
            raise ModelError(f"model {self.name!r}: keyframe {keyframe!r} lies outside the joint ranges ({bad}); "
                             "fix the keyframe or the ranges, or start elsewhere with keyframe=None")
        mujoco.mj_resetDataKeyframe(m, self.data, key_id)

    def site_id(self, name: str) -> int:
        return self._id(mujoco.mjtObj.mjOBJ_SITE, name, "site")

    def body_id(self, name: str) -> int:
        return self._id(mujoco.mjtObj.mjOBJ_BODY, name, "body")

    def joint_id(self, name: str) -> int:
        return self._id(mujoco.mjtObj.mjOBJ_JOINT, name, "joint")

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
