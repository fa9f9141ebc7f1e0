"""Skeleton definitions: the single source of truth for a humanoid.

A :class:`Skeleton` lists bodies in a fixed order (parents before children, body 0 the free-floating
root). Every non-root body hangs from its parent by a :class:`Joint` made of 0 (fixed), 1 (hinge)
or 3 (ball, as three hinges in a stated order) hinge DoFs. Simulators generate their model (MJCF
for MuJoCo) from this description, forward kinematics in :mod:`mocap.kinematics` uses it, and the
motion library maps clips onto its DoFs. Nothing about a humanoid is written twice.

Frames: each body's frame at rest (all DoFs zero) is aligned with the world frame (z up, x
forward, y left); ``offset`` is the body origin in its parent's frame at rest, m. Hinge axes are
unit vectors in the body's own frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Literal

GeomType = Literal["sphere", "capsule", "box"]


@dataclass(frozen=True)
class Geom:
    """A collision/visual shape attached to a body, in the body frame.

    ``capsule`` uses ``fromto`` (6 numbers: two end points) and ``size[0]`` as the radius;
    ``sphere`` uses ``pos`` and ``size[0]``; ``box`` uses ``pos`` and half-sizes ``size[0:3]``.
    """

    type: GeomType
    size: tuple[float, ...]
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    fromto: tuple[float, float, float, float, float, float] | None = None
    density: float | None = None  # kg/m^3; None lets the body's mass decide


@dataclass(frozen=True)
class Hinge:
    """One actuated rotational DoF.

    Attributes:
        name: DoF name, unique in the skeleton (e.g. ``right_hip_y``).
        axis: rotation axis in the body frame (unit vector).
        range: (low, high) joint limit, rad.
        kp, kd: PD gains of the position actuator (N m / rad, N m s / rad).
        torque_limit: actuator force range (symmetric), N m.
        armature: rotor inertia added to the DoF, kg m^2 (stabilizes stiff PD at large dt).
    """

    name: str
    axis: tuple[float, float, float]
    range: tuple[float, float]
    kp: float
    kd: float
    torque_limit: float
    armature: float = 0.05


@dataclass(frozen=True)
class Joint:
    """The joint between a body and its parent: ``hinges`` in application order.

    A ball joint is three hinges; the local rotation is ``R(h0) @ R(h1) @ R(h2)`` (intrinsic
    order). ``kind`` is informative (``fixed`` has no hinges).
    """

    kind: Literal["fixed", "hinge", "ball"]
    hinges: tuple[Hinge, ...] = ()


@dataclass(frozen=True)
class Body:
    """A rigid body of the skeleton.

    Attributes:
        name: body name (unique).
        parent: index of the parent body, -1 for the root.
        offset: body origin in the parent frame at rest, m.
        joint: joint to the parent (ignored for the root, which is free-floating).
        mass: body mass, kg (geoms' inertia is scaled to it).
        geoms: shapes attached to the body.
    """

    name: str
    parent: int
    offset: tuple[float, float, float]
    joint: Joint
    mass: float
    geoms: tuple[Geom, ...]


@dataclass(frozen=True)
class Skeleton:
    """A humanoid's kinematic tree, actuation and shapes.

    Attributes:
        name: humanoid name (registry name, e.g. ``amp``).
        bodies: bodies in order, parents first; body 0 is the root.
        end_effectors: names of hands/feet/head bodies (for rewards and metrics).
        feet: names of the bodies allowed to touch the ground without it counting as a fall.
        friction: sliding friction of body geoms.
    """

    name: str
    bodies: tuple[Body, ...]
    end_effectors: tuple[str, ...] = ()
    feet: tuple[str, ...] = ()
    friction: float = 0.9
    metadata: dict[str, str] = field(default_factory=dict, compare=False, hash=False)

    @cached_property
    def body_names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.bodies)

    @cached_property
    def parents(self) -> tuple[int, ...]:
        return tuple(b.parent for b in self.bodies)

    @cached_property
    def hinges(self) -> tuple[Hinge, ...]:
        """All hinge DoFs in DoF order (bodies in order, each joint's hinges in order)."""
        return tuple(h for b in self.bodies[1:] for h in b.joint.hinges)

    @cached_property
    def dof_names(self) -> tuple[str, ...]:
        return tuple(h.name for h in self.hinges)

    @property
    def num_bodies(self) -> int:
        return len(self.bodies)

    @property
    def num_dofs(self) -> int:
        return len(self.hinges)

    @cached_property
    def dof_slices(self) -> tuple[slice, ...]:
        """Per body, the slice of its hinges in the DoF vector (empty for root and fixed)."""
        out, start = [slice(0, 0)], 0
        for body in self.bodies[1:]:
            n = len(body.joint.hinges)
            out.append(slice(start, start + n))
            start += n
        return tuple(out)

    def body_index(self, name: str) -> int:
        try:
            return self.body_names.index(name)
        except ValueError:
            raise KeyError(f"skeleton {self.name!r} has no body {name!r}; bodies: {', '.join(self.body_names)}") from None

    @property
    def total_mass(self) -> float:
        return float(sum(b.mass for b in self.bodies))

    def validate(self) -> None:
        """Raise ``ValueError`` if the tree is malformed (parents after children, duplicate names)."""
        if not self.bodies or self.bodies[0].parent != -1:
            raise ValueError(f"skeleton {self.name!r}: body 0 must be the root (parent -1)")
        if len(set(self.body_names)) != len(self.body_names):
            raise ValueError(f"skeleton {self.name!r}: duplicate body names")
        if len(set(self.dof_names)) != len(self.dof_names):
            raise ValueError(f"skeleton {self.name!r}: duplicate DoF names")
        for i, body in enumerate(self.bodies[1:], start=1):
            if not 0 <= body.parent < i:
                raise ValueError(f"skeleton {self.name!r}: body {body.name!r} has parent {body.parent}, must precede it")
            if body.joint.kind == "fixed" and body.joint.hinges:
                raise ValueError(f"skeleton {self.name!r}: fixed joint of {body.name!r} has hinges")
        for name in (*self.end_effectors, *self.feet):
            self.body_index(name)
