"""The integrator's error against its step, and the choice of the method, in numbers.

    python benchmarks/integrator_order.py            # every elastic arm, 3 s motions
    python benchmarks/integrator_order.py --quick    # 0.5 s motions

For each elastic arm, a 3 s closed loop at the 1 ms control period (a motor PD with
gravity compensation along a smooth motion, computed from each integration's own state,
so the loop stays bounded) is integrated by:

* the reference: scipy's DOP853 (rtol 1e-12, atol 1e-14) restarted at every period;
* the package's RK4 with step-size control (the default tolerances: what an env steps);
* fixed-step explicit Runge-Kutta methods of orders 3, 4 and 5 over the same right-hand
  side (`ArmIntegrator.derivative`, the compiled model), at 1, 2 and 4 steps per period:
  Bogacki-Shampine 3(2) (3 new evaluations per step, first same as last), the classical
  RK4 with its free third-order companion (4 new evaluations: the derivative at the new
  state is the next step's first and gives the period's q''), Dormand-Prince 5(4)
  (6 new evaluations).

The table gives each one's largest link position error over the motion, the evaluations
of the right-hand side per control period and, for the fixed steps, the observed order
log2(error(h) / error(h / 2)).
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import pinocchio as pin
from scipy.integrate import solve_ivp
from timing import machine_line, print_table

from elastic_gym.envs.plant import PlantArray
from elastic_gym.model import RobotModel
from elastic_gym.model.integrator import ArmIntegrator
from elastic_gym.robots.catalog import get_robot

PERIOD = 1e-3
ROBOTS = ("two_link_elastic", "kr15_elastic", "iiwa_elastic")

# Butcher tableaus (a, b, c) of the fixed-step methods; each FSAL: the last stage is f(x+).
BS3 = (
    [[], [1 / 2], [0, 3 / 4], [2 / 9, 1 / 3, 4 / 9]],
    [2 / 9, 1 / 3, 4 / 9, 0],
)
RK4 = ([[], [1 / 2], [0, 1 / 2], [0, 0, 1]], [1 / 6, 1 / 3, 1 / 3, 1 / 6])
DP5 = (
    [
        [],
        [1 / 5],
        [3 / 40, 9 / 40],
        [44 / 45, -56 / 15, 32 / 9],
        [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729],
        [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656],
        [35 / 384, 0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84],
    ],
    [35 / 384, 0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0],
)
METHODS = {"BS3(2)": (BS3, 3, 3), "RK4(3)": (RK4, 4, 4), "DP5(4)": (DP5, 6, 5)}


class Loop:
    """The closed loop of the check: tau = g(q_d) + K (theta_d - theta) - K_D theta'."""

    def __init__(self, model: RobotModel) -> None:
        spec, self.model = model.spec, model
        low, high = np.asarray(spec.workspace_low), np.asarray(spec.workspace_high)
        self.middle, self.amplitude = 0.5 * (low + high), 0.25 * (high - low)
        self.kd = np.sqrt(model.K * model.B)

    def reference(self, t: float) -> np.ndarray:
        return self.middle + 0.5 * self.amplitude * np.sin(np.pi * t + np.arange(self.model.n))

    def initial_state(self) -> np.ndarray:
        q = self.reference(0.0)
        return np.concatenate([self.model.static_motor_position(q), q, np.zeros(2 * len(q))])

    def torque(self, t: float, x: np.ndarray) -> np.ndarray:
        n, model = self.model.n, self.model
        q_d = self.reference(t)
        gravity = model.gravity(q_d)
        return gravity + model.K * (q_d + gravity / model.K - x[:n]) - self.kd * x[2 * n : 3 * n]


def reference(model: RobotModel, loop: Loop, steps: int) -> np.ndarray:
    """DOP853 of the model from pinocchio (block system [[B, S^T], [S, M]])."""
    data, n = model.pin_model.createData(), model.n

    def rhs(x, tau):
        theta, q, dtheta, dq = x[:n], x[n : 2 * n], x[2 * n : 3 * n], x[3 * n :]
        tau_j = model.K * (theta - q) + model.D * (dtheta - dq)
        M = pin.crba(model.pin_model, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        nle = pin.nonLinearEffects(model.pin_model, data, q, dq)
        inertia = np.block([[np.diag(model.B), model.S.T], [model.S, M]])
        acc = np.linalg.solve(inertia, np.concatenate([tau - tau_j, tau_j - nle]))
        return np.concatenate([dtheta, dq, acc])

    x, states = loop.initial_state(), []
    for s in range(steps):
        tau = loop.torque(s * PERIOD, x)
        x = solve_ivp(
            lambda t, y, tau=tau: rhs(y, tau),
            (0.0, PERIOD),
            x,
            method="DOP853",
            rtol=1e-12,
            atol=1e-14,
        ).y[:, -1]
        states.append(x)
    return np.array(states)


def integrator(model: RobotModel, substeps=(1, 256)) -> ArmIntegrator:
    plants = PlantArray([model])
    coupling = (plants.SBinv, plants.schur_inertia, plants.ST) if plants.has_coupling else None
    return ArmIntegrator(plants.chain, plants.transmission, coupling, True, None, substeps)


def controlled(model: RobotModel, loop: Loop, steps: int) -> tuple[np.ndarray, float]:
    """The package's RK4 with step-size control: states and substeps per period."""
    arms, n = integrator(model), model.n
    x = loop.initial_state()[None]
    theta, q, dtheta, dq = (x[:, i * n : (i + 1) * n].copy() for i in range(4))
    states, work = [], 0
    for s in range(steps):
        tau = loop.torque(s * PERIOD, np.concatenate([theta, q, dtheta, dq], axis=1)[0])
        work += arms.step(theta, dtheta, q, dq, tau[None], PERIOD)
        states.append(np.concatenate([theta, q, dtheta, dq], axis=1)[0])
    return np.array(states), work / steps


def fixed(model: RobotModel, loop: Loop, steps: int, tableau, per_period: int) -> np.ndarray:
    """A fixed-step explicit Runge-Kutta method over the compiled right-hand side."""
    a, b = tableau
    rhs_of, n = integrator(model), model.n

    def f(x, tau):
        parts = [np.ascontiguousarray(x[None, i * n : (i + 1) * n]) for i in range(4)]
        return rhs_of.derivative(parts[0], parts[2], parts[1], parts[3], tau[None])[0]

    x, states, h = loop.initial_state(), [], PERIOD / per_period
    for s in range(steps):
        tau = loop.torque(s * PERIOD, x)
        for _ in range(per_period):
            k = [f(x, tau)]
            for row in a[1:]:
                k.append(f(x + h * sum(c * kj for c, kj in zip(row, k, strict=True)), tau))
            x = x + h * sum(w * kj for w, kj in zip(b, k, strict=True))
        states.append(x)
    return np.array(states)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    duration = 0.5 if args.quick else 3.0
    steps = round(duration / PERIOD)
    print(machine_line())
    rows = []
    for robot in ROBOTS:
        model = RobotModel(get_robot(robot))
        loop = Loop(model)
        exact = reference(model, loop, steps)
        n = model.n

        def error(states, exact=exact, n=n):
            return float(np.abs(states - exact)[:, n : 2 * n].max())

        states, substeps = controlled(model, loop, steps)
        label, work = "RK4(3), step-size control", f"{substeps * 4 + 1:.2f}"
        rows.append([robot, label, work, f"{error(states):.2e}", ""])
        for name, (tableau, evaluations, _) in METHODS.items():
            previous = None
            for per_period in (1, 2, 4):
                e = error(fixed(model, loop, steps, tableau, per_period))
                order = "" if previous is None else f"{math.log2(previous / e):.2f}"
                label = f"{name}, h = 1/{per_period} ms"
                rows.append([robot, label, str(evaluations * per_period + 1), f"{e:.2e}", order])
                previous = e
    print_table(
        f"Link position error against DOP853 over {duration:g} s at the 1 ms control period",
        ["arm", "method", "evaluations per period", "max |q - q_ref| [rad]", "order"],
        rows,
    )


if __name__ == "__main__":
    main()
