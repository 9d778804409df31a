"""Class-II dyads in closed form: RRR and the dyads with prismatic pairs (RRP, PRR,
RPR, PRP). Each solves its two links' six equilibrium equations by force sums and
moments about points where unknowns drop out, with no matrix; a singular dyad (the
determinant of the closed form is zero exactly where its 6 x 6 system is singular)
gets ok = False and zero reactions."""

import jax.numpy as jnp

from .._geometry import cross, safe_norm
from ._system import SINGULAR, Geometry, Reaction, guide_normal, moment_about


def _divided(numerator, det, ok):
    """numerator / det where the dyad is regular (``ok``), 0 where it is singular (never NaN)."""
    return jnp.where(ok, numerator / jnp.where(ok, det, 1.0), 0.0)


def _pairs_by_point(pairs) -> dict:
    """A dyad's pairs keyed by (point, the link they act on, kind)."""
    return {(p.point, p.on, p.kind): p for p in pairs}


def solve_rrr(group, pairs, geom: Geometry, known):
    """RRR dyad, links (a, b), joints (E1, E2, J), closed form.

    Moments about the internal joint J of each link alone eliminate the internal
    reaction: d1 x R1 = -Ma and d2 x R2 = -Mb with d_i = E_i - J; the force sum of
    the dyad gives R2 = -R1 - fa - fb. That leaves a 2 x 2 system for R1 whose
    determinant d1 x d2 vanishes when E1, J, E2 are collinear (singular dyad).
    R1 on a at E1, R2 on b at E2, RJ = R1 + fa on b by a at J.
    """
    (a, b), (e1, e2, j) = group.links, group.joints
    by_point = _pairs_by_point(pairs)
    p1, p2, pj = by_point[(e1, a, "R")], by_point[(e2, b, "R")], by_point[(j, b, "R")]
    fa, fb = known[a][0], known[b][0]
    xj = geom.points[j]
    d1, d2 = geom.points[e1] - xj, geom.points[e2] - xj
    ma_j, mb_j = moment_about(geom, known, a, xj), moment_about(geom, known, b, xj)
    c1 = -ma_j
    c2 = mb_j - cross(d2, fa + fb)
    det = cross(d1, d2)
    ok = jnp.abs(det) > SINGULAR * safe_norm(d1) * safe_norm(d2)
    r1 = _divided(jnp.stack([d2[0] * c1 - d1[0] * c2, d2[1] * c1 - d1[1] * c2]), det, ok)
    rj = r1 + fa
    r2 = -rj - fb
    zero = jnp.zeros(())
    return {p1.name: Reaction(r1, zero), p2.name: Reaction(r2, zero), pj.name: Reaction(rj, zero)}, None, ok


def solve_rrp(group, pairs, geom: Geometry, known):
    """RRP dyad, links (rod, slider), joints (E, J), the slider on its guide at J; closed
    form (:func:`_rod_and_slider`), R_J on the slider by the rod."""
    (rod, slider), (e, j) = group.links, group.joints
    return _rod_and_slider(pairs, geom, known, rod, slider, e, j, joint_on=slider)


def solve_prr(group, pairs, geom: Geometry, known):
    """PRR dyad (the RRP listed from its prismatic end), links (slider, rod), joints (J, E);
    closed form (:func:`_rod_and_slider`), R_J on the rod by the slider."""
    (slider, rod), (j, e) = group.links, group.joints
    return _rod_and_slider(pairs, geom, known, rod, slider, e, j, joint_on=rod)


def _rod_and_slider(pairs, geom: Geometry, known, rod, slider, e, j, joint_on):
    """A rod pinned at E and at J to a slider on its guide at J (RRP, PRR).

    With R_J on the slider by the rod, the slider's forces R_J + N n + f_s = 0 and the
    rod's R_E - R_J + f_r = 0 give R_E = -f_r - f_s - N n; the rod's moments about J,
    d x R_E = -M_r (d = E - J), give N = (M_r - d x (f_r + f_s)) / (d x n), singular when
    the rod is normal to the guide (N = 0 there, never NaN); the slider's moments about J
    give the guide's couple C = -M_s. R_E on the rod at E, R_J at J on ``joint_on`` (the
    link the dyad's layout puts that pair on; on the rod it is -R_J), N n and C on the
    slider by the guide."""
    by_point = _pairs_by_point(pairs)
    pe, pj, guide = by_point[(e, rod, "R")], by_point[(j, joint_on, "R")], by_point[(j, slider, "P")]
    xj = geom.points[j]
    d, n = geom.points[e] - xj, guide_normal(geom, guide)
    det = cross(d, n)
    ok = jnp.abs(det) > SINGULAR * safe_norm(d)
    normal = _divided(moment_about(geom, known, rod, xj) - cross(d, known[rod][0] + known[slider][0]), det, ok)
    on_slider = -known[slider][0] - normal * n
    zero = jnp.zeros(())
    return {pe.name: Reaction(on_slider - known[rod][0], zero),
            pj.name: Reaction(on_slider if joint_on == slider else -on_slider, zero),
            guide.name: Reaction(normal * n, -moment_about(geom, known, slider, xj))}, None, ok


def solve_rpr(group, pairs, geom: Geometry, known):
    """RPR dyad, links (block, guide link), joints (E1, E2), the block sliding on the
    guide link at E1; closed form.

    The block's forces R_1 + N n + f_b = 0 give R_1 = -f_b - N n; its moments about
    E1 give the couple C = -M_b (about E1). The guide link's forces R_2 - N n + f_g = 0
    give R_2 = N n - f_g; its moments about E2, where N n and C act back on it at E1,
    d x (-N n) - C + M_g = 0 (d = E1 - E2), give N = (M_g + M_b) / (d x n) with M_g
    about E2, singular when E1 - E2 is normal to the guide (|E1 E2| = |offset|, the
    dyad's assembly limit). R_1 on the block at E1, R_2 on the guide link at E2,
    N n and C on the block by the guide link.
    """
    (block, arm), (e1, e2) = group.links, group.joints
    by_point = _pairs_by_point(pairs)
    p1, p2, slot = by_point[(e1, block, "R")], by_point[(e2, arm, "R")], by_point[(e1, block, "P")]
    x1, x2 = geom.points[e1], geom.points[e2]
    d, n = x1 - x2, guide_normal(geom, slot)
    det = cross(d, n)
    ok = jnp.abs(det) > SINGULAR * safe_norm(d)
    mb = moment_about(geom, known, block, x1)
    normal = _divided(moment_about(geom, known, arm, x2) + mb, det, ok)
    zero = jnp.zeros(())
    return {p1.name: Reaction(-known[block][0] - normal * n, zero), p2.name: Reaction(normal * n - known[arm][0], zero),
            slot.name: Reaction(normal * n, -mb)}, None, ok


def solve_prp(group, pairs, geom: Geometry, known):
    """PRP dyad, links (slider 1, slider 2) pinned together at J, each on its own guide
    at J; closed form.

    Each slider's moments about J give its guide's couple, C_k = -M_k. The dyad's
    force sum N1 n1 + N2 n2 = -(f1 + f2) = -F, crossed with n2 and with n1, gives
    N1 = (n2 x F) / (n1 x n2) and N2 = (F x n1) / (n1 x n2), singular when the guides
    are parallel (where the dyad cannot assemble either). The first slider's forces
    -R_J + N1 n1 + f1 = 0 give R_J = f1 + N1 n1, on slider 2 by slider 1 at J;
    N_k n_k and C_k on slider k by its guide's link.
    """
    (s1, s2), j = group.links, group.joint
    by_point = _pairs_by_point(pairs)
    pj, g1, g2 = by_point[(j, s2, "R")], by_point[(j, s1, "P")], by_point[(j, s2, "P")]
    f1 = known[s1][0]
    force = f1 + known[s2][0]
    xj = geom.points[j]
    n1, n2 = guide_normal(geom, g1), guide_normal(geom, g2)
    det = cross(n1, n2)
    ok = jnp.abs(det) > SINGULAR
    normal1, normal2 = _divided(cross(n2, force), det, ok), _divided(cross(force, n1), det, ok)
    zero = jnp.zeros(())
    return {pj.name: Reaction(f1 + normal1 * n1, zero),
            g1.name: Reaction(normal1 * n1, -moment_about(geom, known, s1, xj)),
            g2.name: Reaction(normal2 * n2, -moment_about(geom, known, s2, xj))}, None, ok
