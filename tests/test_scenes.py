"""Scene files: bundled scenes, defaults, the documented example, and the float32 opt-in."""

import os
import re
import subprocess
import sys
import tomllib
from importlib import resources
from pathlib import Path

import jax
import numpy as np
import pytest

import assurjax

DOC = Path(__file__).resolve().parents[1] / "docs" / "scene-format.md"


@pytest.mark.parametrize("name", assurjax.bundled_scenes())
def test_bundled_scene_loads_and_assembles_at_q0(name):
    s = assurjax.load_scene(name)
    assert s.name == name
    mech = s.mechanism
    pose = assurjax.pose_at(mech, s.state["q0"])  # raises if it cannot assemble
    assert set(s.outputs["points"]) <= set(pose.points)
    assert set(s.outputs["angles"]) <= set(mech.links)
    for link in mech.links.values():  # the bundled scenes can be simulated: every link has mass
        assert float(link.mass) > 0


def test_bundled_scene_list():
    assert {"roberts", "watt_sixbar", "slider_crank", "quick_return", "tangent_drive"} <= set(assurjax.bundled_scenes())


def test_quick_return_closed_form():
    """Arm through O4 and A; ram S on y = 0.62 at 0.2 m from R, ahead of R's foot."""
    mech = assurjax.load_scene("quick_return").mechanism
    q = np.linspace(-np.pi, np.pi, 181)
    kin = jax.tree.map(np.asarray, assurjax.kinematics(mech, q, order=0))
    A = np.stack([0.1 * np.cos(q), 0.25 + 0.1 * np.sin(q)], -1)
    arm = np.arctan2(A[:, 1], A[:, 0])
    R = 0.6 * np.stack([np.cos(arm), np.sin(arm)], -1)
    S_x = R[:, 0] + np.sqrt(0.2**2 - (0.62 - R[:, 1]) ** 2)
    np.testing.assert_allclose(kin.points["A"], A, atol=1e-13)
    np.testing.assert_allclose(np.cos(kin.angles["arm"] - arm), 1.0, atol=1e-13)
    np.testing.assert_allclose(kin.points["R"], R, atol=1e-13)
    np.testing.assert_allclose(kin.points["S"][:, 0], S_x, atol=1e-13)
    np.testing.assert_allclose(kin.points["S"][:, 1], 0.62, atol=1e-13)
    # the quick return: the ram's two strokes take unequal crank angles
    x = kin.points["S"][:, 0]
    forward = np.mean(np.diff(x) > 0)
    assert abs(forward - 0.5) > 0.1


def test_tangent_drive_closed_form():
    mech = assurjax.load_scene("tangent_drive").mechanism
    q = np.linspace(0.3, np.pi - 0.3, 101)
    kin = jax.tree.map(np.asarray, assurjax.kinematics(mech, q, 1.0, 0.0, order=1))
    np.testing.assert_allclose(kin.points["J"][:, 0], 0.2 / np.tan(q), atol=1e-13)
    np.testing.assert_allclose(kin.points["J"][:, 1], 0.2, atol=1e-13)
    np.testing.assert_allclose(kin.velocities["J"][:, 0], -0.2 / np.sin(q) ** 2, rtol=1e-12)
    with pytest.raises(assurjax.AssemblyError, match="'cross'"):
        assurjax.pose_at(mech, 0.0)  # slot parallel to the guide


def test_defaults(write_scene):
    path = write_scene(
        """
        [ground]
        O = [0.0, 0.0]

        [links.crank]
        points = { O = [0.0, 0.0], A = [0.2, 0.4] }

        [[formation]]
        group = "crank"
        link = "crank"
        pivot = "O"
        """,
        name="pendulum.toml",
    )
    s = assurjax.load_scene(path)
    assert s.name == "pendulum"  # the file's stem
    link = s.mechanism.links["crank"]
    np.testing.assert_allclose(link.com, [0.1, 0.2])  # centroid of the points
    assert float(link.mass) == 0.0 and float(link.inertia) == 0.0
    assert s.state == {"q0": 0.0, "omega0": 0.0, "t0": 0.0, "t1": 1.0}
    np.testing.assert_allclose(s.gravity, [0.0, 0.0])
    assert s.outputs["points"] == () and s.outputs["energies"] is True
    assert s.mechanism.group_names == ("driver",)


def test_settings_are_read_only_and_hashable(roberts_scene):
    with pytest.raises(TypeError):
        roberts_scene.state["q0"] = 1.0
    hash(roberts_scene.state)
    s2 = roberts_scene.with_settings(state={"q0": 1.0})
    assert s2.state["q0"] == 1.0 and roberts_scene.state["q0"] != 1.0
    for op in (lambda d: d.popitem(), lambda d: d.__ior__({"q0": 1.0})):
        with pytest.raises(TypeError):
            op(roberts_scene.state)


@pytest.mark.parametrize("name", ["press_with_friction", "watt_sixbar"])
def test_a_scene_pickles_and_copies_to_an_equal_scene(name):
    """A scene crosses process boundaries (multiprocessing, joblib) and deep-copies: the copy
    equals the original leaf by leaf, its settings are read-only again, and its static parts
    hash alike (so jit finds the program compiled for the original)."""
    import copy
    import pickle

    import equinox as eqx

    scene = assurjax.load_scene(name)
    for twin in (pickle.loads(pickle.dumps(scene)), copy.deepcopy(scene)):
        assert bool(eqx.tree_equal(twin, scene))
        assert jax.tree.structure(twin) == jax.tree.structure(scene)
        assert type(twin.simulation) is type(scene.simulation) and twin.simulation == scene.simulation
        with pytest.raises(TypeError):
            twin.simulation["rtol"] = 1.0


def documented_example() -> str:
    text = DOC.read_text()
    blocks = re.findall(r"```toml\n(.*?)```", text, flags=re.S)
    full = [b for b in blocks if "[[formation]]" in b and "[outputs]" in b]
    assert full, "docs/scene-format.md has no complete example"
    return full[0]


def test_documented_example_loads(write_scene):
    s = assurjax.load_scene(write_scene(documented_example(), name="example.toml"))
    q = np.linspace(0.0, 2 * np.pi, 13)
    kin = assurjax.kinematics(s.mechanism, q, order=1)  # assembles all the way round
    assert np.all(np.asarray(kin.ok))


@pytest.mark.parametrize("kind", ["crank", "slider", "RRR", "RRP", "PRR", "RPR", "PRP"])
def test_every_group_kind_is_documented(kind):
    assert re.search(rf"^#{{2,4}} `{kind}`", DOC.read_text(), flags=re.M), kind


FLOAT32_SCRIPT = r"""
import numpy as np, jax, assurjax
assert not jax.config.jax_enable_x64
L2, L4 = 0.18, 0.12
mech = assurjax.load_scene("roberts").mechanism
q = np.linspace(0.5, 1.5, 200)
kin = assurjax.kinematics(mech, q, order=1)
assert kin.points["P"].dtype == np.float32, kin.points["P"].dtype
# closed form in float64 (seed 001 eqs. 2-7)
U = 4 * L4 * L2 - 2 * L2**2 * np.cos(q); V = -2 * L2**2 * np.sin(q)
W = -4 * L4 * L2 * np.cos(q) + 3 * L4**2 + 2 * L2**2
t3 = 2 * np.arctan((V + np.sqrt(V**2 + U**2 - W**2)) / (U - W))
B = np.stack([-L4 + L2 * np.cos(q), L2 * np.sin(q)], -1)
C = np.stack([L4 + L2 * np.cos(t3), L2 * np.sin(t3)], -1)
t4 = np.arctan2(C[:, 1] - B[:, 1], C[:, 0] - B[:, 0])
P = (B + C) / 2 + np.sqrt(L2**2 - L4**2 / 4) * np.stack([np.sin(t4), -np.cos(t4)], -1)
err = np.abs(np.asarray(kin.points["P"], dtype=float) - P).max()
print(err)
assert err < 1e-6, err
assert np.all(np.isfinite(np.asarray(kin.velocities["P"])))
# every bundled scene loads (the press's table over exactly one turn: 2 pi in float32 rounds past
# the period 2 pi, and was refused as longer than it)
for name in assurjax.bundled_scenes():
    assurjax.load_scene(name)
"""


@pytest.mark.slow  # ~6 s, a process of its own; test_stress.py's float32 test checks the same opt-in more closely
def test_float32_opt_in():
    """ASSURJAX_FLOAT32=1 keeps JAX in float32; positions stay within 1e-6 m (~5e-6 of the
    0.18 m links) of the float64 closed form, as documented in assurjax/__init__.py."""
    env = {**os.environ, "ASSURJAX_FLOAT32": "1", "JAX_ENABLE_X64": "0"}
    out = subprocess.run([sys.executable, "-c", FLOAT32_SCRIPT], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]


def test_integer_modes_and_misspelt_required_fields():
    """docs/scene-format.md: modes 1 and -1 mean +1 and -1 (they were refused); a required
    field misspelt was reported missing without the key the table has instead."""
    raw = tomllib.loads((resources.files("assurjax.scenes") / "watt_sixbar.toml").read_text())
    named = assurjax.scene_from_dict(raw).mechanism
    for entry in raw["formation"]:
        if "mode" in entry:
            entry["mode"] = {"left": 1, "right": -1}[entry["mode"]]
    numbered = assurjax.scene_from_dict(raw).mechanism
    for a, b in zip(named.groups, numbered.groups):
        assert getattr(a, "mode", None) == getattr(b, "mode", None)
    raw["formation"][1]["mode"] = True  # a flag is no mode
    with pytest.raises(assurjax.SceneError, match="field 'mode': expected 'left'/'right'"):
        assurjax.scene_from_dict(raw)
    raw = tomllib.loads((resources.files("assurjax.scenes") / "slider_crank.toml").read_text())
    raw["loads"] = [{"type": "spring", "points": ["O", "B"], "stifness": 1.0}]
    with pytest.raises(assurjax.SceneError, match="missing field 'stiffness' \\(the table has 'stifness': misspelt\\?\\)"):
        assurjax.scene_from_dict(raw)


@pytest.mark.parametrize("kind, fields, missing, named", [
    ("slide_friction", {"joint": "slider/ground", "radius": 0.02}, "pair", "'joint' and 'radius', a joint_friction's"),
    ("slide_friction", {"pair": "slider/ground", "radius": 0.02}, "length", "'radius', a joint_friction's"),
    ("joint_friction", {"pair": "A", "length": 0.04}, "joint", "'pair' and 'length', a slide_friction's"),
])
def test_a_friction_entry_with_the_other_kinds_fields_says_so(kind, fields, missing, named):
    """A slide_friction written with a joint_friction's 'joint'/'radius' (or the converse) was
    reported only missing 'pair' / 'length', where a misspelt key gets a hint."""
    raw = tomllib.loads((resources.files("assurjax.scenes") / "slider_crank.toml").read_text())
    raw["loads"] = [{"type": kind, "coefficient": 0.1, **fields}]
    own = "'pair' and 'length'" if kind == "slide_friction" else "'joint' and 'radius'"
    with pytest.raises(assurjax.SceneError) as e:
        assurjax.scene_from_dict(raw)
    message = str(e.value)
    assert f"missing field '{missing}': a {kind} takes {own}" in message, message
    assert f"given {named}" in message, message


def test_a_scene_built_in_python_takes_numpy_numbers_tuples_and_arrays():
    # the Watt six-bar's tables with its numbers as NumPy scalars and its lists as tuples
    # and arrays give the scene its TOML file gives (they were refused: "expected a number,
    # got np.int64(1)"); a word where a number goes is still named
    plain = tomllib.loads((resources.files("assurjax.scenes") / "watt_sixbar.toml").read_text())

    def numpy_typed(value):
        if isinstance(value, dict):
            return {k: numpy_typed(v) for k, v in value.items()}
        if isinstance(value, list):
            numbers = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
            return np.asarray(value, dtype=float) if numbers and value else tuple(numpy_typed(v) for v in value)
        if isinstance(value, float) and float(np.float32(value)) == value:  # np.float64 is a float already
            return np.float32(value)
        if isinstance(value, int) and not isinstance(value, bool):
            return np.int64(value)
        return value

    typed = assurjax.scene_from_dict(numpy_typed(plain))
    reference = assurjax.scene_from_dict(plain)
    assert jax.tree.structure(typed.mechanism) == jax.tree.structure(reference.mechanism)
    for a, b in zip(jax.tree.leaves(typed.mechanism), jax.tree.leaves(reference.mechanism)):
        np.testing.assert_array_equal(a, b)
    assert typed.state == reference.state and typed.gravity.tolist() == reference.gravity.tolist()
    plain["state"]["q0"] = "fast"
    with pytest.raises(assurjax.SceneError, match="q0.*expected a number"):
        assurjax.scene_from_dict(plain)


def test_a_bundled_scene_is_found_beside_a_folder_of_its_name(tmp_path, monkeypatch):
    # `assurjax run roberts --out roberts` leaves a folder 'roberts' here; the name still
    # means the bundled scene (it said "roberts: a directory, not a scene file")
    monkeypatch.chdir(tmp_path)
    (tmp_path / "roberts").mkdir()
    assert assurjax.load_scene("roberts").name == "roberts"
    (tmp_path / "mine").mkdir()
    with pytest.raises(assurjax.SceneError, match="mine: a directory, not a scene file"):
        assurjax.load_scene("mine")
