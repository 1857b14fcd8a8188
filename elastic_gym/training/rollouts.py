"""Deterministic rollouts of any callable policy on a policy stack: per-episode return,
link tracking RMS and the share of actions at their bounds, episode after episode on one
env (:func:`evaluate_policy`) or all episodes at once on the arms of one batch
(:func:`evaluate_arms`, the same numbers: arm i of a batch reset with seed s is the single
env reset with seed s + i). A trained run's evaluation
(:func:`~elastic_gym.training.trained.evaluate_run`, the learning curve) runs on the
comparison's loop instead and gives the same :class:`Evaluation`.

Here the tracking RMS of an episode is sqrt(mean_k |e_k|^2) with |e_k| the Euclidean norm
over the joints of the link error e = q - q_d of the true state, whatever state the policy
sees, sampled at the policy steps (the end of each hold window); the comparison's
``track_rms`` samples every control period from the reset on.
:class:`PolicyActor` is the act of a trained SB3 model (duck-typed: no SB3 import here).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from elastic_gym.runtime.parallel import single_threaded

Act = Callable[[np.ndarray], np.ndarray]


@dataclass(frozen=True)
class Evaluation:
    """Deterministic policy on fresh episodes: per-episode return and link tracking RMS
    (rad, module docstring), and the fraction of policy steps with an action at its
    bound on some joint (bang-bang actions)."""

    seeds: tuple[int, ...]
    returns: tuple[float, ...]
    tracking_rms: tuple[float, ...]
    saturated_actions: tuple[float, ...]

    @property
    def mean_return(self) -> float:
        return float(np.mean(self.returns))

    @property
    def rms(self) -> float:
        """Tracking RMS over all episodes' samples (equal lengths: the RMS of the RMS)."""
        return float(np.sqrt(np.mean(np.square(self.tracking_rms))))


def at_bound(action: np.ndarray) -> np.ndarray:
    """Per action row: whether some joint's action is at its bound (|a| >= 1 - 1e-6)."""
    return np.any(np.abs(action) >= 1.0 - 1e-6, axis=-1)


def evaluate_policy(
    env, act: Act, seeds: Iterable[int], start: Callable[[], None] | None = None
) -> Evaluation:
    """Run ``act(obs) -> action`` deterministically on one episode per seed of ``env``;
    ``start()`` (e.g. clearing a recurrent policy's memory) is called at each reset."""
    returns, rms, saturated = [], [], []
    seeds = tuple(int(s) for s in seeds)
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        if start is not None:
            start()
        done, total, errors, bounded = False, 0.0, [], 0
        while not done:
            action = act(obs)
            bounded += bool(at_bound(np.asarray(action)))
            obs, reward, terminated, truncated, info = env.step(action)
            total += float(reward)
            done = terminated or truncated
            if "true_state" in info:
                errors.append(info["true_state"]["q"] - info["reference"]["q"])
        returns.append(total)
        rms.append(
            float(np.sqrt(np.mean(np.sum(np.square(errors), axis=1)))) if errors else float("inf")
        )
        saturated.append(bounded / max(len(errors), 1))
    return Evaluation(seeds, tuple(returns), tuple(rms), tuple(saturated))


def evaluate_arms(envs, act: Act, seed: int, start: Callable[[], None] | None = None) -> Evaluation:
    """One deterministic episode per arm of a policy vector env, all at once.

    ``envs``: a policy stack on N arms with autoreset ``NEXT_STEP``
    (:func:`~elastic_gym.training.policy_env.make_policy_vec_env`); arm i is reset with
    seed ``seed + i``. ``act`` maps the (N, size) observations to (N, n) actions;
    ``start()`` is called after the reset. An arm's results stop at the end of its first
    episode (the autoreset that follows is ignored); stepping stops when every arm's
    episode has ended.

    Runs single-threaded (torch and BLAS), as training does: with 2 threads a matmul
    splits the arms' rows differently, and the episodes amplify the last-bit
    differences into visible changes of the metrics, so the numbers would depend on the
    caller's thread settings.
    """
    with single_threaded():
        return _evaluate_arms(envs, act, seed, start)


def _evaluate_arms(envs, act: Act, seed: int, start: Callable[[], None] | None) -> Evaluation:
    n_arms = envs.num_envs
    obs, _ = envs.reset(seed=int(seed))
    if start is not None:
        start()
    running = np.ones(n_arms, dtype=bool)
    returns = np.zeros(n_arms)
    squared = np.zeros(n_arms)
    samples = np.zeros(n_arms, dtype=int)
    bounded = np.zeros(n_arms)
    while running.any():
        action = np.asarray(act(obs))
        obs, reward, terminated, truncated, info = envs.step(action)
        error = info["true_state"]["q"] - info["reference"]["q"]
        returns[running] += reward[running]
        squared[running] += np.sum(error[running] ** 2, axis=1)
        samples[running] += 1
        bounded[running] += at_bound(action[running])
        running &= ~(terminated | truncated)
    return Evaluation(
        tuple(int(seed) + i for i in range(n_arms)),
        tuple(returns.tolist()),
        tuple(np.sqrt(squared / samples).tolist()),
        tuple((bounded / samples).tolist()),
    )


class PolicyActor:
    """The deterministic policy of a model on a batch of observations, normalized with
    a ``VecNormalize``'s statistics; a recurrent policy's memory restarts at
    :meth:`start`. A model whose critic saw privileged entries the actor ignores (a
    policy with ``privileged_size`` k, :mod:`elastic_gym.training.critic`) gets the
    actor's observation with k NaN entries appended: no true state needed."""

    def __init__(self, model, normalizer=None) -> None:
        self.model, self.normalizer = model, normalizer
        self._memory = None
        self._starting = True

    def start(self) -> None:
        self._memory, self._starting = None, True

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float32)
        batch = self._padded(obs if obs.ndim == 2 else obs[None])
        if self.normalizer is not None and self.normalizer.norm_obs:
            batch = self.normalizer.normalize_obs(batch)
        starts = np.full(len(batch), self._starting)
        action, self._memory = self.model.predict(
            batch, state=self._memory, episode_start=starts, deterministic=True
        )
        self._starting = False
        action = np.asarray(action, dtype=float)
        return action if obs.ndim == 2 else action[0]

    def _padded(self, batch: np.ndarray) -> np.ndarray:
        privileged = getattr(self.model.policy, "privileged_size", 0)
        if privileged and batch.shape[1] == self.model.observation_space.shape[0] - privileged:
            filler = np.full((len(batch), privileged), np.nan, dtype=np.float32)
            return np.concatenate([batch, filler], axis=1)
        return batch
