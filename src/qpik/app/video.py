"""Videos of rollouts: MuJoCo's offscreen renderer, several runs as coloured ghosts in one scene.

Each run of a comparison is drawn in its controller's colour, the colour of its curves in
the figures (:mod:`qpik.app.palette`), all in one scene and one camera, so
where they part is where the controllers differ. The desired path is drawn as a grey
tube and the current target as a small dark sphere (user geoms of the ``MjvScene``). A
legend and the time are printed on each frame.

Headless machines render through EGL (GPU or Mesa) or OSMesa: MuJoCo picks the back-end
from ``MUJOCO_GL`` when it is first imported; :func:`prefer_headless_gl` sets
``MUJOCO_GL=egl`` when no display is available and MuJoCo is not imported yet. ``.mp4``
(and other ffmpeg containers) are written with imageio-ffmpeg (``pip install -e
".[video]"`` from a clone), ``.gif`` (looping, for a README) with Pillow.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..errors import InvalidInput, QpikError
from ..extras import require
from .palette import controller_colour, lighten

FFMPEG_SUFFIXES = (".mp4", ".mkv", ".webm", ".avi", ".mov")
SUFFIXES = FFMPEG_SUFFIXES + (".gif",)


class VideoUnavailable(QpikError, RuntimeError):
    """No OpenGL back-end to render with, or no encoder for the requested format."""


def prefer_headless_gl() -> None:
    """Use EGL when there is no display, if MuJoCo has not chosen its GL back-end yet."""
    if "mujoco" in sys.modules or os.environ.get("MUJOCO_GL"):
        return
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        os.environ["MUJOCO_GL"] = "egl"


def check_video_path(path: str | Path) -> Path:
    """Refuse a video path qpik cannot write, before any work."""
    path = Path(path)
    if path.suffix.lower() not in SUFFIXES:
        raise InvalidInput(f"--video {path}: unknown video format {path.suffix!r}; use one of {', '.join(SUFFIXES)}")
    if path.is_dir():
        raise InvalidInput(f"--video {path}: is a folder, expected a file name")
    if path.suffix.lower() in FFMPEG_SUFFIXES:
        _ffmpeg()
    require("PIL", "--video (its captions)")
    return path


def _ffmpeg():
    try:
        import imageio_ffmpeg
    except ImportError:
        raise VideoUnavailable("writing .mp4 needs imageio-ffmpeg: pip install -e \".[video]\" from qpik's "
                               "clone (or write a .gif)") from None
    return imageio_ffmpeg


def _rgb(hex_colour: str) -> tuple[float, float, float]:
    return tuple(int(hex_colour[i:i + 2], 16) / 255 for i in (1, 3, 5))


def _renderer(model, width: int, height: int):
    import warnings

    import mujoco

    width = min(width, int(model.vis.global_.offwidth))
    height = min(height, int(model.vis.global_.offheight))
    try:
        with warnings.catch_warnings():  # glfw warns on stderr before failing without a display
            warnings.simplefilter("ignore")
            return mujoco.Renderer(model, height=height, width=width)
    except Exception as exc:  # ImportError, RuntimeError, mujoco.FatalError: no usable GL
        reason = " ".join(str(exc).split()) or type(exc).__name__
        backend = os.environ.get("MUJOCO_GL", "default (glfw)")
        raise VideoUnavailable(f"cannot render: no OpenGL back-end (MUJOCO_GL={backend}: {reason}); "
                               "on a machine without a display set MUJOCO_GL=egl or MUJOCO_GL=osmesa") from None


def probe_gl() -> None:
    """Raise :class:`VideoUnavailable` now if no OpenGL context can be made (a 16-pixel
    renderer on an empty model), instead of after a whole rollout."""
    import mujoco

    _renderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 16, 16).close()


class GhostScene:
    """Renders several configurations of one model as coloured ghosts, with a path.

    Args:
        model: the MjModel all runs share.
        colours: one ``#rrggbb`` colour per run.
        path: desired points (N, 2 or 3) to draw as a tube (2-D points lie at z = 0).
        width, height: frame size in pixels (capped at the model's offscreen buffer).
    """

    def __init__(self, model, colours: Sequence[str], path: np.ndarray | None = None,
                 width: int = 640, height: int = 480):
        import mujoco

        self._mj = mujoco
        self.model = model
        self.renderer = _renderer(model, width, height)
        # Shadows triple the cost of a frame under software GL (Mesa llvmpipe) and add nothing here.
        self.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
        self.datas = [mujoco.MjData(model) for _ in colours]
        self.colours = [_rgb(c) for c in colours]
        self.option = mujoco.MjvOption()
        self.perturb = mujoco.MjvPerturb()
        self.camera = mujoco.MjvCamera()
        mujoco.mjv_defaultFreeCamera(model, self.camera)
        self.path = None if path is None else _to_3d(path)
        self._radius = 0.004
        self.ghost_alpha = 0.75

    def frame_camera(self, configurations: Sequence[np.ndarray], planar: bool) -> None:
        """Aim the camera at everything that moves over the run (and the path)."""
        mj = self._mj
        data = self.datas[0]
        points = []
        for q in configurations:
            data.qpos[:] = q
            mj.mj_kinematics(self.model, data)
            points.append(data.xpos[1:].copy())
        pts = np.concatenate(points + ([self.path] if self.path is not None else []))
        low, high = pts.min(axis=0), pts.max(axis=0)
        extent = float(np.max(high - low))
        self.camera.lookat[:] = (low + high) / 2
        fovy = np.radians(self.model.vis.global_.fovy)
        self.camera.distance = 0.8 * extent / np.tan(fovy / 2)
        self.camera.elevation = -70.0 if planar else -25.0
        self.camera.azimuth = 90.0 if planar else 120.0
        self._radius = 0.004 * max(extent, 0.05) / 0.3

    def render(self, configurations: Sequence[np.ndarray], target: np.ndarray | None = None) -> np.ndarray:
        """One frame (H, W, 3) uint8: run i at ``configurations[i]``."""
        mj = self._mj
        scene = self.renderer.scene
        for data, q in zip(self.datas, configurations):
            data.qpos[:] = q
            mj.mj_kinematics(self.model, data)
            mj.mj_camlight(self.model, data)
        self.renderer.update_scene(self.datas[0], camera=self.camera, scene_option=self.option)
        dynamic = int(mj.mjtCatBit.mjCAT_DYNAMIC)
        self._tint(0, scene.ngeom, self.colours[0], alpha=1.0)
        for data, colour in zip(self.datas[1:], self.colours[1:]):
            start = scene.ngeom
            mj.mjv_addGeoms(self.model, data, self.option, self.perturb, dynamic, scene)
            self._tint(start, scene.ngeom, colour, alpha=self.ghost_alpha)
        if self.path is not None:
            self._draw_path(scene)
        if target is not None:
            self._add_geom(scene, mj.mjtGeom.mjGEOM_SPHERE, [2.2 * self._radius] * 3, _to_3d(target)[0],
                           (0.1, 0.1, 0.1, 1.0))
        return self.renderer.render()

    def _tint(self, start: int, stop: int, colour, alpha: float) -> None:
        """Paint the moving geoms in [start, stop) in a run's colour (static ones keep theirs)."""
        dynamic = int(self._mj.mjtCatBit.mjCAT_DYNAMIC)
        for i in range(start, stop):
            geom = self.renderer.scene.geoms[i]
            if int(geom.category) != dynamic:
                continue
            # Keep some of the model's shading (darker parts stay darker), in the run's hue.
            shade = 0.55 + 0.45 * float(np.mean(geom.rgba[:3]))
            geom.rgba[:3] = np.asarray(colour) * shade
            geom.rgba[3] = alpha * geom.rgba[3]

    def _draw_path(self, scene) -> None:
        mj = self._mj
        pts = self.path
        step = max(1, len(pts) // 80)
        pts = pts[::step]
        for a, b in zip(pts[:-1], pts[1:]):
            if scene.ngeom >= scene.maxgeom:
                return
            if np.linalg.norm(b - a) < 1e-9:
                continue
            geom = scene.geoms[scene.ngeom]
            mj.mjv_initGeom(geom, mj.mjtGeom.mjGEOM_CAPSULE, np.zeros(3), np.zeros(3), np.eye(3).ravel(),
                            np.array([0.5, 0.5, 0.5, 0.6], dtype=np.float32))
            mj.mjv_connector(geom, mj.mjtGeom.mjGEOM_CAPSULE, self._radius, a, b)
            scene.ngeom += 1

    def _add_geom(self, scene, kind, size, pos, rgba) -> None:
        if scene.ngeom >= scene.maxgeom:
            return
        self._mj.mjv_initGeom(scene.geoms[scene.ngeom], kind, np.asarray(size, dtype=float), np.asarray(pos, dtype=float),
                              np.eye(3).ravel(), np.asarray(rgba, dtype=np.float32))
        scene.ngeom += 1

    def close(self) -> None:
        self.renderer.close()


def _to_3d(points) -> np.ndarray:
    pts = np.atleast_2d(np.asarray(points, dtype=float))
    if pts.shape[1] == 3:
        return pts
    out = np.zeros((len(pts), 3))
    out[:, :min(3, pts.shape[1])] = pts[:, :3]
    return out


def _overlay(frame: np.ndarray, labels: Sequence[str], colours: Sequence[str], caption: str, time: float):
    require("PIL", "the video's captions")
    from PIL import Image, ImageDraw, ImageFont

    image = Image.fromarray(frame)
    draw = ImageDraw.Draw(image)
    size = max(12, frame.shape[0] // 32)
    font = ImageFont.load_default(size=size)
    pad = size // 2
    box_h = (len(labels) + 1) * (size + 4) + pad
    width = max(draw.textlength(text, font=font) for text in (*labels, caption)) + 3 * size
    draw.rectangle([0, 0, width + pad, box_h + pad], fill=(255, 255, 255))
    draw.text((pad, pad), caption, fill=(0, 0, 0), font=font)
    for i, (label, colour) in enumerate(zip(labels, colours)):
        y = pad + (i + 1) * (size + 4)
        draw.rectangle([pad, y + 2, pad + size - 2, y + size], fill=colour)
        draw.text((pad + size + 4, y), label, fill=(0, 0, 0), font=font)
    stamp = f"t = {time:.2f} s"
    tw = draw.textlength(stamp, font=font)
    draw.rectangle([frame.shape[1] - tw - 2 * pad, 0, frame.shape[1], size + 2 * pad], fill=(255, 255, 255))
    draw.text((frame.shape[1] - tw - pad, pad), stamp, fill=(0, 0, 0), font=font)
    return np.asarray(image)


def render_logs(model, logs: Sequence, path: str | Path, *, labels: Sequence[str], colours: Sequence[str],
                caption: str = "", fps: float = 25.0, width: int = 640, height: int = 480,
                progress: Callable[[int, int], None] | None = None) -> Path:
    """Render the logged configurations ``log.q`` of ``logs`` (same model) into a video.

    Frames are taken every 1/fps s of rollout time (real-time playback); a run that
    stopped early stays at its last configuration. The desired path is the first
    log's ``x_des``; ``planar`` camera (from above) when the path has no z.

    Args:
        model: the MjModel of every log.
        logs: :class:`~qpik.rollout.RolloutLog` objects (``t``, ``q``, ``x_des``).
        path: output file, ``.mp4`` (ffmpeg) or ``.gif``.
        labels, colours: legend text and ``#rrggbb`` colour of each log.
        caption: first legend line (e.g. robot / scenario).
        progress: called as ``progress(frame, frames)``.

    Raises:
        InvalidInput: unknown format. VideoUnavailable: no GL back-end or no encoder.
    """
    path = check_video_path(path)
    dt = logs[0].info.dt
    duration = max(float(log.t[-1]) for log in logs)
    stride = max(1, int(round(1.0 / (fps * dt))))
    steps = np.arange(0, int(round(duration / dt)) + 1, stride)
    fps = 1.0 / (stride * dt)
    desired = logs[0].x_des
    planar = desired.shape[1] < 3  # a task in the plane: look from above
    scene = GhostScene(model, colours, desired, width, height)
    try:
        sample = [log.q[np.minimum(steps, len(log.q) - 1)] for log in logs]
        scene.frame_camera([q for series in sample for q in series[:: max(1, len(steps) // 20)]], planar)
        frames = []
        for n, k in enumerate(steps):
            target = desired[min(k, len(desired) - 1)]
            image = scene.render([series[n] for series in sample], target)
            frames.append(_overlay(image, labels, colours, caption, k * dt))
            if progress is not None:
                progress(n + 1, len(steps))
    finally:
        scene.close()
    from ..rollout.io import atomic_path  # here: the rollout package imports MuJoCo (see prefer_headless_gl)

    with atomic_path(path) as partial:  # written whole or not at all
        _encode(frames, partial, fps, colours)
    return path


def _encode(frames: list[np.ndarray], path: Path, fps: float, colours: Sequence[str] = ()) -> None:
    if path.suffix.lower() == ".gif":
        require("PIL", "writing a .gif")
        from PIL import Image

        # One palette for the whole clip (no flicker): a grey ramp for the floor, shades of
        # every run's colour (their ghosts cover few pixels: a median cut alone merges their
        # hues), the rest from a median cut of a montage of frames.
        sample = np.concatenate(frames[:: max(1, len(frames) // 8)], axis=0)
        greys = np.repeat(np.linspace(0, 255, 64)[:, None], 3, axis=1)
        shades = [np.outer(np.linspace(0.35, 1.0, 16), np.array(_rgb(c)) * 255) for c in (colours or ())]
        fixed = np.concatenate([greys, *shades]).round().astype(np.uint8)
        rest = 256 - len(fixed)
        cut = Image.fromarray(sample).quantize(colors=rest, method=Image.Quantize.MEDIANCUT).getpalette()[: 3 * rest]
        palette = Image.new("P", (1, 1))
        palette.putpalette(list(fixed.ravel()) + cut)
        images = [Image.fromarray(f).quantize(palette=palette, dither=Image.Dither.NONE) for f in frames]
        images[0].save(path, format="GIF", save_all=True, append_images=images[1:], loop=0,
                       duration=int(round(1000 / fps)), optimize=True)
        return
    ffmpeg = _ffmpeg()
    height, width = frames[0].shape[:2]
    fmt = {".mp4": "mp4", ".mkv": "matroska", ".webm": "webm", ".avi": "avi", ".mov": "mov"}[path.suffix.lower()]
    writer = ffmpeg.write_frames(str(path), (width, height), fps=fps, codec="libvpx-vp9" if fmt == "webm" else "libx264",
                                 macro_block_size=2, quality=7, output_params=["-f", fmt])
    writer.send(None)
    try:
        for frame in frames:
            writer.send(np.ascontiguousarray(frame))
    finally:
        writer.close()


def coincident_groups(logs: Sequence, tol: float = 1e-3) -> list[list[int]]:
    """Indices of runs grouped by motion: runs whose configurations stay within ``tol``
    (rad or m) of a group's first run over the whole rollout share one ghost."""
    groups: list[list[int]] = []
    for i, log in enumerate(logs):
        for group in groups:
            first = logs[group[0]]
            if first.q.shape == log.q.shape and np.max(np.abs(first.q - log.q)) <= tol:
                group.append(i)
                break
        else:
            groups.append([i])
    return groups


def render_comparison(model, logs: Sequence, path: str | Path, *, caption: str = "", fps: float = 25.0,
                      width: int = 640, height: int = 480, progress: Callable[[int, int], None] | None = None) -> Path:
    """:func:`render_logs` for a comparison: runs that move alike (within 1 mm / 1 mrad over the
    whole rollout) are one ghost with a joint label; each ghost has its first run's
    controller colour (as in the figures), lighter for a second ghost of that controller
    (another solver that moved differently)."""
    from .runs import run_label

    groups = coincident_groups(logs)
    labels, colours = [], []
    for group in groups:
        names = [run_label(logs[i].info.controller, logs[i].info.solver) for i in group]
        stopped = [i for i in group if not getattr(logs[i], "completed", True)]
        text = " = ".join(names) if len(names) <= 3 else f"{' = '.join(names[:2])} = {len(names) - 2} more"
        labels.append(text + (f" (stopped at t = {logs[group[0]].t[-1]:.2f} s)" if stopped else ""))
        controller = logs[group[0]].info.controller
        earlier = sum(logs[g[0]].info.controller == controller for g in groups[:len(colours)])
        colours.append(lighten(controller_colour(controller), min(0.6, 0.3 * earlier)))
    return render_logs(model, [logs[g[0]] for g in groups], path, labels=labels, colours=colours, caption=caption,
                       fps=fps, width=width, height=height, progress=progress)
