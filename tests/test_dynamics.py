"""Forward dynamics (simulate) against the joint-based reference, energy balances,
closed forms and convergence orders. One compile per settings: the runs below
share settings so that the suite stays fast."""

import jax.numpy as jnp
import numpy as np
import pytest

import assurjax as aj
from scene_texts import SLIDER_DRIVEN
from assurjax.dynamics._results import LOCKUP, STANDSTILL

import joint_reference as ref

TIGHT = dict(rtol=1e-12, atol=1e-12, max_steps=20000, check_assembly=False)  # lock-up has its own test
TS = np.linspace(0.0, 2.0, 21)


# ----------------------------------------------------------------------------- scenes


@pytest.fixture(scope="module")
def watt():
    return aj.load_scene("watt_sixbar")


def _bar(a, b, length, mass, inertia=None, **extra):
    """A uniform bar from point a (local origin) to point b on the local x axis."""
    inertia = mass * length**2 / 12 if inertia is None else inertia
    return dict(points={a: [0.0, 0.0], b: [length, 0.0], **extra}, com=[length / 2, 0.0], mass=mass, inertia=inertia)


def slider_driven_scene():
    """The reference's slider-driven rocker: q = x of the pin B on the x axis."""
    d = ref.SLIDER_DRIVEN
    return aj.scene_from_dict(dict(
        scene=dict(name="slider_driven", gravity=[0.0, -9.81]),
        ground=dict(G=[0.0, 0.0], O3=list(d["O3"])),
        links=dict(
            slider=dict(points=dict(B=[0.0, 0.0]), com=[0.0, 0.0], mass=d["m_slider"], inertia=0.0),
            rod=_bar("B", "C", d["L_rod"], d["m_rod"]),
            rocker=_bar("O3", "C", d["L_rocker"], d["m_rocker"]),
        ),
        formation=[
            dict(group="slider", name="slider", link="slider", point="B", guide_point="G", direction=[1.0, 0.0]),
            dict(group="RRR", name="dyad", links=["rod", "rocker"], joints=["B", "O3", "C"], mode="left"),
        ],
    ))


def four_bar_scene(stall, no_load_speed, damping, **geometry):
    """The reference's crank-rocker with a motor line and a translational damper
    from a ground point to the coupler's midpoint M (gravity along -y)."""
    d = {**ref.FOUR_BAR, **geometry}
    return aj.scene_from_dict(dict(
        scene=dict(name="four_bar_motor", gravity=[0.0, -9.81]),
        ground=dict(O2=list(d["O2"]), O4=list(d["O4"]), P=list(d["damper_anchor"])),
        links=dict(
            crank=_bar("O2", "A", d["L2"], d["m2"]),
            coupler=_bar("A", "B", d["L3"], d["m3"], M=[d["L3"] / 2, 0.0]),
            rocker=_bar("O4", "B", d["L4"], d["m4"]),
        ),
        formation=[
            dict(group="crank", name="crank", link="crank", pivot="O2"),
            dict(group="RRR", name="dyad", links=["coupler", "rocker"], joints=["A", "O4", "B"], mode="left"),
        ],
        loads=[
            dict(type="motor", stall=stall, no_load_speed=no_load_speed),
            dict(type="damper", points=["P", "M"], coefficient=damping),
        ],
    ))


# ----------------------------------------------------------------------------- Watt six-bar


@pytest.mark.parametrize("theta0", [0.0, 0.6, -1.2])
def test_watt_matches_joint_reference(watt, theta0):
    sol = aj.simulate(watt, q0=theta0, stop=None, t1=2.0, saveat=TS, energies=True, **TIGHT)
    r = ref.watt_sixbar(theta0).simulate(2.0, t_eval=TS)
    assert sol.status.startswith("reached t1")
    np.testing.assert_allclose(sol.t, TS, atol=1e-12)
    np.testing.assert_allclose(sol.q, r.q, atol=1e-8, rtol=0)
    np.testing.assert_allclose(sol.omega, r.w, atol=1e-8, rtol=0)
    np.testing.assert_allclose(sol.domega, r.wdot, atol=1e-7, rtol=1e-9)
    # energies: T from the reference's body velocities, V from its COM heights
    np.testing.assert_allclose(sol.kinetic, r.T, atol=1e-8)
    assert np.ptp(sol.total) < 1e-9 * np.max(np.abs(sol.kinetic))
    np.testing.assert_allclose(np.asarray(sol.potential) - sol.potential[0], r.V - r.V[0], atol=1e-8)
    assert np.all(np.isfinite(sol.q)) and sol.t_stop is None


def test_watt_standstill_matches_joint_reference(watt):
    sol = aj.simulate(watt, q0=0.0, stop="standstill", t1=5.0, **TIGHT)
    r = ref.watt_sixbar(0.0).simulate(5.0, standstill=0)
    t_ref = r.t_events[0]
    assert sol.event == STANDSTILL and sol.status.startswith("standstill")
    assert abs(sol.t_stop - t_ref) < 1e-8
    assert abs(sol.t[-1] - t_ref) < 1e-8 and abs(sol.q[-1] - r.q[-1]) < 1e-8
    assert abs(sol.omega[-1]) < 1e-8
    # the outputs the scene asks for are there, and end at the stop
    assert set(sol.points) == {"A", "B", "E"} and sol.points["E"].shape == (len(sol.t), 2)
    assert np.all(np.isfinite(sol.points["E"]))


@pytest.mark.parametrize("theta0, omega0", [(2.0, 0.0), (0.0, -1.0), (1.0, 1.0)])
def test_standstill_in_either_direction_matches_joint_reference(watt, theta0, omega0):
    """From rest falling either way (the margin uses q - q0), or thrown against or along
    gravity: the first zero of w, against the joint-based reference's own event."""
    sol = aj.simulate(watt, q0=theta0, omega0=omega0, stop="standstill", t1=5.0, **TIGHT)
    r = ref.watt_sixbar(theta0, omega0).simulate(5.0, standstill=0)
    assert sol.event == STANDSTILL
    assert abs(sol.t_stop - r.t_events[0]) < 1e-8 and abs(r.t[-1] - r.t_events[0]) < 1e-12
    assert abs(sol.q[-1] - r.q[-1]) < 1e-8


def test_watt_standstill_from_the_scene_defaults(watt):
    """The bundled scene says stop = "standstill": falling from rest it swings to a stop;
    from rest a standstill is where T returns to 0, so V(q_stop) = V(q0)."""
    sol = aj.simulate(watt, **TIGHT, energies=True, stop="standstill", t1=5.0)
    assert sol.t_stop is not None and 1.0 < sol.t_stop < 2.0
    assert abs(sol.potential[-1] - sol.potential[0]) < 1e-9


def test_simulate_is_jittable_and_vmappable(watt):
    import equinox as eqx

    settings = aj.SimulationSettings(samples=3, check_assembly=False, rtol=1e-10, atol=1e-10)
    core = eqx.filter_jit(eqx.filter_vmap(
        lambda q0: aj.simulate_core(watt.mechanism, watt.gravity, (), q0, 0.0, 0.0, 0.5, settings=settings)))
    q0s = jnp.array([0.0, 0.6, -1.2])
    sols = core(q0s)
    for k, theta0 in enumerate(np.asarray(q0s)):
        r = ref.watt_sixbar(theta0).simulate(0.5, t_eval=[0.0, 0.25, 0.5])
        np.testing.assert_allclose(sols.q[k], r.q, atol=1e-7)


# ----------------------------------------------------------------------------- other drivers and loads


def test_slider_driver_matches_joint_reference():
    scene = slider_driven_scene()
    ts = np.linspace(0.0, 1.0, 11)
    sol = aj.simulate(scene, q0=0.17, omega0=0.0, stop=None, t1=1.0, saveat=ts, **TIGHT)
    r = ref.slider_driven(0.17).simulate(1.0, t_eval=ts)
    np.testing.assert_allclose(sol.q, r.q, atol=1e-8, rtol=0)
    np.testing.assert_allclose(sol.omega, r.w, atol=1e-8, rtol=0)


@pytest.fixture(scope="module")
def four_bar_runs():
    """Motor + damper, and the same with the motor switched off (energy balance);
    one compile for both (the loads have the same structure)."""
    ts = np.linspace(0.0, 1.5, 16)
    out = {}
    for stall in (ref.FOUR_BAR["T_stall"], 0.0):
        scene = four_bar_scene(stall, ref.FOUR_BAR["w_noload"], ref.FOUR_BAR["damper_c"])
        out[stall] = aj.simulate(scene, q0=0.3, omega0=0.0, stop=None, t1=1.5, saveat=ts, energies=True, **TIGHT)
    return ts, out


def test_motor_line_and_damper_match_joint_reference(four_bar_runs):
    ts, runs = four_bar_runs
    sol = runs[ref.FOUR_BAR["T_stall"]]
    r = ref.four_bar_motor(0.3).simulate(1.5, t_eval=ts)
    np.testing.assert_allclose(sol.q, r.q, atol=1e-8, rtol=0)
    np.testing.assert_allclose(sol.omega, r.w, atol=1e-8, rtol=0)
    assert sol.omega[-1] > 1.0  # the motor drives the crank round


def test_energy_lost_equals_damper_work(four_bar_runs):
    ts, runs = four_bar_runs
    sol = runs[0.0]
    lost = sol.total[0] - np.asarray(sol.total)
    assert np.max(lost) > 1e-2  # the damper does work
    np.testing.assert_allclose(lost, sol.dissipated, atol=1e-9)
    # and the dissipated work agrees with the reference's damper work
    r = ref.four_bar_motor(0.3, T_stall=0.0).simulate(1.5, t_eval=ts)
    np.testing.assert_allclose(sol.dissipated, -r.work, atol=1e-8)


# ----------------------------------------------------------------------------- lock-up and bad input


def test_lockup_stops_with_a_clear_result():
    """A triple-rocker (non-Grashof) four-bar swings into its limit position: the dyad
    cannot assemble beyond it. The run stops there, names the group, no NaN."""
    scene = four_bar_scene(0.0, 1.0, 0.0, L2=0.3, L3=0.3, L4=0.3, O4=(0.5, 0.0))
    sol = aj.simulate(scene, q0=0.9, omega0=-6.0, stop=None, t1=3.0, rtol=1e-8, atol=1e-8)
    for v in (sol.t, sol.q, sol.omega, sol.domega):
        assert np.all(np.isfinite(v))
    # stop=None: no standstill event, so the run can only end by lock-up
    assert sol.event == LOCKUP and "assemble" in sol.status
    assert sol.failed_group == "dyad" and "dyad" in sol.status
    # the dyad is stretched at its limit (closed form): |A - O4| = L3 + L4, with A = O2 + L2 (cos q, sin q)
    a = 0.3 * np.array([np.cos(sol.q[-1]), np.sin(sol.q[-1])])
    assert abs(np.hypot(*(a - np.array([0.5, 0.0]))) - 0.6) < 1e-6
    assert sol.t[-1] < 3.0


def test_a_batch_names_the_group_each_member_failed_in():
    """batch_summary given the group names (batch_simulate's) names each member's failed group,
    None where none failed, as a single run names its own: a batch had failed_group None even
    for a member that could not assemble at the start (slider-cranks of rods 0.3, 0.105 and
    0.08 m from q0 = 1.3 now give (None, None, 'rod_slider'))."""
    from assurjax.dynamics._results import _SUCCESS, START_NOT_ASSEMBLED
    from assurjax.dynamics._solution import batch_summary

    n = 3
    z = np.zeros((n, 2))
    sols = aj.Solution(t=z, q=z, omega=z, domega=None, kinetic=None, potential=None, total=None, dissipated=None,
                       points={}, angles={}, valid=np.ones((n, 2), bool), t_final=np.zeros(n), q_final=np.zeros(n),
                       omega_final=np.zeros(n), t_stop=np.full(n, np.inf), event=np.array([-1, LOCKUP, LOCKUP]),
                       failed_group_index=np.array([-1, 1, 0]), num_steps=np.ones(n, int),
                       result=np.array([_SUCCESS, _SUCCESS, START_NOT_ASSEMBLED]))
    groups = tuple(g.name for g in aj.load_scene("slider_crank").mechanism.groups)
    summary = batch_summary(sols, groups=groups)
    assert summary.failed_group == (None, groups[1], groups[0])
    assert "1 lock-up" in summary.status and "1 cannot assemble at the start" in summary.status
    assert batch_summary(sols).failed_group is None  # without the names


LIMIT = np.arccos((0.3**2 + 0.5**2 - 0.6**2) / (2 * 0.3 * 0.5))  # the triple rocker's stretched dyad: |A - O4| = 0.6


@pytest.mark.parametrize("dt", [None, 1e-3])
def test_lockup_is_located_by_rejected_steps(dt):
    """Steps that meet a configuration where the dyad cannot assemble are rejected and shrunk
    (adaptive) or halved (constant steps) until the lock-up is located: the run stops at the
    stretched dyad (closed form), never past it, without bouncing back."""
    scene = four_bar_scene(0.0, 1.0, 0.0, L2=0.3, L3=0.3, L4=0.3, O4=(0.5, 0.0))
    sol = aj.simulate(scene, q0=0.9, omega0=-6.0, stop=None, t1=3.0, dt=dt)
    assert sol.event == LOCKUP and sol.failed_group == "dyad"
    assert abs(sol.q_final + LIMIT) < 1e-8
    assert np.all(sol.q >= -LIMIT) and np.all(np.diff(sol.q) <= 0.0)
    if dt is None:  # a batch of starts names each member's group, as a single run does (from rest: no lock-up by 0.3 s)
        sols = aj.simulate(scene, q0=np.array([0.9, 0.9]), omega0=np.array([-6.0, 0.0]), stop=None, t1=0.3)
        assert sols.failed_group == ("dyad", None) and abs(sols.q_final[0] + LIMIT) < 1e-8


def test_a_step_budget_spent_closing_in_on_a_lock_up_says_so():
    """At rtol 1e-11 the steps near the triple rocker's limit shrink until the budget is gone
    (J_red's round-off outgrows the tolerance there; 692 steps at 1e-10): the status said
    only 'raise max_steps'. It now names the dyad and the limit position the run closed in
    on, which the closed form puts within 1e-6 rad ahead."""
    scene = four_bar_scene(0.0, 1.0, 0.0, L2=0.3, L3=0.3, L4=0.3, O4=(0.5, 0.0))
    sol = aj.simulate(scene, q0=0.9, omega0=-6.0, stop=None, t1=3.0, rtol=1e-11, atol=1e-11)
    assert sol.event != LOCKUP and "step budget" in sol.status
    assert "closing in on a limit position (group 'dyad'" in sol.status and "loosen rtol/atol" in sol.status
    assert 0.0 < sol.q_final + LIMIT < 1e-6


def long_crank_slider(kind: str):
    """The bundled slider-crank with a 0.32 m crank on its 0.3 m rod: the crank cannot turn
    past sin q = 0.3 / 0.32, where the rod stands square to the guide. ``kind``: its dyad
    listed as RRP or PRR."""
    import tomllib
    from importlib import resources

    d = tomllib.loads(resources.files("assurjax.scenes").joinpath("slider_crank.toml").read_text()
                      .replace("A = [0.1, 0.0] }", "A = [0.32, 0.0] }"))
    if kind == "PRR":
        dyad = d["formation"][1]
        dyad.update(group="PRR", links=dyad["links"][::-1], joints=dyad["joints"][::-1])
    return aj.scene_from_dict(d)


def inverted_slider_crank(mode: int):
    """An RPR dyad on a 0.2 m crank about O: its block pinned at the crank's A slides on a
    guide link pinned at C = (0.3, 0), the guide passing 0.15 m from A. It closes while
    |A C| >= 0.15: |A C|^2 = 0.13 - 0.12 cos q, so q >= acos(0.1075 / 0.12)."""
    bar = _bar("C", "D", 0.4, 1.0)
    return aj.scene_from_dict(dict(
        scene=dict(name="inverted", gravity=[0.0, -9.81]),
        ground=dict(O=[0.0, 0.0], C=[0.3, 0.0]),
        links=dict(crank=_bar("O", "A", 0.2, 0.5), block=dict(points=dict(A=[0.0, 0.0]), com=[0.0, 0.0], mass=0.3,
                                                               inertia=1e-4), guide=bar),
        formation=[dict(group="crank", name="crank", link="crank", pivot="O"),
                   dict(group="RPR", name="inverted", links=["block", "guide"], joints=["A", "C"],
                        direction=[1.0, 0.0], offset=0.15, mode=mode)],
        state=dict(q0=1.0)))


# PRR (RRP listed from its other end) and the RPR's other mode in the slow suite (~7 s): the default suite keeps to 10 min
SLIDER_LIMITS = [(lambda: long_crank_slider("RRP"), np.arcsin(0.3 / 0.32), -1.0, "RRP"),
                 pytest.param(lambda: long_crank_slider("PRR"), np.arcsin(0.3 / 0.32), -1.0, "PRR", marks=pytest.mark.slow),
                 (lambda: inverted_slider_crank(1), np.arccos(0.1075 / 0.12), 1.0, "RPR"),
                 pytest.param(lambda: inverted_slider_crank(-1), np.arccos(0.1075 / 0.12), 1.0, "RPR", marks=pytest.mark.slow)]


@pytest.mark.parametrize("build, q_limit, inside, kind", SLIDER_LIMITS)
def test_a_start_exactly_at_a_slider_dyads_limit_is_refused(build, q_limit, inside, kind):
    """The slider dyads' limits (closed forms above) declare a singularity measure: a start
    exactly there is refused, naming the group (the slider-crank started there from rest ran
    on with its energy balance off by half its kinetic energy); 1e-6 inside it is a motion.
    The measure crosses zero at the closed-form limit and its derivative is its own
    q-derivative (central differences)."""
    scene = build()
    group = scene.mechanism.groups[1]
    with pytest.raises(aj.AssemblyError, match=f"group '{group.name}' \\({kind}\\) is exactly at a singular configuration"):
        aj.simulate(scene, q0=q_limit, stop=None, t1=0.1)
    sol = aj.simulate(scene, q0=q_limit + inside * 1e-6, stop=None, t1=0.1)
    assert np.isfinite(sol.q_final)

    def measure(q):
        c = aj.coefficients(scene.mechanism, q, order=1)
        (x, _, _, turn), (dx, _, _, dturn) = c.x, c.dx
        return (float(v) for v in group.singularity(x, dx, turn, dturn))

    m, dm = measure(q_limit + inside * 1e-3)
    h = 1e-6
    fd = (next(measure(q_limit + inside * 1e-3 + h)) - next(measure(q_limit + inside * 1e-3 - h))) / (2 * h)
    assert abs(dm - fd) < 1e-6 * abs(dm) and abs(m) > 1e-3
    assert abs(next(measure(q_limit))) < 1e-9


def thrown_slider_crank():
    """A slider-crank drawn with a 0.3 m crank on a 0.2 m rod, no gravity: thrown, it runs
    into the limit sin q* = 0.2 / 0.3 where the rod stands square to the guide; and its
    reduced inertia by hand (J(q), kg m^2)."""
    r, rod = 0.3, 0.2
    sketch = aj.Sketch(joints={"O": (0.0, 0.0), "A": (r, 0.0), "B": (r + rod, 0.0)},
                       links={"crank": {"joints": ["O", "A"], "mass": 0.5, "inertia": 0.004},
                              "rod": {"joints": ["A", "B"], "mass": 0.4, "inertia": 0.002},
                              "slider": {"joints": ["B"], "mass": 1.0, "inertia": 0.0}},
                       ground=["O"], driver="crank", slides=[aj.Slide("slider", "ground", (1.0, 0.0))])

    def inertia(q):  # crank about O, the rod's centre and turn, the slider's travel
        s, c = np.sin(q), np.cos(q)
        root = np.sqrt(rod**2 - (r * s) ** 2)
        db = -r * s - r * r * s * c / root
        dg = np.array([-r * s + db, r * c]) / 2
        return 0.004 + 0.5 * (r / 2) ** 2 + 0.002 * (r * c / root) ** 2 + 0.4 * dg @ dg + db**2

    return sketch.scene(gravity=(0.0, 0.0)), np.arcsin(rod / r), inertia


@pytest.mark.parametrize("omega0", [4.4, 4.8, 5.2])
def test_a_step_that_turns_the_driver_at_a_limit_is_a_lock_up(omega0):
    """Near a limit q* the motion approaches as q* - k (t* - t)^2, smooth in t: a step whose
    stages all stayed short of q* passed the error test and turned w round on the same
    branch ('reached t1', 98 % of the energy gone: w0 = 4.8 and 5.2 rad/s by default, 4.4 with
    the tests' XLA flags, and 1-11 % of the starts of scans on other mechanisms). Such a step is
    rejected: the run locks up at q* at the time of the energy quadrature
    t* = int_0^q* sqrt(J(q) / (J(0) w0^2)) dq (J by hand)."""
    from scipy.integrate import quad

    scene, q_limit, inertia = thrown_slider_crank()
    sol = aj.simulate(scene, q0=0.0, omega0=omega0, stop=None, t1=3.0)
    assert sol.event == LOCKUP and sol.failed_group == scene.mechanism.groups[1].name
    assert abs(float(sol.q_final) - q_limit) < 1e-8
    t_limit = quad(lambda q: np.sqrt(inertia(q) / (inertia(0.0) * omega0**2)), 0.0, q_limit, limit=200)[0]
    assert abs(float(sol.t_final) - t_limit) < 1e-5


def test_a_batch_thrown_into_a_limit_locks_up_as_each_run_alone():
    """The starts of the test above in one vmapped run (the turn test's cond on any member):
    each member locks up at q* at its single run's time."""
    scene, q_limit, _ = thrown_slider_crank()
    omega0 = np.array([4.4, 4.8, 5.2])
    batch = aj.simulate(scene, q0=0.0, omega0=omega0, stop=None, t1=3.0)
    for i, w in enumerate(omega0):
        alone = aj.simulate(scene, q0=0.0, omega0=float(w), stop=None, t1=3.0)
        assert int(batch.event[i]) == LOCKUP and abs(float(batch.q_final[i]) - q_limit) < 1e-8
        assert abs(float(batch.t_final[i]) - float(alone.t_final)) < 1e-7


@pytest.mark.parametrize("short", [1e-4, 1e-6])
def test_a_turn_just_short_of_a_limit_stands(short):
    """A constant braking torque tau turns the thrown slider-crank where its work takes all
    the kinetic energy: tau q_turn = J(0) w0^2 / 2, whatever J(q) on the way; with q_turn
    ``short`` of the limit the turn is a motion, not a lock-up (the turn test must not take
    it for one): the run reaches t1, back through the start, its energy T + tau q closed."""
    from scipy.integrate import quad

    scene, q_limit, inertia = thrown_slider_crank()
    omega0 = 4.8
    energy = 0.5 * inertia(0.0) * omega0**2
    tau = energy / (q_limit - short)
    t_turn = quad(lambda q: np.sqrt(inertia(q) / (2 * (energy - tau * q))), 0.0, q_limit - short, limit=400)[0]
    sol = aj.simulate(scene, loads=(aj.Drive(-tau),), q0=0.0, omega0=omega0, stop=None, t1=2 * t_turn + 0.3,
                      save_steps=True)
    assert sol.event != LOCKUP and sol.status.startswith("reached t1")
    assert abs(np.max(sol.q) - (q_limit - short)) < 1e-6  # the runs: 1.5e-8 past it (their tolerance)
    q, w = float(sol.q_final), float(sol.omega_final)
    assert q < 0.0 and abs(0.5 * inertia(q) * w**2 + tau * q - energy) < 1e-6 * energy


def test_constant_steps_that_turn_the_driver_at_a_limit_lock_up():
    """Constant steps (dt=, steps=) into a limit: a four-bar (crank 0.3, coupler 0.25, rocker 0.2, ground
    0.4) thrown at 2 rad/s with dt = 0.01 s turned w round short of its limit ('reached t1',
    99.6 % of the energy gone), 0.015 s reported the other limit; the triple rocker with
    dt = 0.02 s ended at q = -2e28 beside a lock-up status. A turning step at a limit is
    halved as a step that met NaN: each run ends at the limit it runs into (closed forms),
    as a lock-up or, where the constant steps' last stages near it gave no sane velocity
    (it depends on round-off: XLA's scheduler flags change which), saying the motion was
    not resolved; never turned round ('reached t1')."""
    a, b, c, d = 0.4, 0.3, 0.25, 0.2
    along = ((a - b) ** 2 + c * c - d * d) / (2 * (a - b))  # the crank along the ground line at q = 0: C over B D
    cx, cy = b + along, np.sqrt(c * c - along**2)
    scene = aj.Sketch(joints={"A": (0.0, 0.0), "B": (b, 0.0), "C": (cx, cy), "D": (a, 0.0)},
                      links={"crank": {"joints": ["A", "B"], "mass": 0.3, "inertia": 0.003},
                             "coupler": {"joints": ["B", "C"], "mass": 0.25, "inertia": 0.002},
                             "rocker": {"joints": ["D", "C"], "mass": 0.2, "inertia": 0.001}},
                      ground=["A", "D"], driver="crank").scene(gravity=(0.0, 0.0))
    q_limit = np.arccos((a * a + b * b - (c + d) ** 2) / (2 * a * b))  # coupler and rocker in line
    rocker = four_bar_scene(0.0, 1.0, 0.0, L2=0.3, L3=0.3, L4=0.3, O4=(0.5, 0.0))
    runs = [(scene, 0.0, 2.0, dt, q_limit) for dt in (0.01, 0.012, 0.015)] + [(rocker, 0.9, -6.0, 0.02, -LIMIT)]
    for case, q0, omega0, dt, limit in runs:
        sol = aj.simulate(case, q0=q0, omega0=omega0, stop=None, t1=3.0, dt=dt)
        assert sol.event == LOCKUP or "the motion was not resolved" in sol.status
        assert abs(float(sol.q_final) - limit) < 1e-7
    # steps= (a scan, no controller): the thrown slider-crank ran on ('reached t1') at 150 and 300
    # steps; now it stops at the step before the turn (located to the step, as at a NaN)
    thrown, q_star, _ = thrown_slider_crank()
    for n in (150, 300):
        sol = aj.simulate(thrown, q0=0.0, omega0=4.8, stop=None, t1=3.0, steps=n)
        assert sol.event == LOCKUP and 0.0 < q_star - float(sol.q_final) < 3e-3


@pytest.mark.slow  # ~9 s; a batch thrown into a limit stays in the default suite
def test_lockup_in_a_batch_stops_each_member_at_its_limit():
    """Vmapped runs, each closing in on a lock-up of its own (both limits), as run alone (the
    time of arrival is ill-conditioned: q approaches the limit quadratically in t)."""
    import equinox as eqx

    scene = four_bar_scene(0.0, 1.0, 0.0, L2=0.3, L3=0.3, L4=0.3, O4=(0.5, 0.0))
    settings = aj.SimulationSettings(samples=11)
    run = aj.jit(eqx.filter_vmap(lambda w0: aj.simulate_core(scene.model, q0=0.9, omega0=w0, t1=3.0, settings=settings)))
    omega0 = np.array([-6.0, 2.0, 8.0])
    batch = run(jnp.asarray(omega0))
    np.testing.assert_array_equal(np.asarray(batch.event), LOCKUP)
    np.testing.assert_allclose(np.abs(np.asarray(batch.q_final)), LIMIT, atol=1e-8)
    for k, w0 in enumerate(omega0):
        alone = aj.simulate(scene, q0=0.9, omega0=w0, stop=None, t1=3.0, samples=11)
        assert abs(float(batch.q_final[k]) - alone.q_final) < 1e-9 and abs(float(batch.t_final[k]) - alone.t_final) < 1e-6


@pytest.mark.slow  # reverse mode through a lock-up: 20-30 s of compilation for each
@pytest.mark.parametrize("steps", [None, 400])
def test_gradient_through_a_run_that_locks_up(steps):
    """Reverse mode through a run that ends at a lock-up, whose rejected (or, with fixed
    steps, NaN) stages met configurations that cannot assemble: d(q + T)(0.2 s) / d q0 is
    finite and agrees with central differences."""
    import jax

    scene = four_bar_scene(0.0, 1.0, 0.0, L2=0.3, L3=0.3, L4=0.3, O4=(0.5, 0.0))
    settings = aj.SimulationSettings(steps=steps, energies=steps is None, rtol=1e-10, atol=1e-10)
    t1, ts = (3.0, jnp.array([0.0, 0.1, 0.2, 0.25])) if steps is None else (0.4, None)
    at = 2 if steps is None else 200  # t = 0.2 s, before the lock-up at 0.287 s

    def value(q0):
        sol = aj.simulate_core(scene.model, q0=q0, omega0=-6.0, t1=t1, ts=ts, settings=settings)
        assert sol.event == LOCKUP
        return sol.q[at] + (0.0 if sol.kinetic is None else sol.kinetic[at])

    grad = float(jax.grad(value)(jnp.asarray(0.9)))
    fd = (float(value(jnp.asarray(0.9 + 1e-6))) - float(value(jnp.asarray(0.9 - 1e-6)))) / 2e-6
    assert np.isfinite(grad) and abs(grad - fd) < 1e-5 * (1.0 + abs(fd))


@pytest.mark.parametrize("check_assembly", [True, False])
def test_a_load_turning_nan_stops_the_run_there_in_words(watt, check_assembly):
    """A drive that turns NaN from t = 0.5 s (log of a negative number): the steps close in
    on it and the run stops at 0.5 s, every saved value finite, the status saying why."""
    drive = aj.Drive(lambda q, w, t: jnp.where(t > 0.3, jnp.log(0.5 - t), 0.0))
    sol = aj.simulate(watt, loads=list(watt.loads) + [drive], stop=None, t1=1.0, check_assembly=check_assembly)
    assert abs(sol.t_final - 0.5) < 1e-8 and "turned NaN" in sol.status and not sol.successful
    assert all(np.all(np.isfinite(v)) for v in (sol.t, sol.q, sol.omega, sol.domega))


def test_unknown_point_in_a_load_is_a_clear_error(watt):
    with pytest.raises(aj.AssurjaxError, match="unknown point 'Z'"):
        aj.simulate(watt, loads=[aj.PointForce("Z", [1.0, 0.0])])


def test_unknown_solver_and_output_are_clear_errors(watt):
    with pytest.raises(aj.AssurjaxError, match="unknown solver"):
        aj.simulate(watt, solver="rk99")
    with pytest.raises(aj.AssurjaxError, match="unknown point 'Q'"):
        aj.simulate(watt, points=["Q"])


# ----------------------------------------------------------------------------- convergence orders


def _watt_reference_at(t1, theta0=0.3):
    return ref.watt_sixbar(theta0).simulate(t1, t_eval=[t1])


@pytest.mark.parametrize("solver, order, steps", [
    ("heun", 2, (0.02, 0.01, 0.005)),
    pytest.param("bosh3", 3, (0.04, 0.02, 0.01), marks=pytest.mark.slow),
    pytest.param("dopri5", 5, (0.08, 0.04, 0.02), marks=pytest.mark.slow),
])
def test_fixed_step_solvers_show_their_order(watt, solver, order, steps):
    """Error at t = 1.2 s against the reference, halving the (traced) step: one compile per solver."""
    r = _watt_reference_at(1.2)
    errors = []
    for dt in steps:
        sol = aj.simulate(watt, q0=0.3, stop=None, t1=1.2, saveat=np.array([1.2]), solver=solver, dt=dt,
                          check_assembly=False, energies=False, points=(), angles=())
        errors.append(abs(sol.q[-1] - r.q[-1]))
        # one step per grid interval: steps ending a round-off short of their grid point were
        # each followed by one of ~1e-17 s (75 where 60 were due at dt = 0.02)
        assert int(sol.num_steps) == round(1.2 / dt), (dt, int(sol.num_steps))
    slopes = np.diff(np.log(errors)) / np.diff(np.log(steps))
    assert np.all(np.abs(slopes - order) < 0.5), (errors, slopes)


def _watt_energy_speed(q, theta0):
    """|w| at q from energy conservation from rest at theta0: J_red(q) w^2 / 2 = V(theta0) - V(q),
    J_red and V from the reference's closed-form positions (central differences)."""
    m, J = ref.WATT["m"], ref.WATT["J"]
    L = dict(crank=1.0, coupler=1.5, rocker=1.5, link5=1.0, link6=1.0)
    start = dict(crank="O2", coupler="A", rocker="O4", link5="C", link6="D")

    def coms(th):
        pts, ang = ref.watt_sixbar_points(th)
        return {b: pts[start[b]] + L[b] / 2 * np.array([np.cos(ang[b]), np.sin(ang[b])]) for b in L}, ang

    def potential(th):
        return sum(m[b] * 9.81 * c[1] for b, c in coms(th)[0].items())

    h = 1e-6
    (cp, ap), (cm, am) = coms(q + h), coms(q - h)
    jred = sum(m[b] * np.sum(((cp[b] - cm[b]) / (2 * h)) ** 2) + J[b] * ((ap[b] - am[b]) / (2 * h)) ** 2 for b in L)
    return np.sqrt(2 * (potential(theta0) - potential(q)) / jred)


def test_seed_euler_baseline_converges_with_order_one(watt):
    q_target = -1.0  # reached from rest at 0 while falling
    exact = _watt_energy_speed(q_target, 0.0)
    errors, steps = [], (4e-3, 2e-3, 1e-3)
    for dq in steps:
        base = aj.simulate_seed_euler(watt.mechanism, watt.gravity, (), 0.0, 0.0, t1=5.0, dq=dq, max_steps=2000)
        q, w = np.asarray(base.q), np.asarray(base.omega)
        assert q[-1] < q_target
        errors.append(abs(np.interp(q_target, q[::-1], np.abs(w[::-1])) - exact))
    slopes = np.diff(np.log(errors)) / np.diff(np.log(steps))
    assert np.all(np.abs(slopes - 1.0) < 0.25), (errors, slopes)


def test_seed_euler_baseline_checks_its_inputs(watt):
    """A negative dq ran time backwards (t = -4e301 s), dq = 0 took 20 000 steps that did
    nothing, NaN starts ran, an unknown link was a raw KeyError, max_steps had no bound, and
    simulate(..., solver='seed_euler') dropped its max_steps."""
    m, g = watt.mechanism, watt.gravity
    for kw, message in ((dict(dq=-1e-3), "dq must be positive"), (dict(dq=0.0), "dq must be positive"),
                        (dict(dq=2.0), "dq is a step in q"), (dict(max_steps=3_000_000), "max_steps: expected")):
        with pytest.raises(aj.AssurjaxError, match=f"simulate_seed_euler: {message}"):
            aj.simulate_seed_euler(m, g, (), 0.0, 0.0, **kw)
    with pytest.raises(aj.AssurjaxError, match="setting 't1': must be later than t0"):
        aj.simulate_seed_euler(m, g, (), 0.0, 0.0, t1=-1.0)
    with pytest.raises(aj.AssurjaxError, match="setting 'q0': must be finite"):
        aj.simulate_seed_euler(m, g, (), float("nan"), 0.0)
    with pytest.raises(aj.MechanismError, match="unknown link 'foo'"):
        aj.simulate_seed_euler(m, g, (aj.Couple("foo", 1.0),), 0.0, 0.0)
    assert aj.simulate(watt, solver="seed_euler", max_steps=10, stop=None, t1=5.0).q.shape == (11,)


# ----------------------------------------------------------------------------- user events, retracing


def test_user_event_stops_where_its_condition_changes_sign(watt):
    """The first event fires at q = -1 (the reference is there at that time too); the second,
    NaN past t = 0.05 s, never could, and the status says so from the first saved state past
    that time (a run with it alone would say only 'reached t1')."""
    lean = dict(energies=False, points=(), angles=(), check_assembly=False, rtol=1e-12, atol=1e-12)
    events = [lambda t, q, w: q + 1.0, lambda t, q, w: jnp.sqrt(0.05 - t)]
    sol = aj.simulate(watt, q0=0.0, stop=None, t1=2.0, events=events, **lean)
    assert sol.event == aj.dynamics._results.USER and sol.t_stop is not None
    assert abs(sol.q[-1] + 1.0) < 1e-9
    first_nan = sol.t[np.argmax(sol.t > 0.05)]
    assert sol.status.startswith(f"user event #1 at t = {sol.t_stop:.9g} s; event #2 was NaN at "), sol.status
    assert f"the first at t = {first_nan:.6g} s" in sol.status and "could not fire there" in sol.status
    r = ref.watt_sixbar(0.0).simulate(2.0, t_eval=[sol.t_stop])
    assert abs(r.q[-1] + 1.0) < 1e-8  # the reference is at q = -1 at that time too


def test_no_retrace_for_new_initial_state_or_horizon(watt):
    traces = []

    def effort(q, w, t):
        traces.append(1)  # runs only while tracing
        return 0.0 * q

    loads = (aj.Drive(effort, velocity_dependent=False),)
    lean = dict(energies=False, points=(), angles=(), check_assembly=False, samples=5, stop=None)
    aj.simulate(watt, loads=loads, q0=0.1, t1=0.2, **lean)
    first = len(traces)
    aj.simulate(watt, loads=loads, q0=0.3, omega0=1.0, t1=0.3, **lean)
    assert first > 0 and len(traces) == first




def test_unassemblable_start_raises_naming_the_group(write_scene):
    """A start where the mechanism cannot close is an AssemblyError naming the group and
    q0, never a frozen or zero motion: a slider driver pushed past |B O3| = rod + rocker
    (0.6 m: sqrt(0.6^2 + 0.3^2) > 0.45), and a crank-driven scene at an angle where its
    own assembly flags (a sweep of the position analysis) say a group does not close."""
    slider = aj.load_scene(write_scene(SLIDER_DRIVEN))
    assert aj.simulate(slider, t1=0.05).status.startswith("reached t1")
    for q0 in (0.6, -0.6):
        with pytest.raises(aj.AssemblyError, match=r"group 'dyad' \(RRR\) cannot assemble at the start q0 = -?0\.6") as info:
            aj.simulate(slider, q0=q0, t1=0.05)
        assert info.value.group == "dyad"
    roberts = aj.load_scene("roberts")
    qs = np.linspace(-np.pi, np.pi, 721)
    ok = np.asarray(aj.kinematics(roberts.mechanism, qs, order=0, check=False).ok)
    bad = np.flatnonzero(~ok.all(-1))
    assert bad.size, "the Roberts linkage's crank does not turn fully"
    group = roberts.mechanism.groups[int(np.argmin(ok[bad[0]]))].name
    with pytest.raises(aj.AssemblyError, match=f"group '{group}'"):
        aj.simulate(roberts, q0=float(qs[bad[0]]), t1=0.05)


@pytest.mark.slow  # ~10 s: three programs of their own; test_unassemblable_start_raises_naming_the_group keeps the start's check
def test_a_start_that_cannot_go_on_is_named_with_every_step_saved_or_a_nan_load(write_scene):
    """With every step saved no row holds the start: the message named q0 = inf; nor where a
    load is NaN from the start (no step accepted): it was a lock-up 'at t = inf s'."""
    slider = aj.load_scene(write_scene(SLIDER_DRIVEN))
    roberts = aj.load_scene("roberts")
    qs = np.linspace(-np.pi, np.pi, 721)
    bad = np.flatnonzero(~np.asarray(aj.kinematics(roberts.mechanism, qs, order=0, check=False).ok).all(-1))
    with pytest.raises(aj.AssemblyError, match=f"cannot assemble at the start q0 = {float(qs[bad[0]]):.6g}:"):
        aj.simulate(roberts, q0=float(qs[bad[0]]), t1=0.05, save_steps=True)
    nan_drive = aj.Drive(lambda q, w, t: jnp.nan * q, velocity_dependent=False)
    for save_steps in (False, True):
        stuck = aj.simulate(slider, loads=(nan_drive,), t1=0.05, stop=None, save_steps=save_steps)
        assert stuck.event != LOCKUP and "a load or the joint friction" in stuck.status, stuck.status
        assert stuck.t.tolist() == [0.0] and stuck.q.tolist() == [slider.state["q0"]]


def test_point_and_link_rates_along_a_simulation(watt):
    """Velocities and accelerations in the Solution against central differences of the
    saved trajectories (and the centre of mass of a link against its two end points)."""
    ts = np.linspace(0.2, 0.6, 401)
    sol = aj.simulate(watt, stop=None, saveat=ts, points=["E"], angles=["link5"], coms=["link3"], velocities=True,
                      accelerations=True, rtol=1e-11, atol=1e-11)
    h = ts[1] - ts[0]
    mid = slice(1, -1)
    diff = lambda x: (x[2:] - x[:-2]) / (2 * h)  # noqa: E731
    np.testing.assert_allclose(sol.velocities["E"][mid], diff(sol.points["E"]), atol=1e-4 * np.abs(sol.velocities["E"]).max())
    np.testing.assert_allclose(sol.accelerations["E"][mid], diff(sol.velocities["E"]), atol=1e-3 * np.abs(sol.accelerations["E"]).max())
    np.testing.assert_allclose(sol.angular_velocities["link5"][mid], diff(np.unwrap(sol.angles["link5"])), atol=1e-4)
    np.testing.assert_allclose(sol.com_velocities["link3"][mid], diff(sol.coms["link3"]), atol=1e-4 * np.abs(sol.com_velocities["link3"]).max())
    np.testing.assert_allclose(sol.angular_accelerations["link5"][mid], diff(sol.angular_velocities["link5"]), atol=1e-2)


def test_options_that_a_path_cannot_honour_are_refused(watt):
    """steps= ignored saveat and dt, and called its blow-up a lock-up of group 'None'; the
    baseline ignored events and saveat and ended at a standstill without saying why; bridge=
    without a tracked branch did nothing; an event of two arguments was a raw TypeError; Euler
    with adaptive steps was diffrax's RuntimeError."""
    slider = aj.load_scene("slider_crank")
    for kwargs, message in ((dict(steps=200, saveat=[0.1, 0.5]), "steps= .* takes no saveat"),
                            (dict(steps=200, dt=1e-3), "steps= .* takes no dt"),
                            (dict(solver="seed_euler", events=[lambda t, q, w: q - 0.2]), "seed_euler.* takes no events"),
                            (dict(solver="seed_euler", saveat=[0.1, 0.2]), "seed_euler.* takes no saveat"),
                            (dict(solver="seed_euler", rtol=1e-6), "seed_euler.* takes no rtol"),
                            (dict(bridge=5e-3), "'bridge' .* needs branch='tracked'"),
                            (dict(solver="euler"), "'euler' has no error estimate .* give a fixed step"),
                            (dict(events=[lambda t, q: q]), "events: each cond\\(t, q, omega\\) takes"),
                            (dict(events=[lambda t, q, w: jnp.sqrt(q - 10.0)]), "event #1 is NaN at the start")):
        with pytest.raises(aj.AssurjaxError, match=message):
            aj.simulate(slider, t1=1.0, stop=None, **kwargs)
    blown = aj.simulate(slider, t1=1.0, steps=10, stop=None)  # 0.1 s steps: the slider-crank assembles at every q
    assert not blown.successful and blown.event < 0 and "not resolved" in blown.status and "no longer assemble" not in blown.status
    assert aj.simulate(slider, t1=1.0, steps=400, stop=None).successful
    euler = aj.simulate(slider, solver="seed_euler", stop=None, t1=2.0)
    assert "omega reached 0, which Euler in q cannot pass" in euler.status and float(euler.t[-1]) < 2.0
