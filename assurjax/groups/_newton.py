"""Iterative Assur groups: a Newton solve (optimistix) on a few link angles, with
branch continuity by continuation and derivatives by the implicit function theorem.

Groups of class III and higher have no closed-form position analysis. Each such
group here chooses two link angles ``z`` (rad) as unknowns and a smooth residual
``F(z, inputs) = 0`` (two closure conditions). The solution is found in three stages:

1. **Reference**: at the group's reference coordinate ``guess_q`` (the scene's
   ``[state] q0`` unless the group gives ``guess_q``), Newton starts from the angles
   implied by the user's ``guess`` (approximate global positions of the internal
   joints). The guess selects the assembly branch.
2. **Continuation**: from the reference to the queried q in steps of q of at most
   1/``substeps`` of the way; each step predicts with the tangent dz/dq = -F_z^-1 F_q
   and corrects with a loose Newton solve, and is halved unless the corrected angles
   fit the step (trapezoidal rule with the tangents at both ends): a fixed step lands
   on the other branch where it passes close (near a singular configuration) or
   steps past a limit position. The earlier groups move with the
   mechanism at every intermediate q, so the path is the mechanism's own motion and
   the branch is the one reached continuously from the reference. For a crank the
   step q - guess_q is wrapped to (-pi, pi]. The position analysis does this for all
   iterative groups at once (``assurjax._positions``); a group itself only solves
   from a starting point: its guess (``Placement.from_guess``) or a predictor.
   With ``positions(..., near=angles)`` (e.g. the previous sample of a sweep, see
   :func:`assurjax.positions_tracked`) the given link angles are the predictor instead and
   stages 1-2 are skipped: the cheapest way to stay on a branch along a path.
3. **Final solve** at q from that predictor. Stages 1-2 run under
   ``stop_gradient``; only this solve is differentiated, implicitly
   (``optimistix.ImplicitAdjoint``: dz = -F_z^-1 F_p dp), so forward mode,
   nested forward mode (accelerations) and reverse mode never go through the
   iterations. Nested jvp works because optimistix's jvp rule re-enters its own
   implicit solve (its tangent is again implicitly differentiable), so no
   hand-written ``custom_jvp`` is needed; tests/test_iterative_groups.py checks
   second derivatives and reverse-over-forward gradients against finite differences.

A group that cannot assemble returns ``ok`` False (a sub-step or the final solve
did not converge, or the closure residual stays above tolerance); its values are
then finite but meaningless.
"""

from __future__ import annotations

import abc
import dataclasses
import numbers
from collections.abc import Callable, Iterable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array

from .._errors import MechanismError
from .._linalg import PlainLU
from .._listing import did_you_mean
from .._values import check_value, value_problem
from .._geometry import heading
from ._base import AbstractGroup, Link, Placement


def _tolerances(dtype) -> tuple[float, float]:
    """(Newton step tolerance, accepted closure residual) for a float dtype.

    The residuals are dimensionless (relative length errors), so the same
    numbers serve every mechanism scale. The step tolerance (rad) is not the round-off of
    the angles: a mechanism drawn 1000 times its size from the origin carries angles to
    ~1e-13 only, and Newton's steps never got below 100 eps there (ok False at every q but
    the drawn one); where Newton converges quadratically a last step of 1e-10 leaves an
    error of ~1e-20."""
    eps = float(jnp.finfo(dtype).eps)
    return max(1e-10, 100.0 * eps), max(1e-9, 1e3 * eps)


def newton_solve(residual: Callable, z0: Array, args: Any, *, max_steps: int, loose: bool = False,
                 from_drawing: bool = False) -> tuple[Array, Array]:
    """Root of ``residual(z, args)`` by optimistix's Newton from ``z0``.

    ``residual`` must be a global function (no closed-over arrays: everything
    differentiable goes through ``args``). Differentiation is implicit.
    ``loose``: stop at 1e-8 rad (closure 1e-6), enough for an intermediate
    continuation step whose only job is to stay on the branch. ``from_drawing``: z0 is the
    drawing (the guess), tested for a root that Newton's steps leave (see below).
    Returns (z, ok); z is finite even when the solve fails (then z0 is returned). Where
    the solve fails (non-finite input; a singular Jacobian, as at a start drawn exactly at
    a dead centre, where Newton's first step is 0/0) its derivative is 0 beside ok False
    (:class:`PlainLU`'s ``finite``), not an error raised from inside the program."""
    step_tol, f_tol = _tolerances(z0.dtype)
    if loose:
        step_tol, f_tol = max(step_tol, 1e-8), max(f_tol, 1e-6)
    solver = optx.Newton(rtol=step_tol, atol=step_tol, linear_solver=PlainLU())
    adjoint = optx.ImplicitAdjoint(linear_solver=PlainLU(finite=True))
    sol = optx.root_find(residual, solver, z0, args=args, max_steps=max_steps, adjoint=adjoint, throw=False)
    finite = jnp.all(jnp.isfinite(sol.value))
    left = jnp.asarray(False)
    if from_drawing:
        # a drawing that is a root already (a pose drawn at a singular configuration) from which
        # Newton's steps leave: they crossed the singular Jacobian onto another assembly (0.76 m
        # off a triad's drawing, said ok). The start stays, not ok: the pose has no velocity.
        # Tested on solves from the drawing only (at every solve: 5-15 % more on kinematics)
        start = jnp.max(jnp.abs(residual(jax.lax.stop_gradient(z0), jax.lax.stop_gradient(args))))
        left = (start <= 10.0 * float(jnp.finfo(z0.dtype).eps)) & (~finite | (jnp.max(jnp.abs(sol.value - z0)) > LEFT_START))
    z = jnp.where(finite & ~left, sol.value, z0)
    closure = jnp.max(jnp.abs(residual(jax.lax.stop_gradient(z), jax.lax.stop_gradient(args))))
    ok = (sol.result == optx.RESULTS.successful) & finite & ~left & (closure < f_tol)
    return z, ok


LEFT_START = 1e-6  # rad: Newton's root this far from a start that was a root already left it


def _stop(tree):
    return jax.tree.map(lambda x: jax.lax.stop_gradient(x) if eqx.is_array(x) else x, tree)


class IterativeGroup(AbstractGroup):
    """Base of the Assur groups solved by Newton iteration (class III triad, class IV).

    A subclass declares its unknown links (their frame angles are the unknowns z),
    its internal joints (the ones a ``guess`` places), and three pure functions of
    global external joint positions ``ext`` (a tuple in ``external_points()`` order,
    m) and local link geometry ``geo``: the static method ``residual(z, (ext, geo))``
    (a global function: optimistix differentiates through ``args`` only, never
    through closures), and the methods ``frames(z, ext, geo)`` and
    ``angles_from_guess(guess, ext, geo)``. The fields are shared: ``links`` and
    ``joints`` (static names, in the subclass's order), ``guess`` (internal joint ->
    approximate global position, m), ``guess_q`` (static float: the coordinate at
    which ``guess`` holds), ``substeps`` and ``max_steps`` (static ints).
    """

    name: str = eqx.field(static=True)
    links: tuple[str, ...] = eqx.field(static=True)
    joints: tuple[str, ...] = eqx.field(static=True)
    guess: dict[str, Array]
    guess_q: float | None = eqx.field(static=True, default=None)
    substeps: int = eqx.field(static=True, default=8)
    max_steps: int = eqx.field(static=True, default=32)

    def __check_init__(self):
        # equinox runs the subclasses' own checks (link and joint counts) first
        self.check_guess()

    @abc.abstractmethod
    def unknown_links(self) -> tuple[str, str]:
        """The two links whose frame angles are the unknowns."""

    @abc.abstractmethod
    def internal_points(self) -> tuple[str, ...]:
        """The group's internal joints: the points ``guess`` must place."""

    @abc.abstractmethod
    def geometry(self, links: dict[str, Link]) -> dict[str, Array]:
        """The local link data the residual and frames need."""

    # -- the position analysis --------------------------------------------------

    def solve(self, links: dict[str, Link], placed: Placement, q: Array):
        geo = self.geometry(links)
        ext = tuple(placed.point(p) for p in self.external_points())
        z0 = self.predictor(placed, ext, geo)
        z, ok = newton_solve(type(self).residual, jax.lax.stop_gradient(z0), (ext, geo), max_steps=self.max_steps,
                             loose=getattr(placed, "loose", False), from_drawing=self.starts_from_guess(placed))
        return self.frames(z, ext, geo), ok

    def starts_from_guess(self, placed: Placement) -> bool:
        """Whether the solve starts from the guess (the drawing), not from a predictor."""
        near = placed.near
        return not (near is not None and all(k in near for k in self.unknown_links())) and getattr(placed, "from_guess", False)

    def predictor(self, placed: Placement, ext, geo) -> Array:
        """Starting angles for the solve (no gradient flows through them): the
        predictor ``placed.near`` when it has the unknown links, else (stage 1) the
        angles implied by ``guess`` at the current external joints."""
        near = placed.near
        unknown = self.unknown_links()
        if near is not None and all(k in near for k in unknown):
            return _stop(jnp.stack([jnp.asarray(near[k], dtype=float) for k in unknown]))
        if getattr(placed, "from_guess", False):
            return self.angles_from_guess(_stop(self.guess), _stop(ext), _stop(geo))
        raise MechanismError(
            f"{self.describe()} is iterative: it needs starting angles (a branch predictor 'near' with the angles of "
            f"{list(unknown)}); solve it through assurjax.positions, which continues from its guess"
        )

    def check_guess(self) -> None:
        missing = [p for p in self.internal_points() if p not in self.guess]
        extra = [p for p in self.guess if p not in self.internal_points()]
        if missing or extra:
            raise MechanismError(
                f"{self.describe()}: 'guess' must give the approximate global position of each internal joint "
                f"{list(self.internal_points())}; missing {missing}, unknown {extra}"
            )
        for key in ("substeps", "max_steps"):
            value = getattr(self, key)
            if not 1 <= value <= ITERATION_LIMIT:
                raise MechanismError(f"{self.describe()}: {key} must be from 1 to {ITERATION_LIMIT}, got {value}")
        for p, v in self.guess.items():
            check_value(MechanismError, f"{self.describe()}: guess of point '{p}'", v, shape=(2,))
        if self.guess_q is not None:  # a static field: a plain number (an array is not hashable)
            if isinstance(self.guess_q, bool) or not isinstance(self.guess_q, numbers.Real):
                raise MechanismError(f"{self.describe()}: guess_q must be a plain number (the driving coordinate at which "
                                     f"the guess holds), got {type(self.guess_q).__name__}")
            check_value(MechanismError, f"{self.describe()}: guess_q", self.guess_q)


# Continuation substeps and Newton iterations per evaluation: every one is a solve inside
# every right-hand-side evaluation, so 1e7 of them hangs a run instead of helping it.
ITERATION_LIMIT = 1000


def angle_of(local_vector: Array, global_vector: Array) -> Array:
    """Frame angle (rad) of a link that maps ``local_vector`` onto the direction of ``global_vector``."""
    return heading(global_vector) - heading(local_vector)


# -- scene support ---------------------------------------------------------------


def parse_guess(fields, internal: Iterable[str]) -> dict[str, Array]:
    """The ``guess`` table of an iterative group: {internal joint: [x, y]} (m, global)."""
    raw = fields.raw("guess")
    internal = tuple(internal)
    if not isinstance(raw, dict):
        fields.fail("guess", f"expected a table of approximate global positions of the internal joints {list(internal)}, got {raw!r}")
    missing = [p for p in internal if p not in raw]
    extra = [p for p in raw if p not in internal]
    if missing or extra:
        fields.fail("guess", f"must place exactly the internal joints {list(internal)}; missing {missing}, unknown {extra}"
                             f"{did_you_mean(extra, missing)}")
    out = {}
    for p in internal:
        v = raw[p]
        if not (isinstance(v, list) and len(v) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)):
            fields.fail("guess", f"point '{p}': expected [x, y], got {v!r}")
        if (problem := value_problem(v)) is not None:
            fields.fail("guess", f"point '{p}': {problem}")
        out[p] = jnp.asarray(np.asarray(v, dtype=float))
    return out


def parse_options(fields) -> dict:
    """Optional fields shared by iterative groups: guess_q, substeps, max_steps."""
    opts: dict[str, Any] = {"guess_q": fields.number("guess_q") if fields.has("guess_q") else None}
    for key, default in (("substeps", 8), ("max_steps", 32)):
        opts[key] = fields.integer(key, default, at_most=ITERATION_LIMIT)
    return opts


def resolve_guess_q(mechanism, q0: float):
    """The mechanism with every iterative group's unset ``guess_q`` set to ``q0``
    (a scene's ``[state] q0``: guesses refer to it unless the group says otherwise)."""
    groups = tuple(
        dataclasses.replace(g, guess_q=float(q0)) if isinstance(g, IterativeGroup) and g.guess_q is None else g
        for g in mechanism.groups
    )
    if all(a is b for a, b in zip(groups, mechanism.groups)):
        return mechanism
    return eqx.tree_at(lambda m: m.groups, mechanism, groups)


# -- sweeps ------------------------------------------------------------------------


def iterative_unknowns(mechanism) -> tuple[str, ...]:
    """Names of the links whose angles (rad) the iterative groups solve for, two per
    group, in formation order. Their angles, e.g. carried from one time step or
    sample to the next, are what ``positions(..., near=...)`` takes as predictor."""
    return tuple(link for g in mechanism.groups if isinstance(g, IterativeGroup) for link in g.unknown_links())
