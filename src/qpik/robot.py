"""Robot: a MuJoCo model and its data, with the kinematic quantities the controllers need.

The controllers read everything from one :class:`Robot`: the configuration ``q``
(``data.qpos``), site poses and Jacobians, joint limits and joint velocity limits.
:meth:`Robot.update_kinematics` is the single kinematics update of a control step
(``mj_kinematics`` + ``mj_comPos``, what ``mj_jac*`` needs); nothing else runs
MuJoCo's pipeline in the loop.

Frames are sites, bodies or geoms (``frame_type``, as in mink): :meth:`Robot.frame`
returns a :class:`Frame` whose position and rotation are views of MuJoCo's own arrays
(``site_xpos``/``xpos``/``geom_xpos``, ``site_xmat``/``xmat``/``geom_xmat``) and whose
Jacobian is ``mj_jacSite``/``mj_jacBody``/``mj_jacGeom``. A body's frame is its origin
(``xpos``), not its centre of mass.

Names are checked: an unknown site, body, geom, joint, keyframe or equality raises
:class:`~qpik.errors.UnknownName` listing the model's closest names.

Keyframes: ``Robot(model)`` starts at the model's ``qpos0``; ``Robot(model, keyframe=name)``
at that keyframe, which must exist. ``Robot.load`` of a bundled robot starts at its
``"home"`` keyframe, of an MJCF path at ``qpos0``, unless a keyframe is named.

Joint velocity limits are not part of MJCF; a scene declares them as custom numerics
named ``qpik_velocity_limit_<joint>`` holding one value per degree of freedom.

At load a :class:`Robot` refuses what MuJoCo's compiler lets through silently
(:func:`check_model`; the other checks are :class:`Robot`'s Raises), and its start (the
keyframe at load, every :meth:`Robot.set_q`, ``qpos0`` at the first step) must lie inside
the joint ranges (else :class:`~qpik.errors.OutsideJointLimits` names each joint, unless
``allow_outside_limits``): a model whose ``qpos0`` is outside (dm_control's Jaco,
gymnasium's ant) is fine once ``set_q`` puts it inside. Models may also be URDF files
(MuJoCo reads them) or an :class:`mujoco.MjSpec`.
"""

from __future__ import annotations

import difflib
import functools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import mujoco
import numpy as np

from .equalities import EqualityRows
from .errors import InvalidInput, InvalidWorlds, ModelError, OutsideJointLimits, UnknownName, listed
from .scenes import SCENES

VELOCITY_LIMIT_PREFIX = "qpik_velocity_limit_"

_SCALAR_JOINTS = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
_DOF_COUNT = {int(mujoco.mjtJoint.mjJNT_FREE): 6, int(mujoco.mjtJoint.mjJNT_BALL): 3}  # else 1
# A keyframe may sit this far (joint units) outside a range: the rounding of a range
# written in degrees and a keyframe written in radians, not a start outside the limits.
KEYFRAME_TOLERANCE = 1e-9
# MuJoCo's mjMAXVAL: past it a simulation (and a batch's forward) resets the configuration
# to qpos0, so no frame of the kinematics would be at q.
MAX_CONFIGURATION = 1e10


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
        joint = joint_name(model, j)
        if math.isnan(lower) or math.isnan(upper):
            raise ModelError(f"{label}: joint {joint!r} has a NaN in its range [{lower}, {upper}]")
        written = (lower, upper) != (0.0, 0.0)  # MuJoCo's default: no range given
        if written and int(model.jnt_type[j]) in _SCALAR_JOINTS and not lower < upper:
            raise ModelError(f"{label}: joint {joint!r} has range [{lower}, {upper}]: the lower bound must be "
                             "below the upper one (MuJoCo ignores such a range, leaving the joint unlimited)")


def joint_name(model: mujoco.MjModel, joint: int) -> str:
    """A joint's name in messages (``joint<i>`` for an unnamed one)."""
    return mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, joint) or f"joint{joint}"


FRAME_TYPES = ("site", "body", "geom")
# frame type -> (object type, position array, rotation array, Jacobian function, its body's id array)
FRAMES = {
    "site": (mujoco.mjtObj.mjOBJ_SITE, "site_xpos", "site_xmat", mujoco.mj_jacSite, "site_bodyid"),
    "body": (mujoco.mjtObj.mjOBJ_BODY, "xpos", "xmat", mujoco.mj_jacBody, None),
    "geom": (mujoco.mjtObj.mjOBJ_GEOM, "geom_xpos", "geom_xmat", mujoco.mj_jacGeom, "geom_bodyid"),
}
# object type -> (label in messages, MjModel attribute counting them)
_COUNTS = {getattr(mujoco.mjtObj, f"mjOBJ_{kind.upper()}"): (label, count) for kind, label, count in (
    ("site", "site", "nsite"), ("body", "body", "nbody"), ("geom", "geom", "ngeom"), ("joint", "joint", "njnt"),
    ("key", "keyframe", "nkey"), ("equality", "equality", "neq"), ("tendon", "tendon", "ntendon"),
    ("actuator", "actuator", "nu"))}


class _BundledDefault:
    """Robot.load's default keyframe: "home" for a bundled robot, none for a path."""

    def __repr__(self) -> str:
        return "'home' for a bundled robot, else None"


BUNDLED_HOME = _BundledDefault()


def object_names(model: mujoco.MjModel, kind: mujoco.mjtObj) -> list[str]:
    """The names of every object of a kind (sites, bodies, ...), unnamed ones left out."""
    count = getattr(model, _COUNTS[kind][1])
    return [n for n in (mujoco.mj_id2name(model, kind, i) for i in range(count)) if n]


def name_to_id(model: mujoco.MjModel, kind: mujoco.mjtObj, name: str, model_name: str = "") -> int:
    """The id of a named object, or :class:`UnknownName` listing the closest names.

    Raises:
        UnknownName: no object of this kind has this name.
        InvalidInput: ``name`` is not a string.
    """
    label = _COUNTS[kind][0]
    if not isinstance(name, str):
        raise InvalidInput(f"a {label} name must be a string, got {name!r}")
    idx = mujoco.mj_name2id(model, kind, name)
    if idx >= 0:
        return idx
    names = object_names(model, kind)
    where = f" in model {model_name!r}" if model_name else ""
    if not names:
        raise UnknownName(f"unknown {label} {name!r}{where}: the model has no named {label}")
    raise UnknownName(f"unknown {label} {name!r}{where}; {name_hint(name, names, label)}")


def name_hint(name: str, names, label: str = "") -> str:
    """What to say after an unknown name: its close matches (difflib), else the names."""
    names = [n for n in names if n]
    close = difflib.get_close_matches(str(name), names, n=5, cutoff=0.5)
    if close:
        return f"close matches: {close}"
    if len(names) <= 12:
        return f"known: {names}"
    return f"no close match among its {len(names)} {label} names".replace("  ", " ")


def check_configurations(model: mujoco.MjModel, qpos: np.ndarray, batched: bool) -> None:
    """Refuse configurations (N, nq) with an entry that is not finite or beyond
    ``MAX_CONFIGURATION``, naming the worlds (batched) and the first one's joint.

    Raises:
        InvalidInput: one robot's; InvalidWorlds: some of N worlds'.
    """
    if float(np.einsum("ij,ij->", qpos, qpos)) <= MAX_CONFIGURATION * MAX_CONFIGURATION:  # the usual call (NaN fails)
        return
    bad = np.flatnonzero(~(np.abs(qpos) <= MAX_CONFIGURATION).all(axis=1))
    if not len(bad):
        return
    first = int(bad[0])
    index = int(np.flatnonzero(~(np.abs(qpos[first]) <= MAX_CONFIGURATION))[0])
    joint = int(np.searchsorted(model.jnt_qposadr, index, side="right")) - 1
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, joint) or f"#{joint}"
    detail = f"joint {name} at {qpos[first, index]:g}"
    where = f" in worlds {listed(bad)} (world {first}: {detail})" if batched else f" ({detail})"
    message = (f"configuration is not finite or beyond {MAX_CONFIGURATION:g}, where MuJoCo resets a simulation"
               f"{where}; give configurations within it")
    raise InvalidWorlds(message, bad) if batched else InvalidInput(message)


def as_floats(value, what: str, must: str = "must be") -> np.ndarray:
    """``value`` as a float array of any shape, or InvalidInput ("{what} {must} numbers")."""
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InvalidInput(f"{what} {must} numbers, got {value!r}") from None


def as_index(index: np.ndarray) -> slice | np.ndarray:
    """A slice for consecutive indices (views, no fancy-index copies), else the array."""
    index = np.asarray(index, dtype=int)
    if len(index) and np.array_equal(index, np.arange(index[0], index[0] + len(index))):
        return slice(int(index[0]), int(index[0]) + len(index))
    return index


class Frame:
    """A site, body or geom of a robot: its id and its world pose in every world.

    ``positions`` (N, 3) and ``rotations`` (N, 3, 3) are views of the robot's arrays
    (MuJoCo's ``site_xpos``/``xpos``/``geom_xpos``, ``site_xmat``/...), current after each
    kinematics update; ``position`` and ``rotation`` are world 0's. :meth:`jacobians`
    fills the translational and/or rotational Jacobians (N, 3, nv) of the frame's origin.
    """

    __slots__ = ("name", "type", "id", "body", "positions", "rotations", "position", "rotation", "_jac", "_model",
                 "_data")

    def __init__(self, robot: Robot, name: str, frame_type: str = "site"):
        if frame_type not in FRAMES:
            raise InvalidInput(f"frame_type must be one of {FRAME_TYPES}, got {frame_type!r}")
        kind, position, rotation, jac, body = FRAMES[frame_type]
        self.name, self.type = name, frame_type
        self.id = name_to_id(robot.model, kind, name, robot.name)
        self.body = self.id if body is None else int(getattr(robot.model, body)[self.id])  # the body it is on
        i = self.id
        self.positions = getattr(robot.data, position)[i:i + 1]
        self.rotations = getattr(robot.data, rotation)[i:i + 1].reshape(1, 3, 3)
        self.position, self.rotation = self.positions[0], self.rotations[0]
        self._jac, self._model, self._data = jac, robot.model, robot.data

    def jacobians(self, jacp: np.ndarray | None, jacr: np.ndarray | None = None) -> None:
        """Fill the (1, 3, nv) translational (``jacp``) and/or rotational (``jacr``) Jacobians."""
        self._jac(self._model, self._data, None if jacp is None else jacp[0], None if jacr is None else jacr[0],
                  self.id)

    def jacobian(self, jacp: np.ndarray | None, jacr: np.ndarray | None = None) -> None:
        """Fill the 3 x nv Jacobians of this one world (mink's shapes)."""
        self._jac(self._model, self._data, jacp, jacr, self.id)

    def jacobian_filler(self, jacp: np.ndarray | None, jacr: np.ndarray | None = None) -> Callable[[], None]:
        """A call with no arguments that does :meth:`jacobian` into these 3 x nv arrays
        (MuJoCo's function with its arguments bound: no Python frame each step)."""
        return functools.partial(self._jac, self._model, self._data, jacp, jacr, self.id)

    def jacobians_filler(self, jacp: np.ndarray | None, jacr: np.ndarray | None = None) -> Callable[[], None]:
        """:meth:`jacobian_filler` for (1, 3, nv) arrays (:meth:`jacobians`)."""
        return self.jacobian_filler(None if jacp is None else jacp[0], None if jacr is None else jacr[0])

    def __repr__(self) -> str:
        return f"Frame({self.name!r}, {self.type!r}, id={self.id})"


MODEL_SUFFIXES = (".xml", ".urdf")
# What MuJoCo's compiler says about a URDF link without mass or inertia, and what to do.
_MASSLESS = "mass and inertia of moving bodies must be larger than mjMINVAL"
_URDF_HINT = ("a URDF link without an <inertial> is massless to MuJoCo: give the moving links inertials, or let "
              "MuJoCo bound them by adding <mujoco><compiler boundmass=\"1e-3\" boundinertia=\"1e-6\"/></mujoco> "
              "inside <robot>")


def scene_path(scene: str | Path) -> Path:
    """Resolve a bundled scene name (``"arm"``, ``"hexapod"``) or an MJCF or URDF path."""
    key = str(scene)
    if key in SCENES:
        return SCENES[key]
    path = Path(scene)
    if path.suffix.lower() not in MODEL_SUFFIXES and not path.exists():
        raise UnknownName(
            f"unknown robot {key!r}: expected one of {sorted(SCENES)} or a path to an MJCF or URDF file"
        )
    if not path.is_file():
        raise ModelError(f"model file not found: {path}")
    return path


def load_model(scene: str | Path) -> mujoco.MjModel:
    """Load a bundled scene by name, or any MJCF or URDF file, with a clear error if it fails.

    Raises:
        UnknownName: not a bundled robot's name nor a model file's path.
        ModelError: the file is missing or MuJoCo cannot compile it (for a URDF whose
            links lack inertials, the message says how to give them some).
    """
    path = scene_path(scene)
    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:  # MuJoCo's parser and compiler errors
        urdf = path.suffix.lower() == ".urdf"
        raise ModelError(f"cannot load {'URDF' if urdf else 'MJCF'} {path}: {_compile_message(exc, urdf)}") from None


def _compile_message(exc: Exception, urdf: bool) -> str:
    message = " ".join(str(exc).split())
    if urdf and _MASSLESS in message:
        message += f"; {_URDF_HINT}"
    return message


def as_model(model) -> mujoco.MjModel:
    """An MjModel from an MjModel or an MjSpec (compiled, ModelError if it fails), else
    :class:`InvalidInput`."""
    if isinstance(model, mujoco.MjModel):
        return model
    if isinstance(model, mujoco.MjSpec):
        try:
            return model.compile()
        except ValueError as exc:
            raise ModelError(f"cannot compile the MjSpec: {_compile_message(exc, False)}") from None
    raise InvalidInput(f"expected a mujoco.MjModel or mujoco.MjSpec, got {type(model).__name__}; "
                       "load a file or a bundled robot with Robot.load(path_or_name)")


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
        return float(self.violations(np.asarray(q)[None])[0])

    def violations(self, qs: np.ndarray) -> np.ndarray:
        """:meth:`violation` of each row of ``qs`` (steps x nq), in one vectorised pass (a
        row with a NaN counts 0.0)."""
        worst = self.excess(np.asarray(qs, dtype=float)).max(axis=1, initial=0.0)
        return np.fmax(0.0, worst) + 0.0  # + 0.0: never -0.0

    def excess(self, q: np.ndarray) -> np.ndarray:
        """How far each limited joint of ``q`` (..., nq) lies beyond its range, (..., joints):
        negative inside."""
        values = q[..., self.qpos_index]
        return np.maximum(self.lower - values, values - self.upper)

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
                raise UnknownName(f"unknown limited joint {name!r}; {name_hint(name, self.names, 'limited joint')}")
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
        model: compiled MuJoCo model, or an :class:`mujoco.MjSpec` (compiled here).
        name: a label for logs and summaries (defaults to the model's name).
        keyframe: keyframe to start from (default: none, the model's ``qpos0``).
        allow_outside_limits: accept a start (the keyframe, :meth:`set_q`, the first
            step's configuration) outside the joint ranges, for a :class:`~qpik.JointPositionLimit` to bring
            the joints back; by default such a start raises :class:`OutsideJointLimits`
            naming the joints (mink's ``NotWithinConfigurationLimits``). An attribute:
            it can be switched later.

    Raises:
        ModelError: the model fails :func:`check_model`, or the start keyframe is not
            finite, or the start kinematics are not finite (e.g. a NaN body position),
            or the model declares speed limits for some joints and not others.
        OutsideJointLimits: the start keyframe lies outside the joint ranges (beyond
            :data:`KEYFRAME_TOLERANCE`) and ``allow_outside_limits`` is False (``qpos0``
            is checked at the first step, see :meth:`ensure_kinematics`).
        UnknownName: ``keyframe`` names no keyframe of the model.
        InvalidInput: ``model`` is neither an MjModel nor an MjSpec.
    """

    n = 1  # worlds: the engine's arrays have a leading axis of this length
    batched = False  # what a user reads is world 0 of them (``present``)

    def __init__(self, model: mujoco.MjModel | mujoco.MjSpec, name: str | None = None,
                 keyframe: str | None = None, *, allow_outside_limits: bool = False):
        model = as_model(model)
        self.model = model
        self.data = mujoco.MjData(model)
        self._qpos = self.data.qpos  # one view for the data's life: MuJoCo's getter makes a new one (~0.5 µs)
        self.name = name or model.names[: model.names.find(b"\0")].decode() or "robot"
        check_model(model, f"model {self.name!r}")
        self.allow_outside_limits = bool(allow_outside_limits)
        self.nq, self.nv = model.nq, model.nv
        self.qpos = self._qpos[None]  # (1, nq): the engine's view of the one world
        self._kinematics_state = b""
        self._has_mocap = model.nmocap > 0  # read once: MuJoCo's getter costs ~0.1 µs, twice a step
        self._velocity_shape = (model.nv,)
        self.joint_limits = self._read_joint_limits()
        self.velocity_limits = self._read_velocity_limits()
        self._equality_rows: dict[tuple[int, ...], EqualityRows] = {}  # per set of equalities read
        # qpos0 is checked at the first step (ensure_kinematics), a keyframe or set_q at once.
        self._start_unchecked = True
        if keyframe is not None:
            self._reset_to_keyframe(keyframe)
        self.update_kinematics()
        if not (np.all(np.isfinite(self.data.xpos)) and np.all(np.isfinite(self.data.xmat))):
            raise ModelError(f"model {self.name!r}: the kinematics at the start are not finite "
                             "(a NaN or inf in a body, joint or site placement?)")

    @classmethod
    def load(cls, scene: str | Path | mujoco.MjModel | mujoco.MjSpec,
             keyframe: str | None | _BundledDefault = BUNDLED_HOME, *, allow_outside_limits: bool = False) -> Robot:
        """Load a bundled scene by name (``"arm"``, ``"hexapod"``), an MJCF or URDF path,
        an :class:`mujoco.MjModel` or an :class:`mujoco.MjSpec`.

        Args:
            scene: a bundled robot's name, a path to an MJCF or URDF file, or a model.
            keyframe: the keyframe to start from; by default ``"home"`` for a bundled
                robot and none (``qpos0``) otherwise; ``None``: ``qpos0``.
            allow_outside_limits: accept a start outside the joint ranges (see
                :class:`Robot`).

        Raises:
            UnknownName: unknown robot name, or ``keyframe`` names no keyframe of the model.
            ModelError: the file is missing or MuJoCo cannot compile it.
            OutsideJointLimits: the start keyframe lies outside the joint ranges.
        """
        if isinstance(scene, (mujoco.MjModel, mujoco.MjSpec)):
            model, name = as_model(scene), None
        elif isinstance(scene, (str, Path)):
            name = str(scene) if str(scene) in SCENES else None
            model = load_model(scene)
        else:
            raise InvalidInput(f"Robot.load takes a bundled robot's name {sorted(SCENES)}, a path, a mujoco.MjModel "
                               f"or a mujoco.MjSpec, got {type(scene).__name__}")
        if isinstance(keyframe, _BundledDefault):
            keyframe = "home" if name is not None else None
        return cls(model, name=name, keyframe=keyframe, allow_outside_limits=allow_outside_limits)

    def _check_inside(self, q: np.ndarray, what: str, remedy: str) -> None:
        """Raise :class:`OutsideJointLimits` for a configuration outside the joint ranges,
        unless this robot allows it."""
        if self.allow_outside_limits:
            return
        limits = self.joint_limits
        values, excess = q[limits.qpos_index], limits.excess(q)
        outside = np.flatnonzero(excess > KEYFRAME_TOLERANCE)
        if not len(outside):
            return
        joints = {limits.names[i]: float(excess[i]) for i in outside}
        listed = ", ".join(f"{limits.names[i]} = {values[i]:.6g} not in [{limits.lower[i]:.6g}, "
                           f"{limits.upper[i]:.6g}] (by {excess[i]:.3g})" for i in outside[:8])
        more = f" and {len(outside) - 8} more" if len(outside) > 8 else ""
        raise OutsideJointLimits(f"model {self.name!r}: {what} lies outside the joint ranges ({listed}{more}); "
                                 f"{remedy} (then a JointPositionLimit brings the joints back)", joints)

    # Configuration ---------------------------------------------------------------
    @property
    def q(self) -> np.ndarray:
        """The configuration ``data.qpos`` (a view: writing it changes the robot)."""
        return self._qpos

    def set_q(self, q: np.ndarray) -> None:
        """Set the configuration after checking its shape, finiteness and joint ranges.

        Raises:
            InvalidInput: a wrong shape, NaN or inf.
            OutsideJointLimits: a joint outside its range, unless
                ``allow_outside_limits`` is set on the robot.
        """
        q = np.asarray(q, dtype=float)
        if q.shape != (self.nq,):
            raise InvalidInput(f"configuration must have shape ({self.nq},), got {q.shape}")
        if not np.all(np.isfinite(q)):
            raise InvalidInput("configuration contains NaN or inf")
        self._check_inside(q, "the configuration given to set_q", "give one inside them, or set robot.allow_outside_limits = True")
        self.data.qpos[:] = q
        self._start_unchecked = False

    def update_kinematics(self, state: bytes | None = None) -> None:
        """The one kinematics update per control step: frames and Jacobian data
        (``state``: the configuration's bytes, when the caller has them already).

        Raises:
            InvalidInput: a configuration not finite or beyond ``MAX_CONFIGURATION``.
        """
        self._check_magnitude()
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_comPos(self.model, self.data)
        self._kinematics_state = self._state_bytes() if state is None else state

    def ensure_kinematics(self) -> None:
        """Update the kinematics if the configuration (or a mocap pose) changed since the
        last update: what every controller calls first, so forgetting it cannot drift.

        The first call also checks the start (the model's ``qpos0`` or a configuration
        written into :attr:`q` directly) against the joint ranges.

        Raises:
            OutsideJointLimits: at the first call, a start outside the joint ranges (unless
                ``allow_outside_limits``).
        """
        if self._start_unchecked:
            self._check_inside(self._qpos, "the start configuration", "start inside them (set_q(q) or "
                               "keyframe=name), or load with allow_outside_limits=True")
            self._start_unchecked = False
        state = self._state_bytes() if self._has_mocap else self._qpos.tobytes()
        if state != self._kinematics_state:  # update_kinematics, inline (every step)
            self._check_magnitude()
            mujoco.mj_kinematics(self.model, self.data)
            mujoco.mj_comPos(self.model, self.data)
            self._kinematics_state = state

    def _check_magnitude(self) -> None:
        """:func:`check_configurations` of q: one MuJoCo dot product on the usual call (NaN
        fails it; |q| <= MAX_CONFIGURATION in norm is within it entry by entry)."""
        if not mujoco.mju_dot(self._qpos, self._qpos) <= MAX_CONFIGURATION * MAX_CONFIGURATION:
            check_configurations(self.model, self.qpos, False)

    def _state_bytes(self) -> bytes:
        if self._has_mocap:
            data = self.data
            return self._qpos.tobytes() + data.mocap_pos.tobytes() + data.mocap_quat.tobytes()
        return self._qpos.tobytes()

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
        mujoco.mj_integratePos(self.model, self._qpos, qdot, dt)

    def _checked_velocity(self, qdot, dt) -> np.ndarray:
        """The slow path of :meth:`integrate`: raise the precise error, or return a clean copy."""
        check_step(dt)
        try:
            qdot = np.array(qdot, dtype=float)
        except (TypeError, ValueError):
            raise InvalidInput(f"joint velocity must be an array of numbers, got {qdot!r}") from None
        if qdot.shape != self._velocity_shape:
            raise InvalidInput(f"joint velocity must have shape ({self.nv},), got {qdot.shape}")
        if not np.all(np.isfinite(qdot)):
            raise InvalidInput(f"joint velocity contains NaN or inf: {qdot}")
        return qdot

    @staticmethod
    def present(array: np.ndarray) -> np.ndarray:
        """What a user reads of an engine array (N, ...): its world 0 (a view)."""
        return array[0]

    def world(self, index: int) -> Robot:
        """World ``index`` as a one-world robot: this robot itself (index 0)."""
        if index != 0:
            raise InvalidInput(f"robot {self.name!r} has one world (0), not {index}")
        return self

    def subtree_com(self, body: int) -> np.ndarray:
        """(1, 3) view of the centre of mass of ``body``'s subtree (``subtree_com``)."""
        return self.data.subtree_com[body:body + 1]

    def com_jacobian(self, body: int, out: np.ndarray) -> np.ndarray:
        """(1, 3, nv) Jacobian of :meth:`subtree_com` (``mj_jacSubtreeCom``) into ``out``."""
        mujoco.mj_jacSubtreeCom(self.model, self.data, out[0], body)

    def point_jacobian_filler(self, body: int, points: np.ndarray, out: np.ndarray) -> Callable[[], None]:
        """A call with no arguments that writes the (1, 3, nv) translational Jacobian
        (``mj_jac``) of the world point ``points`` (1, 3) as it is then, fixed to ``body``,
        into ``out`` (MuJoCo's function with its arguments bound)."""
        return functools.partial(mujoco.mj_jac, self.model, self.data, out[0], None, points[0], body)

    def distance_filler(self, pairs, cutoffs: np.ndarray, distances: np.ndarray,
                        fromto: np.ndarray) -> Callable[[], None]:
        """A call with no arguments that writes the signed distance of each geom pair
        (g1, g2) into ``distances`` (1, P) and its closest points (from g1 to g2) into
        ``fromto`` (1, P, 6): ``mj_geomDistance`` on this robot's data, searching up to
        ``cutoffs`` (1, P) (a pair farther apart reads its cutoff, its points zero)."""
        rows = [(int(g1), int(g2), points) for (g1, g2), points in zip(pairs, fromto[0])]
        return functools.partial(measure_pairs, self.model, self.data, rows, cutoffs[0], distances[0])

    def equality_rows(self, ids) -> tuple[np.ndarray, np.ndarray]:
        """MuJoCo's rows of the equalities ``ids`` (ascending, each active and acting on a
        dof) at the current kinematics, in ``mj_makeConstraint``'s layout: residual (1, m)
        and Jacobian (1, m, nv) (``efc_pos``, ``efc_J``; every other constraint type
        disabled for the call, see :class:`~qpik.equalities.EqualityRows`). The arrays
        are the robot's, overwritten by the next call for the same equalities; the data's
        ``efc_*`` arrays are rewritten.

        Raises:
            ModelError: an id without rows (inactive, acting on no dof), or active
                equalities changed since the first call for these ids.
        """
        return cached_rows(self._equality_rows, ids, lambda key: EqualityRows(self.model, self.data, key))

    def mass_matrix(self, out: np.ndarray) -> np.ndarray:
        """(1, nv, nv) joint-space inertia M(q) at the current kinematics (``mj_crb``, then
        ``mj_fullM``: armature included) into ``out``."""
        mujoco.mj_crb(self.model, self.data)
        mujoco.mj_fullM(self.model, self.data, out[0])
        return out

    # Names -------------------------------------------------------------------------
    @property
    def joint_names(self) -> tuple[str, ...]:
        """Every joint's name, in the model's order (``joint<i>`` for an unnamed one)."""
        return tuple(joint_name(self.model, j) for j in range(self.model.njnt))

    def object_id(self, kind: mujoco.mjtObj, name: str) -> int:
        """The id of a named model object; :class:`UnknownName` lists the closest names."""
        return name_to_id(self.model, kind, name, self.name)

    def _reset_to_keyframe(self, keyframe: str) -> None:
        m = self.model
        key_id = self.keyframe_id(keyframe)
        qpos = m.key_qpos[key_id]
        if not np.all(np.isfinite(qpos)):
            raise ModelError(f"model {self.name!r}: keyframe {keyframe!r} has a non-finite qpos: {qpos}")
        self._check_inside(qpos, f"keyframe {keyframe!r}", "fix the keyframe or the ranges, start elsewhere "
                           "with keyframe=None, or pass allow_outside_limits=True")
        mujoco.mj_resetDataKeyframe(m, self.data, key_id)

    # The id of a named site, body, ...; UnknownName lists the closest names.
    site_id = functools.partialmethod(object_id, mujoco.mjtObj.mjOBJ_SITE)
    body_id = functools.partialmethod(object_id, mujoco.mjtObj.mjOBJ_BODY)
    geom_id = functools.partialmethod(object_id, mujoco.mjtObj.mjOBJ_GEOM)
    joint_id = functools.partialmethod(object_id, mujoco.mjtObj.mjOBJ_JOINT)
    keyframe_id = functools.partialmethod(object_id, mujoco.mjtObj.mjOBJ_KEY)
    equality_id = functools.partialmethod(object_id, mujoco.mjtObj.mjOBJ_EQUALITY)

    def joint_dofs(self, name: str) -> np.ndarray:
        """The dof indices of a joint (6 for a free joint, 3 for a ball, else 1)."""
        jid = self.joint_id(name)
        count = _DOF_COUNT.get(int(self.model.jnt_type[jid]), 1)
        return int(self.model.jnt_dofadr[jid]) + np.arange(count)

    def dof_name(self, dof: int) -> str:
        """The joint a dof belongs to (``name[k]`` for the k-th dof of a ball or free joint)."""
        m = self.model
        joint = int(m.dof_jntid[dof])
        name = joint_name(m, joint)
        return name if int(m.jnt_type[joint]) in _SCALAR_JOINTS else f"{name}[{dof - int(m.jnt_dofadr[joint])}]"

    def joint_qpos_index(self, name: str) -> int:
        return int(self.model.jnt_qposadr[self.joint_id(name)])

    def joint_dof_index(self, name: str) -> int:
        return int(self.model.jnt_dofadr[self.joint_id(name)])

    # Frames ------------------------------------------------------------------------
    def frame(self, name: str, frame_type: str = "site") -> Frame:
        """A site, body or geom by name, with views of its pose (see :class:`Frame`).

        Raises:
            InvalidInput: ``frame_type`` is not ``"site"``, ``"body"`` or ``"geom"``.
            UnknownName: no frame of that type has this name (the closest are listed).
        """
        return Frame(self, name, frame_type)

    def frame_position(self, frame: Frame) -> np.ndarray:
        """World position of a frame of this model on this robot (a view)."""
        return getattr(self.data, FRAMES[frame.type][1])[frame.id]

    def frame_rotation(self, frame: Frame) -> np.ndarray:
        """World rotation of a frame of this model on this robot (a 3x3 view)."""
        return getattr(self.data, FRAMES[frame.type][2])[frame.id].reshape(3, 3)

    def frame_jacobian(self, frame: Frame, jacp: np.ndarray | None, jacr: np.ndarray | None = None) -> None:
        """Fill a frame's 3 x nv Jacobians on this robot (another robot of the same model)."""
        FRAMES[frame.type][3](self.model, self.data, jacp, jacr, frame.id)

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
        ids = [j for j in range(m.njnt) if m.jnt_limited[j] and int(m.jnt_type[j]) in _SCALAR_JOINTS]
        names = tuple(joint_name(m, j) for j in ids)
        rng = m.jnt_range[ids] if ids else np.zeros((0, 2))
        return JointLimits(names=names, qpos_index=np.asarray(m.jnt_qposadr[ids], dtype=int),
                           dof_index=np.asarray(m.jnt_dofadr[ids], dtype=int), lower=np.array(rng[:, 0], dtype=float),
                           upper=np.array(rng[:, 1], dtype=float))

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
            if jid < 0:
                raise ModelError(f"numeric {name!r} names no joint of the model; "
                                 f"{name_hint(joint, object_names(m, mujoco.mjtObj.mjOBJ_JOINT), 'joint')}")
            dofs = _DOF_COUNT.get(int(m.jnt_type[jid]), 1)
            adr, size = m.numeric_adr[k], m.numeric_size[k]
            values = np.array(m.numeric_data[adr:adr + size], dtype=float)
            if size not in (1, dofs) or not np.all(values > 0) or not np.all(np.isfinite(values)):
                raise ModelError(f"numeric {name!r} must hold one positive finite value"
                                 + (f" or {dofs}, one per dof" if dofs > 1 else ""))
            vmax[m.jnt_dofadr[jid]:m.jnt_dofadr[jid] + dofs] = values
        self._check_every_joint_bounded(vmax)
        return vmax

    def _check_every_joint_bounded(self, vmax: np.ndarray) -> None:
        """All or nothing: a model that declares some joints' speed limits declares them all
        (a joint left out would be silently unbounded)."""
        missing = np.isinf(vmax)
        if missing.all() or not missing.any():
            return
        joints = sorted({self.dof_name(int(d)).split("[")[0] for d in np.flatnonzero(missing)})
        raise ModelError(f"model {self.name!r} declares speed limits ({VELOCITY_LIMIT_PREFIX}<joint> numerics) for "
                         f"some joints but not for {joints}: declare one for every joint, or none and give "
                         "JointVelocityLimit(robot, {joint: vmax}) the joints to bound")


def measure_pairs(model: mujoco.MjModel, data: mujoco.MjData, rows, cutoffs, distances) -> None:
    """``mj_geomDistance`` on ``data`` of each pair of ``rows`` (g1, g2, its closest points'
    row of fromto, written), searching up to ``cutoffs`` (P,), into ``distances`` (P,)."""
    for p, (g1, g2, points) in enumerate(rows):
        distances[p] = mujoco.mj_geomDistance(model, data, g1, g2, cutoffs[p], points)


def check_step(dt) -> None:
    """InvalidInput unless ``dt``, an integration step, is a positive finite number."""
    try:
        ok = 0.0 < dt < math.inf
    except TypeError:
        ok = False
    if not ok:
        raise InvalidInput(f"integration step dt must be positive and finite, got {dt!r}")


def cached_rows(cache: dict, ids, make: Callable) -> tuple[np.ndarray, np.ndarray]:
    """The rows of the equalities ``ids``: ``cache``'s reader for them (``make(ids)`` on
    the first call, ``ids`` as a tuple), called."""
    key = ids if isinstance(ids, tuple) else tuple(np.asarray(ids, dtype=int).reshape(-1).tolist())
    reader = cache.get(key)
    if reader is None:
        reader = cache[key] = make(key)
    return reader()


def check_same_robot(robot: Robot, tasks, limits=(), controller: str = "the controller") -> None:
    """Refuse a task or limit built on another robot than the controller's.

    Another instance, even of the same model, has its own state (its MjData; a
    :class:`qpik.batch.Robot` its N worlds): a task bound to it would read a robot that
    never moves. A one-world :class:`Robot` and a batch of the same model are different
    robots too. Objects without a ``robot`` attribute (a user's limit that needs none) pass.

    Raises:
        InvalidInput: the first task or limit bound to another robot, named.
    """
    for kind, items in (("task", tasks), ("limit", limits)):
        for item in items or ():
            other = getattr(item, "robot", robot)
            if other is robot:
                continue
            label = getattr(item, "name", None) or type(item).__name__
            raise InvalidInput(f"{controller}: {kind} {label!r} was built on {_other_robot(other, robot)}, not on "
                               f"the controller's {_robot_kind(robot)} {robot.name!r}: build every task and limit on "
                               "the robot given to the controller")


def _robot_kind(robot) -> str:
    """``Robot`` or ``batch.Robot`` (what a message calls it)."""
    return "batch.Robot" if getattr(robot, "batched", False) else "Robot"


def _other_robot(other, robot) -> str:
    """How a refusal names the robot a task was built on instead of ``robot``."""
    sizes = (getattr(other, "name", None), getattr(other, "nq", None), getattr(other, "nv", None))
    if sizes != (robot.name, robot.nq, robot.nv):
        return f"robot {getattr(other, 'name', other)!r}"
    kind = _robot_kind(other)
    if kind != _robot_kind(robot):
        return f"a {kind} of the same model {robot.name!r}"
    state = "its own worlds" if other.batched else "its own MjData"
    return f"another {kind} instance of the same model {robot.name!r} ({state}, which this controller never moves)"
