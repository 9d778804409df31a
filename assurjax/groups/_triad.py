"""Class III triad: a ternary link T with internal joints P1, P2, P3, each pinned to
a binary link i whose other end is the external joint Ei (three external joints).

4 links, 6 revolutes (P1, P2, P3 internal; E1, E2, E3 external): zero DOF."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array

from .._geometry import dot, rotate, rotation, wrap_angle
from .._errors import MechanismError
from ._base import Link, frame_from_rotation, frame_through
from ._newton import IterativeGroup, parse_guess, parse_options, angle_of


class Triad(IterativeGroup):
    """Class III triad, solved by Newton on two link angles (see ``_newton``).

    ``links`` = (T, L1, L2, L3): the ternary link, then the binary link i that joins
    the external joint Ei to the ternary's joint Pi. ``joints`` = (E1, E2, E3, P1, P2, P3).
    ``guess``: approximate global positions (m) of P1, P2, P3 at ``guess_q``
    (default: the scene's ``[state] q0``); they select the assembly branch, which
    is then followed continuously (there is no ``mode``: a triad has up to six
    assemblies, which no single sign can name).

    **Unknowns** z = (a1, t): the frame angles (rad) of L1 and of T. Then
    P1 = E1 + R(a1)(P1 - E1)_L1 and T is placed through P1 with angle t, so the
    residual is the closure of the two other binary links:

        F_i(z) = (|Pi(z) - Ei|^2 / r_i^2 - 1) / 2 = 0,   i = 2, 3,

    with r_i the length of Li (dimensionless: relative length error). Why two
    unknowns: one (a1 alone, P2 and P3 from circle intersections) needs an inner
    assembly mode and a residual that is undefined where the circles miss, which
    Newton steps hit; three (the pose of T) is a larger system for nothing. The
    two-angle residual is a trigonometric polynomial, smooth everywhere, its 2x2
    Jacobian is singular exactly at the triad's singular (dead-centre)
    configurations, and the unknowns are link angles, so a previous
    ``Pose.angles`` is directly a predictor (``positions(..., near=...)``).

    **Example** (scene): ``group = "triad"``, ``links = ["T", "L1", "L2", "L3"]``,
    ``joints = ["E1", "E2", "E3", "P1", "P2", "P3"]``,
    ``guess = { P1 = [0.1, 0.2], P2 = [...], P3 = [...] }``.
    """

    kind = "triad"

    def __check_init__(self):
        if len(self.links) != 4 or len(self.joints) != 6:
            raise MechanismError(f"triad '{self.name}': needs 4 links (T, L1, L2, L3) and 6 joints (E1, E2, E3, P1, P2, P3)")

    def external_points(self):
        return self.joints[:3]

    def internal_points(self):
        return self.joints[3:]

    def unknown_links(self):
        return (self.links[1], self.links[0])

    def required_points(self):
        t, *binaries = self.links
        e, p = self.joints[:3], self.joints[3:]
        return {t: tuple(p), **{b: (e[i], p[i]) for i, b in enumerate(binaries)}}

    def geometry(self, links: dict[str, Link]) -> dict[str, Array]:
        t, l1, l2, l3 = self.links
        e1, e2, e3, p1, p2, p3 = self.joints
        tp = links[t].points
        return dict(
            e1_l1=links[l1].points[e1], p1_l1=links[l1].points[p1],
            p1_t=tp[p1], p2_t=tp[p2], p3_t=tp[p3],
            e2_l2=links[l2].points[e2], p2_l2=links[l2].points[p2],
            e3_l3=links[l3].points[e3], p3_l3=links[l3].points[p3],
        )

    # ``ext`` is the tuple of global (E1, E2, E3). ``residual`` is static (global):
    # optimistix differentiates through its arguments only.

    @staticmethod
    def internal_positions(z, ext, geo):
        """Global P1, P2, P3 (m) for the unknown angles z = (a1, t)."""
        e1, _, _ = ext
        p1 = e1 + rotate(geo["p1_l1"] - geo["e1_l1"], rotation(z[0]))
        rot_t = rotation(z[1])
        p2 = p1 + rotate(geo["p2_t"] - geo["p1_t"], rot_t)
        p3 = p1 + rotate(geo["p3_t"] - geo["p1_t"], rot_t)
        return p1, p2, p3

    @staticmethod
    def residual(z, args):
        ext, geo = args
        _, p2, p3 = Triad.internal_positions(z, ext, geo)
        out = []
        for p, e, (a, b) in ((p2, ext[1], ("e2_l2", "p2_l2")), (p3, ext[2], ("e3_l3", "p3_l3"))):
            r = geo[a] - geo[b]
            d = p - e
            out.append(0.5 * (dot(d, d) / dot(r, r) - 1.0))
        return jnp.stack(out)

    def frames(self, z, ext, geo):
        t, l1, l2, l3 = self.links
        e1, e2, e3 = ext
        p1, p2, p3 = Triad.internal_positions(z, ext, geo)
        return {
            l1: frame_from_rotation(geo["e1_l1"], e1, rotation(z[0])),
            t: frame_from_rotation(geo["p1_t"], p1, rotation(z[1])),
            l2: frame_through(geo["e2_l2"], geo["p2_l2"], e2, p2),
            l3: frame_through(geo["e3_l3"], geo["p3_l3"], e3, p3),
        }

    def angles_from_guess(self, guess, ext, geo):
        """Starting angles from the guessed P1, P2, P3: L1 through E1 -> P1, T through P1 -> P2 and P1 -> P3 (mean)."""
        e1 = ext[0]
        g1, g2, g3 = (guess[p] for p in self.internal_points())
        a1 = angle_of(geo["p1_l1"] - geo["e1_l1"], g1 - e1)
        t2 = angle_of(geo["p2_t"] - geo["p1_t"], g2 - g1)
        t3 = angle_of(geo["p3_t"] - geo["p1_t"], g3 - g1)
        t = t2 + wrap_angle(t3 - t2) / 2  # circular mean of the two estimates
        return jnp.stack([a1, t])


def parse_triad(fields, name: str) -> Triad:
    """The scene parser of ``group = "triad"`` (fields: links, joints, guess; optional guess_q, substeps, max_steps)."""
    links, joints = fields.names("links", 4), fields.names("joints", 6)
    return Triad(name, links, joints, parse_guess(fields, joints[3:]), **parse_options(fields))
