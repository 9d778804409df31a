"""Loads: wrenches against hand computation, power balances, potential energy by
central differences, the [[loads]] scene tables and their errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import assurjax as aj

import joint_reference as ref


@pytest.fixture(scope="module")
def watt():
    return aj.load_scene("watt_sixbar")


@pytest.fixture(scope="module")
def kin(watt):
    return aj.kinematics(watt.mechanism, 0.4, 2.0, order=1)


def _power(watt, wrenches, kin):
    """Power (W) of a set of link wrenches: F . v_G + M w."""
    return sum(float(np.dot(f, kin.com_velocities[k]) + m * kin.angular_velocities[k]) for k, (f, m) in wrenches.items())


def test_gravity_wrenches(watt, kin):
    wr = aj.applied_wrenches(watt.mechanism, watt.gravity, (), kin)
    for name, link in watt.mechanism.links.items():
        np.testing.assert_allclose(wr[name][0], [0.0, -9.81 * float(link.mass)], atol=1e-14)
        assert float(wr[name][1]) == 0.0


def test_point_force_moment_about_com(watt, kin):
    f = np.array([2.0, -1.0])
    wr = aj.applied_wrenches(watt.mechanism, [0.0, 0.0], (aj.PointForce("E", f, link="link5"),), kin)
    r = np.asarray(kin.points["E"]) - np.asarray(kin.coms["link5"])
    np.testing.assert_allclose(wr["link5"][0], f)
    assert abs(float(wr["link5"][1]) - (r[0] * f[1] - r[1] * f[0])) < 1e-14
    # its power is F . v_E whichever carrier takes it
    wr6 = aj.applied_wrenches(watt.mechanism, [0.0, 0.0], (aj.PointForce("E", f, link="link6"),), kin)
    expected = float(np.dot(f, kin.velocities["E"]))
    assert abs(_power(watt, wr, kin) - expected) < 1e-12
    assert abs(_power(watt, wr6, kin) - expected) < 1e-12


def test_spring_force_is_minus_gradient_of_its_potential(watt):
    """Virtual work: the spring's reduced torque equals -dV_spring/dq."""
    spring = aj.Spring("O4", "E", 50.0, 0.4)
    q, h = 0.4, 1e-6
    red = aj.reduce(watt.mechanism, q, loads=(spring,))

    def v(th):
        pts, _ = ref.watt_sixbar_points(th)
        return 0.5 * 50.0 * (np.linalg.norm(pts["E"] - pts["O4"]) - 0.4) ** 2

    assert abs(float(red.torque) + (v(q + h) - v(q - h)) / (2 * h)) < 1e-6
    pose = aj.positions(watt.mechanism, q)
    gravity_only = aj.potential_energy(watt.mechanism, watt.gravity, (), pose)
    assert abs(float(aj.potential_energy(watt.mechanism, watt.gravity, (spring,), pose) - gravity_only) - v(q)) < 1e-9


def test_potential_energy_of_gravity(watt):
    pose = aj.positions(watt.mechanism, 0.4)
    pts, ang = ref.watt_sixbar_points(0.4)
    heights = dict(link2=(pts["O2"] + pts["A"]) / 2, link3=(pts["A"] + pts["B"]) / 2, link4=(pts["O4"] + pts["B"]) / 2,
                   link5=(pts["C"] + pts["E"]) / 2, link6=(pts["D"] + pts["E"]) / 2)
    expected = sum(float(watt.mechanism.links[k].mass) * 9.81 * c[1] for k, c in heights.items())
    assert abs(float(aj.potential_energy(watt.mechanism, watt.gravity, (), pose)) - expected) < 1e-12


def test_dampers_dissipate_what_their_wrenches_remove(watt, kin):
    for damper in (aj.Damper("O4", "E", 3.0), aj.RotaryDamper("A", 0.7), aj.RotaryDamper("O2", 0.7)):
        wr = aj.applied_wrenches(watt.mechanism, [0.0, 0.0], (damper,), kin)
        dissipated = float(aj.dissipated_power(watt.mechanism, (damper,), kin))
        assert dissipated > 0
        assert abs(_power(watt, wr, kin) + dissipated) < 1e-12


def test_dissipated_power_closed_form(watt, kin):
    """c (dL/dt)^2 and c (w_b - w_a)^2 from the reference's closed-form positions
    (central differences, crank at q = 0.4 turning at w = 2 rad/s)."""
    q, w, h = 0.4, 2.0, 1e-6
    (pp, ap), (pm, am) = ref.watt_sixbar_points(q + h), ref.watt_sixbar_points(q - h)
    length = lambda pts: np.linalg.norm(pts["E"] - pts["O4"])  # noqa: E731
    rate = lambda link: (ap[link] - am[link]) / (2 * h) * w  # noqa: E731
    expected = [
        (aj.Damper("O4", "E", 3.0), 3.0 * ((length(pp) - length(pm)) / (2 * h) * w) ** 2),
        (aj.RotaryDamper("A", 0.7), 0.7 * (rate("coupler") - rate("crank")) ** 2),
        (aj.RotaryDamper("O2", 0.7), 0.7 * rate("crank") ** 2),
    ]
    for damper, power in expected:
        assert abs(float(aj.dissipated_power(watt.mechanism, (damper,), kin)) - power) < 1e-7 * (1.0 + power)


def test_rotary_damper_on_ground_joint_closed_form(watt, kin):
    wr = aj.applied_wrenches(watt.mechanism, [0.0, 0.0], (aj.RotaryDamper("O2", 0.7),), kin)
    assert abs(float(wr["link2"][1]) + 0.7 * 2.0) < 1e-14  # crank spins at w = 2 rad/s


def test_driving_efforts():
    mech = aj.load_scene("watt_sixbar").mechanism
    motor = aj.MotorLine(1.5, 10.0)
    assert abs(float(aj.driver_effort(mech, (motor,), 0.0, 4.0)) - 1.5 * (1 - 0.4)) < 1e-15
    poly = aj.Drive(aj.Polynomial([1.0, 2.0, 3.0]))
    assert abs(float(aj.driver_effort(mech, (poly,), 2.0, 0.0)) - (1 + 4 + 12)) < 1e-12
    table = aj.Drive(aj.Table([0.0, 1.0, 2.0], [0.0, 10.0, 0.0], period=2.0))
    assert abs(float(aj.driver_effort(mech, (table,), 2.5, 0.0)) - 5.0) < 1e-12
    user = aj.Drive(lambda q, w, t: jnp.sin(t) * 2.0)
    assert abs(float(aj.driver_effort(mech, (user,), 0.0, 0.0, 0.5)) - 2 * np.sin(0.5)) < 1e-15
    assert user.velocity_dependent and not poly.velocity_dependent and motor.velocity_dependent
    assert float(aj.driver_effort(mech, (), 0.0, 0.0)) == 0.0


@pytest.mark.parametrize("n", [2, 7, 64, 65, 300])  # both of the interval searches (_loads.SMALL_TABLE)
def test_table_interpolates_as_numpy_does(n):
    """A Table against numpy's np.interp: inside, at and beyond its points (one repeated:
    a jump), with its gradient finite everywhere and the slope of its interval inside."""
    rng = np.random.default_rng(n)
    x = np.sort(rng.uniform(-3.0, 3.0, n))
    if n > 2:
        x[n // 2] = x[n // 2 - 1]
    values = rng.normal(size=n)
    table = aj.Table(x, values)
    at = np.concatenate([rng.uniform(-4.0, 4.0, 200), x, [x[0] - 1.0, x[-1] + 1.0]])
    found = np.asarray(jax.jit(jax.vmap(lambda v: table(v, 0.0, 0.0)))(jnp.asarray(at)))
    np.testing.assert_allclose(found, np.interp(at, x, values), rtol=0, atol=1e-14)
    slopes = np.asarray(jax.vmap(jax.grad(lambda v: table(v, 0.0, 0.0)))(jnp.asarray(at)))
    assert np.all(np.isfinite(slopes))
    inside = (at > x[0]) & (at < x[-1])
    inside[200:] = False  # the random points only: at a point itself the slope is either side's
    k = np.searchsorted(x, at[inside], side="right")
    expected = (values[k] - values[k - 1]) / (x[k] - x[k - 1])
    np.testing.assert_allclose(slopes[inside], expected, rtol=1e-12)


def test_a_table_out_of_order_is_a_clear_error():
    """x out of order read values of other intervals (Table([2, 1, 0], [0, 1, 2]) at 0.5 gave
    0, not 1.5); a period shorter than the x range never read the values past it."""
    for x, message in ((["a", "b"], "Table: x"), ([2.0, 1.0, 0.0], "x must be increasing"),
                       ([0.0, 2.0, 1.0], "x must be increasing")):
        with pytest.raises(aj.MechanismError, match=message):
            aj.Table(x, [0.0, 1.0, 2.0][:len(x)])
    with pytest.raises(aj.MechanismError, match="period 0.5 is shorter than the x range 2"):
        aj.Table([0.0, 1.0, 2.0], [0.0, 1.0, 0.0], period=0.5)
    assert float(aj.Table([0.0, 1.0, 1.0, 2.0], [0.0, 1.0, 5.0, 6.0])(1.5, 0.0, 0.0)) == 5.5  # a jump at 1


def test_unknown_point_or_link_is_a_clear_error(watt):
    from assurjax._loads import check_loads

    with pytest.raises(aj.MechanismError, match="unknown point 'Z'"):
        check_loads(watt.mechanism, (aj.Spring("O2", "Z", 1.0),))
    with pytest.raises(aj.MechanismError, match="unknown link 'link9'"):
        check_loads(watt.mechanism, (aj.Couple("link9", 1.0),))
    with pytest.raises(aj.MechanismError, match="exactly two links"):
        check_loads(watt.mechanism, (aj.RotaryDamper("Q", 1.0),))


def test_the_public_load_functions_check_their_loads(watt, kin):
    """They raised a raw KeyError 'Z' from inside the sum."""
    m, g, pose = watt.mechanism, watt.gravity, aj.positions(watt.mechanism, 0.3)
    with pytest.raises(aj.MechanismError, match="unknown point 'Z'"):
        aj.potential_energy(m, g, [aj.Spring("O2", "Z", 1.0)], pose)
    with pytest.raises(aj.MechanismError, match="unknown point 'Z'"):
        aj.applied_wrenches(m, g, [aj.PointForce("Z", [1.0, 0.0])], kin)
    with pytest.raises(aj.MechanismError, match="unknown point 'Z'"):
        aj.dissipated_power(m, [aj.Damper("O2", "Z", 2.0)], kin)
    with pytest.raises(aj.MechanismError, match="expected an assurjax load"):
        aj.driver_effort(m, ["drive"], 0.0, 0.0)
    with pytest.raises(aj.MechanismError, match="gravity"):
        aj.applied_wrenches(m, [0.0, 0.0, -9.81], [], kin)
    assert float(aj.driver_effort(m, (load for load in [aj.Drive(1.0)]), 0.3, 0.0)) == 1.0  # a generator, read once


SCENE = """
[scene]
name = "loaded"
gravity = [0.0, -9.81]
[ground]
O = [0.0, 0.0]
P = [0.0, 1.0]
[links.crank]
points = {{ O = [0.0, 0.0], A = [1.0, 0.0] }}
mass = 1.0
inertia = 0.1
[[formation]]
group = "crank"
link = "crank"
pivot = "O"
{loads}
"""


def test_scene_loads_tables(write_scene):
    loads = """
[[loads]]
type = "motor"
stall = 2.0
no_load_speed = 5.0
[[loads]]
type = "spring"
points = ["P", "A"]
stiffness = 10.0
free_length = 0.5
[[loads]]
type = "force"
point = "A"
force = [1.0, { polynomial = [0.0, 2.0], variable = "t" }]
[[loads]]
type = "couple"
link = "crank"
moment = { x = [0.0, 3.141592653589793], values = [1.0, -1.0] }
[[loads]]
type = "rotary_damper"
joint = "O"
coefficient = 0.2
"""
    scene = aj.load_scene(write_scene(SCENE.format(loads=loads)))
    kinds = [type(load).__name__ for load in scene.loads]
    assert kinds == ["MotorLine", "Spring", "PointForce", "Couple", "RotaryDamper"]
    q, w, t = 0.0, 1.0, 0.25
    kin = aj.kinematics(scene.mechanism, q, w, order=1)
    wr = aj.applied_wrenches(scene.mechanism, scene.gravity, scene.loads, kin, t)
    # by hand at q = 0: A = (1, 0), spring P-A length sqrt(2) pulls A towards P
    u = np.array([-1.0, 1.0]) / np.sqrt(2)
    f_spring = 10.0 * (np.sqrt(2) - 0.5) * u
    f_expected = np.array([0.0, -9.81]) + f_spring + np.array([1.0, 2.0 * t])
    np.testing.assert_allclose(wr["crank"][0], f_expected, atol=1e-12)
    r = np.array([0.5, 0.0])  # A relative to the COM
    m_expected = r[0] * (f_spring[1] + 2.0 * t) + 1.0 - 0.2 * w
    assert abs(float(wr["crank"][1]) - m_expected) < 1e-12
    assert abs(float(aj.driver_effort(scene.mechanism, scene.loads, q, w)) - 2.0 * (1 - w / 5.0)) < 1e-15


@pytest.mark.parametrize("table, message", [
    ('type = "force"\npoint = "Z"\nforce = [1.0, 0.0]', r"\[\[loads\]\] #1 \(force\), field 'point': unknown point 'Z'"),
    ('type = "force"\npoint = "A"\nforce = [1.0]', r"#1 \(force\), field 'force'"),
    ('type = "couple"\nlink = "crank"\nmoment = "q**2"', r"field 'moment'"),
    ('type = "spring"\npoints = ["A", "Z"]\nstiffness = 1.0', r"field 'points': unknown point 'Z'"),
    ('type = "warp"', r"field 'type': unknown load type 'warp'"),
    ('type = "motor"\nstall = 1.0\nno_load_speed = 0.0', r"field 'no_load_speed': must be positive"),
    ('type = "damper"\npoints = ["O", "A"]\ncoefficient = 1.0\ncolour = "red"', r"unknown field\(s\) \['colour'\]"),
])
def test_scene_load_errors_name_index_and_field(write_scene, table, message):
    with pytest.raises(aj.SceneError, match=message):
        aj.load_scene(write_scene(SCENE.format(loads="[[loads]]\n" + table)))
