"""The integrated state as one array where diffrax steps it.

diffrax steps a PyTree leaf by leaf: each leaf's share of a stage (its combination of the
stages, its slot in their buffer, its part of the error estimate) is an operation of its
own, and on a CPU XLA runs each as a call of its own (~20 ns each, a few per leaf and
stage), where a scalar's arithmetic is a few flops. So in diffrax's forward mode (see
:func:`packing_of`) the state's scalars (q, w, and the work and dissipated work when asked
for) and its vectors (the tracked angles, the friction elements' rates) go to diffrax as
one array, and the state is unpacked wherever the package reads it (the events, the
step-size controller, the saved states; the vector field inside its region, where the
unpacking and the packing of the rates cost no call of their own). The vectors go in only
while the stages' buffer stays under THREADED_BYTES, over which XLA's CPU runtime runs a
loop's calls across threads: else they are stepped apart (the Watt six-bar with its 7
friction rates in the array: 3.4 -> 5.8 ms a run).

At the same boundary diffrax gets the vector field's arguments as their leaves
(:func:`flattened`: no empty tuple for its backsolve) and the term and events as Modules
(:class:`_OnState`: the same callables from call to call, for its jit's cache).
"""

from __future__ import annotations

import math

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._jit import stays_unthreaded
from ._field import State


class Packed(eqx.Module):
    """A state as diffrax steps it: its packed fields in one array (..., n), the fields
    stepped apart as they are (None where there are none), see :class:`Packing`."""

    values: Array
    apart: tuple | None


class Packing(eqx.Module):
    """Where each of a :class:`State`'s fields goes: ``kinds`` per field, in the order of
    the fields, ``"scalar"`` or a vector's length (into the packed array), ``"apart"``
    (stepped as it is) or None (absent); or, ``kinds`` None, no packing (the state stepped
    as it is)."""

    kinds: tuple | None = eqx.field(static=True)

    def pack(self, y: State) -> Packed | State:
        if self.kinds is None:
            return y
        parts = [v[..., None] if kind == "scalar" else v for v, kind in zip(y, self.kinds) if _packed(kind)]
        # None, not (), with nothing apart: diffrax's backsolve cannot pass an empty tuple (design notes)
        apart = tuple(v for v, kind in zip(y, self.kinds) if kind == "apart") or None
        return Packed(jnp.concatenate(parts, axis=-1), apart)

    def unpack(self, z: Packed | State) -> State:
        """A packed state, or a stack of them (saved states: leading axes kept), as a State."""
        if self.kinds is None:
            return z
        start, apart, fields = 0, iter(z.apart or ()), []
        for kind in self.kinds:
            if kind == "scalar":
                fields.append(z.values[..., start])
                start += 1
            elif _packed(kind):
                fields.append(z.values[..., start:start + kind])
                start += kind
            else:
                fields.append(next(apart) if kind == "apart" else None)
        return State(*fields)

    def view(self, y):
        """``y`` as a State where it is packed; anything else as it is (the augmented state
        of a backward solve, which the controllers also step)."""
        return self.unpack(y) if isinstance(y, Packed) else y


def _packed(kind) -> bool:
    return kind == "scalar" or isinstance(kind, int)


UNPACKED = Packing(None)


def packing_of(y: State, adjoint: str, solver: diffrax.AbstractSolver) -> Packing:
    """The packing of states like ``y`` for a solve by ``solver`` with that ``adjoint``
    setting: packed for diffrax's forward mode (``simulate``'s; jvp and jacfwd cost the
    same either way), as they are for the reverse-mode adjoints, whose backward pass pays
    more for the packing's slices and stacks than the steps save (the Watt six-bar's
    gradient by the recursive adjoint 2.5 -> 3.0 ms packed). The scalars are packed; the
    vectors too while the stages' buffer stays under THREADED_BYTES, else they are stepped
    apart (the Watt six-bar's 7 friction rates with its 4 scalars over 7 stages: its run
    3.4 -> 5.8 ms packed, where the press's 4 rates and 4 scalars gain 37 calls a step)."""
    if adjoint != "forward":
        return UNPACKED
    sizes = [None if v is None else math.prod(jnp.shape(v)) for v in y]
    packs_vectors = stays_unthreaded(_stages(solver) * sum(n for n in sizes if n is not None))
    return Packing(tuple(None if v is None else "scalar" if jnp.ndim(v) == 0 else n if packs_vectors else "apart"
                         for v, n in zip(y, sizes)))


def _stages(solver: diffrax.AbstractSolver) -> int:
    """The stages a step of ``solver`` keeps in its buffer (a Runge-Kutta tableau's; else 1)."""
    tableau = getattr(solver, "tableau", None)
    return 1 if tableau is None else len(tableau.c) + 1


class Rebuilt(eqx.Module):
    """The args from their leaves (see :func:`flattened`)."""

    treedef: object = eqx.field(static=True)

    def __call__(self, leaves):
        return jax.tree.unflatten(self.treedef, leaves)


def flattened(args) -> tuple[list, Rebuilt]:
    """(diffrax's args: the leaves of ``args``, what rebuilds ``args`` from them). diffrax's
    backsolve stops the gradient of its augmented state, which holds the args, with
    ``eqx.tree_at``, and that cannot pass an empty tuple (a Model without loads failed
    there); a list of leaves holds none."""
    leaves, treedef = jax.tree.flatten(args)
    return leaves, Rebuilt(treedef)


class _OnState(eqx.Module):
    """``fn(t, State, args, ...)`` called by diffrax with a packed state (and the args'
    leaves where ``rebuild`` is given). Modules, not closures: diffrax's jit then sees the
    same callable from call to call (a closure made at each call compiled the simulation
    again at every call of a function not jitted as a whole, ``jax.grad(final_state)``)."""

    packing: Packing
    fn: object = eqx.field(static=True)
    rebuild: Rebuilt | None = None

    def args(self, args):
        return args if self.rebuild is None else self.rebuild(args)


class _PackedField(_OnState):
    def __call__(self, t, z, args):
        return self.fn(t, z, self.args(args), self.packing)


class _PackedCondition(_OnState):
    def __call__(self, t, y, args, **kwargs):
        return self.fn(t, self.packing.unpack(y), self.args(args), **kwargs)


def packed_term(packing: Packing, field, rebuild: Rebuilt | None = None) -> diffrax.ODETerm:
    """diffrax's term of ``field(t, z, args, packing)``: the rates of a packed state z, packed
    alike (``_field.packed_vector_field``, which unpacks where it costs least); ``rebuild``:
    the args from what diffrax passes, see :func:`flattened`."""
    return diffrax.ODETerm(_PackedField(packing, field, rebuild))


def packed_event(packing: Packing, event: diffrax.Event | None, rebuild: Rebuilt | None = None) -> diffrax.Event | None:
    """``event``, its conditions read on the unpacked state (``rebuild``: as :func:`packed_term`'s)."""
    if event is None:
        return None
    return diffrax.Event(jax.tree.map(lambda cond: _PackedCondition(packing, cond, rebuild), event.cond_fn),
                         event.root_finder, event.direction)


def unpacked(packing: Packing, sol):
    """A diffrax solution with its saved states unpacked (one SaveAt, or a list of them)."""
    ys = [packing.unpack(y) for y in sol.ys] if isinstance(sol.ys, list) else packing.unpack(sol.ys)
    return eqx.tree_at(lambda s: s.ys, sol, ys)
