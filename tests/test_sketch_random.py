"""Random drawings over every group kind, with shuffled link order and random names:
the decomposition finds a valid formation of the drawn groups, and the positions
equal a generic Newton solution of all the loop-closure equations (every revolute
and prismatic pair, tests/joint_reference.py, numpy only) continued from the drawing.

Each structure (kinds in a random order, random names, shuffled links) is drawn many
times with random geometry; the draws keep every assembly mode at +1 so that they
share one compiled position analysis (stacked, vmapped). A few dyad-only drawings with
random modes are compiled one by one. The reference knows nothing of Assur groups or
modes: it starts from the drawn pose (every link frame the identity, local points the
drawn ones) and follows q in small steps."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import assurjax
from assurjax.structure import Sketch, Slide, build, decompose

from joint_reference import GROUND, Prismatic, Revolute, System

Q0 = 0.3  # the driving coordinate of every drawing (one static guess_q per structure)
OFFSETS = np.linspace(-0.2, 0.2, 5)  # q - q0 where positions are compared
KINDS = ("RRR", "RRP", "RPR", "PRP", "triad", "class4")
MARGIN = 0.3  # |sin| of the angles that keep a drawn group away from its singular configurations


def unit(v):
    return v / np.hypot(*v)


def cross(a, b):
    return a[0] * b[1] - a[1] * b[0]


MAX_TRIES = 1000  # random placements per group before the drawing is given up


class Drawing:
    """A random drawing built group by group (its own formation sequence, kept for the check)."""

    def __init__(self, rng, kinds, driver, modes, topology_seed):
        # the topology (which joints a group hangs from, which links carry guides) comes from
        # its own seed: every draw of one structure has the same one
        self.rng, self.modes, self.topo = rng, modes, np.random.default_rng(topology_seed)
        self.joints, self.links, self.ground, self.slides = {}, {}, [], []
        self.known = []  # joints on the ground or on placed links: externals for later groups
        self.placed = [GROUND]
        self.n = 0
        for k in range(3):
            self.ground.append(self.point(self.rng.uniform(-1, 1, 2)))
        self.known += self.ground
        if driver == "crank":
            o = self.ground[0]
            a = self.point(self.joints[o] + 0.4 * np.array([np.cos(Q0), np.sin(Q0)]))
            self.link([o, a])
            self.driver_u = None
        else:
            u = unit(np.array([1.0, self.rng.uniform(-0.5, 0.5)]))
            s = self.point(self.rng.uniform(-1, 1, 2))
            self.link([s])
            self.slides.append(Slide(self.placed[-1], GROUND, tuple(u)))
            self.driver_u = u
        self.known.append(self.links[self.placed[-1]][-1])
        self.kinds = [getattr(self, kind)() or kind for kind in kinds]

    # -- drawing primitives -------------------------------------------------------------
    def point(self, xy) -> str:
        name = f"p{self.n}"
        self.n += 1
        self.joints[name] = np.asarray(xy, dtype=float)
        return name

    def link(self, joints, extra=True) -> str:
        name = f"l{len(self.links)}"
        if extra:  # a further point to attach later groups to
            joints = joints + [self.point(self.joints[joints[-1]] + self.rng.uniform(-0.5, 0.5, 2))]
        self.links[name] = joints
        self.placed.append(name)
        return name

    def externals(self, k):
        return list(self.topo.choice(self.known, size=k, replace=False))

    def sign(self):
        return 1.0 if self.modes == "+" else self.rng.choice([-1.0, 1.0])

    def guide(self):
        return self.topo.choice(self.placed[:-1] if len(self.placed) > 1 else self.placed)

    def near(self, p, r=(0.4, 0.9)):
        a = self.rng.uniform(0, 2 * np.pi)
        return self.joints[p] + self.rng.uniform(*r) * np.array([np.cos(a), np.sin(a)])

    # -- the groups (each keeps |sin| of its critical angle above MARGIN) -----------------
    def RRR(self):
        e1, e2 = self.externals(2)
        for _ in range(MAX_TRIES):
            j = self.near(e1)
            a, b = j - self.joints[e1], j - self.joints[e2]
            if abs(cross(a, b)) > MARGIN * np.hypot(*a) * np.hypot(*b):
                break
        else:
            raise RuntimeError("no admissible random placement (e.g. coinciding joints)")
        d = self.joints[e2] - self.joints[e1]
        if np.sign(cross(d, a)) != self.sign():  # the mode: reflect J across the line E1 E2
            j = self.joints[e1] + 2 * np.dot(a, unit(d)) * unit(d) - a
        jn = self.point(j)
        self.link([e1, jn]), self.link([e2, jn], extra=False)
        self.known.append(jn)

    def RRP(self):
        (e,) = self.externals(1)
        guide = self.guide()
        for _ in range(MAX_TRIES):
            j, u = self.near(e), unit(self.rng.normal(size=2))
            if abs(np.dot(unit(j - self.joints[e]), u)) > MARGIN:
                break
        else:
            raise RuntimeError("no admissible random placement (e.g. coinciding joints)")
        u = u * np.sign(np.dot(j - self.joints[e], u)) * self.sign()
        jn = self.point(j)
        rod = self.link([e, jn], extra=False)
        slider = self.link([jn])
        self.slides.append(Slide(slider, guide, tuple(u)))
        self.known.append(jn)
        del rod

    def RPR(self):
        e1, e2 = self.externals(2)
        d = self.joints[e1] - self.joints[e2]
        for _ in range(MAX_TRIES):
            u = unit(self.rng.normal(size=2))
            if abs(np.dot(unit(d), u)) > MARGIN:
                break
        else:
            raise RuntimeError("no admissible random placement (e.g. coinciding joints)")
        u = u * np.sign(np.dot(d, u)) * self.sign()
        block = self.link([e1], extra=False)
        guide = self.link([e2])
        self.slides.append(Slide(block, guide, tuple(u)))
        self.known.append(self.links[guide][-1])

    def PRP(self):
        g1, g2 = self.guide(), self.guide()
        for _ in range(MAX_TRIES):
            u1, u2 = unit(self.rng.normal(size=2)), unit(self.rng.normal(size=2))
            if abs(cross(u1, u2)) > MARGIN:
                break
        else:
            raise RuntimeError("no admissible random placement (e.g. coinciding joints)")
        jn = self.point(self.rng.uniform(-1, 1, 2))
        s1 = self.link([jn], extra=False)
        self.slides.append(Slide(s1, g1, tuple(u1)))
        s2 = self.link([jn])
        self.slides.append(Slide(s2, g2, tuple(u2)))
        self.known.append(jn)

    def triad(self):
        es = self.externals(3)
        centre = np.mean([self.joints[e] for e in es], axis=0)
        turn = self.rng.uniform(0.4, 0.8)  # the arms E_i -> P_i must not meet in one point (a singular triad)
        c, s = np.cos(turn), np.sin(turn)
        arms = [0.5 * (self.joints[e] - centre) for e in es]
        ps = [self.point(centre + np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]]) + self.rng.uniform(-0.05, 0.05, 2)) for v in arms]
        self.link(ps)
        for e, p in zip(es, ps):
            self.link([e, p], extra=False)
        self.known.append(ps[0])

    def class4(self):
        b, g = self.externals(2)
        mid = (self.joints[b] + self.joints[g]) / 2
        c, e = self.point(self.near(b, (0.3, 0.6))), self.point(self.near(b, (0.3, 0.6)))
        d, f = self.point(self.near(g, (0.3, 0.6))), self.point(self.near(g, (0.3, 0.6)))
        del mid
        self.link([b, c, e])
        self.link([c, d], extra=False)
        self.link([g, d, f])
        self.link([e, f], extra=False)
        self.known.append(c)

    # -- as a sketch, and as the reference's joint system ---------------------------------
    def sketch(self, link_names, joint_names, order):
        j = {joint_names[p]: xy for p, xy in self.joints.items()}
        links = {link_names[k]: [joint_names[p] for p in self.links[k]] for k in order}
        slides = [Slide(link_names[s.link], link_names.get(s.on, s.on), s.direction) for s in self.slides]
        return Sketch(j, links, ground=[joint_names[p] for p in self.ground], slides=slides,
                      driver=link_names["l0"], q0=Q0 if self.driver_u is None else 0.0)

    def reference(self):
        """Every link's frame is the identity in the drawing (local points = drawn points)."""
        bodies = {k: dict(mass=1.0, inertia=1.0, com_local=(0.0, 0.0)) for k in self.links}
        carriers = {p: ([GROUND] if p in self.ground else []) + [k for k, js in self.links.items() if p in js] for p in self.joints}
        joints = [Revolute(p, c[0], other, tuple(self.joints[p]), tuple(self.joints[p])) for p, c in carriers.items() for other in c[1:]]
        for s in self.slides:
            at = tuple(self.joints[self.links[s.link][0]])
            joints.append(Prismatic(f"{s.link}/{s.on}", s.on, s.link, at, at, s.direction))
        if self.driver_u is None:
            driver = ("l0", "angle")
        else:
            driver = ("l0", "x")
        return System(bodies, joints, driver, max_dq=0.02)

    def reference_points(self, offsets):
        """{point: (len(offsets), 2)} by continuation from the drawing (q - q0 = 0) out to each side."""
        system = self.reference()
        scale = 1.0 if self.driver_u is None else self.driver_u[0]  # a slider drives x = (q - q0) u_x
        frames = {}
        for side in (offsets[offsets >= 0], offsets[offsets < 0][::-1]):
            z, q_prev, zq = np.zeros(system.n), 0.0, None
            for dq in side:
                z, _, zq = system.track(dq * scale, q_prev, z, zq)
                q_prev = dq * scale
                frames[float(dq)] = system.to_frames(z)
        out = {}
        for k, joints in self.links.items():
            for p in joints:
                rows = []
                for dq in offsets:
                    x, y, th = frames[float(dq)][k]
                    c, s, (lx, ly) = np.cos(th), np.sin(th), self.joints[p]
                    rows.append([x + c * lx - s * ly, y + s * lx + c * ly])
                out[p] = np.array(rows)
        return out


def structure(seed, driver="crank"):
    """Kinds in a random order (every kind once), random names, a random link order."""
    rng = np.random.default_rng(seed)
    kinds = list(rng.permutation(KINDS))
    first = Drawing(rng, kinds, driver, "+", seed)
    link_names = {k: f"link_{v}" for k, v in zip(first.links, rng.permutation(len(first.links)))}
    joint_names = {p: f"J{v}" for p, v in zip(first.joints, rng.permutation(len(first.joints)))}
    order = list(rng.permutation(list(first.links)))
    return rng, kinds, link_names, joint_names, order


def usable(drawings, n):
    """The first n drawings whose reference solution exists along the whole sweep (a random
    iterative group may pass near a singular configuration, where the reference stops)."""
    out = []
    for d in drawings:
        try:
            d.ref = d.reference_points(OFFSETS)
        except RuntimeError:
            continue
        out.append(d)
        if len(out) == n:
            return out
    raise AssertionError(f"only {len(out)} of {len(drawings)} random drawings have a reference solution")


def check_batch(drawings, names):
    link_names, joint_names, order = names
    sketches = [d.sketch(link_names, joint_names, order) for d in drawings]
    mechanisms = []
    for d, sk in zip(drawings, sketches):
        dec = decompose(sk)
        expected = sorted(["crank" if d.driver_u is None else "slider"] + d.kinds)
        assert sorted(g.kind for g in dec.groups) == expected
        mechanisms.append(build(sk).mechanism)
    batch = assurjax.stack_mechanisms(mechanisms)
    q = (Q0 if drawings[0].driver_u is None else 0.0) + OFFSETS
    pose = jax.vmap(lambda m: jax.vmap(lambda qq: assurjax.positions(m, qq))(q))(batch)
    ok = np.asarray(pose.ok).all(axis=-1)
    assert ok.all(), f"{(~ok).sum()} of {ok.size} configurations do not assemble"
    worst = 0.0
    for i, d in enumerate(drawings):
        for p, xy in d.ref.items():
            worst = max(worst, float(np.max(np.abs(np.asarray(pose.points[joint_names[p]])[i] - xy))))
    assert worst <= 1e-10, worst
    return len(drawings)


def random_drawings(rng, kinds, driver, seed, count):
    """Up to ``count`` drawings; a drawing whose groups find no admissible placement is skipped."""
    out = []
    for _ in range(count):
        try:
            out.append(Drawing(rng, kinds, driver, "+", seed))
        except RuntimeError:
            continue
    return out


def run_structure(seed, driver, n):
    rng, kinds, *names = structure(seed, driver)
    drawings = usable(random_drawings(rng, kinds, driver, seed, 6 * n), n)
    assert check_batch(drawings, names) == n


def test_random_drawings_of_one_structure_against_loop_closure_newton():
    """A few drawings of one structure holding every kind (one compile)."""
    run_structure(0, "crank", 3)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="known: in 3 of the 200 drawings the package's triad does not converge at "
                   "0.1-0.2 rad from the drawn pose where the loop-closure reference does (Newton max_steps 32; 100 "
                   "fixes 2 of them); the continuation of iterative groups needs a closer look")
def test_200_random_drawings_of_one_structure_against_loop_closure_newton():
    """200 drawings of one structure holding every kind (one compile)."""
    run_structure(0, "crank", 200)


SLIDER_KNOWN = pytest.mark.xfail(strict=True, reason="known: with a slider driver one drawing in 50 ends on another "
                                 "branch (0.33 m off) and another fails to assemble at 2 of 5 offsets where the "
                                 "loop-closure reference succeeds; not yet diagnosed")


@pytest.mark.slow
@pytest.mark.parametrize("seed, driver", [(1, "crank"), (2, "crank"), pytest.param(3, "slider", marks=SLIDER_KNOWN),
                                          pytest.param(4, "slider", marks=SLIDER_KNOWN)])
def test_more_random_structures_against_loop_closure_newton(seed, driver):
    run_structure(seed, driver, 50)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(2))
def test_random_modes_against_loop_closure_newton(seed):
    """Dyads drawn on both sides (random modes): one compile per drawing, so a few."""
    rng = np.random.default_rng(100 + seed)
    kinds = list(rng.permutation(["RRR", "RRP", "RPR", "RRR"]))
    d = Drawing(rng, kinds, "crank", "random", seed)
    names = ({k: f"n{k}" for k in d.links}, {p: f"q{p}" for p in d.joints}, list(rng.permutation(list(d.links))))
    check_batch(usable([d], 1), names)
