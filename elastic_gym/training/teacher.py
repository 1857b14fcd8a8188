"""A privileged teacher for distilling a raw-sensor policy
([`elastic_gym.training.distill`][elastic_gym.training.distill]).

The teacher knows what no policy may: each arm's simulated plant. Its action for the policy step
starting at control period k is the mean over the step's ``hold`` periods of

    a_j = motor_offset_action(tau_d(t_j), theta_d(t_j - delta), theta_d'(t_j - delta), ref(t_j)),

the ``motor-offset`` action whose 1 kHz motor PD applies INVDYN's torque tau_d at the desired motor
state ([`motor_offset_action`][elastic_gym.policy.actions.ActionMap.motor_offset_action]; De Luca,
Schroeder & Thuemmel 2007, Sec. V-B: x_d, tau_d from q_d .. q_d^(4)), with INVDYN of the arm's exact
plant model (its drawn link masses and inertias, K, B, D, unmodelled friction and payload) and delta
its sensor delay (the PD sees delayed encoders). The labels are open loop: they depend on the task
and the plant, not on the state the student reaches.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from elastic_gym.controllers.invdyn import InverseDynamics
from elastic_gym.policy.vector import _ArmResets, elastic_batch, wrapper_attribute
from elastic_gym.validation import checked_count

BLOCK = 256  # control periods planned at a time
LABEL = "teacher_action"  # the info key


class _ArmPlan:
    """One arm's teacher actions a_j (module docstring) from its reset on, planned ahead
    in blocks of `BLOCK` control periods."""

    def __init__(self, batch: Any, arm: int, action_map) -> None:
        settings = batch.settings[arm]
        self.invdyn = InverseDynamics(batch.resolver.plant_model(settings))
        self.task, self.arm, self.map = batch.task, arm, action_map
        self.delay = int(settings.sensor_delay)
        self.start, self.dt = float(batch.time[arm]), batch.control_dt
        n = batch.n_joints
        self.motor = np.zeros((0, 2 * n))  # theta_d, theta_d' at every period planned
        self.actions = np.zeros((0, n))

    def index(self, time: float) -> int:
        return round((time - self.start) / self.dt)

    def mean(self, k: int, hold: int) -> np.ndarray:
        """The mean of a_k .. a_(k + hold - 1)."""
        while len(self.actions) < k + hold:
            self._plan()
        return self.actions[k : k + hold].sum(axis=0) / hold  # np.mean's arithmetic

    def _plan(self) -> None:
        first, n = len(self.actions), self.map.n
        times = self.start + self.dt * np.arange(first, first + BLOCK)
        refs = self.task.reference(times, np.full(BLOCK, self.arm))
        x_d, tau_d = self.invdyn.trajectory(times, refs)
        self.motor = np.concatenate([self.motor, np.hstack([x_d[:, :n], x_d[:, 2 * n : 3 * n]])])
        seen = np.clip(np.arange(first, first + BLOCK) - self.delay, 0, None)  # delayed encoders
        motor = self.motor[seen]
        actions = self.map.motor_offset_action(tau_d, motor[:, :n], motor[:, n:], refs)
        self.actions = np.concatenate([self.actions, actions])


class PlantTeacher(_ArmResets):
    """``info["teacher_action"]`` (N, n): every arm's teacher action (module docstring) for
    the policy step that starts now, ``hold`` control periods long.

    Args:
        env: a vector policy stack with the ``motor-offset`` action
            ([`build_policy_env`][elastic_gym.policy.builder.build_policy_env]); the labels
            are those of the policy step that starts after each reset or step.
        hold: control periods per policy step (the run's decimation).
    """

    def __init__(self, env: gym.vector.VectorEnv, hold: int) -> None:
        super().__init__(env)
        self.hold = checked_count(hold, "hold", 1)
        self.map = wrapper_attribute(env, "map")
        if self.map.config.kind != "motor-offset":
            raise ValueError(
                f"the plant teacher gives motor-offset actions, not {self.map.config.kind!r} "
                "(action kind 'motor-offset')"
            )
        self._plans: list[_ArmPlan | None] = [None] * self.num_envs

    def _restart(self, arms: np.ndarray) -> None:
        batch = elastic_batch(self.env)
        for arm in np.asarray(arms).tolist():
            self._plans[arm] = _ArmPlan(batch, arm, self.map)

    def _labelled(self, info: dict) -> dict:
        time = elastic_batch(self.env).time
        rows = []
        for arm, plan in enumerate(self._plans):
            assert plan is not None
            rows.append(plan.mean(plan.index(float(time[arm])), self.hold))
        info[LABEL] = np.asarray(rows)
        return info

    def reset(self, *, seed=None, options: dict | None = None):
        obs, info = self.env.reset(seed=seed, options=options)
        self._restart(self._reset_arms(options))
        return obs, self._labelled(info)

    def step(self, actions):
        obs, reward, terminated, truncated, info = self.env.step(actions)
        self._restart(self._restarted(terminated, truncated))
        return obs, reward, terminated, truncated, self._labelled(info)
