"""The integrated state's scalars as one array where diffrax steps it.

diffrax steps a PyTree leaf by leaf: each leaf's share of a stage (its combination of the
stages, its slot in their buffer, its part of the error estimate) is an operation of its
own, and on a CPU XLA runs each as a call of its own (~20 ns each, a few per leaf and
stage), where a scalar's arithmetic is a few flops. So in diffrax's forward mode (see
:func:`packing_of`) the state's scalars (q, w, and the work and dissipated work when asked
for) go to diffrax as one array, the vectors (the tracked angles, the friction elements'
rates) as they are, and the state is unpacked wherever the package reads it (the vector
field, the events, the step-size controller, the saved states). The vectors stay apart: in
one array with the scalars, the stages' buffer of a mechanism with 7 friction elements
passed 512 bytes, over which XLA's CPU runtime runs a loop's calls across threads (the Watt
six-bar with friction: 3.4 -> 5.8 ms a run).

At the same boundary diffrax gets the vector field's arguments as their leaves
(:func:`flattened`: no empty tuple for its backsolve) and the term and events as Modules
(:class:`_OnState`: the same callables from call to call, for its jit's cache).
"""

from __future__ import annotations

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from ._field import State


class Packed(eqx.Module):
    """A state as diffrax steps it: its scalars stacked (..., n), its other fields as
    they are (None where absent), see :class:`Packing`."""

    scalars: Array
    vectors: tuple | None


class Packing(eqx.Module):
    """Which of a :class:`State`'s fields are scalars (packed together), which vectors
    (kept apart) and which absent: ``kinds`` per field, in the order of the fields; or,
    ``kinds`` None, no packing (the state stepped as it is)."""

    kinds: tuple | None = eqx.field(static=True)  # per field: "scalar", "vector" or None

    def pack(self, y: State) -> Packed | State:
        if self.kinds is None:
            return y
        scalars = [v for v, kind in zip(y, self.kinds) if kind == "scalar"]
        # None, not (), without vectors: diffrax's backsolve cannot pass an empty tuple (design notes)
        vectors = tuple(v for v, kind in zip(y, self.kinds) if kind == "vector") or None
        return Packed(jnp.stack(scalars, axis=-1), vectors)

    def unpack(self, z: Packed | State) -> State:
        """A packed state, or a stack of them (saved states: leading axes kept), as a State."""
        if self.kinds is None:
            return z
        scalars, vectors, fields = iter(range(z.scalars.shape[-1])), iter(z.vectors or ()), []
        for kind in self.kinds:
            fields.append(z.scalars[..., next(scalars)] if kind == "scalar" else next(vectors) if kind == "vector" else None)
        return State(*fields)

    def view(self, y):
        """``y`` as a State where it is packed; anything else as it is (the augmented state
        of a backward solve, which the controllers also step)."""
        return self.unpack(y) if isinstance(y, Packed) else y


UNPACKED = Packing(None)


def packing_of(y: State, adjoint: str) -> Packing:
    """The packing of states like ``y`` for a solve with that ``adjoint`` setting: packed
    for diffrax's forward mode (``simulate``'s; jvp and jacfwd cost the same either way),
    as they are for the reverse-mode adjoints, whose backward pass pays more for the
    packing's slices and stacks than the steps save (the Watt six-bar's gradient by the
    recursive adjoint 2.5 -> 3.0 ms packed)."""
    if adjoint != "forward":
        return UNPACKED
    return Packing(tuple(None if v is None else "scalar" if jnp.ndim(v) == 0 else "vector" for v in y))


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
        return self.packing.pack(self.fn(t, self.packing.unpack(z), self.args(args)))


class _PackedCondition(_OnState):
    def __call__(self, t, y, args, **kwargs):
        return self.fn(t, self.packing.unpack(y), self.args(args), **kwargs)


def packed_term(packing: Packing, field, rebuild: Rebuilt | None = None) -> diffrax.ODETerm:
    """diffrax's term of ``field(t, State, args) -> State`` on packed states (``rebuild``:
    the args from what diffrax passes, see :func:`flattened`)."""
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
