"""Helpers shared by the built-in humanoid builders and by simulators that use their skeletons.

Everything here works on the rest pose, where every body frame is aligned with the world frame, so
positions simply add up along the tree and geoms need no rotation.
"""

from __future__ import annotations

import math

from mocap.skeleton import Geom, Hinge, Skeleton

X_AXIS = (1.0, 0.0, 0.0)
Y_AXIS = (0.0, 1.0, 0.0)
Z_AXIS = (0.0, 0.0, 1.0)
AXES = {"x": X_AXIS, "y": Y_AXIS, "z": Z_AXIS}


def deg(low: float, high: float) -> tuple[float, float]:
    """A (low, high) range given in degrees, returned in radians."""
    return (math.radians(low), math.radians(high))


def hinges(
    prefix: str,
    order: str,
    ranges: dict[str, tuple[float, float]],
    *,
    kp: float,
    kd: float,
    torque_limit: float,
    armature: float,
) -> tuple[Hinge, ...]:
    """Hinges ``{prefix}_{a}`` about the body axes named by ``order`` (e.g. ``"yxz"``), same gains."""
    return tuple(Hinge(f"{prefix}_{a}", AXES[a], ranges[a], kp=kp, kd=kd, torque_limit=torque_limit, armature=armature) for a in order)


def rest_body_positions(skeleton: Skeleton) -> list[tuple[float, float, float]]:
    """World positions of the body origins at rest with the root origin at (0, 0, 0)."""
    out: list[tuple[float, float, float]] = []
    for body in skeleton.bodies:
        if body.parent < 0:
            out.append((0.0, 0.0, 0.0))
        else:
            p = out[body.parent]
            out.append((p[0] + body.offset[0], p[1] + body.offset[1], p[2] + body.offset[2]))
    return out


def geom_min_z(geom: Geom) -> float:
    """Lowest z of ``geom`` in its (world-aligned) body frame."""
    if geom.type == "sphere":
        return geom.pos[2] - geom.size[0]
    if geom.type == "capsule":
        if geom.fromto is None:
            raise ValueError("capsule geoms need fromto")
        return min(geom.fromto[2], geom.fromto[5]) - geom.size[0]
    if geom.type == "box":
        return geom.pos[2] - geom.size[2]
    raise ValueError(f"unknown geom type {geom.type!r}")


def geom_volume(geom: Geom) -> float:
    """Volume of ``geom``, m^3 (the formulas MuJoCo uses to infer mass from density)."""
    r = geom.size[0]
    if geom.type == "sphere":
        return 4.0 / 3.0 * math.pi * r**3
    if geom.type == "capsule":
        if geom.fromto is None:
            raise ValueError("capsule geoms need fromto")
        a, b = geom.fromto[:3], geom.fromto[3:]
        length = math.dist(a, b)
        return math.pi * r * r * length + 4.0 / 3.0 * math.pi * r**3
    if geom.type == "box":
        return 8.0 * geom.size[0] * geom.size[1] * geom.size[2]
    raise ValueError(f"unknown geom type {geom.type!r}")


def rest_root_height(skeleton: Skeleton, clearance: float = 0.0) -> float:
    """Root height at which the lowest geom of the rest pose sits ``clearance`` above z = 0."""
    positions = rest_body_positions(skeleton)
    lowest = min(positions[i][2] + geom_min_z(g) for i, body in enumerate(skeleton.bodies) for g in body.geoms)
    return clearance - lowest


def geom_masses(skeleton: Skeleton) -> list[list[float]]:
    """Per body, the mass of each geom: explicit densities are kept, the rest of the body's mass
    is spread over the geoms without a density in proportion to their volume."""
    out: list[list[float]] = []
    for body in skeleton.bodies:
        volumes = [geom_volume(g) for g in body.geoms]
        fixed = [g.density * v if g.density is not None else None for g, v in zip(body.geoms, volumes)]
        free_volume = sum(v for f, v in zip(fixed, volumes) if f is None)
        remaining = body.mass - sum(f for f in fixed if f is not None)
        if free_volume > 0 and remaining <= 0:
            raise ValueError(f"body {body.name!r}: geoms with explicit density already exceed its mass")
        out.append([f if f is not None else remaining * v / free_volume for f, v in zip(fixed, volumes)])
    return out
