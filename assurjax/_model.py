"""The Model: what every dynamics stage takes (mechanism, gravity, loads)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ._errors import AssurjaxError
from ._loads import AbstractLoad, check_loads
from ._repr import value_pdoc
from ._mechanism import Mechanism, sketch_hint
from ._values import check_value, concrete, numbers_problem


class Model(eqx.Module):
    """A mechanism with the loads acting on it: the input of every dynamics stage
    (reduction, simulation, kinetostatics, sensitivities).

    ``mechanism``: the :class:`assurjax.Mechanism`; ``gravity``: a 2-vector (m/s^2,
    default 0); ``loads``: a sequence of loads (:class:`assurjax.Spring`, ...; one load
    alone is taken as the only one). Every
    array inside is a traced leaf: a Model can be vmapped and differentiated.

    **Example:**
    >>> model = assurjax.Model(mechanism, gravity=(0.0, -9.81), loads=(assurjax.Drive(2.0),))
    >>> model = assurjax.load_scene("watt_sixbar").model
    """

    __pdoc__ = value_pdoc  # repr: scalars and small arrays by value, long tables cut

    mechanism: Mechanism
    gravity: Array
    loads: tuple

    def __init__(self, mechanism: Mechanism, gravity=None, loads=()):
        if not isinstance(mechanism, Mechanism):
            raise AssurjaxError(f"Model: expected an assurjax.Mechanism, got {type(mechanism).__name__}{sketch_hint(mechanism)}")
        self.mechanism = mechanism
        if gravity is None:
            gravity = np.zeros(2)
        if (problem := numbers_problem(gravity)) is not None:  # before JAX reads "down" and names no field
            raise AssurjaxError(f"Model: gravity {problem}")
        # an array already (a scene's, or traced) is kept as it is: no device round trip per call
        self.gravity = gravity if isinstance(gravity, jax.Array) else jnp.asarray(gravity, dtype=float)
        if self.gravity.shape != (2,):
            raise AssurjaxError(f"Model: gravity must be a 2-vector (m/s^2), got shape {self.gravity.shape}")
        check_value(AssurjaxError, "Model: gravity", gravity)
        self.loads = load_tuple(loads)
        check_loads(mechanism, self.loads)


def load_tuple(loads, what: str = "Model") -> tuple:
    """``loads`` as a tuple; one load alone is the only one (as one point name is a list of one).
    ``what``: the function named in the error."""
    if isinstance(loads, AbstractLoad):
        return (loads,)
    if isinstance(loads, (str, bytes, Mapping)) or not isinstance(loads, Iterable):
        raise AssurjaxError(f"{what}: loads must be a sequence of loads or one load (assurjax.Spring, assurjax.JointFriction, ...), "
                            f"got {type(loads).__name__}")
    return tuple(loads)


def as_model(source, *, mechanism: Mechanism | None = None, gravity=None, loads=None, what: str | None = None) -> Model:
    """The :class:`Model` of a Scene, a Model or a bare Mechanism (no loads, no
    gravity), with any of its parts replaced. ``what``: the function named in the error."""
    if isinstance(source, Model):
        base = source
    elif isinstance(source, Mechanism):
        base = Model(source)
    elif isinstance(source, _scene_class()):
        base = source.model
    elif sketch_hint(source):
        raise AssurjaxError(f"{what + ': ' if what else ''}expected an assurjax Scene, Model or Mechanism, got "
                            f"{type(source).__name__}{sketch_hint(source, scene=True)}")
    else:  # any object with a scene's three parts
        try:
            base = Model(source.mechanism, source.gravity, source.loads)
        except AttributeError:
            raise AssurjaxError(f"{what + ': ' if what else ''}expected an assurjax Scene, Model or Mechanism, got "
                                f"{type(source).__name__}") from None
    if mechanism is None and gravity is None and loads is None:
        return base
    return Model(
        base.mechanism if mechanism is None else mechanism,
        base.gravity if gravity is None else gravity,
        base.loads if loads is None else loads,
    )


def massless_members(mechanism: Mechanism) -> np.ndarray:
    """Where no link has mass or moment of inertia: the indices of such members of a batch of
    mechanisms, [0] for one such mechanism, none where any value is traced."""
    total = 0.0
    for link in mechanism.links.values():
        mass, inertia = concrete(link.mass), concrete(link.inertia)
        if mass is None or inertia is None:
            return np.zeros(0, dtype=int)
        total = total + np.abs(mass) + np.abs(inertia)
    return np.flatnonzero(np.ravel(total) == 0.0)


def check_has_inertia(mechanism: Mechanism) -> None:
    """Raise :class:`AssurjaxError` where no link has mass or moment of inertia (in any
    member of a batch of mechanisms): the reduced inertia is then zero, and the equation of
    motion has no solution. Forward dynamics needs this; kinematics and statics do not.
    Traced values are not checked."""
    empty = massless_members(mechanism)
    if empty.size:
        batched = any(np.ndim(link.mass) for link in mechanism.links.values())
        member = f" (batch member {int(empty[0])})" if batched else ""
        raise AssurjaxError(f"mechanism '{mechanism.name}'{member}: no link has a mass or a moment of inertia, so its "
                            "reduced inertia is zero and its motion is undetermined; give the links masses (in a "
                            "sketch's link table: mass, inertia or density; in a scene file: [links.NAME] mass = ...). "
                            "Kinematics and statics need none.")


def _scene_class():
    from .scene._scene import Scene  # the scene package imports this module

    return Scene
