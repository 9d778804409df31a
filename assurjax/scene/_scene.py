"""The Scene: what a scene file describes, as Python objects."""

from __future__ import annotations

import dataclasses

import equinox as eqx
from jaxtyping import Array

from .._mechanism import Mechanism
from .._repr import value_pdoc


class Settings(dict):
    """A read-only, hashable dict (static settings must be hashable for jit)."""

    def __hash__(self):
        return hash(tuple(sorted((k, _freeze(v)) for k, v in self.items())))

    def _readonly(self, *args, **kwargs):
        raise TypeError("scene settings are read-only; use Scene.with_settings")

    __setitem__ = __delitem__ = update = pop = clear = setdefault = popitem = __ior__ = _readonly

    def __reduce__(self):  # pickle and copy rebuild it whole (the default sets items one by one)
        return (type(self), (dict(self),))


def _freeze(v):
    if isinstance(v, dict):
        return tuple(sorted((k, _freeze(x)) for k, x in v.items()))
    if isinstance(v, (list, tuple)):
        return tuple(_freeze(x) for x in v)
    return v


class Scene(eqx.Module):
    """A mechanism with its loads, initial state, solver settings and wanted outputs.

    Read one from a TOML file with :func:`assurjax.load_scene` (see the scene format
    in docs/scene-format.md) or build it from a dict with :func:`assurjax.scene_from_dict`.

    ``loads`` is a tuple of load objects (:class:`assurjax.PointForce`,
    :class:`assurjax.Couple`, :class:`assurjax.Spring`, :class:`assurjax.Damper`,
    :class:`assurjax.RotaryDamper`, :class:`assurjax.Drive`, :class:`assurjax.MotorLine`;
    all subclasses of :class:`assurjax.AbstractLoad`); ``gravity`` a 2-vector (m/s^2). ``state`` holds ``q0``, ``omega0`` (rad and rad/s for a crank,
    m and m/s for a slider), ``t0`` and ``t1`` (s). ``simulation`` holds solver
    settings (``solver``, ``rtol``, ``atol``, ``stop``, ``max_steps``...).
    ``outputs`` says what to compute: ``points`` (trajectories), ``angles``
    (links), ``reactions`` (joint names), ``energies`` (bool). ``notes``: what building a
    sketch had to choose (e.g. a mode at a singular drawn configuration).

    **Example:**
    >>> scene = assurjax.load_scene("watt_sixbar")
    >>> scene.with_settings(state={"q0": 1.0}).state["q0"]
    1.0
    """

    __pdoc__ = value_pdoc  # repr: scalars and small arrays by value, long tables cut

    mechanism: Mechanism
    gravity: Array
    loads: tuple
    state: Settings = eqx.field(static=True)
    simulation: Settings = eqx.field(static=True)
    outputs: Settings = eqx.field(static=True)
    name: str = eqx.field(static=True)
    description: str = eqx.field(static=True, default="")
    source: str = eqx.field(static=True, default="")
    notes: tuple[str, ...] = eqx.field(static=True, default=())

    @property
    def model(self):
        """The :class:`assurjax.Model` (mechanism, gravity, loads) of this scene."""
        from .._model import Model

        return Model(self.mechanism, self.gravity, self.loads)

    def replace_mechanism(self, mechanism: Mechanism) -> "Scene":
        """A copy with this ``mechanism`` (e.g. one changed by ``eqx.tree_at``), its values
        checked as the Mechanism's own (a NaN or negative mass set by tree_at ran, and failed
        as a load's NaN, or gave numbers) and the loads against it; traced values pass."""
        from .._loads import check_loads
        from .._mechanism import _check_values, check_mechanism

        check_mechanism(mechanism, "replace_mechanism")
        _check_values(mechanism)
        check_loads(mechanism, self.loads)
        return eqx.tree_at(lambda s: s.mechanism, self, mechanism)

    def with_loads(self, loads) -> "Scene":
        """A copy with these ``loads`` (a tuple of :class:`assurjax.AbstractLoad`; one load
        alone is the only one, as in :func:`assurjax.simulate`), checked against the mechanism.
        They replace the scene's: add one with ``scene.with_loads(scene.loads + (load,))``.
        Built inside a traced function, its arrays may be traced:
        ``jax.grad(lambda mu: synthesis.standstill_time(scene.with_loads(scene.loads +
        (assurjax.JointFriction("A", mu, radius=0.01),)))[0])(0.1)``."""
        from .._loads import check_loads
        from .._model import load_tuple

        loads = load_tuple(loads, "with_loads")
        check_loads(self.mechanism, loads)
        return eqx.tree_at(lambda s: s.loads, self, loads)

    def with_settings(self, *, state: dict | None = None, simulation: dict | None = None, outputs: dict | None = None) -> "Scene":
        """A copy with some settings updated, e.g. ``scene.with_settings(state={"q0": 1.0})``."""
        new = {}
        for field, extra in (("state", state), ("simulation", simulation), ("outputs", outputs)):
            if extra:
                new[field] = Settings({**getattr(self, field), **extra})
        return dataclasses.replace(self, **new)
