"""Render a short GIF of every arm tracking a motion, for the docs' environment pages.

    python docs/scripts/render_gifs.py [--out docs/images/envs] [--seconds 3.0] [--fps 12]

Each env runs its default tracking task in closed loop on the true state (eq. (13) of
De Luca et al. for the elastic arms, the computed-torque law with friction compensation
for the rigid ones) and PyBullet's TinyRenderer (DIRECT mode, no display) draws one
frame every ``1 / fps`` simulated seconds. Frames are written with imageio as a looping
GIF (a few hundred kB each); same seed, same GIF.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym
import imageio.v3 as iio
import numpy as np

from elastic_gym import ENVIRONMENTS
from elastic_gym.controllers import make_controller, public_info
from elastic_gym.observers import TrueStateWrapper

ROOT = Path(__file__).resolve().parents[2]
CONTROLLER = {"elastic": "feedforward-state-feedback", "rigid": "feedback-linearization"}


def frames(env_id: str, seconds: float, fps: int, size: tuple[int, int]) -> list[np.ndarray]:
    """Rendered frames of one closed-loop episode (seed 0)."""
    base = gym.make(env_id, render_mode="rgb_array", task_options={"dwell_time": 0.1})
    env = TrueStateWrapper(base)
    raw = base.unwrapped
    controller = make_controller(CONTROLLER[raw.kind], raw.model, raw.control_dt)
    obs, info = env.reset(seed=0)
    controller.reset(obs, public_info(info))
    every = round(1.0 / (fps * raw.control_dt))
    images = []
    for step in range(round(seconds / raw.control_dt)):
        if step % every == 0:
            images.append(raw.batch.sim.render(0, *size))
        obs, _, terminated, truncated, info = env.step(controller(obs, public_info(info)))
        if terminated or truncated:
            break
    env.close()
    return images


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images" / "envs")
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--fps", type=int, default=12)
    parser.add_argument("--width", type=int, default=320)
    parser.add_argument("--height", type=int, default=240)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for name in ENVIRONMENTS:
        images = frames(f"elastic_gym/{name}", args.seconds, args.fps, (args.width, args.height))
        path = args.out / f"{name.removesuffix('-v0')}.gif"
        iio.imwrite(path, np.stack(images), duration=1000 / args.fps, loop=0)
        print(f"{path}: {len(images)} frames, {path.stat().st_size // 1024} kB")


if __name__ == "__main__":
    main()
