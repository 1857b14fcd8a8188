"""The act of a deployed policy: one arm's flat policy observation and its memory in, the
action and the new memory out.

An actor holds no per-arm state: whoever runs it (the comparison's policy controller, an
evaluation) keeps each arm's memory — a recurrent policy's hidden and cell state, nothing
for a memoryless one — and passes it back at the next call.

* `OnnxActor`: an exported policy (`elastic-gym export`) through onnxruntime: a graph with
  the observation normalization, the network and the action clipping inside it; nothing
  is unpickled, no Python from the folder runs.
* `SB3Actor`: a stable-baselines3 model with its ``VecNormalize`` statistics, as training
  left them in memory or as a trusted run folder's pickles load them.
* `CallableActor`: any function of the flat observation.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np


class Actor(ABC):
    """Deterministic action (n,) of one arm for its flat observation (size,).

    Attributes:
        observation_size: entries of the observation it takes (the actor's own; a
            privileged critic's entries are not among them).
        action_size: entries of the action it gives.
    """

    observation_size: int
    action_size: int

    def initial_memory(self) -> Any:
        """The memory of an arm at the start of its episode (None: memoryless)."""
        return None

    @abstractmethod
    def act(self, observation: np.ndarray, memory: Any) -> tuple[np.ndarray, Any]:
        """(action (n,) float, the memory after this step) for one arm's observation."""


class CallableActor(Actor):
    """A function ``f(observation (size,)) -> action (n,)`` as a memoryless actor."""

    def __init__(self, function: Callable, observation_size: int, action_size: int) -> None:
        self.function = function
        self.observation_size, self.action_size = observation_size, action_size

    def act(self, observation: np.ndarray, memory: Any) -> tuple[np.ndarray, Any]:
        return np.asarray(self.function(observation), dtype=float).reshape(-1), None


class SB3Actor(Actor):
    """The deterministic ``predict`` of a stable-baselines3 model on one arm's observation,
    normalized with a ``VecNormalize``'s statistics (``normalizer``, or None); a recurrent
    policy's memory is its LSTM states. A model whose critic saw privileged entries the
    actor ignores (a policy with ``privileged_size`` k, `elastic_gym.training.critic`) gets
    the actor's observation with k NaN entries appended: no true state needed."""

    def __init__(self, model: Any, normalizer: Any = None) -> None:
        self.model, self.normalizer = model, normalizer
        self.privileged = int(getattr(model.policy, "privileged_size", 0))
        self.observation_size = int(model.observation_space.shape[0]) - self.privileged
        self.action_size = int(model.action_space.shape[0])

    def initial_memory(self) -> Any:
        return (None, True)  # (LSTM states, episode start)

    def act(self, observation: np.ndarray, memory: Any) -> tuple[np.ndarray, Any]:
        states, starting = memory
        action, states = self.predict(np.asarray(observation, np.float32)[None], states, starting)
        return action[0], (states, False)

    def predict(self, batch: np.ndarray, states: Any, starting: bool) -> tuple[np.ndarray, Any]:
        """Actions (B, n) of the rows of ``batch`` (B, size), SB3's ``predict``."""
        if self.privileged and batch.shape[1] == self.observation_size:
            filler = np.full((len(batch), self.privileged), np.nan, dtype=np.float32)
            batch = np.concatenate([batch, filler], axis=1)
        if self.normalizer is not None and self.normalizer.norm_obs:
            batch = self.normalizer.normalize_obs(batch)
        starts = np.full(len(batch), starting)
        action, states = self.model.predict(
            batch, state=states, episode_start=starts, deterministic=True
        )
        return np.asarray(action, dtype=float), states


class PolicyActor:
    """An `SB3Actor` with one memory, for rollouts of a batch of arms that start
    together: `start` forgets, a call acts on one observation (size,) or a batch (B,
    size)."""

    def __init__(self, model: Any, normalizer: Any = None) -> None:
        self.actor = SB3Actor(model, normalizer)
        self.model, self.normalizer = model, normalizer
        self._memory = self.actor.initial_memory()

    def start(self) -> None:
        self._memory = self.actor.initial_memory()

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float32)
        states, starting = self._memory
        action, states = self.actor.predict(obs if obs.ndim == 2 else obs[None], states, starting)
        self._memory = (states, False)
        return action if obs.ndim == 2 else action[0]


OBSERVATION, HIDDEN, CELL = "observation", "hidden_state", "cell_state"
ACTION, HIDDEN_OUT, CELL_OUT = "action", "hidden_state_out", "cell_state_out"


class OnnxActor(Actor):
    """An exported policy graph run by onnxruntime on one thread (module docstring).

    Inputs ``observation`` (B, size) float32 and, for a recurrent policy, ``hidden_state``
    and ``cell_state`` (layers, B, hidden) float32; outputs ``action`` (B, n) in [-1, 1]
    and the recurrent policy's ``hidden_state_out``, ``cell_state_out``. An arm's memory
    is its (hidden, cell) state, zeros at the start of its episode.

    Args:
        path: the ``.onnx`` file.
    """

    def __init__(self, path: str | Path) -> None:
        try:
            import onnxruntime
        except ImportError as exc:  # pragma: no cover - the optional dependency is missing
            raise ImportError(
                f"running an exported policy needs onnxruntime ({exc}): pip install "
                "'elastic-gym[export]'"
            ) from None

        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = options.inter_op_num_threads = 1  # same numbers anywhere
        self.path = Path(path)
        self.session = onnxruntime.InferenceSession(
            str(self.path), options, providers=["CPUExecutionProvider"]
        )
        inputs = {i.name: i for i in self.session.get_inputs()}
        outputs = [o.name for o in self.session.get_outputs()]
        recurrent = HIDDEN in inputs
        expected_inputs = [OBSERVATION, HIDDEN, CELL] if recurrent else [OBSERVATION]
        expected_outputs = [ACTION, HIDDEN_OUT, CELL_OUT] if recurrent else [ACTION]
        if sorted(inputs) != sorted(expected_inputs) or outputs != expected_outputs:
            raise ValueError(
                f"{self.path}: the graph's inputs {sorted(inputs)} and outputs {outputs} are "
                f"not those of an exported policy ({expected_inputs} -> {expected_outputs})"
            )
        self.observation_size = _fixed(inputs[OBSERVATION].shape[1], self.path, OBSERVATION)
        self.action_size = _fixed(self.session.get_outputs()[0].shape[1], self.path, ACTION)
        self.recurrent_shape: tuple[int, int] | None = None
        if recurrent:
            layers, _, hidden = inputs[HIDDEN].shape
            self.recurrent_shape = (
                _fixed(layers, self.path, HIDDEN),
                _fixed(hidden, self.path, HIDDEN),
            )

    def initial_memory(self) -> Any:
        if self.recurrent_shape is None:
            return None
        layers, hidden = self.recurrent_shape
        zeros = np.zeros((layers, 1, hidden), dtype=np.float32)
        return zeros, zeros.copy()

    def act(self, observation: np.ndarray, memory: Any) -> tuple[np.ndarray, Any]:
        feed = {OBSERVATION: np.asarray(observation, dtype=np.float32).reshape(1, -1)}
        if memory is not None:
            feed[HIDDEN], feed[CELL] = memory
        out = self.session.run(None, feed)
        memory = None if memory is None else (out[1], out[2])
        return out[0][0].astype(float), memory


def _fixed(value: Any, path: Path, name: str) -> int:
    """A fixed dimension of a graph input or output (an export names the batch axis only)."""
    if not isinstance(value, int):
        raise ValueError(f"{path}: the graph's {name} has no fixed size ({value!r})")
    return value
