"""The DeepMimic / AMP humanoid: 15 bodies, 28 hinge DoFs, 45 kg.

Built at call time from ``pybullet_data/humanoid/humanoid.urdf`` (pybullet is a dependency), so
proportions, masses, geom shapes and the knee/elbow limits are the URDF's, re-expressed in our
:class:`~mocap.skeleton.Skeleton`:

* every length is scaled by 0.25 (what pybullet's ``globalScaling=0.25`` does for DeepMimic);
* the URDF is y-up with x forward and z to the character's right; it is turned to our z-up frame
  by +90 deg about x: a point ``p = (x, y, z)`` becomes ``p' = (x, -z, y)`` (x forward, y left);
* masses are the URDF's link masses (total 45 kg); inertia is left to the simulator, which
  derives it from the geoms scaled to the body mass.

Joints. Ball joints (chest, neck, shoulders, hips, ankles) are three hinges about the body's
y, x and z axes in that intrinsic order, ``R = Ry(a) Rx(b) Rz(c)``. All bones point along z at rest,
so z is the twist axis and the decomposition only locks at x = +-90 deg (e.g. an arm raised
sideways to the horizontal). Knees and elbows are one hinge about ``(0, -1, 0)`` (the URDF's z
axis after the conversion) with the URDF limits: knee [-3.14, 0] (negative bends the shin
backwards), elbow [0, 3.14] (positive bends the forearm forwards). Hands are fixed to the forearms.

Ball-joint ranges are not in the URDF (its spherical joints are unlimited). Ours cover the
envelope of the 15 DeepMimic clips in ``pybullet_data/data/motions`` (decomposed as above) with a
margin; shoulders get the full +-180 deg on y and z because raised arms cross the decomposition's
singularity and their angles wrap there.

Gains and torque limits are DeepMimic's (kp / kd / limit): chest 1000/100/200, neck 100/10/50,
hip 500/50/200, knee 500/50/150, ankle 400/40/90, shoulder 400/40/100, elbow 300/30/60.

Motion loaders: a DeepMimic clip stores each joint's local rotation in the URDF's y-up frames. The
same rotation in our z-up body frames is the conjugate by the frame change, which for a quaternion
``q = (w, x, y, z)`` (y-up) is ``q' = (w, x, -z, y)``; root positions map as ``p' = (x, -z, y)`` and
the root quaternion maps the same way as joint quaternions. ``q'`` is then decomposed as
``Ry(a) Rx(b) Rz(c)`` to give the hinges ``<joint>_y = a, <joint>_x = b, <joint>_z = c``; the
revolute knee/elbow angles are copied unchanged.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from mocap.humanoids.common import deg, hinges
from mocap.skeleton import Body, Geom, Hinge, Joint, Skeleton

URDF_SCALE = 0.25

#: (our body name, URDF link name = URDF joint name) in our body order.
BODY_LINKS: tuple[tuple[str, str], ...] = (
    ("pelvis", "root"),
    ("torso", "chest"),
    ("head", "neck"),
    ("right_upper_arm", "right_shoulder"),
    ("right_lower_arm", "right_elbow"),
    ("right_hand", "right_wrist"),
    ("left_upper_arm", "left_shoulder"),
    ("left_lower_arm", "left_elbow"),
    ("left_hand", "left_wrist"),
    ("right_thigh", "right_hip"),
    ("right_shin", "right_knee"),
    ("right_foot", "right_ankle"),
    ("left_thigh", "left_hip"),
    ("left_shin", "left_knee"),
    ("left_foot", "left_ankle"),
)

#: DeepMimic PD gains and torque limits per URDF joint kind: (kp, kd, torque limit).
GAINS: dict[str, tuple[float, float, float]] = {
    "chest": (1000.0, 100.0, 200.0),
    "neck": (100.0, 10.0, 50.0),
    "hip": (500.0, 50.0, 200.0),
    "knee": (500.0, 50.0, 150.0),
    "ankle": (400.0, 40.0, 90.0),
    "shoulder": (400.0, 40.0, 100.0),
    "elbow": (300.0, 30.0, 60.0),
}

#: Ball-joint ranges (deg) for the right side / centre; the left side mirrors x and z.
BALL_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    "chest": {"y": deg(-60, 90), "x": deg(-60, 60), "z": deg(-60, 60)},
    "neck": {"y": deg(-90, 90), "x": deg(-60, 60), "z": deg(-90, 90)},
    "hip": {"y": deg(-160, 60), "x": deg(-90, 45), "z": deg(-90, 90)},
    "ankle": {"y": deg(-90, 90), "x": deg(-60, 60), "z": deg(-60, 60)},
    "shoulder": {"y": deg(-180, 180), "x": deg(-90, 45), "z": deg(-180, 180)},
}

#: ``shoulder_turns`` that lets the shoulders follow every bundled clip. Decomposed as y-x-z, an arm
#: that passes near the horizontal sideways (x = +-90 deg, the singularity) makes y and z swing by
#: about pi each within a frame or two; unwrapped over time (:class:`~mocap.motion.library.MotionLibrary`)
#: the shoulders of punch, spinkick, backflip, dance_a, dance_b and spin span 6.5-9.8 rad and reach
#: |8.4| rad, and their looping clips wind a full turn per cycle. At +-180 deg those references leave
#: the hinge range 0.0-0.8 s into the clip (``imitator_amp_v4`` fails five of them, all but spinkick,
#: 0.5-1.6 s later); wrapped into +-180 deg instead they jump by 2 pi, which a limited hinge cannot
#: follow either. Eight turns admit the clips and 6 more cycles of winding each way.
FREE_SHOULDER_TURNS = 8.0

BALL_ORDER = "yxz"

#: Hinge orders of the shoulders. An Euler decomposition has a singularity where its middle angle is
#: +-90 deg; next to it the outer two angles swing by about pi within a few frames (choosing the
#: smoother of the two branches per frame, by a Viterbi search over the clip, takes punch from 81 to
#: 42 rad/s but leaves dance_a and dance_b at 71-77: the swings are the order's). With ``yxz`` that is an arm
#: raised sideways to the horizontal, which the clips pass close to: the bundled clips ask the
#: shoulders for up to 81 rad/s (punch, spinkick, dance_a, dance_b, backflip, cartwheel, spin over
#: 25 rad/s), which the 100 N m actuators cannot follow, and their reaction twists the torso (dance_a
#: falls backwards as its arms go up). With ``xzy`` (the twist in the middle) the clips keep the middle
#: angle within 80 deg and ask for at most 34 rad/s; only dance_a's right arm still winds a full turn per
#: cycle, which ``shoulder_turns`` > 0.5 admits. Measured with ``bench/shoulder_references.py``.
SHOULDER_ORDERS = ("yxz", "xzy")
END_EFFECTORS = ("head", "right_hand", "left_hand", "right_foot", "left_foot")
FEET = ("right_foot", "left_foot")


def urdf_path() -> Path:
    """Path of DeepMimic's ``humanoid.urdf`` shipped with ``pybullet_data``."""
    import pybullet_data

    path = Path(pybullet_data.getDataPath()) / "humanoid" / "humanoid.urdf"
    if not path.is_file():
        raise FileNotFoundError(f"DeepMimic humanoid URDF not found at {path} (is pybullet installed?)")
    return path


def y_up_to_z_up(p: tuple[float, float, float]) -> tuple[float, float, float]:
    """``(x, y, z)`` in DeepMimic's y-up frame -> ``(x, -z, y)`` in our z-up frame."""
    return (p[0], -p[2], p[1])


def _floats(text: str | None) -> tuple[float, ...]:
    return tuple(float(v) for v in (text or "").split())


def _rpy_matrix(rpy: tuple[float, ...]) -> list[list[float]]:
    """URDF fixed-axis roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]


@dataclass(frozen=True)
class _Link:
    mass: float
    geoms: tuple[Geom, ...]


def _clean(v: float) -> float:
    v = round(v, 9)
    return 0.0 if v == 0 else v


def _vec(p: tuple[float, ...], scale: float) -> tuple[float, float, float]:
    q = y_up_to_z_up((p[0] * scale, p[1] * scale, p[2] * scale))
    return (_clean(q[0]), _clean(q[1]), _clean(q[2]))


def _parse_link(el: ET.Element, scale: float) -> _Link:
    mass_el = el.find("inertial/mass")
    mass = float(mass_el.get("value", "0")) if mass_el is not None else 0.0
    geoms: list[Geom] = []
    for col in el.findall("collision"):
        origin = col.find("origin")
        xyz = _floats(origin.get("xyz")) if origin is not None else (0.0, 0.0, 0.0)
        rpy = _floats(origin.get("rpy")) if origin is not None else (0.0, 0.0, 0.0)
        center = _vec(xyz, scale)
        geo = col.find("geometry")
        assert geo is not None
        shape = geo[0]
        if shape.tag == "sphere":
            geoms.append(Geom("sphere", (float(shape.get("radius", "0")) * scale,), pos=center))
        elif shape.tag == "capsule":
            radius = float(shape.get("radius", "0")) * scale
            half = 0.5 * float(shape.get("length", "0")) * scale
            rot = _rpy_matrix(rpy)
            # the capsule's local z axis; the URDF writes 90 deg as 1.570796, so snap to 1e-5
            axis = tuple(round(v, 5) for v in y_up_to_z_up((rot[0][2], rot[1][2], rot[2][2])))
            norm = math.sqrt(sum(v * v for v in axis))
            axis = tuple(v / norm for v in axis)
            a = tuple(_clean(c + half * d) for c, d in zip(center, axis))
            b = tuple(_clean(c - half * d) for c, d in zip(center, axis))
            geoms.append(Geom("capsule", (radius,), fromto=(*a, *b)))  # type: ignore[arg-type]
        elif shape.tag == "box":
            if any(abs(v) > 1e-9 for v in rpy):
                raise ValueError("rotated URDF boxes are not supported")
            sx, sy, sz = _floats(shape.get("size"))
            # full sizes along URDF x, y, z -> half sizes along our x (=x), y (=z), z (=y)
            geoms.append(Geom("box", (0.5 * sx * scale, 0.5 * sz * scale, 0.5 * sy * scale), pos=center))
        else:
            raise ValueError(f"unsupported URDF geometry {shape.tag!r}")
    return _Link(mass, tuple(geoms))


def _joint_kind(urdf_joint: str) -> str:
    return urdf_joint.removeprefix("right_").removeprefix("left_")


def amp_skeleton(
    *,
    armature: float = 0.05,
    gain_scale: float = 1.0,
    torque_scale: float = 1.0,
    friction: float = 0.9,
    shoulder_turns: float = 0.5,
    shoulder_order: str = "yxz",
    urdf: str | Path | None = None,
) -> Skeleton:
    """The DeepMimic/AMP humanoid (15 bodies, 28 DoF) built from ``humanoid.urdf``.

    Args:
        armature: rotor inertia added to every hinge, kg m^2 (0.05 keeps the stiff PD stable at a
            1/120 s physics step).
        gain_scale: multiplies every kp and kd of the DeepMimic gain table.
        torque_scale: multiplies every torque limit.
        friction: sliding friction of the body geoms.
        shoulder_turns: the shoulders' y and z hinges range over ``+-shoulder_turns`` full turns
            (0.5: +-180 deg, :data:`BALL_RANGES`). The clips cross the decomposition's singularity
            and their unwrapped angles span up to 9.8 rad within a clip (:data:`FREE_SHOULDER_TURNS`).
        shoulder_order: the shoulders' hinge order, ``"yxz"`` (every ball joint's, :data:`BALL_ORDER`)
            or ``"xzy"`` (:data:`SHOULDER_ORDERS`: the order whose singularity the clips stay away from).
        urdf: another copy of DeepMimic's ``humanoid.urdf`` (default: pybullet_data's).
    """
    if shoulder_order not in SHOULDER_ORDERS:
        raise ValueError(f"shoulder_order must be one of {', '.join(SHOULDER_ORDERS)}, got {shoulder_order!r}")
    text = Path(urdf or urdf_path()).read_text(encoding="utf-8", errors="replace")
    root = ET.fromstring(text.replace("\x00", "").strip())  # the shipped file ends with a NUL byte
    links = {el.get("name"): _parse_link(el, URDF_SCALE) for el in root.findall("link")}
    joints = {el.get("name"): el for el in root.findall("joint")}
    link_index = {link: i for i, (_, link) in enumerate(BODY_LINKS)}

    bodies: list[Body] = []
    for name, link_name in BODY_LINKS:
        link = links[link_name]
        if link_name == "root":
            bodies.append(Body(name, -1, (0.0, 0.0, 0.0), Joint("fixed"), link.mass, link.geoms))
            continue
        jel = joints[link_name]
        parent_el, child_el, origin_el = jel.find("parent"), jel.find("child"), jel.find("origin")
        assert parent_el is not None and child_el is not None and child_el.get("link") == link_name
        parent = link_index[parent_el.get("link", "")]
        offset = _vec(_floats(origin_el.get("xyz")) if origin_el is not None else (0.0, 0.0, 0.0), URDF_SCALE)
        jtype = jel.get("type")
        kind = _joint_kind(link_name)
        joint: Joint
        if jtype == "fixed":
            joint = Joint("fixed")
        else:
            kp, kd, tau = GAINS[kind]
            kp, kd, tau = kp * gain_scale, kd * gain_scale, tau * torque_scale
            if jtype == "spherical":
                ranges, order = dict(BALL_RANGES[kind]), BALL_ORDER
                if kind == "shoulder":
                    order = shoulder_order
                    free = (-2.0 * math.pi * shoulder_turns, 2.0 * math.pi * shoulder_turns)
                    if order == "yxz":
                        ranges["y"] = ranges["z"] = free
                    else:  # x-z-y: the middle hinge (z, the twist) is within +-90 deg by construction
                        ranges = {"x": free, "z": deg(-90, 90), "y": free}
                if link_name.startswith("left_"):  # mirror about the sagittal plane: x and z flip sign
                    ranges["x"] = (-ranges["x"][1], -ranges["x"][0])
                    ranges["z"] = (-ranges["z"][1], -ranges["z"][0])
                joint = Joint(
                    "ball",
                    hinges(link_name, order, ranges, kp=kp, kd=kd, torque_limit=tau, armature=armature),
                )
            elif jtype == "revolute":
                axis_el, limit_el = jel.find("axis"), jel.find("limit")
                assert axis_el is not None and limit_el is not None
                ax = y_up_to_z_up(_floats(axis_el.get("xyz")))  # type: ignore[arg-type]
                ax = (_clean(ax[0]), _clean(ax[1]), _clean(ax[2]))
                rng = (float(limit_el.get("lower", "0")), float(limit_el.get("upper", "0")))
                joint = Joint("hinge", (Hinge(link_name, ax, rng, kp, kd, tau, armature),))
            else:
                raise ValueError(f"unsupported URDF joint type {jtype!r}")
        bodies.append(Body(name, parent, offset, joint, link.mass, link.geoms))

    skeleton = Skeleton(
        name="amp",
        bodies=tuple(bodies),
        end_effectors=END_EFFECTORS,
        feet=FEET,
        friction=friction,
        metadata={
            "source": "pybullet_data/humanoid/humanoid.urdf (DeepMimic), scale 0.25, y-up -> z-up",
            "ball_joint_order": BALL_ORDER,
            "shoulder_order": shoulder_order,
            "joint_rotation_from_y_up": "q' = (w, x, -z, y)",
        },
    )
    skeleton.validate()
    return skeleton
