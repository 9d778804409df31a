"""The integrated state's scalars as one array where diffrax steps it.

diffrax steps a PyTree leaf by leaf: each leaf's share of a stage (its combination of the
stages, its slot in their buffer, its part of the error estimate) is an operation of its
own, and on a CPU XLA runs each as a call of its own (~20 ns each, a few per leaf and
stage), where a scalar's arithmetic is a few flops. So the state's scalars (q, w, and the
work and dissipated work when asked for) go to diffrax as one array, the vectors (the
tracked angles, the friction elements' rates) as they are, and the state is unpacked
wherever the package reads it (the vector field, the events, the step-size controller, the
saved states). The vectors stay apart: in one array with the scalars, the stages' buffer
of a mechanism with 7 friction elements passed 512 bytes, over which XLA's CPU runtime
runs a loop's calls across threads (the Watt six-bar with friction: 3.4 -> 5.8 ms a run).
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
    (kept apart) and which absent: ``kinds`` per field, in the order of the fields."""

    kinds: tuple = eqx.field(static=True)  # "scalar", "vector" or None

    def pack(self, y: State) -> Packed:
        scalars = [v for v, kind in zip(y, self.kinds) if kind == "scalar"]
        # None, not (), without vectors: diffrax's backsolve cannot pass an empty tuple (design notes)
        vectors = tuple(v for v, kind in zip(y, self.kinds) if kind == "vector") or None
        return Packed(jnp.stack(scalars, axis=-1), vectors)

    def unpack(self, z: Packed) -> State:
        """A packed state, or a stack of them (saved states: leading axes kept), as a State."""
        scalars, vectors, fields = iter(range(z.scalars.shape[-1])), iter(z.vectors or ()), []
        for kind in self.kinds:
            fields.append(z.scalars[..., next(scalars)] if kind == "scalar" else next(vectors) if kind == "vector" else None)
        return State(*fields)

    def view(self, y):
        """``y`` as a State where it is packed; anything else as it is (the augmented state
        of a backward solve, which the controllers also step)."""
        return self.unpack(y) if isinstance(y, Packed) else y


def packing_of(y: State) -> Packing:
    return Packing(tuple(None if v is None else "scalar" if jnp.ndim(v) == 0 else "vector" for v in y))


def packed_term(packing: Packing, field) -> diffrax.ODETerm:
    """diffrax's term of ``field(t, State, args) -> State`` on packed states."""
    return diffrax.ODETerm(lambda t, z, args: packing.pack(field(t, packing.unpack(z), args)))


def packed_event(packing: Packing, event: diffrax.Event | None) -> diffrax.Event | None:
    """``event``, its conditions read on the unpacked state."""
    if event is None:
        return None

    def on_state(cond):
        return lambda t, y, args, **kwargs: cond(t, packing.unpack(y), args, **kwargs)

    return diffrax.Event(jax.tree.map(on_state, event.cond_fn), event.root_finder, event.direction)


def unpacked(packing: Packing, sol):
    """A diffrax solution with its saved states unpacked (one SaveAt, or a list of them)."""
    ys = [packing.unpack(y) for y in sol.ys] if isinstance(sol.ys, list) else packing.unpack(sol.ys)
    return eqx.tree_at(lambda s: s.ys, sol, ys)
