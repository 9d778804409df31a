"""Joint friction on random drawings over every group kind, against the joint-based
reference with Coulomb friction (tests/joint_reference_friction.py: absolute coordinates,
multipliers, the friction from the multipliers, Newton's method on the law).

A drawing (tests/test_sketch_random.py) is a crank or a slider driving an RRR, RRP, RPR
and PRP dyad, a class-III triad and a class-IV group (the default suite: the dyads only),
in a random order with random names; here every link also gets a random mass, inertia and centre of mass, and every
pair friction (revolutes mu r |F|, prismatic pairs the block law, viscous terms). The
package builds the mechanism from the drawing (its own Assur decomposition); the
reference is built from the same drawing. Where more than two links share a point, the
reference pins them as the package's pairs do (which links a pin joins is part of the
model; the dynamics of each side is its own). At states along the drawn branch, moving
either way:

- forward: the package's dw/dt with friction is the reference's;
- inverse: the package's driving effort for the reference's motion is 0 (none applied);
- the friction matters there: the frictionless reference's dw/dt differs;
- (slow) a simulation from the drawing: q(t) is the reference's (its stick/slip segments,
  its Coulomb switches).

Where the reference's Newton's method finds no friction values, even continued in mu
(strong coupling in some of these drawings), the package must find no consistent ones
either (a jam).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import assurjax as aj
import joint_reference as jr
import joint_reference_friction as jrf
from assurjax._friction import pairs_by_name
from assurjax.dynamics._field import State, frictional
from assurjax.structure import Sketch, Slide, build
from joint_reference import Prismatic, Revolute
from test_sketch_random import KINDS, Q0, Drawing, follow

MU, RADIUS, LENGTH = 0.15, 0.02, 0.1
OFFSETS = (-0.1, 0.0, 0.1)  # q - q0 of the states checked (rad, or m along the slider's guide)
RATES = (1.3, -0.7)  # w at each
DYADS = ("RRR", "RRP", "RPR", "PRP")


def rough_drawing(seed: int, driver: str, kinds=KINDS):
    """(package Model, reference FrictionSystem, frictionless twin, q at the drawing, the
    reference's coordinate per unit q) of a random drawing of these kinds (in a random
    order, with random names and link order, as tests/test_sketch_random.py draws them)."""
    rng = np.random.default_rng(seed)
    d = Drawing(rng, list(rng.permutation(kinds)), driver, "+", seed)
    link_names = {k: f"link_{v}" for k, v in zip(d.links, rng.permutation(len(d.links)))}
    joint_names = {p: f"J{v}" for p, v in zip(d.joints, rng.permutation(len(d.joints)))}
    order = list(rng.permutation(list(d.links)))
    props = np.random.default_rng(seed + 1000)
    body = {k: dict(mass=props.uniform(0.5, 2.0), inertia=props.uniform(0.02, 0.2),
                    com=np.mean([d.joints[p] for p in d.links[k]], axis=0) + props.uniform(-0.1, 0.1, 2)) for k in d.links}
    name = lambda k: link_names.get(k, k)  # noqa: E731  (the ground keeps its name)
    sketch = Sketch({joint_names[p]: xy for p, xy in d.joints.items()},
                    {name(k): dict(joints=[joint_names[p] for p in d.links[k]], mass=body[k]["mass"],
                                   inertia=body[k]["inertia"], com=tuple(body[k]["com"])) for k in order},
                    ground=[joint_names[p] for p in d.ground], slides=[Slide(name(s.link), name(s.on), s.direction) for s in d.slides],
                    driver=name("l0"), q0=Q0 if d.driver_u is None else 0.0)
    mechanism = build(sketch).mechanism
    # the reference: every link frame the identity in the drawing, so local points are drawn ones
    bodies = {name(k): dict(mass=b["mass"], inertia=b["inertia"], com_local=tuple(b["com"])) for k, b in body.items()}
    drawn = {joint_names[p]: tuple(xy) for p, xy in d.joints.items()}
    pairs = pairs_by_name(mechanism)
    joints = [Revolute(n, p.by, p.on, drawn[p.point], drawn[p.point]) for n, p in pairs.items() if p.kind == "R"]
    for s in d.slides:  # sliding at the slider's first joint, as the package's pair does
        n, at = f"{name(s.link)}/{name(s.on)}", joint_names[d.links[s.link][0]]
        assert pairs[n].point == at
        joints.append(Prismatic(n, name(s.on), name(s.link), drawn[at], drawn[at], s.direction))
    friction = {n: jrf.Friction(mu=MU, radius=RADIUS, damping=1e-3) if p.kind == "R" else jrf.Friction(mu=MU, length=LENGTH, damping=0.05)
                for n, p in pairs.items()}
    loads = tuple(aj.JointFriction(n, MU, RADIUS, viscous=1e-3) if p.kind == "R" else aj.SlideFriction(n, MU, LENGTH, viscous=0.05)
                  for n, p in pairs.items())
    driven = (name("l0"), "angle" if d.driver_u is None else "x")
    reference = jrf.FrictionSystem(bodies, joints, driven, friction=friction, max_dq=0.02)
    frictionless = jrf.FrictionSystem(bodies, joints, driven, max_dq=0.02)
    scale = 1.0 if d.driver_u is None else float(d.driver_u[0])  # a slider drives x = q u_x
    model = aj.Model(mechanism, jnp.array([0.0, -9.81]), loads)
    return model, reference, frictionless, (Q0 if d.driver_u is None else 0.0), scale


def reference_states(reference, frictionless, q0, scale):
    """(q, w, dw/dt with friction, dw/dt without) in the package's coordinate, where the
    drawn branch reaches (a limit position may end it first), and the (q, w) where the
    reference's friction solve finds no root, even continued in mu (16 steps)."""
    rows, jams = [], []
    for dq in OFFSETS:
        z = follow(reference, 0.0, dq * scale, np.zeros(reference.n))
        for w in RATES if z is not None else ():
            try:
                rough = reference.forward(z, w * scale)["wdot"]
            except RuntimeError:  # "friction Newton did not converge"
                reference.continuation = 16
                try:
                    rough = reference.forward(z, w * scale)["wdot"]
                except RuntimeError:
                    jams.append((q0 + dq, w))
                    continue
                finally:
                    reference.continuation = 1
            rows.append((q0 + dq, w, rough / scale, frictionless.forward(z, w * scale)["wdot"] / scale))
    return np.array(rows), np.array(jams).reshape(-1, 2)


@jax.jit
def _forward(model, q, w):
    """dw/dt and whether the friction has a consistent solution (the simulation's path)."""
    found = jax.vmap(lambda q, w: frictional(model, 0.0, State(q, w), jnp.sign(w)))(q, w)
    return found.alpha, found.consistent


def check_drawing(seed: int, driver: str, kinds=KINDS):
    model, reference, frictionless, q0, scale = rough_drawing(seed, driver, kinds)
    states, jams = reference_states(reference, frictionless, q0, scale)
    assert len(states) >= 4, f"the reference reached only {len(states)} states with friction ({len(jams)} jams)"
    q, w, rough, smooth = states.T
    size = 1.0 + np.abs(rough)
    assert np.all(np.abs(rough - smooth) > 1e-2 * size)  # the friction matters at every state
    alpha, consistent = (np.asarray(v) for v in _forward(model, np.append(q, jams[:, 0]), np.append(w, jams[:, 1])))
    assert np.all(consistent[:len(q)])
    np.testing.assert_allclose(alpha[:len(q)], rough, rtol=0, atol=1e-10 * size.max())
    # where the reference finds no friction values, the package finds no consistent ones (a jam)
    assert not np.any(consistent[len(q):])
    inverse = aj.reactions(model, (q, w, rough))
    assert bool(jnp.all(inverse.ok))
    np.testing.assert_allclose(np.asarray(inverse.driving), 0.0, atol=1e-10 * size.max())


def test_a_random_drawing_of_dyads_with_friction_in_every_pair():
    """A crank driving an RRR, RRP, RPR and PRP dyad (closed forms: a short compile)."""
    check_drawing(0, "crank", DYADS)


@pytest.mark.slow
@pytest.mark.parametrize("seed, driver", [(1, "crank"), (0, "crank"), (0, "slider"), (1, "slider")])
def test_random_drawings_of_every_kind_with_friction_in_every_pair(seed, driver):
    """Every group kind, 25 rough pairs. Seed 1: its PRP's two sliders turn together, and
    their pin's relative rate was round-off (1e-16), which gave it a Coulomb sign and a full
    friction couple (dw/dt off by 0.04 rad/s^2, the inverse's effort by 0.1 N m). The
    slider-driven seed 0: the reference finds no friction values at three of its states,
    where the package reports no consistent ones."""
    check_drawing(seed, driver)


@pytest.mark.slow
@pytest.mark.parametrize("seed, driver, omega0, t1", [(1, "crank", RATES[0], 0.5), (1, "slider", RATES[0], 0.5),
                                                      (1, "crank", 0.0, 1.0)])
def test_a_random_drawing_of_every_kind_moves_as_the_reference(seed, driver, omega0, t1):
    """From the drawing under gravity, friction in all 25 pairs: q within 1e-8 of the
    reference at 11 times. Seed 1 (crank): the pin whose links turn together took a
    Coulomb sign at each segment's start from its slope's round-off (q off by 3.5e-4 rad
    at 0.5 s); from rest, a dead point of a sub-chain (12 rates through 0 at once, the pin's
    rate terms with them) left that slope's round-off above the rate terms' scale (w off
    by 8e-7 after it). That motion then reverses (a rest)."""
    model, reference, _, q0, scale = rough_drawing(seed, driver)
    times = np.linspace(0.0, t1, 11)
    start = jr.Initial(0.0, omega0 * scale, reference.to_frames(np.zeros(reference.n)))
    expected = jrf.FrictionModel(reference, start).simulate(t1, t_eval=times)
    sol = aj.simulate(model.mechanism, gravity=model.gravity, loads=model.loads, q0=q0, omega0=omega0, t1=t1,
                      stop=None, saveat=times, rtol=1e-10, atol=1e-10)
    assert sol.status.startswith("reached t1"), sol.status
    np.testing.assert_allclose(np.asarray(sol.q), q0 + expected.q / scale, rtol=0, atol=1e-8)
    np.testing.assert_array_equal(np.asarray(sol.omega)[1:] == 0.0, expected.stuck[1:])
