"""Add your own controller and observer to a comparison.

    python examples/custom_controller_and_observer.py [--duration 2.0]

A controller subclasses ``Controller`` (``__call__(obs, info) -> torque``, reading only
``obs["state"]``, ``obs["reference"]``, the public info and its model); an observer
subclasses ``Observer`` (``reset`` and ``update`` from sensor observations and the applied
torque). Both go in a scenario by class (or as ``"module:Class"`` in a YAML file) next to
the built-in ones.
"""

from __future__ import annotations

import argparse

import numpy as np

from elastic_gym.controllers import Controller
from elastic_gym.controllers.invdyn import InverseDynamics, info_time, reference_derivatives
from elastic_gym.evaluation import Scenario, compare
from elastic_gym.observers import Observer


class MotorPDWithTorsionDamping(Controller):
    """Feedforward + motor PD + a damping term on the torsion rate (theta' - q')."""

    name = "motor-pd-torsion-damping"
    applies_to = frozenset({"elastic"})

    def __init__(self, model, dt, kp: float = 2000.0, kd: float = 60.0, kt: float = 20.0):
        super().__init__(model, dt)
        self.gains = (kp, kd, kt)
        self.invdyn = InverseDynamics(model)

    def reset(self, obs, info) -> None:
        self.invdyn.reset()

    def __call__(self, obs, info) -> np.ndarray:
        theta, q, dtheta, dq = self.split_state(obs)
        # (x_d, tau_d) = INVDYN(q_d, ..., q_d^(4)) of De Luca et al. eq. (13)
        x_d, tau_d = self.invdyn(info_time(info), reference_derivatives(info, self.n))
        theta_d, _, dtheta_d, _ = np.split(x_d, 4)
        kp, kd, kt = self.gains
        return tau_d + kp * (theta_d - theta) + kd * (dtheta_d - dtheta) - kt * (dtheta - dq)


class StaticLinkObserver(Observer):
    """Motor encoders + the static link deflection; velocities by exact differences."""

    name = "static-link"
    applies_to = frozenset({"elastic"})

    def reset(self, obs, initial_estimate=None) -> np.ndarray:
        self._theta = self.measured_position(obs)
        return self._estimate(self._theta, np.zeros(self.n))

    def update(self, obs, torque, dt) -> np.ndarray:
        theta = self.measured_position(obs)
        velocity = (theta - self._theta) / dt
        self._theta = theta
        return self._estimate(theta, velocity)

    def _estimate(self, theta: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        q = self.model.static_link_position(theta)
        return np.concatenate([theta, q, velocity, velocity])


def scenario(duration: float) -> Scenario:
    return Scenario.from_dict(
        {
            "name": "custom-example",
            "duration": duration,
            "seeds": [0],
            "envs": [
                {
                    "id": "TwoLinkElastic-v0",
                    "kwargs": {"task": "regulation", "task_options": {"max_move": 0.1}},
                }
            ],
            "controllers": [
                "feedforward-state-feedback",
                {
                    "name": "torsion-damping",
                    "class": MotorPDWithTorsionDamping,
                    "options": {"kt": 20.0},
                },
            ],
            "state_sources": ["deluca", {"name": "static", "class": StaticLinkObserver}],
        }
    )


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=2.0)
    parser.add_argument("--output", default="compare_out/custom-example")
    args = parser.parse_args()
    compare(scenario(args.duration), output_dir=args.output)
