"""A benchmark's results survive what happens to it: two runs of a command give one card, a
card is verified by running its command again, runs are re-scored without running, an
overwrite keeps the earlier result until the new one is whole (full disk, interrupt), a
second writer is refused naming the first, and refusals are one line."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from helpers import checkout_env, cli_exit_code, folder_holder, jobs_here, tiny_suite_data

from elastic_gym.benchmark import read_scorecard, run_benchmark
from elastic_gym.benchmark.output import (
    OUTGOING,
    RESULT,
    STAGING,
    clear_leftovers,
    earlier_result,
    swap_in,
)
from elastic_gym.benchmark.verify import verify_card
from elastic_gym.cli import main

ENTRY = ["--controller", "motor-pd", "--source", "true", "--label", "pd"]
SLOW = '''
import os
import time

from elastic_gym.controllers.pd import MotorPD


class Slow(MotorPD):
    """Motor PD that takes ``SLOW_DELAY`` s (environment, default 0) per call: a
    benchmark long enough to interrupt, its numbers those of the motor PD."""

    delay = float(os.environ.get("SLOW_DELAY", "0"))

    def __call__(self, obs, info):
        time.sleep(self.delay)
        return super().__call__(obs, info)
'''


def micro_suite(folder: Path, duration: float = 0.02) -> Path:
    """The shipped suite cut to one nominal cell of ``duration`` s on the two-link arm."""
    data = tiny_suite_data()
    data["duration"] = duration
    data["categories"] = {"nominal": data["categories"]["nominal"]}
    path = folder / "micro.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def without_provenance(path: Path) -> dict:
    data = json.loads(path.read_text())
    data.pop("provenance")
    return data


def snapshot(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


@pytest.fixture(scope="module")
def scored(tmp_path_factory):
    """The micro suite scored twice by one command, in this process (its runs too)."""
    root = tmp_path_factory.mktemp("scored")
    suite = micro_suite(root)
    args = ["benchmark", *ENTRY, "--suite", str(suite), "--workers", "1", "--no-progress"]
    with pytest.MonkeyPatch.context() as monkeypatch:
        jobs_here(monkeypatch)
        for name in ("a", "b"):
            assert main([*args, "--output", str(root / name)]) == 0
    return root, suite, args


@pytest.mark.slow
def test_two_runs_of_one_command_give_cards_equal_but_for_their_provenance(scored):
    root, suite, _ = scored
    a, b = (root / name / "scorecard.json" for name in ("a", "b"))
    assert without_provenance(a) == without_provenance(b)
    card = read_scorecard(a)
    assert card.command == (
        f"elastic-gym benchmark --controller motor-pd --source true --label pd --suite {suite}"
    )
    assert card.provenance.wall_time > 0 and card.scores.episodes == 10


@pytest.mark.slow
def test_runs_csv_is_rescored_into_the_same_card_without_running(scored, capsys):
    root, _, args = scored
    card = root / "a" / "scorecard.json"
    before = without_provenance(card)
    runs = (root / "a" / "runs" / "runs.csv").read_bytes()
    assert cli_exit_code([*args, "--output", str(root / "a"), "--rescore"]) == 2  # a card is there
    assert "holds an earlier result (scores.png, scorecard.md, scorecard.json)" in (
        capsys.readouterr().err
    )
    assert main([*args, "--output", str(root / "a"), "--rescore", "--overwrite"]) == 0
    assert "runs" not in capsys.readouterr().out.split("\n")[0]  # no run count: nothing ran
    assert without_provenance(card) == before  # bit for bit: the CSV keeps every digit
    assert read_scorecard(card).provenance.note.startswith("re-scored from runs/runs.csv")
    assert (root / "a" / "runs" / "runs.csv").read_bytes() == runs
    # an incomplete table is refused, naming the file
    lines = runs.decode().splitlines(keepends=True)
    partial = root / "partial"
    (partial / "runs").mkdir(parents=True)
    (partial / "runs" / "runs.csv").write_text("".join(lines[:4]))
    assert cli_exit_code([*args, "--output", str(partial), "--rescore"]) == 2
    err = capsys.readouterr().err
    assert "runs.csv: 7 of the entry's 10 runs missing (two-link/nominal/s seed 90003" in err
    assert sorted(p.name for p in partial.iterdir()) == ["runs"]


@pytest.mark.slow
@pytest.mark.usefixtures("jobs_in_this_process")  # the cards are the claim, not the worker
def test_verify_reproduces_a_card_bit_for_bit_and_names_a_difference(scored, tmp_path, capsys):
    root, _, _ = scored
    card = root / "b" / "scorecard.json"
    assert main(["benchmark", "--verify", str(card), "--workers", "1", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "reproduced bit for bit: 10 episodes (status and 8 metrics each)" in out
    # a metric no score reads, edited: the card still passes the leaderboard's checks, and
    # the re-run shows the difference
    data = json.loads(card.read_text())
    true_value = data["cells"]["two-link/nominal/s"]["torque_rms"][3]
    data["cells"]["two-link/nominal/s"]["torque_rms"][3] = true_value * (1 + 2**-40)
    edited = tmp_path / "edited.json"
    edited.write_text(json.dumps(data))
    report = verify_card(edited, workers=1, progress=False)
    assert not report.exact and len(report.differences) == 1
    assert report.differences[0] == (
        f"cells.two-link/nominal/s.torque_rms[seed 90003]: card {true_value * (1 + 2**-40)!r}, "
        f"re-run {true_value!r}"
    )
    # as on another machine: only a float differs, every status and score is the card's
    assert report.reproduced and report.score_difference == 0.0
    verify = ["benchmark", "--verify", str(edited), "--workers", "1", "--no-progress"]
    assert cli_exit_code(verify) == 0
    assert "reproduced within 0.001 of every score, not bit for bit" in capsys.readouterr().out
    assert cli_exit_code([*verify, "--exact"]) == 1
    data["command"] = None
    edited.write_text(json.dumps(data))
    with pytest.raises(ValueError, match="command: null: the card's entry is a Python object"):
        verify_card(edited)


def failing_card_write(monkeypatch) -> None:
    """The disk is full when a ``scorecard.json`` is flushed to it."""
    from elastic_gym.runtime import atomic

    real = os.fsync

    def fsync(fd: int) -> None:
        if ".scorecard.json." in os.readlink(f"/proc/self/fd/{fd}"):
            raise OSError(errno.ENOSPC, "No space left on device")
        real(fd)

    monkeypatch.setattr(atomic.os, "fsync", fsync)


@pytest.mark.slow
@pytest.mark.usefixtures("jobs_in_this_process")  # the cards are the claim, not the worker
def test_a_card_that_cannot_be_written_keeps_the_earlier_result_or_the_runs(
    scored, tmp_path, monkeypatch
):
    root, suite, _ = scored
    entry = {"controller": "motor-pd", "source": "true", "label": "pd"}
    out = tmp_path / "out"
    (out).mkdir()
    for name in ("scorecard.json", "scorecard.md", "scores.png"):
        (out / name).write_bytes((root / "a" / name).read_bytes())
    (out / "runs").mkdir()
    (out / "runs" / "runs.csv").write_bytes((root / "a" / "runs" / "runs.csv").read_bytes())
    before = snapshot(out)
    failing_card_write(monkeypatch)
    kept = rf"disk full.*: the earlier result in {out}/ is kept, the new one discarded"
    with pytest.raises(RuntimeError, match=kept):
        run_benchmark(entry, suite, output_dir=out, workers=1, progress=False, overwrite=True)
    assert snapshot(out) == before  # nothing touched, nothing left beside
    # a first run: the runs stay, and the message says how to make the card from them
    fresh = tmp_path / "fresh"
    with pytest.raises(RuntimeError, match=r"disk full: the scorecard could not be written; "):
        run_benchmark(entry, suite, output_dir=fresh, workers=1, progress=False)
    assert not (fresh / "scorecard.json").exists() and (fresh / "runs" / "runs.csv").exists()
    monkeypatch.undo()
    card = run_benchmark(entry, suite, output_dir=fresh, workers=1, progress=False, rescore=True)
    assert without_provenance(fresh / "scorecard.json") == without_provenance(
        root / "a" / "scorecard.json"
    )
    assert card.provenance.note


@pytest.mark.slow
@pytest.mark.usefixtures("jobs_in_this_process")  # the cards are the claim, not the worker
def test_an_overwrite_replaces_the_whole_result_and_drops_what_the_new_one_lacks(scored, tmp_path):
    root, suite, _ = scored
    out = tmp_path / "out"
    entry = {"controller": "motor-pd", "source": "true", "label": "pd"}
    run_benchmark(entry, suite, output_dir=out, workers=1, progress=False)
    stamp = (out / "runs" / "runs.csv").stat().st_mtime_ns
    run_benchmark(
        entry, suite, output_dir=out, workers=1, progress=False, overwrite=True, figure=False
    )
    assert sorted(p.name for p in out.iterdir()) == ["runs", "scorecard.json", "scorecard.md"]
    assert (out / "runs" / "runs.csv").stat().st_mtime_ns != stamp
    assert without_provenance(out / "scorecard.json") == without_provenance(
        root / "a" / "scorecard.json"
    )


def test_a_second_benchmark_into_a_folder_in_use_names_the_process(tmp_path, capsys):
    args = ["benchmark", *ENTRY, "--suite", str(micro_suite(tmp_path)), "--no-progress"]
    folder = tmp_path / "out"
    holder = folder_holder(folder)
    try:
        assert holder.stdout.readline().strip() == "locked"
        assert cli_exit_code([*args, "--output", str(folder), "--overwrite"]) == 2
        err = capsys.readouterr().err.strip()
        assert err == (
            f"elastic-gym benchmark: error: output folder {str(folder)!r} is in use by process "
            f"{holder.pid} (lock file .elastic_gym.lock); wait for it to end or choose "
            "another folder"
        )
        assert [p.name for p in folder.iterdir()] == [".elastic_gym.lock"]  # nothing written
    finally:
        holder.kill()
        holder.wait()


def test_a_classical_controller_on_raw_sensors_is_refused_in_one_line(tmp_path, capsys):
    suite = micro_suite(tmp_path)
    code = cli_exit_code(
        ["benchmark", "--source", "sensors", "--suite", str(suite), "--no-progress"]
    )
    assert code == 2
    err = capsys.readouterr().err
    assert err == (
        "elastic-gym benchmark: error: entry: no run of elastic-gym-v1 applies: controller "
        "'feedforward-state-feedback' needs a state source, not raw sensors\n"
    )


FSIZE = """
import resource, signal, sys
from elastic_gym.cli import main
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes beyond the limit: EFBIG
resource.setrlimit(resource.RLIMIT_FSIZE, (int(sys.argv[1]),) * 2)
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.slow
@pytest.mark.usefixtures("jobs_in_this_process")  # the cards are the claim, not the worker
def test_a_full_disk_during_benchmark_overwrite_keeps_the_earlier_result(scored, tmp_path):
    root, _, args = scored
    out = tmp_path / "out"
    assert main([*args, "--output", str(out)]) == 0
    before = snapshot(out)
    done = subprocess.run(
        [sys.executable, "-c", FSIZE, "3000", *args, "--output", str(out), "--overwrite"],
        env=checkout_env(),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 1, done.stderr
    assert "disk full" in done.stderr and "Traceback" not in done.stderr
    assert f"the earlier result in {out}/ is kept, the new one discarded" in done.stderr
    assert snapshot(out) == before


@pytest.mark.slow
def test_an_interrupted_overwrite_keeps_the_earlier_result_and_says_so(
    tmp_path, monkeypatch, jobs_in_this_process
):
    (tmp_path / "slow.py").write_text(SLOW)
    monkeypatch.syspath_prepend(str(tmp_path))
    suite = micro_suite(tmp_path, duration=0.2)
    out = tmp_path / "out"
    args = ["benchmark", "--class", "slow:Slow", "--source", "true", "--suite", str(suite)]
    args += ["--output", str(out), "--workers", "1", "--no-progress"]
    env = checkout_env(tmp_path, SLOW_DELAY="0.002")  # 2 ms per call
    command = [sys.executable, "-m", "elastic_gym.cli", *args]
    assert main(args) == 0  # the earlier result, made here at full speed
    sys.modules.pop("slow", None)
    before = snapshot(out)
    second = subprocess.Popen([*command, "--overwrite"], env=env, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not (out / ".incoming" / "runs" / "scenario.yaml").exists():
        assert time.monotonic() < deadline and second.poll() is None
        time.sleep(0.05)
    time.sleep(0.5)  # inside the runs
    second.send_signal(signal.SIGINT)
    _, err = second.communicate(timeout=120)
    assert second.returncode == 130, err
    assert (
        f"interrupted by SIGINT: the earlier result in {out}/ is kept, the new one discarded"
    ) in err
    assert snapshot(out) == before


def test_swap_in_replaces_the_whole_result_and_a_rerun_clears_leftovers(tmp_path):
    """The staged result moves in (its card last) and every earlier part out, a part the
    new result lacks (here the figure) included; a killed run's staging and outgoing
    folders are removed by the next writer."""
    folder = tmp_path / "bench"
    runs, figure, markdown, card = RESULT
    (folder / runs).mkdir(parents=True)
    (folder / runs / "earlier.csv").write_text("earlier")
    for name in (figure, markdown, card):
        (folder / name).write_text(f"earlier {name}")
    staging = folder / STAGING
    (staging / runs).mkdir(parents=True)
    (staging / runs / "new.csv").write_text("new")
    for name in (markdown, card):
        (staging / name).write_text(f"new {name}")
    assert earlier_result(folder) == list(RESULT)
    swap_in(folder)
    assert earlier_result(folder) == [runs, markdown, card]
    assert [p.name for p in (folder / runs).iterdir()] == ["new.csv"]
    assert (folder / card).read_text() == f"new {card}"
    assert sorted(p.name for p in folder.iterdir()) == sorted([runs, markdown, card])
    for leftover in (STAGING, OUTGOING):
        (folder / leftover / "part").mkdir(parents=True)
    clear_leftovers(folder)
    assert sorted(p.name for p in folder.iterdir()) == sorted([runs, markdown, card])
