"""Random mechanisms of every group kind: closure, no NaN, the kinetostatic/reduction
torque identity, and design gradients.

Four families, each one mechanism structure (one compile) with seeded random
geometries and states:

- ``crank``: a crank carrying one random dyad of every kind (RRR, RRP, PRR, RPR, PRP);
- ``slider``: an RRR and a PRP dyad carried by a slider driver on a random guide (the
  PRP's first guide translates with the slider);
- ``triad``: the bundled class-III triad (``triad_mechanism``), every local point,
  ground pivot, mass and inertia randomly perturbed;
- ``class4``: the bundled class-IV group (``class4_seed003``), perturbed the same way.

The dyads are drawn so that they assemble with a margin from their singular
configurations (checked here with numpy only); the perturbed iterative groups are
kept where they assemble. Both assembly modes of every dyad kind are used (the slow
variant flips them). At every random state (q, w, dw/dt, gravity on) the checks are:

- closure from the raw joint constraints, in numpy: every link is rigid (its points'
  distances and orientation are those of its local geometry, given as input), every
  ground point stays put, the driver's coordinate is q, and every sliding joint lies
  on its guide line;
- every output finite;
- velocities (jvp) equal central differences of the positions in q;
- virtual work: the kinetostatic driving effort (``from_kinematics``, the solve behind
  ``assurjax.reactions``) equals the reduction's
  J_red dw/dt + 0.5 dJ_red/dq w^2 - tau_red (seed 000 eq. 1);
- reverse-mode gradients (``jax.jacrev``) of a coupler point coordinate and of J_red
  w.r.t. every array of the mechanism are finite and agree with central differences
  along random directions in parameter space.
"""

from __future__ import annotations

import types

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import assurjax
from assurjax._kinematics import Kinematics
from assurjax._kinetostatics._api import from_kinematics
from assurjax._mechanism import Pose
from assurjax._kinematics import coefficients
from assurjax._reduction import reduce_single
from assurjax._sweep import stack_mechanisms

GRAVITY = jnp.array([0.0, -9.81])
DYADS = ("RRR", "RRP", "PRR", "RPR", "PRP")
FAMILIES = ("crank", "slider", "triad", "class4")
DYADS_ON = {"crank": DYADS, "slider": ("RRR", "PRP")}  # the slider family is kept small: compile time
OBJECTIVE_POINTS = {"crank": ("RRR_B", "PRP_J"), "slider": ("RRR_B", "PRP_J"), "triad": ("X",), "class4": ("D",)}
BUNDLED = {"triad": "triad_mechanism", "class4": "class4_seed003"}
N_DEFAULT, N_SLOW = 6, 48  # mechanisms per family
N_DIRECTIONS = 3  # random parameter directions for the central differences
H_PARAM = 1e-5  # central-difference step along a unit-scale direction (m, kg, kg m^2); 4-point stencil


# ----------------------------------------------------------------------------- geometry helpers


def unit(angle) -> np.ndarray:
    return np.array([np.cos(angle), np.sin(angle)])


def cross(u, v):
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def bar(a: str, b: str, length: float) -> dict:
    """A uniform bar of 1 kg/m from a (local origin) to b along local x."""
    return {"points": {a: [0.0, 0.0], b: [float(length), 0.0]}, "com": [length / 2, 0.0], "mass": length, "inertia": length**3 / 12}


def block(point: str) -> dict:
    return {"points": {point: [0.0, 0.0]}, "com": [0.0, 0.0], "mass": 0.3, "inertia": 0.01}


# ----------------------------------------------------------------------------- random dyads


def random_dyad(kind: str, rng, A: np.ndarray, carrier_angle: float, mode: str):
    """One random dyad of ``kind`` hung on the point A (m, global, at the drawn state)
    of the driver link, whose angle is ``carrier_angle`` (rad). Drawn to assemble
    with a margin from its singular configurations. Names are prefixed by the kind.
    Returns (ground points, links, formation entry, data for the residuals)."""
    p = kind + "_"
    if kind == "RRR":
        b, c = rng.uniform(0.5, 2.0, 2)
        dist = rng.uniform(abs(b - c) + 0.1, b + c - 0.1)  # |A - O4|: strictly between folded and stretched
        O4 = A + dist * unit(rng.uniform(-np.pi, np.pi))
        entry = {"group": "RRR", "name": p + "dyad", "links": [p + "coupler", p + "rocker"], "joints": ["A", p + "O4", p + "B"],
                 "mode": mode}
        return {p + "O4": O4}, {p + "coupler": bar("A", p + "B", b), p + "rocker": bar(p + "O4", p + "B", c)}, entry, {}
    if kind in ("RRP", "PRR"):
        b, u, G = rng.uniform(0.5, 2.0), unit(rng.uniform(-np.pi, np.pi)), rng.uniform(-1.0, 1.0, 2)
        e = cross(u, A - G) + rng.uniform(-1.0, 1.0) * (b - 0.1)  # B's line within reach of the rod, not tangent
        entry = {"group": kind, "name": p + "dyad", "guide_point": p + "G", "direction": list(u), "offset": float(e), "mode": mode}
        if kind == "RRP":
            entry.update(links=[p + "rod", p + "slider"], joints=["A", p + "B"])
        else:
            entry.update(links=[p + "slider", p + "rod"], joints=[p + "B", "A"])
        links = {p + "rod": bar("A", p + "B", b), p + "slider": block(p + "B")}
        return {p + "G": G}, links, entry, {"line": (p + "B", G, u, e)}
    if kind == "RPR":
        e = rng.uniform(-0.5, 0.5)
        O4 = A + rng.uniform(abs(e) + 0.1, 2.0) * unit(rng.uniform(-np.pi, np.pi))  # A outside the circle |x - O4| = |e|
        entry = {"group": "RPR", "name": p + "dyad", "links": [p + "block", p + "guide"], "joints": ["A", p + "O4"],
                 "direction": [1.0, 0.0], "offset": float(e), "mode": mode}
        return {p + "O4": O4}, {p + "block": block("A"), p + "guide": bar(p + "O4", p + "T", 2.0)}, entry, {"rpr": (O4, e)}
    # PRP: one guide on the driver link through A (direction psi in its frame), one on the ground
    while True:
        psi, phi = rng.uniform(-np.pi, np.pi, 2)
        if abs(np.sin(carrier_angle + psi - phi)) > 0.2:  # guides far from parallel
            break
    G = rng.uniform(-1.0, 1.0, 2)
    entry = {"group": "PRP", "name": p + "dyad", "links": [p + "s1", p + "s2"], "joint": p + "J", "guide_points": ["A", p + "G"],
             "directions": [list(unit(psi)), list(unit(phi))], "offsets": [0.0, 0.0]}
    return {p + "G": G}, {p + "s1": block(p + "J"), p + "s2": block(p + "J")}, entry, {"prp": (psi, G, phi)}


def random_dyads_scene(family: str, rng, modes: dict) -> tuple[dict, float, dict]:
    """Scene tables of a driver (crank or slider) carrying random dyads (one per kind
    of ``DYADS_ON[family]``) on its point A, the driving coordinate q they were drawn at, and the residual data."""
    if family == "crank":
        a, q = rng.uniform(0.5, 2.0), rng.uniform(-np.pi, np.pi)
        A, angle = a * unit(q), q
        ground = {"O": [0.0, 0.0]}
        links = {"input": bar("O", "A", a)}
        driver = {"group": "crank", "name": "driver", "link": "input", "pivot": "O"}
        data = {"driver": ("crank", "O", None)}
    else:
        angle, S, q = rng.uniform(-np.pi, np.pi), rng.uniform(-0.5, 0.5, 2), rng.uniform(-1.0, 1.0)
        A = S + q * unit(angle)
        ground = {"S": list(S)}
        links = {"input": {"points": {"A": [0.0, 0.0]}, "com": [0.1, 0.05], "mass": 0.5, "inertia": 0.02}}
        driver = {"group": "slider", "name": "driver", "link": "input", "point": "A", "guide_point": "S", "direction": list(unit(angle))}
        data = {"driver": ("slider", "S", unit(angle))}
    formation = [driver]
    for kind in DYADS_ON[family]:
        g, ls, entry, d = random_dyad(kind, rng, A, angle, modes[kind])
        ground.update({k: list(v) for k, v in g.items()})
        links.update(ls)
        formation.append(entry)
        data[kind] = d
    tables = {"scene": {"name": f"random_{family}"}, "ground": ground, "links": links, "formation": formation}
    return tables, q, data


# ----------------------------------------------------------------------------- perturbed iterative groups


def perturbed(mech, rng, *, rel: float = 0.03):
    """The mechanism with every 2-vector (local points, centres of mass, ground pivots,
    guesses) moved by up to ``rel`` x 0.3 m per coordinate and every mass and inertia
    scaled by up to 1 +- 10 rel: a random geometry near the bundled one."""
    leaves, tree = jax.tree.flatten(mech)
    out = []
    for leaf in leaves:
        x = np.asarray(leaf, dtype=float)
        if x.shape == (2,):
            x = x + rng.uniform(-rel, rel, 2) * 0.3
        elif x.shape == ():
            x = x * (1.0 + rng.uniform(-10 * rel, 10 * rel))
        out.append(jnp.asarray(x))
    return jax.tree.unflatten(tree, out)


# ----------------------------------------------------------------------------- independent residuals


def rigid_link_residuals(mech, pose) -> list[float]:
    """Closure residuals (m, m^2) from the raw joint constraints: for every link, the
    global distances between its points (and, with three or more points, the cross
    products fixing its orientation) equal those of its local geometry; every ground
    point is where it was given. A point shared by two links (a revolute) is reported
    once, so the rigidity of both links checks the joint."""
    g = {k: np.asarray(v) for k, v in pose.points.items()}
    out = [float(np.abs(g[k] - np.asarray(v)).max()) for k, v in mech.ground.items() if k in g]
    for link in mech.links.values():
        names = list(link.points)
        local = {k: np.asarray(v) for k, v in link.points.items()}
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                out.append(np.linalg.norm(g[b] - g[a]) - np.linalg.norm(local[b] - local[a]))
        for b, c in zip(names[1:], names[2:]):
            a = names[0]
            out.append(cross(g[b] - g[a], g[c] - g[a]) - cross(local[b] - local[a], local[c] - local[a]))
    return out


def driver_residuals(mech, pose, q, data) -> list[float]:
    """The driver's constraint: crank angle q (its local x axis), or slider point at q along the guide."""
    kind, pivot, u = data["driver"]
    g = {k: np.asarray(v) for k, v in pose.points.items()}
    local = {k: np.asarray(v) for k, v in mech.links["input"].points.items()}
    if kind == "crank":
        expected = np.asarray(mech.ground[pivot]) + np.array([[np.cos(q), -np.sin(q)], [np.sin(q), np.cos(q)]]) @ (local["A"] - local[pivot])
        return list(g["A"] - expected)
    return list(g["A"] - (np.asarray(mech.ground[pivot]) + q * u))


def guide_residuals(pose, data) -> list[float]:
    """Sliding joints on their guide lines (m): signed distances minus the offsets."""
    g = {k: np.asarray(v) for k, v in pose.points.items()}
    out = []
    for kind in ("RRP", "PRR"):
        if kind in data:
            point, G, u, e = data[kind]["line"]
            out.append(cross(u, g[point] - G) - e)
    if "RPR" in data:
        O4, e = data["RPR"]["rpr"]
        guide = unit(float(pose.angles["RPR_guide"]))
        out.append(cross(guide, g["A"] - O4) - e)
    if "PRP" in data:
        psi, G, phi = data["PRP"]["prp"]
        carrier = unit(float(pose.angles["input"]) + psi)  # the first guide turns with the driver link
        out += [cross(carrier, g["PRP_J"] - g["A"]), cross(unit(phi), g["PRP_J"] - G)]
    return out


# ----------------------------------------------------------------------------- the compiled analysis


def contract(grads, direction) -> jax.Array:
    """sum over leaves of <d(objectives)/d(leaf), direction leaf>: both directional derivatives."""
    total = jnp.zeros(2)
    for g, d in zip(jax.tree.leaves(grads), jax.tree.leaves(direction), strict=True):
        total = total + jnp.tensordot(g, d, axes=d.ndim)
    return total


def analysis(family: str):
    """For a batch of (mechanism, q, w, dw/dt, parameter directions), one state each:
    pose, jvp velocities and their central differences in q, the reduction, the
    kinetostatic driving effort, jacrev of (point coordinate, J_red) w.r.t. the
    mechanism's arrays, and central differences of both along the directions.
    One compile per family (mechanism structure)."""
    points = OBJECTIVE_POINTS[family]

    def objectives(mech, q, near):
        """(sum of x + 0.5 y over the family's coupler points (m), J_red (kg m^2 or kg)),
        J_red written out from the kinematic coefficients (seed 000 eqs. 5-6)."""
        coords = lambda qq: (lambda p: ((p.points, p.coms, p.angles), p.ok))(assurjax.positions(mech, qq, near=near))  # noqa: E731
        x, dx, _ = jax.jvp(coords, (q,), (jnp.ones_like(q),), has_aux=True)
        j = sum((link.mass * jnp.sum(dx[1][k] ** 2) + link.inertia * dx[2][k] ** 2 for k, link in mech.links.items()), jnp.zeros(()))
        return jnp.stack([sum(x[0][p][0] + 0.5 * x[0][p][1] for p in points), j])

    def one(mech, q, w, a, directions, near):
        # one second-order analysis serves the pose, the velocities and the kinetostatics
        c = coefficients(mech, q, near=near)
        x, dx, d2x, ok = c.x, c.dx, c.d2x, c.ok
        h = 1e-6
        shifted = jax.vmap(lambda qq: assurjax.positions(mech, qq, near=near).points)(q + jnp.array([h, -h]))
        fd = jax.tree.map(lambda s: (s[0] - s[1]) / (2 * h), shifted)
        red = reduce_single(mech, GRAVITY, (), q, w, jnp.zeros(()), near=near)
        vel = jax.tree.map(lambda d: d * w, dx)
        acc = jax.tree.map(lambda d, dd: dd * w**2 + d * a, dx, d2x)
        kin = Kinematics(q=q, omega=w, alpha=a, points=x[0], velocities=vel[0], accelerations=acc[0], coms=x[1], com_velocities=vel[1],
                         com_accelerations=acc[1], angles=x[2], angular_velocities=vel[2], angular_accelerations=acc[2], ok=ok)
        scene = types.SimpleNamespace(mechanism=mech, gravity=GRAVITY, loads=())
        _, _, driving, kin_ok = from_kinematics(scene, kin, jnp.zeros(()))
        pose = Pose(points=x[0], coms=x[1], angles=x[2], ok=ok)
        dpose = types.SimpleNamespace(points=dx[0])
        params, static = eqx.partition(mech, eqx.is_inexact_array)
        f = lambda p: objectives(eqx.combine(p, static), q, near)  # noqa: E731
        grads = jax.jacrev(f)(params)

        steps = H_PARAM * jnp.array([1.0, -1.0, 2.0, -2.0])
        values = jax.vmap(lambda d: jax.vmap(lambda s: f(jax.tree.map(lambda p, dd: p + s * dd, params, d)))(steps))(directions)
        central = (8.0 * (values[:, 0] - values[:, 1]) - (values[:, 2] - values[:, 3])) / (12.0 * H_PARAM)  # error O(h^4)
        exact = jax.vmap(lambda d: contract(grads, d))(directions)
        return dict(pose=pose, velocities=dpose.points, central_velocities=fd, inertia=red.inertia, dinertia=red.dinertia,
                    torque=red.torque, red_ok=red.ok, driving=driving, kin_ok=kin_ok, grads=grads, exact=exact, central=central)

    return eqx.filter_jit(eqx.filter_vmap(one))


# ----------------------------------------------------------------------------- building a family


MODES = {"RRR": "+", "RRP": "-", "PRR": "+", "RPR": "-", "PRP": "+"}  # PRP has no mode (ignored)
FLIPPED = {k: "-" if m == "+" else "+" for k, m in MODES.items()}  # one mode per kind and batch: the structure is shared


@eqx.filter_jit
def _assembly(mechs, qs):
    """Per mechanism: every group assembled, and the link angles (rad) reached by continuation from the guess."""
    pose = jax.vmap(assurjax.positions)(mechs, qs)
    return jnp.all(pose.ok, axis=-1), pose.angles


def random_family(family: str, n: int, seed: int, *, flip: bool = False):
    """``n`` random mechanisms of the family stacked into one batch, their states
    (q, w, dw/dt), per-mechanism residual data (None for the iterative groups) and the
    branch predictor (link angles, rad) of the iterative groups: the angles reached by
    continuation from the scene's guess when filtering, so that the compiled analysis
    starts Newton there instead of repeating the continuation (which
    tests/test_iterative_groups.py covers; this keeps the compile small).
    The dyads' modes are ``MODES`` for the crank, ``FLIPPED`` for the slider,
    the other way round with ``flip``."""
    rng = np.random.default_rng(seed)
    if family in DYADS_ON:
        modes = MODES if (family == "crank") != flip else FLIPPED
        cases = [random_dyads_scene(family, rng, modes) for _ in range(n)]
        mechs = stack_mechanisms([assurjax.scene_from_dict(t).mechanism for t, _, _ in cases])
        qs, data = np.array([q for _, q, _ in cases]), [d for _, _, d in cases]
        near = None  # the dyads' fixed modes
    else:
        base = assurjax.load_scene(BUNDLED[family]).mechanism
        candidates = stack_mechanisms([perturbed(base, rng) for _ in range(2 * n)])
        q_all = rng.uniform(-np.pi, np.pi, 2 * n)
        assembled, angles = _assembly(candidates, jnp.asarray(q_all))
        keep = np.flatnonzero(np.asarray(assembled))[:n]
        assert len(keep) == n, f"only {len(keep)} of {2 * n} perturbed {family} geometries assemble"
        mechs = jax.tree.map(lambda x: x[keep] if eqx.is_array(x) else x, candidates)
        qs, data = q_all[keep], [None] * n
        near = {k: v[keep] for k, v in angles.items()}
    ws, alphas = rng.normal(size=n) * 2.0, rng.normal(size=n) * 3.0
    params = eqx.filter(mechs, eqx.is_inexact_array)
    directions = jax.tree.map(lambda x: jnp.asarray(rng.normal(size=(x.shape[0], N_DIRECTIONS) + x.shape[1:])), params)
    return mechs, qs, ws, alphas, directions, data, near


def run_family(family: str, n: int, seed: int, *, flip: bool = False):
    mechs, qs, ws, alphas, directions, data, near = random_family(family, n, seed, flip=flip)
    out = analysis(family)(mechs, *(jnp.asarray(v) for v in (qs, ws, alphas)), directions, near)
    return family, mechs, qs, ws, alphas, data, jax.tree.map(np.asarray, out)


# ----------------------------------------------------------------------------- the checks


def sample(tree, i):
    return jax.tree.map(lambda x: x[i] if eqx.is_array(x) else x, tree)


def check_closure(family, mechs, qs, data, out):
    """Raw joint constraints (numpy) hold to 1e-11 m at every sample."""
    assert out["pose"].ok.all() and out["red_ok"].all() and out["kin_ok"].all()
    for i, q in enumerate(qs):
        mech, pose = sample(mechs, i), sample(out["pose"], i)
        res = rigid_link_residuals(mech, pose)
        if data[i] is not None:
            res += driver_residuals(mech, pose, q, data[i]) + guide_residuals(pose, data[i])
        assert np.abs(res).max() < 1e-11, (family, i, np.abs(res).max())


def check_finite(out):
    for leaf in jax.tree.leaves(out):
        assert np.isfinite(leaf).all()


def check_velocities(out):
    """jvp velocities against central differences of the positions in q (h = 1e-6)."""
    for name, v in out["velocities"].items():
        ref = out["central_velocities"][name]
        np.testing.assert_allclose(v, ref, atol=1e-7 * (1 + np.abs(ref).max()), err_msg=name)


def check_virtual_work(ws, alphas, out):
    """Driving effort (kinetostatics) = J_red dw/dt + 0.5 dJ_red/dq w^2 - tau_red (reduction)."""
    terms = np.stack([out["inertia"] * alphas, 0.5 * out["dinertia"] * ws**2, out["torque"]])
    expected = terms[0] + terms[1] - terms[2]
    np.testing.assert_allclose(out["driving"], expected, rtol=0, atol=1e-10 * (1 + np.abs(terms).max()))


def check_gradients(out):
    """Reverse-mode directional derivatives against central differences (4-point stencil)
    along random directions, relative to each sample's and objective's scale."""
    exact, central = out["exact"], out["central"]  # (sample, direction, objective)
    scale = 1 + np.abs(central).max(axis=1, keepdims=True)
    worst = (np.abs(exact - central) / scale).max()
    assert worst < 1e-6, worst
    assert (np.abs(exact).max(axis=(0, 1)) > 1e-3).all()  # the directions do move both objectives


def check_family(family: str, n: int, seed: int, *, flip: bool = False):
    family, mechs, qs, ws, alphas, data, out = run_family(family, n, seed, flip=flip)
    check_closure(family, mechs, qs, data, out)
    check_finite(out)
    check_velocities(out)
    check_virtual_work(ws, alphas, out)
    check_gradients(out)


# the default suite draws the slider family (RRR and PRP dyads on a slider driver; every dyad kind is
# checked by default in tests/test_dyads.py); the crank family (~30 s of compiles on a loaded 2-core
# machine, where the default suite ran 10:09-11:00) and the iterative families (~20 s each;
# tests/test_iterative_groups.py checks them by default) in the slow suite, with their many draws below
@pytest.mark.parametrize("family", [f if f == "slider" else pytest.param(f, marks=pytest.mark.slow) for f in FAMILIES])
def test_random_mechanisms_of_every_kind(family):
    """A few random geometries and states per family (one compile each; a single test
    per family so that parallel workers never compile a family twice)."""
    check_family(family, N_DEFAULT, seed=20240501 + FAMILIES.index(family))


@pytest.mark.slow
@pytest.mark.parametrize("family", FAMILIES)
def test_many_random_mechanisms(family):
    """The same checks on many more random geometries and states per family."""
    check_family(family, N_SLOW, seed=7 + FAMILIES.index(family), flip=True)
