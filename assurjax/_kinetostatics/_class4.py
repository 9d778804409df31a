"""Class-IV group with the special Assur points of its two closure links (Calle et al. 2014).

The group: two ternary *dragging* links T1, T2, each with one external joint
X1, X2 (to earlier links) and two internal joints, and two binary *closure* links
C, D, each pinned to T1 and to T2. The reaction on a closure link at its joint P
with Tk is split into a *normal* component along P -> Xk and a *tangential* one
perpendicular to it (left normal). The special point S of a closure link is the
intersection of its two normal lines (line X1 P1 and line X2 P2): in Calle et al. 2014,
S3 = BC x GD for link 3 and S5 = BE x GF for link 5.

1. Moments of each closure link about its special point and of each dragging link
   about its external joint contain only the four tangential components
   (Calle et al. 2014 eqs. 2, 4, 6, 8): a 4 x 4 linear system.
2. The force sum of each closure link gives its two normal components
   (eqs. 9, 10): two 2 x 2 systems.
3. The force sum of each dragging link gives its external reaction (eqs. 11, 12).

When a closure link's two normal lines are parallel its special point is at
infinity: its moment equation is written multiplied by the sine of the angle
between the normals, so it turns continuously into the force balance across them,
and the normal components then come from the link's moments about its joints.
The general 12 x 12 solve of the group (``solve_dense``) is kept as a reference
(``method="dense"``).
"""

from __future__ import annotations

import jax.numpy as jnp

from .._errors import MechanismError
from .._geometry import cross, perp, safe_norm, unit
from ._system import SINGULAR, Geometry, Reaction, moment_about, solve_flagged


def class4_topology(group, pairs):
    """(T1, X-pair 1), (T2, X-pair 2) and for each closure link its pairs with T1 and T2;
    None when the group does not have the class-IV structure."""
    links = set(group.links)
    external = [p for p in pairs if p.by not in links]
    internal = [p for p in pairs if p.by in links]
    if len(group.links) != 4 or len(external) != 2 or len(internal) != 4 or any(p.kind != "R" for p in pairs):
        return None
    t1, t2 = external[0].on, external[1].on
    closures = [link for link in group.links if link not in (t1, t2)]
    if t1 == t2 or len(closures) != 2:
        return None
    joined = {}
    for p in internal:
        ends = {p.on, p.by}
        closure = ends & set(closures)
        drag = ends & {t1, t2}
        if len(closure) != 1 or len(drag) != 1:
            return None
        joined[(closure.pop(), drag.pop())] = p
    if len(joined) != 4:
        return None
    return external, closures, joined


NORMALS_BY_FORCES = 0.1
"""Below this sine of the angle between a closure link's normals, its normal
components come from moments about its joints instead of its force sum."""


def solve_class4_special(group, pairs, geom: Geometry, known):
    """The special-point method: a 4 x 4 system for the tangential components, then
    closed forms for the normal components and the external reactions."""
    topology = class4_topology(group, pairs)
    if topology is None:
        raise MechanismError(f"{group.describe()}: not a class-IV group (two ternary links with one external joint each, two binary closure links)")
    external, closures, joined = topology
    drags = [external[0].on, external[1].on]
    xs = [geom.points[external[0].point], geom.points[external[1].point]]
    at = {key: geom.points[p.point] for key, p in joined.items()}
    e_n = {key: unit(xs[drags.index(key[1])] - at[key]) for key in joined}  # normal: towards the external joint
    e_t = {key: perp(v) for key, v in e_n.items()}  # tangential: its left normal
    order = [(c, d) for c in closures for d in drags]  # the four tangential unknowns
    rows, rhs = [], []
    for c in closures:  # eqs. 2 and 4: closure link about its special point
        row, known_moment = _about_special_point(geom, known, c, drags, at, e_n, e_t, order)
        rows.append(row)
        rhs.append(-known_moment)
    for d, x in zip(drags, xs):  # eqs. 6 and 8: dragging link about its external joint
        rows.append(jnp.stack([-cross(at[k] - x, e_t[k]) if k[1] == d else jnp.zeros(()) for k in order]))
        rhs.append(-moment_about(geom, known, d, x))
    t, ok = solve_flagged(jnp.stack(rows), jnp.stack(rhs))
    tangential = dict(zip(order, t))
    force = {}
    for c in closures:  # eqs. 9 and 10
        k1, k2 = (c, drags[0]), (c, drags[1])
        n1, n2, ok_n = _normal_components(geom, known, c, at[k1], at[k2], e_n[k1], e_n[k2], e_t[k1], e_t[k2], tangential[k1], tangential[k2])
        ok = ok & ok_n
        force[k1] = tangential[k1] * e_t[k1] + n1 * e_n[k1]
        force[k2] = tangential[k2] * e_t[k2] + n2 * e_n[k2]
    zero = jnp.zeros(())
    out = {}
    for key, p in joined.items():  # stored as the force on p.on by p.by
        out[p.name] = Reaction(force[key] if p.on == key[0] else -force[key], zero)
    for p, d in zip(external, drags):  # eqs. 11 and 12: external reaction from the dragging link's force sum
        r = sum((force[(c, d)] for c in closures), jnp.zeros(2)) - known[d][0]
        out[p.name] = Reaction(r, zero)
    return out, None, ok


def _about_special_point(geom, known, c, drags, at, e_n, e_t, order):
    """Moment equation of closure link c about its special point S, multiplied by
    den = n1 x n2 so that it stays finite when the normal lines are parallel (S at
    infinity: the equation becomes the force balance across the normals).
    With S = p1 + s n1, s = ((p2 - p1) x n2) / den, a moment about S is
    M_p1 - s n1 x F, hence den M_S = den M_p1 - ((p2 - p1) x n2) n1 x F."""
    k1, k2 = (c, drags[0]), (c, drags[1])
    p1, n1 = at[k1], e_n[k1]
    den = cross(n1, e_n[k2])
    lever = cross(at[k2] - p1, e_n[k2])
    row = jnp.stack(
        [den * cross(at[k] - p1, e_t[k]) - lever * cross(n1, e_t[k]) if k[0] == c else jnp.zeros(()) for k in order]
    )
    f, _ = known[c]
    return row, den * moment_about(geom, known, c, p1) - lever * cross(n1, f)


def _normal_components(geom, known, c, p1, p2, n1, n2, t1, t2, tan1, tan2):
    """Normal components (N) at the closure link's two joints: from its force sum
    (Calle et al. 2014 eqs. 9, 10) when the normals are far from parallel; otherwise from its
    moments about each joint in turn (each eliminates that joint's force)."""
    rest = -(known[c][0] + tan1 * t1 + tan2 * t2)
    den = cross(n1, n2)
    use_forces = jnp.abs(den) > NORMALS_BY_FORCES
    safe = lambda x: jnp.where(jnp.abs(x) > 0, x, 1.0)  # noqa: E731
    by_forces = (cross(rest, n2) / safe(den), cross(n1, rest) / safe(den))
    d12 = p2 - p1
    den1, den2 = cross(-d12, n1), cross(d12, n2)
    by_moments = (
        -(moment_about(geom, known, c, p2) + tan1 * cross(-d12, t1)) / safe(den1),
        -(moment_about(geom, known, c, p1) + tan2 * cross(d12, t2)) / safe(den2),
    )
    length = safe_norm(d12)
    ok = use_forces | (jnp.minimum(jnp.abs(den1), jnp.abs(den2)) > SINGULAR * length)
    n_1 = jnp.where(use_forces, by_forces[0], by_moments[0])
    n_2 = jnp.where(use_forces, by_forces[1], by_moments[1])
    return n_1, n_2, ok
