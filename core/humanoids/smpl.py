"""A humanoid with the SMPL kinematic tree (24 bodies, 23 x 3 = 69 hinge DoFs), own proportions.

Topology, body names and order, DoF layout and actuation follow PHC/PULSE's SMPL humanoid:
bodies ``Pelvis, L_Hip, L_Knee, L_Ankle, L_Toe, R_Hip, R_Knee, R_Ankle, R_Toe, Torso, Spine, Chest,
Neck, Head, L_Thorax, L_Shoulder, L_Elbow, L_Wrist, L_Hand, R_Thorax, R_Shoulder, R_Elbow, R_Wrist,
R_Hand``; each body is named after the joint at its origin (``L_Hip`` is the left thigh, ``L_Knee``
the left shin, ``L_Ankle`` the foot, ``L_Toe`` the toes, ``L_Thorax`` the clavicle, ``L_Shoulder``
the upper arm, ``L_Elbow`` the forearm, ``L_Wrist`` the palm, ``L_Hand`` the fingers). Every
non-root body has three hinges ``<body>_x, <body>_y, <body>_z`` about the body's x, y, z axes,
applied in that order (``R = Rx(a) Ry(b) Rz(c)``). The rest pose (all DoFs zero) is SMPL's T-pose
turned to face +x with z up: arms stretched sideways along +-y, legs straight down.

Shape. The body is NOT the SMPL mean shape and uses nothing derived from SMPL. It is a generic
adult of ``height`` H (default 1.70 m) and ``mass`` M (default 70 kg), proportioned from the
textbook anthropometric tables in D. A. Winter, *Biomechanics and Motor Control of Human
Movement* (4th ed., 2009, ch. 4):

* segment lengths as fractions of H (Drillis & Contini): thigh 0.245, shank 0.246, ankle height
  0.039, hip (trochanter) height 0.530, shoulder height 0.818, chin 0.870, upper arm 0.186,
  forearm 0.146, hand 0.108, foot length 0.152 and width 0.055, shoulder width 0.259, hip width
  0.191;
* segment masses as fractions of M (Dempster via Winter): head+neck 0.081, thorax 0.216, abdomen
  0.139, pelvis 0.142, upper arm 0.028, forearm 0.016, hand 0.006, thigh 0.100, shank 0.0465,
  foot 0.0145.

Where the tables have no entry our own estimates fill in (so the numbers are ours): the split of
the trunk into Torso/Spine/Chest and of the thorax mass into chest and clavicles, the hip and
shoulder joint spacing, the head/neck, foot/toe and palm/finger splits, and all geom radii.

Actuation follows PHC's gain table (kp / kd): hips, knees, ankles 800/80; toes 500/50; Torso,
Spine, Chest 1000/100; Neck, Head, Thorax, Shoulder, Elbow 500/50; Wrist, Hand 300/30; every
torque is capped at 500 N m (PULSE). Ranges are PHC's (degrees), except that PHC's +-720 deg
shoulder range is capped at +-180 deg: hip +-90; knee x, z +-5.625 and y [0, 180]; ankle x, z +-45
and y +-90; toe +-180; trunk +-60; neck/head x +-5.625, y, z +-90; thorax +-5.625; shoulder +-180;
elbow x, y +-5.625, z [0, 180] (right) / [-180, 0] (left); wrist/hand +-180.

Armature: PHC uses 0.02 (PhysX). In MuJoCo at a 1/120 s step with ``implicitfast`` our default is
0.1 kg m^2: with 0.05 (enough for ``amp``) random PD targets (sigma 0.3 rad, new every 1/30 s)
blew up 10 of 10 ten-second episodes, the three stiff trunk joints (kp 1000) chattering at their
500 N m limit; with 0.08 sigma 0.3 passed but sigma 1.0 failed 22/24; with 0.1 sigma 1.0 gave
0/24 unstable episodes (mujoco 4.0.0).
"""

from __future__ import annotations

from mocap.humanoids.common import deg, hinges
from mocap.skeleton import Body, Geom, Joint, Skeleton

BODY_NAMES: tuple[str, ...] = (
    "Pelvis", "L_Hip", "L_Knee", "L_Ankle", "L_Toe", "R_Hip", "R_Knee", "R_Ankle", "R_Toe",
    "Torso", "Spine", "Chest", "Neck", "Head",
    "L_Thorax", "L_Shoulder", "L_Elbow", "L_Wrist", "L_Hand",
    "R_Thorax", "R_Shoulder", "R_Elbow", "R_Wrist", "R_Hand",
)  # fmt: skip

PARENTS: dict[str, str | None] = {
    "Pelvis": None,
    "L_Hip": "Pelvis", "L_Knee": "L_Hip", "L_Ankle": "L_Knee", "L_Toe": "L_Ankle",
    "R_Hip": "Pelvis", "R_Knee": "R_Hip", "R_Ankle": "R_Knee", "R_Toe": "R_Ankle",
    "Torso": "Pelvis", "Spine": "Torso", "Chest": "Spine", "Neck": "Chest", "Head": "Neck",
    "L_Thorax": "Chest", "L_Shoulder": "L_Thorax", "L_Elbow": "L_Shoulder", "L_Wrist": "L_Elbow", "L_Hand": "L_Wrist",
    "R_Thorax": "Chest", "R_Shoulder": "R_Thorax", "R_Elbow": "R_Shoulder", "R_Wrist": "R_Elbow", "R_Hand": "R_Wrist",
}  # fmt: skip

HINGE_ORDER = "xyz"
END_EFFECTORS = ("Head", "L_Hand", "R_Hand", "L_Ankle", "R_Ankle")
FEET = ("L_Ankle", "L_Toe", "R_Ankle", "R_Toe")

# ---------------------------------------------------------------- proportions (fractions of H)
ANKLE_H = 0.039  # ankle height
SHANK = 0.246
THIGH = 0.245
HIP_H = ANKLE_H + SHANK + THIGH  # 0.530, greater trochanter height
PELVIS_ABOVE_HIP = 0.030  # ours: root origin above the hip-joint centres
HIP_HALF_SPACING = 0.052  # ours: hip-joint centres 0.104 H apart (hip width 0.191 H)
FOOT_LEN = 0.152
FOOT_HALF_WIDTH = 0.055 / 2
HEEL_BEHIND_ANKLE = 0.20 * FOOT_LEN  # ours
TOE_JOINT_AHEAD = 0.55 * FOOT_LEN  # ours: metatarsophalangeal joint ahead of the ankle
TOE_LEN = FOOT_LEN - HEEL_BEHIND_ANKLE - TOE_JOINT_AHEAD
TOE_JOINT_H = 0.012  # ours: toe joint height above the ground
TRUNK = {"Torso": 0.060, "Spine": 0.060, "Chest": 0.065, "Neck": 0.095, "Head": 0.040}  # ours, chained
THORAX_OFFSET = (0.0, 0.020, 0.065)  # ours, from Chest; clavicle root at 0.810 H
SHOULDER_OFFSET = (0.0, 0.085, 0.008)  # ours, from Thorax; shoulder at 0.818 H, 0.21 H apart
UPPER_ARM = 0.186
FOREARM = 0.146
HAND = 0.108
PALM = 0.045  # ours: wrist to knuckles (the rest of the hand is the fingers)

# ------------------------------------------------------------ mass fractions (of M, sum = 1)
MASS_FRACTIONS: dict[str, float] = {
    "Pelvis": 0.142,
    "Torso": 0.070, "Spine": 0.069,  # abdomen 0.139, split by us
    "Chest": 0.200, "L_Thorax": 0.008, "R_Thorax": 0.008,  # thorax 0.216, split by us
    "Neck": 0.015, "Head": 0.066,  # head + neck 0.081, split by us
    "L_Hip": 0.100, "R_Hip": 0.100,
    "L_Knee": 0.0465, "R_Knee": 0.0465,
    "L_Ankle": 0.011, "R_Ankle": 0.011, "L_Toe": 0.0035, "R_Toe": 0.0035,  # foot 0.0145, split by us
    "L_Shoulder": 0.028, "R_Shoulder": 0.028,
    "L_Elbow": 0.016, "R_Elbow": 0.016,
    "L_Wrist": 0.004, "R_Wrist": 0.004, "L_Hand": 0.002, "R_Hand": 0.002,  # hand 0.006, split by us
}  # fmt: skip

# --------------------------------------------------------------------- gains, limits (PHC)
_GROUP = {
    "Hip": "leg", "Knee": "leg", "Ankle": "leg", "Toe": "toe",
    "Torso": "trunk", "Spine": "trunk", "Chest": "trunk",
    "Neck": "upper", "Head": "upper", "Thorax": "upper", "Shoulder": "upper", "Elbow": "upper",
    "Wrist": "hand", "Hand": "hand",
}  # fmt: skip
GAINS: dict[str, tuple[float, float]] = {
    "leg": (800.0, 80.0),
    "toe": (500.0, 50.0),
    "trunk": (1000.0, 100.0),
    "upper": (500.0, 50.0),
    "hand": (300.0, 30.0),
}
TORQUE_LIMIT = 500.0

_SMALL = deg(-5.625, 5.625)
_FULL = deg(-180, 180)
RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "Hip": {"x": deg(-90, 90), "y": deg(-90, 90), "z": deg(-90, 90)},
    "Knee": {"x": _SMALL, "y": deg(0, 180), "z": _SMALL},
    "Ankle": {"x": deg(-45, 45), "y": deg(-90, 90), "z": deg(-45, 45)},
    "Toe": {"x": _FULL, "y": _FULL, "z": _FULL},
    "Torso": {"x": deg(-60, 60), "y": deg(-60, 60), "z": deg(-60, 60)},
    "Neck": {"x": _SMALL, "y": deg(-90, 90), "z": deg(-90, 90)},
    "Thorax": {"x": _SMALL, "y": _SMALL, "z": _SMALL},
    "Shoulder": {"x": _FULL, "y": _FULL, "z": _FULL},
    "L_Elbow": {"x": _SMALL, "y": _SMALL, "z": deg(-180, 0)},
    "R_Elbow": {"x": _SMALL, "y": _SMALL, "z": deg(0, 180)},
    "Wrist": {"x": _FULL, "y": _FULL, "z": _FULL},
}
RANGES["Spine"] = RANGES["Chest"] = RANGES["Torso"]
RANGES["Head"] = RANGES["Neck"]
RANGES["Hand"] = RANGES["Wrist"]


def _kind(name: str) -> str:
    return name.split("_", 1)[1] if name[:2] in ("L_", "R_") else name


def _capsule(a: tuple[float, float, float], b: tuple[float, float, float], r: float) -> Geom:
    return Geom("capsule", (r,), fromto=(*a, *b))


def _layout(h: float) -> dict[str, tuple[tuple[float, float, float], tuple[Geom, ...]]]:
    """Per body: (offset from the parent, geoms), all lengths in metres for height ``h``."""
    out: dict[str, tuple[tuple[float, float, float], tuple[Geom, ...]]] = {}
    out["Pelvis"] = ((0.0, 0.0, 0.0), (_capsule((0, -0.035 * h, -0.010 * h), (0, 0.035 * h, -0.010 * h), 0.060 * h),))
    foot_half_x = 0.5 * (HEEL_BEHIND_ANKLE + TOE_JOINT_AHEAD) * h
    foot_center_x = 0.5 * (TOE_JOINT_AHEAD - HEEL_BEHIND_ANKLE) * h
    foot_half_z = 0.5 * (ANKLE_H - 0.005) * h  # the box reaches from the ground to just below the ankle
    toe_half_z = 0.009 * h
    for side_name in ("L", "R"):
        s = 1.0 if side_name == "L" else -1.0
        out[f"{side_name}_Hip"] = (
            (0.0, s * HIP_HALF_SPACING * h, -PELVIS_ABOVE_HIP * h),
            (_capsule((0, 0, -0.020 * h), (0, 0, -0.225 * h), 0.035 * h),),
        )
        out[f"{side_name}_Knee"] = (
            (0.0, 0.0, -THIGH * h),
            (_capsule((0, 0, -0.015 * h), (0, 0, -0.225 * h), 0.026 * h),),
        )
        out[f"{side_name}_Ankle"] = (
            (0.0, 0.0, -SHANK * h),
            (Geom("box", (foot_half_x, FOOT_HALF_WIDTH * h, foot_half_z), pos=(foot_center_x, 0.0, -ANKLE_H * h + foot_half_z)),),
        )
        out[f"{side_name}_Toe"] = (
            (TOE_JOINT_AHEAD * h, 0.0, -(ANKLE_H - TOE_JOINT_H) * h),
            (Geom("box", (0.5 * TOE_LEN * h, FOOT_HALF_WIDTH * h, toe_half_z), pos=(0.5 * TOE_LEN * h, 0.0, -TOE_JOINT_H * h + toe_half_z)),),
        )
        out[f"{side_name}_Thorax"] = (
            (THORAX_OFFSET[0] * h, s * THORAX_OFFSET[1] * h, THORAX_OFFSET[2] * h),
            (_capsule((0, s * 0.010 * h, 0), (0, s * 0.075 * h, 0), 0.025 * h),),
        )
        out[f"{side_name}_Shoulder"] = (
            (SHOULDER_OFFSET[0] * h, s * SHOULDER_OFFSET[1] * h, SHOULDER_OFFSET[2] * h),
            (_capsule((0, s * 0.015 * h, 0), (0, s * 0.170 * h, 0), 0.024 * h),),
        )
        out[f"{side_name}_Elbow"] = (
            (0.0, s * UPPER_ARM * h, 0.0),
            (_capsule((0, s * 0.010 * h, 0), (0, s * 0.135 * h, 0), 0.019 * h),),
        )
        out[f"{side_name}_Wrist"] = (
            (0.0, s * FOREARM * h, 0.0),
            (_capsule((0, s * 0.008 * h, 0), (0, s * 0.037 * h, 0), 0.017 * h),),
        )
        out[f"{side_name}_Hand"] = (
            (0.0, s * PALM * h, 0.0),
            (_capsule((0, s * 0.004 * h, 0), (0, s * (HAND - PALM - 0.012) * h, 0), 0.012 * h),),
        )
    out["Torso"] = ((0.0, 0.0, TRUNK["Torso"] * h), (_capsule((0, -0.035 * h, 0.030 * h), (0, 0.035 * h, 0.030 * h), 0.050 * h),))
    out["Spine"] = ((0.0, 0.0, TRUNK["Spine"] * h), (_capsule((0, -0.035 * h, 0.030 * h), (0, 0.035 * h, 0.030 * h), 0.050 * h),))
    out["Chest"] = ((0.0, 0.0, TRUNK["Chest"] * h), (_capsule((0, -0.045 * h, 0.045 * h), (0, 0.045 * h, 0.045 * h), 0.055 * h),))
    out["Neck"] = ((0.0, 0.0, TRUNK["Neck"] * h), (_capsule((0, 0, 0.0), (0, 0, 0.035 * h), 0.022 * h),))
    out["Head"] = ((0.0, 0.0, TRUNK["Head"] * h), (Geom("sphere", (0.062 * h,), pos=(0.008 * h, 0.0, 0.055 * h)),))
    return out


def smpl_skeleton(
    *,
    height: float = 1.70,
    mass: float = 70.0,
    armature: float = 0.1,
    gain_scale: float = 1.0,
    torque_limit: float = TORQUE_LIMIT,
    friction: float = 1.0,
) -> Skeleton:
    """The SMPL-topology humanoid (24 bodies, 69 DoF) of an adult of ``height`` m and ``mass`` kg.

    Args:
        height: standing height, m; every length scales with it.
        mass: total mass, kg; every segment mass scales with it.
        armature: rotor inertia added to every hinge, kg m^2 (see the module docstring for why 0.1).
        gain_scale: multiplies every kp and kd of PHC's table (PHC scales by mass / 77 kg when it
            varies body shapes).
        torque_limit: actuator force range of every hinge, N m.
        friction: sliding friction of the body geoms (PHC's ground uses 1.0).
    """
    layout = _layout(height)
    index = {n: i for i, n in enumerate(BODY_NAMES)}
    bodies: list[Body] = []
    for name in BODY_NAMES:
        parent = PARENTS[name]
        offset, geoms = layout[name]
        body_mass = MASS_FRACTIONS[name] * mass
        if parent is None:
            bodies.append(Body(name, -1, offset, Joint("fixed"), body_mass, geoms))
            continue
        kind = _kind(name)
        kp, kd = GAINS[_GROUP[kind]]
        ranges = RANGES[name] if name in RANGES else RANGES[kind]
        hs = hinges(name, HINGE_ORDER, ranges, kp=kp * gain_scale, kd=kd * gain_scale, torque_limit=torque_limit, armature=armature)
        bodies.append(Body(name, index[parent], offset, Joint("ball", hs), body_mass, geoms))
    skeleton = Skeleton(
        name="smpl",
        bodies=tuple(bodies),
        end_effectors=END_EFFECTORS,
        feet=FEET,
        friction=friction,
        metadata={
            "source": "SMPL topology (PHC body order); own proportions from Winter (2009) anthropometric tables",
            "ball_joint_order": HINGE_ORDER,
            "rest_pose": "T-pose facing +x",
        },
    )
    skeleton.validate()
    return skeleton
