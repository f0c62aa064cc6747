r"""The hexapod's MuJoCo scene, generated from :class:`~qpik.robots.hexapod.kinematics.HexapodGeometry`.

``scenes/hexapod.xml`` (the package ``qpik.scenes``) is the output of :func:`hexapod_mjcf` on the default geometry;
rewrite it with ``python -m qpik.robots.hexapod.scene`` after changing the geometry.

Model structure (names are API):

- ``slider1..6``: slide joints along s_i, range [0, 0.35] m, bodies ``slider1..6`` whose
  origin is the slider point S_i (the universal-joint centre).
- ``u1_a, u1_b, ..., u6_a, u6_b``: the universal joint of each leg, two hinges in body
  ``leg1..6`` at S_i: ``u<i>_a`` about the world z axis, then ``u<i>_b`` about the
  rotated y axis. The leg points along σ_i x at zero angles (σ_i = −leg_side_i, towards
  its platform point), so its direction is
  :math:`u = R_z(a) R_y(b) (σ, 0, 0) = σ(\cos a \cos b, \sin a \cos b, -\sin b)`.
  |a| < π/2 is exactly the leg-side rule and |b| < π/2 keeps the cross away from its
  own singularity (leg vertical); the hinge ranges are these open half-planes.
- site ``leg<i>_tip`` at the leg's end; body ``platform`` on a free joint ``platform``
  with sites ``platform_center`` (platform origin) and ``platform_point1..6`` (b_i).
- equalities ``loop1..6``: site connects ``leg<i>_tip`` ↔ ``platform_point<i>``
  (the spherical joints).
- servo per slider: position actuator ``act<i>`` (kp, tracks the commanded stroke) and
  velocity actuator ``vel<i>`` (kv, tracks the commanded stroke rate as feed-forward);
  keyframe ``home``.

qpos = [slider1, u1_a, u1_b, ..., slider6, u6_a, u6_b, platform x, y, z, qw, qx, qy, qz]
(nq = 25); qvel = the same 18 scalar dofs, then the platform's v (world) and ω (local)
(nv = 24).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from ...errors import ModelError
from ...scenes import SCENES_DIR
from .kinematics import N_LEGS, Hexapod, HexapodGeometry

SCENE_PATH = SCENES_DIR / "hexapod.xml"
SLIDER_VELOCITY_LIMIT = 0.5  # m/s, the slider drives' rated speed
# The passive joints' speeds, bounded so that no command drives the chain at a speed its
# linearised loop closures cannot follow: at 5 rad/s a 0.2 m leg's chord misses its arc
# by 1e-5 m per 2 ms step. 6x the largest hinge rate (0.8 rad/s) of the bundled scenarios.
HINGE_VELOCITY_LIMIT = 5.0  # rad/s
PLATFORM_VELOCITY_LIMIT = (1.0, 1.0, 1.0, 5.0, 5.0, 5.0)  # m/s (linear), rad/s (angular)
_LEG_RADIUS = 0.006


def _fmt(*values) -> str:
    """Shortest round-trip text of each number (so the model equals the geometry)."""
    return " ".join(repr(float(v) + 0.0) for v in np.ravel(values))


def universal_joint_angles(hexapod: Hexapod, q, position, R) -> np.ndarray:
    """Hinge angles (6, 2) = [a_i, b_i] that point each leg from S_i to P_i.

    Inverts u = σ(cos a cos b, sin a cos b, −sin b): b = asin(−σ u_z),
    a = atan2(σ u_y, σ u_x) (cos b > 0).
    """
    L = hexapod.legs(q, position, R)[0]
    u = L / np.linalg.norm(L, axis=1)[:, None]
    sigma = -hexapod.geometry.leg_side
    return np.stack([np.arctan2(sigma * u[:, 1], sigma * u[:, 0]),
                     np.arcsin(np.clip(-sigma * u[:, 2], -1.0, 1.0))], axis=1)


def assembly_qpos(hexapod: Hexapod, q: np.ndarray, position: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The full qpos (25,) of a closed assembly, in the scene's order: per leg (stroke,
    u_a, u_b), then the platform's free joint (position, quaternion w x y z)."""
    legs = np.column_stack([q, universal_joint_angles(hexapod, q, position, R)]).ravel()
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(R).ravel())
    return np.concatenate([legs, position, quat])


def hexapod_mjcf(geometry: HexapodGeometry | None = None) -> str:
    """MJCF text of the hexapod scene for a geometry (default: the source's, docs/hexapod.md)."""
    hexapod = Hexapod(geometry)
    g = hexapod.geometry
    home_q = hexapod.home_strokes
    home_qpos = assembly_qpos(hexapod, home_q, g.home_position, np.eye(3))
    stroke = _fmt(g.stroke_min, g.stroke_max)
    hinge = _fmt(-np.pi / 2, np.pi / 2)
    numerics, rails, legs, sites, loops, actuators = [], [], [], [], [], []
    for i in range(N_LEGS):
        n = i + 1
        sigma = -g.leg_side[i]
        tip = _fmt(sigma * g.leg_lengths[i], 0, 0)
        numerics.append(f'    <numeric name="qpik_velocity_limit_slider{n}" data="{_fmt(SLIDER_VELOCITY_LIMIT)}"/>')
        for hinge_name in (f"u{n}_a", f"u{n}_b"):
            numerics.append(f'    <numeric name="qpik_velocity_limit_{hinge_name}" data="{_fmt(HINGE_VELOCITY_LIMIT)}"/>')
        rail = g.slider_origins[i] + np.outer([g.stroke_min, g.stroke_max], g.slider_axes[i])
        rails.append(f'    <geom name="rail{n}" class="rail" fromto="{_fmt(np.round(rail, 12))}"/>')
        legs.append(f"""    <body name="slider{n}" pos="{_fmt(g.slider_origins[i])}">
      <joint name="slider{n}" class="slider" axis="{_fmt(g.slider_axes[i])}"/>
      <geom class="carriage"/>
      <body name="leg{n}">
        <joint name="u{n}_a" class="ujoint" axis="0 0 1"/>
        <joint name="u{n}_b" class="ujoint" axis="0 1 0"/>
        <geom class="leg" fromto="0 0 0 {tip}"/>
        <site name="leg{n}_tip" class="anchor" pos="{tip}"/>
      </body>
    </body>""")
        sites.append(f'      <site name="platform_point{n}" class="anchor" pos="{_fmt(g.platform_points[i])}"/>')
        loops.append(f'    <connect name="loop{n}" site1="leg{n}_tip" site2="platform_point{n}"/>')
        actuators.append(f'    <position name="act{n}" joint="slider{n}" class="drive"/>')
        actuators.append(f'    <velocity name="vel{n}" joint="slider{n}" class="drive_rate"/>')
    radius = np.max(np.linalg.norm(g.platform_points[:, :2], axis=1))
    nl = "\n"
    return f"""<!--
  6-PUS Gough-Stewart hexapod (docs/hexapod.md). GENERATED by qpik.robots.hexapod.scene.hexapod_mjcf from
  HexapodGeometry.default(): do not edit, run `python -m qpik.robots.hexapod.scene`.

  Slider i (body and joint slider<i>) runs along its axis from S0,i; its stroke is the
  slide joint's qpos, range [{stroke}] m. Universal joint u<i>_a (world z) then u<i>_b
  (rotated y), leg along -leg_side*x at zero angles; hinge ranges are radians. The
  spherical joints are the site connects loop<i> (leg<i>_tip to platform_point<i>).
  Slider velocity limit {_fmt(SLIDER_VELOCITY_LIMIT)} m/s (qpik_velocity_limit_slider<i>); hinges {_fmt(HINGE_VELOCITY_LIMIT)} rad/s,
  platform {_fmt(PLATFORM_VELOCITY_LIMIT[0])} m/s and {_fmt(PLATFORM_VELOCITY_LIMIT[3])} rad/s (qpik_velocity_limit_u<i>_a/b, _platform).
  Home keyframe: platform at {_fmt(g.home_position)} m, identity rotation,
  strokes {_fmt(np.round(home_q, 6))} m (rounded here; exact in the keyframe).
  qpos = [slider1, u1_a, u1_b, ..., slider6, u6_a, u6_b, platform xyz, platform quat wxyz].

  Physics: platform 0.3 kg, legs 0.02 kg, carriages 0.05 kg; slider armature 0.5 kg (the
  drive's reflected inertia) lets the servos be stiff (kp 2e5 N/m on the stroke, kv 4e3 N s/m on
  the stroke rate, with the commanded rate as feed-forward so a moving slider does not lag) and stable
  at dt = 2 ms; loops at the stiffest stable soft setting (solref 2 dt, solimp 0.99-0.999).
  Under gravity the platform settles within about 0.5 mm / 0.3 deg of its kinematic pose
  near home; near low-manipulability poses (calibration pose 1) the error grows to about 1 cm.
-->
<mujoco model="hexapod_6pus">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="0.002" integrator="implicitfast" gravity="0 0 -9.81"/>

  <default>
    <geom contype="0" conaffinity="0"/>
    <default class="slider">
      <joint type="slide" range="{stroke}" armature="0.5" damping="2"/>
    </default>
    <default class="ujoint">
      <joint type="hinge" range="{hinge}" armature="1e-4" damping="0.002"/>
    </default>
    <equality solref="0.004 1" solimp="0.99 0.999 0.001"/>
    <default class="rail">
      <geom type="capsule" size="0.004" rgba="0.55 0.55 0.6 1"/>
    </default>
    <default class="carriage">
      <geom type="box" size="0.015 0.012 0.008" mass="0.05" rgba="0.2 0.2 0.25 1"/>
    </default>
    <default class="leg">
      <geom type="capsule" size="{_fmt(_LEG_RADIUS)}" mass="0.02" rgba="0.85 0.45 0.15 1"/>
    </default>
    <default class="anchor">
      <site size="0.008" rgba="0.9 0.1 0.1 1"/>
    </default>
    <default class="drive">
      <position kp="200000" ctrlrange="{stroke}"/>
    </default>
    <default class="drive_rate">
      <velocity kv="4000" ctrlrange="{_fmt(-2 * SLIDER_VELOCITY_LIMIT, 2 * SLIDER_VELOCITY_LIMIT)}"/>
    </default>
  </default>

  <visual>
    <global offwidth="1280" offheight="960"/>
  </visual>

  <custom>
{nl.join(numerics)}
    <numeric name="qpik_velocity_limit_platform" data="{_fmt(PLATFORM_VELOCITY_LIMIT)}"/>
  </custom>

  <asset>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.9 0.9 0.9" rgb2="0.8 0.8 0.8" width="256" height="256"/>
    <material name="grid" texture="grid" texrepeat="8 8"/>
  </asset>

  <worldbody>
    <light pos="0 0 2" dir="0 0 -1"/>
    <geom name="floor" type="plane" size="1 1 0.01" pos="0 0 -0.15" material="grid"/>
{nl.join(rails)}
{nl.join(legs)}
    <body name="platform" pos="{_fmt(g.home_position)}">
      <joint name="platform" type="free"/>
      <geom name="platform" type="cylinder" size="{_fmt(radius + 0.01, 0.005)}" mass="0.3" rgba="0.25 0.45 0.75 1"/>
      <site name="platform_center" size="0.01" rgba="0.1 0.8 0.1 1"/>
{nl.join(sites)}
    </body>
  </worldbody>

  <equality>
{nl.join(loops)}
  </equality>

  <actuator>
{nl.join(actuators)}
  </actuator>

  <keyframe>
    <key name="home" qpos="{_fmt(home_qpos)}" ctrl="{_fmt(np.column_stack([home_q, np.zeros(N_LEGS)]).ravel())}"/>
  </keyframe>
</mujoco>
"""


def write_scene(path: Path = SCENE_PATH, geometry: HexapodGeometry | None = None) -> Path:
    """Write :func:`hexapod_mjcf` to ``path`` (default: the bundled scene)."""
    path.write_text(hexapod_mjcf(geometry))
    return path


def _joint_qposadr(model: mujoco.MjModel, name: str) -> int:
    jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
    if jid < 0:
        raise ModelError(f"the model has no joint {name!r}: not the hexapod scene")
    return int(model.jnt_qposadr[jid])


def close_loops(model: mujoco.MjModel, data: mujoco.MjData, strokes, *, hexapod: Hexapod | None = None,
                initial: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Assemble the hexapod in ``data.qpos`` for six strokes; returns the platform pose.

    Solves FK (:meth:`Hexapod.forward_kinematics`, from ``initial`` or home), then writes
    the slider strokes, the universal-joint angles of every leg and the platform's free
    joint (position, quaternion w x y z), so every ``connect`` residual vanishes (to
    ~1e−15 m). Runs ``mj_kinematics`` so the frames match. ``hexapod`` must describe the
    model's geometry (default: the source's).
    """
    hexapod = Hexapod() if hexapod is None else hexapod
    q = np.asarray(strokes, dtype=float)
    position, R = hexapod.forward_kinematics(q, initial=initial)
    full = assembly_qpos(hexapod, q, position, R)
    for i in range(N_LEGS):
        n = i + 1
        for k, name in enumerate((f"slider{n}", f"u{n}_a", f"u{n}_b")):
            data.qpos[_joint_qposadr(model, name)] = full[3 * i + k]
    adr = _joint_qposadr(model, "platform")
    data.qpos[adr:adr + 7] = full[3 * N_LEGS:]
    mujoco.mj_kinematics(model, data)
    return position, R


def platform_pose(model: mujoco.MjModel, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
    """Platform (position (3,), R (3, 3)) read from its free joint in ``data.qpos``."""
    adr = _joint_qposadr(model, "platform")
    quat = data.qpos[adr + 3:adr + 7]
    R = np.empty(9)
    mujoco.mju_quat2Mat(R, quat / np.linalg.norm(quat))  # integration drifts off unit norm
    return data.qpos[adr:adr + 3].copy(), R.reshape(3, 3)


if __name__ == "__main__":
    print(f"wrote {write_scene()}")
