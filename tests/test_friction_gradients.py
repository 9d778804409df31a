"""Derivatives through joint friction against central differences: the press with Coulomb
friction in its pins and its slide, d q(T)/d mu (docs/design-notes.md, "A slide's block
ends and the loads' knots").

From rest at q = 0 (a dead point: the ram's rate is 0 there) the motion runs to pin B's
Coulomb switch at q = pi/2 (0.0869 s). Inside it, at 0.03648 s and 0.05295 s, the load on
one end of the ram's block, N/2 - M/L, passes through 0 (the couple M is pin B's friction
moment carried to the guide): the slide's Coulomb magnitude mu (|N/2 - M/L| + |N/2 + M/L|)
has a kink there. In a run that can be differentiated (``simulate_core``, ``final_state``,
not ``simulate``), each slip segment freezes the block ends' signs and an event ends it at
such a kink (``Settings.kink_events``, which also cuts at the knots of the loads' tables);
without the cuts, the steps crossed the kinks and the derivative erred by ~sqrt(tol): 4e-5
relative at T = 0.1 s with rtol = atol = 1e-10.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import assurjax as aj

TOL = 1e-10
MU = 0.15


@pytest.fixture(scope="module")
def q_and_slope():
    """(q(T), d q(T)/d mu) at (mu, T), forward mode: one compiled program for every mu and
    T (both traced); the differences take its values too."""
    press = aj.load_scene("press_with_friction")
    others = tuple(load for load in press.loads if not isinstance(load, (aj.JointFriction, aj.SlideFriction)))

    def q_at(mu, t1):
        rough = tuple(aj.JointFriction(j, mu, radius=0.01) for j in ("O", "A", "B")) + (
            aj.SlideFriction("ram/ground", mu, 0.05),)
        return aj.synthesis.final_state(press.with_loads(others + rough), t1, rtol=TOL, atol=TOL, adjoint="forward")[0]

    program = jax.jit(lambda mu, t1: jax.jvp(lambda m: q_at(m, t1), (mu,), (jnp.ones(()),)))

    def run(mu, t1):
        q, slope = program(jnp.asarray(mu, dtype=float), jnp.asarray(t1, dtype=float))
        return float(q), float(slope)

    return run


def _differences(q_and_slope, t1, h=1e-3):
    return (q_and_slope(MU + h, t1)[0] - q_and_slope(MU - h, t1)[0]) / (2 * h)


@pytest.mark.slow
def test_gradient_in_mu_before_the_block_end_kink(q_and_slope):
    """Up to the first kink (T = 0.03 s, from rest on a dead point): exact to the tolerance
    (3e-10 relative)."""
    np.testing.assert_allclose(q_and_slope(MU, 0.03)[1], _differences(q_and_slope, 0.03), rtol=1e-7)


@pytest.mark.slow
def test_gradient_in_mu_past_the_block_end_kinks(q_and_slope):
    """Past both kinks and pin B's Coulomb switch (T = 0.1 s): to the differences' own
    spread (they agree with those at rtol 1e-12 to 2e-6; without the cuts 4e-5 off)."""
    np.testing.assert_allclose(q_and_slope(MU, 0.1)[1], _differences(q_and_slope, 0.1), rtol=2e-6)


@pytest.mark.slow
def test_gradient_in_mu_past_the_process_force_knots(q_and_slope):
    """T = 0.5 s: past the process force's knots (a table in q: kinks of the load, each the
    end of a segment, whose field reads the table's piece continued past the next knot),
    more block-end kinks and Coulomb switches; against differences Richardson-extrapolated
    from h = 2e-3 and 1e-3 (their own error ~3e-9). Without any cut 1.8e-5 off; cut at the
    knots but with the table read as given (the step that crosses a knot spoils the dense
    output the event is located on) 7.7e-6."""
    d1, d2 = _differences(q_and_slope, 0.5, h=2e-3), _differences(q_and_slope, 0.5, h=1e-3)
    np.testing.assert_allclose(q_and_slope(MU, 0.5)[1], (4 * d2 - d1) / 3, rtol=2e-7)


@pytest.mark.slow
def test_cut_runs_move_as_uncut_ones(q_and_slope):
    """The cuts at the kinks change the steps, not the motion: q(0.1 s) of the differentiated
    run (cut) against simulate's (never differentiated, not cut) at a tolerance 100x tighter,
    itself checked against the joint-based reference elsewhere (tests/test_friction.py)."""
    press = aj.load_scene("press_with_friction")
    others = tuple(load for load in press.loads if not isinstance(load, (aj.JointFriction, aj.SlideFriction)))
    rough = tuple(aj.JointFriction(j, MU, radius=0.01) for j in ("O", "A", "B")) + (aj.SlideFriction("ram/ground", MU, 0.05),)
    sol = aj.simulate(press.with_loads(others + rough), t1=0.1, rtol=1e-12, atol=1e-12, stop=None)
    np.testing.assert_allclose(q_and_slope(MU, 0.1)[0], float(sol.q_final), rtol=0, atol=1e-9)


@pytest.mark.slow
def test_reverse_mode_past_the_block_end_kinks():
    """jax.grad (reverse mode, the default adjoint) of q(0.1 s) in mu against central
    differences of the same function."""
    press = aj.load_scene("press_with_friction")
    others = tuple(load for load in press.loads if not isinstance(load, (aj.JointFriction, aj.SlideFriction)))

    @jax.jit
    def q_at(mu):
        rough = tuple(aj.JointFriction(j, mu, radius=0.01) for j in ("O", "A", "B")) + (
            aj.SlideFriction("ram/ground", mu, 0.05),)
        return aj.synthesis.final_state(press.with_loads(others + rough), 0.1, rtol=TOL, atol=TOL)[0]

    slope = float(jax.jit(jax.grad(q_at))(jnp.asarray(MU)))
    h = 1e-3
    np.testing.assert_allclose(slope, (float(q_at(MU + h)) - float(q_at(MU - h))) / (2 * h), rtol=2e-6)


@pytest.mark.slow  # ~4 min: a reverse-mode and a forward-mode program
def test_reverse_mode_through_a_run_the_friction_jams_after_it_moved():
    """The slider-crank with a 0.12 m rod, driven by 3 N m from rest at q = 0.5 with mu in
    every pair: at mu = 0.6 it moves, then the friction jams it before T = 0.5 s. Its
    final_state has no q(T) (NaN under a transformation) and derivative 0: jax.grad gives 0
    as forward mode does (it raised from lineax: the jam segment's pullback, whose rejected
    steps hold NaN partials, sent 0 x NaN into the earlier segments' event root finds); at
    mu = 0.3 (no jam) the two modes give the same derivative."""
    base = aj.load_scene("slider_crank")
    rod = eqx.tree_at(lambda m: (m.links["rod"].points["B"], m.links["rod"].com), base.mechanism,
                      (jnp.array([0.12, 0.0]), jnp.array([0.06, 0.0])))
    base = eqx.tree_at(lambda s: s.mechanism, base, rod)

    def scene(mu):
        return base.with_loads(tuple(aj.JointFriction(j, mu, 0.01) for j in ("O", "A", "B"))
                               + (aj.SlideFriction("slider/ground", mu, 0.05), aj.Drive(3.0)))

    def q_at(mu, adjoint):
        return aj.synthesis.final_state(scene(mu), 0.5, q0=0.5, omega0=0.0, rtol=1e-9, atol=1e-9, adjoint=adjoint)[0]

    jammed = aj.simulate(scene(0.6), q0=0.5, omega0=0.0, stop=None, t1=0.5, samples=5, energies=False)
    assert jammed.jammed and 0.0 < float(jammed.t_final) < 0.5 and float(jammed.q_final) > 0.6, jammed.status
    reverse = jax.jit(jax.grad(lambda mu: q_at(mu, "recursive")))
    forward = jax.jit(jax.jacfwd(lambda mu: q_at(mu, "forward")))
    assert float(reverse(0.6)) == 0.0 and float(forward(0.6)) == 0.0
    np.testing.assert_allclose(float(reverse(0.3)), float(forward(0.3)), rtol=1e-9)


@pytest.mark.slow  # ~5 min: a vmapped reverse-mode program and the single runs' forward-mode one
def test_vmapped_reverse_mode_over_designs_of_which_one_jams():
    """jax.vmap(jax.grad(final_state)) over mu = 0.1 and 0.3 (they move to T) and 0.6 (the
    friction jams it after it moved), the slider-crank of the test before: each member's
    derivative is its forward-mode one (0 for the jammed run, whose value is NaN), and its
    value its single run's. It raised from lineax for the whole batch, also without the jammed
    member: the batch ran in whole segments (the package's nested jit hid the vmap) and the
    pullbacks' conds were selects."""
    base = aj.load_scene("slider_crank")
    rod = eqx.tree_at(lambda m: (m.links["rod"].points["B"], m.links["rod"].com), base.mechanism,
                      (jnp.array([0.12, 0.0]), jnp.array([0.06, 0.0])))
    base = eqx.tree_at(lambda s: s.mechanism, base, rod)

    def q_at(mu, adjoint="recursive"):
        scene = base.with_loads(tuple(aj.JointFriction(j, mu, 0.01) for j in ("O", "A", "B"))
                                + (aj.SlideFriction("slider/ground", mu, 0.05), aj.Drive(3.0)))
        return aj.synthesis.final_state(scene, 0.5, q0=0.5, omega0=0.0, rtol=1e-9, atol=1e-9, adjoint=adjoint)[0]

    mus = jnp.array([0.1, 0.3, 0.6])
    values, slopes = jax.jit(jax.vmap(jax.value_and_grad(q_at)))(mus)
    forward = jax.jit(jax.vmap(jax.jacfwd(lambda mu: q_at(mu, "forward"))))(mus)
    assert np.isnan(values[2]) and float(slopes[2]) == 0.0 and float(forward[2]) == 0.0
    # a batch runs in chunks of steps: its own step sequence (the values agree with the single
    # runs' to the tolerance), and there the two modes agree to the tolerance's level, not to
    # round-off as in whole segments
    np.testing.assert_allclose(values[:2], [float(q_at(mu)) for mu in mus[:2]], rtol=0, atol=1e-7)
    np.testing.assert_allclose(slopes[:2], forward[:2], rtol=5e-7)


# ------------------------------------------------------------ the frozen law, by itself
def test_frozen_block_signs_are_the_law_where_they_hold_and_its_branch_past_them():
    """limits() with a prismatic pair's block-end signs frozen: equal to the law as written
    where the signs are the loads' own, and past a sign change the analytic branch
    b (s1 (N/2 - M/L) + s2 (N/2 + M/L)), written out here."""
    from assurjax._friction import limits

    b, normal, inverse_length = 0.2, jnp.array([0.0, 1.0]), 1.0 / 0.05
    for force, couple in ((jnp.array([3.0, -2.0]), 0.01), (jnp.array([-1.0, 4.0]), -0.3), (jnp.array([0.5, 0.2]), 0.02)):
        ends = np.array([0.5 * force[1] - couple * inverse_length, 0.5 * force[1] + couple * inverse_length])
        written = b * np.sum(np.abs(ends))
        unfrozen = limits((None, b, normal, inverse_length, None), force, couple)
        own = limits((None, b, normal, inverse_length, jnp.asarray(np.sign(ends))), force, couple)
        flipped = limits((None, b, normal, inverse_length, jnp.asarray(-np.sign(ends) * [1.0, 0.0])), force, couple)
        np.testing.assert_allclose([unfrozen, own], written, rtol=1e-15)
        # the first end frozen against its load's sign, the second not frozen (0: read as |.|)
        np.testing.assert_allclose(flipped, b * (-abs(ends[0]) + abs(ends[1])), rtol=1e-15)


def test_next_knot_of_periodic_and_plain_tables():
    """_loads.next_knot against knots counted by hand: the press's process-force table
    (period 2 pi) and a plain time table."""
    from assurjax._loads import Table, next_knot

    two_pi = 2 * np.pi
    press = Table([0.0, 4 * np.pi / 3, 5 * np.pi / 3, 23 * np.pi / 12, two_pi], [0.0, 0.0, -300.0, -300.0, 0.0], period=two_pi)
    ramp = Table([0.5, 1.0], [0.0, 2.0], variable="t")
    cases = [(press, 7.0, 1.0, two_pi + 4 * np.pi / 3), (press, 7.0, -1.0, two_pi),
             (press, 4 * np.pi / 3, 1.0, 5 * np.pi / 3), (press, 4 * np.pi / 3, -1.0, 0.0),  # on a knot: the next one
             (press, -0.1, -1.0, -two_pi + 23 * np.pi / 12), (ramp, 0.2, 1.0, 0.5), (ramp, 1.0, 1.0, np.inf),
             (ramp, 0.7, -1.0, 0.5)]
    for table, x, direction, expected in cases:
        np.testing.assert_allclose(float(next_knot((table,), jnp.asarray(x), direction)), expected, rtol=1e-14, atol=1e-14)
    both = float(next_knot((press, Table([2.0, 3.0], [1.0, 0.0])), jnp.asarray(0.5), 1.0))
    assert both == 2.0


def test_a_tables_piece_is_continued_past_its_knot():
    """_loads.pieces_at and with_pieces: the press's process-force table read as its piece
    ahead of q, written out here (the ramp from 0 at 240 deg to -300 N at 300 deg), equal to
    the table inside the piece and its straight line past the knot; a period later the same."""
    from assurjax._loads import PointForce, Table, Vector, pieces_at, tables_in, with_pieces

    two_pi = 2 * np.pi
    table = Table([0.0, 4 * np.pi / 3, 5 * np.pi / 3, 23 * np.pi / 12, two_pi], [0.0, 0.0, -300.0, -300.0, 0.0], period=two_pi)
    loads = (PointForce("B", Vector(table, 0.0), link="ram"),)
    slope = -300.0 / (np.pi / 3)
    for turn in (0.0, two_pi):
        q0 = turn + 4.5
        (frozen,) = tables_in(with_pieces(loads, "q", pieces_at(tables_in(loads, "q"), jnp.asarray(q0), 1.0)), "q")
        for q in (q0, turn + 5.0, turn + 5.5):  # the last past the knot at 300 deg
            line = slope * (q - turn - 4 * np.pi / 3)
            np.testing.assert_allclose(float(frozen(q, 0.0, 0.0)), line, rtol=1e-13)
        np.testing.assert_allclose(float(frozen(turn + 5.0, 0.0, 0.0)), float(table(turn + 5.0, 0.0, 0.0)), rtol=1e-13)
    (behind,) = tables_in(with_pieces(loads, "q", pieces_at(tables_in(loads, "q"), jnp.asarray(4.5), -1.0)), "q")
    np.testing.assert_allclose(float(behind(4.0, 0.0, 0.0)), slope * (4.0 - 4 * np.pi / 3), rtol=1e-13)


# a kinked torque-speed curve on the press's crank, for its motor line: knots at 4, 8, 12 and 16 rad/s
SPEED_CURVE = ([0.0, 4.0, 8.0, 12.0, 16.0, 20.0], [40.0, 33.0, 25.0, 19.0, 10.0, 0.0])


@pytest.mark.slow
def test_gradient_in_mu_past_the_knots_of_a_table_in_omega():
    """The press driven through a torque-speed table (kinks in omega, which goes up through
    its knots and back down through them within 0.3 s): a segment ends where omega leaves its
    piece either way, and reads that piece continued past it. d q(0.3 s)/d mu against
    differences Richardson-extrapolated from h = 2e-3 and 1e-3 (their spread 5e-7): 2e-8 off
    at rtol 1e-10 (uncut, the steps crossing the kinks, 6e-7 off differences at rtol 1e-12:
    benchmarks/README.md)."""
    press = aj.load_scene("press_with_friction")
    others = tuple(load for load in press.loads if isinstance(load, aj.PointForce))
    drive = aj.Drive(aj.Table(*SPEED_CURVE, variable="omega"))

    def scene(mu):
        rough = tuple(aj.JointFriction(j, mu, radius=0.01) for j in ("O", "A", "B")) + (aj.SlideFriction("ram/ground", mu, 0.05),)
        return press.with_loads(others + (drive,) + rough)

    omega = aj.simulate(scene(MU), t1=0.3, stop=None, samples=301).omega
    assert np.max(omega) > 17.0 and omega[-1] < 7.0  # from rest up through the knots, then down through 16, 12 and 8
    program = jax.jit(lambda mu: jax.jvp(lambda m: aj.synthesis.final_state(scene(m), 0.3, rtol=TOL, atol=TOL, adjoint="forward")[0],
                                         (mu,), (jnp.ones(()),)))
    q = lambda mu: float(program(jnp.asarray(mu))[0])  # noqa: E731
    d1, d2 = ((q(MU + h) - q(MU - h)) / (2 * h) for h in (2e-3, 1e-3))
    np.testing.assert_allclose(float(program(jnp.asarray(MU))[1]), (4 * d2 - d1) / 3, rtol=1e-7)


def test_a_piece_in_omega_is_bounded_by_its_knots_either_way():
    """_loads.piece_around against the table's knots by hand: between knots, its piece and the
    knots around it; on a knot (to round-off either side), the piece on the side given and the
    knots around that piece, moved out by the round-off pad."""
    from assurjax._loads import KNOT_ROUNDOFF, Table, piece_around

    table = Table(*SPEED_CURVE, variable="omega")
    cases = [(10.0, 1.0, (8.0, 12.0), (37.0, -1.5)), (10.0, -1.0, (8.0, 12.0), (37.0, -1.5)),
             (8.0, 1.0, (8.0, 12.0), (37.0, -1.5)), (8.0 - 1e-11, 1.0, (8.0, 12.0), (37.0, -1.5)),
             (8.0 + 1e-11, -1.0, (4.0, 8.0), (41.0, -2.0)), (25.0, 1.0, (20.0, np.inf), (0.0, 0.0))]
    for omega, side, (low, high), (a, b) in cases:
        bounds, pieces = piece_around((table,), jnp.asarray(omega), side)
        pad = 2 * KNOT_ROUNDOFF * (1 + omega)
        np.testing.assert_allclose(np.asarray(bounds), [low - pad, high + pad], rtol=1e-15)
        np.testing.assert_allclose(np.asarray(pieces), [[a, b]], rtol=1e-12, atol=1e-12)


# ------------------------------------------------------------ without friction, and knots in t
def _frictionless_press(stall):
    """The press with its motor line (stall torque ``stall``) and process force alone: no friction."""
    press = aj.load_scene("press_with_friction")
    return press.with_loads(tuple(load for load in press.loads if isinstance(load, aj.PointForce)) + (aj.MotorLine(stall, 20.0),))


def _pulsed_slider_crank(*extra):
    """The slider-crank falling from rest (q decreasing) under a torque pulse given as a table
    in t: 0 -> 0.5 N m at 0.1 s -> 0 at 0.2 s, against the fall."""
    slider = aj.load_scene("slider_crank")
    pulse = aj.Drive(aj.Table([0.0, 0.1, 0.2], [0.0, 0.5, 0.0], variable="t"))
    return slider.with_loads(tuple(slider.loads) + (pulse,) + extra)


def _moves_as_simulate(scene, t1):
    """final_state (cut at the knots) against simulate() (one solve, or segments at Coulomb
    switches only: never cut at knots) at a tolerance 100x tighter."""
    q, omega = aj.synthesis.final_state(scene, t1, rtol=1e-10, atol=1e-10)
    sol = aj.simulate(scene, t1=t1, rtol=1e-12, atol=1e-12, stop=None)
    np.testing.assert_allclose([float(q), float(omega)], [float(sol.q_final), float(sol.omega_final)], rtol=0, atol=1e-8)
    return sol


def test_a_run_without_friction_is_cut_at_its_tables_knots_where_it_can_be_differentiated():
    """Without friction, a differentiable entry point runs in segments at its load tables'
    knots (simulate, never differentiated, in one solve; a tabulated reduction, saved solver
    steps and diffrax's backsolve in one solve as well), and moves as simulate's one solve
    does: the slider-crank falling through its torque pulse's knots in t. (Moving down with
    no table in q, the missing q knot once read as -inf and hid the t knots: the segment ran
    its first piece on, q(0.3 s) -1.411 rad became -0.502.)"""
    from assurjax.dynamics._settings import Settings
    from assurjax.dynamics._solve import in_segments

    model = _pulsed_slider_crank().model
    assert in_segments(model, Settings(), None) and in_segments(_frictionless_press(40.0).model, Settings(), None)
    for settings in (Settings(kink_events=False), Settings(save_steps=True), Settings(adjoint="backsolve")):
        assert not in_segments(model, settings, None)
    assert not in_segments(aj.load_scene("slider_crank").model, Settings(), None)  # no table: one solve
    sol = _moves_as_simulate(_pulsed_slider_crank(), 0.3)
    assert float(sol.omega_final) < 0.0  # still falling: every segment ran down through the knots


@pytest.mark.slow
def test_a_run_with_friction_falling_through_knots_in_t_moves_as_simulate():
    """The same with friction in the slider-crank's crank pivot: the knots in t end segments
    of the friction run too (the bug above was in their shared margin)."""
    _moves_as_simulate(_pulsed_slider_crank(aj.JointFriction("O", 0.1, radius=0.01)), 0.3)


@pytest.mark.slow
def test_gradient_without_friction_past_the_process_force_knots():
    """The press without friction, d q(T)/d stall at T = 0.35 and 0.5 s (past the process
    force's knots at 240, 300, 345 and 360 deg), forward and reverse mode, against
    differences Richardson-extrapolated from h = 2e-2 and 1e-2 at rtol 1e-12: within 1e-8 at
    rtol 1e-10 (1e-11 to 3e-10 when measured; one solve stepping across the knots, as before
    these cuts: 1.2e-5 and 3.5e-5, benchmarks/README.md)."""
    def q_at(stall, t1, adjoint="forward", tol=TOL):
        return aj.synthesis.final_state(_frictionless_press(stall), t1, rtol=tol, atol=tol, adjoint=adjoint)[0]

    forward = jax.jit(lambda s, t1: jax.jvp(lambda m: q_at(m, t1), (s,), (jnp.ones(()),))[1])
    reverse = jax.jit(jax.grad(lambda s, t1: q_at(s, t1, "recursive")))
    values = jax.jit(lambda s, t1: q_at(s, t1, "recursive", 1e-12))
    stall = 40.0
    for t1 in (0.35, 0.5):
        d1, d2 = ((float(values(stall + h, t1)) - float(values(stall - h, t1))) / (2 * h) for h in (2e-2, 1e-2))
        reference = (4 * d2 - d1) / 3
        for program in (forward, reverse):
            np.testing.assert_allclose(float(program(jnp.asarray(stall), jnp.asarray(t1))), reference, rtol=1e-8)


def _incline(mu):
    """A 2 kg block sliding up a 30 degree incline from 2 m/s, Coulomb friction on its guide (mu_s 1.5)."""
    a = np.deg2rad(30.0)
    return aj.scene_from_dict({
        "scene": {"name": "incline", "gravity": [0.0, -9.81]}, "ground": {"O": [0.0, 0.0]},
        "links": {"block": {"points": {"P": [0.0, 0.0]}, "com": [0.0, 0.0], "mass": 2.0, "inertia": 0.01}},
        "formation": [{"group": "slider", "name": "drv", "link": "block", "point": "P", "guide_point": "O",
                       "direction": [float(np.cos(a)), float(np.sin(a))]}],
        "loads": [{"type": "slide_friction", "pair": "block/ground", "coefficient": mu, "length": 0.05,
                   "static_coefficient": 1.5}],
        "state": {"q0": 0.0, "omega0": 2.0, "t1": 1.0}})


@pytest.mark.slow  # ~40-70 s (L-BFGS's program with the friction's standstill); forward against reverse mode
# through optimize stays in the default suite (test_synthesis_optimize.py), on a kinematic objective
def test_optimize_by_forward_mode_finds_the_friction_coefficient_of_a_standstill_time():
    """optimize's "auto" gradient on a design with friction (forward mode, one variable): the
    coefficient that stops the block at t* = 0.25 s, and the gradient at the start, against the
    closed form t* = v0 / (g (sin a + mu cos a))."""
    import optax

    g, a, v0, target = 9.81, np.deg2rad(30.0), 2.0, 0.25
    design = aj.synthesis.Design(_incline(0.1), lambda s: s.loads[0].coefficient, lower=0.0, upper=1.0)

    def objective(scene):
        return (aj.synthesis.standstill_time(scene)[0] - target) ** 2 * 1e3

    result = aj.synthesis.optimize(design, objective, optax.lbfgs, 40, target=1e-14)
    assert result.status == "target", result.message
    np.testing.assert_allclose(float(result.values), (v0 / (g * target) - np.sin(a)) / np.cos(a), rtol=1e-9)
    # d loss / d z at the start: z -> mu = sigmoid(z) (bounds 0, 1), mu -> t*, t* -> loss
    mu = 0.1
    t_star = v0 / (g * (np.sin(a) + mu * np.cos(a)))
    dt_dmu = -v0 * g * np.cos(a) / (g * (np.sin(a) + mu * np.cos(a))) ** 2
    expected = 2e3 * (t_star - target) * dt_dmu * mu * (1.0 - mu)
    np.testing.assert_allclose(float(jax.tree.leaves(result.history.grad)[0][0]), expected, rtol=1e-6)
