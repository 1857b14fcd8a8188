"""Size of each reward term for controllers and policies on the same tracking episodes.

    python studies/reward_terms.py [--seeds 0 1 2] [--policy RUN ...]

Rows: eq. (13) on the true state, motor PD (INVDYN feedforward) on the motor encoders
(filtered differences, the comparison's motor-only law), the motor-offset PD of the
policy stack with a zero action (where a pure-RL policy starts), and any trained run
folder (``elastic-gym train``) on the state source it was trained on. Columns: each term
of ``elastic_gym.envs.reward`` per second of episode (the return is their sum times the
episode length), and the link tracking RMS. TwoLinkElastic tracking, 3 s episodes.
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np

from elastic_gym.controllers import Controller, make_controller, public_info
from elastic_gym.controllers.invdyn import reference_derivatives, state_vector
from elastic_gym.envs.reward import TERM_NAMES, reward_terms
from elastic_gym.observers import ObserverWrapper
from elastic_gym.training import ActionConfig, ActionMap

ENV_ID = "elastic_gym/TwoLinkElastic-v0"


class ZeroOffsetPD(Controller):
    """The motor-offset action map with a = 0: tau = kp (q_d - theta) + kd (q_d' - theta')."""

    name = "zero-offset-pd"

    def __init__(self, model, dt) -> None:
        super().__init__(model, dt)
        self.map = ActionMap(ActionConfig(kind="motor-offset"), model)

    def __call__(self, obs, info) -> np.ndarray:
        x = state_vector(obs, 4 * self.n)
        ref = reference_derivatives(info, self.n)
        n = self.n
        return self.map.torque(np.zeros((1, n)), x[None, :n], x[None, 2 * n : 3 * n], ref[None])[0]


def episode_terms(controller: Controller, source: str, seed: int) -> tuple[dict, float]:
    """Each reward term summed over one episode, divided by its duration; tracking RMS."""
    env = ObserverWrapper(gym.make(ENV_ID), source)
    base = env.unwrapped
    obs, info = env.reset(seed=seed)
    controller.reset(obs, public_info(info))
    totals = dict.fromkeys(TERM_NAMES, 0.0)
    previous, errors, done = info["torque"], [], False
    while not done:
        obs, _, terminated, truncated, info = env.step(controller(obs, public_info(info)))
        done = terminated or truncated
        truth, ref = info["true_state"], info["reference"]
        terms = reward_terms(
            base.batch.reward_config,
            base.control_dt,
            (truth["q"] - ref["q"])[None],
            (truth["dq"] - ref["dq"])[None],
            info["torque"][None],
            previous[None],
            base.torque_limit,
            (truth["theta"] - truth["q"])[None],
        )
        previous = info["torque"]
        for name in TERM_NAMES:
            totals[name] += float(terms[name][0])
        errors.append(truth["q"] - ref["q"])
    env.close()
    seconds = info["time"]
    return ({k: v / seconds for k, v in totals.items()}, float(np.sqrt(np.mean(np.square(errors)))))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--policy", nargs="*", default=[], metavar="RUN")
    args = parser.parse_args()
    model = gym.make(ENV_ID).unwrapped.model
    rows = [
        ("eq. (13)", "true", lambda: make_controller("feedforward-state-feedback", model, 1e-3)),
        ("motor PD", "finite-difference", lambda: make_controller("motor-pd", model, 1e-3)),
        ("motor-offset PD, zero action", "true", lambda: ZeroOffsetPD(model, 1e-3)),
    ]
    for run in args.policy:
        law = make_controller("trained-policy", model, 1e-3, policy=run, trust_pickle=True)
        rows.append((f"policy {run}", law.state_source, lambda law=law: law))
    print(f"| controller | state | {' | '.join(TERM_NAMES)} | sum | track RMS [rad] |")
    print("|---|---|" + "---:|" * (len(TERM_NAMES) + 2))
    for label, source, build in rows:
        results = [episode_terms(build(), source, seed) for seed in args.seeds]
        mean = {k: np.mean([r[0][k] for r in results]) for k in TERM_NAMES}
        rms = float(np.sqrt(np.mean([r[1] ** 2 for r in results])))
        cells = " | ".join(f"{mean[k]:.3g}" for k in TERM_NAMES)
        print(f"| {label} | {source} | {cells} | {sum(mean.values()):.4g} | {rms:.2g} |")


if __name__ == "__main__":
    main()
