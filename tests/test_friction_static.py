"""A static coefficient of friction (``static_coefficient``, mu_s >= mu): it holds a mechanism
at rest and sets where it breaks away; the kinetic mu acts while it moves.

Independent checks: closed forms of a rough arm (held at rest its pivot carries m g, so the
static limit is mu_s r m g; at the break-away the kinetic law gives the acceleration's jump),
the energy balance, and the same run without the static coefficient.
"""

import numpy as np
import pytest
from scipy.optimize import brentq
from scene_texts import ROUGH_ARM
from test_friction import HANGING

import assurjax as aj

MASS, INERTIA, ARM, RADIUS, MU, G = 2.0, 0.015, 0.15, 0.04, 0.3, 9.81  # ROUGH_ARM's arm and pivot
RAMP = 0.5  # N m/s: HANGING's drive k t
PIVOT_INERTIA = INERTIA + MASS * ARM**2  # about O (its COM 0.15 m out)
SWING = '[scene]\nname = "swing"\ngravity = [0.0, -9.81]\n[state]\nq0 = -1.5707963267948966\nomega0 = 3.0\nt1 = 1.5\n' + ROUGH_ARM


@pytest.mark.slow  # ~10 s; the static coefficient against the joint-based reference stays in the default suite
def test_breakaway_at_the_static_limit_then_the_kinetic_law(write_scene):
    """The hanging arm under a torque k t with mu_s = 0.45 > mu = 0.3: held (exactly) until
    k t = mu_s r m g, then moving with the kinetic law, its acceleration jumping from 0 to the
    root of J alpha = k t* - mu r m sqrt(g^2 + (alpha l)^2) (the pivot's reaction carries the
    COM's tangential acceleration). The break-away band at rest is +-mu_s r m g."""
    scene = aj.load_scene(write_scene(HANGING + "static_coefficient = 0.45\n"))
    limit = 0.45 * RADIUS * MASS * G
    t_star, eps = limit / RAMP, 1e-6
    ts = np.array([0.0, 0.5 * t_star, t_star - eps, t_star + eps, 0.9])
    sol = aj.simulate(scene, saveat=ts, stop=None, energies=True, rtol=1e-11, atol=1e-11)
    assert sol.status.startswith("reached t1"), sol.status
    assert np.all(sol.q[:3] == scene.state["q0"]) and np.all(sol.omega[:3] == 0.0)
    jump = brentq(lambda a: PIVOT_INERTIA * a - (limit - MU * RADIUS * MASS * np.hypot(G, a * ARM)), 0.0, 100.0)
    assert jump > 1.0  # (mu_s - mu) r m g / J: a jump the kinetic law alone would not make
    np.testing.assert_allclose(sol.domega[3], jump, rtol=1e-4)
    assert sol.q[4] > scene.state["q0"] + 1e-3
    assert np.max(np.abs(sol.balance)) < 1e-9 * np.max(np.abs(sol.total))
    lower, upper = aj.breakaway_band(scene, scene.state["q0"])
    np.testing.assert_allclose([float(lower), float(upper)], [-limit, limit], rtol=1e-12)


@pytest.mark.slow  # ~13 s; the break-away then the kinetic law stays in the default suite
def test_a_swing_sticks_where_the_static_coefficient_holds_it(write_scene):
    """The arm thrown up from hanging (3 rad/s) comes to rest at q*, where gravity's torque
    m g l |cos q*| lies between the kinetic limit mu r m g and the static mu_s r m g
    (mu_s = 2): it stays there for good (w exactly 0), where the kinetic law alone swings it
    back. Up to the rest both runs are one motion (the kinetic law); the energy balance
    closes; the reactions at rest put gravity's torque on the friction, with no drive."""
    kinetic = aj.load_scene(write_scene(SWING, "kinetic.toml"))
    static = aj.load_scene(write_scene(SWING + "static_coefficient = 2.0\n", "static.toml"))
    ts = np.linspace(0.0, 1.5, 301)
    runs = [aj.simulate(s, saveat=ts, stop=None, energies=True, rtol=1e-11, atol=1e-11) for s in (kinetic, static)]
    for sol in runs:
        assert sol.status.startswith("reached t1"), sol.status
        assert np.max(np.abs(sol.balance)) < 1e-9 * np.max(np.abs(sol.total))
    swinging, held = runs
    rest = np.flatnonzero(held.omega == 0.0)
    assert rest.size > 200 and np.all(np.diff(rest) == 1) and rest[-1] == ts.size - 1  # from its rest to t1
    q_star = held.q[rest[0]]
    assert np.all(held.q[rest] == q_star)
    torque = MASS * G * ARM * abs(np.cos(q_star))
    assert MU * RADIUS * MASS * G < torque <= 2.0 * RADIUS * MASS * G
    before = ts < ts[rest[0]] - 1e-3
    np.testing.assert_allclose(swinging.q[before], held.q[before], rtol=0, atol=1e-9)
    assert np.any(swinging.omega[rest] < -0.1)  # the kinetic law alone: it swings back
    r = aj.reactions(static, held)
    np.testing.assert_allclose(np.asarray(r.driving)[rest], 0.0, atol=1e-10)
    np.testing.assert_allclose(np.abs(np.asarray(r.friction["O"])[rest]), torque, rtol=1e-9)


def test_static_coefficient_is_checked(write_scene):
    """At least the kinetic coefficient, with the exact law only (a smoothed element holds
    nothing at rest): errors that name the element, or the scene entry and field. The
    command names the elements that have one (mu_s / mu)."""
    with pytest.raises(aj.MechanismError, match="JointFriction 'A': static_coefficient must be at least the "
                                                r"\(kinetic\) coefficient 0.2, got 0.1"):
        aj.JointFriction("A", 0.2, 0.01, static_coefficient=0.1)
    with pytest.raises(aj.MechanismError, match="SlideFriction 'block/ground': static_coefficient needs the exact law"):
        aj.SlideFriction("block/ground", 0.2, 0.04, smoothing=0.01, static_coefficient=0.3)
    with pytest.raises(aj.MechanismError, match="JointFriction 'A': static_coefficient must be finite"):
        aj.JointFriction("A", 0.2, 0.01, static_coefficient=float("inf"))
    from assurjax.cli import _static_pairs

    assert _static_pairs(aj.load_scene(write_scene(HANGING + "static_coefficient = 0.45\n", "ok.toml"))) == ["O 0.45 / 0.3"]
    entry = r"\[\[loads\]\] #2 \(joint_friction\)"
    for extra, problem in (("static_coefficient = 0.2\n", r": JointFriction 'O': static_coefficient must be at least the "
                                                          r"\(kinetic\) coefficient 0.3, got 0.2"),
                           ("static_coefficient = 0.5\nsmoothing = 0.1\n", ": JointFriction 'O': static_coefficient needs "
                                                                         "the exact law"),
                           ("static_coefficient = -1\n", ", field 'static_coefficient': must be non-negative, got -1")):
        with pytest.raises(aj.SceneError, match=entry + problem):
            aj.load_scene(write_scene(HANGING + extra, "bad.toml"))


STATIC_RATIO = 1.5  # mu_s / mu in every joint of the reference cases


def _with_static(table):
    import joint_reference_friction as jrf

    return {name: jrf.Friction(mu=f.mu, radius=f.radius, length=f.length, damping=f.damping,
                               static=STATIC_RATIO * f.mu) for name, f in table.items()}


def _package_static(mechanism, table):
    out = []
    for name in aj.joint_names(mechanism):
        ref = table["P" if "/" in name else name]
        if "/" in name:
            out.append(aj.SlideFriction(name, ref.mu, ref.length, viscous=ref.damping, static_coefficient=ref.static))
        else:
            out.append(aj.JointFriction(name, ref.mu, ref.radius, viscous=ref.damping, static_coefficient=ref.static))
    return tuple(out)


@pytest.mark.parametrize("case", ["slider_crank", pytest.param("slider_crank_driven", marks=pytest.mark.slow)])
def test_agrees_with_the_joint_based_reference(case):
    """The slider-crank rough in every pair (viscous terms too) with mu_s = 1.5 mu: from rest
    at 0.5 rad (it swings and sticks), and under a drive 0.3 sin 5t (held, broken away, held
    again: stick segments under a load in time), against the joint-based reference whose
    rest tests read its own static coefficients (its motion 0.02-0.17 rad away from that with mu
    alone, longer at rest): q within 1e-8 rad, the same samples at rest, and a closed energy
    balance."""
    import joint_reference_friction as jrf
    from test_friction import _reference_case

    scene, q0, w0, drive, t1, table, ref = _reference_case(case)
    times = np.linspace(0.0, t1, 41)
    kinetic = ref.simulate(t1, t_eval=times)
    table = _with_static(table)
    expected = jrf.with_friction(ref, table).simulate(t1, t_eval=times)
    assert np.max(np.abs(expected.q - kinetic.q)) > 1e-2 and expected.stuck.sum() > kinetic.stuck.sum()  # it matters
    drives = (aj.Drive(lambda q, w, t: drive(t)),) if callable(drive) else ()
    loads = tuple(scene.loads) + drives + _package_static(scene.mechanism, table)
    sol = aj.simulate(scene, loads=loads, q0=q0, omega0=w0, stop=None, t1=t1, saveat=times, energies=True, rtol=1e-10,
                      atol=1e-10)
    assert sol.status.startswith("reached t1"), sol.status
    if expected.stuck[-1]:  # held to t1 (the reference's rests): the status says since when
        last = np.flatnonzero(~expected.stuck)[-1]
        assert sol.status.endswith(f", held at rest by the joint friction since between the samples at t = "
                                   f"{times[last]:.6g} and {times[last + 1]:.6g} s"), sol.status
    np.testing.assert_allclose(sol.q, expected.q, rtol=0, atol=1e-8)
    np.testing.assert_allclose(sol.omega, expected.w, rtol=0, atol=1e-7)
    np.testing.assert_array_equal(sol.omega[1:] == 0.0, expected.stuck[1:])
    assert expected.stuck[1:].any()
    assert np.max(np.abs(sol.balance)) < 1e-7 * np.max(np.abs(sol.total))


@pytest.mark.slow  # ~12 s (programs of its own); the static coefficient against the reference stays in the default suite
def test_a_traced_static_coefficient_below_the_kinetic_one_is_named_not_held():
    """A static coefficient below mu that the constructor cannot check (traced under the
    user's jit, an optimizer's step, put in by tree_at): the weaker rest law broke the
    mechanism away and the kinetic law stopped it again at once, so it read as held at its
    start (q(T) = q0, a plausible answer). The run's result names it; the band is NaN."""
    import equinox as eqx

    from test_friction import _reference_case

    scene, q0, w0, _, t1, table, _ = _reference_case("slider_crank")
    loads = tuple(scene.loads) + _package_static(scene.mechanism, _with_static(table))
    rough = (aj.JointFriction, aj.SlideFriction)
    weaker = eqx.tree_at(lambda ls: [f.static_coefficient for f in ls if isinstance(f, rough)], loads,
                         replace_fn=lambda mu_s: 0.5 * mu_s / STATIC_RATIO)  # half of mu
    sol = aj.simulate(scene, loads=weaker, q0=q0, omega0=w0, stop=None, t1=t1, saveat=np.linspace(0.0, t1, 41),
                      energies=True, rtol=1e-10, atol=1e-10)
    assert sol.result == aj.RESULTS.static_below_kinetic and not sol.successful
    assert "static coefficient is below its kinetic coefficient" in sol.status, sol.status
    lower, upper = aj.breakaway_band(scene.with_loads(weaker), q0)
    assert np.isnan(lower) and np.isnan(upper)


@pytest.mark.slow  # reverse and forward mode through stick segments and a batch: ~1.5 min of compiles
def test_derivative_in_the_static_coefficient_and_a_batch(write_scene):
    """d q(0.9 s) / d mu_s of the hanging arm under k t (mu_s sets the located break-away,
    t* = mu_s r m g / k) in reverse and forward mode against central differences; and a batch
    of swings thrown at three speeds, each held where it first rests, as its single run."""
    import jax
    import jax.numpy as jnp

    scene = aj.load_scene(write_scene(HANGING))
    ramp = tuple(load for load in scene.loads if isinstance(load, aj.Drive))

    def q_at(mu_s, adjoint="recursive"):
        rough = scene.with_loads(ramp + (aj.JointFriction("O", MU, RADIUS, static_coefficient=mu_s),))
        return aj.synthesis.final_state(rough, 0.9, rtol=1e-11, atol=1e-11, adjoint=adjoint)[0]

    h = 1e-6
    fd = (q_at(jnp.asarray(0.45 + h)) - q_at(jnp.asarray(0.45 - h))) / (2 * h)
    np.testing.assert_allclose(float(jax.grad(q_at)(jnp.asarray(0.45))), float(fd), rtol=1e-6)
    np.testing.assert_allclose(float(jax.jacfwd(lambda m: q_at(m, "forward"))(jnp.asarray(0.45))), float(fd), rtol=1e-6)
    swing = aj.load_scene(write_scene(SWING + "static_coefficient = 2.0\n", "swing.toml"))
    speeds = [2.0, 3.0, 4.0]
    batch = aj.simulate(swing, omega0=jnp.array(speeds), stop=None, rtol=1e-10, atol=1e-10)
    for k, w0 in enumerate(speeds):
        one = aj.simulate(swing, omega0=w0, stop=None, rtol=1e-10, atol=1e-10)
        assert one.omega[-1] == 0.0 and batch.omega[k][-1] == 0.0
        np.testing.assert_allclose(batch.q[k], one.q, rtol=0, atol=1e-9)


BAND_SCRIPT = """
import json, numpy as np, assurjax as aj
sc = aj.load_scene("slider_crank")
rough = tuple(aj.JointFriction(j, 0.2, radius=0.01) for j in ("O", "A", "B")) + (aj.SlideFriction("slider/ground", 0.15, 0.05),)
lower, upper = aj.breakaway_band(sc.with_loads(sc.loads + rough), np.linspace(0.1, 6.2, 13))
print(json.dumps([np.asarray(lower).tolist(), np.asarray(upper).tolist(), str(np.asarray(lower).dtype)]))
"""


@pytest.mark.slow  # a float32 process of its own
def test_the_breakaway_band_in_float32():
    """Each edge is tested with the drive just past it: 1e-9 of it, below float32's spacing,
    put the test at the edge, where the sign of dw/dt is rounding (10 of the slider-crank's
    13 bands came out with an infinite edge: 'no drive starts it'). In float32 the band is
    the float64 one to float32's precision."""
    import json
    import os
    import subprocess
    import sys

    env = {**os.environ, "ASSURJAX_FLOAT32": "1", "JAX_ENABLE_X64": "0"}
    out = subprocess.run([sys.executable, "-c", BAND_SCRIPT], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    lower32, upper32, dtype = json.loads(out.stdout.strip().splitlines()[-1])
    assert dtype == "float32"
    sc = aj.load_scene("slider_crank")
    rough = tuple(aj.JointFriction(j, 0.2, radius=0.01) for j in ("O", "A", "B")) + (aj.SlideFriction("slider/ground", 0.15, 0.05),)
    lower, upper = aj.breakaway_band(sc.with_loads(sc.loads + rough), np.linspace(0.1, 6.2, 13))
    np.testing.assert_allclose(lower32, lower, rtol=0, atol=1e-5)
    np.testing.assert_allclose(upper32, upper, rtol=0, atol=1e-5)


@pytest.mark.slow  # ~8 s: the press's friction analysis compiled for one documented number
def test_the_documented_band_of_the_press_at_its_dead_point():
    """docs/kinetostatics.md: the press's band at q = 0 (the slider on its dead point), and
    without the ram's slide friction."""
    press = aj.load_scene("press_with_friction")
    band = np.round(np.asarray(aj.breakaway_band(press, 0.0)), 5)
    np.testing.assert_array_equal(band, [0.70774, 0.76405])
    pins = tuple(l for l in press.loads if not isinstance(l, aj.SlideFriction))
    band = np.round(np.asarray(aj.breakaway_band(press.with_loads(pins), 0.0)), 5)
    np.testing.assert_array_equal(band, [0.70892, 0.76287])


@pytest.mark.slow  # its own reactions program (~12 s)
def test_a_self_locked_press_held_at_rest_carries_its_drive(write_scene):
    """Held at rest and self-locked both ways (band (-inf, inf)), the press carries its drive:
    ``driving`` is the drive, and the ram's own balance (gravity, the drive, the rod at B and
    the guide's friction within mu_s |N|) bounds |R_B| below; every pin's couple within mu_s r |F|.
    The drive once entered nowhere: 204.69 N and |R_B| 9 N for any drive."""
    from scene_texts import SELF_LOCKED_PRESS

    scene = aj.load_scene(write_scene(SELF_LOCKED_PRESS))
    assert aj.breakaway_band(scene, 0.0) == (-np.inf, np.inf)
    weight, mu_s, radius, length = 20.0 * 9.81, 0.3, 0.02, 0.06
    for drive in (-2000.0, -200.0, 500.0):
        r = aj.reactions(scene.with_loads(scene.loads + (aj.Drive(drive),)), (0.0, 0.0, 0.0))
        assert bool(r.friction_ok) and float(r.driving) == pytest.approx(drive, rel=1e-9)
        # the ram (its force along y): drive - weight + friction + (force on it by the rod)_y = 0;
        # its moments: the guide's couple C balances pin B's friction couple (all else acts at B);
        # the guide's friction at most mu_s (|N/2 - C/L| + |N/2 + C/L|) <= mu_s (|N| + 2 |C| / L)
        on_ram = {p.name: p.on == "ram" for p in r.pairs}["B"]
        rod_on_ram = np.asarray(r["B"]) if on_ram else -np.asarray(r["B"])
        ram_friction, normal = float(r.friction["ram/ground"]), float(r["ram/ground"][0])
        couple = float(r.couples["ram/ground"])
        assert drive - weight + ram_friction + rod_on_ram[1] == pytest.approx(0.0, abs=1e-6 * abs(drive))
        assert abs(couple) == pytest.approx(abs(float(r.friction["B"])), rel=1e-9)
        ends = abs(normal / 2 - couple / length) + abs(normal / 2 + couple / length)
        assert abs(ram_friction) <= mu_s * ends * (1 + 1e-9)
        # so |R_B| >= |drive - W| - mu_s |R_Bx| - 2 mu_s |C| / L, with |C| <= mu_s r |R_B|
        least = abs(drive - weight) / (1.0 + mu_s + 2 * mu_s**2 * radius / length)
        assert np.linalg.norm(rod_on_ram) >= least
        for joint in "OAB":
            assert abs(float(r.friction[joint])) <= mu_s * radius * np.linalg.norm(r[joint]) * (1 + 1e-9)
