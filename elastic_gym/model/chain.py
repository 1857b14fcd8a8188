"""Batched kinematics and dynamics of a chain of revolute joints: N arms in one call.

`SerialChain` evaluates for N configurations at once what
[`RobotModel`][elastic_gym.model.RobotModel] evaluates with pinocchio for one, from the same
pinocchio model: accelerometer readings f = R_WS^T (a_W - g_W) (De Luca et al., eq. (9)),
the maps of eq. (10) (readings = T_A(q) q'' + W_A(q, q')), the link inertia M(q), the bias
n(q, q') = C q' + g by recursive Newton-Euler, and the forward dynamics
(M + M_a) q'' = tau - n by a Cholesky solve (M_a = -S B^-1 S^T: model (2)'s Schur
complement). The loops over arms are compiled with numba; each arm's result depends only
on its own inputs, computed by the same operations in the same order whatever N, so arm i
of a batch is bit-identical to the same arm alone. A chain holds one parameter set for all
arms or one per arm
([`SerialChain.stack`][elastic_gym.model.chain.SerialChain.stack]: arms whose links differ).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pinocchio as pin
from numba import njit

from elastic_gym.model import inlining
from elastic_gym.model.lapack import svd_workspace, thin_svd
from elastic_gym.model.packed import Packed
from elastic_gym.validation import shaped

inlining.install()  # the helpers below are inlined: copy each callee once (same IR)

NO_REFCOUNT: dict[str, Any] = {"_nrt": False}
"""numba's option of a kernel compiled without reference counting (it may allocate
nothing; numba's stubs do not declare the option, hence a mapping)."""

# ---------------------------------------------------------------------------- kernels
# Every kernel takes batched inputs with a leading arm axis, the scratch buffer, its outputs
# and last the chain's constants as one tuple (``SerialChain._kernel_constants``). The
# helpers are inlined by numba (``inline="always"``: a call passing some twenty arrays costs
# more than a 2-link arm's flops), so they take the constants as tuples, never as
# star-arguments. Inlined code is compiled once per kernel that inlines it, and once per
# signature: the quantities sharing a recursion are modes of one kernel (``_sensors_kernel``,
# ``_dynamics_kernel``), called with the same argument types from Python and from compiled
# callers (float64 C-contiguous arrays, complex128 for the complex step; no star-arguments
# and no literal modes, which numba types as other types when a compiled caller passes them).
# The two recursion kernels allocate nothing and are compiled without numba's reference
# counting (``_nrt=False``): counting the workspace views and per-arm constants unpacked
# for every arm cost about 30 % of a 2-link arm's forward dynamics; results are unchanged.


@njit(cache=True, inline="always")
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@njit(cache=True, inline="always")
def _matvec(A, x, out):
    for i in range(3):
        out[i] = A[i, 0] * x[0] + A[i, 1] * x[1] + A[i, 2] * x[2]


@njit(cache=True, inline="always")
def _matmul(A, B, out):
    for i in range(3):
        for k in range(3):
            out[i, k] = A[i, 0] * B[0, k] + A[i, 1] * B[1, k] + A[i, 2] * B[2, k]


@njit(cache=True, inline="always")
def _point_acceleration(acc, alpha, omega, r, out, tmp, tmp2):
    """Classical acceleration of a point at offset r: a + alpha x r + omega x (omega x r)."""
    _cross(alpha, r, tmp)
    _cross(omega, r, tmp2)
    for i in range(3):
        out[i] = acc[i] + tmp[i]
    _cross(omega, tmp2, tmp)
    for i in range(3):
        out[i] += tmp[i]


def _work_size(n: int) -> int:
    """Size of the scratch buffer of a chain of n joints (see `_workspace`)."""
    return 9 + 9 + 3 * 5 + 9 + n * (9 + 3 * 5) + n * (3 + 9 + 3 * 3) + 9 + n + n * n + 2 * n


@njit(cache=True, inline="always")
def _arm_params(a, constants):
    """Views of arm ``a``'s constants (``SerialChain._kernel_constants``): the chain, the
    bodies, the sensors, g_W and -g_W. Each constant is a separate array with a leading
    arm axis (row 0 for every arm when not stacked), not views reshaped here from one
    flat array, which slow the kernels (results: benchmarks, speed work)."""
    parent, rot_p, trans_p, axis, mass, com, inertia, grav, s_joint, s_rot, s_trans = constants
    chain = (parent, rot_p[a], trans_p[a], axis[a])
    return (
        chain,
        (mass[a], com[a], inertia[a]),
        (s_joint, s_rot[a], s_trans[a]),
        grav[a, 0],
        grav[a, 1],
    )


@njit(cache=True, inline="always")
def _workspace(n, w):
    """Scratch views of the flat buffer w, reused for every arm (no allocation per call)."""
    o = 0
    small_mats = w[o : o + 18].reshape((2, 3, 3))
    o += 18
    vecs = w[o : o + 15].reshape((5, 3))
    o += 15
    eye = w[o : o + 9].reshape((3, 3))
    o += 9
    for i in range(3):
        for k in range(3):
            eye[i, k] = 1.0 if i == k else 0.0
    vecs[4, :] = 0.0
    small = (small_mats[0], small_mats[1], vecs[0], vecs[1], vecs[2], eye, vecs[4])
    R = w[o : o + 9 * n].reshape((n, 3, 3))
    o += 9 * n
    lv = w[o : o + 15 * n].reshape((5, n, 3))
    o += 15 * n
    links = (R, lv[0], lv[1], lv[2], lv[3], lv[4])
    com_w = w[o : o + 3 * n].reshape((n, 3))
    o += 3 * n
    inertia_w = w[o : o + 9 * n].reshape((n, 3, 3))
    o += 9 * n
    bv = w[o : o + 9 * n].reshape((3, n, 3))
    o += 9 * n
    tv = w[o : o + 9].reshape((3, 3))
    o += 9
    zero_n = w[o : o + n]
    zero_n[:] = 0.0
    o += n
    M = w[o : o + n * n].reshape((n, n))
    o += n * n
    h, rhs = w[o : o + n], w[o + n : o + 2 * n]
    bodies = (com_w, inertia_w, bv[0], bv[1], bv[2], tv[0], tv[1], tv[2], zero_n)
    return small, links, bodies, (M, h, rhs)


@njit(cache=True, inline="always")
def _forward_kinematics(q, dq, ddq, base_acc, chain, links, small):
    """World rotation R, origin p, axis z, angular velocity omega and acceleration alpha,
    origin acceleration acc of every joint frame (``links``), for one arm.

    Written with scalars (no array views in the loop: they cost more than the flops).
    """
    n = q.shape[0]
    parent, rot_p, trans_p, axis = chain
    R, p, z, omega, alpha, acc = links
    for j in range(n):
        lam = parent[j]
        if lam < 0:  # the fixed base: at rest, accelerating with base_acc
            r00, r01, r02, r10, r11, r12, r20, r21, r22 = (
                1.0,
                0.0,
                0.0,
                0.0,
                1.0,
                0.0,
                0.0,
                0.0,
                1.0,
            )
            px = py = pz = wx = wy = wz = ax = ay = az = 0.0
            cx, cy, cz = base_acc[0], base_acc[1], base_acc[2]
        else:
            r00, r01, r02 = R[lam, 0, 0], R[lam, 0, 1], R[lam, 0, 2]
            r10, r11, r12 = R[lam, 1, 0], R[lam, 1, 1], R[lam, 1, 2]
            r20, r21, r22 = R[lam, 2, 0], R[lam, 2, 1], R[lam, 2, 2]
            px, py, pz = p[lam, 0], p[lam, 1], p[lam, 2]
            wx, wy, wz = omega[lam, 0], omega[lam, 1], omega[lam, 2]
            ax, ay, az = alpha[lam, 0], alpha[lam, 1], alpha[lam, 2]
            cx, cy, cz = acc[lam, 0], acc[lam, 1], acc[lam, 2]
        # T = R_lam R_Pj, then R_j = T Rot(u, q_j), z_j = T u
        P = rot_p[j]
        t00 = r00 * P[0, 0] + r01 * P[1, 0] + r02 * P[2, 0]
        t01 = r00 * P[0, 1] + r01 * P[1, 1] + r02 * P[2, 1]
        t02 = r00 * P[0, 2] + r01 * P[1, 2] + r02 * P[2, 2]
        t10 = r10 * P[0, 0] + r11 * P[1, 0] + r12 * P[2, 0]
        t11 = r10 * P[0, 1] + r11 * P[1, 1] + r12 * P[2, 1]
        t12 = r10 * P[0, 2] + r11 * P[1, 2] + r12 * P[2, 2]
        t20 = r20 * P[0, 0] + r21 * P[1, 0] + r22 * P[2, 0]
        t21 = r20 * P[0, 1] + r21 * P[1, 1] + r22 * P[2, 1]
        t22 = r20 * P[0, 2] + r21 * P[1, 2] + r22 * P[2, 2]
        ux, uy, uw = axis[j, 0], axis[j, 1], axis[j, 2]
        zx = t00 * ux + t01 * uy + t02 * uw
        zy = t10 * ux + t11 * uy + t12 * uw
        zz = t20 * ux + t21 * uy + t22 * uw
        z[j, 0], z[j, 1], z[j, 2] = zx, zy, zz
        c = np.cos(q[j])
        s = np.sin(q[j])
        v = 1.0 - c
        d00, d01, d02 = c + ux * ux * v, ux * uy * v - uw * s, ux * uw * v + uy * s
        d10, d11, d12 = uy * ux * v + uw * s, c + uy * uy * v, uy * uw * v - ux * s
        d20, d21, d22 = uw * ux * v - uy * s, uw * uy * v + ux * s, c + uw * uw * v
        R[j, 0, 0] = t00 * d00 + t01 * d10 + t02 * d20
        R[j, 0, 1] = t00 * d01 + t01 * d11 + t02 * d21
        R[j, 0, 2] = t00 * d02 + t01 * d12 + t02 * d22
        R[j, 1, 0] = t10 * d00 + t11 * d10 + t12 * d20
        R[j, 1, 1] = t10 * d01 + t11 * d11 + t12 * d21
        R[j, 1, 2] = t10 * d02 + t11 * d12 + t12 * d22
        R[j, 2, 0] = t20 * d00 + t21 * d10 + t22 * d20
        R[j, 2, 1] = t20 * d01 + t21 * d11 + t22 * d21
        R[j, 2, 2] = t20 * d02 + t21 * d12 + t22 * d22
        tx, ty, tz = trans_p[j, 0], trans_p[j, 1], trans_p[j, 2]
        rx = r00 * tx + r01 * ty + r02 * tz  # r_j = p_j - p_lam
        ry = r10 * tx + r11 * ty + r12 * tz
        rz = r20 * tx + r21 * ty + r22 * tz
        p[j, 0], p[j, 1], p[j, 2] = px + rx, py + ry, pz + rz
        qd = dq[j]
        omega[j, 0], omega[j, 1], omega[j, 2] = wx + zx * qd, wy + zy * qd, wz + zz * qd
        # alpha_j = alpha_lam + z q'' + omega_lam x (z q')
        vx, vy, vz = zx * qd, zy * qd, zz * qd
        alpha[j, 0] = ax + zx * ddq[j] + (wy * vz - wz * vy)
        alpha[j, 1] = ay + zy * ddq[j] + (wz * vx - wx * vz)
        alpha[j, 2] = az + zz * ddq[j] + (wx * vy - wy * vx)
        # acc_j = acc_lam + alpha_lam x r + omega_lam x (omega_lam x r)
        ex, ey, ez = ay * rz - az * ry, az * rx - ax * rz, ax * ry - ay * rx
        fx, fy, fz = wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx
        acc[j, 0] = cx + ex + (wy * fz - wz * fy)
        acc[j, 1] = cy + ey + (wz * fx - wx * fz)
        acc[j, 2] = cz + ez + (wx * fy - wy * fx)


@njit(cache=True, inline="always")
def _sensor_reading(i, sensors, gravity, links, small, out, row):
    """Specific force of sensor i in its frame into out[row: row + 3]; returns its joint.

    Leaves R_WS in small[1] and the sensor offset from its joint origin in small[2].
    """
    s_joint, s_rot, s_trans = sensors
    R, p, z, omega, alpha, acc = links
    R_s, r_s = small[1], small[2]
    j = s_joint[i]
    for a in range(3):
        for b in range(3):
            R_s[a, b] = (
                R[j, a, 0] * s_rot[i, 0, b]
                + R[j, a, 1] * s_rot[i, 1, b]
                + R[j, a, 2] * s_rot[i, 2, b]
            )
        r_s[a] = (
            R[j, a, 0] * s_trans[i, 0] + R[j, a, 1] * s_trans[i, 1] + R[j, a, 2] * s_trans[i, 2]
        )
    rx, ry, rz = r_s[0], r_s[1], r_s[2]
    wx, wy, wz = omega[j, 0], omega[j, 1], omega[j, 2]
    ax, ay, az = alpha[j, 0], alpha[j, 1], alpha[j, 2]
    fx, fy, fz = wy * rz - wz * ry, wz * rx - wx * rz, wx * ry - wy * rx  # omega x r
    # a_S - g = acc_j + alpha x r + omega x (omega x r) - g
    sx = acc[j, 0] + (ay * rz - az * ry) + (wy * fz - wz * fy) - gravity[0]
    sy = acc[j, 1] + (az * rx - ax * rz) + (wz * fx - wx * fz) - gravity[1]
    sz = acc[j, 2] + (ax * ry - ay * rx) + (wx * fy - wy * fx) - gravity[2]
    for c in range(3):
        out[row + c] = R_s[0, c] * sx + R_s[1, c] * sy + R_s[2, c] * sz
    return j


# What a kernel computes (its first argument): the modes of the two kernels below.
_FORCES, _MAPS = 0, 1  # _sensors_kernel
_GRAVITY, _RNEA, _MASS_AND_BIAS, _FORWARD = 0, 1, 2, 3  # _dynamics_kernel


@njit(cache=True, **NO_REFCOUNT)
def _sensors_kernel(mode, q, dq, ddq, w, T, W, constants):
    """Per arm: the readings of eq. (9) at (q, q', q'') into W (``_FORCES``; T unused), or
    T_A into T and W_A (the readings at q'' = 0) into W of eq. (10) (``_MAPS``; ddq
    unused). One kernel, so that numba compiles the recursions once for every mode."""
    N, n = q.shape
    stacked = constants[1].shape[0] > 1  # rot_p has one row per arm
    small, links, bodies, _ = _workspace(n, w)
    zero, zero_n = small[6], bodies[8]
    parent = constants[0]
    R, p, z, omega, alpha, acc = links
    R_s, r_s, t1, t2 = small[1], small[2], bodies[5], bodies[6]
    maps = mode == _MAPS
    for k in range(N):
        chain, _, sensors, gravity, _ = _arm_params(k if stacked else 0, constants)
        _forward_kinematics(q[k], dq[k], zero_n if maps else ddq[k], zero, chain, links, small)
        for i in range(sensors[0].shape[0]):
            j = _sensor_reading(i, sensors, gravity, links, small, W[k], 3 * i)
            if not maps:
                continue
            Tk = T[k]
            for c in range(3):
                for m in range(n):
                    Tk[3 * i + c, m] = 0.0
            m = j
            while m >= 0:  # the joints moving the sensor's link: z_m x (p_S - p_m)
                for c in range(3):
                    t1[c] = p[j, c] + r_s[c] - p[m, c]
                _cross(z[m], t1, t2)
                for c in range(3):
                    Tk[3 * i + c, m] = R_s[0, c] * t2[0] + R_s[1, c] * t2[1] + R_s[2, c] * t2[2]
                m = parent[m]


@njit(cache=True)
def _acceleration_from_readings_kernel(
    q, dq, readings, threshold, damping, w, ddq, diagnostics, constants
):
    N, n = q.shape
    m = readings.shape[1]
    T = np.empty((N, m, n))
    W = np.empty((N, m))
    _sensors_kernel(np.int64(_MAPS), q, dq, q, w, T, W, constants)  # int64, not a literal
    residual = np.empty(m)
    space = svd_workspace(m, n)
    for k in range(N):
        finite = True
        for i in range(m):
            residual[i] = readings[k, i] - W[k, i]
            for c in range(n):
                finite = finite and np.isfinite(T[k, i, c])
            finite = finite and np.isfinite(residual[i])
        if not finite:  # a diverged estimate: no inverse
            ddq[k, :] = np.nan
            diagnostics[k, :] = np.nan
            continue
        Ut, s, V = thin_svd(T[k], space)  # U = Ut.T, V^T = V.T; dgesdd bit for bit
        sigma_min = s[n - 1]
        ratio = min(sigma_min / threshold, 1.0)
        damping2 = (1.0 - ratio * ratio) * damping * damping
        for c in range(n):
            ddq[k, c] = 0.0
        for r in range(n):
            y = 0.0
            for i in range(m):
                y += Ut[r, i] * residual[i]
            y *= s[r] / (s[r] * s[r] + damping2)
            for c in range(n):
                ddq[k, c] += V[c, r] * y
        diagnostics[k, 0] = s[0]
        diagnostics[k, 1] = sigma_min
        diagnostics[k, 2] = np.sqrt(damping2)


acceleration_from_readings_kernel = _acceleration_from_readings_kernel  # compiled callers


@njit(cache=True, inline="always")
def _mass_and_bias_arm(
    q, dq, ddq, base_acc, chain, body_params, M, h, links, small, bodies, with_mass
):
    """M(q) (if ``with_mass``) and M(q) q'' + n(q, q') of one arm (Newton-Euler with
    a_0 = -g_W, composite Jacobians); ``ddq`` zero gives the bias n(q, q')."""
    n = q.shape[0]
    mass, com, inertia = body_params
    R, p, z, omega, alpha, acc = links
    com_w, inertia_w, force, moment, Jv, r, t1, t2, _ = bodies
    tmp, a_c, Iw = small[1], small[2], small[3]
    parent = chain[0]
    _forward_kinematics(q, dq, ddq, base_acc, chain, links, small)
    for b in range(n):
        _matvec(R[b], com[b], r)  # c_b - p_b
        for c in range(3):
            com_w[b, c] = p[b, c] + r[c]
        _matmul(R[b], inertia[b], tmp)
        for a in range(3):
            for c in range(3):
                inertia_w[b, a, c] = (
                    tmp[a, 0] * R[b, c, 0] + tmp[a, 1] * R[b, c, 1] + tmp[a, 2] * R[b, c, 2]
                )
        _point_acceleration(acc[b], alpha[b], omega[b], r, a_c, t1, t2)
        for c in range(3):
            force[b, c] = mass[b] * a_c[c]
        _matvec(inertia_w[b], omega[b], Iw)
        _cross(omega[b], Iw, t1)
        _matvec(inertia_w[b], alpha[b], t2)
        _cross(r, force[b], Iw)
        for c in range(3):
            moment[b, c] = t2[c] + t1[c] + Iw[c]  # about p_b
    for b in range(n - 1, -1, -1):  # children (higher index) have been added to moment[b]
        h[b] = z[b, 0] * moment[b, 0] + z[b, 1] * moment[b, 1] + z[b, 2] * moment[b, 2]
        lam = parent[b]
        if lam >= 0:
            for c in range(3):
                r[c] = p[b, c] - p[lam, c]
            _cross(r, force[b], t1)
            for c in range(3):
                force[lam, c] += force[b, c]
                moment[lam, c] += moment[b, c] + t1[c]
    if not with_mass:
        return
    for a in range(n):  # M = sum_b J_vb^T m_b J_vb + J_wb^T I_b J_wb
        for c in range(n):
            M[a, c] = 0.0
    for b in range(n):
        m = b
        while m >= 0:
            for c in range(3):
                r[c] = com_w[b, c] - p[m, c]
            _cross(z[m], r, Jv[m])
            m = parent[m]
        a = b
        while a >= 0:
            _matvec(inertia_w[b], z[a], t1)
            c = a
            while c >= 0:
                value = mass[b] * (Jv[a, 0] * Jv[c, 0] + Jv[a, 1] * Jv[c, 1] + Jv[a, 2] * Jv[c, 2])
                value += z[c, 0] * t1[0] + z[c, 1] * t1[1] + z[c, 2] * t1[2]
                M[a, c] += value
                if c != a:
                    M[c, a] += value
                c = parent[c]
            a = parent[a]


@njit(cache=True, inline="always")
def _cholesky_solve(A, b, out):
    """Solve A x = b for a symmetric positive definite A (A is overwritten by its factor)."""
    n = b.shape[0]
    for j in range(n):
        d = A[j, j]
        for k in range(j):
            d -= A[j, k] * A[j, k]
        d = np.sqrt(d)
        A[j, j] = d
        for i in range(j + 1, n):
            s = A[i, j]
            for k in range(j):
                s -= A[i, k] * A[j, k]
            A[i, j] = s / d
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= A[i, k] * out[k]
        out[i] = s / A[i, i]
    for i in range(n - 1, -1, -1):
        s = out[i]
        for k in range(i + 1, n):
            s -= A[k, i] * out[k]
        out[i] = s / A[i, i]


@njit(cache=True, **NO_REFCOUNT)
def _dynamics_kernel(mode, q, dq, ddq, tau, added_inertia, w, M_out, h_out, constants):
    """Per arm: g(q) (``_GRAVITY``) or M(q) q'' + n(q, q') (``_RNEA``) into h_out; M(q) and
    n(q, q') into M_out and h_out (``_MASS_AND_BIAS``); q'' of (M + M_a) q'' = tau - n into
    h_out (``_FORWARD``; ``added_inertia`` (1 or N, n, n)). Arguments a mode does not use
    are not read (M_out is written by ``_MASS_AND_BIAS`` only). One kernel, so that numba
    compiles the Newton-Euler recursion once for every mode."""
    N, n = q.shape
    stacked = constants[1].shape[0] > 1  # rot_p has one row per arm
    small, links, bodies, (M, h, rhs) = _workspace(n, w)
    zero_n = bodies[8]
    per_arm = added_inertia.shape[0] > 1
    with_mass = mode >= _MASS_AND_BIAS  # _MASS_AND_BIAS or _FORWARD
    for k in range(N):
        chain, bodies_p, _, _, minus_gravity = _arm_params(k if stacked else 0, constants)
        _mass_and_bias_arm(
            q[k],
            zero_n if mode == _GRAVITY else dq[k],
            ddq[k] if mode == _RNEA else zero_n,
            minus_gravity,
            chain,
            bodies_p,
            M_out[k] if mode == _MASS_AND_BIAS else M,
            h if mode == _FORWARD else h_out[k],
            links,
            small,
            bodies,
            with_mass,
        )
        if mode == _FORWARD:
            added = added_inertia[k if per_arm else 0]
            for a in range(n):
                rhs[a] = tau[k, a] - h[a]
                for c in range(n):
                    M[a, c] += added[a, c]
            _cholesky_solve(M, rhs, h_out[k])


@njit(cache=True)
def _gravity_kernel(q, h, packed):
    """g(q) into h: `_dynamics_kernel` in the ``_GRAVITY`` mode, its other arguments
    in ``packed``
    ([`SerialChain.gravity_arguments`][elastic_gym.model.chain.SerialChain.gravity_arguments])."""
    unused, w, constants = packed.values
    gravity = np.int64(_GRAVITY)  # int64 as from Python
    _dynamics_kernel(gravity, q, q, q, q, unused, w, unused, h, constants)


@njit(cache=True)
def forward_dynamics_kernel(q, dq, tau, added_inertia, ddq, packed):
    """q'' of (M(q) + M_a) q'' + n(q, q') = tau into ``ddq``: `_dynamics_kernel` in
    the ``_FORWARD`` mode, its other arguments in ``packed``
    ([`SerialChain.forward_dynamics_arguments`][elastic_gym.model.chain.SerialChain.forward_dynamics_arguments])."""
    unused, w, constants = packed.values
    forward = np.int64(_FORWARD)  # int64 as from Python
    _dynamics_kernel(forward, q, dq, q, tau, added_inertia, w, unused, ddq, constants)


@njit(cache=True)
def specific_forces_kernel(q, dq, ddq, w, unused, forces, constants):
    """The readings of eq. (9) at q'' into ``forces``
    ([`SerialChain.specific_forces`][elastic_gym.model.chain.SerialChain.specific_forces];
    the other arguments as `SerialChain.dynamics_and_forces_arguments` gives them)."""
    readings = np.int64(_FORCES)  # int64 as from Python
    _sensors_kernel(readings, q, dq, ddq, w, unused, forces, constants)


@njit(cache=True)
def _dynamics_and_forces_kernel(q, dq, tau, added_inertia, w, ddq, forces, constants):
    """Forward dynamics into ``ddq``, then the readings of eq. (9) at that q'' into
    ``forces``: the two `SerialChain` calls in one dispatch from Python."""
    forward, readings = np.int64(_FORWARD), np.int64(_FORCES)  # int64 as from Python
    _dynamics_kernel(forward, q, dq, q, tau, added_inertia, w, added_inertia, ddq, constants)
    _sensors_kernel(readings, q, dq, ddq, w, added_inertia, forces, constants)


# ---------------------------------------------------------------------------- the chain

Triple = tuple[np.ndarray, np.ndarray, np.ndarray]  # (q, q', q'') or a direction of it

COMPLEX_STEP = 1e-30
"""Imaginary step h of the complex-step derivatives (Squire & Trapp 1998):
f'(x) t = Im f(x + i h t) / h + O(h^2) for the analytic kernels above (sums, products,
sin, cos)."""


def _batch(x: np.ndarray, n: int, name: str) -> np.ndarray:
    if type(x) is np.ndarray and x.dtype == np.float64 and x.ndim == 2 and x.shape[1] == n:
        # the hot path: the simulator's own arrays, or views of rows (a reference's)
        return x if x.flags.c_contiguous else np.ascontiguousarray(x)
    return np.ascontiguousarray(shaped(x, (None, n), name))


class SerialChain:
    """Batched kinematics and dynamics of a pinocchio model of revolute joints.

    Args:
        pin_model: the pinocchio model (revolute joints, one DoF each, parents before
            children), with its link inertias (any parameter scaling already applied).
        sensor_frames: ids of the accelerometer frames in ``pin_model``.

    All methods take arrays with a leading arm axis, (N, n) for joint vectors. Not
    thread-safe (one scratch buffer per chain); give each thread its own chain.
    """

    def __init__(self, pin_model: pin.Model, sensor_frames: list[int] | tuple[int, ...] = ()):
        n = pin_model.nv
        if pin_model.nq != n or pin_model.njoints != n + 1:
            raise ValueError("SerialChain needs one revolute joint per degree of freedom")
        self.n = n
        joints = range(1, n + 1)
        parent = [pin_model.parents[j] - 1 for j in joints]
        axes = []
        for j in joints:
            joint = pin_model.joints[j]
            data = joint.createData()
            joint.calc(data, np.zeros(n))
            motion = np.asarray(data.S).ravel()
            if joint.nq != 1 or np.any(motion[:3] != 0.0):
                raise ValueError(f"joint {pin_model.names[j]!r} is not revolute")
            axes.append(motion[3:])
        bodies = [pin_model.inertias[j] for j in joints]
        frames = [pin_model.frames[f] for f in sensor_frames]
        self.n_sensors = len(frames)
        gravity = np.array(pin_model.gravity.linear, dtype=float)
        constants = {  # one row: the arm axis of the kernels' per-arm constants
            "rot_p": [pin_model.jointPlacements[j].rotation for j in joints],
            "trans_p": [pin_model.jointPlacements[j].translation for j in joints],
            "axis": axes,
            "mass": [body.mass for body in bodies],
            "com": [body.lever for body in bodies],
            "inertia": [body.inertia for body in bodies],
            "grav": [gravity, -gravity],
            "s_rot": np.reshape([f.placement.rotation for f in frames], (-1, 3, 3)),
            "s_trans": np.reshape([f.placement.translation for f in frames], (-1, 3)),
        }
        self._constants = {
            key: np.asarray(value, dtype=float)[None] for key, value in constants.items()
        }
        self._parent = np.array(parent, dtype=np.int64)
        self._s_joint = np.array([f.parentJoint - 1 for f in frames], dtype=np.int64)
        self._no_inertia = np.zeros((1, n, n))  # also what a kernel's unused arrays get
        self._no_inertia_complex = np.zeros((1, n, n), dtype=np.complex128)
        self._scratch()

    @property
    def _arms(self) -> int:
        """Rows of the per-arm constants: 1 (every arm alike) or N (stacked)."""
        return len(self._constants["mass"])

    def _kernel_constants(self) -> tuple[np.ndarray, ...]:
        """The kernels' constants in their argument order (see `_arm_params`)."""
        c = self._constants
        return (
            self._parent,
            c["rot_p"],
            c["trans_p"],
            c["axis"],
            c["mass"],
            c["com"],
            c["inertia"],
            c["grav"],
            self._s_joint,
            c["s_rot"],
            c["s_trans"],
        )

    def _with_constants(self, constants: dict[str, np.ndarray]) -> SerialChain:
        new = SerialChain.__new__(SerialChain)
        vars(new).update(vars(self))
        new._constants = constants
        new._scratch()
        return new

    @classmethod
    def stack(cls, chains: list[SerialChain] | tuple[SerialChain, ...]) -> SerialChain:
        """One chain whose arm k has the parameters of ``chains[k]`` (same joints and
        sensors, e.g. link inertias that differ per arm): its methods then take exactly
        ``len(chains)`` rows, row k computed bit for bit as ``chains[k]`` computes it."""
        first = chains[0]
        if any(
            not np.array_equal(c._parent, first._parent)
            or not np.array_equal(c._s_joint, first._s_joint)
            for c in chains
        ):
            raise ValueError("stacked chains must share their joints and sensors")
        return first._with_constants(
            {key: np.concatenate([c._constants[key] for c in chains]) for key in first._constants}
        )

    def select(self, arms: np.ndarray) -> SerialChain:
        """The chain of the rows ``arms`` of a stacked chain (itself when not stacked)."""
        if self._arms == 1:
            return self
        rows = np.asarray(arms, dtype=np.int64)
        return self._with_constants({key: c[rows] for key, c in self._constants.items()})

    def set_row(self, arm: int, chain: SerialChain) -> None:
        """Give arm ``arm`` of a stacked chain the parameters of ``chain``."""
        for key, c in self._constants.items():
            c[arm] = chain._constants[key][0]

    def _rows(self, x: np.ndarray) -> None:
        if self._arms > 1 and len(x) != self._arms:
            raise ValueError(
                f"a chain stacked for {self._arms} arms got {len(x)} rows; "
                "use select(arms) for a subset"
            )

    def _scratch(self) -> None:
        work = _work_size(self.n)
        self._work = np.empty(work)
        self._work_complex = np.empty(work, dtype=np.complex128)  # complex-step tangents
        self._packed: Packed | None = None  # see gravity_arguments

    def __getstate__(self) -> dict:
        scratch = ("_work", "_work_complex", "_packed")
        return {k: v for k, v in vars(self).items() if k not in scratch}

    def __setstate__(self, state: dict) -> None:
        vars(self).update(state)
        self._scratch()

    def specific_forces(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """(N, 3 n_sensors) noise-free accelerometer readings, eq. (9) stacked."""
        n = self.n
        q, dq, ddq = _batch(q, n, "q"), _batch(dq, n, "dq"), _batch(ddq, n, "ddq")
        self._rows(q)
        out = np.empty((len(q), 3 * self.n_sensors))
        _sensors_kernel(
            _FORCES, q, dq, ddq, self._work, self._no_inertia, out, self._kernel_constants()
        )
        return out

    def accelerometer_maps(self, q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(T_A (N, 3 n_sensors, n), W_A (N, 3 n_sensors)) of eq. (10)."""
        n = self.n
        q, dq = _batch(q, n, "q"), _batch(dq, n, "dq")
        self._rows(q)
        T = np.empty((len(q), 3 * self.n_sensors, n))
        W = np.empty((len(q), 3 * self.n_sensors))
        _sensors_kernel(_MAPS, q, dq, q, self._work, T, W, self._kernel_constants())
        return T, W

    def acceleration_from_readings(
        self,
        q: np.ndarray,
        dq: np.ndarray,
        readings: np.ndarray,
        threshold: float,
        damping: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """q'' = T_A^+(q) (readings - W_A(q, q')) of De Luca et al. (2007), eq. (11), per arm.

        T_A^+ is the damped least-squares inverse V diag(s / (s^2 + lambda^2)) U^T of the SVD
        T_A = U diag(s) V^T, with lambda^2 = (1 - (s_min / threshold)^2) damping^2 when the
        smallest singular value s_min is below ``threshold`` and 0 otherwise (the plain
        pseudo-inverse). Returns (q'' (N, n), (s_max, s_min, lambda) (N, 3)); rows whose
        maps are not finite are NaN.
        """
        n = self.n
        q, dq = _batch(q, n, "q"), _batch(dq, n, "dq")
        self._rows(q)
        readings = np.ascontiguousarray(shaped(readings, (len(q), 3 * self.n_sensors), "readings"))
        ddq = np.empty((len(q), n))
        diagnostics = np.empty((len(q), 3))
        _acceleration_from_readings_kernel(
            q,
            dq,
            readings,
            float(threshold),
            float(damping),
            self._work,
            ddq,
            diagnostics,
            self._kernel_constants(),
        )
        return ddq, diagnostics

    def readings_arguments(self) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
        """(work, constants): the last arguments of `acceleration_from_readings_kernel`
        after its outputs, for compiled callers that run eq. (11) in their own loop (the
        work buffer is this chain's: one caller at a time)."""
        return self._work, self._kernel_constants()

    def mass_and_bias(self, q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(M(q) (N, n, n), n(q, q') = C q' + g (N, n))."""
        n = self.n
        q, dq = _batch(q, n, "q"), _batch(dq, n, "dq")
        self._rows(q)
        M = np.empty((len(q), n, n))
        h = np.empty((len(q), n))
        self._dynamics(_MASS_AND_BIAS, q, dq, q, q, self._no_inertia, M, h)
        return M, h

    def rnea(self, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
        """Inverse dynamics M(q) q'' + C(q, q') q' + g(q) (N, n), without friction."""
        n = self.n
        q, dq, ddq = _batch(q, n, "q"), _batch(dq, n, "dq"), _batch(ddq, n, "ddq")
        self._rows(q)
        out = np.empty(q.shape)
        self._dynamics(_RNEA, q, dq, ddq, q, self._no_inertia, self._no_inertia, out)
        return out

    def rnea_tangent(self, point: Triple, direction: Triple) -> tuple[np.ndarray, np.ndarray]:
        """(tau, d tau): `rnea` at ``point`` = (q, q', q'') and its derivative along
        ``direction`` = (t_q, t_dq, t_ddq), (N, n) arrays each.

        Complex step: d tau = Im rnea(q + i h t_q, q' + i h t_dq, q'' + i h t_ddq) / h,
        exact to rounding (no subtraction; truncation O(h^2), h = `COMPLEX_STEP`).
        Along a trajectory the direction (q', q'', q^(3)) gives the time derivative.
        """
        return self._complex_step(_RNEA, self.n, point, direction)

    def specific_forces_tangent(
        self, point: Triple, direction: Triple
    ) -> tuple[np.ndarray, np.ndarray]:
        """(readings, d readings):
        [`specific_forces`][elastic_gym.model.chain.SerialChain.specific_forces] at ``point`` and
        its derivative
        along ``direction``, by the complex step of
        [`rnea_tangent`][elastic_gym.model.chain.SerialChain.rnea_tangent]."""
        return self._complex_step(_FORCES, 3 * self.n_sensors, point, direction)

    def _complex_step(self, mode: int, width: int, point: Triple, direction: Triple):
        """`rnea` (``mode`` ``_RNEA``) or
        [`specific_forces`][elastic_gym.model.chain.SerialChain.specific_forces] (``_FORCES``) at
        the
        complex point + i h direction."""
        n = self.n
        q, dq, ddq = (
            np.ascontiguousarray(_batch(x, n, "point") + (1j * COMPLEX_STEP) * _batch(t, n, "t"))
            for x, t in zip(point, direction, strict=True)
        )
        self._rows(q)
        out = np.empty((len(q), width), dtype=np.complex128)
        unused = self._no_inertia_complex
        constants = self._kernel_constants()
        if mode == _RNEA:
            w = self._work_complex
            _dynamics_kernel(_RNEA, q, dq, ddq, q, self._no_inertia, w, unused, out, constants)
        else:
            _sensors_kernel(_FORCES, q, dq, ddq, self._work_complex, unused, out, constants)
        return out.real.copy(), out.imag / COMPLEX_STEP

    def _dynamics(self, mode, q, dq, ddq, tau, added_inertia, M_out, h_out) -> None:
        _dynamics_kernel(
            mode,
            q,
            dq,
            ddq,
            tau,
            added_inertia,
            self._work,
            M_out,
            h_out,
            self._kernel_constants(),
        )

    def gravity(self, q: np.ndarray) -> np.ndarray:
        """g(q) (N, n)."""
        q = _batch(q, self.n, "q")
        self._rows(q)
        h = np.empty(q.shape)
        _gravity_kernel(q, h, self.gravity_arguments())
        return h

    def gravity_arguments(self) -> Packed:
        """The arguments of `_gravity_kernel` after q and h (packed once per chain),
        for compiled callers composing g(q) with their own loops."""
        if self._packed is None:
            self._packed = Packed((self._no_inertia, self._work, self._kernel_constants()))
        return self._packed

    def forward_dynamics_arguments(self) -> Packed:
        """The arguments of `forward_dynamics_kernel` after q'' (the same pack as
        [`gravity_arguments`][elastic_gym.model.chain.SerialChain.gravity_arguments]), for compiled
        callers (the simulator's model (2))."""
        return self.gravity_arguments()

    def forward_dynamics(
        self,
        q: np.ndarray,
        dq: np.ndarray,
        tau: np.ndarray,
        added_inertia: np.ndarray | None = None,
    ) -> np.ndarray:
        """q'' solving (M(q) + M_a) q'' + n(q, q') = tau, (N, n); M_a constant, (n, n) for
        every arm or (N, n, n) one per arm."""
        n = self.n
        q, dq, tau = _batch(q, n, "q"), _batch(dq, n, "dq"), _batch(tau, n, "tau")
        self._rows(q)
        extra = (
            self._no_inertia
            if added_inertia is None
            else np.ascontiguousarray(added_inertia, dtype=np.float64).reshape(-1, n, n)
        )
        out = np.empty((len(q), n))
        self._dynamics(_FORWARD, q, dq, q, tau, extra, self._no_inertia, out)
        return out

    def forward_dynamics_and_forces(
        self, q: np.ndarray, dq: np.ndarray, tau: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """([`forward_dynamics`][elastic_gym.model.chain.SerialChain.forward_dynamics] (no
        added inertia), [`specific_forces`][elastic_gym.model.chain.SerialChain.specific_forces]
        at that q''), equal to the two calls bit for bit, in one compiled call."""
        n = self.n
        q, dq, tau = _batch(q, n, "q"), _batch(dq, n, "dq"), _batch(tau, n, "tau")
        self._rows(q)
        ddq = np.empty((len(q), n))
        forces = np.empty((len(q), 3 * self.n_sensors))
        _dynamics_and_forces_kernel(q, dq, tau, *self.dynamics_and_forces_arguments(ddq, forces))
        return ddq, forces

    def dynamics_and_forces_arguments(self, ddq: np.ndarray, forces: np.ndarray) -> tuple:
        """The arguments of `_dynamics_and_forces_kernel` after (q, q', tau), writing
        into ``ddq`` and ``forces``: for compiled callers composing it with their own
        kernels (the simulator's transmission)."""
        return (self._no_inertia, self._work, ddq, forces, self._kernel_constants())
