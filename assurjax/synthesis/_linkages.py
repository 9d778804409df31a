"""Four-bar linkages built from their link lengths (the usual synthesis variables)."""

from __future__ import annotations

import jax.numpy as jnp

from .._mechanism import Mechanism
from ..groups import RRR, Crank, Link


def four_bar(
    *,
    ground: float,
    crank: float,
    coupler: float,
    rocker: float,
    coupler_point,
    mode: int = 1,
    origin=(0.0, 0.0),
    masses=(0.0, 0.0, 0.0),
    name: str = "four_bar",
) -> Mechanism:
    """A crank-driven four-bar from lengths (m), named like the bundled ``roberts`` scene.

    Fixed pivots A = ``origin`` and D = A + (``ground``, 0); crank ``link2`` = AB
    (``crank``), rocker ``link3`` = DC (``rocker``), coupler ``link4`` = BC
    (``coupler``) carrying the coupler point P at ``coupler_point`` = (u, v) in the
    coupler frame (B at the origin, C on +x). ``mode`` +1: C left of the directed
    line B -> D (the ``roberts`` assembly). q is the crank angle from +x (rad).
    Lengths may be JAX tracers (the result is differentiable in them);
    ``masses`` (kg) go to link2, link3, link4 at their midpoints / centroid.
    """
    a = jnp.asarray(origin, dtype=float)
    zero = jnp.zeros(())
    m2, m3, m4 = (jnp.asarray(m, dtype=float) for m in masses)
    p = jnp.asarray(coupler_point, dtype=float)
    c = jnp.stack([jnp.asarray(coupler, dtype=float), zero])
    links = {
        "link2": Link(points={"A": jnp.zeros(2), "B": jnp.stack([jnp.asarray(crank, dtype=float), zero])},
                      com=jnp.stack([0.5 * jnp.asarray(crank, dtype=float), zero]), mass=m2, inertia=m2 * crank**2 / 12),
        "link3": Link(points={"D": jnp.zeros(2), "C": jnp.stack([jnp.asarray(rocker, dtype=float), zero])},
                      com=jnp.stack([0.5 * jnp.asarray(rocker, dtype=float), zero]), mass=m3, inertia=m3 * rocker**2 / 12),
        "link4": Link(points={"B": jnp.zeros(2), "C": c, "P": p}, com=(c + p) / 3.0, mass=m4, inertia=m4 * coupler**2 / 12),
    }
    groups = [Crank("crank2", ("link2",), "A"), RRR("dyad43", ("link4", "link3"), ("B", "D", "C"), mode)]
    ground_points = {"A": a, "D": a + jnp.stack([jnp.asarray(ground, dtype=float), zero])}
    return Mechanism(ground_points, links, groups, name=name)


def triangle_point(base: float, left: float, right: float, *, below: bool = True):
    """The apex (u, v) of a triangle on the segment (0, 0)-(``base``, 0) with sides
    ``left`` from (0, 0) and ``right`` from (base, 0); below the base by default
    (the Roberts coupler point: BP = ``left``, CP = ``right``)."""
    u = (left**2 - right**2 + base**2) / (2.0 * base)
    v = jnp.sqrt(jnp.maximum(left**2 - u**2, 0.0))
    return jnp.stack([u, -v if below else v])


def roberts_lengths(l2: float = 0.18, l4: float = 0.12):
    """Lengths (m) of the Roberts linkage of Fanghella et al. 2019 in the order
    (AD, AB, DC, BC, BP, CP): AB = DC = BP = CP = ``l2``, BC = ``l4``, AD = 2 ``l4``."""
    return jnp.array([2 * l4, l2, l2, l4, l2, l2])


def roberts_like(lengths, *, name: str = "roberts_like") -> Mechanism:
    """A Roberts-type four-bar from its six lengths (AD, AB, DC, BC, BP, CP) in m,
    placed as in the bundled ``roberts`` scene (A, D symmetric about the origin on the x axis)."""
    ad, ab, dc, bc, bp, cp = (lengths[i] for i in range(6))
    return four_bar(
        ground=ad, crank=ab, coupler=bc, rocker=dc, coupler_point=triangle_point(bc, bp, cp),
        origin=jnp.stack([-0.5 * ad, jnp.zeros(())]), name=name,
    )
