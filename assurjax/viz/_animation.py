"""Animations of a mechanism: matplotlib FuncAnimation, saved as GIF (PillowWriter)
or embedded in notebooks as HTML (``to_jshtml``)."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.animation import FuncAnimation, PillowWriter

from .._mechanism import Mechanism
from ._draw import MechanismDrawing, place_legend
from ._frames import mechanism_frames


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
) -> FuncAnimation:
    """Animate ``mechanism`` through the driving coordinates ``q`` (rad or m).

    ``omega`` (rad/s or m/s per frame, default 1) scales the velocity arrows of
    ``velocities``; ``t`` (s) is shown in the title when given (a simulation);
    ``trace`` points get their whole path drawn, over ``trace_q`` when given (e.g.
    every sample of a simulation: smoother than the frames alone). Frames where the mechanism does
    not assemble are drawn faded.

    **Example:**
    >>> anim = assurjax.viz.animate(mech, np.linspace(0, 2 * np.pi, 60), trace=["E"])
    >>> assurjax.viz.save_gif(anim, "watt.gif")
    """
    velocities = tuple(velocities)
    frames = mechanism_frames(mechanism, q, omega, velocities=bool(velocities))
    if ax is None:
        _, ax = plt.subplots(figsize=(8, 5), layout="constrained")
    trace_frames = None if trace_q is None or not tuple(trace) else mechanism_frames(mechanism, trace_q)
    drawing = MechanismDrawing(ax, mechanism, frames, trace=trace, velocities=velocities, unit=unit, trace_frames=trace_frames)
    times = None if t is None else np.asarray(t, dtype=float)
    head = title or mechanism.name
    place_legend(ax)

    def show(i):
        artists = drawing.update(i)
        when = f"t = {times[i]:.3f} s, " if times is not None else ""
        ax.set_title(f"{head}: {when}q = {frames.q[i]:.3f}")
        return artists

    anim = FuncAnimation(ax.figure, show, frames=len(frames), interval=interval_ms, blit=False)
    anim.drawing = drawing  # keep the artists reachable (tests, further styling)
    return anim


def save_gif(anim: FuncAnimation, path: str | Path, *, fps: int = 20, progress: Callable[[int, int], None] | None = None) -> Path:
    """Write ``anim`` as an animated GIF (Pillow); ``progress(i, n)`` is called per frame."""
    path = Path(path)
    anim.save(path, writer=PillowWriter(fps=fps), progress_callback=progress)
    plt.close(anim._fig)
    return path


def animation_html(anim: FuncAnimation, *, default_mode: str = "loop") -> str:
    """The animation as a self-contained HTML/JavaScript player (for notebooks:
    ``IPython.display.HTML(animation_html(anim))``)."""
    html = anim.to_jshtml(default_mode=default_mode)
    plt.close(anim._fig)
    return html
