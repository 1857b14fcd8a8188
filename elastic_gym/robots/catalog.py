"""The robots of the suite, with the source of every number.

Elastic parameters are chosen so that the lowest natural frequencies of the arms
are a few tens of rad/s (industrial arms with cycloidal/harmonic gears: De Luca et al.
report closed-loop poles at 30 rad/s "close to the robot natural frequency" for the
KR15/2), and the physics step keeps dt * omega_max <= 0.1 for the stiffest mode.
The environment pages of the docs list K, B, D and the resulting natural frequencies.
"""

from __future__ import annotations

import math
from functools import cache

import pybullet_data

from elastic_gym.robots.spec import URDF_DIR, AccelerometerMount, LinkFriction, RobotSpec
from elastic_gym.validation import lookup

PI = math.pi


def two_link_elastic() -> RobotSpec:
    """Planar 2R arm in a vertical plane, elastic joints, reduced model (1)."""
    return RobotSpec(
        name="two_link_elastic",
        urdf=str(URDF_DIR / "two_link_elastic.urdf"),
        joint_names=("joint1", "joint2"),
        elastic=True,
        stiffness=(2500.0, 1500.0),
        motor_inertia=(0.5, 0.2),
        damping=(2.0, 1.0),
        torque_limit=(120.0, 60.0),
        accelerometers=(
            AccelerometerMount(
                link="link1", position=(0.35, 0.0, 0.03), rpy=(0.0, 0.0, 0.0), name="acc_link1"
            ),
            AccelerometerMount(
                link="link2",
                position=(0.30, 0.0, 0.025),
                rpy=(PI / 2, 0.0, PI / 6),
                name="acc_link2",
            ),
        ),
        workspace_low=(-2.6, -2.4),
        workspace_high=(0.6, 2.4),
        max_move=1.0,
        camera=((0.3, 0.0, 0.0), 1.4, 0.0, -5.0),
        physics_dt=5e-4,
        source="elastic_gym design values (uniform tubes 5 kg / 0.5 m and 3 kg / 0.4 m)",
    )


def kr15_elastic() -> RobotSpec:
    """Three base axes of a KUKA KR15/2-like arm with model (2) and constant S.

    S has the structure of De Luca et al., Sec. V: the only nonzero entry is
    S23 = r3 * I_R3zz, the coupling between link 2 and the rotor of motor 3 (mounted
    on link 2). With B3 = r3^2 I_R3zz and gear ratio r3 = 60, S23 = B3 / r3.
    """
    B = (20.0, 20.0, 6.0)
    r3 = 60.0
    return RobotSpec(
        name="kr15_elastic",
        urdf=str(URDF_DIR / "kr15_base3.urdf"),
        joint_names=("a1", "a2", "a3"),
        elastic=True,
        stiffness=(5.0e4, 8.0e4, 3.0e4),
        motor_inertia=B,
        damping=(150.0, 250.0, 80.0),
        coupling=((0.0, 0.0, 0.0), (0.0, 0.0, B[2] / r3), (0.0, 0.0, 0.0)),
        torque_limit=(2500.0, 4000.0, 1800.0),
        accelerometers=(
            AccelerometerMount(
                link="forearm", position=(0.45, 0.0, 0.12), rpy=(0.0, 0.0, 0.0), name="acc_forearm"
            ),
        ),
        workspace_low=(-1.2, -0.5, -0.9),
        workspace_high=(1.2, 0.6, 0.6),
        max_move=0.6,
        camera=((0.5, 0.0, 0.9), 2.6, 30.0, -15.0),
        physics_dt=5e-4,
        source="KR15/2-like geometry (KUKA data sheet); S structure of De Luca et al. Sec. V",
        extra={"gear_ratio_3": r3},
    )


def iiwa_elastic() -> RobotSpec:
    """KUKA LBR iiwa 7-DOF (pybullet_data ``kuka_iiwa/model.urdf``), LWR-like elastic joints.

    Stiffness decreases towards the wrist as on the DLR/KUKA LWR; it is scaled to the
    small distal inertias of this URDF (link 7 is a 0.3 kg flange) so that the
    stiffest mode stays below ~700 rad/s.
    """
    return RobotSpec(
        name="iiwa_elastic",
        urdf=str(pybullet_data.getDataPath() + "/kuka_iiwa/model.urdf"),
        joint_names=tuple(f"lbr_iiwa_joint_{i}" for i in range(1, 8)),
        elastic=True,
        stiffness=(8000.0, 8000.0, 4000.0, 4000.0, 800.0, 500.0, 300.0),
        motor_inertia=(0.6, 0.6, 0.3, 0.3, 0.08, 0.05, 0.03),
        damping=(8.0, 8.0, 4.0, 4.0, 0.8, 0.5, 0.3),
        torque_limit=(176.0, 176.0, 110.0, 110.0, 110.0, 40.0, 40.0),
        accelerometers=(
            AccelerometerMount(
                link="lbr_iiwa_link_2",
                position=(0.0, 0.08, 0.10),
                rpy=(0.0, 0.0, 0.0),
                name="acc_link2",
            ),
            AccelerometerMount(
                link="lbr_iiwa_link_4",
                position=(0.0, 0.10, 0.08),
                rpy=(0.0, 0.0, 0.0),
                name="acc_link4",
            ),
            AccelerometerMount(
                link="lbr_iiwa_link_6",
                position=(0.0, 0.06, 0.05),
                rpy=(0.0, 0.0, 0.0),
                name="acc_link6",
            ),
            AccelerometerMount(
                link="lbr_iiwa_link_7",
                position=(0.05, 0.0, 0.03),
                rpy=(0.0, 0.0, 0.0),
                name="acc_link7",
            ),
        ),
        workspace_low=(-1.5, -0.3, -1.5, -1.8, -1.5, -1.5, -1.5),
        workspace_high=(1.5, 1.2, 1.5, -0.4, 1.5, 1.5, 1.5),
        max_move=0.6,
        camera=((0.0, 0.0, 0.6), 1.5, 45.0, -20.0),
        physics_dt=2.5e-4,
        source="pybullet_data kuka_iiwa/model.urdf; LWR-like K, B, D (elastic_gym design values)",
    )


def two_link_rigid() -> RobotSpec:
    """The two-link arm of Cristofaro & De Luca (2022), Table I, rigid joints."""
    return RobotSpec(
        name="two_link_rigid",
        urdf=str(URDF_DIR / "two_link_rigid.urdf"),
        joint_names=("joint1", "joint2"),
        elastic=False,
        torque_limit=(2000.0, 1000.0),
        friction=LinkFriction(viscous=(0.1, 0.3)),
        workspace_low=(-2.5, -2.0),
        workspace_high=(1.0, 2.0),
        max_move=1.0,
        encoder_resolution=7e-4,
        camera=((0.6, 0.0, 0.0), 3.6, 0.0, -5.0),
        physics_dt=5e-4,
        source="Cristofaro & De Luca, IEEE L-CSS 2022, Table I and footnote 3",
    )


def two_link_friction() -> RobotSpec:
    """The two-link arm of Solsona & Puleston, Appendix 2, with Coulomb + viscous friction."""
    return RobotSpec(
        name="two_link_friction",
        urdf=str(URDF_DIR / "two_link_friction.urdf"),
        joint_names=("joint1", "joint2"),
        elastic=False,
        torque_limit=(400.0, 100.0),
        friction=LinkFriction(
            viscous=(2.288, 0.175), coulomb_pos=(8.049, 1.734), coulomb_neg=(7.14, 1.734)
        ),
        workspace_low=(-1.2, -1.5),
        workspace_high=(1.2, 1.5),
        max_move=1.0,
        encoder_resolution=0.0,
        encoder_noise_std=0.01,
        camera=((0.0, 0.0, -0.4), 1.6, 0.0, -5.0),
        physics_dt=5e-4,
        gravity=(0.0, 0.0, -9.8),
        source="Solsona & Puleston, Appendix 2 Table 1 (g = 9.8)",
    )


ROBOTS = {
    "two_link_elastic": two_link_elastic,
    "kr15_elastic": kr15_elastic,
    "iiwa_elastic": iiwa_elastic,
    "two_link_rigid": two_link_rigid,
    "two_link_friction": two_link_friction,
}


@cache
def get_robot(name: str) -> RobotSpec:
    """The spec of a robot by name (see `ROBOTS`)."""
    return lookup(ROBOTS, name, "robot")()
