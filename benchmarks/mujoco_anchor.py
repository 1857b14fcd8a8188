"""The external anchor of the integrator's rates: the same elastic arm as a bare MuJoCo model.

    python benchmarks/mujoco_anchor.py            # TwoLinkElastic: check, then time
    python benchmarks/mujoco_anchor.py --quick

Needs the optional ``mujoco`` package (``pip install mujoco``), this script's only.

The model is built from the package's own `RobotModel` of the arm (the URDF's joint
placements and link inertias, K, B and D), reduced model (1) of De Luca et al. (2007):
each motor is a hinge of its own body fixed to the world, its inertia B about its hinge
through its centre of mass (no rotor mass moving with the links), coupled to its link
hinge by a fixed tendon of length theta - q whose stiffness K and damping D give the
joint torque tau_J = K (theta - q) + D (theta' - q') on the link and -tau_J on the motor;
the motor torque is a ``motor`` actuator on the motor hinge. No geoms, no contacts.

The check: MuJoCo's RK4 at 1 ms and the package's integrator
(`elastic_gym.model.integrator`) under the same held torques reach the same link
trajectory (the models are the same arm). The timing: a bare ``mj_step`` loop per arm
and 1 ms step (Euler, the default, and RK4), one arm in one model and 64 arms in one
model, against the package's integrator stepping the same arms (CPU time of the process,
best of interleaved blocks).
"""

from __future__ import annotations

import argparse
import xml.etree.ElementTree as ET

import numpy as np
from timing import (
    ensure_single_thread_blas,
    interleaved_best,
    machine_line,
    print_table,
    seconds_per_call,
)

from elastic_gym.envs.plant import PlantArray
from elastic_gym.model import RobotModel
from elastic_gym.model.integrator import ArmIntegrator
from elastic_gym.robots.catalog import get_robot

PERIOD = 1e-3  # s: the control period and MuJoCo's time step
SPACING = 2.0  # m between the bases of the arms of one model


def _vector(values) -> str:
    return " ".join(repr(float(v)) for v in np.ravel(values))


def mjcf(model: RobotModel, n_arms: int = 1, integrator: str = "Euler") -> str:
    """MJCF text of ``n_arms`` copies of the elastic arm ``model`` (model (1), no S)."""
    if not model.elastic or model.has_coupling:
        raise ValueError("the MuJoCo anchor models elastic arms of model (1) only")
    pin_model, n = model.pin_model, model.n
    root = ET.Element("mujoco", model=f"{model.spec.name}_x{n_arms}")
    ET.SubElement(root, "compiler", angle="radian", autolimits="true")
    ET.SubElement(
        root,
        "option",
        timestep=repr(PERIOD),
        integrator=integrator,
        gravity=_vector(model.gravity_vector),
    )
    world = ET.SubElement(root, "worldbody")
    tendons = ET.SubElement(root, "tendon")
    actuators = ET.SubElement(root, "actuator")
    for arm in range(n_arms):
        parent = ET.SubElement(world, "body", name=f"base{arm}", pos=_vector([SPACING * arm, 0, 0]))
        bodies = {0: parent}
        for j in range(1, n + 1):
            placement = pin_model.jointPlacements[j]
            quat = np.roll(_quaternion_xyzw(placement.rotation), 1)  # MuJoCo: w x y z
            body = ET.SubElement(
                bodies[pin_model.parents[j]],
                "body",
                name=f"link{j}_{arm}",
                pos=_vector(placement.translation),
                quat=_vector(quat),
            )
            bodies[j] = body
            joint = pin_model.joints[j]
            data = joint.createData()
            joint.calc(data, np.zeros(n))
            axis = np.asarray(data.S).ravel()[3:]
            ET.SubElement(body, "joint", name=f"q{j}_{arm}", type="hinge", axis=_vector(axis))
            inertia = pin_model.inertias[j]
            I = inertia.inertia  # about the centre of mass, joint frame axes
            ET.SubElement(
                body,
                "inertial",
                pos=_vector(inertia.lever),
                mass=repr(float(inertia.mass)),
                fullinertia=_vector([I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]),
            )
        for j in range(n):
            rotor = ET.SubElement(world, "body", name=f"rotor{j + 1}_{arm}")
            B = repr(float(model.B[j]))  # a rotor spinning about its centre of mass
            ET.SubElement(rotor, "inertial", pos="0 0 0", mass="1", diaginertia=f"{B} {B} {B}")
            ET.SubElement(rotor, "joint", name=f"theta{j + 1}_{arm}", type="hinge", axis="0 0 1")
            tendon = ET.SubElement(
                tendons,
                "fixed",
                name=f"spring{j + 1}_{arm}",
                stiffness=repr(float(model.K[j])),
                damping=repr(float(model.D[j])),
                springlength="0",
            )
            ET.SubElement(tendon, "joint", joint=f"theta{j + 1}_{arm}", coef="1")
            ET.SubElement(tendon, "joint", joint=f"q{j + 1}_{arm}", coef="-1")
            ET.SubElement(actuators, "motor", joint=f"theta{j + 1}_{arm}", gear="1")
    return ET.tostring(root, encoding="unicode")


def _quaternion_xyzw(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_quat()


class MujocoArms:
    """``n_arms`` copies of the arm in one MuJoCo model; state in the package's order."""

    def __init__(self, model: RobotModel, n_arms: int, integrator: str) -> None:
        import mujoco

        self.mujoco = mujoco
        self.m = mujoco.MjModel.from_xml_string(mjcf(model, n_arms, integrator))
        self.d = mujoco.MjData(self.m)
        self.n, self.n_arms = model.n, n_arms
        names = [
            [f"theta{j + 1}_{a}" for j in range(self.n)] + [f"q{j + 1}_{a}" for j in range(self.n)]
            for a in range(n_arms)
        ]
        self.qpos = np.array(
            [[self.m.joint(name).qposadr[0] for name in arm] for arm in names], dtype=np.int64
        )
        self.dof = np.array(
            [[self.m.joint(name).dofadr[0] for name in arm] for arm in names], dtype=np.int64
        )
        # actuators in the order of the MJCF: arm by arm, joint by joint (tau.ravel())
        assert self.m.nu == n_arms * self.n

    def set_state(self, x: np.ndarray) -> None:
        """x (N, 4 n): theta, q, theta', q' per arm."""
        n = self.n
        self.d.qpos[self.qpos] = x[:, : 2 * n]
        self.d.qvel[self.dof] = x[:, 2 * n :]
        self.mujoco.mj_forward(self.m, self.d)

    def state(self) -> np.ndarray:
        return np.concatenate([self.d.qpos[self.qpos], self.d.qvel[self.dof]], axis=1)

    def step(self, tau: np.ndarray) -> None:
        """One 1 ms step under the motor torques tau (N, n)."""
        self.d.ctrl[:] = tau.ravel()
        self.mujoco.mj_step(self.m, self.d)


class BareMujoco:
    """The bare loop: ``ctrl`` set, ``mj_step``, per control period (nothing else)."""

    def __init__(self, arms: MujocoArms) -> None:
        self.mujoco, self.m, self.d = arms.mujoco, arms.m, arms.d

    def step(self, tau: np.ndarray) -> None:
        self.d.ctrl[:] = tau
        self.mujoco.mj_step(self.m, self.d)


class BareIntegrator:
    """The package's integrator stepping the same arms (the state arrays in place)."""

    def __init__(self, model: RobotModel, x: np.ndarray) -> None:
        plants = PlantArray([model] * len(x))
        self.integrator = ArmIntegrator(plants.chain, plants.transmission, None, True)
        n = model.n
        self.theta, self.q, self.dtheta, self.dq = (
            x[:, i * n : (i + 1) * n].copy() for i in range(4)
        )
        self.ddq = np.empty(self.q.shape)

    def step(self, tau: np.ndarray) -> None:
        self.integrator.step(self.theta, self.dtheta, self.q, self.dq, tau, PERIOD, ddq=self.ddq)

    def state(self) -> np.ndarray:
        return np.concatenate([self.theta, self.q, self.dtheta, self.dq], axis=1)


def initial_state(model: RobotModel, n_arms: int) -> np.ndarray:
    spec, n = model.spec, model.n
    q = np.tile(
        0.5 * (np.asarray(spec.workspace_low) + np.asarray(spec.workspace_high)), (n_arms, 1)
    )
    theta = np.array([model.static_motor_position(row) for row in q])
    return np.concatenate([theta, q, np.zeros((n_arms, 2 * n))], axis=1)


def gravity_torques(model: RobotModel, x: np.ndarray, steps: int) -> np.ndarray:
    """The held torques of the check and the timing: the static torque plus a smooth
    excitation of 5 % of the torque limits (steps, N, n)."""
    n = model.n
    static = model.K * (x[:, :n] - x[:, n : 2 * n])
    t = np.arange(steps)[:, None, None] * PERIOD
    wave = np.sin(2.0 * np.pi * (1.0 + np.arange(n)) * t + np.arange(len(x))[None, :, None])
    return static[None] + 0.05 * model.torque_limit * wave


def check(model: RobotModel, seconds: float = 1.0) -> dict:
    """MuJoCo's RK4 against the package's integrator on the same held torques."""
    x0 = initial_state(model, 1)
    steps = round(seconds / PERIOD)
    torques = gravity_torques(model, x0, steps)
    mj = MujocoArms(model, 1, "RK4")
    mj.set_state(x0)
    ours = BareIntegrator(model, x0)
    worst = motion = 0.0
    n = model.n
    start = x0[0, n : 2 * n]
    for tau in torques:
        mj.step(tau)
        ours.step(tau)
        worst = max(worst, np.abs(mj.state()[0, n : 2 * n] - ours.q[0]).max())
        motion = max(motion, np.abs(ours.q[0] - start).max())
    return {"link position difference": worst, "motion": motion}


def rates(model: RobotModel, n_arms: int, block: int, repeats: int) -> dict[str, float]:
    """Seconds per arm and 1 ms period of each bare loop."""
    x0 = initial_state(model, n_arms)
    torques = gravity_torques(model, x0, block)
    loops = {}
    for integrator in ("Euler", "RK4"):
        arms = MujocoArms(model, n_arms, integrator)
        arms.set_state(x0)
        flat = [(np.ascontiguousarray(tau.ravel()),) for tau in torques]
        loops[f"MuJoCo {integrator}"] = (BareMujoco(arms).step, flat)
    ours = BareIntegrator(model, x0)
    loops["elastic_gym RK4"] = (ours.step, [(np.ascontiguousarray(tau),) for tau in torques])
    blocks = {
        name: (lambda f=f, a=a: seconds_per_call(f, a) / n_arms) for name, (f, a) in loops.items()
    }
    return interleaved_best(blocks, repeats)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    ensure_single_thread_blas()
    model = RobotModel(get_robot("two_link_elastic"))
    print(machine_line())
    c = check(model)
    print(
        f"MuJoCo RK4 vs elastic_gym RK4, 1 s, 1 ms steps: link positions within "
        f"{c['link position difference']:.2e} rad on a {c['motion']:.2f} rad motion"
    )
    block, repeats = (300, 3) if args.quick else (2000, 7)
    rows = []
    for n_arms in (1, 64):
        r = rates(model, n_arms, max(20, block // n_arms) if n_arms > 1 else block, repeats)
        base = r["MuJoCo Euler"]
        rows += [
            [str(n_arms), name, f"{cost * 1e6:.3g}", f"{cost / base:.2f}"]
            for name, cost in r.items()
        ]
    print_table(
        "Bare loops of TwoLinkElastic, per arm and 1 ms step (CPU time, best block)",
        ["arms", "loop", "us", "/ MuJoCo Euler"],
        rows,
    )


if __name__ == "__main__":
    main()
