"""Gradient-based synthesis: any optax optimizer over a :class:`Design`, keeping designs assemblable."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from .._errors import AssemblyError, AssurjaxError
from .._jit import jit
from .._sweep import _progress_bar
from ._design import Design


class History(eqx.Module):
    """One entry per accepted step (entry 0: the starting design).

    ``loss``: objective value; ``grad_norm``: 2-norm of the gradient with respect
    to the unconstrained variables; ``time``: wall time since the start (s,
    compilation included); ``evaluations``: cumulative objective+gradient
    evaluations; ``backtracks``: step halvings needed to stay assemblable;
    ``aux``: the objective's auxiliary output per step (when it has one);
    ``grad``: the gradient with respect to the unconstrained variables per step
    (a pytree like ``z``, each leaf stacked over steps).
    """

    loss: np.ndarray
    grad_norm: np.ndarray
    time: np.ndarray
    evaluations: np.ndarray
    backtracks: np.ndarray
    aux: Any = None
    grad: Any = None


class SynthesisResult(eqx.Module):
    """What :func:`optimize` found.

    ``mechanism``: the best design found (lowest loss among assemblable designs);
    ``values``: its selected parameters; ``z``: its unconstrained variables;
    ``loss``: its objective; ``status``: ``"target"`` (loss reached ``target``),
    ``"converged"`` (relative loss change below ``rtol`` for ``patience`` steps),
    ``"steps"`` (ran out of steps) or ``"infeasible"`` (no assemblable step
    even after backtracking; ``message`` says more); ``evaluations``: objective+gradient
    evaluations used; ``history``: a :class:`History`.
    """

    mechanism: Any
    values: Any
    z: Any
    loss: float
    status: str = eqx.field(static=True)
    message: str = eqx.field(static=True)
    evaluations: int = eqx.field(static=True)
    history: History


def assembles(mechanism_or_flags) -> jax.Array:
    """True when every ``ok`` flag is True: pass a Kinematics/Pose/Reduction or a bool array."""
    ok = getattr(mechanism_or_flags, "ok", mechanism_or_flags)
    return jnp.all(ok)


def _split_objective(objective: Callable, has_aux: bool):
    """Normalize the objective to ``tree -> (loss, (feasible, aux))``."""

    def normalized(tree):
        out = objective(tree)
        if has_aux:
            loss, aux = out
        else:
            loss, aux = out, None
        feasible = jnp.array(True)
        if isinstance(aux, dict) and "ok" in aux:
            feasible = jnp.all(aux["ok"])
        return loss, (feasible, aux)

    return normalized


def optimize(
    design: Design,
    objective: Callable[[Any], Any],
    optimizer: optax.GradientTransformation,
    steps: int,
    *,
    has_aux: bool = False,
    feasible: Callable[[Any], jax.Array] | None = None,
    target: float | None = None,
    rtol: float = 0.0,
    patience: int = 10,
    max_backtracks: int = 10,
    progress: bool | None = None,
    callback: Callable[[int, float, Any], None] | None = None,
) -> SynthesisResult:
    """Minimize ``objective(design.build(z))`` over the unconstrained variables ``z`` with ``optimizer``.

    **Arguments:**
    - ``objective``: pure JAX function of the built mechanism (or scene) returning
      a scalar loss, or ``(loss, aux)`` with ``has_aux=True``. When ``aux`` is a
      dict with an ``"ok"`` entry (e.g. ``Kinematics.ok``), the design must
      have every flag True to be accepted.
    - ``optimizer``: any ``optax.GradientTransformation`` (e.g. ``optax.adam(1e-2)``).
    - ``steps``: maximum number of optimizer steps.
    - ``feasible``: optional extra test ``mechanism -> bool`` (e.g. a minimum
      transmission angle).
    - ``target``: stop as soon as the loss is at or below it.
    - ``rtol``/``patience``: stop when the best loss improved by less than
      ``rtol`` (relative) over the last ``patience`` steps.
    - ``max_backtracks``: a step that leads to a design that cannot assemble (or
      a non-finite loss or gradient) is halved up to this many times; then the
      run stops with status ``"infeasible"``. Such designs are never scored.
    - ``progress``: tqdm bar (default: only when stderr is a terminal).
    - ``callback(step, loss, mechanism)``: called after every accepted step.

    Raises :class:`AssemblyError` if the starting design cannot assemble.
    """
    if steps < 0:
        raise AssurjaxError(f"steps must be non-negative, got {steps}")
    evaluate = _evaluator(design, _split_objective(objective, has_aux), feasible)
    update = jax.jit(optimizer.update)
    z = design.init()
    opt_state = optimizer.init(z)
    start = time.perf_counter()
    loss, grad, ok, aux = evaluate(z)
    n_eval = 1
    if not _acceptable(loss, grad, ok):
        raise AssemblyError("optimize: the starting design " + _why(loss, grad, ok))
    rec = _Recorder()
    rec.add(loss, grad, time.perf_counter() - start, n_eval, 0, aux)
    best = (float(loss), z)
    status, message = "steps", f"ran {steps} steps"
    bar = _progress_bar(steps, progress, "optimize", unit="step")
    for step in range(1, steps + 1):
        updates, new_state = update(grad, opt_state, z)
        for k in range(max_backtracks + 1):
            scale = 0.5**k
            z_try = jax.tree.map(lambda a, u: a + scale * u, z, updates)
            loss_t, grad_t, ok_t, aux_t = evaluate(z_try)
            n_eval += 1
            if _acceptable(loss_t, grad_t, ok_t):
                break
        else:
            status = "infeasible"
            message = f"step {step}: every trial design after {max_backtracks} halvings " + _why(loss_t, grad_t, ok_t)
            break
        z, opt_state, loss, grad, aux = z_try, new_state, loss_t, grad_t, aux_t
        rec.add(loss, grad, time.perf_counter() - start, n_eval, k, aux)
        if float(loss) < best[0]:
            best = (float(loss), z)
        bar.update(1)
        bar.set_postfix(loss=f"{float(loss):.4g}")
        if callback is not None:
            callback(step, float(loss), design.build(z))
        if target is not None and float(loss) <= target:
            status, message = "target", f"loss {float(loss):.6g} reached the target {target:.6g} at step {step}"
            break
        if rtol > 0 and step >= patience and _stalled(rec.loss, rtol, patience):
            status, message = "converged", f"best loss improved by less than {rtol:g} (relative) over {patience} steps"
            break
    bar.close()
    best_loss, best_z = best
    return SynthesisResult(
        mechanism=design.build(best_z),
        values=design.values(best_z),
        z=best_z,
        loss=best_loss,
        status=status,
        message=message,
        evaluations=n_eval,
        history=rec.history(),
    )


def _evaluator(design: Design, objective, feasible):
    """One jitted call: loss, gradient (w.r.t. z), feasibility and aux at z."""

    @jit
    def evaluate(design, z):
        def loss_of(z):
            tree = design.build(z)
            loss, (ok, aux) = objective(tree)
            if feasible is not None:
                ok = ok & jnp.all(feasible(tree))
            return loss, (ok, aux)

        (loss, (ok, aux)), grad = jax.value_and_grad(loss_of, has_aux=True)(z)
        return loss, grad, ok, aux

    return lambda z: evaluate(design, z)


def _acceptable(loss, grad, ok) -> bool:
    finite_grad = all(bool(jnp.all(jnp.isfinite(g))) for g in jax.tree.leaves(grad))
    return bool(ok) and bool(jnp.isfinite(loss)) and finite_grad


def _why(loss, grad, ok) -> str:
    if not bool(ok):
        return "cannot assemble (some Kinematics.ok flag is False or the feasibility test fails)"
    if not bool(jnp.isfinite(loss)):
        return f"has a non-finite objective ({float(loss)})"
    return "has a non-finite gradient"


def _stalled(losses: list, rtol: float, patience: int) -> bool:
    old = min(losses[: len(losses) - patience])
    new = min(losses[len(losses) - patience :])
    return old - new <= rtol * abs(old)


class _Recorder:
    def __init__(self):
        self.loss, self.grad_norm, self.time, self.evals, self.backtracks, self.aux = [], [], [], [], [], []
        self.grads = []

    def add(self, loss, grad, elapsed, n_eval, backtracks, aux):
        self.loss.append(float(loss))
        self.grad_norm.append(math.sqrt(sum(float(jnp.sum(g**2)) for g in jax.tree.leaves(grad))))
        self.time.append(elapsed)
        self.evals.append(n_eval)
        self.backtracks.append(backtracks)
        self.aux.append(aux)
        self.grads.append(jax.device_get(grad))

    def history(self) -> History:
        aux = None
        if any(a is not None for a in self.aux):
            aux = jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *self.aux)
        return History(
            loss=np.asarray(self.loss),
            grad_norm=np.asarray(self.grad_norm),
            time=np.asarray(self.time),
            evaluations=np.asarray(self.evals),
            backtracks=np.asarray(self.backtracks),
            aux=aux,
            grad=jax.tree.map(lambda *gs: np.stack([np.asarray(g) for g in gs]), *self.grads),
        )
