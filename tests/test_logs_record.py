"""The identification excitation (the `fourier` task, its design) and `record`."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from elastic_gym.cli import main
from elastic_gym.envs.fourier import DitherOptions, dither_parameters
from elastic_gym.logs import read_log
from elastic_gym.logs.excitation import RegressorDesign, design_excitation
from elastic_gym.logs.record import Excitation, record_excitation, reference_table
from elastic_gym.model import RobotModel
from elastic_gym.robots.catalog import get_robot

TWO_LINK = get_robot("two_link_elastic")
OPTIONS = {
    "period": 2.0,
    "offset": [-1.0, 0.2],
    "sine": [[0.3, -0.2], [0.1, 0.05]],
    "cosine": [[0.0, 0.1], [-0.05, 0.2]],
    "ramp": 0.5,
}


@pytest.fixture(scope="module")
def task():
    env = gym.make("elastic_gym/TwoLinkElastic-v0", task="fourier", task_options=OPTIONS)
    yield env.unwrapped.task
    env.close()


def test_the_reference_and_its_derivatives(task):
    t = np.linspace(0.0, 4.0, 801)
    h = 1e-6
    reference = task.reference_at(t)
    ahead, behind = task.reference_at(t + h), task.reference_at(t - h)
    for k in range(4):  # each row is the time derivative of the one above it
        difference = (ahead[:, k] - behind[:, k]) / (2 * h)
        scale = np.abs(reference[:, k + 1]).max()
        assert np.abs(difference - reference[:, k + 1]).max() < 1e-5 * scale
    assert np.array_equal(reference[0, 0], OPTIONS["offset"])  # starts at rest at q0
    assert np.all(reference[0, 1:] == 0.0)
    later = t >= 0.5  # periodic once faded in
    again = task.reference_at(t[later] + 2.0)
    assert np.abs(again - reference[later]).max() < 1e-10 * np.abs(reference).max()


def test_the_dither_has_its_rms_and_band():
    options = DitherOptions(band=(2.0, 25.0), rms=0.03, sines=40, seed=3)
    limit = np.array(TWO_LINK.torque_limit)
    frequencies, phases, amplitudes = dither_parameters(options, limit)
    assert frequencies.min() >= 2.0 and frequencies.max() <= 25.0
    # distinct sines are orthogonal over a long window: RMS² = Σ A²/2
    t = np.arange(0, 60.0, 1e-3)
    signal = amplitudes * np.sin(
        2 * np.pi * np.multiply.outer(t, frequencies)[:, :, None] + phases
    ).sum(1)
    assert np.sqrt(np.mean(signal**2, axis=0)) == pytest.approx(0.03 * limit, rel=0.05)


def test_a_reference_leaving_the_workspace_is_refused():
    with pytest.raises(ValueError, match="leaves the workspace box"):
        gym.make(
            "elastic_gym/TwoLinkElastic-v0",
            task="fourier",
            task_options={**OPTIONS, "sine": [[2.0, 0.0], [0.0, 0.0]]},
        )


def test_the_design_counts_the_base_parameters_and_keeps_the_limits():
    model = RobotModel(TWO_LINK)
    low, high = np.array(TWO_LINK.workspace_low), np.array(TWO_LINK.workspace_high)
    limit = np.array(TWO_LINK.torque_limit)
    design = RegressorDesign(model, limit, low, high, 10.0, 5, 0.6)
    # a planar 2R arm under gravity has 3 base inertial parameters per link (ZZ, MX, MY
    # lumped; Gautier & Khalil 1990) and here 2 friction coefficients per joint
    assert len(design.find_base(np.random.default_rng(0))) == 3 * 2 + 2 * 2
    result = design_excitation(model, limit, low, high, evaluations=150, seed=1)
    assert result.base_columns == 10
    sine, cosine = np.array(result.task_options["sine"]), np.array(result.task_options["cosine"])
    bound = np.sqrt(sine**2 + cosine**2).sum(axis=0)
    assert np.all(bound <= 0.6 * 0.5 * (high - low) + 1e-12)
    assert result.torque_ratio <= 0.5
    assert result.condition_number <= result.start_condition_number
    again = design_excitation(model, limit, low, high, evaluations=150, seed=1)
    assert again.task_options == result.task_options  # reproducible from its seed


@pytest.mark.slow
def test_record_excitation_of_a_mystery_arm(tmp_path):
    kwargs = {"plant_scaling": {"stiffness": 1.1, "link_mass": 0.8}}
    excitation = Excitation(evaluations=60, ramp=0.1)
    log, design = record_excitation("TwoLinkElastic-v0", 0.4, 2, kwargs, excitation)
    assert len(log) == 400 and log.truth is not None and log.sample_time == 0.001
    assert log.sidecar.provenance.env_kwargs["plant_scaling"] == kwargs["plant_scaling"]
    assert log.sidecar.provenance.env_kwargs["task_options"] == design.task_options
    assert np.all(np.abs(log.torque) <= np.array(TWO_LINK.torque_limit))
    # the nominal model is the log's, not the plant's (identification's starting point)
    assert np.array_equal(log.nominal_model().K, TWO_LINK.stiffness)
    # the dither is in the applied torque: its spectrum has power across 2-25 Hz
    spectrum = np.abs(np.fft.rfft(log.torque[200:, 1] - log.torque[200:, 1].mean()))
    frequencies = np.fft.rfftfreq(200, 1e-3)
    assert spectrum[(frequencies >= 5) & (frequencies <= 25)].max() > 0.1 * spectrum.max()
    again, _ = record_excitation("TwoLinkElastic-v0", 0.4, 2, kwargs, excitation)
    assert np.array_equal(again.table()[1], log.table()[1])  # seeds reproduce bit for bit


def test_the_reference_file_is_the_task_sampled(tmp_path):
    header, values = reference_table(TWO_LINK, OPTIONS, 1.0, 1e-3)
    assert header[:3] == ["time", "q_d_1", "q_d_2"] and header[-1] == "dither_2"
    assert values.shape == (1000, 1 + 5 * 2 + 2)
    assert np.all(values[:, -2:] == 0.0)  # no dither in OPTIONS
    # q_d' is the derivative of q_d
    dq = np.gradient(values[:, 1], 1e-3)
    assert np.abs(dq[5:-5] - values[5:-5, 3]).max() < 1e-4


@pytest.mark.slow
def test_record_cli_writes_the_log_and_the_reference(tmp_path, capsys):
    out = tmp_path / "rec" / "arm.csv"
    reference = tmp_path / "rec" / "arm.reference.csv"
    code = main(
        [
            "record",
            "TwoLinkElastic-v0",
            "--duration",
            "0.3",
            "--seed",
            "1",
            "--output",
            str(out),
            "--reference",
            str(reference),
            "--period",
            "4",
        ]
    )
    assert code == 0
    log = read_log(out)
    assert len(log) == 300 and log.sidecar.provenance.seed == 1
    table = np.loadtxt(reference, delimiter=",", skiprows=1)
    assert len(table) == 300 and np.array_equal(table[:, 0], log.time)
    assert "condition number" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["Puma-v0"], "unknown env id"),
        (["TwoLinkElastic-v0", "--env-kwargs", "{plant_scaling: {stifness: 2}}"], "stifness"),
        (["TwoLinkElastic-v0", "--duration", "-1"], "--duration"),
        (["TwoLinkElastic-v0", "--output", "arm.txt"], "unknown log format"),
        (["TwoLinkElastic-v0", "--dither-band", "30", "2"], "band"),
        (["TwoLinkElastic-v0", "--env-kwargs", "{task: regulation}"], "sets the task"),
        (["TwoLinkElastic-v0", "--reference-only"], "needs --reference"),
    ],
)
def test_record_refuses_bad_input_and_writes_nothing(
    tmp_path, monkeypatch, capsys, arguments, message
):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_:
        main(
            ["record", *arguments, "--duration", "0.1"]
            if "--duration" not in arguments
            else ["record", *arguments]
        )
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
