"""`elastic-gym observe` (and `record`): what they write, and that bad input writes
nothing."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import synthetic_log_columns, write_csv_columns

from elastic_gym.cli import main
from elastic_gym.logs import estimate_log, read_log
from elastic_gym.observers.finite_difference import FiniteDifferenceObserver


class ExplodingObserver(FiniteDifferenceObserver):
    """Finite differences whose estimate turns NaN at the 100th update."""

    def _allocate(self, n_arms):
        super()._allocate(n_arms)
        self.updates = 0

    def update_arms(self, obs, torque, dt, arms=None):
        self.updates += 1
        estimate = super().update_arms(obs, torque, dt, arms)
        return estimate * np.nan if self.updates >= 100 else estimate


@pytest.fixture
def log_path(tmp_path):
    return write_csv_columns(tmp_path / "run.csv", synthetic_log_columns())


def test_observe_writes_the_estimate_as_a_log_and_the_error_table(tmp_path, log_path, capsys):
    out = tmp_path / "out"
    code = main(
        [
            "observe",
            str(log_path),
            "--observer",
            "finite-difference",
            "--options",
            "{cutoff_hz: 20.0}",
            "--output",
            str(out),
        ]
    )
    assert code == 0
    estimate = read_log(out / "run.finite-difference.csv")
    assert estimate.sidecar.state == "estimate" and estimate.truth is None
    assert estimate.sidecar.provenance.observer["options"] == {"cutoff_hz": 20.0}
    direct = estimate_log(read_log(log_path), "finite-difference", options={"cutoff_hz": 20.0})
    assert np.array_equal(estimate.state_vector(), direct.estimate)
    assert np.array_equal(estimate.motor_position, read_log(log_path).motor_position)
    table = (out / "run.finite-difference.errors.csv").read_text().splitlines()
    assert table[0] == "column,unit,rms,max_abs,rms_settled" and len(table) == 1 + 8
    assert "| dtheta_1 | rad/s |" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--observer", "kalman"], "unknown observer 'kalman'"),
        (["--observer", "deluca", "--options", "{bandwith: 200}"], "bandwith"),
        (["--observer", "deluca", "--options", "{bandwidth: fast}"], "bandwidth"),
        (["--observer", "deluca-ideal"], "reads the simulator's truth"),
        (["--observer", "deluca", "--options", "missing.yaml"], "no such file"),
        (["--observer", "deluca", "--model", "missing.yaml"], "no such file"),
        (["--observer", "deluca", "--settle", "-1"], "--settle"),
        (["--observer", "nowhere.module:Observer"], "cannot import"),
    ],
)
def test_observe_refuses_bad_options_and_writes_nothing(
    tmp_path, log_path, capsys, arguments, message
):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exit_:
        main(["observe", str(log_path), *arguments, "--output", str(out)])
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_observe_refuses_a_bad_log_and_writes_nothing(tmp_path, capsys):
    columns = synthetic_log_columns()
    columns["torque_2"][41] = np.nan
    path = write_csv_columns(tmp_path / "run.csv", columns)
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as exit_:
        main(["observe", str(path), "--observer", "deluca", "--output", str(out)])
    assert exit_.value.code == 2
    assert "run.csv, row 42 (line 43), column 'torque_2': NaN" in capsys.readouterr().err
    assert not out.exists()


def test_a_diverging_estimate_fails_naming_the_row_and_writes_nothing(tmp_path, log_path, capsys):
    out = tmp_path / "out"
    code = main(
        [
            "observe",
            str(log_path),
            "--observer",
            "test_logs_cli:ExplodingObserver",
            "--output",
            str(out),
        ]
    )
    assert code == 1
    error = capsys.readouterr().err
    assert "row 101" in error and "not finite" in error
    assert not out.exists()


def test_observe_with_an_identified_model_file(tmp_path, capsys):
    """A plant 30 % stiffer than the nominal model: `--model` with a model file holding
    its stiffness removes the link position error the nominal model leaves."""
    from helpers import closed_loop_log

    from elastic_gym.model.identified import IdentifiedModel, identified_robot_model
    from elastic_gym.robots.catalog import get_robot

    _, path = closed_loop_log(
        tmp_path,
        "elastic_gym/TwoLinkElastic-v0",
        "deluca",
        seed=2,
        plant_scaling={"stiffness": 1.3},
    )
    spec = get_robot("two_link_elastic")

    def estimate(value, nominal):
        return {"value": value, "nominal": nominal}

    joints = [
        {
            "name": name,
            "stiffness": estimate(1.3 * k, k),
            "damping": estimate(d, d),
            "motor_inertia": estimate(b, b),
            "link_mass_scale": estimate(1.0, 1.0),
            "viscous_friction": estimate(0.0, 0.0),
            "coulomb_friction": estimate(0.0, 0.0),
        }
        for name, k, d, b in zip(
            spec.joint_names, spec.stiffness, spec.damping, spec.motor_inertia, strict=True
        )
    ]
    model_file = tmp_path / "model.yaml"
    model_file.write_text(IdentifiedModel(robot=spec.name, joints=joints).to_yaml())
    for extra, out in (([], "nominal"), (["--model", str(model_file)], "identified")):
        code = main(
            ["observe", str(path), "--observer", "deluca", "--output", str(tmp_path / out), *extra]
        )
        assert code == 0
    capsys.readouterr()

    def settled(out: str) -> dict:
        lines = (tmp_path / out / "sim.deluca.errors.csv").read_text().splitlines()[1:]
        return {row.split(",")[0]: float(row.split(",")[4]) for row in lines}

    nominal, identified = settled("nominal"), settled("identified")
    for j in (1, 2):
        assert identified[f"q_{j}"] < 0.1 * nominal[f"q_{j}"]
    log = read_log(path)
    model = identified_robot_model(model_file, log.nominal_model())
    direct = estimate_log(log, "deluca", model=model)
    written = read_log(tmp_path / "identified" / "sim.deluca.csv")
    assert np.array_equal(written.state_vector(), direct.estimate)
    assert written.sidecar.provenance.observer["model"] == str(model_file)


def test_record_a_scenarios_controller_and_task(tmp_path, capsys):
    scenario = tmp_path / "scenario.yaml"
    scenario.write_text(
        "name: tiny\nduration: 0.2\nphysics_dt: 0.0005\nseeds: [4]\n"
        "envs: [{id: TwoLinkElastic-v0, kwargs: {task: regulation}}]\n"
        "controllers: [motor-pd, {name: feedforward-state-feedback, label: eq13}]\n"
        "state_sources: [deluca, 'true']\n"
    )
    out = tmp_path / "scenario.csv"
    code = main(
        [
            "record",
            "TwoLinkElastic-v0",
            "--scenario",
            str(scenario),
            "--controller",
            "eq13",
            "--state-source",
            "deluca",
            "--output",
            str(out),
        ]
    )
    assert code == 0
    log = read_log(out)
    assert len(log) == 200 and log.sidecar.provenance.seed == 4
    assert log.sidecar.provenance.controller["name"] == "feedforward-state-feedback"
    assert log.sidecar.provenance.env_kwargs["task"] == "regulation"
    assert "eq13 on deluca" in capsys.readouterr().out
