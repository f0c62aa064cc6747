"""Robot: N worlds of one MuJoCo model, their configurations ``q`` (N, nq) and kinematics.

The model is checked and its limits are read by a serial :class:`qpik.Robot` (the
*template*, at the start configuration): the batched robot has the same names, joint
ranges, velocity limits and start checks. The worlds' states and kinematics live in a
back-end (:mod:`qpik.batch.backends`): ``"cpu"`` by default.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import mujoco
import numpy as np

from ..equalities import EqualityRows
from ..errors import InvalidInput, InvalidWorlds, UnknownName, listed
from ..robot import (BUNDLED_HOME, KEYFRAME_TOLERANCE, Robot as SerialRobot, as_floats, as_index, cached_rows,
                     check_configurations, check_step, measure_pairs)
from .errors import NotBatched

BACKENDS = ("cpu", "warp")
# What a batch robot answers as its template (one world of the same model) does.
_TEMPLATE_NAMES = frozenset({"site_id", "body_id", "geom_id", "joint_id", "keyframe_id", "equality_id", "object_id",
                             "joint_dofs", "dof_name", "joint_qpos_index", "joint_dof_index", "joint_names",
                             "joint_limits", "velocity_limits"})


def make_backend(name: str, model: mujoco.MjModel, n: int, **options):
    """The kinematics back-end called ``name`` for N worlds of ``model``."""
    if name == "cpu":
        from .backends.cpu import CpuBackend

        return CpuBackend(model, n, **options)
    if name == "warp":
        try:
            from .backends.warp import WarpBackend  # the GPU back-end, when installed
        except ImportError as exc:
            from ..errors import MissingExtra

            raise MissingExtra(f"the warp back-end is not available here ({exc})") from None
        return WarpBackend(model, n, **options)
    raise UnknownName(f"unknown batch back-end {name!r}; known: {list(BACKENDS)}")


class Frame:
    """A site, body or geom in every world: ``positions`` (N, 3) and ``rotations``
    (N, 3, 3) are the back-end's arrays (current after each kinematics update, read-only;
    ``position``, ``rotation``: the same arrays; the rotations are copied out of MuJoCo
    from their first read on); :meth:`jacobians` fills the (N, 3, nv) Jacobians of the
    frame's origin."""

    __slots__ = ("name", "type", "id", "body", "positions", "position", "_rotations", "_backend", "_scratch")

    def __init__(self, robots: Robot, name: str, frame_type: str = "site"):
        serial = robots.template.frame(name, frame_type)  # checks the type and the name
        self.name, self.type, self.id, self.body = name, frame_type, serial.id, serial.body
        self.positions, self._rotations = robots.backend.frame_pose(frame_type, self.id, rotation=False)
        self.position = self.positions
        self._backend = robots.backend
        self._scratch = None
        robots.kinematics_stale()

    @property
    def rotations(self) -> np.ndarray:
        if self._rotations is None:  # bound now, and filled at the current configuration
            self._rotations = self._backend.frame_pose(self.type, self.id)[1]
        return self._rotations

    rotation = rotations

    def jacobians(self, jacp: np.ndarray | None, jacr: np.ndarray | None = None) -> None:
        """Fill the (N, 3, nv) translational and/or rotational Jacobians."""
        if jacp is None:
            if self._scratch is None:
                self._scratch = np.empty((len(self.positions), 3, self._backend.model.nv))
            jacp = self._scratch
        self._backend.jacobian(self.body, self.positions, jacp, jacr, rotational=jacr is not None)

    def jacobians_filler(self, jacp: np.ndarray | None, jacr: np.ndarray | None = None):
        """A call with no arguments that does :meth:`jacobians` into these arrays."""
        return functools.partial(self.jacobians, jacp, jacr)

    def __repr__(self) -> str:
        return f"Frame({self.name!r}, {self.type!r}, id={self.id})"


class GeomDistances:
    """Signed distances of geom pairs (g1, g2) in every world, in MuJoCo's C
    (``mj_geomDistance``), world by world on the host.

    The back-end computes the pairs' geoms' poses in every world (``frame_pose``, kept
    current after each kinematics update); a call writes each world's poses of those
    geoms into one scratch ``MjData`` (all that ``mj_geomDistance`` reads of it) and
    measures every pair there. The same poses as a one-world kinematics pass
    (:meth:`Robot.world`) per world, at less cost, the more so the larger the model
    (measured on the CPU back-end, distances included: a sixth less on the Jaco, a third
    less on a humanoid).
    """

    def __init__(self, robots: Robot, pairs, cutoffs: np.ndarray, distances: np.ndarray, fromto: np.ndarray):
        self.pairs = [(int(g1), int(g2)) for g1, g2 in pairs]
        geoms = sorted({g for pair in self.pairs for g in pair})
        n = robots.n
        self._poses = [robots.backend.frame_pose("geom", g) for g in geoms]
        self._geoms = as_index(geoms)
        self._positions, self._rotations = np.empty((n, len(geoms), 3)), np.empty((n, len(geoms), 3, 3))
        self._model, self._data = robots.model, mujoco.MjData(robots.model)
        self._xpos, self._xmat = self._data.geom_xpos, self._data.geom_xmat.reshape(-1, 3, 3)
        # Per world: its poses, its pairs with their rows of fromto (views), its cutoffs
        # and distances (rows of the caller's arrays, read and written at each call).
        self._worlds = [(positions, rotations, [(g1, g2, points) for (g1, g2), points in zip(self.pairs, world_fromto)],
                         world_cutoffs, world_distances)
                        for positions, rotations, world_cutoffs, world_distances, world_fromto in
                        zip(self._positions, self._rotations, cutoffs, distances, fromto)]

    def __call__(self) -> None:
        for k, (positions, rotations) in enumerate(self._poses):
            self._positions[:, k], self._rotations[:, k] = positions, rotations
        model, data, xpos, xmat, geoms = self._model, self._data, self._xpos, self._xmat, self._geoms
        for positions, rotations, rows, limits, written in self._worlds:
            xpos[geoms], xmat[geoms] = positions, rotations
            measure_pairs(model, data, rows, limits, written)


class Robot:
    """N worlds of one model.

    Args:
        model: a compiled ``mujoco.MjModel`` or an ``mujoco.MjSpec``.
        n: the number of worlds N (>= 1).
        name: a label (default: the model's name).
        keyframe: the keyframe every world starts at (default: ``qpos0``).
        backend: ``"cpu"`` (``mujoco.batch`` and NumPy) or ``"warp"`` (MuJoCo Warp).
        allow_outside_limits: accept starts outside the joint ranges (as
            :class:`qpik.Robot`).
        options: for the back-end, e.g. ``nthread`` on the CPU.

    Raises:
        InvalidInput: N not a positive integer.
        ModelError, UnknownName, OutsideJointLimits: as :class:`qpik.Robot`.
    """

    batched = True  # a user reads the engine's arrays (N, ...) as they are (``present``)

    def __init__(self, model, n: int, name: str | None = None, keyframe: str | None = None, *,
                 backend: str = "cpu", allow_outside_limits: bool = False, **options):
        if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 1:
            raise InvalidInput(f"the number of worlds n must be an integer >= 1, got {n!r}")
        self.template = SerialRobot(model, name=name, keyframe=keyframe, allow_outside_limits=allow_outside_limits)
        self.model = self.template.model
        self.name = self.template.name
        self.n, self.nq, self.nv = int(n), self.model.nq, self.model.nv
        self.allow_outside_limits = bool(allow_outside_limits)
        self.backend = make_backend(backend, self.model, self.n, **options)
        self.backend.qpos[:] = self.template.q
        self._snapshot = None  # q at the last kinematics update (None: update needed)
        self._world = None  # the one-world robot of world()
        self._rotational = None  # scratch of point_jacobian_filler
        self._start_unchecked = keyframe is None
        self._equality_rows: dict[tuple[int, ...], _EqualityRows] = {}  # per set of equalities read

    @classmethod
    def load(cls, scene: str | Path | mujoco.MjModel | mujoco.MjSpec, n: int,
             keyframe: str | None = BUNDLED_HOME, **kwargs) -> Robot:
        """Load a bundled robot (``"arm"``, ``"hexapod"``), an MJCF/URDF path or a model,
        N worlds of it; ``keyframe`` as :meth:`qpik.Robot.load` (``"home"`` for a bundled
        robot by default)."""
        serial = SerialRobot.load(scene, keyframe=keyframe, allow_outside_limits=True)  # the model, its name
        if keyframe is BUNDLED_HOME:  # a bundled robot's serial.name is its name
            keyframe = "home" if isinstance(scene, (str, Path)) and serial.name == str(scene) else None
        return cls(serial.model, n, name=serial.name, keyframe=keyframe, **kwargs)

    # -- configuration -----------------------------------------------------------------
    q = qpos = property(lambda self: self.backend.qpos, doc="The worlds' configurations (N, nq): the back-end's "
                        "array (writing it moves the worlds; the next step updates their kinematics).")

    def set_q(self, q) -> None:
        """Set every world's configuration: an (N, nq) array, or one (nq,) for all.

        Raises:
            InvalidInput: a wrong shape.
            InvalidWorlds: NaN/inf in some worlds, or (unless ``allow_outside_limits``)
                joints outside their ranges; ``worlds`` lists them. Nothing is written.
        """
        values = as_floats(q, "configurations")
        if values.shape == (self.nq,):
            values = np.broadcast_to(values, (self.n, self.nq))
        if values.shape != (self.n, self.nq):
            raise InvalidInput(f"configurations must have shape ({self.n}, {self.nq}) or ({self.nq},), "
                               f"got {values.shape}")
        bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
        if len(bad):
            raise InvalidWorlds(f"the configurations of worlds {listed(bad)} contain NaN or inf", bad)
        self._check_inside(values, "set_q")
        self.backend.qpos[:] = values
        self._start_unchecked = False

    def _check_inside(self, values: np.ndarray, what: str) -> None:
        if self.allow_outside_limits:
            return
        limits = self.joint_limits
        excess = limits.excess(values)
        outside = np.flatnonzero((excess > KEYFRAME_TOLERANCE).any(axis=1))
        if len(outside):
            first = int(outside[0])
            joints = [limits.names[j] for j in np.flatnonzero(excess[first] > KEYFRAME_TOLERANCE)]
            raise InvalidWorlds(f"{what}: worlds {listed(outside)} lie outside the joint ranges (world {first}: "
                                f"{joints}); give configurations inside them, or allow_outside_limits=True", outside)

    def integrate(self, qdot, dt: float) -> None:
        """q ← q ⊕ q̇·dt in every world (``mj_integratePos``'s rule).

        Raises:
            InvalidInput: a wrong shape or a step that is not positive and finite.
            InvalidWorlds: non-finite velocities in some worlds (nothing is moved).
        """
        check_step(dt)
        velocity = np.asarray(qdot, dtype=float)
        if velocity.shape != (self.n, self.nv):
            raise InvalidInput(f"joint velocities must have shape ({self.n}, {self.nv}), got {velocity.shape}")
        if not math.isfinite(float(velocity.sum())):
            bad = np.flatnonzero(~np.isfinite(velocity).all(axis=1))
            raise InvalidWorlds(f"the joint velocities of worlds {listed(bad)} contain NaN or inf", bad)
        self.backend.integrate(velocity, float(dt))
        self._snapshot = None  # q moved: the next ensure_kinematics updates without comparing

    # -- kinematics --------------------------------------------------------------------
    def frame(self, name: str, frame_type: str = "site") -> Frame:
        """A site, body or geom in every world (see :class:`Frame`)."""
        return Frame(self, name, frame_type)

    def kinematics_stale(self) -> None:
        """Make the next :meth:`ensure_kinematics` update (a new array was bound)."""
        self._snapshot = None

    def update_kinematics(self) -> None:
        """Every world's kinematics at its current q (one back-end call).

        Raises:
            InvalidWorlds: configurations not finite or beyond ``MAX_CONFIGURATION`` (which
                MuJoCo's forward would reset to qpos0).
        """
        snapshot = self.backend.qpos.copy()  # checked here: one pass over contiguous memory
        check_configurations(self.model, snapshot, True)
        self.backend.forward()
        self._snapshot = snapshot

    def ensure_kinematics(self) -> None:
        """Update the kinematics if some world's q changed since the last update; the first
        call checks the start configurations against the joint ranges."""
        if self._start_unchecked:
            self._check_inside(self.backend.qpos, "the start configuration")
            self._start_unchecked = False
        if self._snapshot is None or not np.array_equal(self._snapshot, self.backend.qpos):
            self.update_kinematics()

    def world(self, index: int) -> SerialRobot:
        """World ``index`` as a one-world :class:`qpik.Robot` at its configuration, its
        kinematics updated: one robot of this batch's, shared by every call (a task
        evaluated world by world reads each world through it in turn)."""
        if self._world is None:
            self._world = SerialRobot(self.model, name=self.name, allow_outside_limits=True)
        self._world.data.qpos[:] = self.backend.qpos[index]
        self._world.update_kinematics()
        return self._world

    # -- the engine's interface (shared with qpik.Robot) ----------------------------------
    @staticmethod
    def present(array: np.ndarray) -> np.ndarray:
        """What a user reads of an engine array (N, ...): the array itself."""
        return array

    def subtree_com(self, body: int) -> np.ndarray:
        """(N, 3) centre of mass of ``body``'s subtree (the back-end's array)."""
        return self.backend.subtree_com(body)

    def com_jacobian(self, body: int, out: np.ndarray) -> np.ndarray:
        """(N, 3, nv) Jacobian of :meth:`subtree_com` into ``out``."""
        return self.backend.subtree_com_jacobian(body, out)

    def point_jacobian_filler(self, body: int, points: np.ndarray, out: np.ndarray):
        """A call with no arguments that writes the (N, 3, nv) translational Jacobians
        (``mj_jac``'s, formed by the back-end) of the world points ``points`` (N, 3) as
        they are then, each fixed to ``body``, into ``out``."""
        if self._rotational is None:
            self._rotational = np.empty((self.n, 3, self.nv))
        return functools.partial(self.backend.jacobian, body, points, out, self._rotational)

    def distance_filler(self, pairs, cutoffs: np.ndarray, distances: np.ndarray,
                        fromto: np.ndarray) -> GeomDistances:
        """A call with no arguments that writes each world's signed distances of the geom
        pairs into ``distances`` (N, P) and their closest points into ``fromto`` (N, P, 6),
        searching up to ``cutoffs`` (N, P): see :class:`GeomDistances`."""
        filler = GeomDistances(self, pairs, cutoffs, distances, fromto)
        self.kinematics_stale()  # the back-end computes the geoms' poses from now on
        return filler

    def equality_rows(self, ids) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`qpik.Robot.equality_rows` in every world: residual (N, m), Jacobian (N, m, nv).

        Each equality's rows come from the back-end, batched, where it writes that type
        (the CPU back-end: ``connect`` and ``joint``, from the anchors' Jacobians and the
        joints' positions; MuJoCo Warp: every type, from its ``make_constraint``); the
        others (on the CPU: ``weld`` and ``tendon``) from MuJoCo's C, world by world, on
        :meth:`world` (``mj_makeConstraint``).

        Raises:
            ModelError: an id without rows (inactive, acting on no dof), or active
                equalities changed since the first call for these ids.
        """
        return cached_rows(self._equality_rows, ids, lambda key: _EqualityRows(self, key))

    def mass_matrix(self, out: np.ndarray) -> np.ndarray:
        """(N, nv, nv) joint-space inertia M(q) of every world into ``out``: the back-end's
        batched matrix where it has one (``backend.mass_matrix``), else MuJoCo's C world
        by world on :meth:`world` (``mj_crb``, ``mj_fullM``), as the CPU and Warp back-ends
        have none."""
        batched = getattr(self.backend, "mass_matrix", None)
        if batched is not None:
            return batched(out)
        for w in range(self.n):
            self.world(w).mass_matrix(out[w:w + 1])
        return out

    def __getattr__(self, name: str):
        # Names, ids and limits (joint_id, joint_dofs, body_id, joint_limits, ...): the template's.
        if name in _TEMPLATE_NAMES:
            return getattr(self.template, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def __repr__(self) -> str:
        return f"batch.Robot({self.name!r}, n={self.n}, nq={self.nq}, nv={self.nv}, backend={self.backend.name!r})"


class _EqualityRows:
    """:meth:`Robot.equality_rows` of one set of equalities: which rows the back-end writes
    and which MuJoCo's C writes world by world, and the (N, m), (N, m, nv) outputs."""

    def __init__(self, robots: Robot, ids: tuple[int, ...]):
        sizes = EqualityRows(robots.model, robots.world(0).data, ids).sizes  # ModelError for bad ids
        self.robots, self.backend = robots, robots.backend
        batched, serial, batched_rows, serial_rows, start = [], [], [], [], 0
        for eq, size in zip(ids, sizes):
            on_backend = self._batched(eq)
            (batched if on_backend else serial).append(eq)
            (batched_rows if on_backend else serial_rows).extend(range(start, start + size))
            start += size
        self.batched, self.serial = np.array(batched, dtype=np.int64), tuple(serial)
        self.batched_rows, self.serial_rows = as_index(batched_rows), as_index(serial_rows)
        self.residual = np.zeros((robots.n, start))
        self.jacobian = np.zeros((robots.n, start, robots.nv))
        # The back-end writes its rows in place where they are consecutive (no copy).
        rows = self.batched_rows
        self._in_place = (self.residual[:, rows], self.jacobian[:, rows]) if isinstance(rows, slice) else None

    def _batched(self, equality: int) -> bool:
        """Whether the back-end writes this equality's rows (it raises NotBatched if not)."""
        try:
            self.backend.equality_rows(np.array([equality], dtype=np.int64))
        except NotBatched:
            return False
        return True

    def __call__(self) -> tuple[np.ndarray, np.ndarray]:
        if len(self.batched) and self._in_place is not None:
            self.backend.equality_rows(self.batched, self._in_place)
        elif len(self.batched):  # rows not consecutive: the back-end's new arrays, scattered
            residual, jacobian = self.backend.equality_rows(self.batched)
            self.residual[:, self.batched_rows] = residual
            self.jacobian[:, self.batched_rows] = jacobian
        if self.serial:
            for w in range(self.robots.n):
                residual, jacobian = self.robots.world(w).equality_rows(self.serial)
                self.residual[w, self.serial_rows] = residual[0]
                self.jacobian[w, self.serial_rows] = jacobian[0]
        return self.residual, self.jacobian
