"""Modular reduction of inertia and loads to the driving link (Durango et al. 2014, section 3).

With a unit driving velocity the velocities of the mechanism are its kinematic
coefficients (``jax.jvp`` of the position map, Durango et al. 2014 step i). Each group then
contributes, for its own links j,

- to the reduced moment of inertia (kinetic-energy equivalence, eqs. 5-6):
  J_red = sum_j m_j |dG_j/dq|^2 + J_j (dtheta_j/dq)^2,
- to the reduced torque (power equivalence, eqs. 3-4):
  tau_red = sum_j F_j . dG_j/dq + M_j dtheta_j/dq,

where F_j, M_j are the applied force and moment about the centre of mass
(:func:`assurjax.applied_wrenches`, driving effort excluded). The mechanism sums
the groups. dJ_red/dq = 2 sum_j m_j dG_j/dq . d2G_j/dq2 + J_j dtheta_j/dq d2theta_j/dq2
comes from a second jvp. For a crank, J_red is in kg m^2 and tau_red in N m; for a
slider driver the reduced link translates: J_red is a reduced mass (kg) and tau_red
a reduced force (N) along the guide.

The equation of motion of the reduced link (Durango et al. 2014 eq. 1, differentiated in time) is
J_red(q) dw/dt + 0.5 dJ_red/dq w^2 = tau + tau_red(q, w, t)
(:func:`reduced_acceleration`, the one place it is written).
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ._errors import AssurjaxError
from ._jit import jit
from ._kinematics import (Coefficients, Kinematics, branch_coefficients, coefficients, exactly_singular, nan_where,
                          singular_groups)
from ._loads import any_velocity_dependent, check_loads, driver_effort
from ._mechanism import Mechanism
from ._repr import value_pdoc
from ._values import check_state_count, check_values


def reduced_acceleration(inertia, dinertia, force, omega):
    """dw/dt of the reduced link: the reduced equation of motion, written once
    (Durango et al. 2014 eq. 1 in time form): J_red dw/dt + 0.5 dJ_red/dq w^2 = force, where
    ``force`` = tau + tau_red is every generalized force on the driving coordinate."""
    return (force - 0.5 * dinertia * omega**2) / inertia


class Reduction(eqx.Module):
    """The mechanism reduced to its driving link at one (q, omega, t), or a batch.

    ``inertia``: J_red (kg m^2; kg for a slider driver). ``dinertia``: dJ_red/dq
    (kg m; kg/m). ``torque``: tau_red, the reduced applied loads without the
    driving effort (N m; N). ``effort``: the driving effort tau (N m; N).
    ``group_inertia``, ``group_dinertia``, ``group_torque``: each group's own
    terms (dicts keyed by group name; they sum to the totals). ``ok``: one flag
    per group (False: cannot assemble). With a batch of q, arrays get its shape.
    ``angle_rates``: dtheta/dq of every link, when a branch predictor was given.
    ``work_force``: the generalized force of every load outside the potential energy
    (all but gravity and springs, the driving effort included), when asked for:
    ``work_force * omega`` is the power that changes T + V.
    """

    __pdoc__ = value_pdoc  # repr: scalars and small arrays by value, long tables cut

    inertia: Array
    dinertia: Array
    torque: Array
    effort: Array
    group_inertia: dict[str, Array]
    group_dinertia: dict[str, Array]
    group_torque: dict[str, Array]
    ok: Array
    angle_rates: dict[str, Array] | None = None
    work_force: Array | None = None

    @property
    def force(self):
        """tau + tau_red: every generalized force on the driving coordinate (N m; N)."""
        return self.effort + self.torque

    def acceleration(self, omega):
        """dw/dt of the reduced link at velocity ``omega`` (:func:`reduced_acceleration`)."""
        return reduced_acceleration(self.inertia, self.dinertia, self.force, omega)


def generalized_force(mechanism: Mechanism, gravity, loads, q, omega, t) -> Array:
    """tau + tau_red (N m or N) from first-order kinematic coefficients only (no dJ/dq):
    at rest (omega = 0) its sign is the direction the mechanism starts to move in."""
    q, omega, t = (jnp.asarray(v, dtype=float) for v in (q, omega, t))
    coeffs = coefficients(mechanism, q, order=1)
    kin = kinematics_from_coefficients(coeffs, omega, velocities=any_velocity_dependent(loads))
    mass, _ = _link_parameters(mechanism, coeffs.names[1])
    return jnp.sum(_torque_terms(mechanism, coeffs, mass, gravity, loads, kin, t)) + driver_effort(mechanism, loads, q, omega, t, check=False)


def kinematics_from_coefficients(coeffs: Coefficients, omega, *, velocities: bool = True) -> Kinematics:
    """A single-configuration :class:`Kinematics` (order 1) built from the coefficients:
    v = dx/dq w. Without ``velocities`` only positions are filled (loads that do not
    depend on velocity need no more)."""
    return coeffs.kinematics(omega, velocities=velocities)


def _link_parameters(mechanism: Mechanism, links: tuple[str, ...]):
    """Masses (kg) and inertias (kg m^2) of the links, stacked in the order given."""
    return (jnp.stack([jnp.asarray(mechanism.links[k].mass, dtype=float) for k in links]),
            jnp.stack([jnp.asarray(mechanism.links[k].inertia, dtype=float) for k in links]))


def _torque_terms(mechanism: Mechanism, coeffs: Coefficients, mass, gravity, loads, kin, t) -> Array:
    """Per link (rows ``coeffs.names[1]``, masses ``mass``): F_j . dG_j/dq + M_j dtheta_j/dq,
    F_j and M_j the resultant of gravity and ``loads`` on link j (Durango et al. 2014 eqs. 3-4)."""
    links = coeffs.names[1]
    row = {k: i for i, k in enumerate(links)}
    force = mass[:, None] * jnp.asarray(gravity, dtype=float)
    moment = jnp.zeros(len(links))
    for load in loads:
        for link, f, m in load.wrenches(mechanism, kin, t):
            force, moment = force.at[row[link]].add(f), moment.at[row[link]].add(m)
    dg, dth = coeffs.stacked[1][1:3]
    return jnp.sum(force * dg, axis=-1) + moment * dth


def _inertia_terms(mass, inertia, coeffs: Coefficients):
    """Per link: m_j |dG_j/dq|^2 + J_j (dtheta_j/dq)^2 and its q-derivative (eqs. 5-6)."""
    (dg, dth), (d2g, d2th) = coeffs.stacked[1][1:3], coeffs.stacked[2][1:3]
    j = mass * jnp.sum(dg * dg, axis=-1) + inertia * dth**2
    dj = 2.0 * (mass * jnp.sum(dg * d2g, axis=-1) + inertia * dth * d2th)
    return j, dj


def reduce_single(mechanism: Mechanism, gravity, loads, q, omega, t, *, velocities: bool | None = None, near=None) -> Reduction:
    """The reduction at one configuration (pure, jittable). ``velocities``: build the
    velocity-dependent part (None: only when some load depends on velocity).
    ``near``: link angles (rad) selecting the branch; then ``angle_rates`` is filled."""
    return reduce_with_kinematics(mechanism, gravity, loads, q, omega, t, velocities=velocities, near=near)[0]


def reduce_with_kinematics(mechanism: Mechanism, gravity, loads, q, omega, t, *, velocities: bool | None = None,
                           near=None, work: bool = False, bridge: float = 0.0) -> tuple[Reduction, Kinematics]:
    """:func:`reduce_single` and the single-configuration :class:`Kinematics` the loads
    were evaluated on (velocities filled when ``velocities``), e.g. for the dampers'
    dissipated power without a second position analysis. ``work``: also fill
    ``Reduction.work_force`` (the energy balance). ``bridge``: on a tracked branch
    (``near``), the window of :func:`bridged_coefficients` (0: off)."""
    if velocities is None:
        velocities = any_velocity_dependent(loads)
    # arrays: the jit below would take Python floats as static and compile per value
    q, omega, t = (jnp.asarray(v, dtype=float) for v in (q, omega, t))
    return _reduce_with_kinematics(mechanism, gravity, loads, q, omega, t, velocities, near, work, bridge)


# A nested jit: a simulation uses the reduction in several places (the solver's stages,
# the outputs); it is traced once and reused, which halves the tracing time of a first
# simulate() (XLA inlines it, so the compiled program and its speed are unchanged).
@jit
def _reduce_with_kinematics(mechanism: Mechanism, gravity, loads, q, omega, t, velocities: bool, near, work: bool, bridge: float):
    coeffs = branch_coefficients(mechanism, q, near=near, bridge=bridge)
    return reduce_coefficients(mechanism, gravity, loads, coeffs, omega, t, velocities=velocities, work=work,
                               rates=near is not None)


def reduce_coefficients(mechanism: Mechanism, gravity, loads, coeffs: Coefficients, omega, t, *, velocities: bool = True,
                        work: bool = False, rates: bool = False) -> tuple[Reduction, Kinematics]:
    """The reduction from kinematic coefficients already computed (order 2), and the
    Kinematics (order 1) the loads were evaluated on. ``rates``: fill ``angle_rates``."""
    kin = kinematics_from_coefficients(coeffs, omega, velocities=velocities)
    mass, inertia = _link_parameters(mechanism, coeffs.names[1])
    j, dj = _inertia_terms(mass, inertia, coeffs)
    torque = _torque_terms(mechanism, coeffs, mass, gravity, loads, kin, t)
    terms = jnp.stack([j, dj, torque], axis=-1)  # (..., links, 3)
    # each group reduces its own links (gathers that a caller reading only the totals never runs)
    row = {k: i for i, k in enumerate(coeffs.names[1])}
    per_group = {g.name: jnp.sum(terms[..., np.asarray([row[k] for k in g.links]), :], axis=-2) for g in mechanism.groups}
    gj, gdj, gt = ({name: v[..., c] for name, v in per_group.items()} for c in range(3))
    effort = driver_effort(mechanism, loads, coeffs.q, omega, t, check=False)
    work_force = None
    if work:  # the loads outside V: every load but gravity and springs
        outside = tuple(load for load in loads if not load.conservative)
        work_force = jnp.sum(_torque_terms(mechanism, coeffs, mass, jnp.zeros(2), outside, kin, t)) + effort
    total = jnp.sum(terms, axis=-2)
    reduction = Reduction(
        inertia=total[..., 0],
        dinertia=total[..., 1],
        torque=total[..., 2],
        effort=effort,
        group_inertia=gj, group_dinertia=gdj, group_torque=gt,
        ok=coeffs.ok, angle_rates=coeffs.link_angles(1) if rates else None, work_force=work_force,
    )
    return reduction, kin


# What is unbounded exactly at a singular configuration (where the driving coordinate does not carry the motion)
REDUCED_FIELDS = ("inertia", "dinertia", "torque", "group_inertia", "group_dinertia", "group_torque")


@jit
def _reduce_public(mechanism, gravity, loads, q, omega, t) -> Reduction:
    """:func:`reduce_single` with NaN J_red, dJ_red/dq and torques exactly at a singular
    configuration (:func:`reduce`'s; a simulation reads the plain one, and refuses to start there)."""
    red, kin = reduce_with_kinematics(mechanism, gravity, loads, q, omega, t)
    singular = exactly_singular(mechanism, singular_groups(mechanism), kin.points, kin.rotations)
    if singular is not None:  # not where a group cannot assemble (its clamped closed form reads as singular)
        singular = singular & jnp.all(kin.ok)
    return dataclasses.replace(red, **nan_where(singular, {name: getattr(red, name) for name in REDUCED_FIELDS}))


@jit
def _reduce_batch(mechanism, gravity, loads, q, omega, t):
    shape = q.shape
    single = lambda q, w, t: _reduce_public(mechanism, gravity, loads, q, w, t)  # noqa: E731
    flat = jax.vmap(single)(q.reshape(-1), omega.reshape(-1), t.reshape(-1))
    return jax.tree.map(lambda v: v.reshape(shape + v.shape[1:]), flat)


def reduce(scene_or_mechanism, q, omega=0.0, t=0.0, *, loads=None, gravity=None) -> Reduction:
    """Reduce a mechanism's inertia and loads to its driving link (Durango et al. 2014 eqs. 3-6).

    **Arguments:**
    - ``scene_or_mechanism``: a :class:`assurjax.Scene` (its loads and gravity are
      used unless given) or a :class:`assurjax.Mechanism`.
    - ``q``: driving coordinate(s) (rad or m), any shape; ``omega`` (rad/s or m/s)
      and ``t`` (s) broadcast against it (they matter only for loads that depend on them).
    - ``loads``: a sequence of loads; ``gravity``: a 2-vector (m/s^2), default 0.

    Returns a :class:`Reduction`; also usable under ``jax.vmap`` / ``jax.jit``. Joint
    friction is left out of ``torque``: it depends on the reactions, so on dw/dt, and the
    simulation and :func:`assurjax.inverse_dynamics` solve it.

    Exactly at a singular configuration of a group (a dead centre, see
    :func:`assurjax.kinematics`) the kinematic coefficients are unbounded, as the driving
    coordinate does not carry the motion there: ``inertia``, ``dinertia``, ``torque`` and
    the group terms are NaN at such a q (``effort`` and ``ok`` stay); a step away they are
    finite and large.

    **Example:**
    >>> scene = assurjax.load_scene("watt_sixbar")
    >>> red = assurjax.reduce(scene, jnp.linspace(0.0, 1.0, 50))
    >>> red.inertia.shape, sorted(red.group_inertia)
    ((50,), ['crank2', 'dyad34', 'dyad56'])
    """
    mechanism, loads, gravity = _unpack(scene_or_mechanism, loads, gravity)
    check_values(AssurjaxError, "reduce", q=q, omega=omega, t=t)
    check_values(AssurjaxError, "reduce", shape=(2,), gravity=gravity)
    check_state_count(AssurjaxError, "reduce", np.shape(q))
    q = jnp.asarray(q, dtype=float)
    try:
        shape = jnp.broadcast_shapes(q.shape, jnp.shape(omega), jnp.shape(t))
    except ValueError:
        raise AssurjaxError(f"reduce: q, omega and t must broadcast together, got shapes {q.shape}, {jnp.shape(omega)}, "
                            f"{jnp.shape(t)}") from None
    q, omega, t = (jnp.broadcast_to(jnp.asarray(v, dtype=float), shape) for v in (q, omega, t))
    if not shape:
        return _reduce_public(mechanism, gravity, loads, q, omega, t)
    return _reduce_batch(mechanism, gravity, loads, q, omega, t)


def _unpack(scene_or_mechanism, loads, gravity):
    if isinstance(scene_or_mechanism, Mechanism):
        mechanism = scene_or_mechanism
        loads = () if loads is None else tuple(loads)
        gravity = jnp.zeros(2) if gravity is None else jnp.asarray(gravity, dtype=float)
    else:
        scene = scene_or_mechanism
        mechanism = scene.mechanism
        loads = scene.loads if loads is None else tuple(loads)
        gravity = scene.gravity if gravity is None else jnp.asarray(gravity, dtype=float)
    check_loads(mechanism, loads)
    return mechanism, loads, gravity
