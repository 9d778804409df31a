"""A tabulated reduced model: the reduction sampled once per crank turn, then interpolated.

Seed 000 (section 3) notes that the reduced moment of inertia J_red and the
reduced torque tau_red are functions of the generalized coordinate only
("independent of time and velocity") when the applied loads are. For a crank
they are then 2 pi-periodic in q, so the equation of motion

    J_red(q) dw/dt + 0.5 dJ_red/dq w^2 = tau(q) + tau_red(q)

needs the position analysis only through three periodic functions of q:
f = (J_red, dJ_red/dq, tau + tau_red). :class:`ReducedTable` samples f and its
q-derivative f' (one more ``jax.jvp`` over the package's second-order reduction,
so J_red'' comes from a third nested jvp) at n uniform nodes q_k = k h,
h = 2 pi / n, vmapped over the nodes, and evaluates f by periodic piecewise cubic
Hermite interpolation: with u = (q mod 2 pi) / h, i = floor(u), s = u - i,

    p(q) = h00(s) f_i + h10(s) h f'_i + h01(s) f_{i+1} + h11(s) h f'_{i+1},

one gather of two table rows and a few multiply-adds per right-hand side
instead of a second-order jvp of the whole position analysis.

Error: |f - p| <= h^4 / 384 max |f''''| (cubic Hermite interpolation).
Measured on the Watt six-bar of Durango et al. 2014 (4096 random off-grid angles, max error
relative to max |f|) for J_red, dJ_red/dq, tau + tau_red: 7e-9 / 3e-8 / 4e-9 with
n = 1024, 4e-10 / 2e-9 / 2e-10 with n = 2048, 3e-11 / 1e-10 / 1.5e-11 with
n = 4096: the h^4 rate (16x per halving of h). The default n = 4096 (a 200 kB
table) makes the model error negligible against a 1e-8 rad integration tolerance
(2 s of the six-bar: table and exact runs agree to ~1e-11 rad).

Validity (checked by :func:`build_table`, each a clear :class:`AssurjaxError`):

- the driver is a crank (q an angle, the model 2 pi-periodic);
- no load depends on the driving velocity (``velocity_dependent``) or on time
  (forms in ``omega`` or ``t``; functions whose traced program reads them, see
  :func:`assurjax._loads.reads`), and the loads are 2 pi-periodic in q (probed at q + 2 pi);
- every group assembles at every node (the crank turns fully); a crank that
  cannot turn fully needs the exact reduction (``reduction="exact"``).

Traced inside jit (``build_table_core``) the table is differentiable and
vmappable over the mechanism's parameters, but only the static checks run there.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._errors import AssurjaxError
from .._jit import jit
from .._kinematics import coefficients, singular_groups, singularity_measures
from .._loads import any_velocity_dependent, check_loads
from .._mechanism import Mechanism
from .._reduction import reduce_single, reduced_acceleration
from .._values import check_value

DEFAULT_TABLE_NODES = 4096  # grid size of a table, unless asked otherwise (simulate's table_nodes too)
TWO_PI = 2.0 * math.pi
_PERIODIC_RTOL = 1e-9  # relative mismatch of tau at q and q + 2 pi taken as non-periodic


class ReducedTable(eqx.Module):
    """(J_red, dJ_red/dq, tau + tau_red) of a crank-driven mechanism on a uniform
    periodic grid, with their q-derivatives, for cubic Hermite interpolation.

    ``data``: (n, 6) array; row k holds f(q_k) (kg m^2, kg m, N m) then f'(q_k)
    (kg m^2/rad, kg m/rad, N m/rad) at q_k = 2 pi k / n. ``ok``: (n,) all groups
    assemble at q_k. Call ``table(q)`` for (J_red, dJ_red/dq, tau + tau_red) at any q (rad).
    """

    data: Array
    ok: Array

    @property
    def nodes(self) -> int:
        return self.data.shape[0]

    def __call__(self, q):
        """(J_red, dJ_red/dq, tau + tau_red) at q (rad, any real: wrapped into one turn)."""
        n = self.data.shape[0]
        h = TWO_PI / n
        u = jnp.mod(q, TWO_PI) / h
        i = jnp.clip(jnp.floor(u), 0, n - 1).astype(jnp.int32)
        s = (u - i)[..., None]  # broadcast against the three columns
        (f0, d0), (f1, d1) = (jnp.split(self._row(k), 2, axis=-1) for k in (i, jnp.where(i + 1 == n, 0, i + 1)))
        p = hermite(s, h, f0, d0, f1, d1)
        return p[..., 0], p[..., 1], p[..., 2]

    def _row(self, k):
        """Row(s) k of the table. For one index a dynamic slice, not a gather: on the
        CPU a gather costs several times the rest of an integration step."""
        if jnp.ndim(k) == 0:
            return jax.lax.dynamic_slice(self.data, (k, jnp.zeros((), k.dtype)), (1, self.data.shape[1]))[0]
        return self.data[k]

    def acceleration(self, q, w):
        """dw/dt (rad/s^2) of the reduced link from the interpolant (Durango et al. 2014 eq. 1 in time form)."""
        return reduced_acceleration(*self(q), w)


def _node_terms(mechanism: Mechanism, gravity, loads, q):
    """f(q) = (J_red, dJ_red/dq, tau + tau_red) at one angle."""
    red = reduce_single(mechanism, gravity, loads, q, jnp.zeros(()), jnp.zeros(()), velocities=False)
    return jnp.stack([red.inertia, red.dinertia, red.torque + red.effort]), jnp.all(red.ok)


def _node_row(mechanism, gravity, loads, q):
    """(f, f') at one node (f' by jvp of the exact reduction) and the assembly flag."""
    f, df, ok = jax.jvp(lambda q: _node_terms(mechanism, gravity, loads, q), (q,), (jnp.ones_like(q),), has_aux=True)
    return jnp.concatenate([f, df]), ok


@jit
def _node_mismatch(mechanism, gravity, loads, table: ReducedTable, rows):
    """Largest difference between the table's rows ``rows`` and the exact reduction there,
    per column relative to its largest value in the table or the exact rows (a column 0 in
    both: no difference). Not against 1 + that value: a millimetre mechanism of milligrams,
    its torques ~1e-11 N m, passed a table built without gravity."""
    n = table.data.shape[0]
    exact, _ = jax.vmap(lambda k: _node_row(mechanism, gravity, loads, k * (TWO_PI / n)))(rows)
    scale = jnp.maximum(jnp.max(jnp.abs(table.data), axis=0), jnp.max(jnp.abs(exact), axis=0))
    scale = jnp.where(scale > 0, scale, 1.0)
    return jnp.max(jnp.abs(exact - table.data[rows]) / scale)


TABLE_MATCH = 1e-9  # a prebuilt table's rows against the exact reduction: the same model to round-off
_MATCHED: dict = {}  # (table, model) identities already checked, each with the objects (kept: ids stay theirs)


def check_table_matches(table: ReducedTable, mechanism: Mechanism, gravity, loads) -> None:
    """Raise where a table given to ``simulate`` does not tabulate this mechanism, gravity and
    loads: it replaces the whole reduced model, and one built for another (without gravity,
    for another mechanism) integrated another motion, silently. Compared with the exact
    reduction at three of its nodes, once per table and model objects."""
    key = (id(table), id(mechanism), id(gravity), tuple(id(load) for load in loads))
    if key in _MATCHED:
        return
    check_tabulable(mechanism, loads)
    n = table.data.shape[0]
    rows = np.array([0, n // 3, (2 * n) // 3])
    miss = float(_node_mismatch(mechanism, jnp.asarray(gravity, dtype=float), tuple(loads), table, rows))
    if not miss <= TABLE_MATCH:
        raise AssurjaxError(f"table: it does not tabulate this scene's mechanism, gravity and loads (at its nodes the "
                            f"exact reduction differs from it by {miss:.3g} times its largest values): build it with "
                            "assurjax.build_table(scene.mechanism, scene.gravity, scene.loads)")
    if len(_MATCHED) > 64:
        _MATCHED.clear()
    _MATCHED[key] = (table, mechanism, gravity, tuple(loads))


def check_tabulable(mechanism: Mechanism, loads) -> None:
    """Static checks: a crank driver and loads independent of velocity and (for the forms) of time."""
    driver = mechanism.driver
    if driver.kind != "crank":
        raise AssurjaxError(f"reduction='table': the driver {driver.describe()} is a {driver.kind}; the table "
                            "needs a crank (a 2 pi-periodic model). Use reduction='exact'.")
    if any_velocity_dependent(loads):
        names = [type(load).__name__ for load in loads if load.velocity_dependent]
        raise AssurjaxError(f"reduction='table': the loads {names} depend on the driving velocity, so the reduction "
                            "is not a function of q alone. Use reduction='exact'.")
    for load in loads:  # a function's program read (a probe in t at the nodes missed a drive switched on later)
        for argument, what in (("omega", "the driving velocity omega"), ("t", "time t")):
            if load.reads(argument):
                raise AssurjaxError(f"reduction='table': a {type(load).__name__} load depends on {what} (a form in "
                                    f"{argument}, or a function that reads it), so the reduction is not a function of "
                                    "q alone. Use reduction='exact'.")


def build_table_core(mechanism: Mechanism, gravity, loads, nodes: int = DEFAULT_TABLE_NODES) -> ReducedTable:
    """The table, traceable (jit, vmap, grad over the mechanism's arrays); static checks only."""
    check_tabulable(mechanism, loads)
    q = jnp.arange(nodes) * (TWO_PI / nodes)
    data, ok = jax.vmap(lambda q: _node_row(mechanism, gravity, loads, q))(q)
    return ReducedTable(data=data, ok=ok)


@jit
def _build_and_probe(mechanism, gravity, loads, nodes: int):
    """The table, per-group assembly flags at the nodes, and probes of time dependence
    (d tau/dt) and periodicity (tau at q + 2 pi). The probe in t is for a load class's own
    ``effort`` or ``wrenches`` reading t; value functions are read whole (``check_tabulable``)."""
    table = build_table_core(mechanism, gravity, loads, nodes)
    q = jnp.arange(nodes) * (TWO_PI / nodes)

    def probe(q):
        def torque(q, t):
            red = reduce_single(mechanism, gravity, loads, q, jnp.zeros(()), t, velocities=False)
            return red.torque + red.effort, red.ok

        (tau, ok), (dtau_dt, _) = jax.jvp(torque, (q, jnp.zeros(())), (jnp.zeros(()), jnp.ones(())))
        return ok, dtau_dt, torque(q + TWO_PI, jnp.zeros(()))[0] - tau

    group_ok, dtau_dt, shift = jax.vmap(probe)(q)
    declared = singular_groups(mechanism)
    measures = jax.vmap(lambda q: singularity_measures(mechanism, coefficients(mechanism, q, order=1), declared))(q) \
        if declared else None
    return table, group_ok, dtau_dt, shift, measures


def build_table(mechanism: Mechanism, gravity=None, loads=(), nodes: int = DEFAULT_TABLE_NODES) -> ReducedTable:
    """Tabulate the reduction of a crank-driven mechanism over one turn, with every check.

    **Arguments:** ``mechanism``; ``gravity`` (m/s^2, 2-vector, default 0); ``loads``
    (independent of omega and t, 2 pi-periodic in q); ``nodes``: grid size n
    (interpolation error ~ (2 pi / n)^4, see the module docstring).

    Raises :class:`AssurjaxError` naming the group that cannot assemble somewhere on
    the turn (the crank cannot rotate fully: use the exact reduction), or the load
    property that makes the reduction depend on more than q.

    **Example:**
    >>> table = assurjax.build_table(scene.mechanism, scene.gravity, scene.loads)
    >>> j, dj, tau = table(0.3)
    """
    from ._settings import setting_problem  # _settings imports this module

    if hasattr(nodes, "dtype") and np.ndim(nodes) == 0 and jnp.issubdtype(nodes.dtype, jnp.integer):
        nodes = int(nodes)  # a NumPy or JAX integer
    if (problem := setting_problem("table_nodes", nodes)) is not None:
        raise AssurjaxError(f"build_table: nodes: {problem}")
    if gravity is not None:
        check_value(AssurjaxError, "build_table: gravity", gravity, shape=(2,))
    gravity = jnp.zeros(2) if gravity is None else jnp.asarray(gravity, dtype=float)
    loads = tuple(loads)
    check_loads(mechanism, loads)
    check_tabulable(mechanism, loads)
    table, group_ok, dtau_dt, shift, measures = jax.device_get(_build_and_probe(mechanism, gravity, loads, int(nodes)))
    _check_assembly(mechanism, np.asarray(group_ok), int(nodes))
    if measures is not None:
        _check_between_nodes(mechanism, np.asarray(measures), int(nodes))
    # relative to the torques' own size (against 1 + it, a millimetre four-bar of milligrams with a
    # torsion spring, not periodic by 3e-12 N m, passed and its batch spun 675 rad away)
    scale = np.max(np.abs(np.asarray(table.data[:, 2])))
    scale = scale if scale > 0 else 1.0
    if np.max(np.abs(dtau_dt)) > 1e-12 * scale:
        raise AssurjaxError("reduction='table': the applied loads depend on time t (d tau/dt != 0 at some node), so "
                            "the reduction is not a function of q alone. Use reduction='exact'.")
    if np.max(np.abs(shift)) > _PERIODIC_RTOL * scale:
        raise AssurjaxError("reduction='table': the applied loads are not 2 pi-periodic in the crank angle q "
                            "(tau(q + 2 pi) != tau(q)), so one turn cannot be tabulated. Use reduction='exact'.")
    return jax.tree.map(jnp.asarray, table)


# A dip of a group's squared singularity measure below this between two nodes is a window
# where it cannot assemble (the measure's square is smooth through the limit: it goes negative)
BETWEEN_NODES_DIP = 1e-9


def hermite(s, h, f0, d0, f1, d1):
    """The cubic through (f0, d0) and (f1, d1) (values, derivatives) at the ends of an interval
    of length h, at its fraction s (NumPy or JAX arrays)."""
    s2, r = s * s, 1.0 - s
    return (1.0 + 2.0 * s) * r * r * f0 + s * r * r * h * d0 + s2 * (3.0 - 2.0 * s) * f1 - s2 * r * h * d1


def _check_between_nodes(mechanism: Mechanism, measures: np.ndarray, nodes: int) -> None:
    """A group that cannot assemble between two nodes only: the cubic through its squared
    singularity measure f = m^2 and df/dq = 2 m m' at the interval's nodes dips below 0.
    The nodes alone passed a slider-crank whose rod was 1e-9 m short of turning through a
    window of 2.7e-4 rad, and the table's runs went straight through it ('reached t1', 6 rad
    from the exact reduction's lock-up)."""
    h = TWO_PI / nodes
    s = np.linspace(0.0, 1.0, 33)[1:-1, None]
    for j, g in enumerate(singular_groups(mechanism)):
        m, dm = measures[:, j, 0], measures[:, j, 1]
        f, df = m**2, 2.0 * m * dm
        cubic = hermite(s, h, f, df, np.roll(f, -1), np.roll(df, -1))
        dips = np.flatnonzero(cubic.min(axis=0) < -BETWEEN_NODES_DIP)
        if dips.size:
            k = int(dips[0])
            raise AssurjaxError(
                f"reduction='table': group '{mechanism.groups[g].name}' cannot assemble between the nodes q = "
                f"{k * h:.6f} and {(k + 1) * h:.6f} rad (its singular measure's square dips below 0 there: a limit "
                "position within one node spacing): the crank cannot turn fully, so the reduction cannot be "
                "tabulated over one turn. Use the exact reduction (reduction='exact').")


def _check_assembly(mechanism: Mechanism, group_ok: np.ndarray, nodes: int) -> None:
    bad = ~group_ok.all(axis=0)
    if bad.any():
        g = int(np.argmax(bad))
        k = np.flatnonzero(~group_ok[:, g])
        q_bad = TWO_PI * k / nodes
        raise AssurjaxError(
            f"reduction='table': group '{mechanism.groups[g].name}' cannot assemble for crank angles "
            f"q in [{q_bad.min():.4f}, {q_bad.max():.4f}] rad ({k.size} of {nodes} nodes): the crank cannot "
            "turn fully, so the reduction cannot be tabulated over one turn. Use the exact reduction (reduction='exact').")
