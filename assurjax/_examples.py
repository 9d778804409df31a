"""Generated example mechanisms (scenes too regular to write out by hand)."""

from __future__ import annotations

import math

from ._errors import AssurjaxError
from .scene._load import scene_from_dict
from .scene._scene import Scene


def _bar(a: str, b: str) -> dict:
    """A uniform bar of 1 m and 1 kg from point a (local origin) to point b:
    centre of mass at its middle, centroidal inertia m L^2 / 12 (kg m^2)."""
    return {"points": {a: [0.0, 0.0], b: [1.0, 0.0]}, "com": [0.5, 0.0], "mass": 1.0, "inertia": 1.0 / 12.0}


# Sizes of the generated mechanisms: 25 times what the benchmarks and tests build (the
# N-four-bar of bench_scaling.py and test_stress.py up to N = 40; the bundled strandbeest's
# 4 pairs). At the bounds a scene builds in ~1.5 s; past them the build alone ran for minutes.
MAX_WINDOWS = 1000
MAX_PAIRS = 100


def _count(value, what: str, where: str, at_most: int) -> int:
    """A positive integer count up to ``at_most``, checked before anything is built."""
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= at_most:
        raise AssurjaxError(f"{where}: the number of {what} must be an integer from 1 to {at_most}, got {value!r}")
    return value


def n_four_bar_dict(n: int, *, t1: float = 20.0) -> dict:
    """The scene tables of :func:`n_four_bar` (to edit before ``scene_from_dict``)."""
    n = _count(n, "windows N", "n_four_bar", MAX_WINDOWS)
    ground = {f"O{i}": [float(i), 0.0] for i in range(n + 1)}
    links = {f"rocker{i}": _bar(f"O{i}", f"B{i}") for i in range(n + 1)}
    links.update({f"coupler{i}": _bar(f"B{i}", f"B{i + 1}") for i in range(n)})
    formation = [{"group": "crank", "name": "driver", "link": "rocker0", "pivot": "O0"}]
    formation += [
        # B_(i+1) starts left of the directed line B_i -> O_(i+1) (rockers up)
        {"group": "RRR", "name": f"window{i}", "links": [f"coupler{i}", f"rocker{i + 1}"], "joints": [f"B{i}", f"O{i + 1}", f"B{i + 1}"], "mode": "left"}
        for i in range(n)
    ]
    return {
        "scene": {"name": f"n_four_bar_{n}", "description": f"IFToMM A02: {n} four-bar windows of unit bars under gravity", "gravity": [0.0, -9.81]},
        "ground": ground,
        "links": links,
        "formation": formation,
        # rockers vertical (up); B_0 moves along +x at 1 m/s: omega = -1 rad/s
        "state": {"q0": math.pi / 2, "omega0": -1.0, "t1": float(t1)},
        "outputs": {"points": ["B0", f"B{n}"], "angles": ["rocker0", f"rocker{n}"], "energies": True},
    }


def n_four_bar(n: int, *, t1: float = 20.0) -> Scene:
    """IFToMM multibody benchmark A02, the N-four-bar mechanism, as a Scene.

    N four-bar windows built from 2N+1 uniform bars of 1 m and 1 kg (inertia
    1/12 kg m^2 about the centre): ground pivots O_0..O_N at x = 0..N m, a rocker
    ``rocker{i}`` from O_i to B_i on each, ``rocker0`` the driver (q = its angle,
    rad, from +x, counterclockwise), and couplers ``coupler{i}`` from B_i to B_(i+1).
    Window i is an RRR dyad (coupler i + rocker i+1; external joints B_i and
    O_(i+1), internal B_(i+1)). Gravity 9.81 m/s^2 along -y. The initial state has
    the rockers vertical (q0 = pi/2) and B_0 moving along +x at 1 m/s (omega0 = -1 rad/s).

    The motion stays on the parallelogram branch, which crosses two singular
    configurations per revolution (rockers along +x: every dyad's external joints
    coincide; along -x: every dyad is stretched). The fixed mode "left" is wrong
    past them: simulate with branch tracking (``near`` predictors).

    N is at most 1000 (``MAX_WINDOWS``: 25 times the 40 windows the benchmarks use).

    >>> scene = assurjax.n_four_bar(2)
    >>> scene.mechanism.group_names
    ('driver', 'window0', 'window1')
    """
    return scene_from_dict(n_four_bar_dict(n, t1=t1), source=f"n_four_bar({n})")


# Jansen's "holy numbers" (cm): a, l place the rockers' ground pivot relative to the
# crank centre, m is the crank radius; the others are the link lengths of one leg.
JANSEN = dict(a=38.0, b=41.5, c=39.3, d=40.1, e=55.8, f=39.4, g=36.7, h=65.7, i=49.0, j=50.0, k=61.9, l=7.8, m=15.0)
BAR_DENSITY = 2.0  # kg per metre of bar: aluminium tube of about 25 mm


def circle_intersection(c1, r1, c2, r2, pick):
    """numpy: both intersections of two circles (centres as (2,) arrays); returns the one
    that ``pick(p, q)`` (two candidate points) selects."""
    import numpy as np

    c1, c2 = np.asarray(c1, dtype=float), np.asarray(c2, dtype=float)
    d = c2 - c1
    dist2 = d @ d
    along = (dist2 + r1**2 - r2**2) / (2.0 * dist2)
    h = np.sqrt(r1**2 / dist2 - along**2)
    base, normal = c1 + along * d, np.array([-d[1], d[0]])
    return pick(base + h * normal, base - h * normal)


def jansen_leg_points(crank_angle: float, side: float = -1.0) -> dict:
    """Global joint positions (m) of one Jansen leg for a crank pin at ``crank_angle``
    (rad) about the origin: ``side`` -1 puts the leg (and its ground pivot Z) left of
    the crank, +1 is its mirror image. Keys: A (crank pin), Z (ground pivot), C, D, E,
    F and the foot G. Branch: C above and D below the pivots, E and F outwards, G lowest."""
    import numpy as np

    n = {k: v / 100.0 for k, v in JANSEN.items()}
    out = lambda p, q: p if side * p[0] > side * q[0] else q  # noqa: E731  (further out)
    up = lambda p, q: p if p[1] > q[1] else q  # noqa: E731
    down = lambda p, q: q if p[1] > q[1] else p  # noqa: E731
    A = n["m"] * np.array([np.cos(crank_angle), np.sin(crank_angle)])
    Z = np.array([side * n["a"], -n["l"]])
    C = circle_intersection(A, n["j"], Z, n["b"], up)
    D = circle_intersection(A, n["k"], Z, n["c"], down)
    E = circle_intersection(Z, n["d"], C, n["e"], out)
    F = circle_intersection(E, n["f"], D, n["g"], out)
    G = circle_intersection(F, n["h"], D, n["i"], down)
    return dict(A=A, Z=Z, C=C, D=D, E=E, F=F, G=G)


def _link_table(points: dict, names: tuple[str, ...]) -> dict:
    """A link through the given global points, in its own frame (origin at the first
    point, x axis towards the second), made of uniform bars of BAR_DENSITY between
    consecutive points (closed for a triangle): mass, centre of mass, centroidal inertia."""
    import numpy as np

    origin = points[names[0]]
    axis = points[names[1]] - origin
    axis = axis / np.linalg.norm(axis)
    to_local = np.array([[axis[0], axis[1]], [-axis[1], axis[0]]])
    local = {p: to_local @ (points[p] - origin) for p in names}
    pairs = [(names[0], names[1])] if len(names) == 2 else list(zip(names, names[1:] + names[:1]))
    bars = [(local[p], local[q], BAR_DENSITY * np.linalg.norm(local[q] - local[p])) for p, q in pairs]
    mass = sum(m for _, _, m in bars)
    com = sum(m * (p + q) / 2 for p, q, m in bars) / mass
    inertia = sum(m * ((q - p) @ (q - p) / 12 + ((p + q) / 2 - com) @ ((p + q) / 2 - com)) for p, q, m in bars)
    return {"points": {p: [float(x) for x in v] for p, v in local.items()}, "com": [float(x) for x in com],
            "mass": float(mass), "inertia": float(inertia)}


def _rrr_mode(e1, e2, j) -> str:
    """The RRR mode that puts J where it is: left or right of the directed line E1 -> E2."""
    d, r = e2 - e1, j - e1
    return "left" if d[0] * r[1] - d[1] * r[0] > 0 else "right"


def strandbeest_dict(pairs: int = 4, *, t1: float = 2.0) -> dict:
    """The scene tables of :func:`strandbeest`."""
    import numpy as np

    pairs = _count(pairs, "leg pairs", "strandbeest", MAX_PAIRS)
    n = {k: v / 100.0 for k, v in JANSEN.items()}
    crank_mass, crank_radius = 2.0, n["m"]
    ground = {"O": [0.0, 0.0], "ZL": [-n["a"], -n["l"]], "ZR": [n["a"], -n["l"]]}
    crank = {"points": {"O": [0.0, 0.0]}, "com": [0.0, 0.0], "mass": crank_mass, "inertia": 0.5 * crank_mass * crank_radius**2}
    links, formation = {"crank": crank}, [{"group": "crank", "name": "driver", "link": "crank", "pivot": "O"}]
    feet = []
    for p in range(pairs):
        phase = 2.0 * np.pi * p / pairs
        pin = f"A{p}"
        crank["points"][pin] = [float(n["m"] * np.cos(phase)), float(n["m"] * np.sin(phase))]
        for side, tag in ((-1.0, "L"), (1.0, "R")):
            leg = f"{tag}{p}"
            g = jansen_leg_points(phase, side)  # the crank's local frame is global at q = 0
            z = f"Z{tag}"
            pts = {pin: g["A"], z: g["Z"], **{f"{k}{leg}": g[k] for k in "CDEFG"}}
            C, D, E, F, G = (f"{k}{leg}" for k in "CDEFG")
            links[f"upper{leg}"] = _link_table(pts, (pin, C))  # j
            links[f"rocker{leg}"] = _link_table(pts, (z, C, E))  # b (Z-C), e (C-E), d (E-Z)
            links[f"lower{leg}"] = _link_table(pts, (pin, D))  # k
            links[f"lower_rocker{leg}"] = _link_table(pts, (z, D))  # c
            links[f"tie{leg}"] = _link_table(pts, (E, F))  # f
            links[f"foot{leg}"] = _link_table(pts, (D, F, G))  # g, h, i
            formation += [
                {"group": "RRR", "name": f"upper{leg}", "links": [f"upper{leg}", f"rocker{leg}"], "joints": [pin, z, C],
                 "mode": _rrr_mode(pts[pin], pts[z], pts[C])},
                {"group": "RRR", "name": f"lower{leg}", "links": [f"lower{leg}", f"lower_rocker{leg}"], "joints": [pin, z, D],
                 "mode": _rrr_mode(pts[pin], pts[z], pts[D])},
                {"group": "RRR", "name": f"foot{leg}", "links": [f"tie{leg}", f"foot{leg}"], "joints": [E, D, F],
                 "mode": _rrr_mode(pts[E], pts[D], pts[F])},
            ]
            feet.append(G)
    return {
        "scene": {"name": "strandbeest", "description": f"Jansen strandbeest: {2 * pairs} legs on one crank, phase-shifted pairs",
                  "gravity": [0.0, -9.81]},
        "ground": ground,
        "links": links,
        "formation": formation,
        "state": {"q0": 0.0, "omega0": 2.0 * math.pi, "t1": float(t1)},
        "outputs": {"points": feet, "angles": ["crank"], "energies": True},
    }


def strandbeest(pairs: int = 4, *, t1: float = 2.0) -> Scene:
    """Theo Jansen's strandbeest as a Scene: ``2 * pairs`` legs on one crank.

    Each leg is Jansen's linkage with his "holy numbers" (a = 38, b = 41.5, c = 39.3,
    d = 40.1, e = 55.8, f = 39.4, g = 36.7, h = 65.7, i = 49, j = 50, k = 61.9,
    l = 7.8, m = 15 cm, here in metres): the crank pin A drives the upper link j and
    the lower link k; the ternary rocker (b, d, e) and the lower rocker c turn about
    the ground pivot Z at (-a, -l) from the crank centre O; the tie f and the ternary
    foot (g, h, i) carry the foot point G (sides: Z-C = b, C-E = e, E-Z = d; A-C = j,
    A-D = k, Z-D = c, E-F = f, D-F = g, F-G = h, D-G = i). Three RRR dyads per leg (C, D, then F).
    Pair p has its crank pin at phase 2 pi p / pairs and drives a left leg and its
    mirror image (pivot at (+a, -l)). Bars of 2 kg/m; the crank is a 2 kg disc of
    radius m. q is the crank angle (rad); the bundled scene ``strandbeest`` is
    ``strandbeest(4)``: 8 legs, 25 groups, 49 links. ``pairs`` is at most 100
    (``MAX_PAIRS``: 25 times the bundled scene's).

    >>> scene = assurjax.strandbeest(1)
    >>> scene.mechanism.group_names[:3]
    ('driver', 'upperL0', 'lowerL0')
    """
    return scene_from_dict(strandbeest_dict(pairs, t1=t1), source=f"strandbeest({pairs})")


def strandbeest_toml(pairs: int = 4) -> str:
    """The scene of :func:`strandbeest` as TOML text (how assurjax/scenes/strandbeest.toml is made)."""
    d = strandbeest_dict(pairs)

    def value(v):
        if isinstance(v, str):
            return f'"{v}"'
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        return repr(float(v)) if isinstance(v, float) else str(v)

    lines = ["# Generated by assurjax._examples.strandbeest_toml(4): Jansen's strandbeest, 8 legs on one crank",
             "# (holy numbers in metres; see assurjax.strandbeest for the geometry and the masses)."]
    for table in ("scene", "ground"):
        lines += ["", f"[{table}]"] + [f"{k} = {value(v)}" for k, v in d[table].items()]
    for name, link in d["links"].items():
        lines += ["", f"[links.{name}]"] + [f"{k} = {value(v)}" for k, v in link.items()]
    for group in d["formation"]:
        lines += ["", "[[formation]]"] + [f"{k} = {value(v)}" for k, v in group.items()]
    for table in ("state", "outputs"):
        lines += ["", f"[{table}]"] + [f"{k} = {value(v)}" for k, v in d[table].items()]
    return "\n".join(lines) + "\n"
