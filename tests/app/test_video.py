"""Videos: headless offscreen rendering (EGL) of rollouts, ghosts told apart by colour.

MuJoCo chooses its GL back-end once, at import, so every rendering runs in a fresh
interpreter (with MUJOCO_GL=egl where there is no display, as the CLI does). Where no GL
back-end works the tests are skipped with the renderer's own reason.
"""

import json
import os
import re
import subprocess
import sys
from functools import lru_cache

import numpy as np
import pytest

from qpik.app.palette import CONTROLLER_COLOURS

PROBE = "from qpik.app.video import prefer_headless_gl, probe_gl\nprefer_headless_gl()\nprobe_gl()\n"


@lru_cache(maxsize=1)
def _gl_problem() -> str:
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True)
    return "" if done.returncode == 0 else (done.stderr.strip().splitlines() or ["no GL"])[-1]


def _needs_gl():
    if _gl_problem():
        pytest.skip(f"no OpenGL back-end here: {_gl_problem()}")


def _hue_mask(frame: np.ndarray, colour: str, tolerance: float = 0.04) -> np.ndarray:
    """Pixels of the hue of ``colour`` (saturated ones: not the grey floor, path or background)."""
    from matplotlib.colors import rgb_to_hsv, to_rgb

    hsv = rgb_to_hsv(frame.astype(float) / 255)
    hue = rgb_to_hsv(np.array(to_rgb(colour)))[0]
    distance = np.abs((hsv[..., 0] - hue + 0.5) % 1.0 - 0.5)
    return (distance < tolerance) & (hsv[..., 1] > 0.35) & (hsv[..., 2] > 0.15)


FRAMES = """
import json, sys
import numpy as np
from qpik.app.video import prefer_headless_gl
prefer_headless_gl()
from qpik.app.runs import run
from qpik.app.palette import CONTROLLER_COLOURS
from qpik.app.video import GhostScene
logs = [run("arm", "joint-limits", c, "daqp")[1] for c in ("qp", "pinv")]
from qpik.robot import load_model
scene = GhostScene(load_model("arm"), [CONTROLLER_COLOURS["qp"], CONTROLLER_COLOURS["pinv"]], logs[0].x_des)
scene.frame_camera([logs[0].q[0], logs[0].q[-1], logs[1].q[-1]], planar=True)
out = []
for k in (0, 1250, 2500):
    out.append(scene.render([logs[0].q[k], logs[1].q[k]], logs[0].x_des[k]))
scene.close()
np.save(sys.argv[1], np.array(out))
"""


def test_headless_frames_are_not_blank_and_show_both_runs(tmp_path):
    _needs_gl()
    path = tmp_path / "frames.npy"
    done = subprocess.run([sys.executable, "-c", FRAMES, str(path)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    frames = np.load(path)
    qp_colour, pinv_colour = CONTROLLER_COLOURS["qp"], CONTROLLER_COLOURS["pinv"]
    assert frames.shape == (3, 480, 640, 3) and frames.dtype == np.uint8
    for frame in frames:
        assert frame.std() > 20  # not one flat colour
    # At t = 0 both arms are at q0: the second (pinv) is drawn over the first.
    assert _hue_mask(frames[0], pinv_colour).sum() > 300
    for frame in frames[1:]:
        assert _hue_mask(frame, qp_colour).sum() > 300 and _hue_mask(frame, pinv_colour).sum() > 300
    # At the end the pseudoinverse law's arm is 0.6 rad past the limits the QP keeps: its
    # pixels are elsewhere.
    end = frames[-1]
    qp_pixels, pinv_pixels = (np.argwhere(_hue_mask(end, c)).mean(axis=0) for c in (qp_colour, pinv_colour))
    assert np.linalg.norm(qp_pixels - pinv_pixels) > 20


def _decode(ffmpeg: str, video) -> tuple[tuple[int, int], float, list[np.ndarray]]:
    """The video's size, frame rate and RGB frames, decoded by ffmpeg in one run whose pipes
    subprocess.run closes (imageio-ffmpeg's read_frames leaves them open when ffmpeg has
    already exited)."""
    done = subprocess.run([ffmpeg, "-nostdin", "-i", str(video), "-f", "rawvideo", "-pix_fmt", "rgb24", "-"],
                          capture_output=True)
    assert done.returncode == 0, done.stderr.decode(errors="replace")[-2000:]
    header = done.stderr.decode(errors="replace").split("Output #0")[0]
    found = re.search(r"Video: .*?, (\d+)x(\d+)[ ,].*?([\d.]+) fps", header)
    assert found, header
    width, height, fps = int(found[1]), int(found[2]), float(found[3])
    frames = np.frombuffer(done.stdout, np.uint8).reshape(-1, height, width, 3)
    return (width, height), fps, list(frames)


def test_compare_video_is_playable_and_tells_qp_from_pinv(tmp_path):
    _needs_gl()
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg", reason="the [video] extra (imageio-ffmpeg) is not installed")
    video = tmp_path / "X.mp4"
    env = {k: v for k, v in os.environ.items() if k != "MUJOCO_GL"}
    done = subprocess.run([sys.executable, "-m", "qpik", "compare", "arm", "--scenario", "joint-limits",
                           "--solvers", "daqp", "--out", str(tmp_path / "out"), "--video", str(video)],
                          capture_output=True, text=True, env={**env, "MPLBACKEND": "Agg"})
    assert done.returncode == 0, done.stderr
    assert str(video) in done.stdout and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    (width, height), fps, frames = _decode(imageio_ffmpeg.get_ffmpeg_exe(), video)
    assert (width, height) == (640, 480) and abs(fps - 25) < 1e-6
    assert len(frames) == 126  # 5 s at 25 frames/s, t = 0 included
    # Runs that move alike share the first one's ghost, in its controller's colour (the
    # colour of its curves in the figures): qp blue, pinv red.
    last = frames[-1][height // 4:]  # below the legend
    qp_pixels, pinv_pixels = (_hue_mask(last, CONTROLLER_COLOURS[kind]) for kind in ("qp", "pinv"))
    assert qp_pixels.sum() > 300 and pinv_pixels.sum() > 300
    assert np.linalg.norm(np.argwhere(qp_pixels).mean(axis=0) - np.argwhere(pinv_pixels).mean(axis=0)) > 20


def test_no_gl_back_end_is_one_clear_line(tmp_path):
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        pytest.skip("a display is available: GLFW would work")
    env = {**os.environ, "MUJOCO_GL": "glfw", "MPLBACKEND": "Agg"}
    done = subprocess.run([sys.executable, "-m", "qpik", "run", "arm", "--scenario", "seed-primary", "--out",
                           str(tmp_path / "o"), "--video", str(tmp_path / "v.mp4")], capture_output=True, text=True, env=env)
    assert done.returncode == 2
    assert len(done.stderr.strip().splitlines()) == 1 and "no OpenGL back-end" in done.stderr, done.stderr
    assert list(tmp_path.iterdir()) == []


def test_importing_the_video_module_leaves_mujoco_unimported():
    """prefer_headless_gl can choose EGL only before MuJoCo is imported, and the command
    imports the video module first for --video: that import must not bring MuJoCo in (a
    module-level import of the rollout package once did, and the GL tests only skipped)."""
    done = subprocess.run([sys.executable, "-c", "import sys, qpik.app.video; assert 'mujoco' not in sys.modules"],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
