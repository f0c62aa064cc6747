"""The bundled scenes: the top-level ``scenes/`` folder, installed as the package ``qpik.scenes``,
found through the package (editable install) and carried by the wheel."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tomllib
import zipfile
from importlib.resources import files
from pathlib import Path

import mujoco
from setuptools import find_packages

from qpik.robot import Robot
from qpik.robots import BUNDLED
from qpik.scenes import SCENES, SCENES_DIR

ROOT = Path(__file__).resolve().parents[2]
SCENE_FILES = ("arm.xml", "arm.urdf", "hexapod.xml")


def test_bundled_scenes_are_the_top_level_folder_through_the_package():
    """The package is a checkout's top-level scenes/ folder (this one's, or, where qpik
    is imported from another checkout's editable install, that one's), holding this
    checkout's files."""
    scenes = files("qpik.scenes")
    for name in SCENE_FILES:
        assert scenes.joinpath(name).is_file(), name
        assert (ROOT / "scenes" / name).read_text() == scenes.joinpath(name).read_text()
    assert {robot: path for robot, (path, _) in BUNDLED.items()} == SCENES  # the robots' registry, the core's names
    checkout = SCENES_DIR.parent
    assert SCENES_DIR == checkout / "scenes" == Path(str(scenes)).resolve()
    assert (checkout / "pyproject.toml").is_file() and (checkout / "src" / "qpik").is_dir()
    for robot, path in SCENES.items():
        assert path == SCENES_DIR / f"{robot}.xml"
        model = mujoco.MjModel.from_xml_path(str(path))
        assert Robot.load(robot).model.nq == model.nq


def test_pyproject_lists_every_package_under_src():
    """packages are listed (qpik.scenes lies outside src/, which packages.find cannot map):
    a subpackage added under src/ and not listed would be missing from the wheel."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(config["packages"])
    assert listed == set(find_packages(str(ROOT / "src"))) | {"qpik.scenes"}
    assert config["package-dir"]["qpik.scenes"] == "scenes"


LOAD_FROM_WHEEL = """
import sys, qpik
from pathlib import Path
from qpik.scenes import SCENES, SCENES_DIR
assert Path(qpik.__file__).is_relative_to(sys.argv[1]), qpik.__file__
for name in ("arm", "hexapod"):
    robot = qpik.Robot.load(name)
    print(name, robot.model.nq, SCENES[name].relative_to(sys.argv[1]))
"""


# What a wheel is built from; a copy of them builds it (a build/ folder left in the
# repository by an earlier build would carry its stale modules into the wheel).
WHEEL_SOURCES = ("pyproject.toml", "README.md", "src", "scenes")


def test_the_wheel_carries_the_scenes(tmp_path):
    """`pip wheel .`, installed (without dependencies, which this environment has) into a
    folder outside the repository: both bundled robots load from it, and it carries
    nothing of the lab."""
    source, wheels = tmp_path / "source", tmp_path / "wheels"
    source.mkdir()
    for name in WHEEL_SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, source / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        else:
            shutil.copy(ROOT / name, source / name)
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", str(source), "--no-deps", "-q", "-w", str(wheels)],
                           capture_output=True, text=True)
    assert build.returncode == 0, build.stderr[-2000:]
    (wheel,) = wheels.glob("qpik-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert {f"qpik/scenes/{name}" for name in SCENE_FILES} <= set(names)
    # The library and the tool a user runs, nothing of the lab (benchmarks/, tools/).
    lab = [n for n in names if n.startswith(("qpik/fuzz/", "benchmarks/", "tools/"))
           or n.rsplit("/", 1)[-1] in ("readme_tables.py", "scenarios_table.py", "mink_mirror.py", "equivalence.py")]
    assert not lab, lab
    target = tmp_path / "site"
    install = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(target),
                              str(wheel)], capture_output=True, text=True)
    assert install.returncode == 0, install.stderr[-2000:]
    env = {**os.environ, "PYTHONPATH": str(target)}
    loaded = subprocess.run([sys.executable, "-c", LOAD_FROM_WHEEL, str(target)], capture_output=True,
                            text=True, env=env, cwd=tmp_path)
    assert loaded.returncode == 0, loaded.stderr[-2000:]
    assert loaded.stdout.split() == ["arm", "4", "qpik/scenes/arm.xml",
                                     "hexapod", str(Robot.load("hexapod").model.nq), "qpik/scenes/hexapod.xml"]
