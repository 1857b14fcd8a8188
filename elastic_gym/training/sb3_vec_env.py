"""stable-baselines3's ``VecEnv`` interface over a Gymnasium vector env of elastic_gym arms.

SB3 expects, in the step that ends an episode, the first observation of the next one,
with the last observation in ``infos[i]["terminal_observation"]`` and
``infos[i]["TimeLimit.truncated"]`` telling a time-out (bootstrapped by the algorithms)
from a termination. `SB3VecEnv` gets there from a vector env with autoreset
``DISABLED``: after each step it resets the arms whose episode ended
(``reset(options={"reset_mask": ended})``), the other arms go on untouched. Put
``VecNormalize`` / ``VecMonitor`` on top as with any SB3 ``VecEnv``.
`ProcessBatches` runs several such batches in worker processes (one per core) as
one ``VecEnv``.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.vec_env import VecEnv

from elastic_gym.runtime.fork_server import start_process
from elastic_gym.runtime.process_pool import main_not_imported, refers_to_main


def _row(obs: Any, i: int) -> Any:
    if isinstance(obs, dict):
        return {key: value[i].copy() for key, value in obs.items()}
    return obs[i].copy()


def _merge(obs: Any, new: Any, rows: np.ndarray) -> Any:
    """``obs`` with the given rows taken from ``new``."""
    if isinstance(obs, dict):
        return {key: _merge(obs[key], new[key], rows) for key in obs}
    out = obs.copy()
    out[rows] = new[rows]
    return out


class SB3VecEnv(VecEnv):
    """An SB3 ``VecEnv`` of the N arms of a Gymnasium vector env (autoreset DISABLED).

    Args:
        env: the vector env (possibly wrapped), created with
            ``autoreset_mode=AutoresetMode.DISABLED``.
        info_keys: per-arm info entries copied into SB3's ``infos`` at every step
            (e.g. for callbacks); nothing else is copied (speed).
    """

    def __init__(self, env: gym.vector.VectorEnv, info_keys: Iterable[str] = ()) -> None:
        mode = env.metadata.get("autoreset_mode")
        if mode is not AutoresetMode.DISABLED:
            raise ValueError(
                f"SB3VecEnv needs a vector env with autoreset_mode=DISABLED "
                f"(it resets ended arms itself), got {mode}"
            )
        self.env = env
        self.info_keys = tuple(info_keys)
        self.render_mode = None
        super().__init__(env.num_envs, env.single_observation_space, env.single_action_space)
        self._actions: np.ndarray | None = None

    # ------------------------------------------------------------------ stepping
    def reset(self):
        seeds = None if all(s is None for s in self._seeds) else list(self._seeds)
        obs, info = self.env.reset(seed=seeds)
        self._reset_seeds()
        self.reset_infos = [self._arm_info(info, i) for i in range(self.num_envs)]
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        obs, reward, terminated, truncated, info = self.env.step(self._actions)
        ended = terminated | truncated
        infos = [self._arm_info(info, i) for i in range(self.num_envs)]
        if ended.any():
            rows = np.flatnonzero(ended)
            for i in rows:
                infos[i]["terminal_observation"] = _row(obs, i)
                infos[i]["TimeLimit.truncated"] = bool(truncated[i] and not terminated[i])
            restarted, reset_info = self.env.reset(options={"reset_mask": ended})
            obs = _merge(obs, restarted, rows)
            for i in rows:
                self.reset_infos[i] = self._arm_info(reset_info, i)
        return obs, np.asarray(reward, dtype=np.float32), ended, infos

    def _arm_info(self, info: dict, i: int) -> dict:
        return {key: info[key][i] for key in self.info_keys if key in info}

    def close(self) -> None:
        self.env.close()

    # ------------------------------------------------------------------ attributes
    def _indices(self, indices: int | Iterable[int] | None) -> Sequence[int]:
        if indices is None:
            return range(self.num_envs)
        return [indices] if isinstance(indices, int) else list(indices)

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        """The vector env's attribute (shared by every arm), once per requested arm."""
        value = getattr(self.env, attr_name)
        return [value for _ in self._indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        setattr(self.env.unwrapped, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs):
        result = getattr(self.env, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices=None) -> list[bool]:
        return [False for _ in self._indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None for _ in range(self.num_envs)]


def _batch_worker(parent: int, remote, parent_remote, factory) -> None:
    """Serve one `SB3VecEnv` (a batch of arms) in a worker process (``parent``: the pid
    of its parent process, unused: it ends when its pipe closes)."""
    parent_remote.close()
    venv = factory.var()
    try:
        while True:
            command, data = remote.recv()
            if command == "step":
                venv.step_async(data)
                remote.send(venv.step_wait())
            elif command == "reset":
                venv._seeds = data
                remote.send((venv.reset(), venv.reset_infos))
            elif command == "spaces":
                remote.send((venv.num_envs, venv.observation_space, venv.action_space))
            elif command == "get_attr":
                remote.send(venv.get_attr(data, [0])[0])
            elif command == "close":
                venv.close()
                remote.send(None)
                break
    except (EOFError, KeyboardInterrupt):
        venv.close()


def _concatenate(parts: list) -> Any:
    if isinstance(parts[0], dict):
        return {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}
    return np.concatenate(parts)


class ProcessBatches(VecEnv):
    """Several batches of arms, one per worker process, as one SB3 ``VecEnv``.

    For machines with more cores than one batch can use: each factory builds an
    `SB3VecEnv` (a PyBullet world of arms) inside its own process; the arms of all
    batches are concatenated in order. Factories must be picklable (cloudpickle).
    """

    def __init__(self, factories: list) -> None:
        import multiprocessing

        from stable_baselines3.common.vec_env.base_vec_env import CloudpickleWrapper

        # a script without a __main__ guard must not run again in the workers
        main = refers_to_main(factories)
        self.remotes, self.processes = [], []
        for factory in factories:
            remote, work_remote = multiprocessing.Pipe()
            args = (work_remote, remote, CloudpickleWrapper(factory))
            with contextlib.nullcontext() if main else main_not_imported():
                process = start_process(_batch_worker, args)
            work_remote.close()
            self.remotes.append(remote)
            self.processes.append(process)
        sizes = []
        for remote in self.remotes:
            remote.send(("spaces", None))
            size, observation_space, action_space = remote.recv()
            sizes.append(size)
        self.bounds = np.cumsum([0, *sizes])
        self.render_mode = None
        self.closed = False
        super().__init__(int(self.bounds[-1]), observation_space, action_space)

    def _parts(self, values) -> list:
        return [values[a:b] for a, b in zip(self.bounds[:-1], self.bounds[1:], strict=True)]

    def reset(self):
        for remote, seeds in zip(self.remotes, self._parts(self._seeds), strict=True):
            remote.send(("reset", list(seeds)))
        results = [remote.recv() for remote in self.remotes]
        self._reset_seeds()
        self.reset_infos = [info for _, infos in results for info in infos]
        return _concatenate([obs for obs, _ in results])

    def step_async(self, actions: np.ndarray) -> None:
        for remote, part in zip(self.remotes, self._parts(np.asarray(actions)), strict=True):
            remote.send(("step", part))

    def step_wait(self):
        results = [remote.recv() for remote in self.remotes]
        obs, rewards, dones, infos = zip(*results, strict=True)
        return (
            _concatenate(list(obs)),
            np.concatenate(rewards),
            np.concatenate(dones),
            [info for part in infos for info in part],
        )

    def close(self) -> None:
        if self.closed:
            return
        for remote in self.remotes:
            remote.send(("close", None))
            remote.recv()
        for process in self.processes:
            process.join()
        self.closed = True

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        if attr_name == "render_mode":
            return [None for _ in self._get_indices(indices)]
        self.remotes[0].send(("get_attr", attr_name))
        value = self.remotes[0].recv()
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        raise NotImplementedError("ProcessBatches does not set attributes in its workers")

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs):
        raise NotImplementedError("ProcessBatches does not call methods in its workers")

    def env_is_wrapped(self, wrapper_class: type, indices=None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None for _ in range(self.num_envs)]
