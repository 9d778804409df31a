"""Simulation settings: one typed, validated set read by every entry point
(``simulate``, ``batch_simulate``, the differentiable results and the sensitivities),
and the diffrax objects they name."""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Iterable, Mapping
from typing import NamedTuple

import diffrax
import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array

from .._errors import AssurjaxError
from .._listing import did_you_mean
from .._positions import assembled
from .._values import MAGNITUDE_LIMIT, all_finite, concrete, found_words, value_problem
from ._packed import UNPACKED, Packing
from ._table import DEFAULT_TABLE_NODES

SOLVERS: dict[str, Callable[[], diffrax.AbstractSolver]] = {
    "tsit5": diffrax.Tsit5,
    "dopri5": diffrax.Dopri5,
    "dopri8": diffrax.Dopri8,
    "bosh3": diffrax.Bosh3,
    "heun": diffrax.Heun,
    "midpoint": diffrax.Midpoint,
    "ralston": diffrax.Ralston,
    "euler": diffrax.Euler,
}
BASELINES = ("seed_euler",)
# solvers without an embedded error estimate: the step-size controller has nothing to control
FIXED_STEP_SOLVERS = ("euler",)
# Chosen from the work-precision run (benchmarks/README.md): on the Watt six-bar, Tsit5 at
# rtol = atol = 1e-8 keeps the angle within 3.2e-7 rad of the converged motion over 2 s from
# 64 starting angles (1e-7 lets it reach 4e-6), faster than Dopri5 or Dopri8 reaching that.
DEFAULT_SOLVER = "tsit5"
DEFAULT_RTOL = 1e-8
DEFAULT_ATOL = 1e-8
# Step-size safety factor (diffrax's default 0.9): at 0.8 fewer steps are rejected; measured on
# the Watt six-bar (Tsit5 1e-8, 64 starting angles): 113 instead of 117 steps, max error 3.2e-7
# instead of 4.0e-7 rad.
CONTROLLER_SAFETY = 0.8
LOCKUP_RESOLUTION = 5e-10  # the steps closing in on a lock-up stop once they move q by less than this (1 + |q|)
DEFAULT_SAMPLES = 201
DEFAULT_MAX_STEPS = 4096

# Gradients through diffeqsolve: "recursive" (RecursiveCheckpointAdjoint, reverse mode,
# discretize-then-optimize: exact gradients of the computed solution), "forward"
# (ForwardMode: jvp / jacfwd, cheapest for few parameters), "backsolve" (BacksolveAdjoint:
# solves the adjoint ODE backwards, O(1) memory, gradients only to the solver tolerance).
ADJOINTS: dict[str, Callable[[], diffrax.AbstractAdjoint]] = {
    "recursive": diffrax.RecursiveCheckpointAdjoint,
    "forward": diffrax.ForwardMode,
    "backsolve": diffrax.BacksolveAdjoint,
}
BRANCHES = ("fixed", "tracked")
REDUCTIONS = ("exact", "table", "auto")
STOPS = ("standstill", "none")


class Settings(NamedTuple):
    """Static settings of :func:`assurjax.simulate_core` (hashable: one compile per distinct value).

    Build them with :func:`settings_from` (validated, the scene's ``[simulation]`` and
    ``[outputs]`` tables under keyword overrides) or directly for ``simulate_core``."""

    solver: str = DEFAULT_SOLVER
    rtol: float = DEFAULT_RTOL
    atol: float = DEFAULT_ATOL
    fixed_step: bool = False  # True: constant steps of the traced ``dt``; False: adaptive (PID controller)
    dt: float | None = None  # a static fixed step (s): compiles per value; prefer simulate_core's traced ``dt``
    # the longest adaptive step (s; None: no limit): where a load varies faster than the motion shows (a short pulse
    # on a mechanism held by friction, or one that the stages of a long step straddle), so that the steps sample it
    max_step: float | None = None
    max_steps: int = DEFAULT_MAX_STEPS
    standstill: bool = False
    check_assembly: bool = True
    events: tuple = ()  # user conditions cond(t, q, omega) -> real
    samples: int = DEFAULT_SAMPLES  # saved times when no saveat is given
    points: tuple[str, ...] = ()
    angles: tuple[str, ...] = ()
    energies: bool = False
    velocities: bool = False  # point, COM and link velocities along the motion (for the points, coms, angles asked)
    accelerations: bool = False  # and their accelerations
    coms: tuple[str, ...] = ()  # links whose centre-of-mass trajectories are saved
    domega: bool = True
    branch: str = "fixed"  # "tracked": carry the link angles in the state (branch continuity, see _tracking)
    adjoint: str = "recursive"  # how gradients go through diffrax: see ADJOINTS
    # "table": the RHS interpolates a ReducedTable (crank, loads of q only; see _table); "auto": simulate() chooses,
    # simulate_core takes the exact reduction
    reduction: str = "exact"
    table_nodes: int = DEFAULT_TABLE_NODES  # grid size of the table when it is built inside simulate_core
    steps: int | None = None  # fixed steps over [t0, t1] by lax.scan over the solver's own step (see _steps_solve)
    bridge: float = 0.0  # tracked branch: half-width (rad or m of q) of the bridged singular windows (BRIDGE_WINDOW); 0: off
    save_steps: bool = False  # also save the state at every accepted solver step, merged in time with the saved times
    # joint friction: at most this many solver steps per diffrax call, the segment going on in the next one (None:
    # a whole segment per call); set by simulate and batch_simulate for batches, whose members then wait for one
    # another per chunk
    segment_steps: int | None = None
    # with joint friction, slip segments end at the kinks of the law and the loads, so that derivatives see
    # them (accurate to the tolerance instead of ~its square root): where a prismatic pair's block-end load
    # changes sign (each segment freezes those signs; one more friction solve per step: the press's run 1.6x)
    # and at the knots of the loads' tables in q, t and omega; without friction a run with such tables then runs
    # in segments too (one solve otherwise). Steps across those kinks also cost the values accuracy: the press at
    # rtol 1e-8 is off by 6.5e-7 rad without the cuts, 1.2e-9 with them (at 2.1x the run time). Off by default
    # in simulate() and the sweeps, never differentiated; simulate(kink_events=True) or [simulation] kink_events
    # asks for them
    kink_events: bool = True


# [simulation] keys of a scene file and what they must be: (type check, description).
def _positive_number(v) -> bool:
    return _number(v) and v > 0


def _number(v) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(float(v))


def _positive_int(v) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool) and v > 0


# Bounds on the work a setting asks for: key -> (largest value, bytes per unit at least: the
# float64 t, q, omega of one saved state or one table node's values). Beyond them a run exhausts
# memory (steps = 1e8 asked 33 GB) or takes hours (samples = 2e6) instead of failing at once.
WORK_LIMITS: dict[str, tuple[int, int]] = {
    "samples": (100_000, 24),
    "steps": (1_000_000, 24),
    "table_nodes": (1_000_000, 32),
    "max_steps": (DEFAULT_MAX_STEPS * 2**12, 24),  # the largest default budget (step_budget)
}


SAVED_STEPS_LIMIT = WORK_LIMITS["samples"][0]  # steps a run saves with save_steps, rows like samples


def _bounded(key: str, check: Callable) -> Callable:
    return lambda v: check(v) and v <= WORK_LIMITS[key][0]


SIMULATION_KEYS: dict[str, tuple[Callable, str]] = {
    "solver": (lambda v: isinstance(v, str) and (v in SOLVERS or v in BASELINES), f"one of {sorted(SOLVERS) + list(BASELINES)}"),
    "rtol": (lambda v: _positive_number(v) and v < 1, "a positive finite number below 1"),
    "atol": (lambda v: _positive_number(v) and v < 1, "a positive finite number below 1"),
    "dt": (lambda v: _positive_number(v) and v <= 1e3, "a positive finite step (s), at most 1000"),
    "max_step": (lambda v: _positive_number(v) and v <= 1e3, "a positive finite step (s), at most 1000"),
    "max_steps": (_bounded("max_steps", _positive_int), f"a positive integer, at most {WORK_LIMITS['max_steps'][0]}"),
    "samples": (_bounded("samples", lambda v: _positive_int(v) and v >= 2), f"an integer from 2 to {WORK_LIMITS['samples'][0]}"),
    "stop": (lambda v: isinstance(v, str) and v in STOPS, f"one of {list(STOPS)}"),
    "branch": (lambda v: isinstance(v, str) and v in BRANCHES, f"one of {list(BRANCHES)}"),
    "reduction": (lambda v: isinstance(v, str) and v in REDUCTIONS, f"one of {list(REDUCTIONS)}"),
    "table_nodes": (_bounded("table_nodes", lambda v: _positive_int(v) and v >= 8), f"an integer from 8 to {WORK_LIMITS['table_nodes'][0]}"),
    "steps": (_bounded("steps", _positive_int), f"a positive integer, at most {WORK_LIMITS['steps'][0]}"),
    "save_steps": (lambda v: isinstance(v, bool), "true or false"),
    "bridge": (lambda v: _number(v) and 0 <= v <= 0.1, "a number from 0 (off) to 0.1 (rad or m of the driving coordinate)"),
    "kink_events": (lambda v: isinstance(v, bool), "true or false"),
}


def _names(v) -> bool:
    return isinstance(v, (list, tuple)) and all(isinstance(x, str) for x in v)


# [outputs] keys and what they must be (the names are checked against the mechanism by the loader).
OUTPUT_KEYS: dict[str, tuple[Callable, str]] = {
    "points": (_names, "a list of point names"),
    "angles": (_names, "a list of link names"),
    "coms": (_names, "a list of link names"),
    "reactions": (_names, "a list of joint names"),
    "energies": (lambda v: isinstance(v, bool), "true or false"),
    "velocities": (lambda v: isinstance(v, bool), "true or false"),
    "accelerations": (lambda v: isinstance(v, bool), "true or false"),
}


def setting_problem(key: str, value, schema: Mapping = SIMULATION_KEYS) -> str | None:
    """What is wrong with one setting (the same words for a scene field and a keyword), or None."""
    check, what = schema[key]
    if check(value):
        return None
    problem = f"expected {what}, got {value!r}"
    if key in WORK_LIMITS and _positive_int(value) and value > WORK_LIMITS[key][0]:
        limit, unit = WORK_LIMITS[key]
        row = {"table_nodes": "node", "samples": "sample"}.get(key, "step")
        problem += (f" (at {unit} bytes a {row} it would need at least {_size(value * unit)}; the limit allows "
                    f"{_size(limit * unit)})")
    return problem


def _size(n_bytes: float) -> str:
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if n_bytes >= scale:
            return f"{n_bytes / scale:.3g} {unit}"
    return f"{n_bytes / 1e3:.3g} kB"


def check_simulation_table(table: Mapping, where: str = "[simulation]", schema: Mapping = SIMULATION_KEYS) -> dict:
    """The ``[simulation]`` (or, with ``schema=OUTPUT_KEYS``, ``[outputs]``) table checked key
    by key; raises :class:`AssurjaxError` naming an unknown key (a typo such as ``rtoll``),
    a value of the wrong type, out of range or asking for too much work."""
    out = {}
    for key, value in table.items():
        if key not in schema:
            raise AssurjaxError(f"{where}: unknown field '{key}'{did_you_mean([key], schema)}; rename or remove it "
                                f"(known: {sorted(schema)})")
        problem = setting_problem(key, value, schema)
        if problem is not None:
            raise AssurjaxError(f"{where}, field '{key}': {problem}")
        out[key] = value
    return out


def state_problem(q0, omega0, t0, t1) -> tuple[str, str] | None:
    """(field, what is wrong) with a starting state and time span, or None: finite values of
    sane magnitude, t0 and t1 single numbers, t1 later than t0. Arrays of starts (a batch) are
    checked elementwise; tracers by their shapes only. Shared by the scene loader's [state] and
    ``simulate``'s keywords."""
    if _plain_state_ok(q0, omega0, t0, t1):  # the common case, decided without NumPy (~30 us less per call)
        return None
    for key, value, shape in (("q0", q0, None), ("omega0", omega0, None), ("t0", t0, ()), ("t1", t1, ())):
        if (problem := value_problem(value, shape=shape)) is not None:
            return key, problem
    start, end = concrete(t0), concrete(t1)
    if start is not None and end is not None and not np.all(end > start):
        return "t1", f"must be later than t0 = {t0}, got {t1}"
    return None


def check_single_start(q0, omega0, t0, t1) -> None:
    """Raise :class:`assurjax.AssurjaxError` naming a start or span of one run (not a batch of
    starts) that :func:`state_problem` rejects or that is not a single number."""
    for key, value in (("q0", q0), ("omega0", omega0)):
        if (problem := value_problem(value, shape=())) is not None:
            raise AssurjaxError(f"setting '{key}': {problem}")
    if (problem := state_problem(q0, omega0, t0, t1)) is not None:
        raise AssurjaxError(f"setting '{problem[0]}': {problem[1]}")


def _plain_state_ok(*values) -> bool:
    """True for Python numbers (not bool, not NumPy) that the checks of state_problem accept:
    finite, of magnitude at most MAGNITUDE_LIMIT, t1 > t0. False: let those checks decide."""
    if not all(type(v) in (int, float) for v in values):
        return False
    t0, t1 = values[2], values[3]
    return all(abs(v) <= MAGNITUDE_LIMIT and math.isfinite(v) for v in values) and t1 > t0


def settings_from(scene=None, **overrides) -> Settings:
    """Validated :class:`Settings` from a scene's ``[simulation]`` and ``[outputs]``
    tables (None: the defaults) under keyword overrides (None: keep the scene's).

    Keywords: the fields of :class:`Settings`, plus ``stop`` (``"standstill"`` or
    None: sets ``standstill``) and ``dt`` (a fixed step: sets ``fixed_step``; its value
    is read by :func:`fixed_step_from`, since it is traced). Every entry point reads its
    settings here, so a scene's tolerances apply to ``simulate``, ``batch_simulate``
    and the differentiable results alike."""
    sim = {} if scene is None else check_simulation_table(scene.simulation)
    outs = {} if scene is None else check_simulation_table(scene.outputs, "[outputs]", OUTPUT_KEYS)
    unknown = sorted(set(overrides) - set(Settings._fields) - {"stop"})
    if unknown:
        raise AssurjaxError(f"unknown setting(s) {unknown}; known: {sorted(set(Settings._fields) | {'stop'})}")
    stop = overrides.pop("stop", ...)
    stop = sim.get("stop", None) if stop is ... else stop
    if stop not in (None, *STOPS):
        raise AssurjaxError(f"stop must be 'standstill' or None, got {stop!r}")
    from_scene = dict(
        solver=sim.get("solver", DEFAULT_SOLVER), rtol=sim.get("rtol", DEFAULT_RTOL), atol=sim.get("atol", DEFAULT_ATOL),
        max_steps=sim.get("max_steps", DEFAULT_MAX_STEPS), samples=sim.get("samples", DEFAULT_SAMPLES),
        branch=sim.get("branch", "fixed"), reduction=sim.get("reduction", "auto"),
        table_nodes=sim.get("table_nodes", DEFAULT_TABLE_NODES), steps=sim.get("steps", None),
        save_steps=sim.get("save_steps", False), bridge=sim.get("bridge", 0.0), max_step=sim.get("max_step", None),
        fixed_step=sim.get("dt", None) is not None, standstill=stop == "standstill",
        points=tuple(outs.get("points", ())), angles=tuple(outs.get("angles", ())), energies=bool(outs.get("energies", False)),
        velocities=bool(outs.get("velocities", False)), accelerations=bool(outs.get("accelerations", False)),
        coms=tuple(outs.get("coms", ())),
    )
    dt = overrides.pop("dt", None)
    if dt is not None:  # the step itself is traced (fixed_step_from): checked when it is concrete
        if (problem := step_problem(dt)) is not None:
            raise AssurjaxError(f"setting 'dt': {problem}")
        overrides["fixed_step"] = True
    values = {**from_scene, **{k: v for k, v in overrides.items() if v is not None}}
    for key in ("points", "angles", "events", "coms"):
        if key in values:
            values[key] = _as_tuple(key, values[key])
    settings = Settings(**values)
    check(settings)
    return with_python_ints(settings)


def step_problem(dt) -> str | None:
    """What is wrong with a fixed step ``dt`` (s) given as a keyword, or None: the range of
    the scene field (SIMULATION_KEYS); a traced one is checked by its shape only."""
    if (problem := value_problem(dt, shape=())) is not None:
        return problem
    step = concrete(dt)
    return None if step is None else setting_problem("dt", float(step))


# Settings that must be Python ints: diffrax's max_steps and the shapes of arrays. A NumPy
# integer passes their checks (an integer) but not equinox's loop ("max_steps must be a
# Python integer") nor a traced comparison (TracerBoolConversionError).
INTEGER_SETTINGS = ("max_steps", "samples", "table_nodes", "steps", "segment_steps")


def with_python_ints(settings: Settings) -> Settings:
    """``settings`` with every integer setting (checked already) a Python int."""
    ints = {key: int(getattr(settings, key)) for key in INTEGER_SETTINGS if getattr(settings, key) is not None}
    return settings._replace(**ints)


def _as_tuple(key: str, value) -> tuple:
    """A keyword's names (or event functions) as a tuple: a plain string is one name, as
    ``kinematics`` takes it (``points="AB"`` split into 'A' and 'B' saved two points), and
    one function one event."""
    if isinstance(value, str) or (key == "events" and callable(value)):
        return (value,)
    what = "functions cond(t, q, omega)" if key == "events" else "names"
    if isinstance(value, (bytes, Mapping)) or not isinstance(value, Iterable):
        raise AssurjaxError(f"setting '{key}': expected a sequence of {what}, got {value!r:.60}")
    return tuple(value)


BUDGET_SPAN = 4.0  # s of motion per DEFAULT_MAX_STEPS (bundled mechanisms take ~400 steps/s at the default tolerances)


def step_budget(t0, t1) -> int:
    """The default max_steps for a time span: DEFAULT_MAX_STEPS up to BUDGET_SPAN seconds,
    doubled per doubling of the span (a power of two, so nearby horizons share a program)."""
    span = abs(float(t1) - float(t0))
    doublings = max(0, math.ceil(math.log2(max(span, 1e-300) / BUDGET_SPAN)))
    return DEFAULT_MAX_STEPS * 2 ** min(doublings, 12)


LARGEST_BUDGET = WORK_LIMITS["max_steps"][0]  # the default budget of the longest spans (step_budget)
# Steps per second of motion at the default tolerances: the slowest of the bundled mechanisms
# in motion (20 s, stop=None: Watt six-bar 54, quick-return 130, slider-crank and triad 178,
# strandbeest 217, press with friction 686; the tangent drive 4 and the class-IV scene 0.25
# barely move)
SLOWEST_STEP_RATE = 50.0
LONGEST_UNBOUNDED_SPAN = LARGEST_BUDGET / SLOWEST_STEP_RATE  # s: ~3.4e5 (about 4 days of motion)


def check_span_covered(t0, t1, settings: Settings) -> None:
    """Raise naming 't1' where a run with the default step budget (no max_steps given)
    would run to t1 with nothing to end it sooner (no standstill stop, no events) over a
    span longer than the largest default budget covers at the bundled mechanisms' step
    rates (LONGEST_UNBOUNDED_SPAN): such a span (t1 = 1e12) is most likely a mistake, and
    the run took two minutes to use up its 16.7 million steps. A given max_steps runs it."""
    span = abs(float(t1) - float(t0))
    if span <= LONGEST_UNBOUNDED_SPAN or settings.standstill or settings.events:
        return
    raise AssurjaxError(
        f"setting 't1': {span:.6g} s of motion with nothing to end it sooner (stop=None, no events) is more than the "
        f"largest default step budget ({LARGEST_BUDGET:,} steps) covers: ~{LONGEST_UNBOUNDED_SPAN:.3g} s at "
        f"{SLOWEST_STEP_RATE:g} steps/s, the slowest of the bundled mechanisms in motion; shorten the span, stop at "
        "standstill or an event, or give max_steps to run it anyway")


def check_step_within_span(dt, t0, t1) -> None:
    """Raise naming 'dt' where a fixed step (s) is longer than the span t1 - t0: the solver
    clips its one step to t1 and 'reaches t1' by a step of another length than asked (dt =
    1e6 over 0.2 s: q = -8.25 rad where the motion reaches -0.98). None (adaptive steps) and
    traced values pass."""
    step, start, end = (None if v is None else concrete(v) for v in (dt, t0, t1))
    if step is None or start is None or end is None:
        return
    span = abs(float(end) - float(start))
    if float(step) > span:
        raise AssurjaxError(f"setting 'dt': the fixed step {float(step):g} s is longer than the time span t1 - t0 = "
                            f"{span:g} s (the solver would take one step of the span instead): give a dt within "
                            "the span, small enough to resolve the motion, or adaptive steps (dt=None)")


def fixed_step_from(scene=None, dt=None):
    """The fixed step (s): ``dt`` if given, else the scene's ``[simulation] dt``, else None."""
    if dt is not None:
        return dt
    return None if scene is None else scene.simulation.get("dt", None)


def check(settings: Settings) -> None:
    """Types and ranges of every field, with errors naming the field."""
    if settings.solver not in SOLVERS and settings.solver not in BASELINES:
        raise AssurjaxError(f"unknown solver {settings.solver!r}; choose one of {sorted(SOLVERS) + list(BASELINES)}")
    if settings.solver in FIXED_STEP_SOLVERS and adaptive(settings) and settings.steps is None:
        raise AssurjaxError(f"solver {settings.solver!r} has no error estimate to choose its steps by: give a fixed step "
                            "(setting 'dt' or 'steps'), or an adaptive solver ('heun' is the lowest order with one)")
    for key in ("rtol", "atol", "max_steps", "samples", "branch", "table_nodes", "save_steps", "bridge"):
        problem = setting_problem(key, getattr(settings, key))
        if problem is not None:
            raise AssurjaxError(f"setting '{key}': {problem}")
    for key in ("fixed_step", "standstill", "check_assembly", "energies", "velocities", "accelerations", "domega",
                "kink_events"):
        if not isinstance(getattr(settings, key), (bool, np.bool_)):  # a string 'no' read as True
            raise AssurjaxError(f"setting '{key}': expected True or False, got {getattr(settings, key)!r}")
    if settings.reduction not in ("exact", "table", "auto"):
        raise AssurjaxError(f"reduction must be 'exact', 'table' or 'auto', got {settings.reduction!r}")
    if settings.bridge and settings.branch != "tracked":
        raise AssurjaxError(f"setting 'bridge' ({settings.bridge:g}) bridges singular windows of a tracked branch: it "
                            "needs branch='tracked'")
    if settings.adjoint not in ADJOINTS:
        raise AssurjaxError(f"unknown adjoint {settings.adjoint!r}; choose one of {sorted(ADJOINTS)}")
    if settings.steps is not None and (problem := setting_problem("steps", settings.steps)) is not None:
        raise AssurjaxError(f"setting 'steps': {problem}")
    if settings.max_step is not None:
        if (problem := setting_problem("max_step", settings.max_step)) is not None:
            raise AssurjaxError(f"setting 'max_step': {problem}")
        fixed = [what for what, on in (("'dt'", not adaptive(settings)), ("'steps'", settings.steps is not None),
                                       (f"the baseline solver {settings.solver!r}", settings.solver in BASELINES)) if on]
        if fixed:
            raise AssurjaxError(f"setting 'max_step' bounds the adaptive steps; with {fixed[0]} every step is fixed")
    scalar = jax.ShapeDtypeStruct((), jnp.result_type(float))
    for i, cond in enumerate(settings.events):
        if not callable(cond):
            raise AssurjaxError(f"events must be functions cond(t, q, omega), got {type(cond).__name__}")
        try:
            found = jax.eval_shape(cond, scalar, scalar, scalar).shape  # traced for its shape only
        except TypeError as e:  # not a function of (t, q, omega)
            raise AssurjaxError(f"events: each cond(t, q, omega) takes the time, the driving coordinate and its "
                                f"velocity; event #{i + 1}: {e}") from None
        if found != ():
            raise AssurjaxError(f"events: each cond(t, q, omega) must return a single number; event #{i + 1} returns {found_words(found)}")


def solver_for(settings: Settings) -> diffrax.AbstractSolver:
    if settings.solver in BASELINES:  # a single run's labelled baseline (simulate), not a diffrax solver
        raise AssurjaxError(f"solver {settings.solver!r} is a baseline that simulate() runs for one start; here "
                            f"choose one of {sorted(SOLVERS)}")
    if settings.solver not in SOLVERS:
        raise AssurjaxError(f"unknown solver {settings.solver!r}; choose one of {sorted(SOLVERS) + list(BASELINES)}")
    return SOLVERS[settings.solver]()


def adjoint_for(settings: Settings) -> diffrax.AbstractAdjoint:
    if settings.adjoint not in ADJOINTS:
        raise AssurjaxError(f"unknown adjoint {settings.adjoint!r}; choose one of {sorted(ADJOINTS)}")
    return ADJOINTS[settings.adjoint]()


def adaptive(settings: Settings) -> bool:
    """True where the PID controller chooses the steps (False: constant steps)."""
    return not (settings.fixed_step or settings.dt is not None)


def controller_for(settings: Settings, norm=None) -> diffrax.AbstractStepSizeController:
    """Constant steps, or the PID controller with the package's safety factor (every
    adaptive solve of the package, the sensitivities included, steps the same way)."""
    if not adaptive(settings):
        return diffrax.ConstantStepSize()
    kwargs = {} if norm is None else {"norm": norm}
    return diffrax.PIDController(rtol=settings.rtol, atol=settings.atol, safety=CONTROLLER_SAFETY, dtmax=settings.max_step,
                                 **kwargs)


def lockup_controller(settings: Settings, packing: Packing = UNPACKED, rebuild=None) -> diffrax.AbstractStepSizeController:
    """The step-size controller of :func:`controller_for` for the reduced link's state
    when its vector field may turn NaN (where a group cannot assemble, a friction jam, a
    load): it rejects the steps that meet NaN and closes in on where it starts
    (:class:`LockupController`, :class:`ConstantStepsUntilLockup`). ``packing``: how
    diffrax gets the state (:class:`Packing`; by default as it is); ``rebuild``: what
    rebuilds the field's arguments from diffrax's args (None: they are the arguments)."""
    if not adaptive(settings):
        return ConstantStepsUntilLockup(packing=packing, rebuild=rebuild)
    return LockupController(rtol=settings.rtol, atol=settings.atol, safety=CONTROLLER_SAFETY, dtmax=settings.max_step,
                            norm=FiniteNorm(packing), packing=packing, rebuild=rebuild)


def _met_unassembled(y1_candidate, y_error):
    """True where a step met NaN: at its end or in a stage (the error estimate holds
    them all, the last one at the step's end included). Any state: the backward solve of
    ``adjoint='backsolve'`` steps an augmented one with these controllers too."""
    return ~all_finite((y1_candidate, y_error))


def _turned_at_a_limit(t0, t1, y0, y1_candidate, args, rebuild, kept):
    """True where a step turned the driver (w changed sign) on a fixed branch with a limit
    position within the step's reach beyond the turn: a group fails to assemble at the
    turn's q (w taken linear over the step) moved on by the step's travel to and from it.
    Near a limit q* the motion approaches as q* - k (t* - t)^2, smooth in t: a step whose
    stages all stayed short of q* passed the error test, turned w round on the same branch
    and lost most of the energy (a slider-crank thrown into its limit ran on, 'reached t1',
    98 % of its kinetic energy gone, in 1-11 % of the starts of a scan). Such a step is
    rejected, and the shorter ones that follow close in on the lock-up as the steps that
    met NaN do; a turn short of the limit by more than the step's reach stands. One
    position analysis at a turn of a step the error test ``kept``; none on a tracked branch
    (it goes through the limit). ``rebuild``: see :func:`lockup_controller`. Returns (that
    flag, the step's reach: where it is below the lock-up's resolution the lock-up is found)."""
    if not hasattr(y0, "omega") or getattr(y0, "branch", None) is not None:
        return jnp.asarray(False), jnp.zeros(())
    args = args if rebuild is None else rebuild(args)
    if not getattr(args, "nan_unassembled", False):
        return jnp.asarray(False), jnp.zeros(())
    turned, probe, reach = turn_probe(t1 - t0, y0.q, y0.omega, y1_candidate.q, y1_candidate.omega)
    turned = turned & kept

    def short_of_a_limit():
        return ~jnp.all(assembled(args.model.mechanism, probe))

    return turned & jax.lax.cond(eqxi.unvmap_any(turned), short_of_a_limit, lambda: jnp.zeros_like(turned)), reach


def turn_probe(h, q0, w0, q1, w1):
    """(turned, probe, reach) of steps of length ``h`` from (q0, w0) to (q1, w1): w changed
    sign; the q where a group must assemble for the turn to stand: the turn's q (w linear
    over the step) moved on by the step's travel to and from it, ``reach``."""
    turned = w0 * w1 < 0
    peak = q0 + 0.5 * w0 * h * w0 / jnp.where(turned, w0 - w1, 1.0)
    reach = jnp.abs(peak - q0) + jnp.abs(peak - q1)
    return turned, peak + jnp.sign(w0) * reach, reach


REST_RESOLUTION = 1e-10  # s per s of t: the shortest step from rest (w = 0) that closes in on a lock-up


def _located(t0, t1, y0, met, shortest=0.0, turned=False, reach=0.0):
    """diffrax's ``dt_min_reached`` where a step that met a configuration that cannot
    assemble moves q by less than ``LOCKUP_RESOLUTION`` (1 + |q|) or is no longer than
    ``shortest``: the lock-up is found (or, if no group fails just past it, the solver
    could not get on). Not in an augmented backward solve (no q, w there): its NaN steps are only rejected."""
    if not hasattr(y0, "omega"):
        return diffrax.RESULTS.successful
    # from rest (w = 0) the steps close in on the lock-up in time: q moves by ~dw/dt h^2 / 2 there
    moving = y0.omega != 0
    small = ((moving & (jnp.abs(y0.omega) * (t1 - t0) <= LOCKUP_RESOLUTION * (1.0 + jnp.abs(y0.q))))
             | (~moving & (t1 - t0 <= REST_RESOLUTION * (1.0 + jnp.abs(t0)))) | (t1 - t0 <= shortest))
    # a step that turned at a limit (_turned_at_a_limit) by the q it travelled, to the turn and back
    small_turn = turned & ((reach <= LOCKUP_RESOLUTION * (1.0 + jnp.abs(y0.q))) | (t1 - t0 <= shortest))
    return diffrax.RESULTS.where((met & small) | small_turn, diffrax.RESULTS.dt_min_reached, diffrax.RESULTS.successful)


class LastAccepted(NamedTuple):
    """The end (``t``, ``y``) of a run's last accepted step, carried in the lock-up
    controllers' state (``SaveAt(controller_state=True)`` hands it back). Where a batch
    member's loop ended on a rejected step while another member's event fired, diffrax's
    final state of it is its dense output at the end of that rejected attempt: NaN where
    the attempt met NaN (a lock-up), and a time past the last accepted step."""

    t: Array
    y: object

    def after(self, kept, t1, y1):
        return LastAccepted(jnp.where(kept, t1, self.t), jax.tree.map(lambda new, old: jnp.where(kept, new, old), y1, self.y))


class LockupController(diffrax.PIDController):
    """A step whose stages met a configuration where some group cannot assemble (NaN) has
    an infinite error: it is rejected and the next one shrunk (diffrax's ``factormin``), so
    the steps close in on the lock-up, until one moves q by less than ``LOCKUP_RESOLUTION``
    (1 + |q|): the run ends there with ``dt_min_reached`` -- the lock-up, found by the steps
    the solver takes anyway, without a position analysis of its own. With joint friction,
    a step from rest that stays at rest (w exactly 0 at its end: the friction holds the
    mechanism, see ``_field._rates``) is rejected and ends the solve the same way, before
    any accepted step: ``_stick`` reads that as held."""

    packing: Packing = UNPACKED
    rebuild: object = None  # see lockup_controller

    def init(self, terms, t0, t1, y0, dt0, args, func, error_order):
        next_t1, state = super().init(terms, t0, t1, y0, dt0, args, func, error_order)
        return next_t1, (state, LastAccepted(jnp.asarray(t0, dtype=jnp.result_type(next_t1)), y0))

    def adapt_step_size(self, t0, t1, y0, y1_candidate, args, y_error, error_order, controller_state):
        controller_state, last = controller_state
        keep, next_t0, next_t1, jump, state, result = super().adapt_step_size(
            t0, t1, y0, y1_candidate, args, y_error, error_order, controller_state)
        packed_y1 = y1_candidate
        y0, y1_candidate = self.packing.view(y0), self.packing.view(y1_candidate)
        turned, reach = _turned_at_a_limit(t0, t1, y0, y1_candidate, args, self.rebuild, keep)
        located = _located(t0, t1, y0, _met_unassembled(y1_candidate, y_error), turned=turned, reach=reach)
        held = _held_at_rest(y0, y1_candidate)
        located = diffrax.RESULTS.where(held, diffrax.RESULTS.dt_min_reached, located)
        kept = keep & ~held & ~turned
        # a turn at a limit: this step again, halved, the controller's state as it was
        next_t0, next_t1 = jnp.where(turned, t0, next_t0), jnp.where(turned, t0 + 0.5 * (t1 - t0), next_t1)
        state = jax.tree.map(lambda new, old: jnp.where(turned, old, new), state, controller_state)
        return (kept, next_t0, next_t1, jump, (state, last.after(kept, t1, packed_y1)),
                diffrax.RESULTS.where(result == diffrax.RESULTS.successful, located, result))


def _held_at_rest(y0, y1_candidate):
    """With joint friction (its rates in the state): a step from rest that did not start."""
    if getattr(y0, "friction_rates", None) is None:
        return jnp.asarray(False)
    return (y0.omega == 0) & (y1_candidate.omega == 0)


class ConstantStepsUntilLockup(diffrax.ConstantStepSize):
    """Constant steps dt0; a step that meets a configuration where some group cannot
    assemble (NaN) is rejected and halved, then the steps go on to the next point of the
    grid, closing in on the lock-up as :class:`LockupController` does. Without error
    control the steps may find no sane motion near a limit position: halving ends 30
    times below dt0."""

    packing: Packing = UNPACKED
    rebuild: object = None  # see lockup_controller

    def init(self, terms, t0, t1, y0, dt0, args, func, error_order):
        next_t1, state = super().init(terms, t0, t1, y0, dt0, args, func, error_order)
        return next_t1, (state, LastAccepted(jnp.asarray(t0, dtype=jnp.result_type(next_t1)), y0))

    def adapt_step_size(self, t0, t1, y0, y1_candidate, args, y_error, error_order, controller_state):
        controller_state, last = controller_state
        _, _, grid_next, jump, grid_state, _ = super().adapt_step_size(
            t0, t1, y0, y1_candidate, args, y_error, error_order, controller_state)
        packed_y1 = y1_candidate
        y0, y1_candidate = self.packing.view(y0), self.packing.view(y1_candidate)
        nan = _met_unassembled(y1_candidate, y_error)
        turned, reach = _turned_at_a_limit(t0, t1, y0, y1_candidate, args, self.rebuild, ~nan)
        met = nan | turned  # a turn at a limit is halved as a NaN step
        completed, count, start, end = controller_state
        grid_here = jnp.where(completed == count, end, start + (end - start) * completed / count)  # where this step should end
        shortest = 2.0**-30 * (end - start) / count
        # on the grid up to round-off (t0 + dt0 and the grid's own sum differ by ulps: taken as
        # short, each such step was followed by one of ~1e-17 s, 25 extra steps in 100); a halved
        # step falls short by at least half its step, far more than this
        on_grid = t1 >= grid_here - 0.5 * shortest
        # kept on the grid: on to the next grid point; kept short of it (after a halving): on to this one
        next_t1 = jnp.where(met, t0 + 0.5 * (t1 - t0), jnp.where(on_grid, grid_next, grid_here))
        state = jax.tree.map(lambda new, old: jnp.where(~met & on_grid, new, old), grid_state, controller_state)
        held = _held_at_rest(y0, y1_candidate)  # as LockupController
        located = diffrax.RESULTS.where(held, diffrax.RESULTS.dt_min_reached,
                                        _located(t0, t1, y0, nan, shortest, turned=turned, reach=reach))
        kept = ~met & ~held
        return kept, jnp.where(met, t0, t1), next_t1, jump, (state, last.after(kept, t1, packed_y1)), located


class FiniteNorm(eqx.Module):
    """diffrax's RMS norm, infinite where the error is not finite (NaN stages: rejected).
    The friction elements' integrated rates (``State.friction_rates``) only mark where a
    segment ends: they do not steer the steps (mu = 0 steps as without friction).
    ``packing``: as :func:`lockup_controller`'s."""

    packing: Packing = UNPACKED

    def __call__(self, y) -> Array:
        y = self.packing.view(y)
        if getattr(y, "friction_rates", None) is not None:
            y = y._replace(friction_rates=None)
        n = optx.rms_norm(y)
        return jnp.where(jnp.isfinite(n), n, jnp.inf)
