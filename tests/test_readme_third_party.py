"""The README's API example on a robot qpik did not ship with: dm_control's Kinova Jaco.

The example's code is taken from README.md as written and only its names are changed: the
scene (the Jaco's own MJCF plus a ``home`` keyframe inside its joint ranges, written with
MjSpec; its file stays in dm_control), the frame, the speed limits (the Jaco declares
none, so they are named per joint) and the target (the Jaco's wrist's own start, moved
0.1 m along +x as the arm's is). Each replacement must match the README exactly once, so
an edited example fails here rather than silently testing something else.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np

from qpik import Robot

ROOT = Path(__file__).resolve().parents[1]
API_EXAMPLE = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S)[0]
HOME = [0.0, 3.6, 2.0, -1.0, -1.5, 1.0]
SPEEDS = {"joint_1": 1.0, "joint_2": 1.0, "joint_3": 1.0, "joint_4": 1.5, "joint_5": 1.5, "joint_6": 1.5}


def jaco_scene(jaco_path: Path, out: Path) -> Path:
    """The Jaco's MJCF with a ``home`` keyframe (its meshes still read from dm_control)."""
    spec = mujoco.MjSpec.from_file(str(jaco_path))
    spec.meshdir = str(jaco_path.parent / spec.meshdir)
    spec.add_key(name="home", qpos=HOME)
    path = out / "jaco_home.xml"
    path.write_text(spec.to_xml())
    return path


def on_the_jaco(code: str, scene: Path, start: np.ndarray) -> str:
    x, y = (float(v) for v in start[:2])
    replacements = [
        ('Robot.load("arm")', f'Robot.load({str(scene)!r}, keyframe="home")'),
        ('"end_effector"', '"wristsite"'),
        ("JointVelocityLimit(robot)", f"JointVelocityLimit(robot, {SPEEDS!r})"),
        ("[0.5 + 0.1 * t, 2.0]", f"[{x!r} + 0.1 * t, {y!r}]"),
        ("asked for [0.6 2. ]", f"asked for {np.round([x + 0.1, y], 6)}"),
    ]
    for old, new in replacements:
        assert code.count(old) == 1, f"the README's API example no longer has {old!r} exactly once"
        code = code.replace(old, new)
    return code


def test_the_api_example_runs_on_the_jaco_with_its_names(jaco_path, tmp_path):
    scene = jaco_scene(jaco_path, tmp_path)
    robot = Robot.load(scene, keyframe="home")
    start = robot.frame_position(robot.frame("wristsite")).copy()
    code = on_the_jaco(API_EXAMPLE, scene, start)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert not done.stderr  # no warning either
    printed = re.fullmatch(r"end effector at \[(.*)\] m; asked for \[(.*)\]\n", done.stdout)
    assert printed, done.stdout
    reached, asked = (np.array(group.split(), dtype=float) for group in printed.groups())
    np.testing.assert_allclose(asked, np.round(start[:2] + [0.1, 0.0], 6))
    np.testing.assert_allclose(reached, asked, atol=2e-6)


def test_unchanged_the_example_says_what_the_jaco_lacks(jaco_path, tmp_path):
    """Only the scene swapped: the arm's frame name is not the Jaco's, and the error says so."""
    code = API_EXAMPLE.replace('Robot.load("arm")', f'Robot.load({str(jaco_scene(jaco_path, tmp_path))!r}, '
                                                    'keyframe="home")')
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert done.returncode != 0
    assert "UnknownName" in done.stderr and "end_effector" in done.stderr
    code = code.replace('"end_effector"', '"wristsite"')
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path)
    assert "ModelError" in done.stderr and "declares no joint speed limit" in done.stderr


def test_the_third_party_table_renders_the_recorded_benchmark():
    """tools.tables.third_party_table: one row per case of third_party.json, its medians
    and ratio as recorded (the renderer against the JSON itself; docs/results.md against
    the renderer is tests/test_results_page.py's check)."""
    import json

    from tools.tables import third_party_table

    results = ROOT / "benchmarks" / "results"
    data = json.loads((results / "third_party.json").read_text())
    lines = third_party_table(results).splitlines()
    assert len(lines) == 2 + len(data["cases"])
    for line, case in zip(lines[2:], data["cases"]):
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        rows = {row["label"]: row for row in case["timing"]["rows"]}
        assert cells[0] == case["title"]
        assert float(cells[1]) == round(rows["qpik"]["median_us"], 1)
        assert float(cells[2]) == round(rows["mink"]["median_us"], 1)
        assert cells[3].startswith(f"{case['timing']['ratio']['median']:.2f} (")
