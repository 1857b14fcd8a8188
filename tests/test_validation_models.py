"""The shared configuration base: field-path errors, unknown keys refused, numpy scalars."""

import numpy as np
import pytest
from pydantic import Field, PositiveFloat

from elastic_gym.validation import StrictModel, validated


class _Options(StrictModel):
    omega: PositiveFloat = 1.0


class _Controller(StrictModel):
    name: str
    options: _Options = Field(default_factory=_Options)


class _Scenario(StrictModel):
    controllers: list[_Controller]


def test_errors_name_the_field_path_first():
    data = {"controllers": [{"name": "a"}, {"name": "b", "options": {"omega": -1}}]}
    with pytest.raises(ValueError, match=r"^controllers\[1\]\.options\.omega: "):
        validated(_Scenario, data)


def test_unknown_keys_are_refused_with_their_path():
    with pytest.raises(ValueError, match=r"^controllers\[0\]\.speed: unexpected field"):
        validated(_Scenario, {"controllers": [{"name": "a", "speed": 1}]})


def test_numpy_scalars_validate_like_python_numbers():
    data = {"controllers": [{"name": "a", "options": {"omega": np.float32(0.5)}}]}
    assert validated(_Scenario, data).controllers[0].options.omega == 0.5


def test_a_prefix_is_put_before_the_path_and_none_gives_the_defaults():
    with pytest.raises(ValueError, match=r"^options\.omega: "):
        validated(_Options, {"omega": 0}, prefix="options")
    assert validated(_Options, None).omega == 1.0
