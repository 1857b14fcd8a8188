"""Magnitudes of one parameter: the generated axes and one-at-a-time sweeps of a scenario.

A parameter is a dotted path into the env kwargs; its magnitudes are listed (``values``)
or spaced over a ``range`` (``num`` points, ``log: true`` for geometric spacing). A
`Sweep` also states the ``nominal`` magnitude, the one the scenario's runs as
given have ([`scenario`][elastic_gym.evaluation.scenario]).
"""

from __future__ import annotations

from typing import Annotated, Any

import numpy as np
from pydantic import ConfigDict, Field, PrivateAttr, StrictBool, StrictInt, model_validator

from elastic_gym.evaluation.scenario_models import NOMINAL, Real, Variation
from elastic_gym.validation import FieldError, StrictModel, all_or_none, at_most_one, numbers


class Magnitudes(StrictModel):
    """Magnitudes of one parameter, a dotted path into the env kwargs
    (``plant_scaling.link_mass``, ``encoder.noise_std``, ``sensor_delay``): ``values``, or
    ``range`` + ``num`` (``log``: geometric). After validation ``values`` holds them."""

    model_config = ConfigDict(frozen=True)
    parameter: Annotated[
        str, Field(pattern=r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*$", examples=["plant_scaling.link_mass"])
    ]
    values: tuple[Real, ...] = Field((), min_length=1)
    range: tuple[Real, Real] | None = None
    num: Annotated[StrictInt, Field(ge=2)] | None = None
    log: StrictBool = False
    nominal: Real | None = None
    _name: str = PrivateAttr("")

    @model_validator(mode="after")
    def _resolved(self) -> Magnitudes:
        values = self.values if "values" in self.model_fields_set else None
        at_most_one({"values": values, "range": self.range}, required=True)
        all_or_none({"range": self.range, "num": self.num}, loc=("num",))
        if self.range is not None and self.num is not None:
            low, high = self.range
            if self.log:
                needs = "log: true needs bounds > 0"
                numbers(self.range, "", needs, [(2,)], minimum=0.0, strict=True, loc=("range",))
            points = (np.geomspace if self.log else np.linspace)(low, high, self.num)
            values = tuple(float(f"{v:.12g}") for v in points)  # 1.2000000000000002 -> 1.2
            vars(self).update(values=values, range=None, num=None)
        for i, v in enumerate(self.values if self.log else ()):
            numbers(
                v, "", "must be finite and > 0", [()], minimum=0.0, strict=True, loc=("values", i)
            )
        if len({f"{v:g}" for v in self.values}) < len(self.values):
            raise FieldError(("values",), f"magnitudes repeat: {list(self.values)}")
        return self

    @property
    def name(self) -> str:
        """The sweep's (or generated axis') name, the key it is given under."""
        return self._name

    def named(self, name: str) -> Magnitudes:
        self._name = name
        return self

    def label(self, value: float) -> str:
        """Label of a magnitude in the ``sweep`` axis; ``"nominal"`` for the nominal one."""
        return NOMINAL if value == self.nominal else f"{self.name}={value:g}"

    def kwargs(self, value: float) -> dict:
        """The env kwargs that set the parameter to ``value``."""
        out: Any = value
        for key in reversed(self.parameter.split(".")):
            out = {key: out}
        return out

    def extremes(self) -> tuple[float, ...]:
        """The farthest magnitude below and above the nominal (those that exist)."""
        below = [v for v in self.values if self.nominal is not None and v < self.nominal]
        above = [v for v in self.values if self.nominal is None or v > self.nominal]
        return tuple(
            v for v in (min(below, default=None), max(above, default=None)) if v is not None
        )

    def axis_values(self) -> tuple[Variation, ...]:
        """The values of an axis generated from these magnitudes, ``<name>=<magnitude>``."""
        return tuple(
            Variation(label=f"{self.name}={v:g}", values=self.kwargs(v)) for v in self.values
        )

    def variations(self) -> tuple[Variation, ...]:
        """The values these magnitudes add to the ``sweep`` axis (the nominal left out)."""
        return tuple(
            Variation(label=self.label(v), values=self.kwargs(v))
            for v in self.values
            if v != self.nominal
        )

    def magnitude(self, label: str) -> float | None:
        """The magnitude of a ``sweep`` axis label of this sweep (None if not one)."""
        if label == NOMINAL:
            return self.nominal
        return next((v for v in self.values if self.label(v) == label), None)


class Sweep(Magnitudes):
    """A one-at-a-time sweep: magnitudes and the ``nominal`` one (required), which the
    runs as given have."""

    nominal: Real = Field(description="the magnitude of the nominal runs")
