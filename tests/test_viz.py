"""assurjax.viz, headless (Agg): what is drawn is checked against closed-form
positions (tests/joint_reference.py) and central finite differences."""

import gc
import os
import re
import sys
import warnings

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from PIL import Image  # noqa: E402

import assurjax  # noqa: E402
from assurjax import viz  # noqa: E402

sys.path.insert(0, os.path.dirname(__file__))
import joint_reference as jr  # noqa: E402

Q_WATT = np.linspace(0.0, 2 * np.pi, 7)


@pytest.fixture(scope="module")
def watt():
    return assurjax.load_scene("watt_sixbar").mechanism


@pytest.fixture(scope="module")
def watt_frames(watt):
    return viz.mechanism_frames(watt, Q_WATT, 2.0, velocities=True)


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


def test_frames_match_closed_form_positions(watt_frames):
    for i, q in enumerate(Q_WATT):
        points, _ = jr.watt_sixbar_points(q)
        for name in ("A", "B", "E"):
            np.testing.assert_allclose(watt_frames.points[name][i], points[name], atol=1e-12)
    assert watt_frames.ok.all()


def test_drawing_puts_links_and_joints_where_the_closed_form_says(watt, watt_frames):
    fig, ax = plt.subplots()
    drawing = viz.MechanismDrawing(ax, watt, watt_frames, velocities=["E"], trace=["E"])
    i = 3
    drawing.update(i)
    points, _ = jr.watt_sixbar_points(Q_WATT[i])
    crank, _ = drawing.link_artists["link2"]  # a bar O2-A
    xy = np.column_stack(crank.get_data())
    expected = {tuple(np.round(points["O2"], 9)), tuple(np.round(points["A"], 9))}
    assert {tuple(np.round(p, 9)) for p in xy} == expected
    coupler, order = drawing.link_artists["link3"]  # A, C, B on one line: drawn as a bar A-B
    assert sorted(order) == ["A", "B"]
    joints = np.column_stack(drawing.joints.get_data())
    np.testing.assert_allclose(joints[list(watt.point_names).index("E")], points["E"], atol=1e-12)


def test_velocity_arrow_is_the_finite_difference_velocity(watt, watt_frames):
    """Arrow from E to E + scale * v_E, with v_E = dE/dq * omega by central differences of the closed form."""
    fig, ax = plt.subplots()
    drawing = viz.MechanismDrawing(ax, watt, watt_frames, velocities=["E"], velocity_scale=0.1)
    i, h, omega = 2, 1e-6, 2.0
    drawing.update(i)
    e_plus, _ = jr.watt_sixbar_points(Q_WATT[i] + h)
    e_minus, _ = jr.watt_sixbar_points(Q_WATT[i] - h)
    v = (e_plus["E"] - e_minus["E"]) / (2 * h) * omega
    arrow = drawing.arrows["E"]
    np.testing.assert_allclose(arrow.xyann, watt_frames.points["E"][i], atol=1e-12)
    np.testing.assert_allclose(np.asarray(arrow.xy) - watt_frames.points["E"][i], 0.1 * v, rtol=1e-6, atol=1e-9)


def test_a_velocity_arrow_reaching_past_the_axes_is_drawn_to_their_edge(watt, watt_frames):
    """matplotlib skips an annotation whose tip lies outside the axes: the fastest points lost
    their arrows (the command's Watt six-bar animation: A in 11 of 60 frames). The arrow is
    drawn, cut at the axes' edge: crimson pixels on the segment from E towards its tip."""
    fig, ax = plt.subplots(figsize=(4, 4), dpi=100)
    drawing = viz.MechanismDrawing(ax, watt, watt_frames, velocities=["E"], velocity_scale=50.0, labels=False)
    drawing.update(2)
    tail, tip = np.asarray(drawing.arrows["E"].xyann), np.asarray(drawing.arrows["E"].xy)
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert not (x0 <= tip[0] <= x1 and y0 <= tip[1] <= y1)  # the tip is outside
    fig.canvas.draw()
    image = np.asarray(fig.canvas.buffer_rgba())[..., :3].astype(int)
    crimson = (np.abs(image - np.array([220, 20, 60])).sum(-1) < 60)
    inside = np.array([tail + s * (tip - tail) for s in np.linspace(0.0, 1.0, 4001)])
    inside = inside[(inside[:, 0] > x0) & (inside[:, 0] < x1) & (inside[:, 1] > y0) & (inside[:, 1] < y1)]
    pixels = ax.transData.transform(inside[len(inside) // 4: 3 * len(inside) // 4])  # clear of the joint
    rows, cols = (image.shape[0] - pixels[:, 1]).astype(int), pixels[:, 0].astype(int)
    near = [crimson[max(r - 2, 0): r + 3, max(c - 2, 0): c + 3].any() for r, c in zip(rows, cols)]
    assert np.mean(near) > 0.9


def test_coupler_curve_has_gaps_exactly_where_the_four_bar_cannot_assemble(roberts_scene):
    """Roberts: the dyad B-C-D assembles iff 0.06 <= |BD| <= 0.30 m (circle intersection)."""
    q = np.linspace(-np.pi, np.pi, 121)
    frames = viz.mechanism_frames(roberts_scene.mechanism, q)
    b = np.column_stack([-0.12 + 0.18 * np.cos(q), 0.18 * np.sin(q)])
    bd = np.hypot(*(np.array([0.12, 0.0]) - b).T)
    clear = (bd > 0.06 + 1e-6) & (bd < 0.30 - 1e-6)
    edge = ~clear & (np.abs(bd - 0.30) > 1e-6) & (np.abs(bd - 0.06) > 1e-6)
    ax = viz.plot_coupler_curves(frames, ["P"], unit="mm", equal=False)
    y = ax.lines[0].get_ydata()
    assert np.all(np.isfinite(y[clear])) and np.all(np.isnan(y[edge]))
    assert "(mm)" in ax.get_xlabel() and "(mm)" in ax.get_ylabel()
    assert ax.get_legend() is not None


def test_a_legend_outside_the_axes_stays_inside_a_users_figure(watt, watt_frames):
    """Axes of a user's plt.subplots() (no layout engine): a legend placed beside them is
    given room (a plain savefig cut it off). At omega = 1 the label says the speed."""
    fig, ax = plt.subplots()
    viz.plot_angular_velocities(watt_frames, ax=ax)
    fig.canvas.draw()
    assert len(watt.links) > 2 and ax.get_legend().get_window_extent().x1 <= fig.bbox.x1
    assert "at driver speed" not in ax.get_ylabel()  # these frames are at omega = 2
    unit_speed = viz.mechanism_frames(watt, Q_WATT[:3], velocities=True)
    assert "at driver speed 1 rad/s" in viz.plot_angular_velocities(unit_speed).get_ylabel()


def test_reactions_plot_takes_a_reactions_and_leaves_samples_without_statics_out():
    """A Reactions whole (it was a raw AttributeError): its samples whose friction_ok is False
    (no statics there, e.g. a jammed run's last state) are gaps, the others |F| = hypot(Fx, Fy)."""
    import assurjax as aj

    t, forces = np.linspace(0, 1, 4), np.array([[3.0, 4.0], [6.0, 8.0], [0.0, 1.0], [5.0, 12.0]])
    r = aj.Reactions(forces={"A": forces}, couples={}, driving=np.zeros(4), ok=np.ones((4, 1), bool), pairs=(),
                     friction_ok=np.array([True, True, True, False]))
    drawn = viz.plot_reactions(t, r).lines[0].get_ydata()
    np.testing.assert_array_equal(drawn[:3], [5.0, 10.0, 1.0])
    assert np.isnan(drawn[3])
    with pytest.raises(aj.AssurjaxError, match="pass an assurjax.Reactions or a mapping"):
        viz.plot_reactions(t, forces)


def test_line_plots_carry_units_and_legends(watt_frames):
    t = np.linspace(0, 1, 11)
    checks = [
        (viz.plot_angular_velocities(watt_frames, degrees=True), "deg/s"),
        (viz.plot_energies(t, t**2, 1 - t**2), "(J)"),
        (viz.plot_energy_drift(t, 1 + 1e-9 * t), "(J)"),
        (viz.plot_reactions(t, {"A": np.ones((11, 2))}), "(N)"),
        (viz.plot_time_histories(t, {"q": t}, ylabel="q (rad)"), "(rad)"),
    ]
    for ax, unit in checks:
        assert unit in ax.get_ylabel()
        assert ax.get_legend() is not None
    axes = viz.plot_reduced(t, 1 + t, -t)
    assert "kg m^2" in axes[0].get_ylabel() and "N m" in axes[1].get_ylabel()
    assert axes[0].get_yscale() == "linear"
    # near a dead point J_red grows without bound: a log scale shows the rest of the turn
    assert viz.plot_reduced(t, 1 / (1e-9 + (t - 0.5) ** 2))[0].get_yscale() == "log"
    # |F| = hypot(Fx, Fy)
    np.testing.assert_allclose(checks[3][0].lines[0].get_ydata(), np.sqrt(2.0))
    # with the work W and the dissipated energy D: T + V - W and D drawn as given
    ax = viz.plot_energies(t, t**2, 1 - t**2, work=-0.5 * t, dissipated=0.5 * t)
    assert [line.get_label() for line in ax.lines][2:] == ["T + V - W", "dissipated (friction, dampers)"]
    np.testing.assert_allclose(ax.lines[2].get_ydata(), 1 + 0.5 * t)
    np.testing.assert_allclose(ax.lines[3].get_ydata(), 0.5 * t)


@pytest.mark.parametrize("call, message", [
    (lambda m: viz.animate(m, [0.1, 0.2], trace=["ZZ"]), "animate: trace: unknown point\\(s\\) \\['ZZ'\\]"),
    (lambda m: viz.animate(m, [], trace=["E"]), "mechanism_frames: q must be one value or a 1-D array of at least one"),
    (lambda m: viz.animate(m, [0.1, 0.2], omega=[1.0, 2.0, 3.0]), "mechanism_frames: omega of shape \\(3,\\)"),
    (lambda m: viz.animate(m, [0.1, 0.2], t=[0.0]), "animate: t must give one time per value of q"),
    (lambda m: viz.draw_mechanism(m, np.array([0.3])), "draw_mechanism: q must be a single number"),
    (lambda m: viz.draw_mechanism(assurjax.load_scene("watt_sixbar"), 0.3), "expected an assurjax.Mechanism"),
    (lambda m: viz.save_gif([], "x.gif"), "save_gif: no frames to write"),
    (lambda m: viz.save_gif([np.zeros((4, 4, 3), np.uint8)], "x.png"), "save_gif: the path must end in .gif"),
    # a bare KeyError, an IndexError, an AttributeError, matplotlib's NaN limits, NumPy's broadcast
    (lambda m: viz.plot_angular_velocities(viz.mechanism_frames(m, [0.1, 0.2], velocities=True), ["nope"]),
     "plot_angular_velocities: unknown link\\(s\\) \\['nope'\\]"),
    (lambda m: viz.plot_energy_drift([], []), "energy drift: total must be a 1-D array of at least one sample"),
    (lambda m: viz.render_frames([1, 2]), "render_frames: expected an animation made by assurjax.viz.animate"),
    (lambda m: viz.plot_velocity_polygon({"A": [np.nan, 1.0]}), "the velocity of 'A' must be 2 finite numbers"),
    (lambda m: viz.plot_reactions(np.linspace(0, 1, 10), {"A": np.ones(10)}), "the force at 'A' must be \\(samples, 2\\)"),
    (lambda m: viz.plot_energies(np.linspace(0, 1, 10), np.ones(5), np.ones(10)), "energies: kinetic has shape \\(5,\\)"),
    (lambda m: viz.plot_time_histories(np.linspace(0, 1, 10), {"x": np.ones(3)}, ylabel="x (m)"),
     "'x' has shape \\(3,\\), its abscissa \\(10,\\)"),
])
def test_bad_drawing_requests_are_named(watt, call, message):
    with pytest.raises(assurjax.AssurjaxError, match=message):
        call(watt)


def test_a_wide_drawing_keeps_its_labels_and_legend_inside_the_figure(tmp_path):
    # equal aspect: in the fixed 8 x 5 in figure the strandbeest's y label and legend were cut off
    mech = assurjax.load_scene("strandbeest").mechanism
    drawing = viz.draw_mechanism(mech, 0.3, trace=["FL0", "FR0"])
    drawing.ax.figure.savefig(tmp_path / "wide.png")
    ink = np.asarray(Image.open(tmp_path / "wide.png").convert("L")) < 128
    assert not ink[:, :2].any() and not ink[:, -2:].any()
    assert drawing.ax.get_legend() is not None


def test_an_animation_keeps_its_labels_and_legend_inside_its_frames():
    # the command's animation of a fast offset slider-crank (a coupler point's path, its velocity
    # scale's legend entry): in the fixed 8 x 5 in figure the y label was gone and the legend cut off
    mech = assurjax.Sketch(joints={"O": (0.0, 0.0), "A": (0.0, 0.1), "B": (0.2891, 0.02), "P": (0.1, 0.25)},
                           links={"crank": ["O", "A"], "rod": ["A", "B", "P"], "ram": ["B"]}, ground=["O"],
                           slides=[assurjax.Slide("ram", "ground", (1.0, 0.0))], driver="crank").mechanism()
    q = np.linspace(1.6, 61.7, 60)
    anim = viz.animate(mech, q, 88.0 * (q - 1.6) / 60.1, t=np.linspace(0.0, 2.0, 60), trace=["A", "B", "P"],
                       trace_q=np.linspace(0.0, 2 * np.pi, 91), velocities=["A", "B"])
    frames = viz.render_frames(anim)
    ink = np.asarray(frames[20]).min(axis=-1) < 128
    assert not ink[:, :2].any() and not ink[:, -2:].any()
    label = anim.drawing.ax.yaxis.label
    assert label.get_text() == "y (m)" and label.get_window_extent().x0 >= 0
    plt.close(anim._fig)


def test_a_point_at_rest_is_drawn_as_a_point(watt):
    frames = viz.mechanism_frames(watt, np.full(5, 0.3))  # the same configuration throughout
    ax = viz.plot_coupler_curves(frames, ["E"])
    assert ax.lines[0].get_marker() == "o" and ax.lines[0].get_label() == "E (at rest)"


def test_velocity_polygon_closes(roberts_scene):
    """v_C = v_B + v_CB (seed 001, eq. 8): the relative arrow joins the two tips."""
    kin = assurjax.kinematics(roberts_scene.mechanism, 1.0, order=1)
    v = {p: np.asarray(kin.velocities[p]) for p in ("B", "C", "P")}
    ax = viz.plot_velocity_polygon(v, relative=[("C", "B")], unit="mm")
    arrows = [c for c in ax.texts if c.arrow_patch is not None]
    rel = arrows[-1]
    np.testing.assert_allclose(rel.xyann, v["B"] * 1e3, atol=1e-9)
    np.testing.assert_allclose(rel.xy, v["C"] * 1e3, atol=1e-9)
    assert "mm/s" in ax.get_xlabel()
    with pytest.raises(assurjax.AssurjaxError, match="relative pair \\('C', 'Z'\\) names point\\(s\\) \\['Z'\\]"):
        viz.plot_velocity_polygon(v, relative=[("C", "Z")])  # a bare KeyError: 'Z'


def test_animation_gif_and_html(tmp_path, watt):
    anim = viz.animate(watt, Q_WATT[:4], trace=["E"], velocities=["E"], t=np.arange(4) * 0.1)
    path = viz.save_gif(anim, tmp_path / "watt.gif", fps=10)
    with Image.open(path) as im:
        assert im.n_frames == 4
        assert im.info["duration"] == 100  # ms per frame at 10 fps
        # the figure's white in every frame (the first was 255, the rest 252: a flash at each loop)
        corners = [(im.seek(i), tuple(np.asarray(im.convert("RGB"))[2, 2]))[1] for i in range(4)]
        assert corners == [(255, 255, 255)] * 4
    html = viz.animation_html(viz.animate(watt, Q_WATT[:3]))
    assert "<script" in html and "img" in html
    assert html.count("iVBOR") == 3 + 1  # three PNG frames, plus the first one shown before any script runs


def test_gif_of_36_frames_has_every_frame_at_the_figure_size(tmp_path, watt):
    """Each frame is the figure rendered at that configuration: the crank tip A (a bar
    O2-A) moves from frame to frame, and the frame size is the figure's size in pixels."""
    q = np.linspace(0.0, 2 * np.pi, 36, endpoint=False)
    anim = viz.animate(watt, q, trace=["E"], trace_q=np.linspace(0, 2 * np.pi, 361), velocities=["E"])
    fig = anim._fig
    size = tuple(int(round(v)) for v in fig.get_size_inches() * fig.dpi)
    frames = viz.render_frames(anim)
    assert len(frames) == 36 and frames[0].shape == (size[1], size[0], 3)
    assert all(not np.array_equal(frames[i], frames[i + 1]) for i in range(35))
    # the moving crank is redrawn, the background is not duplicated: frame 0 rendered again is identical
    np.testing.assert_array_equal(viz.render_frames(anim)[0], frames[0])
    path = viz.save_gif(anim, tmp_path / "watt36.gif")
    with Image.open(path) as im:
        assert im.n_frames == 36 and im.size == size


def test_mp4_goes_to_ffmpeg_as_raw_frames(tmp_path, watt, monkeypatch):
    """A stand-in ffmpeg on the PATH records what it is given: 5 frames of w x h RGB."""
    fake = tmp_path / "bin" / "ffmpeg"
    fake.parent.mkdir()
    fake.write_text("#!/bin/sh\nfor last; do :; done\ncat > \"$last\"\necho \"$@\" > \"$last.args\"\n")
    fake.chmod(0o755)
    monkeypatch.setenv("PATH", f"{fake.parent}{os.pathsep}{os.environ['PATH']}")
    assert viz.ffmpeg_available()
    anim = viz.animate(watt, Q_WATT[:5])
    w, h = (int(round(v)) for v in anim._fig.get_size_inches() * anim._fig.dpi)
    out = viz.save_mp4(anim, tmp_path / "watt.mp4", fps=12)
    assert out.stat().st_size == 5 * w * h * 3
    args = (tmp_path / "watt.mp4.args").read_text()
    assert f"-s {w}x{h}" in args and "-r 12" in args and "libx264" in args


def test_player_widget_steps_through_the_frames(watt):
    pytest.importorskip("ipywidgets")
    box = viz.player(viz.animate(watt, Q_WATT[:3]))
    view, (play, slider) = box.children[0], box.children[1].children
    assert slider.max == 2 and play.max == 2
    first = view.value
    slider.value = 2
    assert bytes(view.value) != bytes(first) and bytes(view.value).startswith(b"\x89PNG")


def test_traced_points_have_their_own_colour_and_legend_entry(watt):
    drawing = viz.draw_mechanism(watt, 0.3, trace=["A", "B", "E"], trace_q=np.linspace(0, 2 * np.pi, 91))
    paths = [line for line in drawing.ax.lines if line.get_label().startswith("path of")]
    assert [p.get_label() for p in paths] == ["path of A", "path of B", "path of E"]
    assert len({p.get_color() for p in paths}) == 3
    legend = [t.get_text() for t in drawing.ax.get_legend().get_texts()]
    assert {"path of A", "path of B", "path of E"} <= set(legend)
    assert drawing.ax.get_title().endswith("q = 0.3 rad")
    anim = viz.animate(watt, [0.25, 0.5], t=[0.0, 0.1])
    assert anim._fig.axes[0].get_title().endswith("t = 0.000 s, q = 0.250 rad")
    viz.render_frames(anim)  # (an animation never rendered warns when it is deleted)


def test_legend_entries_are_told_apart_by_their_colours(watt):
    """A link gets a legend entry while every link has a colour of its own: the Watt six-bar's
    links, each its own colour; the strandbeest's 49 links share 10 colours, and their 57
    entries overflowed the figure (matplotlib warned that its layout collapsed)."""
    small = viz.draw_mechanism(watt, 0.3)
    handles, labels = small.ax.get_legend_handles_labels()
    assert labels == list(watt.links)
    colours = {matplotlib.colors.to_hex(h.get_color() if isinstance(h, Line2D) else h.get_facecolor()) for h in handles}
    assert len(colours) == len(watt.links)
    beest, q = assurjax.load_scene("strandbeest").mechanism, [0.25, 0.5]  # one position analysis compiled
    anim = viz.animate(beest, q, trace=["GL0", "GR0"], trace_q=q)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a collapsed layout warns
        frames = viz.render_frames(anim)
    assert len(frames) == 2
    assert [t.get_text() for t in anim._fig.axes[0].get_legend().get_texts()] == ["path of GL0", "path of GR0"]
    nameless = viz.animate(beest, q)
    assert len(viz.render_frames(nameless)) == 2 and nameless._fig.axes[0].get_legend() is None  # no empty legend


def test_legend_of_many_curves_sits_outside_the_data(watt_frames):
    ax = viz.plot_angular_velocities(watt_frames)
    fig = ax.figure
    fig.canvas.draw()
    legend = ax.get_legend().get_window_extent()
    assert legend.x0 >= ax.get_window_extent().x1  # right of the axes: it covers no curve


def test_draw_mechanism_slider_and_units(tmp_path):
    scene = assurjax.load_scene("slider_crank")
    drawing = viz.draw_mechanism(scene.mechanism, 0.5, velocities=["B"], unit="cm")
    ax = drawing.ax
    assert ax.get_xlabel() == "x (cm)"
    slider, order = drawing.link_artists["slider"]
    corners = slider.get_xy()[:4] / 100  # a block centred on B
    b = np.array([0.1 * np.cos(0.5) + np.sqrt(0.3**2 - (0.1 * np.sin(0.5)) ** 2), 0.0])
    np.testing.assert_allclose(corners.mean(axis=0), b, atol=1e-12)
    ax.figure.savefig(tmp_path / "slider.png")
    assert (tmp_path / "slider.png").stat().st_size > 1000



def _guided_mechanisms():
    """Bundled scenes with a guide on the ground, and random dyads (test_dyads) whose guides
    on the ground have random directions and offsets: RRP, PRR, a slider driver with a PRP."""
    import test_dyads

    rng = np.random.default_rng(7)
    out = {name: assurjax.load_scene(name).mechanism for name in ("slider_crank", "quick_return", "tangent_drive")}
    out["random RRP"] = test_dyads.crank_rrp(rng, 1)[0]
    out["random PRR"] = test_dyads.crank_rrp(rng, -1, kind="PRR")[0]
    out["random slider + PRP"] = test_dyads.slider_prp(rng)[0]
    return out


def test_ground_guides_drawn_through_the_sliding_points():
    """Every guide line the drawing puts on the ground carries the point that slides on it,
    at every configuration that assembles (the lines come from the groups' declared guides)."""
    from assurjax.groups import GROUND
    from assurjax.viz._draw import _ground_guides

    for name, mech in _guided_mechanisms().items():
        q = np.linspace(0.0, 2 * np.pi, 13) if mech.driver.kind == "crank" else np.linspace(-0.05, 0.05, 9)
        frames = viz.mechanism_frames(mech, q)
        lines = _ground_guides(mech)
        owner = dict(mech.owner)
        sliding = [p for g in mech.groups for _, guide, p in g.prismatic_pairs(owner) if guide == GROUND]
        assert lines and sliding and frames.ok.any(), name
        for p in sliding:
            xy = frames.points[p][frames.ok]
            distances = [np.max(np.abs(u[0] * (xy - base)[:, 1] - u[1] * (xy - base)[:, 0])) for base, u in lines]
            assert min(distances) < 1e-9, (name, p, distances)


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda m: viz.animate(m, np.linspace(0.0, 1.0, 10_001)), "at most 10000 frames"),
        (lambda m: viz.animate(m, [0.1, 0.2], interval_ms=0.0), "interval_ms must be positive"),
        (lambda m: viz.animate(m, [0.1, np.nan]), "q must be finite"),
        (lambda m: viz.animation_html(viz.animate(m, [0.1, 0.2]), fps=0), "fps must be positive"),
        (lambda m: viz.save_gif(viz.animate(m, [0.1, 0.2]), "never.gif", fps=np.inf), "fps must be finite"),
        (lambda m: viz.player(viz.animate(m, [0.1, 0.2]), fps=5000), "fps must be at most 1000"),
        # each refused by its keyword, before anything is traced or drawn
        (lambda m: viz.animate(m, [0.1, 0.2], unit="furlong"), "animate: unit must be one of 'm', 'cm', 'mm'"),
        (lambda m: viz.animate(m, [0.1, 0.2], t=[np.nan, 1.0]), "animate: t must be finite"),
        (lambda m: viz.animate(m, [0.1, 0.2, 0.3], t=[0.0, 0.2, 0.1]), "animate: t must not decrease from frame to frame"),
        (lambda m: viz.animate(m, [0.1, 0.2], omega=[1.0, np.inf]), "mechanism_frames: omega must be finite"),
        (lambda m: viz.animate(m, [0.1, 0.2], trace=["E"], trace_q=[[0.1, 0.2]]), "animate: trace_q must be one value or a 1-D"),
        (lambda m: viz.animate(m, [0.1, 0.2], trace=["E"], trace_q=[0.1, np.nan]), "animate: trace_q must be finite"),
        (lambda m: viz.animate(assurjax.load_scene("roberts"), [0.1]), "animate: expected an assurjax.Mechanism"),
        (lambda m: viz.save_gif("x", "never.gif"), "save_gif: anim must be an animation made by assurjax.viz.animate"),
        (lambda m: viz.save_gif([np.zeros((4, 4, 3))], "never.gif"), "save_gif: anim's frame 0 must be a (height, width, 3) uint8"),
        (lambda m: viz.save_gif([np.zeros((4, 4, 3), np.uint8)], "/nonexistent-dir/x.gif"), "save_gif: path's folder"),
        (lambda m: viz.save_mp4([np.zeros((4, 4, 3), np.uint8)] * 2, "never.gif"), "save_mp4: the path must end in .mp4"),
        (lambda m: viz.draw_mechanism(m, 0.1, velocities=["E"], velocity_scale=np.nan), "draw_mechanism: velocity_scale must be finite"),
        (lambda m: viz.draw_mechanism(m, 0.1, velocities=["E"], velocity_scale=0.0), "draw_mechanism: velocity_scale must be positive"),
        (lambda m: viz.draw_mechanism(m, 0.1, velocities=["E"], velocity_scale=-2.0), "draw_mechanism: velocity_scale must be positive"),
        (lambda m: viz.draw_mechanism(m, 0.1, unit="in"), "draw_mechanism: unit must be one of"),
        (lambda m: viz.plot_velocity_polygon({"A": [1.0, 0.0]}, unit="km"), "plot_velocity_polygon: unit must be one of 'm', 'cm', 'mm'"),
        (lambda m: viz.plot_reduced(np.arange(5.0), np.ones(5), driver_kind="rocket"), "plot_reduced: driver_kind must be one of 'crank', 'slider'"),
        (lambda m: viz.plot_angular_velocities(viz.mechanism_frames(m, [0.1]), driver_kind="rocket"), "plot_angular_velocities: driver_kind"),
        (lambda m: viz.plot_coupler_curves(viz.mechanism_frames(m, [0.1]), mechanism=assurjax.load_scene("watt_sixbar")),
         "plot_coupler_curves: expected an assurjax.Mechanism"),
    ],
)
@pytest.mark.filterwarnings("ignore:Animation was deleted without rendering")  # refused before rendering
def test_animation_requests_are_checked_and_bounded(watt, call, message):
    with pytest.raises(assurjax.AssurjaxError, match=re.escape(message)):
        call(watt)
    plt.close("all")


@pytest.mark.filterwarnings("ignore:Animation was deleted without rendering")  # its frames are shown, not rendered
def test_an_animation_refuses_frames_that_do_not_assemble(roberts_scene):
    """The Roberts linkage's dyad reaches only while |B D| <= 0.30 (closed form): at q = pi,
    |B D| = 0.42 and it does not. animate refuses it by the kinematics' own AssemblyError
    (naming the group and q), as mechanism_frames does when asked to check; frames that all
    assemble still animate. With check=False that frame is drawn marked: its title says so,
    its links faded, no joints, labels nor arrows where no pose puts them."""
    mech = roberts_scene.mechanism
    for call in (lambda: viz.animate(mech, [0.0, np.pi]), lambda: viz.mechanism_frames(mech, [0.0, np.pi], check=True)):
        with pytest.raises(assurjax.AssemblyError, match=r"'dyad43' .* cannot assemble at q = 3\.14159") as caught:
            call()
        assert caught.value.group == "dyad43"
    assert len(viz.render_frames(viz.animate(mech, [0.0, 0.3, 1.0]))) == 3
    anim = viz.animate(mech, np.array([0.3, 2.5]), velocities=["P"], check=False)
    drawing = anim.drawing
    anim.show_frame(1)
    assert anim.drawing.ax.get_title().endswith("q = 2.500 rad (does not assemble here)")
    assert not drawing.joints.get_visible() and not drawing.arrows["P"].get_visible()
    assert not any(label.get_visible() for label in drawing.labels.values())
    assert all(artist.get_alpha() < 0.1 for artist, _ in drawing.link_artists.values())
    anim.show_frame(0)
    assert anim.drawing.ax.get_title().endswith("q = 0.300 rad")
    assert drawing.joints.get_visible() and drawing.arrows["P"].get_visible()


@pytest.mark.filterwarnings("ignore:Animation was deleted without rendering")  # their legends are read, not rendered
def test_arrows_without_omega_say_they_are_at_unit_speed(watt):
    """Without omega the arrows are dx/dq (omega = 1 rad/s): the legend says so; draw_mechanism's
    legend names the omega it was given."""
    for omega, words in ((None, "velocity at omega = 1 rad/s\n("), ([2.0, 2.0], "velocity (")):
        drawing = viz.animate(watt, [0.1, 0.2], omega, velocities=["E"]).drawing
        assert any(label.startswith(words) for label in drawing.ax.get_legend_handles_labels()[1])
    gc.collect()  # the animations' warning here, not in a later test
    drawing = viz.draw_mechanism(watt, 0.1, omega=2.5, velocities=["E"])
    assert any(label.startswith("velocity at omega = 2.5 rad/s\n(") for label in drawing.ax.get_legend_handles_labels()[1])


H_TANGENT = 0.2  # the tangent drive's guide height (m): x_J = h cot q


@pytest.mark.filterwarnings("ignore:Animation was deleted without rendering")  # the test before's, collected here
def test_a_drawing_follows_the_mechanism_not_a_path_that_runs_off():
    """The tangent drive at q = pi/2: O = (0, 0), K = (0, 0.1), J = H = (0, h) (closed form).
    Over a turn J's path reaches h cot(pi/360) = 22.9 m beside the parallel guides: the axes
    follow the mechanism (a few h wide), the path is cut and the x label says how far it
    reaches; the block is smaller than the 0.1 m crank, and J's arrow (v_J = -h / sin^2 q =
    -0.2 m/s per rad/s) is a quarter of the mechanism's size h, inside the axes."""
    mech = assurjax.load_scene("tangent_drive").mechanism
    q = np.linspace(-np.pi / 2, 3 * np.pi / 2, 721)  # steps of pi/360
    drawing = viz.draw_mechanism(mech, np.pi / 2, velocities=["J"], trace=["J"], trace_q=q)
    ax = drawing.ax
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert x1 - x0 < 5 * H_TANGENT and y1 - y0 < 5 * H_TANGENT
    far = H_TANGENT / np.tan(np.pi / 360)
    assert f"the path of J is cut at the edge: it reaches x in [{-far:.3g}, {far:.3g}]" in ax.get_xlabel()
    block, _ = drawing.link_artists["block"]
    assert np.ptp(block.get_xy(), axis=0).max() < 0.1
    tail, tip = np.asarray(drawing.arrows["J"].xyann), np.asarray(drawing.arrows["J"].xy)
    np.testing.assert_allclose(tail, [0.0, H_TANGENT], atol=1e-12)
    np.testing.assert_allclose(tip - tail, [-0.25 * H_TANGENT, 0.0], atol=1e-9)
    assert x0 < tip[0] < x1 and y0 < tip[1] < y1


def test_a_slot_on_the_crank_carries_its_block_at_every_frame():
    """The tangent drive's slot runs along the crank through O: drawn at every frame from
    past O to past J = (h cot q, h) (closed form), so the block at J sits on it."""
    mech = assurjax.load_scene("tangent_drive").mechanism
    q = np.linspace(0.3, 2.8, 6)
    anim = viz.animate(mech, q)
    [(line, carrier, _, point)] = anim.drawing.slots
    assert (carrier, point) == ("crank", "J")
    for i, qi in enumerate(q):
        anim.show_frame(i)
        ends = np.column_stack(line.get_data())
        u = np.array([np.cos(qi), np.sin(qi)])  # the slot's direction: the crank's
        j = np.array([H_TANGENT / np.tan(qi), H_TANGENT])
        for p in (np.zeros(2), j):  # on the line
            d = p - ends[0]
            assert abs(u[0] * d[1] - u[1] * d[0]) < 1e-12
        assert abs(ends[0] @ u) < 1e-12 and (j - ends[1]) @ u < 0  # from O to past J
    viz.render_frames(anim)


def test_velocity_arrows_end_inside_the_axes(watt):
    """Every arrow tip lies within the axes: the slider-crank's A, v_A = r (-sin q, cos q)
    (closed form, r = 0.1 m), drawn alone and through an animation; and the Watt six-bar's
    unit crank tip A, v_A = w (-sin q, cos q), in every frame of a turn at w = 2 rad/s."""
    slider_crank = assurjax.load_scene("slider_crank").mechanism
    cases = [(viz.draw_mechanism(slider_crank, 0.5, velocities=["A", "B"], trace=["A", "B"]), [0.5], 0.1, 1.0)]
    q = np.linspace(0.0, 2 * np.pi, 24, endpoint=False)
    anim = viz.animate(watt, q, 2.0, velocities=["A", "E"], trace=["E"])
    cases.append((anim.drawing, q, 1.0, 2.0))
    for drawing, qs, r, w in cases:
        (x0, x1), (y0, y1) = drawing.ax.get_xlim(), drawing.ax.get_ylim()
        for i, qi in enumerate(qs):
            drawing.update(i)
            a = r * np.array([np.cos(qi), np.sin(qi)])
            tip = a + drawing.velocity_scale * r * w * np.array([-np.sin(qi), np.cos(qi)])
            np.testing.assert_allclose(drawing.arrows["A"].xy, tip, atol=1e-9)
            assert x0 < tip[0] < x1 and y0 < tip[1] < y1, (qi, tip)
    assert "cut" not in cases[0][0].ax.get_xlabel()
    viz.render_frames(anim)


def test_an_undefined_velocity_draws_no_arrow():
    """At a singular configuration a velocity ratio is NaN: the drawing shows no arrow
    there, sizes its arrows by the defined ones, and renders without a warning."""
    mech = assurjax.load_scene("slider_crank").mechanism
    import dataclasses

    frames = viz.mechanism_frames(mech, [0.3, 0.6, 0.9], velocities=True)
    b = np.array(frames.velocities["B"], copy=True)
    b[1] = np.nan
    frames = dataclasses.replace(frames, velocities=frames.velocities | {"B": b})
    fig, ax = plt.subplots()
    drawing = viz.MechanismDrawing(ax, mech, frames, velocities=["A", "B"])
    assert np.isfinite(drawing.velocity_scale) and drawing.velocity_scale > 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for i in range(3):
            drawing.update(i)
            assert drawing.arrows["B"].get_visible() == (i != 1) and drawing.arrows["A"].get_visible()
            fig.canvas.draw()


def test_no_legend_past_the_colour_cycle(tmp_path):
    """Past the colour cycle (10 colours) lines share colours and a legend entry names none:
    no legend then (the strandbeest's 49 angular velocities' legend collapsed the layout)."""
    t = np.linspace(0.0, 1.0, 11)
    colours = len(plt.rcParams["axes.prop_cycle"].by_key()["color"])
    for count, legend in ((colours, True), (colours + 1, False)):
        ax = viz.plot_time_histories(t, {f"x{k}": k * t for k in range(count)}, ylabel="x (m)")
        assert (ax.get_legend() is not None) == legend
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # a collapsed layout warns
            ax.figure.savefig(tmp_path / f"{count}.png")


@pytest.mark.filterwarnings("ignore:Animation was deleted without rendering")  # an earlier test's, collected here
def test_coupler_curves_frame_the_mechanism_not_a_path_that_runs_off():
    """The tangent drive: O = (0, 0) and H = (0, h) on the ground, a 0.1 m crank: its links
    reach x in [-0.1, 0.1], y in [-0.1, h + 0.1] (0.4 m). Over a turn that steps over the
    parallel guides (q = 0, pi) J = (h cot q, h) runs to h cot(pi/720) = 45.8 m: the axes
    frame the mechanism (they hold its reach, a few of its sizes wide), J's path runs to
    their edge and is cut there, no segment crosses them between two samples outside (one
    from -45.8 m to 45.8 m across the singular position), and the x label says how far it reaches."""
    mech = assurjax.load_scene("tangent_drive").mechanism
    q = np.linspace(-np.pi / 2, 3 * np.pi / 2, 721) + np.pi / 720  # no sample where the guides are parallel
    frames = viz.mechanism_frames(mech, q)
    assert frames.ok.all()
    ax = viz.plot_coupler_curves(frames, ["J"], mechanism=mech)
    ax.figure.canvas.draw()  # the limits as drawn, after the equal aspect is applied
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    crank, size = 0.1, H_TANGENT + 2 * 0.1
    assert x0 <= -crank and x1 >= crank and y0 <= -crank and y1 >= H_TANGENT + crank
    assert x1 - x0 <= 4 * size and y1 - y0 <= 4 * size
    far = H_TANGENT / np.tan(np.pi / 720)
    assert f"the path of J is cut at the edge: it reaches x in [{-far:.3g}, {far:.3g}]" in ax.get_xlabel()
    x = ax.lines[0].get_xdata()
    assert np.nanmin(x) < x0 and np.nanmax(x) > x1  # it runs on past both edges
    inside = (x >= x0) & (x <= x1)
    drawn = np.isfinite(x[:-1]) & np.isfinite(x[1:])
    assert not np.any(drawn & ~inside[:-1] & ~inside[1:])


def test_coupler_curves_that_stay_near_the_mechanism_are_drawn_whole(watt, watt_frames):
    """The Watt six-bar's paths of A, B, E stay within its links' reach: given the mechanism,
    each is drawn whole, at the closed-form positions, inside the axes, and nothing is said cut."""
    ax = viz.plot_coupler_curves(watt_frames, ["A", "B", "E"], mechanism=watt)
    ax.figure.canvas.draw()
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert ax.get_xlabel() == "x (m)"
    for line, name in zip(ax.lines, ("A", "B", "E")):
        expected = np.array([jr.watt_sixbar_points(qi)[0][name] for qi in Q_WATT])
        np.testing.assert_allclose(np.column_stack(line.get_data()), expected, atol=1e-12)
        assert np.all((x0 < expected[:, 0]) & (expected[:, 0] < x1) & (y0 < expected[:, 1]) & (expected[:, 1] < y1))


def test_a_drawing_refuses_a_q_that_does_not_assemble(roberts_scene):
    """The Roberts linkage at q = pi: |B D| = 0.42 m > BC + DC = 0.30 m (closed form), its dyad
    'dyad43' does not assemble. draw_mechanism refuses it as animate does (the kinematics'
    AssemblyError naming the group and q), before opening a figure; with check=False it draws
    it marked: its title says so, its links faded, no joints nor labels."""
    mech = roberts_scene.mechanism
    with pytest.raises(assurjax.AssemblyError, match=r"draw_mechanism: group 'dyad43' .* cannot assemble at q = 3\.14159") as caught:
        viz.draw_mechanism(mech, np.pi)
    assert caught.value.group == "dyad43" and "check=False" in str(caught.value)
    assert not plt.get_fignums()
    drawing = viz.draw_mechanism(mech, np.pi, check=False)
    assert "it does not assemble there" in drawing.ax.get_title()
    assert not drawing.joints.get_visible() and not any(label.get_visible() for label in drawing.labels.values())
    assert all(artist.get_alpha() < 0.1 for artist, _ in drawing.link_artists.values())
