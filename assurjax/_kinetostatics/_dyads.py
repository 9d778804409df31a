"""Class-II RRR dyad in closed form. The dyads with prismatic pairs (RRP, PRR,
RPR, PRP) solve their own 6 x 6 system (two links, three equations each) with
:func:`._system.solve_dense`, the fallback of :func:`._api.solve_groups`."""

import jax.numpy as jnp

from .._geometry import cross, safe_norm
from ._system import SINGULAR, Geometry, Reaction, moment_about


def solve_rrr(group, pairs, geom: Geometry, known):
    """RRR dyad, links (a, b), joints (E1, E2, J), closed form.

    Moments about the internal joint J of each link alone eliminate the internal
    reaction: d1 x R1 = -Ma and d2 x R2 = -Mb with d_i = E_i - J; the force sum of
    the dyad gives R2 = -R1 - fa - fb. That leaves a 2 x 2 system for R1 whose
    determinant d1 x d2 vanishes when E1, J, E2 are collinear (singular dyad).
    R1 on a at E1, R2 on b at E2, RJ = R1 + fa on b by a at J.
    """
    (a, b), (e1, e2, j) = group.links, group.joints
    by_point = {(p.point, p.on): p for p in pairs}
    p1, p2, pj = by_point[(e1, a)], by_point[(e2, b)], by_point[(j, b)]
    fa, fb = known[a][0], known[b][0]
    xj = geom.points[j]
    d1, d2 = geom.points[e1] - xj, geom.points[e2] - xj
    ma_j, mb_j = moment_about(geom, known, a, xj), moment_about(geom, known, b, xj)
    c1 = -ma_j
    c2 = mb_j - cross(d2, fa + fb)
    det = cross(d1, d2)
    ok = jnp.abs(det) > SINGULAR * safe_norm(d1) * safe_norm(d2)
    det = jnp.where(ok, det, 1.0)
    r1 = jnp.where(ok, jnp.stack([d2[0] * c1 - d1[0] * c2, d2[1] * c1 - d1[1] * c2]) / det, 0.0)
    rj = r1 + fa
    r2 = -rj - fb
    zero = jnp.zeros(())
    return {p1.name: Reaction(r1, zero), p2.name: Reaction(r2, zero), pj.name: Reaction(rj, zero)}, None, ok
