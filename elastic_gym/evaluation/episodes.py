"""The episodes of one world and their results.

Part of the execute stage. [`run_group`][elastic_gym.evaluation.episodes.run_group]: a
group's runs are built into one world
([`build_world`][elastic_gym.evaluation.world.build_world]), run in its closed loop
([`simulate`][elastic_gym.evaluation.closed_loop.simulate]) for the runs' duration, and
each gets a [`RunResult`][elastic_gym.evaluation.episodes.RunResult] with its status, its
metrics ([`compute_arm_metrics`][elastic_gym.evaluation.metrics.compute_arm_metrics]) and
its time series. What happens inside a run never raises: an arm that terminates gets its
status while its batch mates go on, and a world that raises is run again one run at a
time, so that only the run that raised fails.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from elastic_gym.evaluation.closed_loop import STATUS_OK, ClosedLoop, Recorder, simulate
from elastic_gym.evaluation.grid import RunSpec
from elastic_gym.evaluation.groups import RunGroup
from elastic_gym.evaluation.metrics import TimeSeries, compute_arm_metrics
from elastic_gym.evaluation.world import arm_vector_env, build_world
from elastic_gym.runtime.parallel import user_failure


@dataclass
class RunResult:
    """Outcome of one run: status (``"ok"``, ``"terminated: ..."``, ``"failed: ..."``).

    ``diagnostics``: the largest value over the run of each numeric entry of the
    observer's ``diagnostics`` (e.g. ``jumps`` of the hybrid gain, ``cond_TA``).
    ``episode_return``: the sum of the env's rewards over the run's control periods.
    ``controller_diagnostics``: the run's entry, at its end, of each per-arm array in the
    vector controller's ``arm_diagnostics`` (e.g. ``saturated_actions`` of a trained policy).
    """

    spec: RunSpec
    status: str
    metrics: dict
    series: TimeSeries | None  # None when the run failed before its first sample
    wall_time: float
    diagnostics: dict = field(default_factory=dict)
    episode_return: float = float("nan")
    controller_diagnostics: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status == STATUS_OK


def describe_failure(exc: BaseException) -> str:
    """``"<Type>: <message>"`` on one line (``SystemExit``: the exit code it was given;
    a ``KeyboardInterrupt``: that it came from the code, not from a signal)."""
    if isinstance(exc, SystemExit):
        message = f"sys.exit({exc.code!r}) called by the run's code"
    elif isinstance(exc, KeyboardInterrupt):
        message = "raised by the run's code (no signal)"
    else:
        message = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {message}"


def failed_status(exc: BaseException, where: str = "") -> str:
    """``"failed: <Type>: <message>"``
    ([`describe_failure`][elastic_gym.evaluation.episodes.describe_failure])."""
    return f"failed: {where}{describe_failure(exc)}"


def run_group(group: RunGroup) -> list[RunResult]:
    """Run the group's episodes in one world, ``duration`` seconds each, and compute their
    metrics; one result per run, in the group's order.

    Never raises for what happens inside a run: an arm whose episode diverges ends early
    with status ``"terminated: <reason>"`` (the env's or the observer wrapper's
    termination) while the others go on (it is no longer recorded, its torque is zero);
    an exception (in the setup, or in a controller or observer during the loop) ends the
    world, and each of its runs is run again in a world of its own (the same episode,
    bit for bit), where the one that raises gets status ``"failed: <Type>: <message>"``
    with the metrics of the samples recorded until then (none, ``series=None``, when the
    setup failed). ``wall_time`` is the world's loop time divided by its arms.
    """
    world = recorder = loop = None
    wall = 0.0
    try:
        world = build_world(group)
        base = arm_vector_env(world.envs)
        steps = round(group.first.duration / base.control_dt)
        state_dim = world.wrapped.observer.state_dim
        recorder = Recorder(steps, len(group), base.n_joints, state_dim, base.batch.robot.elastic)
        start = time.perf_counter()
        loop = ClosedLoop(world, group)
        try:
            simulate(loop, recorder, steps)
        finally:
            wall = time.perf_counter() - start
        statuses = loop.statuses
    except BaseException as exc:
        if not user_failure(exc):
            raise
        if len(group) > 1:
            return [result for spec in group.runs for result in run_group(RunGroup((spec,)))]
        statuses = [failed_status(exc)]
    finally:
        if world is not None:
            world.close()
    if recorder is None or recorder.row == 0:
        return [
            RunResult(spec, status, {}, None, wall)
            for spec, status in zip(group.runs, statuses, strict=True)
        ]
    assert world is not None and loop is not None  # the recorder has rows
    tracking = arm_vector_env(world.envs).batch.task.name != "excitation"
    names = world.wrapped.state_names
    results = _results(group, statuses, recorder, names, tracking, wall / len(group))
    controller_diagnostics = getattr(world.controller, "arm_diagnostics", {})
    for i, result in enumerate(results):
        result.episode_return = float(loop.returns[i])
        result.controller_diagnostics = {
            key: float(values[i]) for key, values in controller_diagnostics.items()
        }
    return results


def _results(
    group: RunGroup,
    statuses: list[str],
    recorder: Recorder,
    names: tuple[str, ...],
    tracking: bool,
    wall: float,
) -> list[RunResult]:
    series = recorder.series(names)
    try:
        all_metrics = compute_arm_metrics(series, tracking=tracking)
    except Exception as exc:
        status = failed_status(exc, "metrics: ")
        return [
            RunResult(spec, status, {}, series.arm(i), wall) for i, spec in enumerate(group.runs)
        ]
    results = []
    diagnostics = recorder.diagnostics
    for i, (spec, status, metrics) in enumerate(
        zip(group.runs, statuses, all_metrics, strict=True)
    ):
        one = series.arm(i)
        metrics["sim_time"] = float(one.time[-1])
        metrics["sim_wall_ratio"] = metrics["sim_time"] / wall if wall > 0 else float("nan")
        results.append(RunResult(spec, status, metrics, one, wall, diagnostics[i]))
    return results


def run_episode(spec: RunSpec) -> RunResult:
    """Run one episode alone (a world of one arm,
    [`run_group`][elastic_gym.evaluation.episodes.run_group])."""
    return run_group(RunGroup((spec,)))[0]
