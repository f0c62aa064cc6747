r"""The device-resident control step's kernels (:mod:`qpik.batch.backends.warp_step`):
every world's task rows, cost, box, answer check and integration, one thread per world,
in float64 on MuJoCo Warp's float32 kinematics.

Each kernel restates one formula of the host code, which stays the definition:

- :func:`frame_rows`: ``FrameTask``, ``PositionTask``, ``OrientationTask`` (world or
  local axes, masks); the Jacobian columns as MuJoCo Warp's ``jac`` forms them
  (``cdof`` and the root's subtree centre of mass, in float32), the rotation error
  as :mod:`qpik.batch.rotations` (MuJoCo's quaternion routines, branch for branch);
- :func:`posture_rows`: ``PostureTask`` (``mj_differentiatePos`` on the float64 state);
- :func:`equality_rows`: ``EqualityTask`` from MuJoCo Warp's own constraint rows,
  found per world by type and equality id (their order in a world's rows comes from
  atomic counters on a GPU, so it is not assumed);
- :func:`cost_start`, :func:`add_joint_space`, :func:`add_soft`, :func:`add_hard`,
  :func:`cost_rescale`: ``batch.QPController``'s H, c, A, b (Levenberg–Marquardt
  terms and their rescaling included);
- :func:`position_limit`: ``JointPositionLimit.apply`` (the velocity box is a constant
  copied in first);
- :func:`prepare_qp`, :func:`check_answers`: the QP's refusals and the promise checked
  on the device (hard rows to 1e-9 (1 + |b|), the box to 1e-9 (1 + |bound|)), then the
  answer clipped into the box; a world that misses it is listed for the host;
- :func:`integrate_solved`, :func:`apply_host_answers`: ``mj_integratePos`` (the CPU
  back-end's ``_Integration``).

The tests pin every kernel to the host code (tests/batch/test_warp_step.py).
"""

import warp as wp

F64 = wp.float64
MINVAL = wp.constant(F64(1e-15))  # mjMINVAL
PI = wp.constant(F64(3.141592653589793))
LM_RESCALE = wp.constant(F64(1e6))  # the controller's (qpik.batch.controllers.LM_RESCALE)
SOLVED = wp.constant(0)  # qpik.batch.backends.base.QPStatus.SOLVED

# Per-world fault codes (lowest wins: the first task in the controller's order):
# 2k: task k's rows are not finite, 2k + 1: task k's constraint rows are not MuJoCo's
# expected ones; NO_FAULT: none.
NO_FAULT = wp.constant(1 << 30)
# Outcome of a world's step.
OK, FAULT, EMPTY_BOX, NAN_DATA, HOST = (wp.constant(k) for k in range(5))

JOINT_FREE, JOINT_BALL = wp.constant(0), wp.constant(1)  # mjtJoint
# A frame's errors: rows 0-2 position, 3-5 orientation; columns error, feed-forward.
mat62d = wp.types.matrix(shape=(6, 2), dtype=F64)


# -- quaternions (w, x, y, z), MuJoCo's routines ---------------------------------------
@wp.func
def normalize4(q: wp.vec4d) -> wp.vec4d:
    """``mju_normalize4``."""
    norm = wp.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if norm < MINVAL:
        return wp.vec4d(F64(1.0), F64(0.0), F64(0.0), F64(0.0))
    return q / norm


@wp.func
def mat2quat(R: wp.mat33d) -> wp.vec4d:
    """``mju_mat2Quat``, its four branches."""
    quarter = F64(0.25)
    trace = R[0, 0] + R[1, 1] + R[2, 2]
    q = wp.vec4d()
    if trace > F64(0.0):
        main = F64(0.5) * wp.sqrt(F64(1.0) + trace)
        q = wp.vec4d(main, quarter * (R[2, 1] - R[1, 2]) / main, quarter * (R[0, 2] - R[2, 0]) / main,
                     quarter * (R[1, 0] - R[0, 1]) / main)
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        main = F64(0.5) * wp.sqrt(F64(1.0) + R[0, 0] - R[1, 1] - R[2, 2])
        q = wp.vec4d(quarter * (R[2, 1] - R[1, 2]) / main, main, quarter * (R[0, 1] + R[1, 0]) / main,
                     quarter * (R[0, 2] + R[2, 0]) / main)
    elif R[1, 1] > R[2, 2]:
        main = F64(0.5) * wp.sqrt(F64(1.0) - R[0, 0] + R[1, 1] - R[2, 2])
        q = wp.vec4d(quarter * (R[0, 2] - R[2, 0]) / main, quarter * (R[0, 1] + R[1, 0]) / main, main,
                     quarter * (R[1, 2] + R[2, 1]) / main)
    else:
        main = F64(0.5) * wp.sqrt(F64(1.0) - R[0, 0] - R[1, 1] + R[2, 2])
        q = wp.vec4d(quarter * (R[1, 0] - R[0, 1]) / main, quarter * (R[0, 2] + R[2, 0]) / main,
                     quarter * (R[1, 2] + R[2, 1]) / main, main)
    return normalize4(q)


@wp.func
def quat_mul(a: wp.vec4d, b: wp.vec4d) -> wp.vec4d:
    """``mju_mulQuat``."""
    return wp.vec4d(a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
                    a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
                    a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
                    a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0])


@wp.func
def quat2vel(q: wp.vec4d) -> wp.vec3d:
    """``mju_quat2Vel`` (dt = 1)."""
    axis = wp.vec3d(q[1], q[2], q[3])
    sin_half = wp.length(axis)
    if sin_half < MINVAL:
        axis = wp.vec3d(F64(1.0), F64(0.0), F64(0.0))
    else:
        axis = axis / sin_half
    speed = F64(2.0) * wp.atan2(sin_half, q[0])
    if speed > PI:
        speed = speed - F64(2.0) * PI
    return axis * speed


@wp.func
def quat_sub(qa: wp.vec4d, qb: wp.vec4d) -> wp.vec3d:
    """``mju_subQuat``: v with qb * exp(v) = qa, in qb's frame."""
    return quat2vel(quat_mul(wp.vec4d(qb[0], -qb[1], -qb[2], -qb[3]), qa))


@wp.func
def quat_integrate(quat: wp.vec4d, velocity: wp.vec3d, dt: F64) -> wp.vec4d:
    """``mju_quatIntegrate`` as the CPU back-end writes it: quat * exp(velocity dt),
    normalised."""
    norm = wp.length(velocity)
    axis = wp.vec3d(F64(1.0), F64(0.0), F64(0.0))
    angle = F64(0.0)
    if not (norm < MINVAL):
        axis = velocity / norm
        angle = dt * norm
    rotation = wp.vec4d(F64(1.0), F64(0.0), F64(0.0), F64(0.0))
    if angle != F64(0.0):
        half = F64(0.5) * angle
        s = wp.sin(half)
        rotation = wp.vec4d(wp.cos(half), axis[0] * s, axis[1] * s, axis[2] * s)
    return normalize4(quat_mul(quat, rotation))


# -- small conversions -----------------------------------------------------------------
@wp.func
def vec3d_of(v: wp.vec3) -> wp.vec3d:
    return wp.vec3d(F64(v[0]), F64(v[1]), F64(v[2]))


@wp.func
def mat33d_of(m: wp.mat33) -> wp.mat33d:
    return wp.mat33d(F64(m[0, 0]), F64(m[0, 1]), F64(m[0, 2]), F64(m[1, 0]), F64(m[1, 1]), F64(m[1, 2]),
                     F64(m[2, 0]), F64(m[2, 1]), F64(m[2, 2]))


@wp.func
def quat_at(q: wp.array2d(dtype=F64), w: int, adr: int) -> wp.vec4d:
    return wp.vec4d(q[w, adr], q[w, adr + 1], q[w, adr + 2], q[w, adr + 3])


@wp.func
def flag_fault(fault: wp.array(dtype=int), w: int, code: int):
    if code < fault[w]:
        fault[w] = code


@wp.kernel
def state_to_float32(q: wp.array2d(dtype=F64), qpos: wp.array2d(dtype=float)):
    """MuJoCo Warp's float32 qpos from the float64 state."""
    w, i = wp.tid()
    qpos[w, i] = float(q[w, i])


# -- task rows ---------------------------------------------------------------------------
@wp.func
def frame_errors(p: wp.vec3d, R: wp.mat33d, w: int, has_rotation: int, local: int,
                 target_position: wp.array2d(dtype=F64), position_column: wp.array(dtype=int),
                 linear_velocity: wp.array2d(dtype=F64), target_rotation: wp.array3d(dtype=F64),
                 angular_velocity: wp.array2d(dtype=F64)) -> mat62d:
    """The frame's six errors and feed-forward terms (mat62d), world or local axes."""
    e_pos = wp.vec3d()
    f_pos = wp.vec3d()
    for a in range(3):
        col = position_column[a]
        if col >= 0:
            e_pos[a] = target_position[w, col] - p[a]
            f_pos[a] = linear_velocity[w, col]
    e_rot = wp.vec3d()
    f_rot = wp.vec3d()
    Rt = wp.transpose(R)
    if has_rotation != 0:
        f_rot = wp.vec3d(angular_velocity[w, 0], angular_velocity[w, 1], angular_velocity[w, 2])
        desired = wp.mat33d()
        for i in range(3):
            for j in range(3):
                desired[i, j] = target_rotation[w, i, j]
        e_rot = quat_sub(mat2quat(desired), mat2quat(R))  # in the frame's axes
        if local == 0:
            e_rot = R @ e_rot
    if local != 0:
        e_pos = Rt @ e_pos
        f_pos = Rt @ f_pos
        f_rot = Rt @ f_rot
    out = mat62d()
    for a in range(3):
        out[a, 0] = e_pos[a]
        out[a, 1] = f_pos[a]
        out[a + 3, 0] = e_rot[a]
        out[a + 3, 1] = f_rot[a]
    return out


@wp.kernel
def frame_rows(xpos: wp.array2d(dtype=wp.vec3), xmat: wp.array2d(dtype=wp.mat33), frame: int, root: int,
               chain: wp.array(dtype=int), subtree_com: wp.array2d(dtype=wp.vec3),
               cdof: wp.array2d(dtype=wp.spatial_vector), rows: wp.array(dtype=int), local: int, has_rotation: int,
               gains: wp.array(dtype=F64), target_position: wp.array2d(dtype=F64),
               position_column: wp.array(dtype=int), linear_velocity: wp.array2d(dtype=F64),
               target_rotation: wp.array3d(dtype=F64), angular_velocity: wp.array2d(dtype=F64), task: int,
               error: wp.array2d(dtype=F64), jacobian: wp.array3d(dtype=F64), velocity: wp.array2d(dtype=F64),
               fault: wp.array(dtype=int)):
    """A frame's masked pose rows (the batched ``_PoseRows``): error, Jacobian,
    target velocity ``K e + feed-forward``."""
    w = wp.tid()
    point = xpos[w, frame]
    p = vec3d_of(point)
    R = mat33d_of(xmat[w, frame])
    Rt = wp.transpose(R)
    dim = rows.shape[0]
    finite = int(1)
    errors = frame_errors(p, R, w, has_rotation, local, target_position, position_column, linear_velocity,
                          target_rotation, angular_velocity)
    for r in range(dim):
        a = rows[r]
        error[w, r] = errors[a, 0]
        velocity[w, r] = gains[r] * errors[a, 0] + errors[a, 1]
        if not wp.isfinite(velocity[w, r]):
            finite = 0
    offset = point - subtree_com[w, root]  # MuJoCo Warp's jac, in float32
    for j in range(jacobian.shape[2]):
        jp = wp.vec3d()
        jr = wp.vec3d()
        if chain[j] != 0:
            d = cdof[w, j]
            jp = vec3d_of(wp.spatial_bottom(d) + wp.cross(wp.spatial_top(d), offset))
            jr = vec3d_of(wp.spatial_top(d))
            if local != 0:
                jp = Rt @ jp
                jr = Rt @ jr
        for r in range(dim):
            a = rows[r]
            value = F64(0.0)
            if a < 3:
                value = jp[a]
            else:
                value = jr[a - 3]
            jacobian[w, r, j] = value
            if not wp.isfinite(value):
                finite = 0
    if finite == 0:
        flag_fault(fault, w, 2 * task)


@wp.func
def difference(q: wp.array2d(dtype=F64), target: wp.array2d(dtype=F64), jnt_type: wp.array(dtype=int),
               jnt_qposadr: wp.array(dtype=int), jnt_dofadr: wp.array(dtype=int), w: int,
               out: wp.array2d(dtype=F64)):
    """``mj_differentiatePos(q -> target)`` (dt = 1) of world w, into out[w]."""
    for jnt in range(jnt_type.shape[0]):
        kind = jnt_type[jnt]
        qadr = jnt_qposadr[jnt]
        vadr = jnt_dofadr[jnt]
        if kind == JOINT_FREE:
            for i in range(3):
                out[w, vadr + i] = target[w, qadr + i] - q[w, qadr + i]
            qadr = qadr + 3
            vadr = vadr + 3
        if kind == JOINT_FREE or kind == JOINT_BALL:
            v = quat_sub(quat_at(target, w, qadr), quat_at(q, w, qadr))
            for i in range(3):
                out[w, vadr + i] = v[i]
        else:
            out[w, vadr] = target[w, qadr] - q[w, qadr]


@wp.kernel
def posture_rows(q: wp.array2d(dtype=F64), target: wp.array2d(dtype=F64), jnt_type: wp.array(dtype=int),
                 jnt_qposadr: wp.array(dtype=int), jnt_dofadr: wp.array(dtype=int), dofs: wp.array(dtype=int),
                 gains: wp.array(dtype=F64), task: int, scratch: wp.array2d(dtype=F64),
                 error: wp.array2d(dtype=F64), velocity: wp.array2d(dtype=F64), fault: wp.array(dtype=int)):
    """``PostureTask``: e = (target ⊖ q)[dofs], v = K e."""
    w = wp.tid()
    difference(q, target, jnt_type, jnt_qposadr, jnt_dofadr, w, scratch)
    for k in range(dofs.shape[0]):
        e = scratch[w, dofs[k]]
        error[w, k] = e
        velocity[w, k] = gains[k] * e
        if not wp.isfinite(velocity[w, k]):
            flag_fault(fault, w, 2 * task)


@wp.func
def block_position(efc_type: wp.array2d(dtype=int), efc_id: wp.array2d(dtype=int), w: int, i: int,
                   kind: int) -> int:
    """How many rows of the same constraint precede row i (a constraint's rows are
    consecutive)."""
    j = int(0)
    while i - 1 - j >= 0 and efc_type[w, i - 1 - j] == kind and efc_id[w, i - 1 - j] == efc_id[w, i]:
        j = j + 1
    return j


@wp.kernel
def equality_rows(nefc: wp.array(dtype=int), efc_type: wp.array2d(dtype=int), efc_id: wp.array2d(dtype=int),
                  efc_pos: wp.array2d(dtype=float), efc_J: wp.array3d(dtype=float), equality_kind: int,
                  equalities: wp.array(dtype=int), row_offset: wp.array(dtype=int), row_count: wp.array(dtype=int),
                  expected_rows: int, gains: wp.array(dtype=F64), task: int, error: wp.array2d(dtype=F64),
                  jacobian: wp.array3d(dtype=F64), velocity: wp.array2d(dtype=F64), fault: wp.array(dtype=int)):
    """``EqualityTask``: MuJoCo Warp's rows of the task's equalities, in the task's
    order; v = -K e."""
    w = wp.tid()
    found = int(0)
    finite = int(1)
    nv = jacobian.shape[2]
    for i in range(nefc[w]):
        if efc_type[w, i] == equality_kind:
            for k in range(equalities.shape[0]):
                if equalities[k] == efc_id[w, i]:
                    j = block_position(efc_type, efc_id, w, i, equality_kind)
                    if j < row_count[k]:
                        slot = row_offset[k] + j
                        e = F64(efc_pos[w, i])
                        error[w, slot] = e
                        velocity[w, slot] = -gains[slot] * e
                        for d in range(nv):
                            jacobian[w, slot, d] = F64(efc_J[w, i, d])
                            if not wp.isfinite(jacobian[w, slot, d]):
                                finite = 0
                        if not wp.isfinite(velocity[w, slot]):
                            finite = 0
                        found = found + 1
    if found != error.shape[1] or nefc[w] != expected_rows:
        flag_fault(fault, w, 2 * task + 1)
    elif finite == 0:
        flag_fault(fault, w, 2 * task)


# -- the cost and the hard rows --------------------------------------------------------
@wp.kernel
def cost_start(H0: wp.array2d(dtype=F64), per_world: int, H: wp.array3d(dtype=F64), c: wp.array2d(dtype=F64),
               lm_total: wp.array(dtype=F64), fault: wp.array(dtype=int)):
    """H = H0 (per world when soft general tasks add to it), c = 0; no fault yet."""
    w = wp.tid()
    n = c.shape[1]
    if per_world != 0:
        for i in range(n):
            for j in range(n):
                H[w, i, j] = H0[i, j]
    for j in range(n):
        c[w, j] = F64(0.0)
    lm_total[w] = F64(0.0)
    fault[w] = NO_FAULT


@wp.kernel
def add_joint_space(dofs: wp.array(dtype=int), weight: wp.array(dtype=F64), velocity: wp.array2d(dtype=F64),
                    c: wp.array2d(dtype=F64)):
    """A joint-space task (its weights already on H0's diagonal): c[dofs] -= w v."""
    w = wp.tid()
    for k in range(dofs.shape[0]):
        c[w, dofs[k]] = c[w, dofs[k]] - weight[k] * velocity[w, k]


@wp.kernel
def add_soft(jacobian: wp.array3d(dtype=F64), velocity: wp.array2d(dtype=F64), error: wp.array2d(dtype=F64),
             weight: wp.array(dtype=F64), lm_damping: wp.array(dtype=F64), H: wp.array3d(dtype=F64),
             c: wp.array2d(dtype=F64), lm_total: wp.array(dtype=F64)):
    """A soft task: H += JᵀWJ, c -= JᵀWv, and the Levenberg–Marquardt term
    λ eᵀWe on H's diagonal."""
    w = wp.tid()
    dim = jacobian.shape[1]
    n = jacobian.shape[2]
    for i in range(n):
        for j in range(n):
            s = F64(0.0)
            for k in range(dim):
                s = s + jacobian[w, k, i] * (weight[k] * jacobian[w, k, j])
            H[w, i, j] = H[w, i, j] + s
        s = F64(0.0)
        for k in range(dim):
            s = s + velocity[w, k] * (weight[k] * jacobian[w, k, i])
        c[w, i] = c[w, i] - s
    if lm_damping[0] != F64(0.0):
        s = F64(0.0)
        for k in range(dim):
            s = s + error[w, k] * weight[k] * error[w, k]
        lm = lm_damping[0] * s
        for i in range(n):
            H[w, i, i] = H[w, i, i] + lm
        lm_total[w] = lm_total[w] + lm


@wp.kernel
def cost_rescale(H: wp.array3d(dtype=F64), c: wp.array2d(dtype=F64), lm_total: wp.array(dtype=F64)):
    """The controller's rescaling when the Levenberg–Marquardt terms are large."""
    w = wp.tid()
    if lm_total[w] > LM_RESCALE:
        scale = F64(1.0) / (F64(1.0) + lm_total[w])
        n = c.shape[1]
        for i in range(n):
            c[w, i] = c[w, i] * scale
            for j in range(n):
                H[w, i, j] = H[w, i, j] * scale


@wp.kernel
def add_hard(jacobian: wp.array3d(dtype=F64), velocity: wp.array2d(dtype=F64), offset: int,
             A: wp.array3d(dtype=F64), b: wp.array2d(dtype=F64)):
    """A hard task's rows J q̇ = v at rows offset.. of A and b."""
    w = wp.tid()
    for k in range(jacobian.shape[1]):
        b[w, offset + k] = velocity[w, k]
        for j in range(jacobian.shape[2]):
            A[w, offset + k, j] = jacobian[w, k, j]


# -- the box ------------------------------------------------------------------------------
@wp.kernel
def position_limit(q: wp.array2d(dtype=F64), qpos_index: wp.array(dtype=int), dof_index: wp.array(dtype=int),
                   lower: wp.array(dtype=F64), upper: wp.array(dtype=F64), rates: wp.array(dtype=F64),
                   lb: wp.array2d(dtype=F64), ub: wp.array2d(dtype=F64)):
    """``JointPositionLimit.apply``: rates = (gain/dt, influence, damped rate)."""
    w = wp.tid()
    step_rate = rates[0]
    influence = rates[1]
    damped = rates[2]
    for k in range(qpos_index.shape[0]):
        value = q[w, qpos_index[k]]
        low = lower[k] - value
        high = upper[k] - value
        low_rate = step_rate
        high_rate = step_rate
        if influence > F64(0.0):
            if wp.abs(low) < influence:
                low_rate = damped
            if wp.abs(high) < influence:
                high_rate = damped
        low = low * low_rate
        high = high * high_rate
        dof = dof_index[k]
        vel_lo = lb[w, dof]
        vel_hi = ub[w, dof]
        low = wp.min(low, vel_hi)  # recovery never asks for more than the velocity box
        high = wp.max(high, vel_lo)
        lb[w, dof] = wp.max(vel_lo, low)
        ub[w, dof] = wp.min(vel_hi, high)


@wp.kernel
def prepare_qp(c: wp.array2d(dtype=F64), A: wp.array3d(dtype=F64), b: wp.array2d(dtype=F64), meq: int,
               lb: wp.array2d(dtype=F64), ub: wp.array2d(dtype=F64), fault: wp.array(dtype=int),
               empty: wp.array(dtype=int), nan_data: wp.array(dtype=int), mask: wp.array(dtype=int)):
    """The worlds the QP is not given (``WarpQP``'s refusals): a task fault, NaN or
    inf in the QP's data, an empty box (its first variable kept for the message)."""
    w = wp.tid()
    n = c.shape[1]
    first_empty = int(-1)
    finite = int(1)
    for j in range(n):
        if lb[w, j] > ub[w, j] and first_empty < 0:
            first_empty = j
        if wp.isnan(lb[w, j]) or wp.isnan(ub[w, j]) or not wp.isfinite(c[w, j]):
            finite = 0
    for i in range(meq):
        if not wp.isfinite(b[w, i]):
            finite = 0
        for j in range(n):
            if not wp.isfinite(A[w, i, j]):
                finite = 0
    empty[w] = first_empty
    nan_data[w] = 1 - finite
    mask[w] = 0
    if fault[w] == NO_FAULT and finite == 1 and first_empty < 0:
        mask[w] = 1


@wp.func
def answer_holds(x: wp.array2d(dtype=F64), A: wp.array3d(dtype=F64), b: wp.array2d(dtype=F64), meq: int,
                 lb: wp.array2d(dtype=F64), ub: wp.array2d(dtype=F64), tolerance: F64, w: int) -> int:
    """x finite, hard rows to tolerance (1 + |b|), bounds to tolerance (1 + |bound|)."""
    one = F64(1.0)
    n = x.shape[1]
    for j in range(n):
        if not wp.isfinite(x[w, j]):
            return 0
        if x[w, j] < lb[w, j] - tolerance * (one + wp.abs(lb[w, j])):
            return 0
        if x[w, j] > ub[w, j] + tolerance * (one + wp.abs(ub[w, j])):
            return 0
    for i in range(meq):
        s = -b[w, i]
        for j in range(n):
            s = s + A[w, i, j] * x[w, j]
        if wp.abs(s) > tolerance * (one + wp.abs(b[w, i])):
            return 0
    return 1


@wp.kernel
def check_answers(x: wp.array2d(dtype=F64), qp_status: wp.array(dtype=int), A: wp.array3d(dtype=F64),
                  b: wp.array2d(dtype=F64), meq: int, lb: wp.array2d(dtype=F64), ub: wp.array2d(dtype=F64),
                  tolerance: F64, fault: wp.array(dtype=int), empty: wp.array(dtype=int),
                  nan_data: wp.array(dtype=int), outcome: wp.array(dtype=int), listed_count: wp.array(dtype=int),
                  listed: wp.array(dtype=int)):
    """Each world's outcome; a checked answer is clipped into its box, any other world
    gets x = 0 and is listed for the host."""
    w = wp.tid()
    state = OK
    if fault[w] != NO_FAULT:
        state = FAULT
    elif nan_data[w] != 0:
        state = NAN_DATA
    elif empty[w] >= 0:
        state = EMPTY_BOX
    elif qp_status[w] != SOLVED or answer_holds(x, A, b, meq, lb, ub, tolerance, w) == 0:
        state = HOST
    outcome[w] = state
    for j in range(x.shape[1]):
        if state == OK:
            x[w, j] = wp.min(wp.max(x[w, j], lb[w, j]), ub[w, j])
        else:
            x[w, j] = F64(0.0)
    if state != OK:
        listed[wp.atomic_add(listed_count, 0, 1)] = w


# -- integration -------------------------------------------------------------------------
@wp.func
def integrate_world(q: wp.array2d(dtype=F64), x: wp.array2d(dtype=F64), w: int, dt: F64,
                    jnt_type: wp.array(dtype=int), jnt_qposadr: wp.array(dtype=int), jnt_dofadr: wp.array(dtype=int)):
    """q[w] ← q[w] ⊕ x[w] dt (``mj_integratePos``)."""
    for jnt in range(jnt_type.shape[0]):
        kind = jnt_type[jnt]
        qadr = jnt_qposadr[jnt]
        vadr = jnt_dofadr[jnt]
        if kind == JOINT_FREE:
            for i in range(3):
                q[w, qadr + i] = q[w, qadr + i] + x[w, vadr + i] * dt
            qadr = qadr + 3
            vadr = vadr + 3
        if kind == JOINT_FREE or kind == JOINT_BALL:
            turned = quat_integrate(quat_at(q, w, qadr), wp.vec3d(x[w, vadr], x[w, vadr + 1], x[w, vadr + 2]), dt)
            for i in range(4):
                q[w, qadr + i] = turned[i]
        else:
            q[w, qadr] = q[w, qadr] + x[w, vadr] * dt


@wp.kernel
def integrate_solved(q: wp.array2d(dtype=F64), x: wp.array2d(dtype=F64), outcome: wp.array(dtype=int), dt: F64,
                     jnt_type: wp.array(dtype=int), jnt_qposadr: wp.array(dtype=int),
                     jnt_dofadr: wp.array(dtype=int)):
    """The worlds whose answer the device checked move; the listed ones wait for the host."""
    w = wp.tid()
    if outcome[w] == OK:
        integrate_world(q, x, w, dt, jnt_type, jnt_qposadr, jnt_dofadr)


@wp.kernel
def gather_listed(listed: wp.array(dtype=int), H: wp.array3d(dtype=F64), per_world: int, c: wp.array2d(dtype=F64),
                  A: wp.array3d(dtype=F64), b: wp.array2d(dtype=F64), lb: wp.array2d(dtype=F64),
                  ub: wp.array2d(dtype=F64), outcome: wp.array(dtype=int), fault: wp.array(dtype=int),
                  empty: wp.array(dtype=int), H_out: wp.array3d(dtype=F64), c_out: wp.array2d(dtype=F64),
                  A_out: wp.array3d(dtype=F64), b_out: wp.array2d(dtype=F64), lb_out: wp.array2d(dtype=F64),
                  ub_out: wp.array2d(dtype=F64), codes_out: wp.array2d(dtype=int)):
    """The listed worlds' QPs and codes (outcome, fault, empty variable), packed for
    the host."""
    k = wp.tid()
    w = listed[k]
    codes_out[k, 0] = outcome[w]
    codes_out[k, 1] = fault[w]
    codes_out[k, 2] = empty[w]
    n = c.shape[1]
    for i in range(n):
        c_out[k, i] = c[w, i]
        lb_out[k, i] = lb[w, i]
        ub_out[k, i] = ub[w, i]
        for j in range(n):
            H_out[k, i, j] = H[w * per_world, i, j]
    for i in range(A.shape[1]):
        b_out[k, i] = b[w, i]
        for j in range(n):
            A_out[k, i, j] = A[w, i, j]


@wp.kernel
def apply_host_answers(listed: wp.array(dtype=int), answers: wp.array2d(dtype=F64), x: wp.array2d(dtype=F64),
                       q: wp.array2d(dtype=F64), dt: F64, jnt_type: wp.array(dtype=int),
                       jnt_qposadr: wp.array(dtype=int), jnt_dofadr: wp.array(dtype=int)):
    """The host's answers for the listed worlds (zero where none), then their step."""
    k = wp.tid()
    w = listed[k]
    for j in range(x.shape[1]):
        x[w, j] = answers[k, j]
    integrate_world(q, x, w, dt, jnt_type, jnt_qposadr, jnt_dofadr)
