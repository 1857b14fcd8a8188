"""Distillation of the privileged plant teacher into a recurrent raw-sensor policy: DAgger
(Ross, Gordon & Bagnell, AISTATS 2011) trains a RecurrentPPO policy instead of RL.

Iteration i runs one episode on every training arm (``episodes`` rounds of them). A share
beta_i = ``teacher_mix`` ** i of the arms acts with the teacher's action
([`PlantTeacher`][elastic_gym.training.teacher.PlantTeacher]), the others with the student's
deterministic one; every step is labelled with the teacher's action. The student, the
RecurrentPPO actor (its LSTM, MLP and Gaussian mean), is then fitted to all the labels
collected so far: mean squared error over whole episodes (backpropagation through time
from each episode's start), ``steps`` Adam steps at ``learning_rate`` (annealed along a
cosine to ``final_learning_rate`` over each fit, if given) on minibatches of
``batch_size`` episodes drawn at random. An arm's steps after its first episode ends are not used.
Observations are stored raw and normalized with the run's ``VecNormalize`` statistics at
each fit (the statistics keep updating while the arms run).
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from elastic_gym.training.teacher import LABEL
from elastic_gym.validation import ConfigModel, PositiveFinite


class DistillConfig(ConfigModel):
    """The ``distill`` hyper-parameter (module docstring).

    Attributes:
        iterations: DAgger iterations.
        episodes: rounds of one episode on every arm per iteration.
        steps: Adam steps per fit. batch_size: episodes per Adam step.
        learning_rate: Adam's learning rate (at the start of each fit).
        final_learning_rate: if given, each fit's learning rate follows a cosine from
            ``learning_rate`` down to it over the fit's steps (Loshchilov & Hutter,
            ICLR 2017, without restarts within a fit): the fit ends near a minimum
            instead of wherever the last steps of constant size left it.
        teacher_mix: the share of arms the teacher drives at iteration i is
            ``teacher_mix ** i`` (all of them at the first).
    """

    section = "distill"
    iterations: int = Field(8, ge=1)
    episodes: int = Field(1, ge=1)
    steps: int = Field(500, ge=1)
    batch_size: int = Field(16, ge=1)
    learning_rate: PositiveFinite = 1e-3
    final_learning_rate: PositiveFinite | None = None
    teacher_mix: float = Field(0.5, ge=0.0, le=1.0)


class Episodes:
    """Raw observations (T, A, D), teacher labels (T, A, n) and the mask of steps used
    (T, A), collected round by round (one episode per arm)."""

    def __init__(self) -> None:
        self.rounds: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def add(self, obs: np.ndarray, labels: np.ndarray, mask: np.ndarray) -> None:
        self.rounds.append((obs, labels, mask))

    @property
    def steps(self) -> int:
        """Policy steps collected (every arm's steps, all rounds)."""
        return sum(obs.shape[0] * obs.shape[1] for obs, _, _ in self.rounds)

    def arms(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Every collected episode as (obs (T, D), labels (T, n), mask (T,))."""
        return [
            (obs[:, a], labels[:, a], mask[:, a])
            for obs, labels, mask in self.rounds
            for a in range(obs.shape[1])
        ]


def collect(model, venv, teacher_arms: np.ndarray) -> tuple[np.ndarray, ...]:
    """One round: every arm of ``venv`` (a ``VecNormalize`` over the training arms with
    the teacher's labels in its infos) from a reset to the end of its episode; arms where
    ``teacher_arms`` is set act with the teacher's action, the others with the student's.
    Returns raw observations, labels and the mask of steps in each arm's first episode."""
    obs = venv.reset()
    label = np.stack([info[LABEL] for info in venv.unwrapped.reset_infos])
    raws, labels, masks = [], [], []
    running = np.ones(venv.num_envs, dtype=bool)
    state, starts = None, np.ones(venv.num_envs, dtype=bool)
    while running.any():
        raws.append(venv.get_original_obs())
        labels.append(label)
        masks.append(running.copy())
        student, state = model.predict(obs, state=state, episode_start=starts, deterministic=True)
        actions = np.where(teacher_arms[:, None], np.clip(label, -1.0, 1.0), student)
        obs, _, dones, infos = venv.step(actions)
        label = np.stack([info[LABEL] for info in infos])
        running &= ~dones
        starts = dones
    return np.stack(raws), np.stack(labels), np.stack(masks)


def _padded(rows: np.ndarray, length: int) -> np.ndarray:
    """``rows`` (T, ...) with zero rows appended up to ``length``."""
    return np.concatenate([rows, np.zeros((length - len(rows), *rows.shape[1:]), rows.dtype)])


def fit(model, normalizer, episodes: Episodes, config: DistillConfig, rng) -> float:
    """``steps`` Adam steps of the student's mean action on the collected episodes
    (module docstring); returns the mean squared error per entry of the last tenth."""
    import torch

    policy = model.policy
    data = episodes.arms()
    length = max(len(mask) for _, _, mask in data)  # rounds end with their longest episode
    obs = np.stack([_padded(normalizer.normalize_obs(o), length) for o, _, _ in data])
    labels = np.stack([_padded(label, length) for _, label, _ in data])  # (E, T, n)
    masks = np.stack([_padded(mask, length) for _, _, mask in data]).astype(np.float32)
    optimizer = torch.optim.Adam(policy.parameters(), lr=config.learning_rate)
    final = config.final_learning_rate
    schedule = (
        None
        if final is None
        else torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, config.steps, final)
    )
    lstm = policy.lstm_actor
    n_seq, length = min(config.batch_size, len(data)), obs.shape[1]
    zeros = torch.zeros(lstm.num_layers, n_seq, lstm.hidden_size)
    starts = torch.zeros(n_seq * length)  # zero initial states: each episode's start
    losses = []
    for _ in range(config.steps):
        chosen = rng.choice(len(data), n_seq, replace=False)
        batch = torch.as_tensor(obs[chosen].reshape(n_seq * length, -1), dtype=torch.float32)
        distribution, _ = policy.get_distribution(batch, (zeros, zeros), starts)
        mean = distribution.distribution.mean.reshape(n_seq, length, -1)
        target = torch.as_tensor(labels[chosen], dtype=torch.float32)
        mask = torch.as_tensor(masks[chosen])[..., None]
        loss = (mask * (mean - target) ** 2).sum() / (mask.sum() * target.shape[-1])
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        if schedule is not None:
            schedule.step()
        losses.append(loss.item())
    return float(np.mean(losses[-max(1, config.steps // 10) :]))


def check_distill(config, settings, action_kind: str) -> None:
    """Refuse a ``distill`` hyper-parameter the run ``config`` (a
    [`TrainConfig`][elastic_gym.training.config.TrainConfig] with its resolved ``settings``
    and its action's ``kind``) cannot use, before anything is built: it needs RecurrentPPO,
    the ``motor-offset`` action (the teacher's) and a batch of arms, and it replaces RL
    training (a run's total steps are refused; the hyper-parameter ``n_timesteps`` is not
    used)."""
    if settings.distill is None:
        return
    algo, total_steps = config.algo, config.total_steps
    problems = []
    if algo != "recurrentppo":
        problems.append(f"the algo recurrentppo (the student is its LSTM actor), not {algo!r}")
    if action_kind != "motor-offset":
        problems.append(f"the action kind 'motor-offset' (the teacher's), not {action_kind!r}")
    if settings.n_envs < 2:
        problems.append("a batch of arms: n_envs > 1")
    if total_steps is not None:
        problems.append("no total steps: the run trains by imitation only")
    if problems:
        raise ValueError("distill needs " + "; ".join(problems))


def distill(
    model, venv, config: DistillConfig, seed: int, after_iteration=None, progress: bool = False
) -> list[float]:
    """Run the DAgger iterations of the module docstring on ``model`` (a RecurrentPPO
    whose env ``venv`` carries the teacher's labels); ``after_iteration(policy_steps)`` is
    called after each fit with the policy steps collected so far (``model.num_timesteps``
    is set to them). Returns each iteration's fit loss."""
    from rich.progress import Progress

    rng = np.random.default_rng(seed)
    episodes = Episodes()
    losses: list[float] = []
    with Progress(disable=not progress, transient=False) as bar:
        task = bar.add_task("distillation (DAgger iterations)", total=config.iterations)
        for i in range(config.iterations):
            beta = config.teacher_mix**i
            for _ in range(config.episodes):
                teacher_arms = rng.random(venv.num_envs) < beta
                episodes.add(*collect(model, venv, teacher_arms))
            losses.append(fit(model, venv, episodes, config, rng))
            model.num_timesteps = episodes.steps
            if after_iteration is not None:
                after_iteration(episodes.steps)
            bar.advance(task)
    return losses
