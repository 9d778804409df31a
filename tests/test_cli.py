"""The `assurjax` command end to end, in temporary directories.

``main([...])`` runs in-process (one compilation for the whole module); one
subprocess smoke test covers the installed script. Numbers in the files are
checked against closed forms, the energy balance and the independent joint-based
reference (tests/joint_reference.py)."""

import csv
import math
import os
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

import assurjax
from assurjax.cli import DEFAULT_SCENE, build_parser, main, parse_args

sys.path.insert(0, os.path.dirname(__file__))
import joint_reference as jr  # noqa: E402
from scene_texts import ROUGH_ARM  # noqa: E402


def read_csv(path):
    """Columns by name; an empty cell (no value) is NaN."""
    with open(path) as f:
        rows = list(csv.reader(f))
    return {name: np.array([float(r[i]) if r[i] else np.nan for r in rows[1:]]) for i, name in enumerate(rows[0])}


@pytest.fixture(scope="module")
def watt_run(tmp_path_factory):
    """`assurjax run` with no scene (the bundled default), once for the module."""
    out = tmp_path_factory.mktemp("run")
    status = main(["run", "--out", str(out), "--frames", "4", "--quiet"])
    return status, out


def test_run_defaults_to_the_watt_sixbar():
    assert DEFAULT_SCENE == "watt_sixbar"
    assert build_parser().parse_args(["run"]).scene == "watt_sixbar"


def test_csv_columns_in_the_scenes_order():
    from types import SimpleNamespace

    from assurjax.cli import _solution_columns

    t = np.zeros(3)
    scene = SimpleNamespace(outputs={"points": ["Z", "A"], "angles": ["crank", "arm"]})
    sol = SimpleNamespace(t=t, q=t, omega=t, points={"A": np.zeros((3, 2)), "Z": np.zeros((3, 2))},
                          angles={"arm": t, "crank": t})  # sorted, as a pytree's dicts come back
    assert list(_solution_columns(scene, sol, {}, None))[3:] == ["x_Z", "y_Z", "x_A", "y_A", "theta_crank", "theta_arm"]


def test_common_options_before_or_after_the_command():
    for argv in (["--debug", "--no-cache", "run"], ["run", "--debug", "--no-cache"]):
        args = parse_args(build_parser(), argv)
        assert args.debug and args.no_cache and not args.quiet, argv
    assert not parse_args(build_parser(), ["run"]).debug


def test_run_writes_every_file(watt_run):
    status, out = watt_run
    assert status == 0
    for name in ("solution.csv", "histories.png", "reduced.png", "coupler_curves.png", "animation.gif", "summary.json"):
        assert (out / name).stat().st_size > 0, name
    with Image.open(out / "animation.gif") as im:
        assert im.n_frames == 4


def test_run_csv_columns_and_values(watt_run):
    _, out = watt_run
    cols = read_csv(out / "solution.csv")
    expected = {"t", "q", "omega", "domega", "T", "V", "E", "x_A", "y_A", "x_B", "y_B", "x_E", "y_E", "theta_link2", "driving"}
    expected |= {f"{c}_{j}" for j in ("O2", "A", "E") for c in ("Fx", "Fy", "F")}
    assert expected <= set(cols)
    assert np.all(np.diff(cols["t"]) > 0)  # once per time (a solver step ending on a sample time was saved twice)
    # A is on the unit crank: closed form x_A = cos q, y_A = sin q
    np.testing.assert_allclose(cols["x_A"], np.cos(cols["q"]), atol=1e-12)
    np.testing.assert_allclose(cols["y_A"], np.sin(cols["q"]), atol=1e-12)
    # closed-form positions of E from the reference's circle intersections
    for k in (0, len(cols["q"]) // 2):
        points, _ = jr.watt_sixbar_points(cols["q"][k])
        np.testing.assert_allclose([cols["x_E"][k], cols["y_E"][k]], points["E"], atol=1e-9)
    # energy balance (no loads but gravity): E = T + V stays at its initial value
    assert np.max(np.abs(cols["E"] - cols["E"][0])) < 1e-5 * np.max(cols["T"])
    # |F| column is the magnitude of its components
    np.testing.assert_allclose(cols["F_A"], np.hypot(cols["Fx_A"], cols["Fy_A"]), rtol=1e-12)
    # kinetostatics agrees with the dynamics: the free fall needs no driving torque
    assert np.max(np.abs(cols["driving"])) < 1e-6 * np.max(np.abs(cols["F_O2"]))


def test_run_reactions_at_release_match_the_joint_reference(watt_run):
    """At t = 0 the six-bar is released from rest: compare |F| with the joint-based Lagrange multipliers."""
    _, out = watt_run
    cols = read_csv(out / "solution.csv")
    ref = jr.watt_sixbar(0.0, 0.0).simulate(1e-9, t_eval=[0.0])
    for joint in ("O2", "A", "E"):
        np.testing.assert_allclose(cols[f"F_{joint}"][0], np.hypot(*ref.reactions[joint][0]), rtol=1e-6)
    np.testing.assert_allclose(cols["domega"][0], ref.wdot[0], rtol=1e-8)


def test_run_summary_standstill(watt_run, capsys):
    _, out = watt_run
    import json

    summary = json.loads((out / "summary.json").read_text())
    cols = read_csv(out / "solution.csv")
    assert summary["t_stop"] == pytest.approx(cols["t"][-1]) and summary["jammed"] is False
    assert abs(cols["omega"][-1]) < 1e-6 * np.max(np.abs(cols["omega"]))  # at rest again
    assert summary["energy_drift_J"] < 1e-5 * np.max(cols["T"])
    assert {"simulate_first_call", "simulate_compiled"} <= set(summary["timings_s"])


def test_command_turns_off_the_stalling_scheduler_and_keeps_the_users_flags(monkeypatch):
    """The command sets XLA's scheduler flag for its own process (reactions of the friction
    press stalled in 3 of 5 runs with it on), adds it to flags the user set, and leaves a
    setting of that flag the user made alone."""
    from assurjax import cli

    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/dev/null")
    cli._avoid_runtime_stall()
    assert os.environ["XLA_FLAGS"] == "--xla_dump_to=/dev/null " + cli.STALL_FREE_FLAG
    monkeypatch.delenv("XLA_FLAGS")
    cli._avoid_runtime_stall()
    assert os.environ["XLA_FLAGS"] == cli.STALL_FREE_FLAG
    mine = "--xla_cpu_enable_concurrency_optimized_scheduler=true"
    monkeypatch.setenv("XLA_FLAGS", mine)
    cli._avoid_runtime_stall()
    assert os.environ["XLA_FLAGS"] == mine


def test_scenes_lists_bundled_with_descriptions(capsys):
    assert main(["scenes"]) == 0
    text = capsys.readouterr().out
    for name in assurjax.bundled_scenes():
        line = next(line for line in text.splitlines() if line.startswith(name))
        assert assurjax.load_scene(name).description in line


def test_validate_good_scene(capsys):
    assert main(["validate", "roberts"]) == 0
    assert "OK" in capsys.readouterr().out


ONE_LINK = """
[ground]
O = [0.0, 0.0]
[links.crank]
points = { O = [0.0, 0.0], A = [1.0, 0.0] }
[[formation]]
"""

BAD_SCENES = {
    "not toml": ("x = ", "not valid TOML"),
    "unknown group": (ONE_LINK + 'group = "RRRR"\n', "unknown group kind"),
    "unknown output point": (
        ONE_LINK + 'group = "crank"\nlink = "crank"\npivot = "O"\n[outputs]\npoints = ["Z"]\n',
        "unknown point 'Z'",
    ),
}


@pytest.mark.parametrize("case", BAD_SCENES)
def test_validate_bad_scene_exits_2_with_one_line(case, write_scene, capsys):
    text, reason = BAD_SCENES[case]
    path = write_scene(text)
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("assurjax: error:") and reason in err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1


DRAWN_FOUR_BAR = """
[sketch]
driver = "crank"
ground = ["A", "D"]
joints = { A = [0.0, 0.0], B = [0.1, 0.2], C = [CX, CY], D = [0.4, 0.0] }
[sketch.links]
crank = { joints = ["A", "B"] MASS }
coupler = { joints = ["B", "C"] }
rocker = { joints = ["D", "C"] }
"""


def test_validate_prints_what_the_drawing_left_open_and_run_refuses_no_mass(write_scene, capsys):
    # C on the line B-D (the drawn configuration is singular: the mode is a choice), no masses
    massless = write_scene(DRAWN_FOUR_BAR.replace("CX", "0.7").replace("CY", "-0.2").replace(" MASS", ""))
    assert main(["validate", str(massless)]) == 0
    out = capsys.readouterr().out
    assert "note: group 'RRR1' (RRR: links coupler, rocker): drawn at a singular configuration" in out
    assert "note: no link has a mass or a moment of inertia: kinematics and statics only" in out
    assert main(["run", "--quiet", "--no-animation", str(massless)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("assurjax: error: mechanism 'scene': no link has a mass") and "Traceback" not in err
    weighed = write_scene(DRAWN_FOUR_BAR.replace("CX", "0.5").replace("CY", "0.3").replace(" MASS", ", mass = 0.2"))
    assert main(["validate", str(weighed)]) == 0
    assert "note:" not in capsys.readouterr().out


def test_validate_scene_that_cannot_assemble_names_the_group(write_scene, capsys):
    path = write_scene(
        """
        [ground]
        O = [0.0, 0.0]
        F = [5.0, 0.0]
        [links.crank]
        points = { O = [0.0, 0.0], A = [1.0, 0.0] }
        [links.rod]
        points = { A = [0.0, 0.0], B = [1.0, 0.0] }
        [links.rocker]
        points = { F = [0.0, 0.0], B = [1.0, 0.0] }
        [[formation]]
        group = "crank"
        link = "crank"
        pivot = "O"
        [[formation]]
        group = "RRR"
        name = "dyad"
        links = ["rod", "rocker"]
        joints = ["A", "F", "B"]
        mode = "left"
        """
    )
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    # why, from the numbers above: at q0 = 0, A = (1, 0) is 5 - 1 from F, beyond rod + rocker = 1 + 1;
    # the file and the tables where those lengths are set (it said only "group 'dyad' (RRR) cannot assemble at q = 0")
    assert err.startswith(f"assurjax: error: {path}: group 'dyad' (RRR) cannot assemble at q = 0: ")
    assert f"|A F| = {5.0 - 1.0:.4g} m > 1 + 1 m (links rod, rocker too short)" in err
    assert "check [links.rod] points, [links.rocker] points, [links.crank] points and [ground] (m), or [state] q0 (rad)" in err


def test_validate_sketch_scene_that_cannot_assemble_names_its_joints(write_scene, capsys):
    """A drawn four-bar asked to start where its crank points away from the rocker (q0 = pi)."""
    path = write_scene(
        """
        [sketch]
        driver = "crank"
        ground = ["A", "D"]
        joints = { A = [0.0, 0.0], B = [0.2, 0.3], C = [0.5, 0.3], D = [0.4, 0.0] }
        [sketch.links]
        crank = { joints = ["A", "B"], density = 2.0 }
        coupler = { joints = ["B", "C"], density = 2.0 }
        rocker = { joints = ["D", "C"], density = 2.0 }
        [state]
        q0 = 3.141592653589793
        """
    )
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err
    bd, bc, dc = 0.4 + np.hypot(0.2, 0.3), 0.3, np.hypot(0.1, 0.3)  # B = (-|A B|, 0) at q0 = pi
    assert f"{path}: group 'RRR1' (RRR) cannot assemble at q = 3.14159: |B D| = {bd:.4g} m > {bc:.4g} + {dc:.4g} m" in err
    assert "check the [sketch.joints] of link(s) coupler, rocker, crank and the ground joints (m), or [state] q0 (rad)" in err


@pytest.mark.parametrize(
    "argv, reason",
    [
        (["validate", "no_such_scene"], "neither a scene file nor a bundled scene"),
        (["run", "missing.toml"], "no such scene file"),
        (["kinematics", "roberts", "--samples", "1"], "--samples"),
        (["kinematics", "roberts", "--start", "2", "--stop", "1"], "--stop"),
        (["kinematics", "roberts", "--start", "1e300", "--stop", "1e301"], "--start must be at most 1e+12 in magnitude"),
    ],
)
def test_user_errors_exit_2(argv, reason, capsys):
    assert main(argv) == 2
    assert reason in capsys.readouterr().err


def test_unknown_command_and_missing_argument_exit_2(capsys):
    assert main(["bogus"]) == 2
    assert main(["validate"]) == 2
    assert main([]) == 2


def test_output_directory_that_is_a_file(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    assert main(["kinematics", "roberts", "--out", str(blocker / "sub"), "--samples", "5"]) == 2
    assert "cannot create output directory" in capsys.readouterr().err


def test_debug_shows_the_exception():
    with pytest.raises(assurjax.SceneError):
        main(["validate", "no_such_scene", "--debug"])


def test_kinematics_sweep_roberts(tmp_path, capsys):
    """Seed 001: y_P (the straight-line error) stays below 1 mm for -130 < x_P < 130 mm,
    and P is where the circle-intersection closed form puts it."""
    assert main(["kinematics", "roberts", "--out", str(tmp_path), "--samples", "61", "--start", "0.2", "--stop", "2.9", "--quiet"]) == 0
    cols = read_csv(tmp_path / "kinematics.csv")
    assert {"q", "ok", "x_P", "y_P", "dx_P/dq", "theta_link4", "dtheta_link3/dq"} <= set(cols)
    for name in ("coupler_curves.png", "angular_velocities.png", "mechanism.png"):
        assert (tmp_path / name).stat().st_size > 0
    ok = cols["ok"] == 1
    line = ok & (np.abs(cols["x_P"]) < 0.13)
    assert line.sum() > 10 and np.max(np.abs(cols["y_P"][line])) < 1e-3
    for k in np.flatnonzero(ok)[::10]:
        q = cols["q"][k]
        b = np.array([-0.12 + 0.18 * np.cos(q), 0.18 * np.sin(q)])
        c = jr.circle_intersection(b, 0.12, np.array([0.12, 0.0]), 0.18, left=True)
        m, u = (b + c) / 2, (c - b) / 0.12
        p = m + np.sqrt(0.18**2 - 0.06**2) * np.array([u[1], -u[0]])  # seed 001 eq. (7)
        np.testing.assert_allclose([cols["x_P"][k], cols["y_P"][k]], p, atol=1e-9)


def test_reactions_static_matches_the_joint_reference(capsys):
    """Watt six-bar held at rest at q0 = 0: the driving torque by inverse dynamics of the reference."""
    assert main(["reactions", "watt_sixbar", "--static"]) == 0
    text = capsys.readouterr().out
    torque = float(re.search(r"driving effort = ([-+0-9.e]+)", text).group(1))
    model = jr.watt_sixbar(0.0, 0.0)
    z, _ = model.system.newton(0.0, model.system.to_internal(model.initial.coords))
    expected = model.system.inverse_dynamics(z, 0.0, 0.0)[0]
    assert torque == pytest.approx(expected, rel=1e-5)


def test_reactions_static_with_joint_friction_gives_the_breakaway_band(write_scene, capsys):
    """`assurjax reactions --static` on the rough arm held level: the frictionless holding
    torque m g l_G, and the band m g l_G -+ mu r m g (closed form) within which any drive
    holds it; an infinite edge is said in words (no drive starts it that way)."""
    from assurjax.cli import _band_line

    assert main(["reactions", str(write_scene(ROUGH_ARM_RUN)), "--static"]) == 0
    text = capsys.readouterr().out
    holding, limit = 2.0 * 9.81 * 0.15, 0.3 * 0.04 * 2.0 * 9.81
    assert float(re.search(r"driving effort = ([-+0-9.e]+)", text).group(1)) == pytest.approx(holding, rel=1e-6)
    upper, lower = (float(v) for v in re.search(r"starts forward above ([-+0-9.e]+) N m and backward below ([-+0-9.e]+) N m",
                                                  text).groups())
    assert upper == pytest.approx(holding + limit, rel=1e-6) and lower == pytest.approx(holding - limit, rel=1e-6)
    assert "it has no drive of its own: 0 N m is below the band: it starts backward" in text  # it falls
    # its own drive against the band (they stand for a drive in its place): within it holds, past it starts
    for torque, verdict in ((holding, "within the band: it stays at rest"), (holding + 1.2 * limit, "above the band: it "
                                                                                                   "starts forward")):
        drive = f'[[loads]]\ntype = "drive"\nvalue = {torque!r}\n'
        assert main(["reactions", str(write_scene(ROUGH_ARM_RUN + drive, "driven.toml")), "--static"]) == 0
        assert f"its own drive at q0 (w = 0, t = t0) is {torque:+.6g} N m, {verdict}" in capsys.readouterr().out
    units = dict(driving="N m")
    assert _band_line(-math.inf, 1.5, units) == ("  with its joint friction it starts forward above +1.5 N m; any drive below "
                                                 "that holds it (the break-away band); no drive starts it backward: the "
                                                 "friction self-locks it")
    assert "any drive above that holds it" in _band_line(-1.5, math.inf, units)
    both = _band_line(-math.inf, math.inf, units)  # no bounds: no "between"
    assert "no drive starts it either way" in both and "between" not in both
    assert _band_line(0.5, 0.5, units) == ("  with its joint friction only +0.5 N m holds it (the friction holds nothing "
                                           "at rest): any other drive starts it, forward above, backward below")


def test_reactions_along_the_motion_balance_the_crank(watt_run, tmp_path, capsys):
    """Newton's law for the crank (m = 1 kg, centre of mass at 0.5 m): F_O2 - F_A + m g = m a_G,
    with a_G from the closed form of a point on a rotating crank. (F_O2: on the crank by the
    ground; F_A: on link 3 by the crank.) Reuses the compiled simulation of the run fixture."""
    assert main(["reactions", "watt_sixbar", "--out", str(tmp_path), "--quiet"]) == 0
    assert "peak |F|" in capsys.readouterr().out
    cols = read_csv(tmp_path / "reactions.csv")
    assert (tmp_path / "reactions.png").stat().st_size > 0
    q, w, dw = cols["q"], cols["omega"], cols["domega"]
    a_g = 0.5 * (-(w**2)[:, None] * np.column_stack([np.cos(q), np.sin(q)]) + dw[:, None] * np.column_stack([-np.sin(q), np.cos(q)]))
    net = np.column_stack([cols["Fx_O2"] - cols["Fx_A"], cols["Fy_O2"] - cols["Fy_A"] - 9.81])
    np.testing.assert_allclose(net, a_g, atol=1e-8 * np.max(cols["F_O2"]))
    assert np.all(cols["ok"] == 1)


def test_installed_script_smoke(tmp_path):
    exe = shutil.which("assurjax")
    assert exe, "the assurjax script is not installed (pip install -e .)"
    done = subprocess.run([exe, "scenes"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "watt_sixbar" in done.stdout
    bad = tmp_path / "bad.toml"
    bad.write_text("[scene\n")
    done = subprocess.run([exe, "validate", str(bad)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "Traceback" not in done.stderr and "bad.toml" in done.stderr


ROUGH_ARM_RUN = """
[scene]
name = "rough_arm"
gravity = [0.0, -9.81]
[state]
q0 = 0.0
t1 = 3.0
[simulation]
stop = "standstill"
[outputs]
reactions = ["O"]
energies = true
""" + ROUGH_ARM


def test_run_with_joint_friction_to_a_standstill(write_scene, tmp_path, capsys):
    """`assurjax run` on a scene with joint friction that stops at the first rest: the arm
    released level swings down and up the other side; the balance closes with the friction's
    work and the undriven motion needs no drive, its start (from rest) included."""
    import json

    out = tmp_path / "out"
    assert main(["run", str(write_scene(ROUGH_ARM_RUN)), "--out", str(out), "--frames", "2", "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    cols = read_csv(out / "solution.csv")
    assert summary["t_stop"] == pytest.approx(cols["t"][-1]) and summary["jammed"] is False and cols["q"][-1] < -math.pi / 2  # past the bottom
    assert summary["energy_drift_J"] < 1e-6 * np.max(cols["T"])
    assert np.min(cols["W"]) < -0.01  # the friction took energy
    np.testing.assert_allclose(cols["driving"], 0.0, atol=1e-9)
    # the pivot's friction: mu r |F| against the motion, and its power integrates to the work W
    # the solver integrated along the motion (trapezoidal rule on the samples)
    moving = cols["omega"] != 0.0
    np.testing.assert_allclose(np.abs(cols["friction_O"][moving]), 0.3 * 0.04 * cols["F_O"][moving], rtol=1e-12)
    assert np.all(cols["friction_O"][moving] * cols["omega"][moving] < 0)
    assert np.all(cols["friction_ok"] == 1)  # every sample's friction a consistent solution
    lost = -np.trapezoid(cols["friction_power_O"], cols["t"])
    assert lost == pytest.approx(-cols["W"][-1], rel=1e-4)
    printed = capsys.readouterr().out
    assert f"friction: {lost:.5g} J lost over the motion (O 100 %)" in printed
    # held at q* only where gravity's torque -m g l_G cos q* is within the static limit mu r m g
    # (closed form): not so past the bottom, where it pulls the arm back up (+q)
    torque, limit = -2.0 * 9.81 * 0.15 * math.cos(cols["q"][-1]), 0.3 * 0.04 * 2.0 * 9.81
    assert torque > limit and ("a turning point: the joint friction does not hold it there, and the motion goes on "
                               "forward") in printed
    # its peak, located on the dense output as the reaction's is: mu r times that peak, at its time
    friction, force = summary["peaks"]["friction O"], summary["peaks"]["O"]
    assert friction["t"] == force["t"] and friction["value"] == pytest.approx(0.3 * 0.04 * force["value"], rel=1e-12)
    assert friction["value"] >= np.max(np.abs(cols["friction_O"]))
    assert f"peak |friction| (located on the dense output): O {friction['value']:.5g} N m at t = {friction['t']:.6g} s" in printed
    # with samples too coarse for the trapezoidal rule the total is the integrated one, and said to be
    coarse = tmp_path / "coarse"
    assert main(["run", str(write_scene(ROUGH_ARM_RUN)), "--out", str(coarse), "--samples", "5", "--no-animation",
                 "--quiet"]) == 0
    few = read_csv(coarse / "solution.csv")
    assert few["W"][-1] == pytest.approx(cols["W"][-1], rel=1e-9)
    assert f"friction: {-few['W'][-1]:.5g} J lost over the motion (integrated); shares from the friction power at the" in capsys.readouterr().out


def test_summary_says_where_a_run_ends_held_at_rest(write_scene, capsys):
    """The run's summary says where a run that reached t1 without friction is at rest
    throughout (a frictionless w passes through 0 where it moves); held by the joint
    friction, the run's status says it (test_friction_static.py). Nothing where it moves at
    its end, stopped at an event or failed, or where the standstill line reports the stop;
    and a driving effort of round-off is not said to drive a mechanism that stays at rest."""
    from types import SimpleNamespace

    from assurjax._peaks import Peak
    from assurjax.cli import _print_peaks, _rest_line

    rough = assurjax.load_scene(str(write_scene(ROUGH_ARM_RUN.replace('stop = "standstill"', 'stop = "none"'))))
    smooth, stops = rough.with_loads(()), assurjax.load_scene(str(write_scene(ROUGH_ARM_RUN, "stops.toml")))
    t = np.linspace(0.0, 0.4, 5)

    def run(omega, successful=True, event=-1):
        return SimpleNamespace(t=t, omega=np.asarray(omega, dtype=float), successful=successful, event=np.asarray(event))

    stopping, still = run([1.0, 0.5, -0.2, 0.0, 0.0]), run(np.zeros(5))
    assert _rest_line(smooth, still) == "  at rest throughout: nothing moves it from its start"
    # held by the friction: the run's status says since when (test_friction_static.py)
    for scene, sol in ((rough, stopping), (rough, still), (smooth, stopping), (rough, run([1.0, 0.5, -0.2, 0.0, 0.1])),
                       (stops, stopping),
                       (rough, run(np.zeros(5), event=0)), (rough, run(np.zeros(5), successful=False))):
        assert _rest_line(scene, sol) is None
    peaks = {"O": Peak("O", 19.62, 0.0), "driving": Peak("driving", 1e-15, 0.0)}
    _print_peaks(peaks, dict(driving="N m"), rough, moves=False)
    _print_peaks(peaks, dict(driving="N m"), rough)
    printed = capsys.readouterr().out
    assert "driving effort: none needed (it stays at rest; largest value 1.0e-15 N m is round-off)" in printed
    assert "driving effort: none needed (the loads alone drive this motion; largest value" in printed
    # a constant drive's effort is said to be constant (its peak's time was where round-off put it)
    peaks["driving"] = Peak("driving", 1.5 + 4e-16, 2.96)
    _print_peaks(peaks, dict(driving="N m"), rough, driving=1.5 + np.array([0.0, 4e-16, -2e-16]))
    _print_peaks(peaks, dict(driving="N m"), rough, driving=np.array([1.5, 1.4, 1.0]))
    printed = capsys.readouterr().out
    assert "driving effort: constant, +1.5 N m" in printed and "peak |driving effort|: 1.5 N m at t = 2.96 s" in printed


@pytest.mark.slow  # ~9 s; the default suite keeps to 10 min
def test_run_to_a_lockup_reports_the_balance_before_its_approach(tmp_path, capsys):
    """The Roberts four-bar coasts (no loads) into the limit position of its crank: T stays at
    T(0) up to the lock-up's approach, where J_red grows without bound and w goes to 0; the
    command reports the balance before that window apart from the one at the lock-up, and
    the peaks before it."""
    import json

    import importlib.resources

    out, scene = tmp_path / "out", tmp_path / "roberts.toml"
    text = (importlib.resources.files("assurjax") / "scenes" / "roberts.toml").read_text()
    scene.write_text(text.replace('[outputs]\n', '[outputs]\nreactions = ["A", "D"]\n'))
    assert main(["run", str(scene), "--out", str(out), "--no-animation", "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    cols = read_csv(out / "solution.csv")
    assert "can no longer assemble" in summary["status"]
    window = summary["lockup_window_s"]
    assert window == pytest.approx(0.01 * (cols["t"][-1] - cols["t"][0]))
    before = cols["t"] < cols["t"][-1] - window
    assert np.max(np.abs(cols["T"][before] - cols["T"][0])) < 1e-5 * cols["T"][0]  # no loads: T is conserved
    assert summary["energy_drift_before_lockup_J"] < 1e-5 * cols["T"][0]
    assert summary["energy_drift_before_lockup_J"] <= summary["energy_drift_J"]
    printed = capsys.readouterr().out
    assert "s before the lock-up" in printed and "no longer resolves T" in printed
    # nor do the steps resolve the reactions there: the peaks are searched before that window
    # (a slider's lock-up gave 569, 366 or 323 N at the lock-up by its scale, where they tend to 307 N)
    assert "before the last" in printed and "the approach to the lock-up is not resolved" in printed
    assert summary["peaks"] and all(p["t"] < cols["t"][-1] - window for p in summary["peaks"].values())
    assert summary["peaks_searched_before_s"] == pytest.approx(cols["t"][-1] - window)


def test_summary_names_samples_held_where_the_friction_self_locks():
    """The reactions summary counts the samples whose friction has no consistent solution
    (Reactions.friction_ok False), and says nothing where every one has."""
    from assurjax._peaks import Peak
    from assurjax.cli import _Along, _friction_lines

    from types import SimpleNamespace

    scene, sol = SimpleNamespace(loads=(), outputs={"reactions": ()}), SimpleNamespace(t=np.linspace(0.0, 1.0, 5), dissipated=None)
    along = lambda ok: _Along({}, np.zeros(5), np.ones(5, bool), {"A": np.ones(5)}, {"A": -np.ones(5)}, 0.0, ok)  # noqa: E731
    peaks = {"friction A": Peak("friction A", 1.0, 0.25)}
    lines = _friction_lines(scene, sol, along(np.array([True, False, False, True, True])), peaks)
    assert lines[0].startswith("  friction: 1 J lost over the motion")
    assert "self-locks the mechanism at 2 of 5 samples" in lines[-1] and "the CSV's friction_ok column" in lines[-1]
    assert not any("self-locks" in line for line in _friction_lines(scene, sol, along(np.ones(5, bool)), peaks))


def test_a_long_first_run_is_not_integrated_again_to_time_it(monkeypatch):
    # the timing line's compiled run integrated a 1e6 s motion twice (53 s, then 59 s)
    from assurjax import cli

    scene = assurjax.load_scene("roberts")
    monkeypatch.setattr(cli, "RERUN_LIMIT", -1.0)  # every run counts as long
    sol, first, second = cli._simulate(scene, 11)
    assert second is None and first > 0 and len(sol.t) >= 2
    monkeypatch.setattr(cli, "RERUN_LIMIT", 1e9)
    assert cli._simulate(scene, 11)[2] > 0
    assert cli._covered([(0.0, 2.0), (1.0, 3.0), (5.0, 6.0), (1.5, 1.75)]) == 4.0  # nested and side by side spans once


def _bundled(name):
    import importlib.resources

    return (importlib.resources.files("assurjax") / "scenes" / f"{name}.toml").read_text()


@pytest.mark.slow  # ~9 s; the default suite keeps to 10 min
def test_a_run_whose_solver_fails_exits_1_and_says_the_motion_is_not_to_be_trusted(tmp_path, capsys):
    """The slider-crank under gravity alone conserves T + V (physics). With constant steps of
    dt = 0.5 s the solver stops early (NaN ahead) after samples that break that law by
    orders of magnitude: exit status 1, the files written for inspection, and the lines say
    the motion is not to be trusted, the samples before the failure included. The same scene
    with adaptive steps reaches t1, conserves T + V and exits 0."""
    import json

    coarse = tmp_path / "coarse.toml"
    coarse.write_text(_bundled("slider_crank") + "[simulation]\ndt = 0.5\n")
    out = tmp_path / "coarse"
    assert main(["run", str(coarse), "--out", str(out), "--no-animation", "--quiet"]) == 1
    printed, err = capsys.readouterr()
    cols = read_csv(out / "solution.csv")
    assert cols["t"][-1] < 2.0  # short of t1
    assert np.max(np.abs(cols["E"] - cols["E"][0])) > 1e3 * abs(cols["E"][0])  # nothing like the conserved T + V
    assert json.loads((out / "summary.json").read_text())["solver_failed"] is True
    assert "FAILED" in printed and "not to be trusted" in printed
    assert "the samples before t = " in printed and "may be unresolved too" in printed and "(no dt in [simulation])" in printed
    assert "energy balance (of the failed run: no measure of its accuracy)" in printed
    assert err.startswith("assurjax: error: slider_crank: the solver failed at t = ") and len(err.strip().splitlines()) == 1
    # the reactions along that motion: the same failure, the same status
    assert main(["reactions", str(coarse), "--out", str(tmp_path / "rx"), "--quiet"]) == 1
    assert "not to be trusted" in capsys.readouterr().out
    fine = tmp_path / "fine"
    assert main(["run", "slider_crank", "--out", str(fine), "--no-animation", "--quiet"]) == 0
    cols = read_csv(fine / "solution.csv")
    assert cols["t"][-1] == pytest.approx(2.0) and np.max(np.abs(cols["E"] - cols["E"][0])) < 1e-6 * np.max(cols["T"])
    assert json.loads((fine / "summary.json").read_text())["solver_failed"] is False
    assert "FAILED" not in capsys.readouterr().out


def test_physical_ends_are_no_solver_failure():
    """Exit status 0 for the ends of a motion that physics gives: t1, a standstill, a
    lock-up, a user event (the solver's result is successful) and a friction jam (the
    solver's NaN ahead, ``jammed``); 1 for NaN ahead, a used-up budget."""
    from types import SimpleNamespace

    from assurjax.cli import _solver_failed

    def run(successful, jammed=False):
        return SimpleNamespace(successful=successful, jammed=jammed)

    assert not _solver_failed(run(True)) and not _solver_failed(run(False, jammed=True))
    assert _solver_failed(run(False))


STEEP_SLIDER = """
[scene]
name = "steep_slider"
gravity = [0.0, 0.0]
[ground]
O = [0.0, 0.0]
[links.crank]
points = { O = [0.0, 0.0], A = [0.1, 0.0] }
inertia = 0.001
[links.rod]
points = { A = [0.0, 0.0], B = [0.105, 0.0] }
[links.slider]
points = { B = [0.0, 0.0] }
mass = 1.0
[[formation]]
group = "crank"
link = "crank"
pivot = "O"
[[formation]]
group = "RRP"
links = ["rod", "slider"]
joints = ["A", "B"]
guide_point = "O"
direction = [1.0, 0.0]
mode = "forward"
[[loads]]
type = "drive"
value = 1.0
[[loads]]
type = "slide_friction"
pair = "slider/ground"
coefficient = 0.5
length = 0.05
[state]
q0 = 1.0
omega0 = 0.5
t1 = 0.5
"""


@pytest.mark.slow  # ~30 s: a slider-crank with friction and its jam test compiled
def test_a_run_that_jams_by_friction_exits_0(write_scene, tmp_path, capsys):
    """The crank drives the slider through a rod steeper than the friction allows: it jams
    where ex = mu |ey| (hand-solved: sin q = l / (r sqrt(1 + mu^2))), a physical end, not a
    failure of the solver."""
    import json

    out = tmp_path / "out"
    assert main(["run", str(write_scene(STEEP_SLIDER)), "--out", str(out), "--no-animation", "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"].startswith("the joint friction jams the mechanism") and summary["solver_failed"] is False
    assert summary["jammed"] is True  # a script need not read the status's words
    assert summary["q_final"] == pytest.approx(math.asin(0.105 / (0.1 * math.sqrt(1.0 + 0.5**2))), abs=1e-6)
    assert "FAILED" not in capsys.readouterr().out


@pytest.mark.slow  # ~30 s: the steep slider's run and reactions programs (test_a_run_that_jams_by_friction_exits_0's)
def test_reactions_report_no_statics_from_a_jams_state(write_scene, tmp_path, capsys):
    """The steep slider started past the angle where it jams (sin q* = l / (r sqrt(1 + mu^2)),
    q* = 1.2201; q0 = 1.25): the run stops at its start, and `reactions` reports no reactions,
    driving effort or friction from that state, where the motion has no dw/dt (it printed the
    statics of a made-up dw/dt as the values at t = 0 and as peaks); its plot says so. On the
    run from q0 = 1 to the jam, the drive is its constant 1 N m (the jam's state had put a
    peak of 1.0000048 at its time)."""
    past = write_scene(STEEP_SLIDER.replace("q0 = 1.0", "q0 = 1.25"), "past.toml")
    assert main(["reactions", str(past), "--out", str(tmp_path / "past"), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "1 sample in" in printed and "peak |F|" not in printed and "driving effort =" not in printed
    assert ("reactions, driving effort and friction: none reported: its only sample is the jam's state, where the "
            "motion has no dw/dt") in printed
    assert read_csv(tmp_path / "past" / "reactions.csv")["t"].tolist() == [0.0]
    assert main(["reactions", str(write_scene(STEEP_SLIDER)), "--out", str(tmp_path / "on"), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "driving effort: constant, +1 N m" in printed, printed


def test_kinematics_leaves_empty_cells_and_names_the_gaps_where_it_does_not_assemble(tmp_path, capsys):
    """The tangent drive: x_J = h cot q (h = 0.2 m); its guides are parallel at q = 0 and pi
    (closed form), where it does not assemble: every value of those rows is an empty cell,
    and the printed lines list those gaps instead of one range from the first to the last."""
    assert main(["kinematics", "tangent_drive", "--out", str(tmp_path), "--quiet"]) == 0
    printed = capsys.readouterr().out
    cols = read_csv(tmp_path / "kinematics.csv")
    q, ok = cols["q"], cols["ok"] == 1
    parallel = np.abs(np.sin(q)) < 1e-12
    assert parallel.sum() == 2 and np.array_equal(~ok, parallel)
    for name, values in cols.items():
        if name not in ("q", "ok"):
            assert np.all(np.isnan(values[~ok])), name
            assert np.all(np.isfinite(values[ok])), name
    np.testing.assert_allclose(cols["x_J"][ok], 0.2 / np.tan(q[ok]), rtol=1e-9)
    np.testing.assert_allclose(cols["dx_J/dq"][ok], -0.2 / np.sin(q[ok]) ** 2, rtol=1e-9)
    assert "assembles at 719 of 721 samples of q (rad)" in printed
    assert "cannot assemble for q in [0, 0], [3.14159, 3.14159]" in printed and "q from" not in printed


def test_coupler_curves_frame_the_mechanism_not_a_path_that_runs_off(tmp_path, monkeypatch):
    """The tangent drive (O = (0, 0) and H = (0, h) on the ground, h = 0.2 m, a 0.1 m crank:
    its links reach x in [-0.1, 0.1], y in [-0.1, 0.3]): over the kinematics' turn J = (h cot q, h)
    runs to h cot(pi/360) = 22.9 m beside the parallel guides. coupler_curves.png, of the
    sweep and of a run's paths, holds the mechanism's reach, a few of its sizes wide (it spanned
    46 m), and its x label says the path is cut."""
    import matplotlib.pyplot as plt

    from assurjax import cli, viz

    shown = {}
    real = cli._savefig

    def keep_axes(fig, path):
        ax = fig.axes[0]
        shown[path.name] = (ax.get_xlim(), ax.get_ylim(), ax.get_xlabel())
        return real(fig, path)

    monkeypatch.setattr(cli, "_savefig", keep_axes)
    assert main(["kinematics", "tangent_drive", "--out", str(tmp_path), "--quiet"]) == 0
    scene = assurjax.load_scene("tangent_drive")
    q = np.linspace(-np.pi / 2, 3 * np.pi / 2, 721)  # the sweep's q: the compiled kinematics again
    paths = cli._paths_figure(scene, viz.frames_from_kinematics(cli.sweep_kinematics(scene.mechanism, q)), ["J"])
    ax = paths.axes[0]
    shown["run"] = (ax.get_xlim(), ax.get_ylim(), ax.get_xlabel())
    plt.close(paths)
    for (x0, x1), (y0, y1), label in (shown["coupler_curves.png"], shown["run"]):
        assert x0 <= -0.1 and x1 >= 0.1 and y0 <= -0.1 and y1 >= 0.3
        assert x1 - x0 <= 4 * 0.4 and y1 - y0 <= 4 * 0.4
        assert "the path of J is cut at the edge: it reaches x in [-22.9, 22.9]" in label


def test_kinematics_ranges_and_drawing_take_undefined_ratios(tmp_path, monkeypatch, capsys):
    """At a singular configuration a velocity ratio is undefined (NaN): the printed ranges
    are those of the defined values (the slider-crank's rod: dtheta/dq = r cos q / (l cos phi),
    closed form, within [-1/3, 1/3]) and say how many are not; the CSV leaves those cells
    empty, and the drawing shows a sample where they are defined."""
    import equinox as eqx

    from assurjax import cli

    real = cli.sweep_kinematics

    def with_a_nan(mechanism, q, **kw):
        kin = real(mechanism, q, **kw)
        rod = np.array(kin.angular_velocities["rod"], copy=True)
        b = np.array(kin.velocities["B"], copy=True)
        k = int(np.argmin(np.abs(q - 0.5)))  # the scene's q0: the drawing's first choice
        rod[k], b[k] = np.nan, np.nan
        return eqx.tree_at(lambda k: (k.angular_velocities["rod"], k.velocities["B"]), kin, (rod, b))

    monkeypatch.setattr(cli, "sweep_kinematics", with_a_nan)
    assert main(["kinematics", "slider_crank", "--out", str(tmp_path), "--samples", "73", "--quiet"]) == 0
    printed = capsys.readouterr().out
    low, high = (float(v) for v in re.search(r"dtheta_rod/dq in \[([-0-9.e]+), ([-0-9.e]+)\]", printed).groups())
    q = np.delete(np.linspace(0.5 - np.pi, 0.5 + np.pi, 73), 36)  # the samples but the undefined one
    ratio = 0.1 * np.cos(q) / np.sqrt(0.3**2 - (0.1 * np.sin(q)) ** 2)  # |dtheta_rod/dq| up to its sign
    assert low == pytest.approx(-ratio.max(), rel=1e-3) and high == pytest.approx(ratio.max(), rel=1e-3)
    assert "undefined (NaN) at 1 sample (singular configurations)" in printed
    cols = read_csv(tmp_path / "kinematics.csv")
    assert np.isnan(cols["dtheta_rod/dq"]).sum() == 1 and np.isnan(cols["dx_B/dq"]).sum() == 1
    assert (tmp_path / "mechanism.png").stat().st_size > 0


def test_single_line_panels_carry_no_legend():
    """The driving coordinate's and velocity's panels hold one line each, named by their
    titles and axis labels: a legend there only hid part of the curve."""
    from types import SimpleNamespace

    from assurjax.cli import _history_figure

    t = np.linspace(0.0, 1.0, 11)
    sol = SimpleNamespace(t=t, q=t, omega=np.ones(11), kinetic=None, status="reached t1 = 1 s")
    fig = _history_figure(SimpleNamespace(name="x"), sol, {}, dict(q="rad", omega="rad/s"))
    q_axes, omega_axes = fig.axes[:2]
    assert q_axes.get_title() == "driving coordinate" and omega_axes.get_title() == "driving velocity"
    assert q_axes.get_legend() is None and omega_axes.get_legend() is None


# [simulation] settings that `validate` passed and `run` then refused (or ended in an internal error)
UNRUNNABLE = {
    "euler without a step": ("slider_crank", 'solver = "euler"', "solver 'euler' has no error estimate"),
    "baseline with friction": ("press_with_friction", 'solver = "seed_euler"', "has no joint friction"),
    "table with velocity loads": ("press_with_friction", 'reduction = "table"', "depend on the driving velocity"),
    "steps and dt": ("slider_crank", "steps = 100\ndt = 0.01", "steps = 100 and dt = 0.01 both set the fixed step"),
}


@pytest.mark.parametrize("case", UNRUNNABLE)
def test_validate_refuses_what_run_would_refuse(case, write_scene, capsys):
    name, settings, reason = UNRUNNABLE[case]
    path = write_scene(_bundled(name) + f"\n[simulation]\n{settings}\n")
    for command in ("validate", "run"):
        assert main([command, "--quiet", str(path)] if command == "run" else [command, str(path)]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"assurjax: error: {path}: ") and reason in err, err
        assert "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_run_takes_the_scene_fixed_steps_as_its_step(write_scene, tmp_path, capsys):
    """[simulation] steps = 200 (equal steps by lax.scan, which saves no grid of the command's
    own): run as dt = t1 / 200 over the command's output grid, which is where simulate()'s
    own steps=200 run ends (the same solver steps)."""
    import assurjax

    path = write_scene(_bundled("slider_crank").replace("t1 = 2.0", "t1 = 0.4") + "\n[simulation]\nsteps = 200\n")
    out = tmp_path / "out"
    assert main(["validate", str(path)]) == 0
    assert main(["run", str(path), "--out", str(out), "--no-animation", "--quiet", "--samples", "41"]) == 0
    text = capsys.readouterr().out
    assert "fixed steps: [simulation] steps = 200 run as equal steps of dt = 0.002 s" in text
    assert "200 solver steps tried" in text
    cols = read_csv(out / "solution.csv")
    scan = assurjax.simulate(assurjax.load_scene(str(path)))
    middle = np.flatnonzero(np.abs(cols["t"] - 0.2) < 1e-13)[0]
    for row, step in ((middle, 100), (-1, 200)):
        assert abs(cols["q"][row] - scan.q[step]) < 1e-12, (row, cols["q"][row], scan.q[step])


def test_python_dash_m_runs_the_command():
    """``python -m assurjax --help`` runs the console script's entry point (it failed with
    "No module named assurjax.__main__"): its usage names the command's subcommands."""
    done = subprocess.run([sys.executable, "-m", "assurjax", "--help"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: assurjax ") and "run" in done.stdout and "validate" in done.stdout
