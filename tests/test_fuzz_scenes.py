"""Hostile scene files: a seeded corpus of mutations of the bundled scenes, each run
through ``assurjax validate`` (and a few through ``assurjax run``). A bad file must end
with exit status 2 and one line naming the field at fault; a good one must succeed.
Never exit status 1 (an internal error), never a traceback, never a NaN in an output."""

from __future__ import annotations

import contextlib
import copy
import io
import json
import math
import random
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from assurjax.cli import main

SEED = 17
SCENES = sorted(p for p in resources.files("assurjax.scenes").iterdir() if p.name.endswith(".toml"))

# Values a careless or hostile file may hold where a number, string, list or table goes.
BAD_VALUES = [
    math.nan, math.inf, -math.inf, 1e300, -1e300, -1.0, 0, 0.0, 10**9, "x", ["x"], ["RRR"],
    {"n": 5}, True, [], [math.nan, 0.0], [-math.inf, 0.0], [1e300, 0.0], [0.0, 0.0],
]
# Requests of absurd work (a run would exhaust memory or never end) and wrong types in [simulation].
SIMULATION_VALUES = {
    "samples": [2_000_000, 10**12, {"n": 5}, "many", 1.5, 1],
    "steps": [10**8, [10], 0, -3, 1e8],
    "table_nodes": [10**9, "big", 4],
    "max_steps": [10**12, "many", 0],
    "dt": ["x", math.nan, -0.1, math.inf],
    "max_step": [math.nan, 0.0, -1e-3, 1e4, "short"],
    "rtol": [math.nan, 0.0, 2.0, "tight"],
    "atol": [math.inf, -1e-9],
    "solver": [["tsit5"], "rk99"],
    "stop": [5, "never"],
    "rtoll": [1e-6],  # a typo
}
# Loads added to a scene, each one valid, so that their fields can be mutated too.
LOADS = [
    {"type": "couple", "link": None, "moment": 0.5},
    {"type": "couple", "link": None, "moment": {"x": [0.0, 3.0, 6.3], "values": [0.0, 1.0, 0.0], "period": 6.283185307179586}},
    {"type": "couple", "link": None, "moment": {"polynomial": [0.1, 0.2], "variable": "omega"}},
    {"type": "rotary_damper", "joint": None, "coefficient": 0.01},
    {"type": "spring", "points": None, "stiffness": 10.0, "free_length": 0.1},
    {"type": "damper", "points": None, "coefficient": 0.5},
    {"type": "motor", "stall": 2.0, "no_load_speed": 10.0},
    {"type": "drive", "value": 0.3},
    {"type": "force", "point": None, "force": [1.0, 0.0]},
    {"type": "spring", "points": None, "links": ["", ""], "stiffness": 5.0},  # "": the default carriers
]


# ------------------------------------------------------------------ a small TOML writer


def _inline(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return {math.inf: "inf", -math.inf: "-inf"}.get(v, "nan" if math.isnan(v) else repr(v))
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_inline(x) for x in v) + "]"
    return "{ " + ", ".join(f"{json.dumps(k)} = {_inline(x)}" for k, x in v.items()) + " }"


def to_toml(data: dict) -> str:
    lines = []
    for key, value in data.items():
        if isinstance(value, dict):
            lines += [f"[{json.dumps(key)}]"] + [f"{json.dumps(k)} = {_inline(v)}" for k, v in value.items()]
        elif isinstance(value, list) and value and all(isinstance(t, dict) for t in value):
            for table in value:
                lines += [f"[[{json.dumps(key)}]]"] + [f"{json.dumps(k)} = {_inline(v)}" for k, v in table.items()]
        else:
            lines.insert(0, f"{json.dumps(key)} = {_inline(value)}")
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ the corpus


def _leaves(node, path=()):
    """Paths (tuples of keys and indices) of every value in the parsed scene."""
    yield path
    items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
    for k, v in items:
        yield from _leaves(v, (*path, k))


def _get(data, path):
    for k in path:
        data = data[k]
    return data


def _with_loads(data: dict, rng: random.Random) -> dict:
    """The scene with a few valid loads on its own links, points and joints."""
    if "links" not in data:
        return data
    links = list(data["links"])
    points = [p for link in data["links"].values() for p in link["points"]]
    shared = [p for p in points if points.count(p) > 1 or p in data.get("ground", {})]
    loads = []
    for template in rng.sample(LOADS, 3):
        load = copy.deepcopy(template)
        for key, pick in (("link", lambda: rng.choice(links)), ("joint", lambda: rng.choice(shared or points)),
                          ("point", lambda: rng.choice(points)), ("points", lambda: rng.sample(sorted(set(points)), 2))):
            if key in load:
                load[key] = pick()
        loads.append(load)
    return {**data, "loads": data.get("loads", []) + loads}


def corpus(size: int, seed: int = SEED) -> list[tuple[str, bytes, str]]:
    """(label, file bytes, the key the mutation touched) of ``size`` mutated scenes."""
    rng = random.Random(seed)
    bases = {p.name: tomllib.loads(p.read_text()) for p in SCENES}
    out = []
    while len(out) < size:
        name = rng.choice(sorted(bases))
        data = _with_loads(copy.deepcopy(bases[name]), rng) if rng.random() < 0.5 else copy.deepcopy(bases[name])
        kind = rng.choice(["value", "value", "value", "delete", "extra", "simulation", "encoding"])
        paths = [p for p in _leaves(data) if p]
        path = rng.choice(paths)
        key = next((k for k in reversed(path) if isinstance(k, str)), "")  # the field (not a list index)
        if kind == "value":
            parent = _get(data, path[:-1])
            parent[path[-1]] = copy.deepcopy(rng.choice(BAD_VALUES))
        elif kind == "delete":  # a missing key, or a list one item short
            del _get(data, path[:-1])[path[-1]]
        elif kind == "extra":
            tables = [p for p in paths if isinstance(_get(data, p), dict)]
            path = rng.choice(tables) if tables else ()
            key = "surplus"
            _get(data, path)[key] = 1.0
        elif kind == "simulation":
            key = rng.choice(sorted(SIMULATION_VALUES))
            data.setdefault("simulation", {})[key] = rng.choice(SIMULATION_VALUES[key])
        text = to_toml(data).encode()
        if kind == "encoding":  # a Latin-1 name, a UTF-16 file or a 0xFF byte in a comment
            key = "offset"
            text = rng.choice([text.replace(b'"name" = "', b'"name" = "Gr\xfcbler ', 1), text.decode().encode("utf-16"),
                               b"# \xff\xfe comment\n" + text])
        out.append((f"{name}:{kind}:{'.'.join(map(str, path))}", text, key))
    return out


def _cli(argv) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(argv)
    return status, out.getvalue(), err.getvalue()


def _check_rejection(label: str, status: int, err: str, path: Path, key: str) -> None:
    # 1: a run whose solver did not finish (its files written, its failure said in words)
    assert status in (0, 1, 2), f"{label}: exit status {status}: {err}"
    if status == 1:
        assert "Traceback" not in err and "internal error" not in err, f"{label}: {err}"
    if status == 2:
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("assurjax: error: "), f"{label}: {err}"
        assert "Traceback" not in err and "internal error" not in err, f"{label}: {err}"
        # a scene error names the file; an assembly error (validate assembles at q0) the group
        assert str(path) in err or "group '" in err, f"{label}: the message names neither file nor group: {err}"


# ------------------------------------------------------------------ validate: the whole corpus


@pytest.mark.parametrize("size", [200, pytest.param(600, marks=pytest.mark.slow)])
def test_validate_rejects_every_bad_scene_in_words(tmp_path, size):
    """``validate`` on a hostile corpus of mutated scenes (the first 200 by default, 600 in the slow suite)."""
    mutants = corpus(size)
    statuses = []
    named = 0
    for i, (label, text, key) in enumerate(mutants):
        path = tmp_path / f"m{i}.toml"
        path.write_bytes(text)
        status, _, err = _cli(["validate", str(path)])
        _check_rejection(label, status, err, path, key)
        statuses.append(status)
        named += status == 2 and (key in err or "group '" in err)
    rejected = statuses.count(2)
    # the corpus is hostile: most mutants are bad, and the messages name the field mutated
    assert rejected > len(mutants) // 2, f"only {rejected} of {len(mutants)} rejected"
    assert named > 0.8 * rejected, f"only {named} of {rejected} rejections name the field mutated"


def test_non_utf8_names_the_byte_offset(tmp_path):
    path = tmp_path / "latin1.toml"
    text = (resources.files("assurjax.scenes") / "slider_crank.toml").read_bytes()
    bad = text.replace(b'name = "slider_crank"', b'name = "Gr\xfcbler"')
    path.write_bytes(bad)
    status, _, err = _cli(["validate", str(path)])
    assert status == 2
    offset = bad.index(b"\xfc")
    assert f"offset {offset}" in err and "0xfc" in err and "UTF-8" in err


# ------------------------------------------------------------------ run: one scene, one compiled program


RUN_BASE = "slider_crank.toml"
# Mutations of numbers only (same structure, so one compiled program serves all); each either
# rejected at load or giving a finite result.
RUN_MUTATIONS = [
    ("links", "rod", "mass", math.inf),
    ("links", "rod", "com", [1e300, 0.0]),
    ("links", "crank", "inertia", -1.0),
    ("ground", "O", [-math.inf, 0.0]),
    ("scene", "gravity", [0.0, -math.inf]),
    ("state", "omega0", 1e300),
    ("state", "t0", math.nan),
    ("links", "rod", "mass", 2.0),  # a good one: runs
    ("state", "omega0", 3.0),  # a good one
]


def _run_mutant(tmp_path, i, path_and_value, t1=0.05):
    data = tomllib.loads((resources.files("assurjax.scenes") / RUN_BASE).read_text())
    data["state"]["t1"] = t1
    *where, key, value = path_and_value
    _get(data, tuple(where))[key] = value
    path = tmp_path / f"run{i}.toml"
    path.write_text(to_toml(data))
    out = tmp_path / f"out{i}"
    status, _, err = _cli(["run", str(path), "--out", str(out), "--no-animation"])
    _check_rejection(str(path_and_value), status, err, path, key)
    if status == 0:
        summary = json.loads((out / "summary.json").read_text())
        csv = np.genfromtxt(out / "solution.csv", delimiter=",", skip_header=1)
        assert np.all(np.isfinite(csv)), f"{path_and_value}: non-finite values in solution.csv"
        assert "nan" not in json.dumps(summary).lower() and "infinity" not in json.dumps(summary).lower()
    return status


def test_run_mutants_reject_or_finish_finite(tmp_path):
    statuses = [_run_mutant(tmp_path, i, m) for i, m in enumerate(RUN_MUTATIONS)]
    assert statuses == [2] * 7 + [0, 0]


@pytest.mark.slow
def test_run_corpus(tmp_path):
    """Every kind of mutation of the corpus through ``run`` (a compile per structure: slow)."""
    for i, (label, text, key) in enumerate(corpus(60, seed=SEED + 1)):
        path = tmp_path / f"m{i}.toml"
        path.write_bytes(text)
        out = tmp_path / f"out{i}"
        status, _, err = _cli(["run", str(path), "--out", str(out), "--no-animation"])
        _check_rejection(label, status, err, path, key)
        if status == 0:
            csv = np.genfromtxt(out / "solution.csv", delimiter=",", skip_header=1)
            assert np.all(np.isfinite(csv)), f"{label}: non-finite values in solution.csv"


def test_run_says_in_words_when_the_step_budget_is_used_up(tmp_path):
    data = tomllib.loads((resources.files("assurjax.scenes") / RUN_BASE).read_text())
    data["state"].update(t1=0.05, omega0=3.0)
    data["simulation"] = {"max_steps": 3}  # far fewer than 0.05 s at rtol 1e-8 takes
    path = tmp_path / "budget.toml"
    path.write_text(to_toml(data))
    status, out, err = _cli(["run", str(path), "--out", str(tmp_path / "out"), "--no-animation"])
    assert status == 1, err  # the run did not finish: a failure, its files written
    first = out.splitlines()[0]
    assert "step budget" in first and "max_steps = 3" in first, out
