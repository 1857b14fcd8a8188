"""The compiled kernels of a batch's control period.

A control period of every arm in two compiled calls where it can be
([`ArmBatch.step`][elastic_gym.envs.batch.ArmBatch.step]): `control_period_kernel` (the
task's open-loop torque, the clip to the torque limits, the physics substeps of
[`elastic_gym.envs.simulator`][elastic_gym.envs.simulator] or the RK4, the clock, the reference) and
`post_step_kernel` (q'' and the accelerometers' noise-free readings of eq. (9) of De Luca
et al. 2007, the termination codes, the sensors through their delay line, the reward).
Their arguments are packed by [`elastic_gym.envs.packing`][elastic_gym.envs.packing]; the
small kernels they are made of (`break_codes`, `clip_torque`, `advance_clock`) are what
the step by step path calls one by one, so both paths are bit for bit the same.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from elastic_gym.envs import bullet_capi
from elastic_gym.envs.reward import _reward_kernel
from elastic_gym.envs.sensors import _shared_readings
from elastic_gym.envs.simulator import (
    _coupled_link_torque,
    _is_coupled,
    _period_kernel,
    _transmission_kernel,
)
from elastic_gym.envs.tasks import open_loop_torque_kernel, reference_kernel
from elastic_gym.model.chain import _dynamics_and_forces_kernel, specific_forces_kernel
from elastic_gym.model.integrator import rk4_period_kernel


@njit(cache=True)
def break_codes(q, dq, theta, dtheta, lower, upper, max_velocity, codes):
    """Per arm: 0 (the physics holds), 1 (a joint limit crossed), 2 (|q'| or |theta'| above
    max_velocity), 3 (a non-finite state), the most severe one; returns whether any arm
    broke."""
    broken = False
    for k in range(q.shape[0]):
        code = 0
        for j in range(q.shape[1]):
            values = (q[k, j], dq[k, j], theta[k, j], dtheta[k, j])
            if not (
                np.isfinite(values[0])
                and np.isfinite(values[1])
                and np.isfinite(values[2])
                and np.isfinite(values[3])
            ):
                code = 3
            elif abs(values[1]) > max_velocity or abs(values[3]) > max_velocity:
                code = max(code, 2)
            elif values[0] < lower[j] or values[0] > upper[j]:
                code = max(code, 1)
        codes[k] = code
        broken = broken or code > 0
    return broken


@njit(cache=True)
def clip_torque(command, external, low, high, tau, saturated):
    """tau = min(max(command + external, low), high) per joint (`external` None: none),
    as numpy's addition, maximum and minimum give it (NaN stays NaN), and per arm whether
    any joint's torque changed in the clip (NaN: changed)."""
    for k in range(command.shape[0]):
        changed = False
        for j in range(command.shape[1]):
            c = command[k, j]
            if external is not None:
                c = c + external[k, j]
            v = low[j] if c < low[j] else c
            v = high[j] if v > high[j] else v
            tau[k, j] = v
            changed = changed or v != c
        saturated[k] = changed


@njit(cache=True)
def advance_clock(steps, stepping, dt, max_steps, time, truncated):
    """steps += 1 for the stepping arms (`stepping` None: every arm), time = steps dt
    (numpy's int64 by float64 product) and truncated = steps >= max_steps (not written
    when `max_steps` is -1: episodes without a length); returns whether any arm is
    truncated."""
    ended = False
    for k in range(steps.shape[0]):
        if stepping is None or stepping[k]:
            steps[k] += 1
        time[k] = steps[k] * dt
        if max_steps >= 0:
            truncated[k] = steps[k] >= max_steps
            ended = ended or truncated[k]
    return ended


@njit(cache=True, inline="always")
def _copy(source, target):
    """target[k, j] = source[k, j] (N, n): a slice assignment would compile numba's
    broadcasting checks and their error messages (string formatting) into the kernel."""
    for k in range(target.shape[0]):
        for j in range(target.shape[1]):
            target[k, j] = source[k, j]


@njit(cache=True)
def post_step_kernel(tau, previous, reference, slot, reward, coupling, packed):
    """The end of a control period of every arm in one call, the same kernels in the same
    order as the step by step path of
    [`ArmBatch.step`][elastic_gym.envs.batch.ArmBatch.step] calls them one by one (so bit
    for bit the same):

    1. q'' and the noise-free accelerometer readings (eq. (9)), no link-side torque:
       the simulator's `_transmission_kernel` and the chain's
       `_dynamics_and_forces_kernel` (`transmission`, `dynamics`: their arguments after
       the motor torques `tau` and after q, q', tau), as its `_link_dynamics_kernel`
       calls them; for model (2) (`coupling`'s matrices (N, n, n), not (N, 0, 0)) q''
       of the simulator's `_coupled_link_torque` and the readings at it
       (`specific_forces_kernel`); with the RK4 (`integrated`: (its q'' at the end of
       the period, True)) that q'', which is the same q'' bit for bit (the RK4's
       right-hand side is these kernels' operations in their order), and the readings
       at it. `coupling` is a `Packed` of the same types for either model, so that
       numba compiles one signature for both;
    2. the termination codes (`break_codes`, `limits`: its arguments after the state); if
       an arm broke, returns False here (the caller measures with the hold of non-finite
       readings);
    3. the encoders' and accelerometers' readings (`_shared_readings` of
       [`elastic_gym.envs.sensors`][elastic_gym.envs.sensors]: one error model for every
       arm, no filter), through the sensor delay line (`slot`: its newest slot), into the
       observation with the reference q_d, q_d' (`reference` (N, 5, n));
    4. the reward (`_reward_kernel` of [`elastic_gym.envs.reward`][elastic_gym.envs.reward],
       into `reward` (N,)) at e = q - q_d, e' = q' - q_d', torsion theta - q, the torques
       `tau` and `previous`.

    `packed`: a `Packed` (`elastic_gym.model.packed`) of what holds for the episode
    ([`FusedArguments`][elastic_gym.envs.packing.FusedArguments]): (theta, theta', q, q',
    transmission, dynamics, limits, sensors, the torque
    limit row and the reward constants after it, integrated, scratch (3, N, n) for the
    reward's errors and torsion, the simulator's (N, 0) array of no link torque);
    `sensors`: (elastic, encoder std, block, next,
    resolution, has accelerometers, bias, std, block, next, range, resolution, readings
    (encoders, accelerometers), delay lines (L, N, size) of both, delays (N,), observation
    arrays (position, acceleration, reference))."""
    theta, dtheta, q, dq, transmission = packed.values[:5]
    dynamics, limits, sensors, rewards, integrated, scratch, no_link = packed.values[5:]
    (
        elastic,
        enc_std,
        enc_block,
        enc_next,
        enc_resolution,
        has_acc,
        acc_bias,
        acc_std,
        acc_block,
        acc_next,
        acc_range,
        acc_resolution,
        position_reading,
        acc_reading,
        position_line,
        acc_line,
        delay,
        position_obs,
        acc_obs,
        reference_obs,
    ) = sensors
    unused, w, ddq, forces, constants = dynamics
    integrated_ddq, known = integrated
    coupled = _is_coupled(coupling)
    if known:
        _copy(integrated_ddq, ddq)
    elif not coupled:
        _transmission_kernel(theta, dtheta, q, dq, tau, *transmission)
        _dynamics_and_forces_kernel(q, dq, transmission[10], *dynamics)
    else:
        _coupled_link_torque(theta, dtheta, q, dq, tau, no_link, transmission, coupling)
        _copy(coupling.values[8], ddq)
    if known or coupled:
        specific_forces_kernel(q, dq, ddq, w, unused, forces, constants)
    if break_codes(q, dq, theta, dtheta, *limits):
        return False
    _shared_readings(
        theta if elastic else q,
        None,
        enc_std,
        enc_block,
        enc_next,
        np.inf,
        enc_resolution,
        position_reading,
    )
    if has_acc:
        _shared_readings(
            forces, acc_bias, acc_std, acc_block, acc_next, acc_range, acc_resolution, acc_reading
        )
    N, n = q.shape
    length = position_line.shape[0]
    for k in range(N):
        if length > 1:
            oldest = (slot - delay[k]) % length
            for j in range(position_reading.shape[1]):
                position_line[slot, k, j] = position_reading[k, j]
                position_obs[k, j] = position_line[oldest, k, j]
            if has_acc:
                for j in range(acc_reading.shape[1]):
                    acc_line[slot, k, j] = acc_reading[k, j]
                    acc_obs[k, j] = acc_line[oldest, k, j]
        else:
            for j in range(position_reading.shape[1]):
                position_obs[k, j] = position_reading[k, j]
            if has_acc:
                for j in range(acc_reading.shape[1]):
                    acc_obs[k, j] = acc_reading[k, j]
        for j in range(n):
            reference_obs[k, j] = reference[k, 0, j]
            reference_obs[k, n + j] = reference[k, 1, j]
    error, error_rate, torsion = scratch[0], scratch[1], scratch[2]
    for k in range(N):
        for j in range(n):
            error[k, j] = q[k, j] - reference[k, 0, j]
            error_rate[k, j] = dq[k, j] - reference[k, 1, j]
            torsion[k, j] = theta[k, j] - q[k, j]
    _reward_kernel(error, error_rate, tau, previous, rewards[0], torsion, *rewards[1:], reward)
    return True


@njit(cache=True)
def control_period_kernel(command, truncated, bullet, rk4, packed):
    """A control period of every arm up to its end (`post_step_kernel`) in one call, the
    kernels of the step by step path in its order (so bit for bit the same):

    1. the task's open-loop torque at the period's start (`open_loop_torque_kernel` of
       [`elastic_gym.envs.tasks`][elastic_gym.envs.tasks]) added to `command` and clipped
       to the torque limits (`clip_torque`);
    2. the physics of the period: PyBullet's substeps (the simulator's `_period_kernel`,
       `bullet` a `Packed` of its arguments, `rk4` None) or the RK4 (`rk4_period_kernel`,
       `rk4` a `Packed` of its arguments after the torques, `bullet` None), as
       [`ArmSimulator.period_arguments`][elastic_gym.envs.simulator.ArmSimulator.period_arguments]
       gives them; arguments, not packed, so that numba compiles the one form given (a
       compiled layer choosing it would cost another optimisation of all the physics);
    3. the clock (`advance_clock`, `truncated` written when episodes have a length) and
       the torques shifted (previous <- current <- the clipped torque);
    4. the reference at the new time (`reference_kernel` of the tasks).

    `packed`: a `Packed` (`elastic_gym.model.packed`) of the batch's arrays changed
    in place ([`FusedArguments.period`][elastic_gym.envs.packing.FusedArguments.period]).
    Returns (the physics' `bullet_capi` code, whether an arm is truncated); after a code
    other than OK nothing past step 2 has run. (The end of the period is a call of its
    own: compiled into this kernel it would cost each of its variants as much compile time
    again, for 3 us per step.)"""
    (low, high, tau, saturated, external, task_torque, q, n_substeps) = packed.values[:8]
    (steps, dt, max_steps, time, torque, previous, reference, task_reference) = packed.values[8:]
    if open_loop_torque_kernel(time, q, external, task_torque):
        clip_torque(command, external, low, high, tau, saturated)
    else:
        clip_torque(command, None, low, high, tau, saturated)
    code = bullet_capi.OK
    if bullet is not None:  # (numba prunes the test of an argument that is None)
        slot, world, substep, coupling, states = bullet.values
        no_link = substep.values[5]  # the substep pack's (N, 0) array: no link torque
        code = _period_kernel(slot, world, n_substeps, tau, no_link, substep, coupling, states)
    if rk4 is not None:
        theta, dtheta, q, dq, no_ext, period, substeps, ddq, integrator = rk4.values
        rk4_period_kernel(theta, dtheta, q, dq, tau, no_ext, period, substeps, ddq, integrator)
    if code != bullet_capi.OK:
        return code, False
    ended = advance_clock(steps, None, dt, max_steps, time, truncated)
    for k in range(tau.shape[0]):
        for j in range(tau.shape[1]):
            previous[k, j] = torque[k, j]
            torque[k, j] = tau[k, j]
    reference_kernel(time, task_reference, reference)
    return code, ended
