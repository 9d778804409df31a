"""Animations of a mechanism: one figure whose moving artists are redrawn frame by frame.

The static part (axes, grid, ground, traced paths, legend) is rendered once; each frame
restores that background and draws only the moving links, joints, labels, arrows and the
title (blitting), and the pixels go straight to Pillow (GIF), to ffmpeg (MP4), into a
self-contained HTML player or an ipywidgets player. :func:`animate` also returns a
matplotlib ``FuncAnimation``, so ``anim.save`` and ``anim.to_jshtml`` keep working.
"""

from __future__ import annotations

import base64
import io
import shutil
import subprocess
from collections.abc import Callable, Iterable
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.animation import FuncAnimation
from matplotlib.backends.backend_agg import FigureCanvasAgg

from .._errors import AssurjaxError
from .._kinematics import point_names
from .._mechanism import Mechanism, check_mechanism
from .._values import check_value, check_values
from ._draw import VELOCITY_COLOR, MechanismDrawing, place_legend, posed_frames, widen_for_drawing
from ._frames import check_coordinates, length_scale, mechanism_frames

MAX_FRAMES = 10_000  # ~8 min of animation at 20 frames per second; each frame is drawn and rendered


def animate(
    mechanism: Mechanism,
    q,
    omega=None,
    *,
    t=None,
    trace: Iterable[str] = (),
    trace_q=None,
    velocities: Iterable[str] = (),
    unit: str = "m",
    interval_ms: float = 50.0,
    ax=None,
    title: str | None = None,
    check: bool = True,
) -> FuncAnimation:
    """Animate ``mechanism`` through the driving coordinates ``q`` (rad, or m for a slider).

    ``omega`` (rad/s or m/s per frame) scales the velocity arrows of ``velocities``;
    without it they are the velocities at omega = 1 (the kinematic coefficients dx/dq), and
    their legend entry says so. ``t`` (s, one per frame, finite, never decreasing) is shown
    in the title when given (a simulation); ``trace`` points get their whole path drawn, over
    ``trace_q`` when given (e.g. every sample of a simulation: smoother than the frames alone;
    gaps where it does not assemble). At most 10,000 frames (each is drawn and rendered).

    Every frame must assemble (a simulation's samples do): a q where some group cannot
    raises :class:`assurjax.AssemblyError` naming the group and q. With ``check=False``
    (a sweep past a rocker's limit, on purpose) such frames are drawn marked instead: their
    links faded, no joints, labels nor arrows (their positions are no pose), and the title
    says it does not assemble there.

    Returns a matplotlib ``FuncAnimation``; write it with :func:`save_gif` or
    :func:`save_mp4`, show it in a notebook with :func:`animation_html` or :func:`player`.

    **Example:**
    >>> anim = assurjax.viz.animate(mech, np.linspace(0, 2 * np.pi, 60), trace=["E"])
    >>> assurjax.viz.save_gif(anim, "watt.gif")
    """
    _check_request(mechanism, q, t, trace_q, unit, interval_ms)
    velocities, trace = point_names(mechanism, velocities, "animate: velocities"), point_names(mechanism, trace, "animate: trace")
    frames = posed_frames("animate", mechanism, q, omega, velocities=bool(velocities), check=check,
                          hint="every frame must be a pose (check=False draws such frames marked)")
    own_figure = ax is None
    if own_figure:
        _, ax = plt.subplots(figsize=(8, 5), layout="constrained")
    trace_frames = None if trace_q is None or not tuple(trace) else mechanism_frames(mechanism, trace_q)
    q_unit = "m" if mechanism.driver.kind == "slider" else "rad"
    arrows = "velocity" if omega is not None else f"velocity at omega = 1 {q_unit}/s"
    drawing = MechanismDrawing(ax, mechanism, frames, trace=trace, velocities=velocities, unit=unit, trace_frames=trace_frames,
                               velocity_label=arrows)
    times = None if t is None else np.asarray(t, dtype=float)
    head = title or mechanism.name
    place_legend(ax)
    if own_figure:
        widen_for_drawing(ax)

    def show(i):
        artists = drawing.update(i)
        when = f"t = {times[i]:.3f} s, " if times is not None else ""
        apart = "" if frames.ok[i] else " (does not assemble here)"  # its links faded, its joints hidden
        ax.title.set_text(f"{head}: {when}q = {frames.q[i]:.3f} {q_unit}{apart}")
        ax.title.set_color("black" if frames.ok[i] else VELOCITY_COLOR)
        return [*artists, ax.title]

    anim = FuncAnimation(ax.figure, show, frames=len(frames), interval=interval_ms, blit=False)
    anim.drawing = drawing  # keep the artists reachable (tests, further styling)
    anim.show_frame, anim.frame_count = show, len(frames)
    show(drawing._first_ok())
    return anim


def _check_request(mechanism, q, t, trace_q, unit, interval_ms) -> None:
    """Refuse a bad animation request by its keyword, before any kinematics is traced."""
    check_mechanism(mechanism, "animate")
    if np.size(q) > MAX_FRAMES:
        raise AssurjaxError(f"animate: at most {MAX_FRAMES} frames (values of q), got {np.size(q)}: take every k-th sample, q[::k]")
    check_value(AssurjaxError, "animate: interval_ms", interval_ms, shape=(), positive=True)
    length_scale(unit, "animate")
    if trace_q is not None:
        check_coordinates("animate", "trace_q", trace_q)
    if t is not None:
        _check_times(t, np.size(q))


def _check_times(t, count: int) -> None:
    """The frames' times: one finite time per frame, never decreasing."""
    if np.shape(t) != (count,):
        raise AssurjaxError(f"animate: t must give one time per value of q ({count}), got shape {np.shape(t)}")
    check_values(AssurjaxError, "animate", t=t)
    t = np.asarray(t, dtype=float)
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        i = int(back[0]) + 1
        raise AssurjaxError(f"animate: t must not decrease from frame to frame (s), got t[{i}] = {t[i]:.6g} after "
                            f"t[{i - 1}] = {t[i - 1]:.6g}")


def render_frames(anim: FuncAnimation, *, progress: Callable[[int, int], None] | None = None) -> list[np.ndarray]:
    """Every frame of an :func:`animate` animation as an (height, width, 3) uint8 RGB array.

    The figure's static part is rendered once; each frame redraws only the artists
    that move. ``progress(i, n)`` is called after each frame."""
    if not hasattr(anim, "show_frame"):
        raise AssurjaxError(f"render_frames: expected an animation made by assurjax.viz.animate, got {type(anim).__name__}")
    fig = anim._fig
    canvas = FigureCanvasAgg(fig)  # pixels without a display, whatever the backend
    n = anim.frame_count
    moving = anim.show_frame(0)
    canvas.draw()  # lay the figure out once with everything visible (the title included)...
    fig.set_layout_engine("none")  # ...and keep that layout for every frame
    for artist in moving:
        artist.set_animated(True)  # left out of the background
    canvas.draw()
    background = canvas.copy_from_bbox(fig.bbox)
    images = []
    for i in range(n):
        canvas.restore_region(background)
        for artist in anim.show_frame(i):
            fig.draw_artist(artist)
        images.append(np.asarray(canvas.buffer_rgba())[..., :3].copy())
        if progress is not None:
            progress(i, n)
    for artist in moving:
        artist.set_animated(False)
    return images


def _images(anim, progress, where: str) -> list[np.ndarray]:
    """Frames rendered from an animation (whose figure is then closed), or given already rendered."""
    if isinstance(anim, FuncAnimation):
        images = render_frames(anim, progress=progress)
        plt.close(anim._fig)
        return images
    if not isinstance(anim, (list, tuple, np.ndarray)):  # a string is iterable too: refuse it here
        raise AssurjaxError(f"{where}: anim must be an animation made by assurjax.viz.animate or the frames "
                            f"render_frames returned, got {type(anim).__name__}")
    images = [np.asarray(image) for image in anim]
    if not images:
        raise AssurjaxError(f"{where}: no frames to write")
    _check_images(images, where)
    return images


def _check_images(images: list[np.ndarray], where: str) -> None:
    """Every frame an RGB image of uint8 (what render_frames returns), all of one size."""
    first = images[0]
    for i, image in enumerate(images):
        if image.ndim != 3 or image.shape[-1] != 3 or image.dtype != np.uint8 or image.shape != first.shape:
            raise AssurjaxError(f"{where}: anim's frame {i} must be a (height, width, 3) uint8 RGB image of the first "
                                f"frame's shape {first.shape}, as render_frames returns, got {image.dtype} of shape {image.shape}")


def _writable(path: str | Path, suffix: str, where: str) -> Path:
    """``path`` as a Path ending in ``suffix`` in a folder that exists."""
    if not isinstance(path, (str, Path)):
        raise AssurjaxError(f"{where}: path must be a file name (str or Path), got {type(path).__name__}")
    path = Path(path)
    if path.suffix.lower() != suffix:  # Pillow would write whatever the suffix names
        raise AssurjaxError(f"{where}: the path must end in {suffix}, got {str(path)!r}")
    if not path.parent.is_dir():
        raise AssurjaxError(f"{where}: path's folder {str(path.parent)!r} does not exist")
    return path


def save_gif(anim, path: str | Path, *, fps: int = 20, progress: Callable[[int, int], None] | None = None) -> Path:
    """Write an :func:`animate` animation as a looping GIF (Pillow) and close its figure.

    ``anim`` may also be the frames :func:`render_frames` returned (to write a GIF and an
    MP4 from one rendering: (height, width, 3) uint8 arrays of one shape); anything else is
    refused. ``path`` ends in .gif, in a folder that exists. ``fps``: frames per second; ``progress(i, n)`` is called per
    frame. All frames share the palette of the first one, so colours do not flicker.
    Returns the path.

    **Example:**
    >>> assurjax.viz.save_gif(assurjax.viz.animate(mech, np.linspace(0, 6.28, 36)), "mech.gif")
    """
    _check_fps(fps)
    from PIL import Image

    path = _writable(path, ".gif", "save_gif")
    images = _images(anim, progress, "save_gif")
    colours = Image.fromarray(images[0]).quantize(colors=255, method=Image.Quantize.MEDIANCUT).getpalette()
    frames = []
    for indices in _nearest_colours(images, np.asarray(colours, dtype=np.int32).reshape(-1, 3)):
        frame = Image.fromarray(indices)  # an L image: putpalette makes it P (mode= is deprecated)
        frame.putpalette(colours)
        frames.append(frame)
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=round(1000 / fps), loop=0)
    return path


def _nearest_colours(images, palette):
    """Each image's pixels as indices (uint8) of their nearest ``palette`` colour (n, 3),
    exactly, through a table over the 2^24 colours filled as they appear (an animation has
    a few thousand). Pillow's own mapping onto a palette is approximate: the first frame's
    white stayed 255 while the others' became 252, a grey flash at each loop of the GIF."""
    table, known = np.zeros(1 << 24, dtype=np.uint8), np.zeros(1 << 24, dtype=bool)
    for image in images:
        rgb = np.asarray(image, dtype=np.int32)[..., :3]
        codes = (rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]
        new = np.unique(codes[~known[codes]])
        if new.size:
            colour = np.stack([new >> 16, (new >> 8) & 255, new & 255], axis=-1)
            table[new] = np.argmin(((colour[:, None, :] - palette[None]) ** 2).sum(-1), axis=1)
            known[new] = True
        yield table[codes]


def _check_fps(fps) -> None:
    check_value(AssurjaxError, "fps", fps, shape=(), positive=True)
    if fps > 1000:
        raise AssurjaxError(f"fps must be at most 1000 (frames per second), got {fps}")


def ffmpeg_available() -> bool:
    """True when an ``ffmpeg`` executable is on the PATH (needed by :func:`save_mp4`)."""
    return shutil.which("ffmpeg") is not None


def save_mp4(anim, path: str | Path, *, fps: int = 20, progress: Callable[[int, int], None] | None = None) -> Path:
    """Write an :func:`animate` animation (or frames from :func:`render_frames`) as an
    H.264 MP4 through ``ffmpeg`` and close its figure.

    ``path`` ends in .mp4, in a folder that exists. Raises ``FileNotFoundError`` when ffmpeg
    is not on the PATH (see :func:`ffmpeg_available`).

    **Example:**
    >>> if assurjax.viz.ffmpeg_available():
    ...     assurjax.viz.save_mp4(anim, "mech.mp4")
    """
    _check_fps(fps)
    path = _writable(path, ".mp4", "save_mp4")
    exe = shutil.which("ffmpeg")
    if exe is None:
        raise FileNotFoundError("ffmpeg is not on the PATH: cannot write an MP4 (save_gif needs no external program)")
    images = _images(anim, progress, "save_mp4")
    h, w = images[0].shape[:2]
    cmd = [exe, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}", "-r", str(fps), "-i", "-",
           "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-c:v", "libx264", "-pix_fmt", "yuv420p", str(path)]
    done = subprocess.run(cmd, input=b"".join(im.tobytes() for im in images), capture_output=True)
    if done.returncode != 0:
        raise RuntimeError(f"ffmpeg failed writing {path}: {done.stderr.decode(errors='replace').strip()}")
    return path


def _png(image: np.ndarray) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG")
    return buffer.getvalue()


PLAYER_TEMPLATE = """<div class="assurjax-player">
<img id="{id}-img" src="data:image/png;base64,{first}" style="max-width:100%"><br>
<button onclick="{id}_toggle()" id="{id}-btn">play</button>
<input type="range" id="{id}-slider" min="0" max="{last}" value="0" oninput="{id}_show(+this.value)" style="width:60%">
<span id="{id}-label">frame 1 / {count}</span>
<script>
var {id}_frames = [{frames}];
var {id}_i = 0, {id}_timer = null;
function {id}_show(i) {{
  {id}_i = i;
  document.getElementById("{id}-img").src = "data:image/png;base64," + {id}_frames[i];
  document.getElementById("{id}-slider").value = i;
  document.getElementById("{id}-label").textContent = "frame " + (i + 1) + " / {count}";
}}
function {id}_toggle() {{
  var btn = document.getElementById("{id}-btn");
  if ({id}_timer) {{ clearInterval({id}_timer); {id}_timer = null; btn.textContent = "play"; return; }}
  btn.textContent = "pause";
  {id}_timer = setInterval(function () {{ {id}_show(({id}_i + 1) % {count}); }}, {interval});
}}
</script>
</div>"""


def animation_html(anim: FuncAnimation, *, fps: int = 20) -> str:
    """The animation as a self-contained HTML/JavaScript player (play/pause button and a
    frame slider; frames embedded as PNG) and close its figure.

    **Example** (in a notebook):
    >>> from IPython.display import HTML
    >>> HTML(assurjax.viz.animation_html(anim))
    """
    _check_fps(fps)
    images = render_frames(anim)
    plt.close(anim._fig)
    frames = ",".join(f'"{base64.b64encode(_png(im)).decode()}"' for im in images)
    uid = f"aj{id(anim):x}"
    return PLAYER_TEMPLATE.format(id=uid, first=base64.b64encode(_png(images[0])).decode(), last=len(images) - 1,
                                  count=len(images), frames=frames, interval=round(1000 / fps))


def player(anim: FuncAnimation, *, fps: int = 20):
    """An interactive ipywidgets player for notebooks (play button linked to a frame
    slider) and close the animation's figure. Needs ``ipywidgets`` (the ``notebooks`` extra).

    **Example:**
    >>> assurjax.viz.player(assurjax.viz.animate(mech, np.linspace(0, 6.28, 60)))
    """
    _check_fps(fps)
    import ipywidgets as widgets

    images = [_png(im) for im in render_frames(anim)]
    plt.close(anim._fig)
    view = widgets.Image(value=images[0], format="png")
    slider = widgets.IntSlider(value=0, min=0, max=len(images) - 1, description="frame")
    play = widgets.Play(value=0, min=0, max=len(images) - 1, interval=round(1000 / fps))
    widgets.jslink((play, "value"), (slider, "value"))
    slider.observe(lambda change: setattr(view, "value", images[change["new"]]), names="value")
    return widgets.VBox([view, widgets.HBox([play, slider])])
