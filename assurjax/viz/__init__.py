"""Plots and animations of mechanisms and their simulations (matplotlib).

Everything works headless: when no display is available matplotlib falls back to
its Agg backend (the ``assurjax`` command selects Agg explicitly). Lengths are
plotted in the ``unit`` asked for ("m", "cm", "mm"); angles in rad unless a
function says otherwise; forces in N, energies in J, times in s.

**Example:**
>>> from assurjax import viz
>>> frames = viz.mechanism_frames(mech, np.linspace(0, 2 * np.pi, 181), velocities=True)
>>> viz.plot_coupler_curves(frames, ["E"])
>>> viz.save_gif(viz.animate(mech, frames.q[::3], trace=["E"]), "mech.gif")
"""

from ._animation import (
    animate as animate,
    animation_html as animation_html,
    ffmpeg_available as ffmpeg_available,
    player as player,
    render_frames as render_frames,
    save_gif as save_gif,
    save_mp4 as save_mp4,
)
from ._draw import MechanismDrawing as MechanismDrawing, draw_mechanism as draw_mechanism
from ._frames import Frames as Frames, frames_from_kinematics as frames_from_kinematics, mechanism_frames as mechanism_frames
from ._plots import (
    plot_against as plot_against,
    plot_angular_velocities as plot_angular_velocities,
    plot_coupler_curves as plot_coupler_curves,
    plot_energies as plot_energies,
    plot_energy_drift as plot_energy_drift,
    plot_reactions as plot_reactions,
    plot_reduced as plot_reduced,
    plot_time_histories as plot_time_histories,
    plot_velocity_polygon as plot_velocity_polygon,
)
