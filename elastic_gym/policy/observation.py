"""What a policy sees: a flat vector of scaled features, built on arrays with a leading
arm axis (N arms).

Features (`ObservationConfig`, in this order when selected; n joints, m
accelerometers): ``error``, ``error_rate`` and ``error_integral`` (`ErrorIntegral`,
the integral action's information) of the state source, ``reference``
(q_d .. q_d^(k-1), scaled per order), ``preview`` (q_d(t + h) - q_d(t) for horizons h),
``torsion`` and ``torsion_rate`` (elastic state), ``motor_error``, ``reset_rest``
(`RestAtReset`) and ``acceleration`` (raw sensors), ``last_action``,
``base_torque``, ``base_motor_error`` (residual: the motor half of the base's x - x_d of
eq. (13), zero on the nominal plant while it tracks), ``link_mass_estimate`` and
``link_mass_fit`` (a residual's link-mass scales, and those its base's motor error showed
at the reset). The reference and its preview are no measurement: the task defines them.
`TrueStateFeatures` computes the state features of the true state, what a
privileged critic sees (`elastic_gym.training.critic`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np
from pydantic import AfterValidator, Field, StrictBool, StrictInt

from elastic_gym.validation import ConfigModel, PositiveFinite, distinct

FEATURES = (
    "error",
    "error_rate",
    "error_integral",
    "reference",
    "preview",
    "torsion",
    "torsion_rate",
    "motor_error",
    "reset_rest",
    "acceleration",
    "last_action",
    "base_torque",
    "base_motor_error",
    "link_mass_estimate",
    "link_mass_fit",
)
STATE_FEATURES = frozenset({"error", "error_rate", "error_integral", "torsion", "torsion_rate"})
TRUE_STATE_FEATURES = ("error", "error_rate", "torsion", "torsion_rate")  # memoryless
ELASTIC_FEATURES = frozenset(
    {
        "torsion",
        "torsion_rate",
        "motor_error",
        "reset_rest",
        "base_motor_error",
        "link_mass_fit",
    }
)
RESIDUAL_FEATURES = frozenset(
    {"base_torque", "base_motor_error", "link_mass_estimate", "link_mass_fit"}
)
SENSOR_FEATURES = frozenset({"motor_error", "reset_rest", "acceleration"})
GRAVITY = 9.81


def _in_order(features: tuple[str, ...] | None) -> tuple[str, ...] | None:
    """Features repeat nowhere and are kept in the order of `FEATURES`."""
    distinct(features or (), "observation feature(s)")
    return features and tuple(f for f in FEATURES if f in features)


class ObservationConfig(ConfigModel):
    """Which features the policy sees and their scales (module docstring).

    ``features=None`` selects the defaults of `default_features` for the state
    source and action kind; ``full_state`` adds ``torsion_rate`` to that selection on
    elastic arms, so that the state features hold the whole state (q, theta, q',
    theta') relative to the reference (without it theta' is unseen; explicit
    ``features`` are taken as given). ``frames`` > 1: the actor sees the last ``frames`` feature
    vectors of a state source, oldest first (memory without a recurrent policy; raw sensors
    are stacked by the run's ``frame_stack`` instead).
    """

    section = "observation"
    features: Annotated[
        tuple[Literal[FEATURES], ...] | None,  # type: ignore[valid-type]
        Field(min_length=1),
        AfterValidator(_in_order),
    ] = None
    reference_order: StrictInt = Field(2, ge=0, le=4)
    preview: tuple[PositiveFinite, ...] = ()  # horizons (s)
    error_scale: PositiveFinite = 0.01
    error_rate_scale: PositiveFinite = 0.1
    error_integral_scale: PositiveFinite = 1e-3  # rad s
    torsion_scale: PositiveFinite = 0.05
    torsion_rate_scale: PositiveFinite = 1.0
    preview_scale: PositiveFinite = 0.1
    frames: StrictInt = Field(1, ge=1)  # a state source's last feature vectors, oldest first
    full_state: StrictBool = False  # the default selection with torsion_rate (elastic)


def default_features(
    sensors: bool, elastic: bool, residual: bool, preview: bool, full_state: bool = False
) -> tuple[str, ...]:
    """The default selection: tracking error and rate, reference (and preview), torsion
    (and with ``full_state`` its rate), last action (state sources); motor error and
    accelerations instead of the state features on raw sensors; the base torque for
    residual policies."""
    chosen = {"reference", "last_action"}
    if sensors:
        chosen |= {"motor_error", "acceleration"} if elastic else {"motor_error"}
    else:
        chosen |= {"error", "error_rate"}
        if elastic:
            chosen |= {"torsion", "torsion_rate"} if full_state else {"torsion"}
    if residual:
        chosen.add("base_torque")
    if preview:
        chosen.add("preview")
    return tuple(f for f in FEATURES if f in chosen)


def _given(value: np.ndarray | None, feature: str) -> np.ndarray:
    """The input a feature is computed from, or a ``ValueError`` naming the feature."""
    if value is None:
        raise ValueError(f"observation feature {feature!r}: its input is missing")
    return value


def base_state_error(base) -> np.ndarray | None:
    """x - x_d (N, dim) of a residual's base (vector) controller at its last call, None
    for a base without a desired state (only eq. (13), its integral and PD variants keep
    one: ``state_error``)."""
    return getattr(base, "state_error", None)


def check_base_error(features: tuple[str, ...], base) -> None:
    """Refuse ``base_motor_error`` when the residual's base keeps no state error x - x_d."""
    if "base_motor_error" in features and base_state_error(base) is None:
        raise ValueError(
            "observation feature 'base_motor_error' needs a residual base with a desired "
            f"state x_d (eq. (13), its integral action or PD variants), not {base.name!r}"
        )


@dataclass
class ObservationInputs:
    """What the features are computed from, every array with a leading arm axis N.

    ``state`` (N, 4n | 2n) for state sources, ``motor_position`` (N, n) and
    ``acceleration`` (N, 3m) for raw sensors; ``reference`` (N, 5, n) rows q_d .. q_d^(4);
    ``preview`` (N, H, n) q_d at the preview horizons; ``last_action`` (N, a), a the
    action's entries; ``base_torque`` (N, n) of the residual's base in the last control
    period and ``base_error`` (N, 4n) its x - x_d on the current state; ``error_integral``
    (N, n) of `ErrorIntegral`; ``link_mass_estimate`` (N, a) the residual's
    link-mass scales (s - 1) / residual_scale; ``link_mass_fit`` (N, a) the scales that fit
    the base's motor error at the arm's reset, (s_fit - 1) / residual_scale;
    ``reset_rest`` (N, 2n) of `RestAtReset`.
    """

    reference: np.ndarray
    last_action: np.ndarray
    state: np.ndarray | None = None
    motor_position: np.ndarray | None = None
    acceleration: np.ndarray | None = None
    preview: np.ndarray | None = None
    base_torque: np.ndarray | None = None
    base_error: np.ndarray | None = None
    error_integral: np.ndarray | None = None
    link_mass_estimate: np.ndarray | None = None
    link_mass_fit: np.ndarray | None = None
    reset_rest: np.ndarray | None = None


class RestAtReset:
    """Each arm at rest at its last reset, held: the motor error theta - q_d there and the
    position q_d (N, 2n). The arm rests on the reference's start in the static
    equilibrium, so the motor error is the torsion K^-1 g(q) of eq. (1): with the position,
    it shows the ratio of the arm's load to its stiffness before any action moves the
    motors (raw sensors: the policy's own action makes the later motor errors).

    Args:
        n_arms, n: arms and joints.
    """

    def __init__(self, n_arms: int, n: int) -> None:
        self.value = np.zeros((n_arms, 2 * n))

    def latch(self, arms: np.ndarray, motor_position: np.ndarray, reference: np.ndarray) -> None:
        """Arms ``arms`` were reset: ``motor_position`` (N, n) and ``reference`` (N, >= 1,
        n) rows q_d, ... of all arms."""
        position = reference[arms, 0]
        self.value[arms] = np.hstack([motor_position[arms] - position, position])


class ErrorIntegral:
    """The integral of each arm's link tracking error over its episode, at the policy
    steps: I_0 = 0 at a (re)start, I_k = I_(k-1) + (t_k - t_(k-1)) (q_k - q_d,k), with q
    from the state source (the quantity an integral action integrates).

    Args:
        n_arms, n: arms and joints. ``elastic``: the state is (theta, q, theta', q').
    """

    def __init__(self, n_arms: int, n: int, elastic: bool) -> None:
        self.n, self.elastic = n, elastic
        self.value = np.zeros((n_arms, n))
        self._time = np.zeros(n_arms)

    def restart(self, arms: np.ndarray, time: np.ndarray) -> None:
        """Arms ``arms`` start an episode at ``time`` (N,)."""
        self.value[arms] = 0.0
        self._time[arms] = time[arms]

    def advance(
        self, arms: np.ndarray, state: np.ndarray, reference: np.ndarray, time: np.ndarray
    ) -> None:
        """One policy step of arms ``arms``: ``state`` (len(arms), dim), ``reference``
        (len(arms), >= 1, n) rows q_d, ..., ``time`` (N,) of all arms."""
        q = state[:, self.n : 2 * self.n] if self.elastic else state[:, : self.n]
        self.value[arms] += (time[arms] - self._time[arms])[:, None] * (q - reference[:, 0])
        self._time[arms] = time[arms]


class ObservationBuilder:
    """Flat policy observations (N, size) from `ObservationInputs`.

    Args:
        config: the features and scales.
        n: joints. ``elastic``: elastic arm. ``sensors``: the policy sees raw sensors
            instead of a state. ``n_accelerations``: accelerometer channels (3 m).
        residual: residual policy (``base_torque`` available).
        torque_limit: tau_max (n,), scales the base torque.
        action_size: entries of an action (default n), of ``last_action`` and
            ``link_mass_estimate`` and ``link_mass_fit``.
    """

    @classmethod
    def for_observations(
        cls,
        observation: ObservationConfig | dict | None,
        space,
        n: int,
        elastic: bool,
        residual: bool,
        torque_limit: np.ndarray,
        action_size: int | None = None,
    ) -> ObservationBuilder:
        """The builder for an env (or one arm of a vector env) whose observations have the
        Dict ``space``: raw sensors when it has no ``state``, its accelerometer channels."""
        accelerations = space.spaces.get("acceleration")
        return cls(
            ObservationConfig.from_config(observation),
            n,
            elastic,
            "state" not in space.spaces,
            residual,
            torque_limit,
            0 if accelerations is None else accelerations.shape[0],
            action_size,
        )

    def __init__(
        self,
        config: ObservationConfig,
        n: int,
        elastic: bool,
        sensors: bool,
        residual: bool,
        torque_limit: np.ndarray,
        n_accelerations: int = 0,
        action_size: int | None = None,
    ) -> None:
        self.config = config
        self.n, self.elastic, self.sensors = n, elastic, sensors
        self.torque_limit = np.asarray(torque_limit, dtype=float)
        self.features = config.features or default_features(
            sensors, elastic, residual, bool(config.preview), config.full_state
        )
        problems = []
        for name in self.features:
            if name in STATE_FEATURES and sensors:
                problems.append(f"{name!r} needs a state source, not raw sensors")
            if name in SENSOR_FEATURES and not sensors:
                problems.append(f"{name!r} needs raw sensors")
            if name in ELASTIC_FEATURES and not elastic:
                problems.append(f"{name!r} needs an elastic arm")
            if name in RESIDUAL_FEATURES and not residual:
                problems.append(f"{name!r} needs a residual action")
            if name == "preview" and not config.preview:
                problems.append("'preview' needs preview horizons")
            if name == "acceleration" and not n_accelerations:
                problems.append("'acceleration' needs accelerometers")
        if problems:
            raise ValueError("observation features: " + "; ".join(problems))
        actions = n if action_size is None else action_size
        sizes = {
            "reference": (config.reference_order + 1) * n,
            "preview": len(config.preview) * n,
            "acceleration": n_accelerations,
            "base_motor_error": 2 * n,
            "reset_rest": 2 * n,
            "last_action": actions,
            "link_mass_estimate": actions,
            "link_mass_fit": actions,
        }
        self.sizes = {name: sizes.get(name, n) for name in self.features}
        self.size = sum(self.sizes.values())
        self._reference_scale = 10.0 ** np.maximum(np.arange(config.reference_order + 1) - 1, 0)

    def meaning(self, name: str) -> str:
        """What the entries of feature ``name`` are, with this builder's scales (the
        observation layout of an exported policy's manifest)."""
        c = self.config
        return {
            "error": f"(q - q_d) / {c.error_scale:g} per joint: the link tracking error of "
            "the state source (rad)",
            "error_rate": f"(q' - q_d') / {c.error_rate_scale:g} per joint (rad/s)",
            "error_integral": "the integral of (q - q_d) dt over the episode, at the policy "
            f"steps, / {c.error_integral_scale:g} per joint (rad s)",
            "reference": f"q_d, q_d', ..., q_d^({c.reference_order}), each order k divided by "
            "10^max(k - 1, 0), all joints of one order after another",
            "preview": f"(q_d(t + h) - q_d(t)) / {c.preview_scale:g} for h in "
            f"{list(c.preview)} s, all joints of one horizon after another",
            "torsion": f"(theta - q) / {c.torsion_scale:g} per joint (rad)",
            "torsion_rate": f"(theta' - q') / {c.torsion_rate_scale:g} per joint (rad/s)",
            "motor_error": f"(theta - q_d) / {c.torsion_scale:g} per joint: the encoder "
            "reading minus the reference (rad)",
            "reset_rest": f"held from the episode's reset: (theta - q_d) / {c.torsion_scale:g} "
            "per joint, then q_d per joint (rad)",
            "acceleration": f"accelerometer specific force / {GRAVITY:g}, x y z of each "
            "sensor in its own frame (m/s^2)",
            "last_action": "the policy's previous action clipped to [-1, 1] (0 after a reset)",
            "base_torque": "the residual base controller's torque of the last control period "
            "/ torque_limit, per joint",
            "base_motor_error": f"the residual base's (theta - theta_d) / {c.error_scale:g} per "
            f"joint, then (theta' - theta_d') / {c.error_rate_scale:g} per joint",
            "link_mass_estimate": "(s - 1) / residual_scale of the residual's link-mass scales s",
            "link_mass_fit": "(s_fit - 1) / residual_scale: the link-mass scales that fit the "
            "residual base's motor error at the episode's reset, held",
        }[name]

    def build(self, inputs: ObservationInputs) -> np.ndarray:
        """Observations (N, size), float32."""
        return np.concatenate(
            [self._feature(name, inputs) for name in self.features], axis=-1
        ).astype(np.float32)

    def _feature(self, name: str, x: ObservationInputs) -> np.ndarray:
        c, n = self.config, self.n
        ref = x.reference
        if name == "reference":
            rows = ref[:, : c.reference_order + 1] / self._reference_scale[:, None]
            return rows.reshape(len(ref), -1)
        if name == "preview":
            preview = _given(x.preview, name)
            return ((preview - ref[:, None, 0]) / c.preview_scale).reshape(len(ref), -1)
        if name == "last_action":
            return x.last_action
        if name == "base_torque":
            return _given(x.base_torque, name) / self.torque_limit
        if name == "motor_error":
            return (_given(x.motor_position, name) - ref[:, 0]) / c.torsion_scale
        if name == "reset_rest":
            rest = _given(x.reset_rest, name)
            return np.hstack([rest[:, :n] / c.torsion_scale, rest[:, n:]])
        if name == "acceleration":
            return _given(x.acceleration, name) / GRAVITY
        if name == "link_mass_estimate":
            return _given(x.link_mass_estimate, name)
        if name == "link_mass_fit":
            return _given(x.link_mass_fit, name)
        if name == "error_integral":
            return _given(x.error_integral, name) / c.error_integral_scale
        if name == "base_motor_error":
            e = _given(x.base_error, name)
            return np.concatenate(
                [e[:, :n] / c.error_scale, e[:, 2 * n : 3 * n] / c.error_rate_scale], axis=1
            )
        s = _given(x.state, name)
        if self.elastic:
            theta, q, dtheta, dq = (s[:, i * n : (i + 1) * n] for i in range(4))
        else:
            q, dq = s[:, :n], s[:, n:]
        if name == "error":
            return (q - ref[:, 0]) / c.error_scale
        if name == "error_rate":
            return (dq - ref[:, 1]) / c.error_rate_scale
        if name == "torsion":
            return (theta - q) / c.torsion_scale
        return (dtheta - dq) / c.torsion_rate_scale  # torsion_rate


class TrueStateFeatures:
    """The state features of the true state, (N, k) float32: error, error_rate and, for
    elastic arms, torsion, torsion_rate, with the scales of ``config`` (the same values
    the ``"true"`` state source gives these features; the selection of ``config`` is
    ignored). k = 4n (elastic) or 2n: with the reference they determine the whole state.
    """

    def __init__(self, config: ObservationConfig, n: int, elastic: bool) -> None:
        features = tuple(f for f in TRUE_STATE_FEATURES if elastic or f not in ELASTIC_FEATURES)
        self.builder = ObservationBuilder(
            config.model_copy(update={"features": features}), n, elastic, False, False, np.ones(n)
        )
        self.n, self.size = n, self.builder.size

    def __call__(self, true_state: np.ndarray, reference: np.ndarray) -> np.ndarray:
        """``true_state`` (N, 4n | 2n) in the layout (theta, q, theta', q') | (q, q');
        ``reference`` (N, 5, n) rows q_d .. q_d^(4)."""
        return self.builder.build(
            ObservationInputs(
                reference=reference,
                last_action=np.zeros((len(reference), self.n)),
                state=true_state,
            )
        )
