"""Third-party MuJoCo models, located in the PyPI packages that ship them.

qpik never copies a foreign model into its repository: the files are read where their
package installed them. The ones used by the tests, the examples and the benchmarks:

============ ============== ==================================== ============================================
name         package        file in the package                  model
============ ============== ==================================== ============================================
jaco         dm_control     third_party/kinova/jaco_arm.xml      Kinova Jaco arm, 6 hinges, no gripper
humanoid     dm_control     suite/humanoid_CMU.xml               CMU humanoid, free joint + 56 hinges
pusher       gymnasium      envs/mujoco/assets/pusher.xml        7-DoF arm, a puck and a goal (4 slides)
ant          gymnasium      envs/mujoco/assets/ant.xml           quadruped, free joint + 8 hinges
gym_humanoid gymnasium      envs/mujoco/assets/humanoid.xml      gymnasium's humanoid, free joint + 17 hinges
============ ============== ==================================== ============================================

The ant's ankles and both humanoids' knees start at ``qpos0`` outside their ranges:
load them with ``allow_outside_limits=True``, or ``set_q`` a configuration inside
before the first step (see :class:`qpik.Robot`).

Both packages come with the ``models`` extra (``pip install -e ".[models]"`` from a
clone; the ``test`` extra includes them too).

    from qpik import Robot
    from qpik.models import third_party

    robot = Robot.load(third_party("jaco"))
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import NamedTuple

from .errors import ModelError, UnknownName
from .robot import name_hint

EXTRA = "models"


class ThirdPartyModel(NamedTuple):
    """Where a third-party model lives: the import name of its package, the pip name of
    that package, and the MJCF's path inside it."""

    package: str
    distribution: str
    path: str
    description: str


THIRD_PARTY: dict[str, ThirdPartyModel] = {
    "jaco": ThirdPartyModel("dm_control", "dm-control", "third_party/kinova/jaco_arm.xml",
                            "Kinova Jaco arm (dm_control): 6 hinges, joints 2 and 3 limited, one site"),
    "humanoid": ThirdPartyModel("dm_control", "dm-control", "suite/humanoid_CMU.xml",
                                "CMU humanoid (dm_control): a free joint and 56 limited hinges"),
    "pusher": ThirdPartyModel("gymnasium", "gymnasium", "envs/mujoco/assets/pusher.xml",
                              "7-DoF pusher arm (gymnasium), with a puck and a goal on slide joints"),
    "ant": ThirdPartyModel("gymnasium", "gymnasium", "envs/mujoco/assets/ant.xml",
                           "ant (gymnasium): a free torso and 8 hinges; the ankles start outside their ranges"),
    "gym_humanoid": ThirdPartyModel("gymnasium", "gymnasium", "envs/mujoco/assets/humanoid.xml",
                                    "humanoid (gymnasium): a free torso and 17 hinges; the knees start outside"),
}


def third_party_names() -> list[str]:
    """The names :func:`third_party` knows."""
    return list(THIRD_PARTY)


def third_party(name: str) -> Path:
    """The MJCF file of a third-party model in its installed package.

    Args:
        name: ``"jaco"``, ``"humanoid"``, ``"pusher"``, ``"ant"`` or ``"gym_humanoid"``
            (see :func:`third_party_names`).

    Returns:
        The path of the model's MJCF file (load it with :meth:`qpik.Robot.load`).

    Raises:
        UnknownName: no such model (the closest names are listed).
        ModelError: the package that ships the model is not installed (the message names
            the pip extra), or it lacks the file (another version's layout).
    """
    entry = THIRD_PARTY.get(name) if isinstance(name, str) else None
    if entry is None:
        raise UnknownName(f"no third-party model named {name!r}; {name_hint(str(name), list(THIRD_PARTY), 'model')}")
    spec = importlib.util.find_spec(entry.package)
    if spec is None or spec.origin is None:
        raise ModelError(f"the {name} model comes with the {entry.distribution} package, which is not installed: "
                         f"pip install -e \".[{EXTRA}]\" from qpik's clone (or pip install {entry.distribution})")
    path = Path(spec.origin).parent / entry.path
    if not path.is_file():
        raise ModelError(f"the installed {entry.distribution} has no {entry.path} (looked in {path.parent}); "
                         f"pip install -e \".[{EXTRA}]\" from qpik's clone installs a version that has it")
    return path


def pusher_arm():
    """The 7-DoF arm of gymnasium's pusher (PR2's right arm: shoulder pan, lift, upper-arm
    roll, elbow flex, forearm roll, wrist flex, wrist roll; the tip body ``tips_arm``), its
    puck and goal bodies (four slide joints) removed: a third-party 7-DoF arm alone.

    Returns:
        The compiled ``mujoco.MjModel``.

    Raises:
        ModelError: gymnasium is not installed (see :func:`third_party`).
    """
    import mujoco

    spec = mujoco.MjSpec.from_file(str(third_party("pusher")))
    for body in ("object", "goal"):
        spec.delete(spec.body(body))
    return spec.compile()
