"""A deployed policy's closed loop on N arms, as the comparison's controller runs it.

The policy sees what it saw in training and acts the same way: every ``decimation``
control periods an arm's actor gets the features of
[`ObservationBuilder`][elastic_gym.policy.observation.ObservationBuilder] (from the state
source, the reference in ``info``, its last action, the residual's last base torque and
its base's state error now), its last ``frames`` feature vectors stacked; at every period
its held action becomes a torque through the same
[`ActionMap`][elastic_gym.policy.actions.ActionMap] (motor PD, residual base, ...).

Per arm: the actor's memory (a recurrent policy's state), the frame stack, the held and
last actions, the call count, the error integral and the rest at the reset; the residual
base is one vector controller of all arms. Each acting arm's actor is called on its own
row, so an arm's numbers do not depend on the other arms of the batch.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from elastic_gym.controllers.vector import ControllerTwin, make_vector_controller
from elastic_gym.policy.actions import check_link_mass_features, link_mass_residual
from elastic_gym.policy.observation import (
    ErrorIntegral,
    ObservationInputs,
    RestAtReset,
    base_state_error,
    check_base_error,
)


def at_bound(action: np.ndarray) -> np.ndarray:
    """Per action row: whether some joint's action is at its bound (|a| >= 1 - 1e-6)."""
    return np.any(np.abs(action) >= 1.0 - 1e-6, axis=-1)


class DeployedLaw:
    """The loop of the module docstring for the arms of ``twin`` (a
    [`VectorPolicy`][elastic_gym.policy.controller.VectorPolicy] whose controller runs a
    deployed policy)."""

    def __init__(self, twin: ControllerTwin[Any]) -> None:
        c = twin.controller
        self.twin, self.c = twin, c
        N, n = twin.n_arms, twin.n
        self.actor = c.policy.actor
        self.base = (
            None if c.base is None else make_vector_controller(c.base, twin.model, twin.dt, N)
        )
        if self.base is not None:
            check_base_error(c.builder.features, self.base)
        self._memory: list[Any] = [self.actor.initial_memory() for _ in range(N)]
        self._calls = np.zeros(N, dtype=np.int64)
        self._action = np.zeros((N, c.map.size))
        self._last_action = np.zeros((N, c.map.size))
        self._last_base = np.zeros((N, n))
        self._base_error = np.zeros((N, twin.state_dim))  # x - x_d of this call's base
        self._frames = np.zeros((N, c.frames, c.builder.size), dtype=np.float32)
        self._previous_motor = np.zeros((N, n))  # encoders at the last call (raw sensors)
        self._acts = np.zeros(N)
        self._at_bound = np.zeros(N)
        self._integral = ErrorIntegral(N, n, c.elastic)
        self._rest = RestAtReset(N, n)
        check_link_mass_features(c.builder.features, c.map.config)
        self._link_mass = link_mass_residual(c.map.config, self.base, N, twin.dt)

    @property
    def diagnostics(self) -> dict[str, np.ndarray]:
        """``saturated_actions``: each arm's share of policy steps since its reset with an
        action at its bound on some joint (`at_bound`)."""
        return {"saturated_actions": self._at_bound / np.maximum(self._acts, 1)}

    def _check_source(self, obs: Mapping) -> None:
        c = self.c
        if c.sensors != ("state" not in obs):
            given = "a state estimate" if c.sensors else "raw sensors"
            state = c.policy.spec.state
            raise ValueError(
                f"the policy in {c.source} was trained on {state!r} but the loop gives "
                f"it {given}: pair it with the state source {state!r}"
            )

    def reset_arms(self, obs: Mapping, info: Mapping, arms: np.ndarray) -> None:
        self._check_source(obs)
        if self.base is not None:
            self.base.reset_arms(obs, info, arms)
        for i in arms:
            self._memory[i] = self.actor.initial_memory()
        self._calls[arms] = 0
        for held in (self._action, self._last_action, self._last_base, self._acts, self._at_bound):
            held[arms] = 0.0
        if self.c.sensors:
            motor = np.asarray(obs["motor_position"], dtype=float)
            self._previous_motor[arms] = motor[arms]
            if self.c.elastic:
                self._rest.latch(arms, motor, self.twin.references(info))
        self._integral.restart(arms, np.broadcast_to(info["time"], (self.twin.n_arms,)))
        if self._link_mass is not None:
            self._link_mass.restart(arms)

    def _inputs(
        self, obs: Mapping, info: Mapping, x: np.ndarray | None, reference: np.ndarray, arms
    ) -> ObservationInputs:
        """The policy's feature inputs of the acting ``arms``: the state (and the error
        integral, advanced to this policy step), or the raw sensors."""
        link_mass = {} if self._link_mass is None else self._link_mass.features()
        inputs = ObservationInputs(
            reference=reference[arms],
            last_action=self._last_action[arms],
            base_torque=self._last_base[arms],
            base_error=self._base_error[arms],
            reset_rest=self._rest.value[arms],
            **{name: value[arms] for name, value in link_mass.items()},
        )
        if x is None:  # raw sensors
            inputs.motor_position = np.asarray(obs["motor_position"], dtype=float)[arms]
            if "acceleration" in obs:
                inputs.acceleration = np.asarray(obs["acceleration"], dtype=float)[arms]
            return inputs
        later = arms[self._calls[arms] > 0]  # the first call is the reset's step
        time = np.broadcast_to(info["time"], (self.twin.n_arms,))
        self._integral.advance(later, x[later], reference[later], time)
        inputs.state = x[arms]
        inputs.error_integral = self._integral.value[arms]
        return inputs

    def _policy_observations(self, features: np.ndarray, arms: np.ndarray) -> np.ndarray:
        """Each acting arm's last ``frames`` feature vectors, flat, oldest first; an arm's
        first frame after its reset fills its whole stack (as in training)."""
        first = self._calls[arms] == 0
        frames = self._frames
        frames[arms[~first], :-1] = frames[arms[~first], 1:]
        frames[arms, -1] = features
        frames[arms[first]] = features[first, None]
        return frames[arms].reshape(len(arms), -1)

    def _motor_state(self, obs: Mapping, x: np.ndarray | None):
        """(theta, theta') of the action map: from the state, or the encoders and their
        backward difference over the control period (raw sensors)."""
        n = self.twin.n
        if not self.c.elastic:
            return None, None
        if x is not None:
            return x[:, :n], x[:, 2 * n : 3 * n]
        theta = np.asarray(obs["motor_position"], dtype=float)
        dtheta = (theta - self._previous_motor) / self.twin.dt
        return theta, dtheta

    def _act(self, policy_obs: np.ndarray, arms: np.ndarray) -> None:
        n = self.actor.action_size
        for k, i in enumerate(arms):
            action, self._memory[i] = self.actor.act(policy_obs[k], self._memory[i])
            if action.shape != (n,) or not np.all(np.isfinite(action)):
                raise ValueError(
                    f"the policy in {self.c.source} must return {n} finite numbers, got {action!r}"
                )
            self._action[i] = action

    def __call__(self, obs: Mapping, info: Mapping) -> np.ndarray:
        c, twin = self.c, self.twin
        reference = twin.references(info)
        x = None if c.sensors else twin.states(obs)
        base = np.zeros((twin.n_arms, twin.n)) if self.base is None else self.base(obs, info)
        sensitivity = None
        if self._link_mass is not None:  # the fit of each arm's first call after its reset
            sensitivity = self._link_mass.after_base(np.flatnonzero(self._calls == 0))
        error = base_state_error(self.base)
        if error is not None:
            self._base_error = error
        acting = np.flatnonzero(self._calls % c.decimation == 0)  # at 1 / (decimation dt)
        if len(acting):
            features = c.builder.build(self._inputs(obs, info, x, reference, acting))
            self._act(self._policy_observations(features, acting), acting)
            self._last_action[acting] = np.clip(self._action[acting], -1.0, 1.0)
            self._acts[acting] += 1
            self._at_bound[acting] += at_bound(self._action[acting])
        self._calls += 1
        self._last_base = base
        theta, dtheta = self._motor_state(obs, x)
        if c.sensors:
            self._previous_motor = np.asarray(obs["motor_position"], dtype=float).copy()
        change = None if self._link_mass is None else self._link_mass.advance(self._action)
        return c.map.torque(self._action, theta, dtheta, reference, base, sensitivity, change)
