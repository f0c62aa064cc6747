"""The ``qpik`` command where an extra is not installed: ``--plot`` without matplotlib,
``--video`` without imageio-ffmpeg or Pillow, ``qpik calibrate`` without SciPy. Each is
one line naming the extra to install and exit code 2, before the run starts: no table
printed, no output folder. (``--plot`` used to fail only after the whole run.)"""

from __future__ import annotations

import subprocess
import sys

import pytest

HIDE = """\
import importlib.machinery, sys
HIDDEN = {hidden!r}
class Hide(importlib.machinery.PathFinder):
    @classmethod
    def find_spec(cls, name, path=None, target=None):
        return None if name.split(".")[0] in HIDDEN else super().find_spec(name, path, target)
sys.meta_path[:] = [Hide if finder is importlib.machinery.PathFinder else finder for finder in sys.meta_path]
from qpik.app.cli import main
sys.exit(main({argv!r}))
"""


def _qpik_without(hidden: tuple[str, ...], *argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", HIDE.format(hidden=hidden, argv=list(argv))],
                          capture_output=True, text=True, timeout=300)


CASES = [
    (("matplotlib",), ["run", "arm", "--scenario", "seed-redundant", "--plot"], '".[plots]"'),
    (("matplotlib",), ["compare", "arm", "--scenario", "seed-redundant", "--plot"], '".[plots]"'),
    (("imageio_ffmpeg",), ["run", "arm", "--scenario", "seed-redundant", "--video", "{out}/run.mp4"], '".[video]"'),
    (("PIL",), ["run", "arm", "--scenario", "seed-redundant", "--video", "{out}/run.gif"], '".[video]"'),
    (("PIL",), ["compare", "arm", "--scenario", "seed-redundant", "--video", "{out}/run.mp4"], '".[video]"'),
    (("scipy", "qpsolvers", "osqp"), ["calibrate"], '".[calibration]"'),
    (("matplotlib",), ["calibrate", "--plot"], '".[plots]"'),
]


@pytest.mark.parametrize("hidden, argv, extra", CASES, ids=lambda v: " ".join(v) if isinstance(v, (list, tuple)) else v)
def test_a_missing_extra_is_one_line_before_any_work(tmp_path, hidden, argv, extra):
    out = tmp_path / "out"
    argv = [a.format(out=tmp_path) for a in argv] + ["--out", str(out), "--quiet"]
    done = _qpik_without(hidden, *argv)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("qpik: error:") and extra in lines[0], done.stderr
    assert done.stdout == ""  # no table: the run never started
    assert not out.exists() and list(tmp_path.iterdir()) == []
