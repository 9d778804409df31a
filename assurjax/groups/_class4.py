"""Class IV Assur group (Calle et al. 2014): two ternary links, each with one
external joint and two internal joints, joined by two binary closure links.

The paper's numbering: ternary link 2 carries B (external), C and E; ternary link 4
carries G (external), D and F; closure link 3 joins C and D, closure link 5
joins E and F. 4 links, 6 revolutes (C, D, E, F internal; B, G external)."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array

from .._geometry import dot, rotate, rotation, wrap_angle
from .._errors import MechanismError
from ._base import Link, frame_from_rotation, frame_through
from ._newton import IterativeGroup, parse_guess, parse_options, angle_of


class ClassIV(IterativeGroup):
    """Class IV group, solved by Newton on the two ternary links' angles (see ``_newton``).

    ``links`` = (link2, link3, link4, link5) in the paper's order: ternary, closure,
    ternary, closure. ``joints`` = (B, G, C, D, E, F): B is the external joint of
    link2, G that of link4; link3 joins C (on link2) to D (on link4), link5 joins
    E (on link2) to F (on link4). ``guess``: approximate global positions (m) of
    C, D, E, F at ``guess_q`` (default: the scene's ``[state] q0``); it selects the
    assembly branch, which is then followed continuously.

    **Unknowns** z = (phi2, phi4): the frame angles (rad) of the two ternary links,
    each turning about its (known) external joint. The residual is the closure
    of the two binary links:

        F_3 = (|D(phi4) - C(phi2)|^2 / l3^2 - 1) / 2,   F_5 = (|F(phi4) - E(phi2)|^2 / l5^2 - 1) / 2,

    dimensionless (relative length errors). Two unknowns is the minimum without
    inner assembly modes (one angle plus a circle intersection would need a mode
    and be undefined where the circles miss); the residual is smooth everywhere
    and its Jacobian is singular exactly at the group's singular configurations
    (there the paper's special points S3, S5 of the closure links coincide with
    the lines they are built from).

    **Example** (scene): ``group = "class4"``, ``links = ["link2", "link3", "link4", "link5"]``,
    ``joints = ["B", "G", "C", "D", "E", "F"]``, ``guess = { C = [...], D = [...], E = [...], F = [...] }``.
    """

    kind = "class4"

    def __check_init__(self):
        if len(self.links) != 4 or len(self.joints) != 6:
            raise MechanismError(f"class4 group '{self.name}': needs 4 links (link2, link3, link4, link5) and 6 joints (B, G, C, D, E, F)")

    def external_points(self):
        return self.joints[:2]

    def internal_points(self):
        return self.joints[2:]

    def unknown_links(self):
        return (self.links[0], self.links[2])

    def required_points(self):
        l2, l3, l4, l5 = self.links
        b, g, c, d, e, f = self.joints
        return {l2: (b, c, e), l3: (c, d), l4: (g, d, f), l5: (e, f)}

    def geometry(self, links: dict[str, Link]) -> dict[str, Array]:
        l2, l3, l4, l5 = self.links
        b, g, c, d, e, f = self.joints
        p2, p3, p4, p5 = (links[k].points for k in self.links)
        return dict(
            b_2=p2[b], c_2=p2[c], e_2=p2[e],
            g_4=p4[g], d_4=p4[d], f_4=p4[f],
            c_3=p3[c], d_3=p3[d], e_5=p5[e], f_5=p5[f],
        )

    @staticmethod
    def internal_positions(z, ext, geo):
        """Global C, D, E, F (m) for the ternary angles z = (phi2, phi4); ext = (B, G)."""
        b, g = ext
        r2, r4 = rotation(z[0]), rotation(z[1])
        c = b + rotate(geo["c_2"] - geo["b_2"], r2)
        e = b + rotate(geo["e_2"] - geo["b_2"], r2)
        d = g + rotate(geo["d_4"] - geo["g_4"], r4)
        f = g + rotate(geo["f_4"] - geo["g_4"], r4)
        return c, d, e, f

    @staticmethod
    def residual(z, args):
        ext, geo = args
        c, d, e, f = ClassIV.internal_positions(z, ext, geo)
        l3 = geo["d_3"] - geo["c_3"]
        l5 = geo["f_5"] - geo["e_5"]
        return jnp.stack([0.5 * (dot(d - c, d - c) / dot(l3, l3) - 1.0), 0.5 * (dot(f - e, f - e) / dot(l5, l5) - 1.0)])

    def frames(self, z, ext, geo):
        l2, l3, l4, l5 = self.links
        b, g = ext
        c, d, e, f = ClassIV.internal_positions(z, ext, geo)
        return {
            l2: frame_from_rotation(geo["b_2"], b, rotation(z[0])),
            l3: frame_through(geo["c_3"], geo["d_3"], c, d),
            l4: frame_from_rotation(geo["g_4"], g, rotation(z[1])),
            l5: frame_through(geo["e_5"], geo["f_5"], e, f),
        }

    def special_points(self, points: dict[str, Array]) -> dict[str, Array]:
        """The special Assur points of Calle et al. 2014 from global joint positions (m), e.g. a
        ``Pose.points``: S3 (of closure link 3) = intersection of lines BC and GD,
        S5 (of closure link 5) = intersection of lines BE and GF. The normal components
        of the internal joint forces point at them. Far away (or inf) when the lines
        are parallel."""
        b, g, c, d, e, f = (points[p] for p in self.joints)
        return {"S3": _line_intersection(b, c - b, g, d - g), "S5": _line_intersection(b, e - b, g, f - g)}

    def angles_from_guess(self, guess, ext, geo):
        """Starting angles from the guessed C, D, E, F: each ternary's angle is the
        circular mean of the angles implied by its two internal joints."""
        b, g = ext
        c, d, e, f = (guess[p] for p in self.internal_points())

        def mean_angle(origin, local_origin, pairs):
            (l1, p1), (l2, p2) = pairs
            a1 = angle_of(l1 - local_origin, p1 - origin)
            a2 = angle_of(l2 - local_origin, p2 - origin)
            return a1 + wrap_angle(a2 - a1) / 2

        phi2 = mean_angle(b, geo["b_2"], ((geo["c_2"], c), (geo["e_2"], e)))
        phi4 = mean_angle(g, geo["g_4"], ((geo["d_4"], d), (geo["f_4"], f)))
        return jnp.stack([phi2, phi4])


def _line_intersection(p, u, r, v):
    """Intersection of the lines p + s u and r + t v (Cramer's rule)."""
    w = r - p
    s = (w[..., 0] * v[..., 1] - w[..., 1] * v[..., 0]) / (u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0])
    return p + s[..., None] * u


def parse_class4(fields, name: str) -> ClassIV:
    """The scene parser of ``group = "class4"`` (fields: links, joints, guess; optional guess_q, substeps, max_steps)."""
    links, joints = fields.names("links", 4), fields.names("joints", 6)
    return ClassIV(name, links, joints, parse_guess(fields, joints[2:]), **parse_options(fields))
