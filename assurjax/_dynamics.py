"""Forward dynamics of the reduced link (seed 000, steps ii-v), integrated with diffrax.

The state is y = (q, w) (plus the dissipated work when energies are asked for
and some load dissipates):

    dq/dt = w,
    dw/dt = (tau + tau_red - 0.5 dJ_red/dq w^2) / J_red,

the time form of seed 000 eq. 1, d/dq (J_red w^2 / 2) = tau + tau_red. Every
right-hand-side evaluation redoes the reduction at (q, w, t), so velocity-dependent
loads are updated at every stage (the seed's step v); when no load depends on
velocity the velocity part is never built.
With ``reduction="table"`` (crank drivers, loads of q only) the right-hand side
interpolates a :class:`assurjax.ReducedTable` sampled once per crank turn instead
(see ``_table``); outputs are still computed with the exact analysis.

Events (diffrax.Event, located by an optimistix root finder on the dense output):
standstill (w crosses 0 against the direction of motion), a group that can no
longer assemble, and user conditions ``cond(t, q, omega)`` (stop when they change sign).

The seed's own scheme (Euler in q, eq. 2) is :func:`simulate_seed_euler`, a labelled
baseline for benchmarks.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array

from ._errors import AssurjaxError
from ._jit import checks_without_callbacks, jit
from ._loads import Damper, RotaryDamper, check_loads, dissipated_power, potential_energy
from ._mechanism import Mechanism, positions
from ._reduction import reduce_single, reduce_with_kinematics, reduce_with_pose
from ._table import DEFAULT_TABLE_NODES, ReducedTable, build_table, build_table_core
from ._tracking import branch_angles, branch_rates, branch_state

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
DEFAULT_SAMPLES = 201
DEFAULT_MAX_STEPS = 4096

_TINY = 1e-30
# Event codes in Solution.event.
NO_EVENT, STANDSTILL, LOCKUP, USER = -1, 0, 1, 2


class Settings(NamedTuple):
    """Static settings of :func:`simulate_core` (hashable: one compile per distinct value)."""

    solver: str = DEFAULT_SOLVER
    rtol: float = DEFAULT_RTOL
    atol: float = DEFAULT_ATOL
    fixed_step: bool = False  # True: constant steps of the traced ``dt``; False: adaptive (PID controller)
    dt: float | None = None  # a static fixed step (s): compiles per value; prefer simulate_core's traced ``dt``
    max_steps: int = DEFAULT_MAX_STEPS
    standstill: bool = False
    check_assembly: bool = True
    events: tuple = ()  # user conditions cond(t, q, omega) -> real
    samples: int = DEFAULT_SAMPLES  # saved times when no saveat is given
    points: tuple[str, ...] = ()
    angles: tuple[str, ...] = ()
    energies: bool = False
    domega: bool = True
    branch: str = "fixed"  # "tracked": carry the link angles in the state (branch continuity, see _tracking)
    adjoint: str = "recursive"  # how gradients go through diffrax: see ADJOINTS
    reduction: str = "exact"  # "table": the RHS interpolates a ReducedTable (crank, loads of q only; see _table)
    table_nodes: int = DEFAULT_TABLE_NODES  # grid size of the table when it is built inside simulate_core
    steps: int | None = None  # fixed steps over [t0, t1] by lax.scan over the solver's own step (see _steps_solve)


class Solution(eqx.Module):
    """A simulated motion of the reduced link and what the outputs asked for.

    ``t`` (s), ``q`` (rad or m), ``omega`` (rad/s or m/s), ``domega`` (dw/dt) at the
    saved times. ``kinetic``, ``potential``, ``total`` (J): energies (None unless
    asked); ``dissipated`` (J): work removed by dampers since t0 (None without
    dampers). ``points``: name -> (n, 2) trajectories (m); ``angles``: link -> (n,) (rad).
    ``t_stop``: time (s) at which a stop event fired (None when none did; under
    jit/vmap an array, +inf when none did). ``event``: -1 none, 0 standstill, 1 a group
    can no longer assemble (``failed_group`` names it), 2 + k the k-th user event.
    ``valid``: the saved times reached, then the final state (at ``t_final``); the
    entries after it repeat the final state (under jit/vmap only; :func:`simulate`
    trims them). ``result``: diffrax result code
    (0 successful); ``status`` a readable summary.
    """

    t: Array
    q: Array
    omega: Array
    domega: Array | None
    kinetic: Array | None
    potential: Array | None
    total: Array | None
    dissipated: Array | None
    points: dict[str, Array]
    angles: dict[str, Array]
    valid: Array
    t_final: Array
    q_final: Array
    omega_final: Array
    t_stop: Any
    event: Array
    failed_group_index: Array
    result: Array
    num_steps: Array
    failed_group: str | None = eqx.field(static=True, default=None)
    status: str = eqx.field(static=True, default="")


# ---------------------------------------------------------------------------- right-hand side


def _dissipative(loads) -> bool:
    return any(isinstance(load, (Damper, RotaryDamper)) for load in loads)


def _rhs(t, y, args):
    """(dq/dt, dw/dt[, dW_diss/dt]) at (t, y): the reduced equation of motion."""
    mechanism, gravity, loads, track_work = args
    loads = () if loads is None else loads  # see _solver_args
    q, w = y[0], y[1]
    near = branch_state(y)
    # One position analysis per evaluation: the dampers' power reads the same kinematics
    # (track_work implies a damper, so the velocities are built).
    red, kin = reduce_with_kinematics(mechanism, gravity, loads, q, w, t, near=near)
    out = (w, red.acceleration(w)) + ((dissipated_power(mechanism, loads, kin),) if track_work else ())
    return out if near is None else out + (branch_rates(red, near, w),)


def _solver_args(args):
    """The args as given to diffeqsolve: empty tuples (no loads, no user events) become None,
    since diffrax.BacksolveAdjoint cannot take an empty tuple inside its args."""
    return tuple(None if isinstance(a, tuple) and not a else a for a in args)


def _rhs_table(t, y, args):
    """(dq/dt, dw/dt) from the tabulated reduction only (no position analysis)."""
    return y[1], args[-1].acceleration(y[0], y[1])


# ---------------------------------------------------------------------------- events


def _margins(settings: Settings, t, y, args, lockup=None) -> list:
    """One margin per enabled stop condition, positive until that condition fires.

    standstill: w times the direction of motion, the sign of w0, or from rest the
    displacement q - q0 (0 at the start, > 0 while moving, < 0 once w has reversed:
    no force evaluation at t0 is needed to know which way the mechanism starts);
    assembly: +1 while every group assembles, -1 once one cannot; user events:
    cond(t, q, w) times its sign at t0. ``lockup``: the assembly margin when already
    known (then no position analysis here).
    """
    mechanism, (direction, q0), user_signs = args[0], args[4], args[5]
    out = []
    if settings.standstill:
        out.append(y[1] * jnp.where(direction != 0, direction, y[0] - q0))
    if settings.check_assembly:
        if lockup is None:
            lockup = jnp.where(jnp.all(positions(mechanism, y[0], near=branch_state(y)).ok), 1.0, -_TINY)
        out.append(lockup)
    for k, cond in enumerate(settings.events):
        out.append(user_signs[k] * jnp.asarray(cond(t, y[0], y[1]), dtype=float))
    return out


def _event_codes(settings: Settings) -> tuple[int, ...]:
    codes = [STANDSTILL] if settings.standstill else []
    codes += [LOCKUP] if settings.check_assembly else []
    return tuple(codes + [USER + k for k in range(len(settings.events))])


def _event(settings: Settings):
    """One diffrax.Event on the smallest margin (down-crossing), located by bisection
    on the dense output: the assembly margin is a step, and bisection needs no
    right-hand-side evaluations."""
    if not _event_codes(settings):
        return None

    def cond_fn(t, y, args, **kwargs):
        # Clipped at a tiny positive value: the bisection's |f| < atol test then holds
        # on both sides of a step (the assembly margin), and the root is the first crossing.
        return jnp.minimum(jnp.min(jnp.stack(_margins(settings, t, y, args))), _TINY)

    tol = min(1e-3 * settings.rtol, 1e-12)
    return diffrax.Event(cond_fn, optx.Bisection(rtol=tol, atol=tol, flip=True), direction=False)


# ---------------------------------------------------------------------------- core


def _solver(settings: Settings):
    if settings.solver not in SOLVERS:
        raise AssurjaxError(f"unknown solver {settings.solver!r}; choose one of {sorted(SOLVERS) + list(BASELINES)}")
    return SOLVERS[settings.solver]()


# Gradients through diffeqsolve: "recursive" (RecursiveCheckpointAdjoint, reverse mode,
# discretize-then-optimize: exact gradients of the computed solution), "forward"
# (ForwardMode: jvp / jacfwd, cheapest for few parameters), "backsolve" (BacksolveAdjoint:
# solves the adjoint ODE backwards, O(1) memory, gradients only to the solver tolerance).
ADJOINTS: dict[str, Callable[[], diffrax.AbstractAdjoint]] = {
    "recursive": diffrax.RecursiveCheckpointAdjoint,
    "forward": diffrax.ForwardMode,
    "backsolve": diffrax.BacksolveAdjoint,
}


def _adjoint(settings: Settings):
    if settings.adjoint not in ADJOINTS:
        raise AssurjaxError(f"unknown adjoint {settings.adjoint!r}; choose one of {sorted(ADJOINTS)}")
    return ADJOINTS[settings.adjoint]()


def _controller(settings: Settings):
    if settings.fixed_step or settings.dt is not None:
        return diffrax.ConstantStepSize()
    return diffrax.PIDController(rtol=settings.rtol, atol=settings.atol, safety=CONTROLLER_SAFETY)


def _initial_step(settings, dt):
    """The fixed step, or the controller's first step (None: diffrax's automatic choice,
    two right-hand-side evaluations; a small guess costs more steps to grow)."""
    if dt is None:
        dt = settings.dt
    if dt is not None:
        return jnp.asarray(dt, dtype=float)
    if settings.fixed_step:
        raise AssurjaxError("fixed_step needs a step dt")
    return None


def simulate_core(mechanism: Mechanism, gravity, loads, q0, omega0, t0, t1, ts=None, dt=None, *, settings: Settings = Settings(),
                  table: ReducedTable | None = None) -> Solution:
    """The pure, jittable simulation (no Python-side checks or trimming).

    ``q0``, ``omega0``, ``t0``, ``t1`` and the arrays inside ``mechanism`` and
    ``loads`` may be traced (vmap over them with ``eqx.filter_vmap``); ``settings``
    is static. ``ts``: save times (default ``settings.samples`` times from t0 to t1).
    ``dt``: the step (s) when ``settings.fixed_step`` (traced: a step-size sweep
    compiles once); else an optional initial step.

    ``settings.reduction == "table"``: the right-hand side interpolates ``table`` (a
    :class:`ReducedTable`; None: built here from ``settings.table_nodes`` nodes, traced,
    so differentiable in the mechanism's arrays but without the host-side checks of
    :func:`build_table`). For a batch over q0 pass one table built outside the vmap.
    Outputs are then computed from the saved (q, w) with the exact analysis, and the
    assembly event is off (the table checked a full turn).

    **Example** (10 starting angles at once):
    >>> core = assurjax.jit(eqx.filter_vmap(
    ...     lambda q0: assurjax.simulate_core(mech, gravity, (), q0, 0.0, 0.0, 2.0,
    ...                                       settings=assurjax.SimulationSettings(samples=2))))
    >>> sols = core(jnp.linspace(0.0, 1.0, 10))
    """
    q0, omega0, t0, t1 = (jnp.asarray(v, dtype=float) for v in (q0, omega0, t0, t1))
    tabulated = _check_reduction(settings)
    if tabulated:
        settings = settings._replace(check_assembly=False)
        table = build_table_core(mechanism, gravity, loads, settings.table_nodes) if table is None else table
    if settings.steps is not None:
        return _steps_solve(mechanism, gravity, loads, q0, omega0, t0, t1, settings, table)
    if ts is None:
        ts = jnp.linspace(t0, t1, settings.samples)
    ts = jnp.asarray(ts, dtype=float)
    track_work = settings.energies and _dissipative(loads)
    y0 = (q0, omega0, jnp.zeros(())) if track_work else (q0, omega0)
    if settings.branch == "tracked":  # the branch travels with the state, starting on the fixed modes
        y0 = y0 + (branch_angles(mechanism, positions(mechanism, q0)),)
    user_signs = tuple(jnp.sign(jnp.asarray(c(t0, q0, omega0), dtype=float)) for c in settings.events)
    args = (mechanism, gravity, loads, track_work, (jnp.sign(omega0), q0), user_signs) + ((table,) if tabulated else ())
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(_rhs_table if tabulated else (lambda t, y, a: _rhs(t, y, a[:4]))),
        _solver(settings),
        t0=t0,
        t1=t1,
        dt0=_initial_step(settings, dt),
        y0=y0,
        args=_solver_args(args),
        saveat=diffrax.SaveAt(ts=ts, t1=True),
        stepsize_controller=_controller(settings),
        event=_event(settings),
        max_steps=settings.max_steps,
        adjoint=_adjoint(settings),
        throw=False,
    )
    return _package(mechanism, gravity, loads, sol, ts, args, settings, track_work)


def _steps_solve(mechanism, gravity, loads, q0, omega0, t0, t1, settings: Settings, table) -> Solution:
    """``settings.steps`` equal steps of the diffrax solver from t0 to t1, by
    ``jax.lax.scan`` over the solver's own ``step`` (no step-size controller, no
    event root finding, no dense output): the leanest use of diffrax for this
    two-state ODE, whose adaptive loop costs more per step than a tabulated
    right-hand side. Saves every step (``dissipated`` stays None). Without a table, a
    step any of whose stages meets a configuration that cannot assemble ends the valid
    samples before it (event 1, located to the step, not by root finding): with the
    fixed mode, stepping over a limit position would otherwise bounce back unphysically."""
    _check_steps(settings)
    tabulated = table is not None
    term = diffrax.ODETerm(_rhs_table if tabulated else (_rhs_or_nan if settings.check_assembly else _rhs))
    args = (None, None, None, None, None, None, table) if tabulated else (mechanism, gravity, loads, False)
    solver = _solver(settings)
    h = (t1 - t0) / settings.steps
    y0 = (q0, omega0)

    def step(carry, k):
        y, state = carry
        t = t0 + k * h
        y1, _, _, state, _ = solver.step(term, t, t + h, y, args, state, False)
        return (y1, state), y1

    _, (q, w) = jax.lax.scan(step, (y0, solver.init(term, t0, t0 + h, y0, args)), jnp.arange(settings.steps))
    t = t0 + h * jnp.arange(settings.steps + 1)
    q, w = jnp.concatenate([q0[None], q]), jnp.concatenate([omega0[None], w])
    n = settings.steps
    if tabulated or not settings.check_assembly:  # nothing can fail (the table checked a full turn)
        valid, last, locked, failed = jnp.ones(n + 1, dtype=bool), n, jnp.asarray(False), jnp.asarray(-1)
    else:  # a NaN marks a step that met a configuration that cannot assemble
        assembled = jnp.isfinite(q) & jnp.isfinite(w)
        locked = ~jnp.all(assembled)
        last = jnp.where(locked, jnp.argmin(assembled) - 1, n)  # the last sample before it
        valid = jnp.arange(n + 1) <= last
        t, q, w = (jnp.where(valid, x, x[last]) for x in (t, q, w))
        ahead = positions(mechanism, q[last] + h * w[last]).ok  # the group failing one step on
        failed = jnp.where(locked & ~jnp.all(ahead), jnp.argmin(ahead), -1)
    outputs = _outputs(mechanism, gravity, loads, t, q, w, settings)
    return Solution(
        t=t, q=q, omega=w, **outputs, dissipated=None, valid=valid,
        t_final=t[last], q_final=q[last], omega_final=w[last],
        t_stop=jnp.where(locked, t[last], jnp.inf), event=jnp.where(locked, LOCKUP, NO_EVENT),
        failed_group_index=failed, result=jnp.asarray(0), num_steps=jnp.asarray(n),
    )


def _rhs_or_nan(t, y, args):
    """(dq/dt, dw/dt), with dw/dt NaN where a group cannot assemble (fixed steps)."""
    mechanism, gravity, loads, _ = args
    red, _ = reduce_with_kinematics(mechanism, gravity, loads, y[0], y[1], t)
    return y[1], jnp.where(jnp.all(red.ok), red.acceleration(y[1]), jnp.nan)


def _check_steps(settings: Settings) -> None:
    if int(settings.steps) < 1:
        raise AssurjaxError(f"steps must be a positive number of steps, got {settings.steps}")
    if settings.standstill or settings.events:
        raise AssurjaxError("steps= integrates with fixed steps and locates no events: use stop=None and no events, "
                            "or the adaptive solver (steps=None) for stop='standstill' and user events")
    if settings.branch == "tracked":
        raise AssurjaxError("steps= needs branch='fixed' (a tracked branch travels in the adaptive solver's state)")


def _check_reduction(settings: Settings) -> bool:
    """True in table mode; clear errors for unknown modes and unsupported combinations."""
    if settings.reduction not in ("exact", "table", "auto"):
        raise AssurjaxError(f"reduction must be 'exact', 'table' or 'auto', got {settings.reduction!r}")
    if settings.reduction == "auto":
        raise AssurjaxError("reduction='auto' is resolved by simulate(); simulate_core takes 'exact' or 'table'")
    if settings.reduction == "table" and settings.branch == "tracked":
        raise AssurjaxError("reduction='table' needs branch='fixed' (the table is sampled on the scene's assembly modes)")
    return settings.reduction == "table"


def _package(mechanism, gravity, loads, sol, ts, args, settings, track_work) -> Solution:
    # diffrax writes the final state right after the saved times reached (an event
    # deletes those past it) and pads with inf.
    last = jnp.sum(jnp.isfinite(sol.ts)) - 1
    t_final, q_final, w_final = sol.ts[last], sol.ys[0][last], sol.ys[1][last]
    # The times reached, then the final state itself (an event stops between two
    # saved times); the rest repeat the final state, so every output stays finite.
    valid = jnp.arange(ts.shape[0]) <= last
    reached = jnp.arange(ts.shape[0]) < last
    q = jnp.where(reached, sol.ys[0][:-1], q_final)
    w = jnp.where(reached, sol.ys[1][:-1], w_final)
    t = jnp.where(reached, ts, t_final)
    near = branch_state(sol.ys)  # saved link angles (tracked branch) or None
    near_final = None if near is None else jax.tree.map(lambda z: z[last], near)
    near = None if near is None else jax.tree.map(lambda z: jnp.where(reached, z[:-1], z[last]), near)
    ok_final = _assembles(mechanism, q_final, w_final, near_final) if settings.check_assembly else None
    event = _which_event(sol, settings, args, last, ok_final)
    outputs = _outputs(mechanism, gravity, loads, t, q, w, settings, near)
    dissipated = None
    if track_work:
        work = sol.ys[2]
        dissipated = jnp.where(reached, work[:-1], work[last])
    failed = jnp.asarray(-1) if ok_final is None else jnp.where((event == LOCKUP) & ~jnp.all(ok_final), jnp.argmin(ok_final), -1)
    return Solution(
        t=t, q=q, omega=w, **outputs, dissipated=dissipated, valid=valid,
        t_final=t_final, q_final=q_final, omega_final=w_final,
        t_stop=jnp.where(event >= 0, t_final, jnp.inf), event=event, failed_group_index=failed,
        result=jnp.asarray(sol.result._value), num_steps=sol.stats["num_steps"],
    )


def _which_event(sol, settings, args, last, ok_final):
    """The code of the stop condition that fired (the smallest margin at the stop), or -1.
    The assembly condition is read at and just past the final state, since bisection
    may leave that state on the assembled side."""
    codes = _event_codes(settings)
    if not codes:
        return jnp.asarray(NO_EVENT)
    y_final = jax.tree.map(lambda y: y[last], sol.ys)
    lockup = jnp.where(jnp.all(ok_final), 1.0, -1.0) if settings.check_assembly else None
    margins = _margins(settings, sol.ts[last], y_final, args, lockup)
    return jnp.where(sol.event_mask, jnp.asarray(codes)[jnp.argmin(jnp.stack(margins))], NO_EVENT)


def _assembles(mechanism, q_final, w_final, near=None):
    """Per group: assembled at the final state and just past it (in the direction of motion)."""
    nudge = 1e-9 * (1.0 + jnp.abs(q_final)) * jnp.sign(w_final)
    return positions(mechanism, q_final + nudge, near=near).ok & positions(mechanism, q_final, near=near).ok


def _outputs(mechanism, gravity, loads, t, q, w, settings, near=None) -> dict:
    """Only what the settings ask for: dw/dt, energies, point trajectories, link angles.
    ``near``: saved link angles of a tracked branch (None: the fixed modes).
    One vmapped evaluation per saved time: the reduction gives dw/dt and J_red
    (T = J_red w^2 / 2), its position analysis gives points, angles and V."""
    out = dict(domega=None, kinetic=None, potential=None, total=None, points={}, angles={})
    if not (settings.domega or settings.energies or settings.points or settings.angles):
        return out

    def sample(t, q, w, z):
        values = {}
        if settings.domega or settings.energies:
            red, pose = reduce_with_pose(mechanism, gravity, loads, q, w, t, near=z)
            if settings.domega:
                values["domega"] = red.acceleration(w)
            if settings.energies:
                values["kinetic"] = 0.5 * red.inertia * w**2
                values["potential"] = potential_energy(mechanism, gravity, loads, pose)
        elif settings.angles:  # angles of any link: the full position analysis
            pose = positions(mechanism, q, near=z)
        else:  # only the groups the points need
            pose = positions(mechanism, q, points=settings.points, near=z)
        values["points"] = {p: pose.points[p] for p in settings.points}
        values["angles"] = {a: pose.angles[a] for a in settings.angles}
        return values

    out.update(jax.vmap(sample)(t, q, w, near))
    if settings.energies:
        out["total"] = out["kinetic"] + out["potential"]
    return out


_simulate_jit = jit(simulate_core)


# ---------------------------------------------------------------------------- user-facing


def simulate(
    scene,
    *,
    q0=None,
    omega0=None,
    t0=None,
    t1=None,
    saveat=None,
    stop: str | None | type(...) = ...,
    solver: str | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    dt: float | None = None,
    max_steps: int | None = None,
    samples: int | None = None,
    events: Sequence[Callable] = (),
    check_assembly: bool = True,
    mechanism: Mechanism | None = None,
    loads=None,
    gravity=None,
    points: Sequence[str] | None = None,
    angles: Sequence[str] | None = None,
    energies: bool | None = None,
    branch: str | None = None,
    reduction: str | None = None,
    table_nodes: int | None = None,
    table: ReducedTable | None = None,
    steps: int | None = None,
) -> Solution:
    """Simulate a scene's motion from its initial state (seed 000's forward dynamics).

    Keyword arguments override the scene: ``q0`` (rad or m), ``omega0`` (rad/s or
    m/s), ``t0``, ``t1`` (s) from ``[state]``; ``stop`` (``"standstill"`` or None),
    ``solver`` (``"tsit5"`` default, ``"dopri5"``, ``"dopri8"``, ..., or the baseline
    ``"seed_euler"``), ``rtol``, ``atol`` (default 1e-8: errors below 1e-6 rad over seconds
    of motion; pass 1e-10 or tighter for reference-quality runs), ``dt`` (a fixed step, s), ``max_steps``,
    ``samples`` from ``[simulation]``; ``points``, ``angles``, ``energies`` from
    ``[outputs]``. ``branch``: ``"fixed"`` (default: the scene's assembly modes) or
    ``"tracked"``: the link angles travel in the ODE state (d theta/dt = d theta/dq w,
    from the same jvp) and every group takes the root nearest to them, which keeps
    the motion on one continuous branch through singular configurations (e.g. the
    N-four-bar's). ``reduction``: ``"exact"`` (the reduction at every right-hand
    side), ``"table"``: a :class:`ReducedTable` of ``table_nodes`` (default 4096)
    nodes over one crank turn is built and checked first, and the right-hand side
    interpolates it (crank drivers, loads of q only; see :func:`build_table`), or
    ``"auto"`` (default): the table for a batch of at least AUTO_TABLE_BATCH starting
    states when the scene allows one (its build then costs less than the exact
    reduction saves), else exact. ``table``: a prebuilt :class:`ReducedTable` to use.
    ``steps``: integrate with that many equal steps by ``jax.lax.scan`` over the
    solver's own step (no step-size control, no events: ``stop`` must be None; saves
    every step) -- the fastest path for short runs: with a table, ``steps=80``
    (Tsit5) keeps the Watt six-bar within 4e-9 rad over 1 s in ~60 us.
    ``saveat``: an array of times (s). ``events``: functions ``cond(t, q, omega)``;
    the motion stops where one changes sign. ``mechanism``, ``loads``, ``gravity``
    replace the scene's.

    ``q0`` and ``omega0`` may be 1-D arrays (broadcast together): then all starting
    states are simulated at once (vmapped) and the :class:`Solution` has a leading
    batch axis, untrimmed (read ``valid``; ``t_stop`` is +inf where no event fired).

    Returns a :class:`Solution` trimmed to the times reached (a single run).

    **Example:**
    >>> sol = assurjax.simulate(assurjax.load_scene("watt_sixbar"))
    >>> float(sol.t_stop)   # first standstill after falling from rest
    >>> batch = assurjax.simulate(scene, q0=np.linspace(0, 6, 10_000), stop=None)
    """
    mechanism = scene.mechanism if mechanism is None else mechanism
    loads = tuple(scene.loads if loads is None else loads)
    gravity = scene.gravity if gravity is None else jnp.asarray(gravity, dtype=float)
    check_loads(mechanism, loads)
    state, sim, outs = scene.state, scene.simulation, scene.outputs
    pick = lambda given, table, key, default: given if given is not None else table.get(key, default)  # noqa: E731
    stop = sim.get("stop", None) if stop is ... else stop
    if stop not in (None, "standstill", "none"):
        raise AssurjaxError(f"stop must be 'standstill' or None, got {stop!r}")
    settings = Settings(
        solver=str(pick(solver, sim, "solver", DEFAULT_SOLVER)),
        rtol=float(pick(rtol, sim, "rtol", DEFAULT_RTOL)),
        atol=float(pick(atol, sim, "atol", DEFAULT_ATOL)),
        fixed_step=pick(dt, sim, "dt", None) is not None,
        max_steps=int(pick(max_steps, sim, "max_steps", DEFAULT_MAX_STEPS)),
        standstill=stop == "standstill",
        check_assembly=bool(check_assembly),
        events=tuple(events),
        samples=int(pick(samples, sim, "samples", DEFAULT_SAMPLES)),
        points=tuple(pick(points, outs, "points", ())),
        angles=tuple(pick(angles, outs, "angles", ())),
        energies=bool(pick(energies, outs, "energies", False)),
        branch=str(pick(branch, sim, "branch", "fixed")),
        reduction=str(pick(reduction, sim, "reduction", "auto")),
        table_nodes=int(pick(table_nodes, sim, "table_nodes", DEFAULT_TABLE_NODES)),
        steps=None if (n_steps := pick(steps, sim, "steps", None)) is None else int(n_steps),
    )
    if settings.branch not in ("fixed", "tracked"):
        raise AssurjaxError(f"branch must be 'fixed' (the scene's assembly modes) or 'tracked' (continuous through singular configurations), got {settings.branch!r}")
    _check_outputs(mechanism, settings)
    q0, omega0, t0, t1 = (pick(v, state, k, d) for v, k, d in ((q0, "q0", 0.0), (omega0, "omega0", 0.0), (t0, "t0", 0.0), (t1, "t1", 1.0)))
    if settings.solver in BASELINES:
        if np.ndim(q0) or np.ndim(omega0):
            raise AssurjaxError(f"solver={settings.solver!r} (a baseline) simulates one starting state at a time")
        return simulate_seed_euler(mechanism, gravity, loads, q0, omega0, t0=t0, t1=t1, dq=pick(dt, sim, "dt", None) or 1e-3,
                                   standstill=settings.standstill)
    _solver(settings)  # unknown names fail here, not inside jit
    if settings.steps is not None:
        _check_steps(settings)
    # Arrays, not Python floats: filter_jit would treat floats as static and recompile per value.
    # NumPy scalars: jit takes them without the cost of creating device arrays one by one.
    q0, omega0, t0, t1 = (np.asarray(v, dtype=float) for v in (q0, omega0, t0, t1))
    saveat = None if saveat is None else _checked_saveat(saveat, t0, t1)
    batch = _batch_shape(q0, omega0)
    step = pick(dt, sim, "dt", None)
    step = None if step is None else np.asarray(step, dtype=float)
    settings, table = _resolve_reduction(settings, table, mechanism, gravity, loads, batch)
    with checks_without_callbacks():  # saveat and the rest were checked above: see _jit
        if batch is None:
            sol = _simulate_jit(mechanism, gravity, loads, q0, omega0, t0, t1, saveat, step, settings=settings, table=table)
            return _trim(sol, mechanism)
        q0, omega0 = np.broadcast_to(q0, batch), np.broadcast_to(omega0, batch)
        sols = _simulate_batch_jit(mechanism, gravity, loads, q0, omega0, t0, t1, saveat, step, settings, table)
    return _batch_summary(jax.device_get(sols))


def _checked_saveat(saveat, t0, t1) -> np.ndarray:
    """The save times as a 1-D float array, sorted from t0 towards t1 and inside [t0, t1]."""
    saveat = np.asarray(saveat, dtype=float)
    if saveat.ndim != 1:
        raise AssurjaxError(f"saveat must be a 1-D array of times, got shape {saveat.shape}")
    steps = np.diff(saveat) * np.sign(t1 - t0)
    if np.any(steps < 0) or not np.all(np.isfinite(saveat)):
        raise AssurjaxError("saveat must be finite times in the direction from t0 to t1")
    if np.any((saveat - t0) * (saveat - t1) > 0):
        raise AssurjaxError(f"saveat must lie between t0 = {float(t0)} and t1 = {float(t1)} s; "
                            f"got times from {saveat.min()} to {saveat.max()}")
    return saveat


AUTO_TABLE_BATCH = 64  # starting states from which reduction="auto" tabulates (a build costs ~15 exact runs)


def _batch_shape(q0, omega0):
    """None for one starting state, else the common 1-D shape of q0 and omega0."""
    if q0.ndim == 0 and omega0.ndim == 0:
        return None
    try:
        shape = np.broadcast_shapes(q0.shape, omega0.shape)
    except ValueError:
        raise AssurjaxError(f"q0 (shape {q0.shape}) and omega0 (shape {omega0.shape}) do not broadcast together") from None
    if len(shape) != 1:
        raise AssurjaxError(f"a batch of starting states needs 1-D q0/omega0, got shape {shape}")
    return shape


def _resolve_reduction(settings: Settings, table, mechanism, gravity, loads, batch):
    """(settings with reduction 'exact' or 'table', the table or None). The table is
    built and checked on the host, once, outside the jitted core."""
    if table is not None:
        if not isinstance(table, ReducedTable):
            raise AssurjaxError(f"table must be an assurjax.ReducedTable (from assurjax.build_table), got {type(table).__name__}")
        return settings._replace(reduction="table"), table
    if settings.reduction == "auto":
        wanted = batch is not None and batch[0] >= AUTO_TABLE_BATCH and settings.branch == "fixed"
        if wanted:
            try:
                return settings._replace(reduction="table"), build_table(mechanism, gravity, loads, settings.table_nodes)
            except AssurjaxError:  # not tabulable (slider, velocity/time loads, a crank that cannot turn fully)
                pass
        return settings._replace(reduction="exact"), None
    if _check_reduction(settings):
        return settings, build_table(mechanism, gravity, loads, settings.table_nodes)
    return settings, None


def _simulate_batch(mechanism, gravity, loads, q0, omega0, t0, t1, ts, dt, settings, table):
    run = lambda q, w: simulate_core(mechanism, gravity, loads, q, w, t0, t1, ts, dt, settings=settings, table=table)  # noqa: E731
    return jax.vmap(run)(q0, omega0)


_simulate_batch_jit = jit(_simulate_batch)


def _batch_summary(sols: Solution) -> Solution:
    """A batched Solution (host arrays) with a status counting the outcomes."""
    events, results = np.asarray(sols.event), np.asarray(sols.result)
    parts = [f"{np.sum(events == code)} {name}" for code, name in ((STANDSTILL, "standstill"), (LOCKUP, "lock-up"))
             if np.any(events == code)]
    parts += [f"{np.sum(events >= USER)} user event"] if np.any(events >= USER) else []
    parts += [f"{np.sum((events < 0) & (results == 0))} reached t1"] if np.any((events < 0) & (results == 0)) else []
    parts += [f"{np.sum((events < 0) & (results != 0))} solver failures"] if np.any((events < 0) & (results != 0)) else []
    return dataclasses.replace(sols, status=f"batch of {events.size}: " + ", ".join(parts))


def _check_outputs(mechanism, settings):
    for p in settings.points:
        if p not in mechanism.point_names:
            raise AssurjaxError(f"outputs: unknown point '{p}' (known: {sorted(mechanism.point_names)})")
    for a in settings.angles:
        if a not in mechanism.links:
            raise AssurjaxError(f"outputs: unknown link '{a}' (known: {sorted(mechanism.links)})")


RESULT_MESSAGES = {0: "successful", 1: "max_steps_reached"}


def _trim(sol: Solution, mechanism: Mechanism) -> Solution:
    """Keep only the saved times reached, and turn codes into readable fields."""
    # On the host, in one transfer: slicing device arrays to a new length n would
    # compile per n. The trimmed Solution holds NumPy arrays.
    sol = jax.device_get(sol)
    n_saved = sol.valid.shape[0]
    n = int(np.sum(sol.valid))
    cut = lambda x: x[:n] if isinstance(x, np.ndarray) and x.ndim >= 1 and x.shape[0] == n_saved else x  # noqa: E731
    fields = {k: jax.tree.map(cut, getattr(sol, k)) for k in _SAVED}
    event, failed = int(sol.event), int(sol.failed_group_index)
    group = mechanism.groups[failed].name if failed >= 0 else None
    t_stop = float(sol.t_final) if event >= 0 else None
    status = _status(int(sol.result), event, group, float(sol.t_final))
    return dataclasses.replace(sol, **fields, t_stop=t_stop, failed_group=group, status=status)


_SAVED = ("t", "q", "omega", "domega", "kinetic", "potential", "total", "dissipated", "points", "angles", "valid")


def _status(result: int, event: int, group: str | None, t_final: float) -> str:
    if event == STANDSTILL:
        return f"standstill at t = {t_final:.9g} s"
    if event == LOCKUP:
        return f"group '{group}' can no longer assemble at t = {t_final:.9g} s (lock-up / limit position)"
    if event >= USER:
        return f"user event #{event - USER} at t = {t_final:.9g} s"
    if result == 0:
        return f"reached t1 = {t_final:.9g} s"
    return f"solver stopped at t = {t_final:.9g} s: {_result_name(result)}"


def _result_name(code: int) -> str:
    for name in dir(diffrax.RESULTS):
        item = getattr(diffrax.RESULTS, name)
        if not name.startswith("_") and getattr(item, "_value", None) == code:
            return f"{name} ({diffrax.RESULTS[item]})"
    return f"result code {code}"


# ---------------------------------------------------------------------------- seed baseline


class SeedEulerSolution(NamedTuple):
    """The seed's Euler-in-q baseline: samples every ``dq`` of travel. ``t`` (s), ``q``,
    ``omega`` (rad/s), ``t_stop`` (s, None if no standstill within ``t1`` or the
    step budget). ``valid`` marks the steps taken."""

    t: Array
    q: Array
    omega: Array
    valid: Array
    t_stop: Any
    status: str


@jit
def _seed_euler_core(mechanism, gravity, loads, q0, omega0, t0, t1, dq, n_steps: int, standstill: bool):
    """Seed 000 eq. 2 by jax.lax.scan: w_{i+1}^2 = (J_i w_i^2 + 2 (tau + tau_red)_i dq) / J_{i+1},
    with q stepping by dq in the direction of motion and dt = dq / mean(|w_i|, |w_{i+1}|)."""
    red = lambda q, w, t: reduce_single(mechanism, gravity, loads, q, w, t)  # noqa: E731
    r0 = red(q0, omega0, t0)
    a0 = r0.acceleration(omega0)
    s = jnp.where(omega0 != 0, jnp.sign(omega0), jnp.sign(a0))
    step = s * dq

    def body(carry, _):
        q, w2, t, j, moving = carry
        r = red(q, s * jnp.sqrt(w2), t)
        q_next = q + step
        j_next = red(q_next, s * jnp.sqrt(w2), t).inertia
        w2_next = (j * w2 + 2.0 * (r.effort + r.torque) * step) / j_next
        stops = w2_next <= 0.0
        dt = dq / (0.5 * (jnp.sqrt(w2) + jnp.sqrt(jnp.maximum(w2_next, 0.0))))
        dt = jnp.where(stops, 2.0 * dq / jnp.maximum(jnp.sqrt(w2), 1e-300), dt)  # decelerate to rest within the step
        t_next = t + dt
        go = moving & (t_next <= t1) & ~(stops & standstill)
        new = (jnp.where(go, q_next, q), jnp.where(go, jnp.maximum(w2_next, 0.0), w2), jnp.where(go, t_next, t),
               jnp.where(go, j_next, j), go)
        stopped_here = moving & stops & standstill & (t_next <= t1)
        return new, (new[0], s * jnp.sqrt(new[1]), new[2], go, stopped_here, t_next)

    init = (q0, omega0**2, t0, r0.inertia, jnp.asarray(True))
    _, (q, w, t, go, stopped, t_hit) = jax.lax.scan(body, init, None, length=n_steps)
    t_stop = jnp.where(jnp.any(stopped), t_hit[jnp.argmax(stopped)], jnp.inf)
    return q, w, t, go, t_stop


def simulate_seed_euler(mechanism, gravity, loads, q0, omega0, *, t0=0.0, t1=1.0, dq=1e-3, standstill=True, max_steps=None) -> SeedEulerSolution:
    """The seed's scheme (Euler in q with a fixed step ``dq`` rad, seed 000 eq. 2) — a
    labelled baseline for benchmarks, first order in ``dq``. Integrates until ``t1``,
    the first standstill (``standstill=True``) or ``max_steps`` steps of ``dq``
    (default: 20 000)."""
    n = int(max_steps or 20000)
    loads = tuple(loads)
    q, w, t, go, t_stop = _seed_euler_core(mechanism, jnp.asarray(gravity, dtype=float), loads, jnp.asarray(q0, dtype=float),
                                          jnp.asarray(omega0, dtype=float), jnp.asarray(t0, dtype=float),
                                          jnp.asarray(t1, dtype=float), jnp.asarray(dq, dtype=float), n, bool(standstill))
    k = int(np.sum(np.asarray(go)))
    q = jnp.concatenate([jnp.asarray(q0, dtype=float)[None], q[:k]])
    w = jnp.concatenate([jnp.asarray(omega0, dtype=float)[None], w[:k]])
    t = jnp.concatenate([jnp.asarray(t0, dtype=float)[None], t[:k]])
    ts = float(t_stop) if np.isfinite(float(t_stop)) else None
    status = f"standstill at t = {ts:.9g} s" if ts is not None else f"stopped at t = {float(t[-1]):.9g} s after {k} steps"
    return SeedEulerSolution(t=t, q=q, omega=w, valid=jnp.ones(k + 1, dtype=bool), t_stop=ts, status=status)
