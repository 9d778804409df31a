"""Forward sensitivities of the reduced motion: the variational equations, integrated by diffrax.

The reduced equation of motion (Durango et al. 2014 eq. 1 in time form) is y' = f(t, y, p) with
y = (q, w) and p every floating-point parameter of the mechanism, gravity and loads.
Its sensitivities S = dy/dP with respect to P = (q0, w0, p) obey

    S' = df/dy S + df/dp [0 | I],     S(t0) = [I | 0],

the forward-sensitivity (variational) equations. With ``method="loop"`` the augmented
state (q, w, S) is integrated by diffrax in one solve; since only dw/dt depends on p, the
right-hand side of S needs one reverse pass of the reduced acceleration per stage,
whatever the number of parameters. No derivative is taken *through* the solver.

Step sizes are chosen by the error of (q, w) only, so the state follows exactly the
steps of the plain simulation, and with an explicit Runge-Kutta method the computed S
is the derivative of the discrete solution at those steps: gradients agree with the
simulation's own finite differences to about the solver tolerance (not to round-off
as reverse mode through the solver would).

``method="quadrature"`` gets the same S from the variation-of-constants formula
instead (see :func:`_augmented_quadrature`): the parameter derivative is then one
batched reverse pass at Gauss-Legendre nodes after the plain simulation, 3.5-4x the
cost of the simulation itself for all 50 parameters of the Watt six-bar (the
``"loop"`` method pays a reverse pass per solver stage: ~45x; a reverse pass, like a
batch of 50 tangents, costs far more inside the solver's loop, where the plain
right-hand side takes about 2 microseconds, than once over a batch of nodes).

The result is wrapped in ``jax.custom_jvp``: ``jax.grad``, ``jax.jacfwd``,
``jax.jvp`` and ``jax.vmap`` of :func:`final_state_sensitivity` and
:func:`standstill_time_sensitivity` all run one augmented solve (reverse mode
transposes the linear map S).

The standstill time t* (w(t*) = 0, located by a diffrax.Event on the augmented
state) is differentiated by the implicit function theorem:

    dt*/dP = -(dw/dP at t*) / (dw/dt at t*).
"""

from __future__ import annotations

from typing import NamedTuple

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax.flatten_util import ravel_pytree

from .._errors import AssurjaxError
from .._friction import frictions_of, smoothed_only
from .._jit import jit
from .._model import Model, as_model, check_has_inertia
from .._positions import assembled
from .._reduction import generalized_force
from ..dynamics._field import State, field_args, vector_field
from ..dynamics._results import FINISHED, RESULTS, result_value
from ..dynamics._settings import Settings, controller_for, settings_from, solver_for
from ..dynamics._solve import friction_result

_TINY = 1e-30


class SensitivityOptions(NamedTuple):
    """Static options of the sensitivity solves (one compile per distinct value): the
    simulation's own settings (:func:`assurjax.settings_from`: the scene's
    ``[simulation]`` under the caller's keywords) and the sensitivity method."""

    settings: Settings = Settings()
    dt: float | None = None  # a fixed step (s); None: adaptive (the simulation's PID controller on (q, w))
    method: str = "loop"  # "loop": S integrated with the state; "quadrature": variation of constants (below)
    panels: int = 16  # quadrature: panels of equal length over [t0, T]
    nodes: int = 6  # quadrature: Gauss-Legendre nodes per panel


def _split(model: Model):
    """(flat parameter vector p, rebuild(p) -> Model)."""
    params, static = eqx.partition(model, eqx.is_inexact_array)
    flat, unravel = ravel_pytree(params)
    return flat, lambda p: eqx.combine(unravel(p), static)


def _field(rebuild):
    """f(t, (q, w), p) -> (dq/dt, dw/dt): the simulation's vector field at parameters p."""

    def f(t, y, p):
        out = vector_field(t, State(y[0], y[1]), field_args(rebuild(p)))
        return out.q, out.omega

    return f


def _augmented_field(f, n_p: int):
    """(q, w, S) -> (dq/dt, dw/dt, dS/dt), S of shape (2, 2 + n_p), columns (q0, w0, p).

    Only dw/dt = a(t, q, w, p) depends on p, so one reverse-mode pass over a gives the
    whole Jacobian: df/dy = [[0, 1], [a_q, a_w]] and df/dp = [0; a_p]. Its cost does not
    grow with the number of parameters (a batch of forward tangents would)."""

    def acceleration(q, w, p, t):
        return f(t, (q, w), p)[1]

    grad = jax.value_and_grad(acceleration, argnums=(0, 1, 2))

    def rhs(t, state, p):
        q, w, s = state
        a, (a_q, a_w, a_p) = grad(q, w, p, t)
        ds_w = a_q * s[0] + a_w * s[1] + jnp.concatenate([jnp.zeros(2, p.dtype), a_p])
        return w, a, jnp.stack([s[1], ds_w])

    return rhs


def _solver(options: SensitivityOptions):
    return solver_for(options.settings)


def _state_norm(error):
    """Error norm of (q, w) only: the sensitivities ride on the state's steps."""
    return optx.rms_norm((error[0], error[1]))


def _standstill_event(options: SensitivityOptions):
    """w crosses 0 against the direction of motion (args[1]); clipped as in the simulation's
    event so that a start from rest (margin 0) is not a crossing."""

    def cond_fn(t, y, args, **kwargs):
        return jnp.minimum(args[1] * y[1], _TINY)

    tol = min(1e-3 * options.settings.rtol, 1e-12)
    return diffrax.Event(cond_fn, optx.Bisection(rtol=tol, atol=tol, flip=True), direction=False)


def _solve(term, y0, t0, t1, args, options: SensitivityOptions, standstill: bool, saveat=diffrax.SaveAt(t1=True)):
    fixed = options.dt is not None
    return diffrax.diffeqsolve(
        diffrax.ODETerm(term),
        _solver(options),
        t0=t0,
        t1=t1,
        dt0=jnp.asarray(options.dt, dtype=float) if fixed else None,
        y0=y0,
        args=args,
        saveat=saveat,
        stepsize_controller=diffrax.ConstantStepSize() if fixed else controller_for(options.settings, norm=_state_norm),
        event=_standstill_event(options) if standstill else None,
        max_steps=options.settings.max_steps,
        adjoint=diffrax.ForwardMode(),  # never differentiated: the custom_jvp below supplies the derivative
        throw=False,
    )


def _plain(f, p, y0, t0, t1, direction, options, standstill):
    """(t_final, q, w, event fired, diffrax result) of the plain simulation."""
    sol = _solve(lambda t, y, a: f(t, y, a[0]), (y0[0], y0[1]), t0, t1, (p, direction), options, standstill)
    return sol.ts[-1], sol.ys[0][-1], sol.ys[1][-1], _fired(sol), result_value(sol.result)


def _augmented(f, p, y0, t0, t1, direction, options, standstill):
    """The plain outputs plus S (2, 2 + n_p) at the final time."""
    if options.method == "quadrature":
        return _augmented_quadrature(f, p, y0, t0, t1, direction, options, standstill)
    n_p = p.shape[0]
    s0 = jnp.concatenate([jnp.eye(2, dtype=p.dtype), jnp.zeros((2, n_p), p.dtype)], axis=1)
    rhs = _augmented_field(f, n_p)
    sol = _solve(lambda t, y, a: rhs(t, y, a[0]), (y0[0], y0[1], s0), t0, t1, (p, direction), options, standstill)
    return sol.ts[-1], sol.ys[0][-1], sol.ys[1][-1], sol.ys[2][-1], _fired(sol), result_value(sol.result)


# ---------------------------------------------------------------------------- variation of constants


def _augmented_quadrature(f, p, y0, t0, t1, direction, options, standstill):
    """S at the final time T by the variation-of-constants formula

        S_y0(T) = Phi(T),   S_p(T) = Phi(T) int_t0^T Phi(t)^-1 [0; a_p(t)] dt,

    with Phi' = A(t) Phi, Phi(t0) = I the state-transition matrix of the 2x2 variational
    equation, A = [[0, 1], [a_q, a_w]]. The plain simulation gives y at Gauss-Legendre
    nodes; ONE batched reverse pass over all nodes gives (a_q, a_w, a_p) there; diffrax
    integrates Phi with A interpolated per panel (Lagrange polynomial through the panel's
    nodes); the integral is the Gauss-Legendre sum on the same nodes.
    Costs about one plain simulation plus one batched gradient: the parameter derivative
    is never taken inside the solver's loop. Accuracy: the solver tolerance plus the
    interpolation error O(h^nodes) of A on panels of length h, estimated by S with A one
    degree lower (NaN past QUADRATURE_TOLERANCE, see :func:`_resolved`).
    """
    t_end, (q, w), (q_end, w_end), sol, (h, x, nodes, weights) = _states_at_nodes(f, p, y0, t0, t1, direction,
                                                                                  options, standstill)

    def acceleration(q, w, p, t):
        return f(t, (q, w), p)[1]

    a_q, a_w, a_p = jax.vmap(jax.grad(acceleration, argnums=(0, 1, 2)), in_axes=(0, 0, None, 0))(q, w, p, nodes)
    # A interpolated through each panel's nodes, and one degree lower (its last Legendre
    # term dropped): the difference of the two S is the estimate of the interpolation's error
    a = jnp.stack([a_q.reshape(options.panels, -1), a_w.reshape(options.panels, -1)])
    a = jnp.stack([a, _one_degree_lower(x, a)])
    phi_nodes, phi_end = _transition(h, x, a, options)
    # Phi(t)^-1 e_w for every node (closed-form 2x2 inverse)
    det = phi_nodes[..., 0, 0] * phi_nodes[..., 1, 1] - phi_nodes[..., 0, 1] * phi_nodes[..., 1, 0]
    inv_col = jnp.stack([-phi_nodes[..., 0, 1], phi_nodes[..., 0, 0]], axis=-1) / det[..., None]
    integral = jnp.einsum("k,vki,kj->vij", weights, inv_col, a_p)
    s = jnp.concatenate([phi_end, phi_end @ integral], axis=-1)
    s = jnp.where(_resolved(s[0], s[1]), s[0], jnp.nan)  # a loud failure, not a wrong derivative
    result = result_value(sol.result)
    if not standstill:  # a run short of t1 has no states at the later nodes: no S (NaN to the caller, derivative 0)
        s = jnp.where(jnp.isin(result, jnp.asarray(FINISHED)), s, 0.0)
    return t_end, q_end, w_end, s, _fired(sol), result


def _gauss_nodes(t0, t_end, options):
    """(panel length h, Gauss-Legendre nodes x on [-1, 1], the nodes in time, their weights)."""
    x, wts = np.polynomial.legendre.leggauss(options.nodes)
    h = (t_end - t0) / options.panels
    left = t0 + h * jnp.arange(options.panels)
    return h, x, (left[:, None] + 0.5 * h * (1.0 + x)).ravel(), jnp.tile(0.5 * h * wts, options.panels)


def _states_at_nodes(f, p, y0, t0, t1, direction, options, standstill):
    """The plain simulation: (T, (q, w) at the Gauss nodes over [t0, T], (q, w) at T, its
    solution, :func:`_gauss_nodes`). To t1 the nodes are known before the solve, which saves
    at them; a standstill's T is known after it, whose dense output is evaluated there (dense
    output cost the Watt six-bar's gradient about one simulation more)."""
    term = lambda t, y, a: f(t, y, a[0])  # noqa: E731
    if standstill:
        sol = _solve(term, (y0[0], y0[1]), t0, t1, (p, direction), options, True, diffrax.SaveAt(t1=True, dense=True))
        quadrature = _gauss_nodes(t0, sol.ts[-1], options)
        return sol.ts[-1], jax.vmap(sol.evaluate)(quadrature[2]), (sol.ys[0][-1], sol.ys[1][-1]), sol, quadrature
    quadrature = _gauss_nodes(t0, t1, options)
    nodes = quadrature[2]
    saveat = diffrax.SaveAt(subs=(diffrax.SubSaveAt(ts=nodes), diffrax.SubSaveAt(t1=True)))
    sol = _solve(term, (y0[0], y0[1]), t0, t1, (p, direction), options, False, saveat)
    (ts, t_end), (at_nodes, end) = sol.ts, sol.ys
    # a run short of t1 has no states past its end (diffrax leaves inf): its last one there
    # keeps the transition's solve finite (not stepping to max_steps on NaN)
    at_nodes = tuple(jnp.where(ts <= t_end[0], y, y_end[0]) for y, y_end in zip(at_nodes, end))
    return t_end[0], at_nodes, (end[0][0], end[1][0]), sol, quadrature


# The quadrature's S is taken where its estimated error (S less S with A interpolated one
# degree lower, per column) is at most this share of the column's largest entry
QUADRATURE_TOLERANCE = 1e-3


def _one_degree_lower(x, values):
    """``values`` (..., panels, nodes) at the nodes ``x`` of each panel, less their polynomial's
    last Legendre term: the interpolant one degree lower, at the same nodes."""
    to_legendre = np.linalg.inv(np.polynomial.legendre.legvander(x, len(x) - 1))
    last = np.polynomial.legendre.legval(x, np.eye(len(x))[-1])  # P_{n-1} at the nodes
    return values - jnp.einsum("j,...j->...", to_legendre[-1], values)[..., None] * last


def _resolved(s, lower):
    """Whether the panels resolve A: per column of S (units differ between columns), the
    largest |S - S one degree lower| within QUADRATURE_TOLERANCE of the column's largest entry
    (a driven slider-crank over two turns erred 1.7e-2 at 64 panels, estimated 0.7-1.8e-2;
    a guard on the panels' last Legendre coefficients had passed it). A column of zeros
    (a parameter that moves nothing) passes."""
    scale = jnp.max(jnp.abs(s), axis=0)
    error = jnp.max(jnp.abs(s - lower), axis=0)
    return jnp.all(error <= QUADRATURE_TOLERANCE * scale)


def _lagrange(x_nodes):
    """Basis values L_j(x) of the Lagrange polynomials through x_nodes (on [-1, 1])."""
    x_nodes = jnp.asarray(x_nodes)
    k = x_nodes.shape[0]
    eye = jnp.eye(k, dtype=bool)
    gaps = jnp.where(eye, 1.0, x_nodes[:, None] - x_nodes[None, :])

    def basis(x):
        return jnp.prod(jnp.where(eye, 1.0, (x - x_nodes[None, :]) / gaps), axis=1)

    return basis


def _transition(h, x, a, options):
    """Phi at the nodes and at the end: Phi' = A(t) Phi, A's row (a_q, a_w) interpolated per
    panel; ``a`` (variants, 2, panels, nodes): the variants in one solve. Each panel's own
    transition (from I at its start) in one diffrax solve over the panels' common local time
    [0, h]; Phi is their running product. A is smooth within a panel, not across the joins
    between panels: the Watt six-bar's 16 panels take 4 steps at 6 saved times, against 25
    steps at 96 saved times over the whole span (1e-8 rtol, as accurate)."""
    basis = _lagrange(x)
    variants, _, panels, _ = a.shape

    def rhs(t, phi, args):  # t from each panel's start; phi (variants, panels, 2, 2)
        row = a @ basis(2.0 * t / h - 1.0)  # (variants, 2, panels)
        dw = row[:, 0, :, None] * phi[:, :, 0] + row[:, 1, :, None] * phi[:, :, 1]
        return jnp.stack([phi[:, :, 1], dw], axis=2)

    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(rhs), _solver(options), t0=0.0, t1=h, dt0=options.dt,
        y0=jnp.broadcast_to(jnp.eye(2), (variants, panels, 2, 2)), saveat=diffrax.SaveAt(ts=0.5 * h * (1.0 + x), t1=True),
        # the steps the first variant needs in its least resolved panel: the others (an error
        # estimate) ride on them, as the sensitivities ride on the state's steps
        stepsize_controller=controller_for(options.settings, norm=_panels_norm),
        max_steps=options.settings.max_steps, adjoint=diffrax.ForwardMode(), throw=False,
    )
    # Phi at each panel's end: the product of the panels' own, the later on the left
    ends = jax.lax.associative_scan(lambda earlier, later: later @ earlier, sol.ys[-1], axis=1)
    starts = jnp.concatenate([jnp.broadcast_to(jnp.eye(2), (variants, 1, 2, 2)), ends[:, :-1]], axis=1)
    at_nodes = jnp.einsum("jvkab,vkbc->vkjac", sol.ys[:-1], starts)
    return at_nodes.reshape(variants, -1, 2, 2), ends[:, -1]


def _panels_norm(error):
    """The largest over the panels of the first variant's RMS error."""
    return jnp.max(jnp.sqrt(jnp.mean(error[0] ** 2, axis=(-2, -1))))


def _fired(sol):
    return jnp.asarray(False) if sol.event_mask is None else jnp.asarray(sol.event_mask)


def _no_tangent(x):
    """The (float0) tangent of an integer or boolean output."""
    return np.zeros(np.shape(x), dtype=jax.dtypes.float0)


def _state_tangent(f, p, y0, t0, s, dp, dy0, dt0):
    """dy at a fixed time from the parameter tangents: S (dy0, dp) - S_y0 f(t0, y0) dt0."""
    f0 = jnp.stack(f(t0, (y0[0], y0[1]), p))
    s_y0 = s[:, :2]
    return s_y0 @ (dy0 - f0 * dt0) + s[:, 2:] @ dp


def _final_state_fn(f, options: SensitivityOptions):
    @jax.custom_jvp
    def final(p, y0, t0, t1):
        _, q, w, _, result = _plain(f, p, y0, t0, t1, 1.0, options, False)
        return jnp.stack([q, w]), result

    @final.defjvp
    def final_jvp(primals, tangents):
        p, y0, t0, t1 = primals
        dp, dy0, dt0, dt1 = tangents
        _, q, w, s, _, result = _augmented(f, p, y0, t0, t1, 1.0, options, False)
        y_final = jnp.stack([q, w])
        f1 = jnp.stack(f(t1, (q, w), p))
        dy = _state_tangent(f, p, y0, t0, s, dp, dy0, dt0) + f1 * dt1
        return (y_final, result), (dy, _no_tangent(result))

    return final


def _standstill_fn(f, options: SensitivityOptions):
    @jax.custom_jvp
    def stop(p, y0, t0, t1, direction):
        t, q, w, fired, result = _plain(f, p, y0, t0, t1, direction, options, True)
        return t, q, fired, result

    @stop.defjvp
    def stop_jvp(primals, tangents):
        p, y0, t0, t1, direction = primals
        dp, dy0, dt0, dt1, _ = tangents
        t, q, w, s, fired, result = _augmented(f, p, y0, t0, t1, direction, options, True)
        alpha = f(t, (q, w), p)[1]  # dw/dt at the standstill
        dq, dw = _state_tangent(f, p, y0, t0, s, dp, dy0, dt0)
        dt = jnp.where(fired, -dw / jnp.where(alpha == 0, 1.0, alpha), dt1)
        return (t, q, fired, result), (dt, dq + w * dt, _no_tangent(fired), _no_tangent(result))

    return stop


def _routed(model: Model, options: SensitivityOptions) -> Model:
    """The model, checked to carry joint friction these routes can differentiate: none, or
    the regularized law in every element (see :class:`assurjax.JointFriction`), and that
    by ``method="loop"`` alone. The exact law's Coulomb signs come from a direction of
    motion and switch at events (segments), which one vector field of (q, w) does not carry.
    The regularized law's turns near a relative rest are steep in time (over ~v_s / dw/dt),
    which the loop's steps resolve, as the state's do, and the quadrature's fixed panels do
    not (the slider-crank from rest, v_s = 0.005-0.05: d q(0.6 s)/d mu -0.0748 with 16
    panels, -0.0671 with 64, -0.05069 with 256, against -0.050702 by differences)."""
    check_has_inertia(model.mechanism)
    frictions = frictions_of(model.loads)
    if not frictions:
        return model
    if not smoothed_only(frictions):
        exact = [f.pair for f in frictions if f.smoothing is None]
        raise AssurjaxError(f"joint friction: the forward-sensitivity routes (adjoint='quadrature' or 'sensitivity') do "
                            f"not carry the exact law's Coulomb signs (stick and slip), which {len(exact)} element(s) "
                            f"have (the first: '{exact[0]}', no smoothing); use "
                            "adjoint='recursive' (reverse mode through the simulation itself), adjoint='forward' "
                            "(forward mode through it: jax.jvp / jax.jacfwd, the quicker to compile for a few "
                            "parameters), or the regularized law (smoothing=...) in every element with "
                            "adjoint='sensitivity'")
    if options.method != "loop":
        raise AssurjaxError("joint friction with the regularized law: adjoint='quadrature' (method 'quadrature') does "
                            "not resolve its steep turns near a rest in time (its derivatives were wrong by up to 50 %); "
                            "use adjoint='sensitivity' (method 'loop') or adjoint='recursive'")
    return model


def _initial(scene, q0, omega0):
    state = scene.state
    q0 = state.get("q0", 0.0) if q0 is None else q0
    omega0 = state.get("omega0", 0.0) if omega0 is None else omega0
    return jnp.stack([jnp.asarray(q0, dtype=float), jnp.asarray(omega0, dtype=float)])


SENSITIVITY_SETTINGS = ("solver", "rtol", "atol", "dt", "max_steps")


def _options(scene, settings: dict) -> SensitivityOptions:
    own = {k: settings.pop(k) for k in ("method", "panels", "nodes") if k in settings}
    unknown = set(settings) - set(SENSITIVITY_SETTINGS)
    if unknown:
        raise AssurjaxError(f"the sensitivity routes support the settings {list(SENSITIVITY_SETTINGS) + list(own)}; "
                            f"got also {sorted(unknown)}")
    dt = settings.get("dt", scene.simulation.get("dt", None))
    options = SensitivityOptions(settings=settings_from(scene, **settings), dt=dt, **own)
    if options.method not in ("loop", "quadrature"):
        raise AssurjaxError(f"sensitivity method must be 'loop' or 'quadrature', got {options.method!r}")
    counts = (options.panels, options.nodes)
    if (not all(isinstance(n, (int, np.integer)) and not isinstance(n, bool) for n in counts) or options.panels < 1
            or not 2 <= options.nodes <= MAX_NODES or options.panels * options.nodes > MAX_QUADRATURE_NODES):
        raise AssurjaxError(f"quadrature needs integers panels >= 1 and nodes from 2 to {MAX_NODES}, "
                            f"panels * nodes at most {MAX_QUADRATURE_NODES:,}; got panels={options.panels!r}, "
                            f"nodes={options.nodes!r}")
    return options


MAX_NODES = 64  # Gauss-Legendre nodes per panel (NumPy's rule loses accuracy past ~100)
MAX_QUADRATURE_NODES = 100_000  # nodes in all: each holds a reverse pass's state


def final_state_sensitivity(scene, t1, *, q0=None, omega0=None, mechanism=None, gravity=None, loads=None, **settings):
    """(q(T), omega(T)) at ``t1`` (s) and the diffrax result code, from the scene's
    initial state, differentiable by forward sensitivities (see the module docstring).

    Derivatives (``jax.grad``/``jax.jacfwd``/``jax.jvp``) with respect to every
    floating-point array of the mechanism, gravity and loads, and to ``q0``, ``omega0``,
    ``t0``, ``t1``, cost one augmented solve. ``settings``: fields of
    :class:`SensitivityOptions`: ``solver`` (default ``"tsit5"``), ``rtol``, ``atol``
    (1e-8), ``dt`` (fixed step, s), ``max_steps``, ``method`` (``"loop"`` or
    ``"quadrature"``), ``panels``, ``nodes`` (quadrature).
    Fixed assembly branch, exact reduction, no stop events. Joint friction: the regularized
    law in every element (``smoothing``), by ``method="loop"`` alone.
    """
    options = _options(scene, settings)
    model = _routed(as_model(scene, mechanism=mechanism, gravity=gravity, loads=loads), options)
    t0 = jnp.asarray(scene.state.get("t0", 0.0), dtype=float)
    y, result = _final_state_program(model, _initial(scene, q0, omega0), t0, jnp.asarray(t1, dtype=float), options)
    return y[0], y[1], _friction_code(model, result)


def standstill_time_sensitivity(scene, *, t1=None, q0=None, omega0=None, mechanism=None, gravity=None, loads=None, **settings):
    """The first standstill time t* (s) after the scene's initial state (omega = 0 against
    the direction of motion; from rest, the direction the loads start it in), an ok flag
    (False: no standstill before ``t1``; t* is then ``t1``) and the diffrax result code.
    Where the mechanism does not assemble at t* (the motion passed a lock-up before it,
    which this route, without assembly checks, integrates through), t* is NaN and ok False.

    dt*/dP = -(dw/dP at t*) / (dw/dt at t*) (implicit function theorem on w(t*, P) = 0),
    with dw/dP from the forward sensitivities integrated up to the event: one augmented
    solve for the whole gradient.
    """
    model = as_model(scene, mechanism=mechanism, gravity=gravity, loads=loads)
    t, q, fired, result = standstill_state(scene, t1=t1, q0=q0, omega0=omega0, mechanism=mechanism, gravity=gravity,
                                           loads=loads, **settings)
    assembles = jnp.all(assembled(model.mechanism, q))
    return jnp.where(assembles, t, jnp.nan), fired & assembles, result


def standstill_state(scene, *, t1=None, q0=None, omega0=None, mechanism=None, gravity=None, loads=None, **settings):
    """(t*, q(t*), ok, result code) of :func:`standstill_time_sensitivity`, q(t*) as it was
    integrated, whether or not the mechanism assembles there (its callers check that)."""
    options = _options(scene, settings)
    model = _routed(as_model(scene, mechanism=mechanism, gravity=gravity, loads=loads), options)
    y0 = _initial(scene, q0, omega0)
    t0 = jnp.asarray(scene.state.get("t0", 0.0), dtype=float)
    t1 = jnp.asarray(scene.state.get("t1", 1.0) if t1 is None else t1, dtype=float)
    force = generalized_force(model.mechanism, model.gravity, model.loads, y0[0], y0[1], t0)
    direction = jax.lax.stop_gradient(jnp.where(y0[1] != 0, jnp.sign(y0[1]), jnp.sign(force)))
    t, q, fired, result = _standstill_program(model, y0, t0, t1, direction, options)
    return t, q, fired, _friction_code(model, result)


def _friction_code(model: Model, result):
    """The result code, failed where a friction value traced into the run is out of range
    (:func:`~assurjax.dynamics._solve.friction_result`)."""
    checked = friction_result(model.loads, RESULTS.successful)
    return jnp.where(checked == RESULTS.successful, result, result_value(checked))


# Each route as one program compiled once per model structure and options, the model's arrays
# traced: built at each call, its closures were traced and compiled anew under a jax.grad the
# user has not jitted (the slider-crank's derivative in gravity: 2-2.7 s at every call)
@jit
def _final_state_program(model: Model, y0, t0, t1, options: SensitivityOptions):
    p, rebuild = _split(model)
    return _final_state_fn(_field(rebuild), options)(p, y0, t0, t1)


@jit
def _standstill_program(model: Model, y0, t0, t1, direction, options: SensitivityOptions):
    p, rebuild = _split(model)
    return _standstill_fn(_field(rebuild), options)(p, y0, t0, t1, direction)
