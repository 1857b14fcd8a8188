"""Deterministic rollouts of any callable policy on a policy stack: per-episode return,
link tracking RMS and the share of actions at their bounds, episode after episode on one
env (`evaluate_policy`) or all episodes at once on the arms of one batch
(`evaluate_arms`, the same numbers: arm i of a batch reset with seed s is the single
env reset with seed s + i). A trained run's evaluation
([`evaluate_run`][elastic_gym.training.trained.evaluate_run], the learning curve) runs on the
comparison's loop instead and gives the same `Evaluation`.

Here the tracking RMS of an episode is sqrt(mean_k |e_k|^2) with |e_k| the Euclidean norm
over the joints of the link error e = q - q_d of the true state, whatever state the policy
sees, sampled at the policy steps (the end of each hold window); the comparison's
``track_rms`` samples every control period from the reset on.
`PolicyActor` (of `elastic_gym.policy.actors`) is the act of a trained SB3 model.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from elastic_gym.policy.deployed_law import at_bound
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
    ([`build_policy_env`][elastic_gym.policy.builder.build_policy_env]); arm i is reset with
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
