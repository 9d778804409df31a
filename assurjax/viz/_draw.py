"""Drawing a mechanism: links as polygons or bars through their points, joints as
circles, ground pivots with hatched symbols, guides, traced point paths and
velocity arrows. One :class:`MechanismDrawing` owns the artists and moves them
from frame to frame, which is what the animation needs."""

from __future__ import annotations

from collections.abc import Iterable

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Polygon

from .._errors import AssurjaxError
from .._kinematics import point_names
from .._mechanism import Mechanism
from .._values import check_values
from ..groups import GROUND
from ._frames import Frames, extent, length_scale, mechanism_frames

LINK_COLORS = plt.rcParams["axes.prop_cycle"].by_key()["color"]
VELOCITY_COLOR = "crimson"
TRACE_COLORS = plt.get_cmap("Dark2").colors  # distinct from the links' colours


def trace_color(k: int):
    """Colour of the k-th traced point path (one per point, shared by every plot)."""
    return TRACE_COLORS[k % len(TRACE_COLORS)]


def _hull_order(local: dict[str, np.ndarray]) -> list[str]:
    """Point names of a link ordered by angle around their centroid (a tidy polygon);
    for points on one line, the two end points (the link is drawn as a bar)."""
    names = list(local)
    xy = np.array([np.asarray(local[n], dtype=float) for n in names])
    c = xy.mean(axis=0)
    if len(names) >= 3:
        _, sv, vt = np.linalg.svd(xy - c)
        if sv[1] <= 1e-9 * max(sv[0], 1e-300):  # collinear: a bar between its extreme points
            along = (xy - c) @ vt[0]
            return [names[int(np.argmin(along))], names[int(np.argmax(along))]]
    order = np.argsort(np.arctan2(xy[:, 1] - c[1], xy[:, 0] - c[0]))
    return [names[i] for i in order]


def _ground_guides(mechanism: Mechanism) -> list[tuple[np.ndarray, np.ndarray]]:
    """(point on the line, unit direction) of each prismatic guide carried by the ground (m):
    the guides the groups declare (``AbstractGroup.guides``) through a ground point."""
    owner = dict(mechanism.owner)
    guides = []
    for g in mechanism.groups:
        for point, direction, offset in g.guides():
            if point is None or owner.get(point) != GROUND:
                continue
            u = np.asarray(direction, dtype=float)
            u = u / np.hypot(*u)
            n = np.array([-u[1], u[0]])
            guides.append((np.asarray(mechanism.ground[point], dtype=float) + float(offset) * n, u))
    return guides


class MechanismDrawing:
    """The artists of one mechanism on one Axes; :meth:`update` moves them to a frame.

    **Arguments:**
    - ``ax``: the matplotlib Axes (equal aspect is set).
    - ``mechanism``: the :class:`assurjax.Mechanism` to draw.
    - ``frames``: the configurations that will be shown (used for limits, traces
      and the velocity scale).
    - ``trace``: point names whose whole path over ``frames`` is drawn (coupler curves).
    - ``velocities``: point names that get a velocity arrow (needs ``frames.velocities``).
    - ``velocity_scale``: arrow length per unit speed (s: m of drawing per m/s);
      default: the fastest arrow is a quarter of the drawing's size.
    - ``unit``: length unit of the axes ("m", "cm" or "mm").
    - ``labels``: write point names next to the joints.
    - ``trace_frames``: configurations for the traced paths, if not ``frames``.
    """

    def __init__(
        self,
        ax,
        mechanism: Mechanism,
        frames: Frames,
        *,
        trace: Iterable[str] = (),
        velocities: Iterable[str] = (),
        velocity_scale: float | None = None,
        unit: str = "m",
        labels: bool = True,
        trace_frames: Frames | None = None,
    ):
        self.ax, self.mechanism, self.frames = ax, mechanism, frames
        self.trace_frames = frames if trace_frames is None else trace_frames
        self.scale = length_scale(unit)
        self.velocity_points = tuple(velocities)
        if self.velocity_points and frames.velocities is None:
            raise ValueError("velocity arrows need frames computed with velocities=True")
        lo, hi = extent(frames)
        if trace_frames is not None and trace:
            t_lo, t_hi = extent(trace_frames, trace)
            lo, hi = np.minimum(lo, t_lo), np.maximum(hi, t_hi)
        self.size = float(np.max(hi - lo)) or 1.0
        self.velocity_scale = velocity_scale if velocity_scale is not None else self._auto_velocity_scale()
        self._setup_axes(lo, hi, unit)
        self._draw_ground()
        self._draw_traces(tuple(trace))
        self.link_artists = self._make_links()
        self.joints = ax.plot([], [], "o", ms=6, mfc="white", mec="black", mew=1.5, zorder=5)[0]
        self.labels = {p: ax.annotate(p, (0, 0), xytext=(4, 4), textcoords="offset points", fontsize=8, zorder=6) for p in mechanism.point_names} if labels else {}
        self.arrows = {p: self._velocity_arrow() for p in self.velocity_points}
        if self.velocity_points:  # a legend entry saying how long the arrows are
            ax.plot([], [], color=VELOCITY_COLOR, lw=1.5, label=f"velocity ({self.velocity_scale * self.scale:.3g} {unit} per m/s)")
        self.update(self._first_ok())

    def _first_ok(self) -> int:
        ok = np.flatnonzero(self.frames.ok)
        return int(ok[0]) if ok.size else 0

    def _velocity_arrow(self):
        """An arrow drawn wherever its tip is, cut at the axes' edge: matplotlib skips an
        annotation whose tip lies outside the axes, and the fastest points lost their arrows
        (the Watt six-bar's A in 11 of 60 frames of the command's animation)."""
        arrow = self.ax.annotate("", (0, 0), xytext=(0, 0), arrowprops=dict(arrowstyle="->", color=VELOCITY_COLOR, lw=1.5),
                                 zorder=7, annotation_clip=False)
        arrow.arrow_patch.set_clip_box(self.ax.bbox)
        arrow.arrow_patch.set_clip_on(True)
        return arrow

    def _auto_velocity_scale(self) -> float:
        if not self.velocity_points:
            return 1.0
        # a high percentile, not the maximum: speeds blow up near singular positions
        speeds = np.concatenate([np.hypot(*self.frames.velocities[p][self.frames.ok].T) for p in self.velocity_points])
        vmax = float(np.percentile(speeds, 90)) if speeds.size else 0.0
        return 0.25 * self.size / vmax if vmax > 0 else 1.0

    def _setup_axes(self, lo, hi, unit):
        pad = 0.12 * self.size
        ax, s = self.ax, self.scale
        ax.set_xlim((lo[0] - pad) * s, (hi[0] + pad) * s)
        ax.set_ylim((lo[1] - pad) * s, (hi[1] + pad) * s)
        ax.set_aspect("equal")
        ax.set_xlabel(f"x ({unit})")
        ax.set_ylabel(f"y ({unit})")
        ax.grid(True, lw=0.3, alpha=0.5)

    def _draw_ground(self):
        s, h = self.scale, 0.04 * self.size * self.scale
        for name, xy in self.mechanism.ground.items():
            x, y = np.asarray(xy, dtype=float) * s
            self.ax.add_patch(Polygon([[x, y], [x - h, y - 1.5 * h], [x + h, y - 1.5 * h]], closed=True, fc="lightgray", ec="black", hatch="///", zorder=3))
        for base, u in _ground_guides(self.mechanism):
            ends = np.array([base - 2 * self.size * u, base + 2 * self.size * u]) * s
            self.ax.plot(ends[:, 0], ends[:, 1], color="gray", lw=1, ls="--", zorder=1)

    def _draw_traces(self, names):
        s, ok = self.scale, self.trace_frames.ok
        named = len(names) <= len(TRACE_COLORS)  # see _make_links
        for k, name in enumerate(names):
            xy = np.where(ok[:, None], self.trace_frames.points[name], np.nan) * s
            self.ax.plot(xy[:, 0], xy[:, 1], lw=1.2, ls="--", color=trace_color(k), zorder=2,
                         label=f"path of {name}" if named else None)

    def _make_links(self) -> dict:
        # legend entries only while each colour is one link's: past the palette colours repeat,
        # and an entry names nothing (the strandbeest's 49 links overflowed the figure)
        named = len(self.mechanism.links) <= len(LINK_COLORS)
        artists = {}
        for i, (name, link) in enumerate(self.mechanism.links.items()):
            color, label = LINK_COLORS[i % len(LINK_COLORS)], name if named else None
            order = _hull_order(link.points)
            if len(order) == 2:  # a bar
                artist = self.ax.plot([], [], color=color, lw=4, solid_capstyle="round", zorder=3.5, label=label)[0]
            else:  # a plate through its points, or a slider block around its only point
                corners = np.zeros((4 if len(order) == 1 else len(order), 2))
                artist = self.ax.add_patch(Polygon(corners, closed=True, fc=color, ec=color, lw=2, zorder=2.5, label=label))
            artists[name] = (artist, order)
        return artists

    def _block(self, centre, angle):
        """Corners of a slider block centred on ``centre`` and aligned with ``angle``."""
        a, b = 0.06 * self.size, 0.035 * self.size
        u = np.array([np.cos(angle), np.sin(angle)])
        n = np.array([-u[1], u[0]])
        return np.array([centre + a * u + b * n, centre - a * u + b * n, centre - a * u - b * n, centre + a * u - b * n])

    def update(self, i: int) -> list:
        """Move every artist to configuration ``i``; returns the artists (for blitting)."""
        f = self.frames.at(i)
        s, pts = self.scale, f["points"]
        for name, (artist, order) in self.link_artists.items():
            if len(order) == 1:
                artist.set_xy(self._block(pts[order[0]], f["angles"][name]) * s)
            elif len(order) == 2:
                xy = np.array([pts[p] for p in order]) * s
                artist.set_data(xy[:, 0], xy[:, 1])
            else:
                artist.set_xy(np.array([pts[p] for p in order]) * s)
            artist.set_alpha((0.45 if len(order) != 2 else 0.9) if f["ok"] else 0.08)
        xy = np.array([pts[p] for p in self.mechanism.point_names]) * s
        self.joints.set_data(xy[:, 0], xy[:, 1])
        for p, label in self.labels.items():
            label.xy = tuple(pts[p] * s)
        for p, arrow in self.arrows.items():
            tail = pts[p] * s
            arrow.xy = tuple(tail + f["velocities"][p] * self.velocity_scale * s)
            arrow.set_position(tuple(tail))
        return [a for a, _ in self.link_artists.values()] + [self.joints, *self.labels.values(), *self.arrows.values()]


def place_legend(ax):
    """The legend outside the drawing, on its right, so it never hides the mechanism; none
    where nothing is named (see ``MechanismDrawing._make_links``)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=7, borderaxespad=0.0)


def draw_mechanism(
    mechanism: Mechanism,
    q: float,
    *,
    omega: float = 1.0,
    ax=None,
    velocities: Iterable[str] = (),
    trace: Iterable[str] = (),
    trace_q=None,
    unit: str = "m",
    labels: bool = True,
    velocity_scale: float | None = None,
):
    """Draw ``mechanism`` at driving coordinate ``q`` (rad or m).

    ``velocities``: points that get velocity arrows for the driving speed ``omega``
    (rad/s or m/s). ``trace``: points whose paths over ``trace_q`` (an array of
    driving coordinates; default a full turn around q) are drawn dashed, one colour per point.
    Returns the :class:`MechanismDrawing` (its ``ax`` is the Axes).

    **Example:**
    >>> drawing = assurjax.viz.draw_mechanism(mech, 1.0, velocities=["P"], trace=["P"], unit="mm")
    """
    velocities = point_names(mechanism, velocities, "draw_mechanism: velocities")
    trace = point_names(mechanism, trace, "draw_mechanism: trace")
    check_values(AssurjaxError, "draw_mechanism", shape=(), q=q, omega=omega)
    own_figure = ax is None
    if own_figure:
        _, ax = plt.subplots(figsize=(8, 5), layout="constrained")
    frames = mechanism_frames(mechanism, [q], omega, velocities=bool(velocities))
    trace_frames = None
    if trace:
        trace_q = np.asarray(trace_q if trace_q is not None else q + np.linspace(-np.pi, np.pi, 361), dtype=float)
        trace_frames = mechanism_frames(mechanism, trace_q)
    drawing = MechanismDrawing(ax, mechanism, frames, trace=trace, velocities=velocities, unit=unit, labels=labels,
                               velocity_scale=velocity_scale, trace_frames=trace_frames)
    drawing.update(0)
    unassembled = "" if frames.ok[0] else " (it does not assemble there: the drawing means nothing)"
    ax.set_title(f"{mechanism.name} at q = {float(q):.4g} {'m' if mechanism.driver.kind == 'slider' else 'rad'}{unassembled}")
    place_legend(ax)
    if own_figure:  # wide enough for an equal-aspect drawing beside its labels and legend (a wide one was clipped)
        (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
        beside = 0.9 + (1.6 if ax.get_legend() is not None else 0.0)  # inches: the y label, the legend
        ax.figure.set_size_inches(min(max(8.0, 4.0 * (x1 - x0) / (y1 - y0) + beside), 16.0), 5.0)
    return drawing
