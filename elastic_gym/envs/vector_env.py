"""Many arms in one PyBullet world as a native Gymnasium vector env.

``gym.make_vec("elastic_gym/<Id>", num_envs=N, vectorization_mode="vector_entry_point")``
returns an `ArmVectorEnv`: N arms driven by the same
[`ArmBatch`][elastic_gym.envs.batch.ArmBatch] as the single env, every quantity on a leading
arm axis.

* Seeds: ``reset(seed=s)`` seeds arm i with s + i (a list: one seed per arm); arm i is bit
  for bit the single env reset with seed s + i, across autoresets too.
* Autoreset (kwarg ``autoreset_mode``): ``NEXT_STEP`` (Gymnasium's default), ``SAME_STEP``
  (``info["final_obs"]``, ``info["final_info"]``) or ``DISABLED``
  (``reset(options={"reset_mask": mask})``).
* Info: the single env's keys with a leading arm axis and Gymnasium's ``_key`` masks.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from elastic_gym.envs.arm_env import check_kind, validated_actions
from elastic_gym.envs.batch import ArmBatch
from elastic_gym.envs.config import RenderMode
from elastic_gym.envs.signature import with_batch_options
from elastic_gym.robots.spec import RobotSpec
from elastic_gym.validation import checked_count, is_count, option_value


def masked_info(info: dict, mask: np.ndarray) -> dict:
    """Gymnasium's vector info layout: every key gets a boolean mask ``_key``."""
    out = {}
    for key, value in info.items():
        out[key] = masked_info(value, mask) if isinstance(value, dict) else value
        out[f"_{key}"] = mask.copy()
    if "termination_reason" in info:
        out["_termination_reason"] = mask & (info["termination_reason"] != None)  # noqa: E711
    return out


def _generator(seed: object, where: str) -> np.random.Generator:
    """The generator of an integer seed >= 0; ``ValueError`` naming ``where`` otherwise."""
    return seeding.np_random(checked_count(seed, where))[0]


class ArmVectorEnv(VectorEnv):
    """N arms of a robot of the catalog in one PyBullet client.

    Args:
        robot: robot name or a ``RobotSpec``.
        num_envs: number of arms N.
        autoreset_mode: an ``AutoresetMode`` (or its value); default ``NEXT_STEP``.
        max_episode_steps: optional limit in control periods (``gym.make_vec`` passes the
            id's limit); ``episode_time`` (s) is the env's own limit.
        render_mode: ``"rgb_array"`` (one image per arm) or None.
        **kwargs: the options of [`ArmBatch`][elastic_gym.envs.batch.ArmBatch].
    """

    # replaced per instance in __init__ (gymnasium declares metadata per instance)
    metadata: dict[str, Any] = {  # noqa: RUF012
        "render_modes": ["rgb_array"],
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }
    kind: ClassVar[str | None] = None

    @with_batch_options
    def __init__(
        self,
        robot: str | RobotSpec,
        num_envs: int = 1,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        **kwargs,
    ) -> None:
        mode = option_value("autoreset_mode", autoreset_mode, AutoresetMode, prefix="")
        option_value("render_mode", render_mode, RenderMode | None, prefix="")
        if max_episode_steps is not None:
            checked_count(max_episode_steps, "max_episode_steps", 1)
        self.batch = batch = ArmBatch(robot, num_envs, kwargs)
        if max_episode_steps is not None:
            batch.limit_episode(max_episode_steps)
        check_kind(batch, self.kind, "VectorEnv")
        self.num_envs = batch.n_arms
        self.render_mode = render_mode
        self.autoreset_mode = mode
        self.metadata = {
            **self.metadata,
            "autoreset_mode": mode,
            "render_fps": round(1.0 / batch.control_dt),
            "physics_dt": batch.physics_dt,
            "control_dt": batch.control_dt,
            "robot": batch.robot.name,
            "task": batch.task.name,
        }
        self.single_observation_space = batch.single_observation_space
        self.single_action_space = batch.single_action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._all = np.ones(self.num_envs, dtype=bool)

    @property
    def model(self):
        """Nominal RobotModel (what observers and controllers use)."""
        return self.batch.model

    @property
    def control_dt(self) -> float:
        return self.batch.control_dt

    @property
    def torque_limit(self) -> np.ndarray:
        return self.batch.torque_limit

    @property
    def n_joints(self) -> int:
        return self.batch.n_joints

    # ------------------------------------------------------------------ API
    def reset(self, *, seed: int | list | None = None, options: dict | None = None):
        """Reset every arm (or those of ``options["reset_mask"]``); arm i seeded with s + i."""
        batch = self.batch
        batch.check_open()
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        if mask is None:
            mask = self._all
        else:
            mask = np.asarray(mask)
            if mask.dtype != np.bool_ or mask.shape != (self.num_envs,):
                raise ValueError(f"reset_mask must be a bool array of shape ({self.num_envs},)")
        arms = np.flatnonzero(mask)
        seeds = self._seeds(seed)
        generators = {  # checked before anything changes; unseeded arms continue their stream
            i: _generator(seeds[i], f"seed[{i}]" if isinstance(seed, list) else "seed")
            for i in arms
            if seeds[i] is not None
        }
        with batch.generators_kept_on_error(arms):
            for i, generator in generators.items():
                batch.set_generator(int(i), generator)
            batch.reset_arms(arms, options)
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            super().reset(seed=int(seed))
        self._autoreset[arms] = False
        return batch.observation(), masked_info(batch.info(), mask)

    def _seeds(self, seed) -> list:
        N = self.num_envs
        if seed is None:
            return [None] * N
        if is_count(seed, minimum=None):  # a negative one is refused by the arm
            return [int(seed) + i for i in range(N)]
        if not isinstance(seed, (list, tuple, np.ndarray)):
            raise TypeError(
                f"seed must be an integer >= 0, a list of {N} such integers (or None "
                f"per arm) or None, got {seed!r}"
            )
        seeds = list(seed)
        if len(seeds) != N:
            raise ValueError(f"give one seed or {N} seeds, got {len(seeds)}")
        return seeds

    def step(self, actions):
        batch = self.batch
        batch.check_open()
        tau = validated_actions(actions, self.num_envs, batch.n_joints)
        mode = self.autoreset_mode
        disabled = mode is AutoresetMode.DISABLED
        if not (batch.running if disabled else batch.running | self._autoreset).all():
            raise RuntimeError(
                "autoreset is disabled: reset the arms whose episode has ended "
                "(reset(options={'reset_mask': ...})) before stepping them"
                if disabled
                else "call reset() before step()"
            )
        stepping = ~self._autoreset
        reward, terminated, truncated = batch.step(tau, stepping)
        done = terminated | truncated
        pending = np.flatnonzero(self._autoreset)
        if len(pending):  # NEXT_STEP resets (and episodes ended by a wrapper)
            batch.reset_arms(pending)
        if mode is AutoresetMode.NEXT_STEP:
            self._autoreset = done
        else:
            self._autoreset[:] = False
        if mode is AutoresetMode.SAME_STEP and done.any():
            ended = np.flatnonzero(done)
            final = batch.observation()
            final_obs = np.full(self.num_envs, None, dtype=object)
            for i in ended:
                final_obs[i] = {key: value[i] for key, value in final.items()}
            final_info = masked_info(batch.info(), done)
            batch.reset_arms(ended)
            info = masked_info(batch.info(), self._all)
            info.update(
                final_obs=final_obs,
                _final_obs=done.copy(),
                final_info=final_info,
                _final_info=done.copy(),
            )
            return batch.observation(), reward, terminated, truncated, info
        return (
            batch.observation(),
            reward,
            terminated,
            truncated,
            masked_info(batch.info(), self._all),
        )

    def end_episodes(self, arms: np.ndarray) -> None:
        """End the episodes of ``arms`` now (a wrapper terminated them, e.g. on a diverged
        state estimate): they are reset like any ended episode (autoreset or reset_mask)."""
        self.batch.end_episodes(arms)
        if self.autoreset_mode is not AutoresetMode.DISABLED:
            self._autoreset[arms] = True  # reset (not stepped) at the next step

    def render(self):
        if self.render_mode == "rgb_array":
            return tuple(self.batch.render(i) for i in range(self.num_envs))
        return None

    def close_extras(self, **kwargs) -> None:
        self.batch.close()


class ElasticArmVectorEnv(ArmVectorEnv):
    """N arms with elastic joints (the vector twin of ElasticArmEnv)."""

    kind = "elastic"

    def __init__(self, robot: str | RobotSpec = "two_link_elastic", **kwargs) -> None:
        super().__init__(robot, **kwargs)


class RigidArmVectorEnv(ArmVectorEnv):
    """N arms with rigid joints (the vector twin of RigidArmEnv)."""

    kind = "rigid"

    def __init__(self, robot: str | RobotSpec = "two_link_rigid", **kwargs) -> None:
        super().__init__(robot, **kwargs)
