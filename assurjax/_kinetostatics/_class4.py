"""Class-IV group with the special Assur points of its two closure links (seed 003).

The group: two ternary *dragging* links T1, T2, each with one external joint
X1, X2 (to earlier links) and two internal joints, and two binary *closure* links
C, D, each pinned to T1 and to T2. The reaction on a closure link at its joint P
with Tk is split into a *normal* component along P -> Xk and a *tangential* one
perpendicular to it (left normal). The special point S of a closure link is the
intersection of its two normal lines (line X1 P1 and line X2 P2): in seed 003,
S3 = BC x GD for link 3 and S5 = BE x GF for link 5.

1. Moments of each closure link about its special point and of each dragging link
   about its external joint contain only the four tangential components
   (seed 003 eqs. 2, 4, 6, 8): a 4 x 4 linear system.
2. The force sum of each closure link gives its two normal components
   (eqs. 9, 10): two 2 x 2 systems.
3. The force sum of each dragging link gives its external reaction (eqs. 11, 12).

When a closure link's two normal lines are parallel its special point is at
infinity; the general 12 x 12 solve of the group (``solve_dense``) is used then.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._errors import MechanismError
from .._geometry import cross, perp, safe_norm, unit
from ._system import SINGULAR, Geometry, Reaction, solve_dense, solve_flagged


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


def _special_point(p1, n1, p2, n2):
    """Intersection of the lines p1 + s n1 and p2 + r n2, and a flag (False: parallel)."""
    den = cross(n1, n2)
    ok = jnp.abs(den) > SINGULAR
    s = cross(p2 - p1, n2) / jnp.where(ok, den, 1.0)
    return p1 + s * n1, ok


def _moment_about(geom, known, link, centre):
    f, m = known[link]
    return m + cross(geom.coms[link] - centre, f)


def solve_class4_special(group, pairs, geom: Geometry, known):
    """The special-point method; falls back to the 12 x 12 solve when a special point is at infinity."""
    topology = class4_topology(group, pairs)
    if topology is None:
        raise MechanismError(f"{group.describe()}: not a class-IV group (two ternary links with one external joint each, two binary closure links)")
    external, closures, joined = topology
    drags = [external[0].on, external[1].on]
    xs = [geom.points[external[0].point], geom.points[external[1].point]]
    # normal (towards the dragging link's external joint) and tangential directions
    at = {key: geom.points[p.point] for key, p in joined.items()}
    e_n = {key: unit(xs[drags.index(key[1])] - at[key]) for key in joined}
    e_t = {key: perp(v) for key, v in e_n.items()}
    specials, parallel_free = [], jnp.array(True)
    for c in closures:
        k1, k2 = (c, drags[0]), (c, drags[1])
        s, ok = _special_point(at[k1], e_n[k1], at[k2], e_n[k2])
        specials.append(s)
        parallel_free = parallel_free & ok

    def special(_):
        return _special_solution(group, pairs, geom, known, external, closures, joined, drags, xs, at, e_n, e_t, specials)

    def general(_):
        return solve_dense(group.links, pairs, geom, known)

    return jax.lax.cond(parallel_free, special, general, None)


def _special_solution(group, pairs, geom, known, external, closures, joined, drags, xs, at, e_n, e_t, specials):
    order = [(c, d) for c in closures for d in drags]  # unknown tangential components
    rows, rhs = [], []
    for c, s in zip(closures, specials):  # eqs. 2 and 4: closure link about its special point
        rows.append(jnp.stack([cross(at[k] - s, e_t[k]) if k[0] == c else jnp.zeros(()) for k in order]))
        rhs.append(-_moment_about(geom, known, c, s))
    for d, x in zip(drags, xs):  # eqs. 6 and 8: dragging link about its external joint
        rows.append(jnp.stack([-cross(at[k] - x, e_t[k]) if k[1] == d else jnp.zeros(()) for k in order]))
        rhs.append(-_moment_about(geom, known, d, x))
    t, ok = solve_flagged(jnp.stack(rows), jnp.stack(rhs))
    tangential = dict(zip(order, t))
    force = {}
    for c in closures:  # eqs. 9 and 10: normal components from the closure link's force sum
        k1, k2 = (c, drags[0]), (c, drags[1])
        rest = -(known[c][0] + tangential[k1] * e_t[k1] + tangential[k2] * e_t[k2])
        den = cross(e_n[k1], e_n[k2])
        den = jnp.where(jnp.abs(den) > SINGULAR, den, 1.0)
        n1, n2 = cross(rest, e_n[k2]) / den, cross(e_n[k1], rest) / den
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
