"""The integrators of a simulator's control period: PyBullet's step or the compiled RK4.

`integrator="pybullet"` (the env kwarg) steps the links with PyBullet's first-order
semi-implicit Euler at `physics_dt` and the elastic transmission beside each step (see
[`simulator`][elastic_gym.envs.simulator]); `integrator="rk4"` integrates the whole state
(theta, q, theta', q') of every arm over the control period with the compiled RK4 of
[`elastic_gym.model.integrator`][elastic_gym.model.integrator] (step-size control per
arm, `physics_dt` the largest substep), through the same plants (`PlantArray`). PyBullet
then stays the world (URDF, rendering, GUI, link poses), its joints set to the state when
something reads them (the batch's `control_period_kernel` makes the compiled call of either).
"""

from __future__ import annotations

import numpy as np

from elastic_gym.envs.plant import PlantArray
from elastic_gym.model.integrator import MAX_SUBSTEPS, ArmIntegrator


class RungeKutta:
    """The RK4 of a simulator's arms: its plants, its state arrays (changed in place).

    Args:
        plants: the arms' plants (changed in place between periods: a payload picked up,
            a plant drawn at a reset).
        state: (theta, theta', q, q') (N, n), the simulator's arrays.
        elastic: elastic or rigid joints.
        least: the fewest substeps of a period (the period over `physics_dt`).
    """

    def __init__(
        self, plants: PlantArray, state: tuple[np.ndarray, ...], elastic: bool, least: int
    ) -> None:
        self.plants, self.state, self.elastic = plants, state, elastic
        self.least = int(least)
        self.ddq = np.zeros(state[2].shape)  # q'' at the end of the last period
        self.substeps = np.full(len(state[2]), self.least, dtype=np.int64)
        self._no_link_torque = np.zeros((len(state[2]), 0))
        self._built: tuple | None = None  # (the plants' transmission it holds, integrator)

    @property
    def integrator(self) -> ArmIntegrator:
        """The integrator of the current plants (made again when the plants' flags
        changed: `PlantArray.set` makes a new transmission tuple)."""
        plants = self.plants
        if self._built is None or self._built[0] is not plants.transmission:
            coupling = (
                (plants.SBinv, plants.schur_inertia, plants.ST) if plants.has_coupling else None
            )
            arms = ArmIntegrator(
                plants.chain,
                plants.transmission,
                coupling,
                self.elastic,
                substeps=(self.least, max(self.least, MAX_SUBSTEPS)),
            )
            arms.substeps_now = self.substeps  # the arms' counts live here (snapshots)
            self._built = (plants.transmission, arms)
        return self._built[1]

    def reset(self, arms: np.ndarray) -> None:
        """New episodes of `arms`: their next period starts with the fewest substeps."""
        self.substeps[arms] = self.least

    def step(self, tau: np.ndarray, period: float, link_torque: np.ndarray | None) -> None:
        """Advance every arm by `period` (s) under `tau` and `link_torque` (or None)."""
        theta, dtheta, q, dq = self.state
        self.integrator.step(theta, dtheta, q, dq, tau, period, link_torque, self.ddq)

    def period_arguments(self, period: float) -> tuple:
        """`rk4_period_kernel`'s arguments after the torques: the state, no link torque,
        the period, the substep counts, the final q'' and the integrator's pack."""
        theta, dtheta, q, dq = self.state
        packed = self.integrator.packed
        return theta, dtheta, q, dq, self._no_link_torque, period, self.substeps, self.ddq, packed
