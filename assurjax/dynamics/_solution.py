"""The Solution of a simulation and what is computed along it (outputs, trimming, summaries)."""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._friction import frictions_of
from .._loads import potential_energy
from .._tracking import branch_mapping
from .._mechanism import Mechanism, Pose, positions
from .._positions import assembled
from .._repr import value_pdoc
from .._model import Model
from .._reduction import reduce_with_kinematics
from ._field import State, acceleration_and_reduction
from .._errors import AssemblyError
from ._results import DT_MIN, FINISHED, JAM_REMEDY, LOCKUP, MAX_STEPS, START_NOT_ASSEMBLED, START_SINGULAR, STANDSTILL, USER, result_code, result_text, status_text
from ._settings import Settings


class Solution(eqx.Module):
    """A simulated motion of the reduced link and what the outputs asked for.

    ``t`` (s), ``q`` (rad or m), ``omega`` (rad/s or m/s), ``domega`` (dw/dt) at the
    saved times. ``kinetic``, ``potential``, ``total`` (J): energies (None unless
    asked); ``work`` (J): work done since t0 by every load outside the potential
    energy (driving torque or motor, applied forces and couples, dampers, friction;
    None unless energies are asked, and with a tabulated reduction), so that
    ``balance`` = T + V - W - (T + V at t0) stays 0 up to the solver's error;
    ``dissipated`` (J): work removed by dissipative loads since t0 (None without them).
    ``points``: name -> (n, 2) trajectories (m); ``angles``: link -> (n,) (rad);
    ``coms``: link -> (n, 2) centre-of-mass trajectories (m). With ``velocities`` /
    ``accelerations`` asked: ``velocities``, ``accelerations`` (m/s, m/s^2) of those
    points, ``com_velocities``, ``com_accelerations`` of those centres of mass and
    ``angular_velocities``, ``angular_accelerations`` (rad/s, rad/s^2) of those links
    (from the kinematic coefficients and the simulated w, dw/dt).
    ``t_stop``: time (s) at which a stop event fired (None when none did; under
    jit/vmap an array, +inf when none did). ``event``: -1 none, 0 standstill, 1 a group
    can no longer assemble (``failed_group`` names it; for a batch of mechanisms one name or
    None per member), 2 + k the user event ``events[k]`` (which ``status`` counts from 1: 'user
    event #1').
    ``valid``: the saved times reached, then the final state (at ``t_final``); the
    entries after it repeat the final state (under jit/vmap only; :func:`simulate`
    trims them). ``result``: an :class:`assurjax.RESULTS` item
    (``sol.result == assurjax.RESULTS.successful``); ``status`` a readable summary
    with a remedy when the solver stopped early. ``jammed``: True where the run stopped
    because the joint friction jams the mechanism (no consistent motion on: a physical end,
    see ``status``; its ``result`` is the solver's ``dt_min_reached``, so ``successful`` is
    False; the last sample is the jam's state, where the motion has no dw/dt: its ``domega`` is
    that of no motion, and :func:`assurjax.reactions` marks it ``friction_ok`` False), per
    member for a batch; None under jit/vmap (``simulate_core``), where it is not tested. ``mechanism_points``: the simulated mechanism's point names (None under jit/vmap):
    :func:`assurjax.reactions` refuses a Solution of another mechanism by them.
    """

    __pdoc__ = value_pdoc  # repr: scalars and small arrays by value, long tables cut

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
    result: Any
    num_steps: Array
    work: Array | None = None
    velocities: dict[str, Array] = eqx.field(default_factory=dict)
    accelerations: dict[str, Array] = eqx.field(default_factory=dict)
    coms: dict[str, Array] = eqx.field(default_factory=dict)
    com_velocities: dict[str, Array] = eqx.field(default_factory=dict)
    com_accelerations: dict[str, Array] = eqx.field(default_factory=dict)
    angular_velocities: dict[str, Array] = eqx.field(default_factory=dict)
    angular_accelerations: dict[str, Array] = eqx.field(default_factory=dict)
    jammed: Any = None
    failed_group: str | None = eqx.field(static=True, default=None)
    mechanism_points: tuple[str, ...] | None = eqx.field(static=True, default=None)
    status: str = eqx.field(static=True, default="")

    @property
    def balance(self) -> Array | None:
        """T + V - W minus its value at t0 (J): zero for an exact solution (None
        unless energies and work were computed). Not at a lock-up (``event`` 1): at a
        limit position J_red grows without bound as w goes to 0, and T = J_red w^2 / 2
        is not resolved by the driving coordinate in the last steps before it (the
        Roberts four-bar at the default tolerances: 1e-6 of its energy until 5 ms
        before, 7e-5 until 3 us before, 10 % at it)."""
        if self.total is None or self.work is None:
            return None
        closed = self.total - self.work
        return closed - closed[..., :1]

    @property
    def successful(self) -> bool:
        """True when the solver reached t1 or a stop event (no solver failure)."""
        return bool(np.all(np.isin(result_code(self.result), FINISHED)))


def any_outputs(settings: Settings) -> bool:
    """True where the settings ask for anything computed at the saved times."""
    return bool(settings.domega or settings.energies or settings.points or settings.angles or settings.coms)


def no_outputs() -> dict:
    """The output fields of a Solution for which nothing is computed."""
    return dict(domega=None, kinetic=None, potential=None, total=None, points={}, angles={})


def outputs(model: Model, t, q, w, settings: Settings, near=None, *, flags: bool = False) -> dict:
    """Only what the settings ask for: dw/dt, energies, point trajectories, link angles.
    ``near``: saved link angles of a tracked branch (None: the fixed modes).
    One vmapped evaluation per saved time (with friction, dw/dt's friction solved first, one
    sample after another: :func:`_serial_friction`): the reduction gives dw/dt and J_red
    (T = J_red w^2 / 2), its position analysis gives points, angles and V.
    ``flags``: also every group's ok flag at every time (``out["ok"]``, (times, groups);
    then the full position analysis is made even where only some points are asked for)."""
    mechanism, gravity, loads = model.mechanism, model.gravity, model.loads
    out = no_outputs()
    rates = settings.velocities or settings.accelerations
    if not any_outputs(settings):
        return out

    rows = (t, q, w, near)
    # with friction, dw/dt's friction solve one sample after another (see _serial_friction)
    solved = jax.lax.map(lambda row: _serial_acceleration(model, settings, *row), rows) if _serial_friction(
        model, settings) else None

    def sample(t, q, w, stacked, solved):
        z = branch_mapping(mechanism, stacked)
        values = {}
        if settings.domega or settings.energies:
            if settings.domega:  # (with friction, its solve gives the reduction too)
                values["domega"], red, kin = solved if solved is not None else acceleration_and_reduction(
                    model, t, State(q, w, branch=stacked), settings.bridge)
            else:  # the energies alone need no friction solve
                red, kin = reduce_with_kinematics(mechanism, gravity, loads, q, w, t, near=z, bridge=settings.bridge)
            pose = Pose(points=kin.points, coms=kin.coms, angles=kin.angles, ok=kin.ok)
            if settings.energies:
                values["kinetic"] = 0.5 * red.inertia * w**2
                values["potential"] = potential_energy(mechanism, gravity, loads, pose, check=False)
        elif settings.angles or settings.coms or flags:  # angles or centres of any link: the full position analysis
            pose = positions(mechanism, q, near=z)
        else:  # only the groups the points need
            pose = positions(mechanism, q, points=settings.points, near=z)
        values["points"] = {p: pose.points[p] for p in settings.points}
        values["angles"] = {a: pose.angles[a] for a in settings.angles}
        values["coms"] = {c: pose.coms[c] for c in settings.coms} if settings.coms else {}
        if flags:
            values["ok"] = pose.ok
        if rates:
            alpha = values["domega"] if "domega" in values else None
            values.update(_rates(mechanism, q, w, alpha, z, settings))
        return values

    out.update(jax.vmap(sample)(*rows, solved))
    if settings.energies:
        out["total"] = out["kinetic"] + out["potential"]
    return out


def _serial_friction(model: Model, settings: Settings) -> bool:
    """Whether the outputs' dw/dt solve their friction one sample after another: wherever
    dw/dt is asked with friction. Each sample's solve is then the integration's own
    right-hand side's method (the fixed-point iteration, in the trace of
    _field._friction_start, which the segments' starts share; up to SUMMED_TERMS elements its
    batched Newton's method, with its K x K Jacobians and LU, is gone from the outputs'
    program; past them its vmapped iteration, whose
    tangents worked past the CPU's caches: the strandbeest with friction in its 73 joints,
    0.2 s and 201 samples, 271 -> 239 ms warm, first call 38.3 -> 36.2 s). Only that solve: the
    rest of a sample stays vmapped (the whole sample one after another: the Watt six-bar's
    201 samples 18.9 against 18.2 ms a call)."""
    return bool(settings.domega and frictions_of(model.loads))


def _serial_acceleration(model: Model, settings: Settings, t, q, w, branch):
    """:func:`acceleration_and_reduction` of one saved state, by the right-hand side's trace."""
    return acceleration_and_reduction(model, t, _integrated_state(model, settings, q, w, branch), settings.bridge,
                                      iterate=True)


def quadratures(model: Model, settings: Settings, exact: bool) -> dict:
    """The work terms an integrated state carries (0 at the start) or None: ``work`` and
    ``dissipated`` with energies asked, along the exact reduction (``exact``)."""
    zero = jnp.zeros(())
    tracked = settings.energies and exact
    return dict(work=zero if tracked else None,
                dissipated=zero if tracked and any(load.dissipative for load in model.loads) else None)


def _integrated_state(model: Model, settings: Settings, q, w, branch) -> State:
    """A saved state with the parts the integration carries (and the friction's rates, whose
    values the analysis does not read), so that the friction analysis of an output sample
    is the right-hand side's trace."""
    return State(q, w, **quadratures(model, settings, exact=settings.reduction != "table"), branch=branch,
                 friction_rates=jnp.zeros(len(frictions_of(model.loads))))


def _rates(mechanism, q, w, alpha, near, settings: Settings) -> dict:
    """Velocities (and accelerations) of the points, centres of mass and links asked for."""
    from .._kinematics import coefficients

    order = 2 if settings.accelerations else 1
    kin = coefficients(mechanism, q, order=order, near=near).kinematics(w, alpha if order == 2 else None)
    pick = lambda d, names: {} if d is None else {k: d[k] for k in names}  # noqa: E731
    out = dict(velocities=pick(kin.velocities, settings.points), com_velocities=pick(kin.com_velocities, settings.coms),
               angular_velocities=pick(kin.angular_velocities, settings.angles))
    if order == 2:
        out.update(accelerations=pick(kin.accelerations, settings.points),
                   com_accelerations=pick(kin.com_accelerations, settings.coms),
                   angular_accelerations=pick(kin.angular_accelerations, settings.angles))
    return out


# the Solution's fields with a value per saved time
SAVED_FIELDS = ("t", "q", "omega", "domega", "kinetic", "potential", "total", "dissipated", "work", "points", "angles",
                "valid", "velocities", "accelerations", "coms", "com_velocities", "com_accelerations",
                "angular_velocities", "angular_accelerations")


def trim(sol: Solution, mechanism: Mechanism, settings: Settings, q0) -> Solution:
    """Keep only the saved times reached, and turn codes into readable fields. ``q0``: the
    start (a start that is no motion names it; with save_steps no row is saved then)."""
    # On the host, in one transfer: slicing device arrays to a new length n would
    # compile per n. The trimmed Solution holds NumPy arrays.
    sol = to_host(sol)
    event, failed, code = int(sol.event), int(sol.failed_group_index), int(result_code(sol.result))
    group = mechanism.groups[failed].name if failed >= 0 else None
    if code == START_NOT_ASSEMBLED:
        raise AssemblyError(f"{mechanism.groups[failed].describe()} cannot assemble at the start q0 = {float(q0):.6g}: "
                            "choose a starting driving coordinate where the mechanism closes (or, for a triad or class-IV "
                            "group, a better 'guess' of its inner joints)", group=group)
    if code == START_SINGULAR:
        raise AssemblyError(f"{mechanism.groups[failed].describe()} is exactly at a singular configuration at the start "
                            f"q0 = {float(q0):.6g} ({mechanism.groups[failed].singular_configuration}: a limit position "
                            "of the driver, or where two branches cross), where the driving coordinate does not carry the "
                            "motion: give a q0 inside the driver's range (a drawing made there gives this q0)", group=group)
    t_final = float(sol.t_final)
    t_stop = t_final if event >= 0 else None
    status = status_text(code, event, group, t_final, max_steps=settings.max_steps) + _nan_event_words(sol, settings)
    if code == MAX_STEPS and settings.branch == "fixed":
        status += _limit_ahead(mechanism, float(sol.q_final), float(sol.omega_final))
    n = int(np.count_nonzero(sol.valid))
    rows = slice(0, n)  # views, where indices copy
    if settings.save_steps:  # once per time: a solver step that ends on a requested time is saved twice
        fresh = np.diff(np.asarray(sol.t)[:n], prepend=-np.inf) != 0
        rows = rows if fresh.all() else np.flatnonzero(fresh)
    reached = saved_rows(sol, rows)
    return replaced(reached, t_stop=t_stop, failed_group=group, status=status, mechanism_points=mechanism.point_names)


def _nan_event_words(sol: Solution, settings: Settings) -> str:
    """What a run adds to its status where a user event turned NaN at some saved state: a
    NaN never changes sign, so the event could not fire from there on (one finite at the
    start is all the request checks); '' otherwise."""
    n = int(np.count_nonzero(sol.valid))
    if not settings.events or not n:
        return ""
    t, q, omega = (np.asarray(v)[:n] for v in (sol.t, sol.q, sol.omega))
    words = ""
    for k, cond in enumerate(settings.events):
        value = np.asarray(jax.vmap(lambda t, q, w: jnp.asarray(cond(t, q, w), dtype=float))(t, q, omega))
        nan = np.flatnonzero(np.isnan(value))
        if nan.size:
            words += (f"; event #{k + 1} was NaN at {nan.size} of the {n} saved states, the first at t = {t[nan[0]]:.6g} s "
                      f"(q = {q[nan[0]]:.6g}): a NaN never changes sign, so it could not fire there")
    return words


LIMIT_AHEAD = 1e-6  # (1 + |q|): a limit position this near past where a run ran out of steps is the one it closed in on


def limit_ahead(mechanism: Mechanism, q: float, omega: float, distances=(LIMIT_AHEAD,)) -> tuple[str, float] | None:
    """(the group, the distance): the first group that assembles at q but not one of
    ``distances`` x (1 + |q|) further on in the direction of ``omega``, the nearest first;
    None where there is none (or the run is at rest). The fixed branch's analysis."""
    if omega == 0:
        return None
    here = np.asarray(assembled(mechanism, q))
    for distance in distances:
        step = float(np.sign(omega)) * distance * (1.0 + abs(q))
        failing = np.flatnonzero(here & ~np.asarray(assembled(mechanism, q + step)))
        if failing.size:
            return mechanism.groups[failing[0]].describe(), abs(step)
    return None


def _limit_ahead(mechanism: Mechanism, q: float, omega: float) -> str:
    """Words for a run that used up its steps closing in on a limit position: near one, the
    reduced coordinate's round-off (J_red grows without bound) outgrows a tight tolerance,
    and the steps shrink (a four-bar's lock-up: 312 steps at rtol 1e-8, 2816 at 1e-10,
    11401 at 1e-11). Empty where every group assembles LIMIT_AHEAD past q (or fails at q)."""
    limit = limit_ahead(mechanism, q, omega)
    if limit is None:
        return ""
    group, distance = limit
    return (f"; it was closing in on a limit position ({group} cannot assemble {np.sign(omega) * distance:+.1g} "
            "further on), where the driving coordinate does not resolve the motion to so tight a "
            "tolerance: loosen rtol/atol to locate the lock-up")


def saved_rows(sol: Solution, rows) -> Solution:
    """``sol`` with only the saved times ``rows`` (a slice or indices) in its SAVED_FIELDS."""
    n = sol.t.shape[0]
    take = lambda x: x[rows] if getattr(x, "ndim", 0) >= 1 and x.shape[0] == n else x  # noqa: E731
    return replaced(sol, **{k: jax.tree.map(take, getattr(sol, k)) for k in SAVED_FIELDS})


def to_host(tree):
    """``jax.device_get(tree)``: NumPy arrays for the jax arrays in it. On the CPU, where
    the device's memory is the host's, each array is read directly (still an explicit
    transfer for JAX's transfer guards): device_get's asynchronous copy requests, made
    for accelerators, cost ~5 us per array, more than a small simulation's run."""
    scope = _explicit_transfer_scope()
    if scope is None or not _on_cpu():
        return jax.device_get(tree)
    with scope():
        return jax.tree.map(lambda x: np.asarray(x) if isinstance(x, jax.Array) else x, tree)


@functools.cache
def _explicit_transfer_scope():
    """JAX's own scope of device_get (a private name: None if it moves)."""
    try:
        from jax._src import config
    except ImportError:
        return None
    return getattr(config, "explicit_device_get_scope", None)


@functools.cache
def _on_cpu() -> bool:
    """JAX computes on the CPU (fixed once its backends are up; asking costs 3-60 us a call)."""
    return jax.default_backend() == "cpu"


def replaced(sol: Solution, **changes) -> Solution:
    """``dataclasses.replace(sol, **changes)`` without running the Module's __init__ again
    (~60 us: every field passes equinox's checks), as equinox itself rebuilds a Module
    when unflattening it: a new instance with its fields set. Every field is set."""
    new = object.__new__(type(sol))
    for field in dataclasses.fields(sol):
        object.__setattr__(new, field.name, changes[field.name] if field.name in changes else getattr(sol, field.name))
    return new


def batch_summary(sols: Solution, jammed: np.ndarray | None = None, groups: tuple[str, ...] | None = None) -> Solution:
    """A batched Solution (host arrays) with a status counting the outcomes; ``jammed``:
    the members stopped where the joint friction jams (counted apart from solver failures);
    ``groups``: the mechanisms' group names, to name each member's ``failed_group`` (a tuple
    with one name or None per member, as a single run's; left None without them)."""
    codes = result_code(sols.result)
    events, results = np.asarray(sols.event), np.where(np.isin(codes, FINISHED), 0, codes)
    unassembled = codes == START_NOT_ASSEMBLED  # its event says lock-up too: counted once, below
    singular = codes == START_SINGULAR
    unassembled = unassembled | singular  # counted apart, below
    jammed = np.zeros(codes.shape, dtype=bool) if jammed is None else jammed
    # a member jammed at rest ended held there (at t1, or a start held with stop='standstill'): counted as jammed only
    parts = [f"{np.sum((events == code) & ~unassembled & ~jammed)} {name}" for code, name in ((STANDSTILL, "standstill"), (LOCKUP, "lock-up"))
             if np.any((events == code) & ~unassembled & ~jammed)]
    parts += [f"{np.sum(events >= USER)} user event"] if np.any(events >= USER) else []
    reached = (events < 0) & (results == 0) & ~jammed
    parts += [f"{np.sum(reached)} reached t1"] if np.any(reached) else []
    parts += [f"{np.sum(unassembled & ~singular)} cannot assemble at the start"] if np.any(unassembled & ~singular) else []
    parts += [f"{np.sum(singular)} start exactly at a singular configuration"] if np.any(singular) else []
    parts += [f"{np.sum(jammed)} jammed by the joint friction (Painleve's paradox: {JAM_REMEDY})"] if np.any(jammed) else []
    failures = (events < 0) & (results != 0) & ~unassembled & ~jammed
    parts += [f"{np.sum(failures & (codes == code))} solver failures ({result_text(int(code))})" for code in np.unique(codes[failures])]
    named = {} if groups is None else {"failed_group": tuple(groups[i] if i >= 0 else None
                                                            for i in np.ravel(sols.failed_group_index).tolist())}
    if np.any(jammed & np.isin(codes, FINISHED)):  # jammed at rest, where the segments had held it: no run as asked
        named["result"] = eqx.tree_at(lambda r: r._value, sols.result, np.where(jammed, DT_MIN, codes).astype(codes.dtype))
    return dataclasses.replace(sols, jammed=jammed, status=f"batch of {events.size}: " + ", ".join(parts), **named)
