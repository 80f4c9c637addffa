"""
People for the simulated rig: a skeleton of ellipsoids with skin and clothing temperatures.

A pose is a floor position, a heading, a gait phase (walking swings arms and legs) and a sitting
weight (0 standing, 1 seated on a chair of seat height 0.46 m). Each body part carries its own
procedural pattern (clothing folds, skin blood flow) that moves with it.
"""

import dataclasses
import math

import numpy as np

from st_stereo.sim.scene import Ellipsoid, ThermalMaterial


@dataclasses.dataclass(frozen=True)
class PersonPose:
    """Where a person is and what they are doing at one instant."""

    x: float
    y: float
    heading_rad: float = 0.0
    gait_phase: float = 0.0
    gait_amplitude_rad: float = 0.0
    sitting: float = 0.0


@dataclasses.dataclass(frozen=True)
class PersonLook:
    """Height and temperatures of one person, degrees Celsius."""

    height_m: float = 1.75
    skin: float = 33.5
    hair: float = 29.5
    top: float = 29.0
    trousers: float = 27.0
    seed: int = 0


def _segment(name, label, start, end, radius, material, rotation_z=None):
    """Ellipsoid spanning a bone from ``start`` to ``end`` with the given radius."""
    start, end = np.asarray(start, dtype=np.float64), np.asarray(end, dtype=np.float64)
    axis = end - start
    length = float(np.linalg.norm(axis))
    z_axis = axis / length
    helper = np.array([1.0, 0.0, 0.0]) if abs(z_axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x_axis = np.cross(helper, z_axis)
    x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(z_axis, x_axis)
    rotation = np.column_stack([x_axis, y_axis, z_axis])
    return Ellipsoid(name, label, (start + end) / 2.0,
                     np.array([radius[0], radius[1], length / 2.0 + 0.25 * min(radius)]),
                     rotation, material)


def body_parts(pose, look, label, ambient=21.0):
    """
    Ellipsoids of a person (world frame, metres) and the world position of the head centre.

    Proportions follow a 1.75 m adult scaled by ``look.height_m``: hips at 0.53 h, shoulders at
    0.82 h, head centre at 0.93 h (standing).
    """
    h = look.height_m
    s = float(np.clip(pose.sitting, 0.0, 1.0))
    swing = pose.gait_amplitude_rad * math.sin(pose.gait_phase)
    hip_z = (1 - s) * 0.53 * h + s * 0.50
    thigh, shin = 0.245 * h, 0.25 * h

    def mat(base, kelvin, wavelength, seed_offset, grazing=0.35):
        return ThermalMaterial(base=base, noise_kelvin=kelvin, noise_wavelength_m=wavelength,
                               grazing=grazing, ambient=ambient, seed=look.seed * 31 + seed_offset)
    skin, hair = mat(look.skin, 0.5, 0.12, 1), mat(look.hair, 0.6, 0.1, 2)
    top, trousers = mat(look.top, 0.9, 0.15, 3), mat(look.trousers, 0.8, 0.18, 4)
    local = []
    for side, sign in (('left', -1.0), ('right', 1.0)):
        leg_swing = swing * sign
        thigh_angle = (1 - s) * leg_swing + s * math.radians(85)
        shin_angle = (1 - s) * (leg_swing - 0.35 * abs(leg_swing)) + s * math.radians(-5)
        hip = np.array([0.09 * sign, 0.0, hip_z])
        knee = hip + thigh * np.array([0.0, math.sin(thigh_angle), -math.cos(thigh_angle)])
        ankle = knee + shin * np.array([0.0, math.sin(shin_angle), -math.cos(shin_angle)])
        ankle[2] = max(ankle[2], 0.06)
        local.append(_segment(f'{side}_thigh', label, hip, knee, (0.075, 0.075), trousers))
        local.append(_segment(f'{side}_shin', label, knee, ankle, (0.055, 0.055), trousers))
        foot_end = ankle + np.array([0.0, 0.2, -0.02])
        local.append(_segment(f'{side}_foot', label, ankle, foot_end, (0.045, 0.035),
                              mat(ambient + 4.0, 0.3, 0.1, 5)))
    lean = s * 0.06
    neck = np.array([0.0, lean, hip_z + 0.29 * h])
    local.append(_segment('torso', label, [0.0, 0.0, hip_z + 0.02], neck, (0.17, 0.11), top))
    head_centre = neck + np.array([0.0, 0.01, 0.11 * h / 1.75 + 0.03])
    local.append(_segment('neck', label, neck - [0, 0, 0.02], neck + [0, 0, 0.06],
                          (0.055, 0.055), skin))
    local.append(_segment('face', label, head_centre - [0, 0, 0.1], head_centre + [0, 0, 0.02],
                          (0.075, 0.09), skin))
    local.append(_segment('hair', label, head_centre - [0, 0.015, 0.0],
                          head_centre + [0, -0.015, 0.1], (0.08, 0.095), hair))
    for side, sign in (('left', -1.0), ('right', 1.0)):
        arm_swing = -swing * sign * 0.8
        upper_angle = (1 - s) * arm_swing + s * math.radians(20)
        lower_angle = (1 - s) * (arm_swing + 0.2) + s * math.radians(75)
        shoulder = neck + np.array([0.2 * sign, 0.0, -0.05])
        elbow = shoulder + 0.17 * h * np.array([0.02 * sign, math.sin(upper_angle),
                                                -math.cos(upper_angle)])
        wrist = elbow + 0.15 * h * np.array([0.0, math.sin(lower_angle), -math.cos(lower_angle)])
        local.append(_segment(f'{side}_upper_arm', label, shoulder, elbow, (0.05, 0.05), top))
        local.append(_segment(f'{side}_forearm', label, elbow, wrist, (0.04, 0.04), top))
        hand_end = wrist + 0.1 * (wrist - elbow) / np.linalg.norm(wrist - elbow)
        local.append(_segment(f'{side}_hand', label, wrist, hand_end, (0.035, 0.02), skin))
    # Local (x right, y forward, z up) to world: turn by the heading, move to (x, y).
    c, si = math.cos(pose.heading_rad), math.sin(pose.heading_rad)
    turn = np.array([[c, -si, 0.0], [si, c, 0.0], [0.0, 0.0, 1.0]])
    offset = np.array([pose.x, pose.y, 0.0])
    parts = [dataclasses.replace(part, centre=turn @ part.centre + offset,
                                 rotation=turn @ part.rotation) for part in local]
    return parts, turn @ head_centre + offset
