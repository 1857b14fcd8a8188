"""A trained run folder as a controller of the comparison runner (``"trained-policy"``).

The policy sees what it saw in training: ``{"state", "reference"}`` from the same state
source, flattened in the order of Gymnasium's ``FlattenObservation``, normalized with
the saved ``VecNormalize`` statistics, acting every ``decimation`` control periods;
residual runs add their correction to the same classical controller.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from gymnasium import spaces

from elastic_gym.controllers.policy import PolicyController
from elastic_gym.model import RobotModel
from elastic_gym.training.policy_env import SENSORS
from elastic_gym.training.train import load_run


class TrainedPolicyController(PolicyController):
    """``PolicyController`` built from a folder written by ``elastic-gym train``.

    Args:
        model, dt: nominal model and control period of the comparison.
        run: the run folder. ``best``: use the EvalCallback's best model.

    The comparison must feed it the state source it was trained on
    (``state_source``); policies trained on raw ``sensors`` cannot be compared on a
    state source and are refused.
    """

    name = "trained-policy"

    def __init__(self, model: RobotModel, dt: float, run: str | Path, best: bool = False) -> None:
        trained = load_run(run, best=best)
        config = trained.config
        if config.state == SENSORS:
            raise ValueError(
                f"the policy in {run} was trained on raw sensors; only policies trained on a "
                "state source ('true' or an observer) can run in a comparison"
            )
        n = model.n
        state_dim = 4 * n if model.elastic else 2 * n
        space = spaces.Dict({
            "state": spaces.Box(-np.inf, np.inf, (state_dim,), dtype=np.float64),
            "reference": spaces.Box(-np.inf, np.inf, (2 * n,), dtype=np.float64),
        })
        super().__init__(
            model, dt, trained.model, normalization=trained.normalizer,
            preprocess=lambda obs, info: spaces.flatten(space, obs),
            residual=config.residual, residual_scale=config.residual_scale,
            decimation=trained.decimation,
        )
        self.state_source = config.state
        self.run = str(run)
