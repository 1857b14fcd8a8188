# %% [markdown]
# # A robustness sweep and how to read its margins
#
# A sweep varies one parameter of the *simulated plant* at a time while the controllers and
# observers keep the nominal model, and records how every loop's metrics move. This
# tutorial sweeps the link mass and the measurement delay of TwoLinkElastic for eq. (13) on
# the truth, the De Luca observer and the EKF, and motor PD on filtered encoder
# differences, then reads the curves and the margins.
#
# With `ELASTIC_GYM_TUTORIAL_QUICK=1`: one magnitude per side and sweep, the robots' own
# 0.5 ms physics step, 0.6 s runs (seconds). Without it: five mass magnitudes, three delays,
# the comparisons' converged 1/16 ms step, 1.2 s runs (under a minute of CPU).

# %%
import csv
import math
import os
import tempfile
from pathlib import Path

from rich.console import Console

import elastic_gym  # noqa: F401 - registers the environments
from elastic_gym.evaluation import Scenario, compare

QUICK = os.environ.get("ELASTIC_GYM_TUTORIAL_QUICK") == "1"
work = Path(tempfile.mkdtemp(prefix="elastic-gym-tutorial-"))

# %% [markdown]
# ## The scenario
#
# The nominal runs are the grid as given (one smooth C⁴ move); each sweep adds runs that
# change only its parameter, a dotted path into the env kwargs. `nominal` is the magnitude
# of the nominal runs: `plant_scaling.link_mass` 1.0 (the model's masses), `sensor_delay` 0.

# %%
mass = [1.3] if QUICK else [0.7, 0.9, 1.1, 1.3, 1.6]
delay = [2] if QUICK else [1, 2, 3]
scenario = Scenario.from_dict(
    {
        "name": "sweep-tutorial",
        "duration": 0.6 if QUICK else 1.2,
        "physics_dt": None if QUICK else 6.25e-5,
        "seeds": [0],
        "envs": [
            {
                "id": "TwoLinkElastic-v0",
                "label": "two-link",
                "kwargs": {"task_options": {"move_time": 0.5, "dwell_time": 0.05, "n_moves": 1}},
            }
        ],
        "sweeps": {
            "link_mass": {"parameter": "plant_scaling.link_mass", "nominal": 1.0, "values": mass},
            "delay_ms": {"parameter": "sensor_delay", "nominal": 0, "values": delay},
        },
        "controllers": [
            {"name": "feedforward-state-feedback", "label": "eq13"},
            {"name": "motor-pd", "sources": ["finite-difference"]},
        ],
        "state_sources": ["true", "deluca", "ekf", "finite-difference"],
    }
)
result = compare(
    scenario,
    output_dir=work,
    workers=1,
    progress=False,
    plots=not QUICK,
    console=Console(quiet=True),
)
print(len(result.runs), "runs in", work)

# %% [markdown]
# ## The curves
#
# `curves/` holds one figure per metric (with plots on): a panel per sweep, a line per
# loop through the mean over the seeds at each magnitude, an `x` where a loop became
# unstable. `runs.csv` holds the same numbers per run; its `sweep` column says which sweep
# and magnitude a run belongs to (`nominal` for the shared nominal runs).

# %%
for row in result.runs.to_dict("records"):
    print(
        f"{row['sweep']:16} {row['controller']:10} {row['source']:18} "
        f"track {row['track_rms']:.2e} rad   est q' {row['est_rms_dq']:.2e} rad/s"
    )

# %% [markdown]
# ## The margins
#
# A magnitude *passes* when the loop stays stable and its metric stays within 2× its own
# nominal value; the margin on a side is the farthest magnitude passed before the first
# failure. `1.3` passes up to 1.3; `1.6*` passes every magnitude tested; `<1.3` fails at
# the first magnitude above the nominal (`>0.9` below it). Tracking margins apply to every
# loop, estimation margins (link position and velocity errors) to the loops on an observer.

# %%
print((work / "margins.md").read_text())

# %% [markdown]
# How to read them (the numbers are those of the full run):
#
# * A margin is relative to the loop's **own** nominal precision. Eq. (13) with the link
#   velocity tracks the move to about 1e-4 rad; without integral action a 10 % mass error
#   multiplies that by about 40, so its tracking margin is `>0.9 .. <1.1`: it says how well
#   the model must be known to keep that precision, not where the loop fails. Motor PD on
#   encoder differences starts 50× worse (5e-3 rad) and reads `0.9 .. 1.1`; in absolute
#   terms it stays close to eq. (13) at every mass (9e-3 against 1.2e-2 rad at 1.3×). Read
#   the absolute values beside the margins.
# * The estimation margins separate the observers. De Luca's error dynamics do not depend
#   on the link parameters (Theorem 1): its velocity error stays within 1.8e-3 – 3.3e-3
#   rad/s from 0.7× to 1.6× the masses, and it passes every heavier mass (at 0.7× its
#   position error is 2.1× nominal, just past the 2× rule). The EKF predicts with the
#   nominal link model and fails at the first magnitude on each side: its velocity error
#   grows tenfold at ±10 %.
# * One control period of measurement delay (1 ms) already breaks the observer-based
#   loops (4e-2 and 5e-3 rad against 1e-4), and eq. (13) on the true state sees no delay.

# %% [markdown]
# `margins.csv` has the same margins as numbers (`upper`, `upper_failed_at`, the failure's
# reason in `upper_failure`; `lower...` below the nominal). The claims above, checked on
# this sweep (the test suite runs this script):

# %%
with open(work / "margins.csv", newline="") as file:
    margins = {
        (r["source"], r["sweep"], r["criterion"]): float(r["upper_failed_at"])
        for r in csv.DictReader(file)
        if r["controller"] == "eq13"
    }
assert math.isnan(margins["deluca", "link_mass", "estimation"])  # passes every mass: Theorem 1
assert not math.isnan(margins["ekf", "link_mass", "estimation"])  # the EKF's link model
assert not math.isnan(margins["deluca", "delay_ms", "tracking"])  # delay breaks the loop
