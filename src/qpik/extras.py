"""Optional dependencies: what ``import qpik`` does not need, and the extra that brings each.

``import qpik`` and a QP step need mujoco, numpy, daqp and SciPy only. The rest is
imported where it is used, through :func:`require`, which names the extra to install
from a clone (qpik is not on a package index): ``pip install -e ".[plots]"``.
"""

from __future__ import annotations

import importlib
import importlib.util

from .errors import MissingExtra

# module -> (pip distribution, the extra that brings it)
EXTRAS = {
    "matplotlib": ("matplotlib", "plots"),
    "PIL": ("pillow", "video"),
    "imageio_ffmpeg": ("imageio-ffmpeg", "video"),
    "tqdm": ("tqdm", "cli"),
    "threadpoolctl": ("threadpoolctl", "cli"),
    "qpsolvers": ("qpsolvers", "solvers"),
    "osqp": ("osqp", "solvers"),
    "proxsuite": ("proxsuite", "solvers"),
    "quadprog": ("quadprog", "solvers"),
    "mink": ("mink", "peers"),
    "placo": ("placo", "peers"),
    "dm_control": ("dm-control", "models"),
    "gymnasium": ("gymnasium", "models"),
    "warp": ("warp-lang", "gpu"),
    "mujoco_warp": ("mujoco-warp", "gpu"),
    "ray": ("ray", "ray"),  # qpik sweep --ray
}


def install_hint(module: str, extra: str | None = None) -> str:
    """The command that installs ``module``'s extra (or ``extra``) from qpik's clone."""
    distribution, default = EXTRAS[module]
    extra = extra or default
    return f'pip install -e ".[{extra}]" from qpik\'s clone (or pip install {distribution})'


def installed(module: str) -> bool:
    """Whether an optional module can be imported (without importing it)."""
    try:
        return importlib.util.find_spec(module) is not None
    except ImportError:  # an import hook that refuses it
        return False


def require(module: str, purpose: str, extra: str | None = None):
    """Import an optional module, or raise :class:`~qpik.errors.MissingExtra` naming its extra.

    Args:
        module: the import name (a key of :data:`EXTRAS`).
        purpose: what needs it, for the message (e.g. ``"--plot"``).
        extra: the extra to name, where it is not the module's usual one.
    """
    if not installed(module):
        raise MissingExtra(f"{purpose} needs {EXTRAS[module][0]}, which is not installed: "
                           f"{install_hint(module, extra)}")
    return importlib.import_module(module)
