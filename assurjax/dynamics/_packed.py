"""The integrated state as one array where diffrax steps it.

diffrax steps a PyTree leaf by leaf: each leaf's share of a stage (its combination of
the stages, its slot in their buffer, its part of the error estimate) is an operation of
its own, and on a CPU XLA runs each as a call of its own (~20 ns each, a few per leaf and
stage). The reduced link's state is a handful of scalars and short vectors (q, w, the
quadratures, the tracked angles, the friction elements' rates), so it goes to diffrax
packed into one array, and is unpacked wherever the package reads it (the vector field,
the events, the step-size controller, the saved states). The press's step: 318 -> 288
calls without friction, 778 -> 673 with it (benchmarks/README.md).
"""

from __future__ import annotations

import math

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array

from ._field import State


class Packing(eqx.Module):
    """The layout of a :class:`State` packed into one array: each field's shape (None
    where the field is absent), in the order of the fields."""

    shapes: tuple = eqx.field(static=True)

    @property
    def size(self) -> int:
        return sum(math.prod(shape) for shape in self.shapes if shape is not None)

    def pack(self, y: State) -> Array:
        """One state -> its array (size,)."""
        return jnp.concatenate([jnp.ravel(v) for v in y if v is not None])

    def unpack(self, z: Array) -> State:
        """An array (..., size) -> its state(s), any leading axes kept (saved states)."""
        lead, start, fields = z.shape[:-1], 0, []
        for shape in self.shapes:
            if shape is None:
                fields.append(None)
                continue
            n = math.prod(shape)
            fields.append(z[..., start:start + n].reshape(lead + shape))
            start += n
        return State(*fields)

    def view(self, y):
        """``y`` as a State where it is a packed state (or a stack of them); anything else
        as it is (the augmented state of a backward solve, which the controllers also step)."""
        return self.unpack(y) if isinstance(y, jax.Array) and y.ndim >= 1 and y.shape[-1] == self.size else y


def packing_of(y: State) -> Packing:
    return Packing(tuple(None if v is None else tuple(jnp.shape(v)) for v in y))


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
