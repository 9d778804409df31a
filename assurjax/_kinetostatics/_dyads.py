"""Class-II RRR and RRP dyads in closed form. The other dyads with prismatic pairs (PRR,
RPR, PRP) solve their own 6 x 6 system (two links, three equations each) with
:func:`._system.solve_dense`, the fallback of :func:`._api.solve_groups`."""

import jax.numpy as jnp

from .._geometry import cross, safe_norm
from ._system import SINGULAR, Geometry, Reaction, guide_normal, moment_about


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


def solve_rrp(group, pairs, geom: Geometry, known):
    """RRP dyad, links (rod, slider), joints (E, J), the slider on its guide at J; closed form.

    The slider's forces R_J + N n + f_s = 0 and the rod's R_E - R_J + f_r = 0 give
    R_E = -f_r - f_s - N n; the rod's moments about J, d x R_E = -M_r (d = E - J),
    give N = (M_r - d x (f_r + f_s)) / (d x n), singular when the rod is normal to the
    guide; the slider's moments about J give the guide's couple C = -M_s. R_E on the
    rod at E, R_J on the slider by the rod at J, N n and C on the slider by the guide.
    """
    (rod, slider), (e, j) = group.links, group.joints
    by_point = {(p.point, p.on, p.kind): p for p in pairs}
    pe, pj, guide = by_point[(e, rod, "R")], by_point[(j, slider, "R")], by_point[(j, slider, "P")]
    fr, fs = known[rod][0], known[slider][0]
    xj = geom.points[j]
    d, n = geom.points[e] - xj, guide_normal(geom, guide)
    det = cross(d, n)
    ok = jnp.abs(det) > SINGULAR * safe_norm(d)
    normal = jnp.where(ok, (moment_about(geom, known, rod, xj) - cross(d, fr + fs)) / jnp.where(ok, det, 1.0), 0.0)
    rj = -fs - normal * n
    zero = jnp.zeros(())
    return {pe.name: Reaction(rj - fr, zero), pj.name: Reaction(rj, zero),
            guide.name: Reaction(normal * n, -moment_about(geom, known, slider, xj))}, None, ok
