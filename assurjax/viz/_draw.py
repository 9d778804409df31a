"""Drawing a mechanism: links as polygons or bars through their points, joints as
circles, ground pivots with hatched symbols, guides, traced point paths and
velocity arrows. One :class:`MechanismDrawing` owns the artists and moves them
from frame to frame, which is what the animation needs."""

from __future__ import annotations

from collections.abc import Iterable

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Polygon

from .._errors import AssemblyError, AssurjaxError
from .._kinematics import point_names
from .._mechanism import Mechanism
from .._values import check_value, check_values
from ..groups import GROUND
from ._frames import Frames, check_coordinates, extent, length_scale, mechanism_frames

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


def _moving_guides(mechanism: Mechanism) -> list[tuple[str, np.ndarray, str]]:
    """(link carrying the guide, unit direction in its frame, the point sliding on it) of each
    prismatic guide a moving link carries (a slot): drawn from frame to frame, as far as
    the sliding point, so a block there sits on its slot."""
    owner = dict(mechanism.owner)
    slots = []
    for g in mechanism.groups:
        for (_, carrier, point), (guide_point, direction, _) in zip(g.prismatic_pairs(owner), g.guides()):
            if carrier == GROUND or (guide_point is not None and owner.get(guide_point) != carrier):
                continue  # a ground guide (drawn once), or a group whose lists do not pair up
            u = np.asarray(direction, dtype=float)
            slots.append((carrier, u / np.hypot(*u), point))
    return slots


def _rotated(u: np.ndarray, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([c * u[0] - s * u[1], s * u[0] + c * u[1]])


class MechanismDrawing:
    """The artists of one mechanism on one Axes; :meth:`update` moves them to a frame.

    **Arguments:**
    - ``ax``: the matplotlib Axes (equal aspect is set).
    - ``mechanism``: the :class:`assurjax.Mechanism` to draw.
    - ``frames``: the configurations that will be shown (used for limits, traces
      and the velocity scale).
    - ``trace``: point names whose whole path over ``frames`` is drawn (coupler curves).
    - ``velocities``: point names that get a velocity arrow (needs ``frames.velocities``).
    - ``velocity_scale``: arrow length per unit speed (s: m of drawing per m/s), positive;
      default: the fastest arrow (bar the fastest tenth) is a quarter of the mechanism's size.
    - ``velocity_label``: the arrows' legend entry (what they show; their scale is added).
    - ``unit``: length unit of the axes ("m", "cm" or "mm").
    - ``labels``: write point names next to the joints.
    - ``trace_frames``: configurations for the traced paths, if not ``frames``.

    A frame where the mechanism does not assemble (``frames.ok`` False) shows its links
    faded and no joints, labels nor arrows: its positions are no pose.

    The axes follow the mechanism at the drawn poses (``size``: its extent, m), widened by
    the traced paths and velocity arrows up to ``REACH`` sizes beyond it: paths and arrows
    that reach farther (near a singular position) are cut at the axes' edge, and the x
    label says so.
    """

    REACH = 1.0  # how far (in mechanism sizes) traced paths and arrow tips may widen the view

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
        velocity_label: str = "velocity",
    ):
        self.ax, self.mechanism, self.frames = ax, mechanism, frames
        self.trace_frames = frames if trace_frames is None else trace_frames
        self.scale = length_scale(unit, "MechanismDrawing")
        check_velocity_scale("MechanismDrawing", velocity_scale)
        self.velocity_points = tuple(velocities)
        if self.velocity_points and frames.velocities is None:
            raise AssurjaxError("MechanismDrawing: velocity arrows need frames computed with velocities=True")
        lo, hi = extent(frames)  # the mechanism at the drawn poses
        self.size = float(np.max(hi - lo)) or 1.0
        self.velocity_scale = velocity_scale if velocity_scale is not None else self._auto_velocity_scale()
        self._setup_axes(*self._widened(lo, hi, tuple(trace)), unit)
        self._say_clipped(tuple(trace), unit)
        self._draw_ground()
        self._draw_traces(tuple(trace))
        self.slots = [(self.ax.plot([], [], color=self._link_color(carrier), lw=1.5, alpha=0.7, zorder=2.2)[0], carrier, u, p)
                      for carrier, u, p in _moving_guides(mechanism)]
        self.link_artists = self._make_links()
        self.joints = ax.plot([], [], "o", ms=6, mfc="white", mec="black", mew=1.5, zorder=5)[0]
        self.labels = {p: ax.annotate(p, (0, 0), xytext=(4, 4), textcoords="offset points", fontsize=8, zorder=6) for p in mechanism.point_names} if labels else {}
        self.arrows = {p: self._velocity_arrow() for p in self.velocity_points}
        if self.velocity_points:  # a legend entry saying how long the arrows are
            gap = " " if velocity_label == "velocity" else "\n"  # a longer one on two lines: the legend's width is cut off
            length = f"({self.velocity_scale * self.scale:.3g} {unit} per m/s)"
            ax.plot([], [], color=VELOCITY_COLOR, lw=1.5, label=f"{velocity_label}{gap}{length}")
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
        # a high percentile, not the maximum: speeds blow up near singular positions (and are
        # NaN exactly at one)
        speeds = np.concatenate([np.hypot(*self.frames.velocities[p][self.frames.ok].T) for p in self.velocity_points])
        speeds = speeds[np.isfinite(speeds)]
        vmax = float(np.percentile(speeds, 90)) if speeds.size else 0.0
        return 0.25 * self.size / vmax if vmax > 0 else 1.0

    def _arrow_tips(self) -> dict[str, np.ndarray]:
        """Each velocity arrow's tips (m) over the assembled frames with a finite velocity."""
        f, tips = self.frames, {}
        for p in self.velocity_points:
            xy = f.points[p] + f.velocities[p] * self.velocity_scale
            tips[p] = xy[f.ok & np.all(np.isfinite(xy), axis=1)]
        return tips

    def _path_points(self, trace) -> dict[str, np.ndarray]:
        """Each traced path's points (m) where the mechanism assembles."""
        f = self.trace_frames
        paths = {n: f.points[n][f.ok] for n in trace}
        return {n: xy[np.all(np.isfinite(xy), axis=1)] for n, xy in paths.items()}

    def _widened(self, lo, hi, trace):
        """The view's corners (m): the mechanism's, widened by the traced paths' points and the
        arrow tips within REACH sizes of it (those farther are cut at the axes' edge)."""
        far_lo, far_hi = lo - self.REACH * self.size, hi + self.REACH * self.size
        for xy in [*self._path_points(trace).values(), *self._arrow_tips().values()]:
            near = xy[np.all((xy >= far_lo) & (xy <= far_hi), axis=1)]
            if len(near):
                lo, hi = np.minimum(lo, near.min(axis=0)), np.maximum(hi, near.max(axis=0))
        return lo, hi

    def _setup_axes(self, lo, hi, unit):
        self.view = float(np.max(hi - lo)) or self.size  # the view's extent (m)
        pad = 0.12 * self.view
        ax, s = self.ax, self.scale
        ax.set_xlim((lo[0] - pad) * s, (hi[0] + pad) * s)
        ax.set_ylim((lo[1] - pad) * s, (hi[1] + pad) * s)
        ax.set_aspect("equal")
        ax.set_xlabel(f"x ({unit})")
        ax.set_ylabel(f"y ({unit})")
        ax.grid(True, lw=0.3, alpha=0.5)

    def _say_clipped(self, trace, unit):
        """Add to the x label each path and arrow that reaches past the axes (cut at their edge)."""
        s = self.scale
        box_lo = np.array([self.ax.get_xlim()[0], self.ax.get_ylim()[0]]) / s
        box_hi = np.array([self.ax.get_xlim()[1], self.ax.get_ylim()[1]]) / s
        notes = [clipped_note(f"path of {n}", (xy.min(axis=0), xy.max(axis=0)), s, unit)
                 for n, xy in self._path_points(trace).items() if np.any((xy < box_lo) | (xy > box_hi))]
        for p, xy in self._arrow_tips().items():
            out = int(np.count_nonzero(np.any((xy < box_lo) | (xy > box_hi), axis=1)))
            if out:
                notes.append(clipped_note(f"velocity arrow of {p}", (out, len(xy)), s, unit))
        self.ax.set_xlabel("\n".join([self.ax.get_xlabel(), *notes]))

    def _draw_ground(self):
        s, h = self.scale, 0.04 * self.size * self.scale
        for name, xy in self.mechanism.ground.items():
            x, y = np.asarray(xy, dtype=float) * s
            self.ax.add_patch(Polygon([[x, y], [x - h, y - 1.5 * h], [x + h, y - 1.5 * h]], closed=True, fc="lightgray", ec="black", hatch="///", zorder=3))
        for base, u in _ground_guides(self.mechanism):  # across the whole view, wherever the base is in it
            ends = np.array([base - 3 * self.view * u, base + 3 * self.view * u]) * s
            self.ax.plot(ends[:, 0], ends[:, 1], color="gray", lw=1, ls="--", zorder=1)

    def _draw_traces(self, names):
        s, ok = self.scale, self.trace_frames.ok
        named = len(names) <= len(TRACE_COLORS)  # see _make_links
        for k, name in enumerate(names):
            xy = np.where(ok[:, None], self.trace_frames.points[name], np.nan) * s
            self.ax.plot(xy[:, 0], xy[:, 1], lw=1.2, ls="--", color=trace_color(k), zorder=2,
                         label=f"path of {name}" if named else None)

    def _link_color(self, link: str):
        return LINK_COLORS[list(self.mechanism.links).index(link) % len(LINK_COLORS)]

    def _make_links(self) -> dict:
        # legend entries only while each colour is one link's: past the palette colours repeat,
        # and an entry names nothing (the strandbeest's 49 links overflowed the figure)
        named = len(self.mechanism.links) <= len(LINK_COLORS)
        artists = {}
        for name, link in self.mechanism.links.items():
            color, label = self._link_color(name), name if named else None
            order = _hull_order(link.points)
            if len(order) == 2:  # a bar
                artist = self.ax.plot([], [], color=color, lw=4, solid_capstyle="round", zorder=3.5, label=label)[0]
            else:  # a plate through its points, or a slider block around its only point
                corners = np.zeros((4 if len(order) == 1 else len(order), 2))
                artist = self.ax.add_patch(Polygon(corners, closed=True, fc=color, ec=color, lw=2, zorder=2.5, label=label))
            artists[name] = (artist, order)
        return artists

    BLOCK = (0.06, 0.035)  # a slider block's half length and half width, in mechanism sizes

    def _block(self, centre, angle):
        """Corners of a slider block centred on ``centre`` and aligned with ``angle``."""
        a, b = self.BLOCK[0] * self.size, self.BLOCK[1] * self.size
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
        for line, carrier, u, p in self.slots:
            line.set_data(*(self._slot(f, carrier, u, p) * s).T)
            line.set_visible(f["ok"])
        xy = np.array([pts[p] for p in self.mechanism.point_names]) * s
        self.joints.set_data(xy[:, 0], xy[:, 1])
        self.joints.set_visible(f["ok"])  # where it does not assemble the joints sit where no pose puts them
        for p, label in self.labels.items():
            label.xy = tuple(pts[p] * s)
            label.set_visible(f["ok"])
        for p, arrow in self.arrows.items():
            tail, v = pts[p] * s, f["velocities"][p]
            shown = f["ok"] and bool(np.all(np.isfinite(v)))  # none at a singular configuration, where it is undefined (NaN)
            arrow.xy = tuple(tail + (v * self.velocity_scale * s if shown else 0.0))
            arrow.set_position(tuple(tail))
            arrow.set_visible(shown)
        slots = [line for line, *_ in self.slots]
        return [*slots] + [a for a, _ in self.link_artists.values()] + [self.joints, *self.labels.values(), *self.arrows.values()]

    def _slot(self, f: dict, carrier: str, u: np.ndarray, point: str) -> np.ndarray:
        """The ends (m) of a slot at frame ``f``: along its line through the sliding point,
        over the carrier's points and a block's length past the sliding point."""
        base, along = f["points"][point], _rotated(u, f["angles"][carrier])
        reach = [(f["points"][n] - base) @ along for n in self.mechanism.links[carrier].points]
        block = self.BLOCK[0] * self.size
        return np.array([base + min(*reach, -block) * along, base + max(*reach, block) * along])


def clipped_note(what: str, clipped, scale: float, unit: str) -> str:
    """The x label's words for a path or an arrow cut at the axes' edge."""
    if isinstance(clipped[0], int):  # (frames where it does, frames)
        where = f" in {clipped[0]} of {clipped[1]} frames" if clipped[1] > 1 else ""
        return f"(the {what} reaches past the edge{where}: cut there)"
    corners = np.array([clipped[0], clipped[1]], dtype=float) * scale
    corners[np.abs(corners) <= 1e-12 * np.abs(corners).max()] = 0.0  # round-off, not a place (h cot(pi/2) = 1.2e-17 m)
    (x0, y0), (x1, y1) = corners
    return f"(the {what} is cut at the edge: it reaches x in [{x0:.3g}, {x1:.3g}], y in [{y0:.3g}, {y1:.3g}] {unit})"


def check_velocity_scale(where: str, velocity_scale) -> None:
    """None (chosen from the speeds) or a positive, finite arrow length per unit speed (s)."""
    if velocity_scale is not None:
        check_value(AssurjaxError, f"{where}: velocity_scale", velocity_scale, shape=(), positive=True)


def _check_drawing_request(q, omega, trace_q, unit, velocity_scale) -> None:
    """Refuse a bad draw_mechanism request by its keyword, before any kinematics is traced."""
    check_values(AssurjaxError, "draw_mechanism", shape=(), q=q, omega=omega)
    check_velocity_scale("draw_mechanism", velocity_scale)
    length_scale(unit, "draw_mechanism")
    if trace_q is not None:
        check_coordinates("draw_mechanism", "trace_q", trace_q)


def posed_frames(where: str, mechanism: Mechanism, q, omega, *, velocities: bool, check: bool, hint: str) -> Frames:
    """The frames at ``q``, refused where a group cannot assemble (the kinematics' own
    AssemblyError, naming the group and q, prefixed by ``where`` and followed by ``hint``)
    unless ``check`` is False: then such frames are kept, flagged in ``Frames.ok``."""
    try:
        return mechanism_frames(mechanism, q, omega, velocities=velocities, check=check)
    except AssemblyError as e:
        raise AssemblyError(f"{where}: {e}; {hint}", group=e.group) from e


def place_legend(ax):
    """The legend outside the drawing, on its right, so it never hides the mechanism; none
    where nothing is named (see ``MechanismDrawing._make_links``)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=7, borderaxespad=0.0)
        make_room_for_legend(ax)


def make_room_for_legend(ax):
    """A legend outside the axes in a figure without a layout engine (a user's
    ``plt.subplots()``) gets matplotlib's constrained layout, which makes room for it: without
    it a plain ``savefig`` cut the legend off, and in a figure of several axes it lay on the
    next panel's ticks and title."""
    fig = ax.get_figure()
    if fig is not None and fig.get_layout_engine() is None:
        fig.set_layout_engine("constrained")


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
    check: bool = True,
):
    """Draw ``mechanism`` at driving coordinate ``q`` (rad or m).

    ``velocities``: points that get velocity arrows for the driving speed ``omega``
    (rad/s or m/s; the legend says which), ``velocity_scale`` long per m/s (s, positive;
    default: from the speeds). ``trace``: points whose paths over ``trace_q`` (an array of
    driving coordinates; default a full turn around q) are drawn dashed, one colour per point.
    Returns the :class:`MechanismDrawing` (its ``ax`` is the Axes).

    ``q`` must be a pose, as every frame of :func:`animate`: a q where some group cannot
    assemble raises :class:`assurjax.AssemblyError` naming the group and q. With
    ``check=False`` it is drawn marked instead: its links faded, no joints, labels nor arrows
    (its positions are no pose), and the title says it does not assemble there.

    **Example:**
    >>> drawing = assurjax.viz.draw_mechanism(mech, 1.0, velocities=["P"], trace=["P"], unit="mm")
    """
    velocities = point_names(mechanism, velocities, "draw_mechanism: velocities")
    trace = point_names(mechanism, trace, "draw_mechanism: trace")
    _check_drawing_request(q, omega, trace_q, unit, velocity_scale)
    frames = posed_frames("draw_mechanism", mechanism, [q], omega, velocities=bool(velocities), check=check,
                          hint="q must be a pose (check=False draws it faded)")  # before a figure is opened
    own_figure = ax is None
    if own_figure:
        _, ax = plt.subplots(figsize=(8, 5), layout="constrained")
    trace_frames = None
    if trace:
        trace_q = np.asarray(trace_q if trace_q is not None else q + np.linspace(-np.pi, np.pi, 361), dtype=float)
        trace_frames = mechanism_frames(mechanism, trace_q)
    q_unit = "m" if mechanism.driver.kind == "slider" else "rad"
    drawing = MechanismDrawing(ax, mechanism, frames, trace=trace, velocities=velocities, unit=unit, labels=labels,
                               velocity_scale=velocity_scale, trace_frames=trace_frames,
                               velocity_label=f"velocity at omega = {float(omega):.4g} {q_unit}/s")
    drawing.update(0)
    unassembled = "" if frames.ok[0] else " (it does not assemble there: the drawing means nothing)"
    ax.set_title(f"{mechanism.name} at q = {float(q):.4g} {q_unit}{unassembled}")
    place_legend(ax)
    if own_figure:
        widen_for_drawing(ax)
    return drawing


def widen_for_drawing(ax) -> None:
    """The axes' own 5 in high figure made wide enough for its equal-aspect drawing beside its
    y label and legend: in a fixed 8 in the layout could not fit a wide one (the strandbeest) or a
    long legend (a velocity scale's), and cut the label and the legend off."""
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    legend, fig = ax.get_legend(), ax.figure
    width = 0.0
    if legend is not None:
        try:  # measured: its labels' length varies (1.6 in was too little for a velocity scale's)
            width = legend.get_window_extent(fig.canvas.get_renderer()).width / fig.dpi
        except (AttributeError, RuntimeError):  # a canvas without a renderer to measure with
            width = 1.6
    beside = 0.9 + width + (0.2 if legend is not None else 0.0)  # inches: the y label and ticks, the legend
    fig.set_size_inches(min(max(8.0, 4.2 * (x1 - x0) / (y1 - y0) + beside), 16.0), 5.0)
