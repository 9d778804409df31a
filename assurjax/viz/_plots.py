"""Line plots: coupler curves, angular velocities, time histories, energies,
joint reactions, the reduced inertia and load, and the velocity polygon.

Every function takes plain arrays (SI units), draws on ``ax`` (a new figure when
omitted), labels its axes with units and returns the Axes."""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import matplotlib.pyplot as plt
import numpy as np

from .._errors import AssurjaxError
from .._mechanism import Mechanism, check_mechanism
from ._draw import clipped_note, make_room_for_legend, trace_color
from ._frames import Frames, length_scale, masked, reach_box


def _axes(ax, figsize=(6, 4)):
    if ax is None:
        _, ax = plt.subplots(figsize=figsize, layout="constrained")
    return ax


def place_legend_clear(ax, entries: int):
    """A legend that does not hide data: inside (matplotlib's emptiest corner) for up to
    two entries, outside on the right of the axes for more (room made for it:
    :func:`make_room_for_legend`). None past the
    colour cycle: colours repeat and an entry names no line (the strandbeest's 49 angular
    velocities' legend took the figure's whole width)."""
    if entries > len(plt.rcParams["axes.prop_cycle"].by_key()["color"]):
        return
    if entries <= 2:
        ax.legend(fontsize=8, loc="best")
        return
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    make_room_for_legend(ax)


DRIVER_KINDS = ("crank", "slider")


def check_driver_kind(where: str, driver_kind) -> None:
    """``driver_kind`` is a mechanism's ``driver.kind``: "crank" or "slider"."""
    if not isinstance(driver_kind, str) or driver_kind not in DRIVER_KINDS:
        raise AssurjaxError(f"{where}: driver_kind must be one of {', '.join(map(repr, DRIVER_KINDS))} "
                            f"(mechanism.driver.kind), got {driver_kind!r:.60}")


def driving_label(frames_or_kind) -> str:
    """Axis label of the driving coordinate: a crank angle (rad) or a slider position (m)."""
    kind = frames_or_kind if isinstance(frames_or_kind, str) else "crank"
    return "driving coordinate q (m)" if kind == "slider" else "crank angle q (rad)"


VIEW_REACH = 1.0  # how far (in mechanism sizes) beyond the mechanism the coupler curves' view reaches


def plot_coupler_curves(frames: Frames, points: Iterable[str] | None = None, *, ax=None, unit: str = "m", equal: bool = True,
                        mechanism: Mechanism | None = None):
    """Paths of ``points`` (default: all) over the configurations of ``frames``.

    Gaps show driving coordinates where the mechanism does not assemble; each point
    has its own colour and legend entry. With ``equal=False`` the axes are scaled
    independently (Fanghella et al. 2019, Fig. 2b, where y_P is the straight-line error).
    For smooth curves pass enough configurations (e.g. 721 over a turn).

    ``mechanism`` (the frames' own): the paths are shown within a view a mechanism's size
    beyond it (its ground points widened by its longest link, on every side). Near a singular
    position a point can run off far beyond the mechanism (the tangent drive's J to 23 m from
    a 0.3 m mechanism over a turn): then the axes frame the mechanism and what stays in the
    view, such a path is cut at their edge and the x label says how far it reaches. Paths
    that stay in the view are drawn as without ``mechanism``.

    **Example:**
    >>> frames = assurjax.viz.mechanism_frames(mech, np.linspace(0, 2 * np.pi, 721))
    >>> assurjax.viz.plot_coupler_curves(frames, ["E"], unit="mm", mechanism=mech)
    """
    s = length_scale(unit, "plot_coupler_curves")
    ax = _axes(ax)
    names = [points] if isinstance(points, str) else list(points if points is not None else frames.points)
    unknown = [n for n in names if n not in frames.points]
    if unknown:
        raise AssurjaxError(f"plot_coupler_curves: unknown point(s) {unknown}; the frames have {sorted(frames.points)}")
    box = view = None
    if mechanism is not None:
        check_mechanism(mechanism, "plot_coupler_curves")
        box = reach_box(mechanism)
        view = _view(*box)
    for k, name in enumerate(names):
        xy = masked(frames.points[name], frames.ok)
        if view is not None:
            xy = _broken_outside(xy, *view)
        shown = np.asarray(frames.points[name])[np.asarray(frames.ok)]
        still = shown.size > 0 and np.ptp(shown, axis=0).max() == 0.0
        ax.plot(xy[:, 0] * s, xy[:, 1] * s, "o" if still else "-", color=trace_color(k),
                label=f"{name} (at rest)" if still else f"path of {name}")
    ax.set_xlabel(f"x ({unit})")
    ax.set_ylabel(f"y ({unit})")
    framed = view is not None and _frame_mechanism(ax, {n: _assembled(frames, n) for n in names}, box, view, s, unit)
    if equal:  # the limits a framed view set are kept; otherwise matplotlib widens one of them for the aspect
        ax.set_aspect("equal", adjustable="box" if framed else "datalim")
    ax.set_title("coupler curves")
    ax.grid(True, lw=0.3)
    place_legend_clear(ax, len(names))
    return ax


def _view(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Corners (m) of the coupler curves' view: the mechanism's reach box (``lo``, ``hi``,
    see ``reach_box``), VIEW_REACH of its size farther on every side."""
    size = float(np.max(hi - lo)) or 1.0
    return lo - VIEW_REACH * size, hi + VIEW_REACH * size


def _inside(xy: np.ndarray, lo, hi) -> np.ndarray:
    return np.all((xy >= lo) & (xy <= hi), axis=1)


def _broken_outside(xy: np.ndarray, lo, hi) -> np.ndarray:
    """``xy`` with a gap (a NaN row) between two samples that are both outside the view: their
    segment, where a path runs off to one side and comes back from the other, would otherwise
    cross the view as a straight line. A segment from inside to outside is kept (cut at the
    axes' edge)."""
    out = ~_inside(xy, lo, hi)
    return np.insert(xy, np.flatnonzero(out[:-1] & out[1:]) + 1, np.nan, axis=0)


def _assembled(frames: Frames, name: str) -> np.ndarray:
    """A point's finite positions (m) where the mechanism assembles."""
    xy = np.asarray(frames.points[name])[np.asarray(frames.ok)]
    return xy[np.all(np.isfinite(xy), axis=1)]


def _frame_mechanism(ax, paths: dict[str, np.ndarray], box, view, scale: float, unit: str) -> bool:
    """Where a path leaves the ``view``: axes around the mechanism's reach ``box`` and the
    paths' points within the view, each path that leaves cut at their edge and named in the x
    label with how far it reaches; True. Otherwise False: matplotlib's own limits, around the
    whole paths."""
    lo, hi = view
    leaving = {n: xy for n, xy in paths.items() if not _inside(xy, lo, hi).all()}
    if not leaving:
        return False
    near = np.concatenate([np.array(box), *[xy[_inside(xy, lo, hi)] for xy in paths.values()]])
    a, b = near.min(axis=0), near.max(axis=0)
    pad = 0.05 * float(np.max(b - a))
    a, b = np.maximum(a - pad, lo), np.minimum(b + pad, hi)  # not past the view: a path leaving it runs to the axes' edge
    ax.set_xlim(a[0] * scale, b[0] * scale)
    ax.set_ylim(a[1] * scale, b[1] * scale)
    notes = [clipped_note(f"path of {n}", (xy.min(axis=0), xy.max(axis=0)), scale, unit) for n, xy in leaving.items()]
    ax.set_xlabel("\n".join([ax.get_xlabel(), *notes]))
    return True


def plot_against(x, series: Mapping[str, np.ndarray], *, xlabel: str, ylabel: str, ax=None, title: str | None = None, ok=None, styles: Mapping[str, str] | None = None):
    """One line per entry of ``series`` against ``x``; NaN gaps where ``ok`` is False."""
    x = np.asarray(x, dtype=float)
    what = title or ylabel
    if x.ndim != 1 or x.size == 0:
        raise AssurjaxError(f"{what}: the abscissa must be a 1-D array of at least one sample, got shape {x.shape}")
    values = {name: np.asarray(y, dtype=float) for name, y in series.items()}
    for name, y in values.items():
        if y.shape != x.shape:
            raise AssurjaxError(f"{what}: '{name}' has shape {y.shape}, its abscissa {x.shape}: one value per sample")
    ax = _axes(ax)
    for name, y in values.items():
        y = masked(y, ok) if ok is not None else y
        ax.plot(x, y, (styles or {}).get(name, "-"), label=name)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    ax.grid(True, lw=0.3)
    if series:
        place_legend_clear(ax, len(series))
    return ax


def plot_angular_velocities(frames: Frames, links: Iterable[str] | None = None, *, ax=None, degrees: bool = False, driver_kind: str = "crank"):
    """Angular velocities of ``links`` (default: all) against the driving coordinate.

    With the frames computed for omega = 1 these are the kinematic coefficients
    d(theta)/dq (Fanghella et al. 2019, Fig. 3, use w2 = 1 rad/s and deg/s)."""
    check_driver_kind("plot_angular_velocities", driver_kind)
    if frames.angular_velocities is None:
        raise AssurjaxError("plot_angular_velocities: angular velocities need frames computed with velocities=True")
    k = np.degrees(1.0) if degrees else 1.0
    names = [links] if isinstance(links, str) else list(links) if links is not None else list(frames.angular_velocities)
    unknown = [n for n in names if n not in frames.angular_velocities]
    if unknown:
        raise AssurjaxError(f"plot_angular_velocities: unknown link(s) {unknown}; the frames have "
                            f"{sorted(frames.angular_velocities)}")
    series = {f"w {n}": frames.angular_velocities[n] * k for n in names}
    ylabel = "angular velocity (deg/s)" if degrees else "angular velocity (rad/s)"
    if frames.omega is not None and np.all(frames.omega == 1.0):  # the kinematic coefficients: say at what speed
        ylabel += f" at driver speed 1 {'rad/s' if driver_kind == 'crank' else 'm/s'}"
    return plot_against(frames.q, series, xlabel=driving_label(driver_kind), ylabel=ylabel, ax=ax, title="angular velocities", ok=frames.ok)


def plot_time_histories(t, series: Mapping[str, np.ndarray], *, ylabel: str, ax=None, title: str | None = None):
    """Quantities against time t (s); ``ylabel`` must carry the unit."""
    return plot_against(t, series, xlabel="time t (s)", ylabel=ylabel, ax=ax, title=title)


def plot_energies(t, kinetic, potential, *, ax=None, work=None, dissipated=None):
    """Kinetic T, potential V and total E = T + V (J) against time (Durango et al. 2014, Fig. 7a);
    with ``work`` (J, the work of the loads outside V since t0, e.g. ``Solution.work``) the
    conserved T + V - W instead of E; with ``dissipated`` (J, e.g. ``Solution.dissipated``:
    what friction and dampers took since t0) that too."""
    for name, v in (("kinetic", kinetic), ("potential", potential), ("work", work), ("dissipated", dissipated)):
        if v is not None and np.shape(v) != np.shape(t):
            raise AssurjaxError(f"energies: {name} has shape {np.shape(v)}, t {np.shape(t)}: one value per sample")
    kinetic, potential = np.asarray(kinetic), np.asarray(potential)
    series = {"T (kinetic)": kinetic, "V (potential)": potential}
    balance = "E = T + V" if work is None else "T + V - W"
    series[balance] = kinetic + potential - (0 if work is None else np.asarray(work))
    if dissipated is not None:
        series["dissipated (friction, dampers)"] = np.asarray(dissipated)
    # the balance dashed: where V = 0 it lies on T, which stays visible under it
    return plot_against(t, series, xlabel="time t (s)", ylabel="energy (J)", ax=ax, title="energies", styles={balance: "--"})


def plot_energy_drift(t, total, *, ax=None):
    """Drift of the conserved energy from its initial value (J) (Durango et al. 2014, Fig. 7b)."""
    total = np.asarray(total, dtype=float)
    if total.ndim != 1 or total.size == 0:
        raise AssurjaxError(f"energy drift: total must be a 1-D array of at least one sample, got shape {total.shape}")
    return plot_time_histories(t, {"E(t) - E(0)": total - total[0]}, ylabel="energy drift (J)", ax=ax, title="energy drift")


def plot_reactions(t, reactions, *, ax=None, components: bool = False):
    """Joint reactions (N) against time: magnitudes (Durango et al. 2014, Fig. 6c), or x/y components.

    ``reactions``: joint -> (samples, 2) forces (``Reactions.forces``), or an
    :class:`assurjax.Reactions` along the samples, whose samples without statics
    (``friction_ok`` False: a motion the friction self-locks, a jammed run's last state)
    are left out as gaps."""
    statics = None
    if hasattr(reactions, "forces") and hasattr(reactions, "friction_ok"):  # a Reactions
        statics = None if reactions.friction_ok is None else np.asarray(reactions.friction_ok, dtype=bool)
        reactions = reactions.forces
    if not isinstance(reactions, Mapping):
        raise AssurjaxError("joint reactions: pass an assurjax.Reactions or a mapping joint -> (samples, 2) forces, "
                            f"got {type(reactions).__name__}")
    series = {}
    for joint, force in reactions.items():
        force = np.asarray(force, dtype=float)
        if force.ndim != 2 or force.shape[-1] != 2:
            raise AssurjaxError(f"joint reactions: the force at '{joint}' must be (samples, 2) (Fx, Fy per sample, N), "
                                f"got shape {force.shape}")
        if statics is not None and statics.shape == force.shape[:1]:
            force = masked(force, statics)
        if components:
            series[f"{joint} Fx"], series[f"{joint} Fy"] = force[..., 0], force[..., 1]
        else:
            series[f"|F| at {joint}"] = np.hypot(force[..., 0], force[..., 1])
    return plot_time_histories(t, series, ylabel="reaction force (N)", ax=ax, title="joint reactions")


def plot_reduced(q, j_red, tau_red=None, *, axes=None, driver_kind: str = "crank", ok=None):
    """Reduced inertia J_red(q) (kg m^2, or kg for a slider) and reduced load
    tau_red(q) (N m, or N) against the driving coordinate (Durango et al. 2014, eqs. 3-6).

    Pass one period of q (one crank turn, or the slider's stroke): the curves repeat after it.
    ``ok``: where the mechanism assembles (e.g. ``Reduction.ok.all(axis=-1)``); elsewhere the
    values mean nothing and are left out (gaps). ``driver_kind``: "crank" or "slider"
    (``mechanism.driver.kind``)."""
    check_driver_kind("plot_reduced", driver_kind)
    if ok is not None:
        j_red = masked(j_red, ok)
        tau_red = None if tau_red is None else masked(tau_red, ok)
    slider = driver_kind == "slider"
    if axes is None:
        _, axes = plt.subplots(1, 2 if tau_red is not None else 1, figsize=(10 if tau_red is not None else 5, 4), squeeze=False, layout="constrained")
        axes = axes[0]
    plot_against(q, {"J_red": j_red}, xlabel=driving_label(driver_kind), ylabel="reduced inertia (kg)" if slider else "reduced inertia (kg m^2)", ax=axes[0], title="reduced inertia")
    shown = np.asarray(j_red)[np.isfinite(j_red)]
    if shown.size and shown.min() > 0 and shown.max() > 1e3 * shown.min():  # near a dead point J_red grows without bound
        axes[0].set_yscale("log")
    if tau_red is not None:
        plot_against(q, {"tau_red": tau_red}, xlabel=driving_label(driver_kind), ylabel="reduced load (N)" if slider else "reduced torque (N m)", ax=axes[1], title="reduced load")
    for ax in axes:  # a stroke's many-digit ticks ran into each other at matplotlib's default count
        ax.locator_params(axis="x", nbins=6)
    return axes


def plot_velocity_polygon(velocities: Mapping[str, np.ndarray], *, ax=None, unit: str = "mm", relative: Iterable[tuple[str, str]] = ()):
    """The velocity polygon (Fanghella et al. 2019, Fig. 5): absolute velocities drawn from one
    pole, relative velocities v_ab = v_a - v_b joining their tips.

    ``velocities``: point -> (2,) velocity (m/s); ``relative``: pairs (a, b) for
    which v_ab is drawn. Lengths in ``unit``/s ("m", "cm" or "mm")."""
    s = length_scale(unit, "plot_velocity_polygon")
    if not velocities:
        raise AssurjaxError("plot_velocity_polygon: no velocities given (point -> (2,) velocity, m/s)")
    for name, v in velocities.items():
        v = np.asarray(v, dtype=float)
        if v.shape != (2,) or not np.all(np.isfinite(v)):
            raise AssurjaxError(f"plot_velocity_polygon: the velocity of '{name}' must be 2 finite numbers (m/s), got {v.tolist()}")
    ax = _axes(ax, (5, 5))
    tips = {}
    for i, (name, v) in enumerate(velocities.items()):
        v = np.asarray(v, dtype=float) * s
        tips[name] = v
        ax.annotate("", xy=tuple(v), xytext=(0, 0), arrowprops=dict(arrowstyle="->", lw=2, color=f"C{i}"))
        ax.plot([], [], color=f"C{i}", lw=2, label=f"v_{name}: {np.hypot(*v):.1f} {unit}/s")
        ax.annotate(f"v_{name}", tuple(v), xytext=(4, 4), textcoords="offset points", fontsize=9)
    for a, b in relative:
        unknown = [p for p in (a, b) if p not in tips]
        if unknown:
            raise AssurjaxError(f"plot_velocity_polygon: relative pair ({a!r}, {b!r}) names point(s) {unknown} without a "
                             f"velocity; velocities has {sorted(tips)}")
        d = tips[a] - tips[b]
        ax.annotate("", xy=tuple(tips[a]), xytext=tuple(tips[b]), arrowprops=dict(arrowstyle="->", lw=1.2, ls="--", color="gray"))
        ax.plot([], [], color="gray", ls="--", label=f"v_{a}{b}: {np.hypot(*d):.1f} {unit}/s")
    pts = np.array([[0.0, 0.0], *tips.values()])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = 0.15 * float(np.max(hi - lo) or 1.0)
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.plot([0], [0], "ko")
    ax.set_xlabel(f"v_x ({unit}/s)")
    ax.set_ylabel(f"v_y ({unit}/s)")
    ax.set_title("velocity polygon")
    ax.grid(True, lw=0.3)
    ax.legend(fontsize=8, loc="best")
    return ax
