"""The ``qpik`` command where an extra is not installed: ``--plot`` without matplotlib,
``--video`` without imageio-ffmpeg or Pillow, ``qpik calibrate --plot`` without matplotlib.
Each is one line naming the extra to install and exit code 2, before the run starts: no
table printed, no output folder. (``--plot`` used to fail only after the whole run.)
SciPy is a dependency of qpik (as are mujoco, numpy and daqp), not an extra: an
environment without it is a broken install, like one without numpy, and names no extra."""

from __future__ import annotations


import pytest

CASES = [
    (("matplotlib",), ["run", "arm", "--scenario", "seed-redundant", "--plot"], '".[plots]"'),
    (("matplotlib",), ["compare", "arm", "--scenario", "seed-redundant", "--plot"], '".[plots]"'),
    (("imageio_ffmpeg",), ["run", "arm", "--scenario", "seed-redundant", "--video", "{out}/run.mp4"], '".[video]"'),
    (("PIL",), ["run", "arm", "--scenario", "seed-redundant", "--video", "{out}/run.gif"], '".[video]"'),
    (("PIL",), ["compare", "arm", "--scenario", "seed-redundant", "--video", "{out}/run.mp4"], '".[video]"'),
    (("matplotlib",), ["calibrate", "--plot"], '".[plots]"'),
]


@pytest.mark.parametrize("hidden, argv, extra", CASES, ids=lambda v: " ".join(v) if isinstance(v, (list, tuple)) else v)
def test_a_missing_extra_is_one_line_before_any_work(tmp_path, hidden, argv, extra, run_without_modules):
    out = tmp_path / "out"
    argv = [a.format(out=tmp_path) for a in argv] + ["--out", str(out), "--quiet"]
    done = run_without_modules(f"from qpik.app.cli import main\nsys.exit(main({list(argv)!r}))", hidden, timeout=300)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("qpik: error:") and extra in lines[0], done.stderr
    assert done.stdout == ""  # no table: the run never started
    assert not out.exists() and list(tmp_path.iterdir()) == []
