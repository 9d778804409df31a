"""What a simulation's result codes and events mean, in words, with a remedy."""

from __future__ import annotations

import warnings

import diffrax
import numpy as np

# Event codes in Solution.event.
NO_EVENT, STANDSTILL, LOCKUP, USER = -1, 0, 1, 2
RATE_SWITCH = -2  # internal: a friction element's d phi_k/dq changed sign (a segment ends, the run goes on)
END_SWITCH = -3  # internal: the load on a prismatic pair's block end changed sign (a segment ends, the run goes on)
KNOT = -4  # internal: q, t or omega reached a knot of a load's table (a segment ends, the run goes on)


with warnings.catch_warnings():  # equinox warns that ``successful`` gets a message (diffrax's is ""); that is wanted
    warnings.filterwarnings("ignore", message="Enumeration has duplicate incompatible values for successful")

    class RESULTS(diffrax.RESULTS):
        """Outcome of a simulation, in diffrax's style (extends ``diffrax.RESULTS``):
        ``sol.result == assurjax.RESULTS.successful``; ``assurjax.RESULTS[sol.result]``
        is the message. An item prints as ``assurjax.RESULTS<message>``."""

        __module__ = "assurjax"  # where users find it (an item's repr names its class by module and name)

        successful = "The run finished as asked (at t1 or at a stop event)."
        start_not_assembled = "The mechanism cannot assemble at the starting state."
        start_singular = ("The mechanism starts exactly at a singular configuration of a group (a limit position, or "
                          "where two branches cross), where the driving coordinate does not carry the motion.")
        max_segments_reached = ("The motion needed more segments (with joint friction: rests, break-aways and changes of "
                                "a joint's Coulomb sign; where derivatives are taken, also the kinks of the friction law "
                                "and the knots of the loads' tables) than a run allows before t1: shorten the time span "
                                "(or, where no derivative is taken, set kink_events=False).")
        nonfinite_friction = ("A friction element's coefficient, radius, length or damping is not finite (a traced "
                              "value, which cannot be checked before the run): no motion is computed from it.")
        friction_out_of_range = ("A friction element's coefficient, radius or damping is negative, or its block "
                                 "length or smoothing speed is not positive (a traced value, which cannot be checked "
                                 "before the run): no motion is computed from it.")
        static_below_kinetic = ("A friction element's static coefficient is below its kinetic coefficient (a traced "
                                "value, which cannot be checked before the run): no motion is computed from it.")


def result_value(result):
    """The integer code of a result item as a (traced) array: for outputs that must be
    plain arrays, e.g. of a ``jax.custom_jvp``. ``RESULTS[...]`` reads it back."""
    return result._value


def result_code(result) -> np.ndarray:
    """The integer code(s) of a result (host side), for summaries and counting."""
    return np.asarray(getattr(result, "_value", result))


_SUCCESS = int(RESULTS.successful._value)
_EVENT = int(RESULTS.event_occurred._value)
FINISHED = (_SUCCESS, _EVENT)  # host-side codes of runs that ended as asked
START_NOT_ASSEMBLED = int(RESULTS.start_not_assembled._value)
START_SINGULAR = int(RESULTS.start_singular._value)
MAX_STEPS = int(RESULTS.max_steps_reached._value)  # host-side code of a run that used up its step budget
DT_MIN = int(RESULTS.dt_min_reached._value)  # host-side code of a run that could not get on (NaN ahead)


def result_text(code: int, *, max_steps: int | None = None) -> str:
    """A sentence for a result code with what to change."""
    if code in (_SUCCESS, _EVENT):
        return "successful"
    if code == MAX_STEPS:
        budget = "" if max_steps is None else f" (max_steps = {max_steps})"
        return (f"the step budget{budget} was used up before t1: raise max_steps, loosen rtol/atol, "
                "or shorten the time span")
    if code == DT_MIN:  # from the lock-up controllers (dynamics._settings.lockup_controller)
        return ("the right-hand side turned NaN ahead and the steps closing in on it got no further, yet every group "
                "assembles just past where they stopped: a load or the joint friction (a jam) gave NaN there, or, with "
                "dt= or steps= constant steps, the motion was not resolved (use adaptive steps, a smaller dt or more steps)")
    try:
        message = RESULTS[_item(code)]
    except Exception:  # a code this version does not know
        message = ""
    return f"result code {code}" + (f": {message}" if message else "")


def _item(code: int):
    for name in getattr(RESULTS, "_name_to_item", {}):
        item = getattr(RESULTS, name)
        if int(item._value) == code:
            return item
    raise KeyError(code)


def finished(result):
    """True (traced) where a run ended as asked: reached t1 or stopped at an event."""
    return (result == RESULTS.successful) | (result == RESULTS.event_occurred)


def status_text(code: int, event: int, group: str | None, t_final: float, *, max_steps: int | None = None) -> str:
    """A one-line summary of how a single run ended."""
    if event == STANDSTILL:
        return f"standstill at t = {t_final:.9g} s"
    if event == LOCKUP:
        return f"group '{group}' can no longer assemble at t = {t_final:.9g} s (lock-up / limit position)"
    if event >= USER:
        return f"user event #{event - USER + 1} at t = {t_final:.9g} s"  # counted from 1, as the checks name them
    if code in (_SUCCESS, _EVENT):
        return f"reached t1 = {t_final:.9g} s"
    return f"solver stopped at t = {t_final:.9g} s: {result_text(code, max_steps=max_steps)}"


JAM_REMEDY = "lower the friction coefficients, lengthen the slider blocks or change the geometry"


def jam_text(t_final: float, q_final: float, omega_final: float, limit: tuple[str, float] | None = None,
             reversing: list[str] | None = None) -> str:
    """The status of a run stopped where the joint friction jams the mechanism; ``limit``:
    (the group, the distance) of a limit position just ahead, if there is one; ``reversing``:
    the friction elements whose relative motion turns round there, if any."""
    where = f"at t = {t_final:.9g} s (q = {q_final:.6g}, w = {omega_final:.6g})"
    if reversing:
        pairs = ", ".join(f"'{p}'" for p in reversing)
        where += (f", where the relative motion in {pairs} turns round (its friction turns with it, and with the "
                  "turned friction the motion has no consistent solution)")
    if limit is not None:
        group, distance = limit
        return (f"the joint friction jams the mechanism {where}, within {distance:.1g} of a limit position ({group} cannot "
                "assemble that much further on): near it the driver's motion barely moves the group, its force line "
                "passes within the pins' friction circles and the friction self-locks it (no friction values satisfy the "
                "Coulomb law of this motion with a positive effective inertia); a real mechanism wedges there. Keep the "
                "motion away from that limit position (the geometry or the drive), or lower the friction coefficients")
    if omega_final == 0:
        return (f"the joint friction jams the mechanism at rest at t = {t_final:.9g} s (q = {q_final:.6g}): holding it "
                "there needs more friction than the joints' limits give, and the motion its loads start has no friction "
                "values that satisfy the Coulomb law with a positive effective inertia (Painleve's paradox: a slider "
                "pushed past its friction angle wedges), so it can neither stay nor move; a real mechanism wedges there. "
                f"{JAM_REMEDY[0].upper() + JAM_REMEDY[1:]}")
    return (f"the joint friction jams the mechanism {where}: "
            "there no friction values satisfy the Coulomb law of this motion with a positive effective inertia "
            "(Painleve's paradox: the friction would drive the motion it opposes, or it self-locks: a slider driven past "
            "its friction angle, a toggle whose force line passes within its pins' friction circles), so it cannot go on "
            "sliding; a real "
            f"mechanism wedges there. {JAM_REMEDY[0].upper() + JAM_REMEDY[1:]}")
