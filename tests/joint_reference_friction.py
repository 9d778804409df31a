"""Joint friction for the independent joint-coordinate reference (tests/joint_reference.py).

numpy + scipy only: like joint_reference.py it shares no code (and no jax) with ``assurjax``.
It extends that module's absolute-coordinate, Lagrange-multiplier formulation with Coulomb
friction driven by the joint reactions, stiction, and viscous joint damping.

Friction law (SI units)
-----------------------
Every joint ``(name, body_i, body_j)`` may carry a :class:`Friction` (coefficient ``mu``,
friction-circle radius ``radius`` [m] of a revolute, block length ``length`` [m] of a
prismatic pair, viscous coefficient ``damping``).  All friction loads are reported, like the
reactions of joint_reference.py, as the load ON body_i BY body_j (body_j receives the opposite).

* Revolute.  Relative rate ``u = omega_i - omega_j`` [rad/s] (the ground has omega = 0).
  Reaction ``F = (Fx, Fy)``: the joint's multipliers, ``|F| = |lam_pair|``.  Couple on body_i:
  Coulomb ``-mu * radius * |F| * sign(u)`` [N m] plus viscous ``-damping * u``
  (``damping`` in N m s/rad); body_j receives the opposite couples.
* Prismatic.  In joint_reference.py's convention body_i carries the guide (the line through
  its point ``s_i`` with direction ``axis_i``) and body_j slides on it: the *sliding point* P is
  body_j's point ``s_j``, which stays on the guide line.  ``e = A(theta_i) axis_i / |axis_i|``
  is the guide direction, ``n = perp(e)`` (e turned +90 degrees) the guide normal.
  The reference reports the normal force ``N`` as the reaction ``F = N n`` on body_i by body_j
  acting at P (``N = F . n``, signed), and ``M`` = ``couples[name]``, the couple on body_i by
  body_j (counterclockwise positive).  The block of length ``L`` is centred at P: it touches the
  guide at ``P - (L/2) e`` with the normal force ``N1 = N/2 - M/L`` and at ``P + (L/2) e`` with
  ``N2 = N/2 + M/L`` (signed magnitudes along n; N1 + N2 = N, (L/2)(N2 - N1) = M).
  Relative sliding rate ``u = e . (V_i(P) - V_j(P))`` [m/s]: the velocity of body_i's material
  point at P relative to body_j's (the relative velocity is along e; the rotation is locked).
  Friction force on body_i, along e, applied at P: Coulomb ``-mu (|N1| + |N2|) sign(u)`` [N]
  plus viscous ``-damping * u`` (``damping`` in N s/m); body_j receives the opposite force at
  the same global point P.  (With the guide on body_i this is the same law as "the force on the
  slider opposes the slider's velocity relative to the guide".)

The friction loads enter the equations of motion as generalized forces ``Q_f(lam, zd)``:

    M zdd + Phi_z^T lam = Q + tau D_z^T + sum_f g_f * (coulomb_f(lam) + viscous_f(zd)),
    Phi_z zdd = gamma,

where ``g_f`` is the generalized direction of the unit load of joint f (a unit couple on body_i
and minus one on body_j; or a unit force +e on body_i at P and -e on body_j at P), so that the
joint's relative rate is ``u_f = g_f . zd`` and the friction power is ``load_f * u_f <= 0``.
Because Coulomb friction depends on the multipliers, every evaluation is a small nonlinear
system in ``(zdd, lam)``, solved here by Newton from the frictionless solution to rounding
(updates below 1e-14 relative); a joint whose relative rate is round-off of its terms (its
bodies turn or slide together: it never slips) carries no kinetic Coulomb friction. Inverse
dynamics solves the same equations for ``(lam, tau)`` at a given ``(q, w, dw/dt)``.

Stiction and piecewise integration (one degree of freedom)
----------------------------------------------------------
Every relative rate is proportional to the driver rate w: ``u_f = k_f(q) w`` with
``k_f = g_f . dz/dq``.  The motion is integrated in segments with ``solve_ivp`` (DOP853,
rtol = 1e-12, atol = 1e-13 by default) over which every Coulomb sign is frozen
(``sign(k_f) * sign(w)``), so the right-hand side is smooth inside a segment.  A segment ends
at an event:

* ``switch``: some ``k_f(q)`` crosses zero (that joint's relative rate reverses while the
  mechanism moves on): the segment restarts with that sign flipped.
* ``rest``: w reaches 0.  Then, with w = 0 and the driver effort ``tau(t, q, 0)``, for each
  direction s = +1 / -1 the acceleration ``a_s`` is computed with every Coulomb sign set as for
  motion in direction s (``s * sign(k_f)``; a joint with ``k_f = 0`` takes the sign of k_f a
  little further along the motion).  If exactly one s gives ``s * a_s > 0`` the motion (re)starts
  that way; if none does the mechanism *sticks* (w = dw/dt = 0 exactly); if both do the
  problem is ambiguous and a RuntimeError is raised.  The same test decides a start from rest.
  It reads every Coulomb load with the joint's static coefficient (``Friction.static``, mu when
  none); the motion that starts has the kinetic mu.
* While stuck, the break-away function ``b(t) = max_s s * a_s(t)`` (which changes only through
  a time-dependent driver effort) is scanned on a grid of step ``scan`` and its first root is
  located by ``scipy.optimize.brentq`` (to ~1e-14 s); the motion restarts from rest there in the
  direction that breaks away.

While stuck the individual joint friction loads are statically indeterminate; this reference
reports the pattern of the impending direction (the one the frictionless acceleration points
to; static coefficients) scaled by one common factor alpha in [0, 1] chosen so that dw/dt = 0 (alpha = 0 when
the frictionless acceleration is zero).

Work quadratures (integrated with the motion; constant while stuck):
``work_drive = int tau w dt``, ``work_friction = int sum_f coulomb_f u_f dt <= 0`` (Coulomb),
``work_damping = int (sum_f viscous_f u_f + translational-damper power) dt <= 0``; then
``T + V - work_drive - work_friction - work_damping`` is constant.

Example::

    import joint_reference_friction as jf
    model = jf.slider_crank(0.5, 3.0, tau=lambda t, q, w: 0.3 * np.sin(5 * t))
    r = model.simulate(2.0, t_eval=np.linspace(0, 2, 41))   # FrictionResult
    r.q, r.w, r.stuck, r.friction["P"], r.event_times("break")
    model.inverse(1.0, 2.0, 0.5)["tau"]                      # effort needed, with friction
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

sys.path.insert(0, os.path.dirname(__file__))
import joint_reference as jr  # noqa: E402

GROUND = jr.GROUND
_LOOK_AHEAD = 1e-6  # q step used to read the sign of a vanishing rate coefficient k_f(q)
_TINY_RATE = 1e-9   # |k_f| below this counts as vanishing
_ROUNDOFF = 1e-13   # a relative rate within this fraction of its terms is their round-off


def _slip_signs(G, zd):
    """sign(G @ zd), the Coulomb signs of the relative rates; 0 where a rate is round-off
    of its terms: the bodies of such a joint turn (slide) together, it never slips and
    carries no kinetic friction (its static friction is indeterminate)."""
    u = G @ zd
    return np.where(np.abs(u) > _ROUNDOFF * (np.abs(G) @ np.abs(zd)), np.sign(u), 0.0)


@dataclass(frozen=True)
class Friction:
    """Friction of one joint (SI).  mu: Coulomb coefficient; radius: friction-circle radius of
    a revolute [m]; length: block length of a prismatic pair [m] (needed when mu > 0);
    damping: viscous coefficient [N m s/rad] (revolute) or [N s/m] (prismatic); static: the
    coefficient at rest (whether it starts, when it breaks away, what holds it), None: mu."""
    mu: float = 0.0
    radius: float = 0.0
    length: float = 0.0
    damping: float = 0.0
    static: float | None = None


def _zero_effort(t, q, w):
    return 0.0


# ----------------------------------------------------------------------------- system
class FrictionSystem(jr.System):
    """jr.System with joint friction.  ``friction``: {joint name: Friction}; joints not named
    are frictionless.  The inherited methods (accelerations, inverse_dynamics, state, ...)
    stay frictionless; the friction versions are ``forward``, ``inverse``, ``stuck``,
    ``holding_range`` and ``simulate`` (which overrides jr.System.simulate)."""

    def __init__(self, bodies, joints, driver, friction=None, gravity=(0.0, -jr.G), dampers=(),
                 max_dq=0.05):
        super().__init__(bodies, joints, driver, gravity=gravity, dampers=dampers, max_dq=max_dq)
        friction = dict(friction or {})
        names = [jt.name for jt in self.joints]
        unknown = set(friction) - set(names)
        if unknown:
            raise ValueError(f"friction given for unknown joints {sorted(unknown)}; joints are {names}")
        self.friction = friction
        # one entry per joint carrying friction: (joint index, multiplier row, is prismatic, axis)
        self._fr, mu, rad, length, damping, rest = [], [], [], [], [], []
        for k, jt in enumerate(self.joints):
            fr = friction.get(jt.name)
            if fr is None or (fr.mu == 0.0 and fr.damping == 0.0):
                continue
            prism = isinstance(jt, jr.Prismatic)
            if prism and fr.mu > 0.0 and not fr.length > 0.0:
                raise ValueError(f"prismatic joint {jt.name!r}: friction mu > 0 needs a block length > 0")
            if fr.mu < 0.0 or fr.radius < 0.0 or fr.damping < 0.0:
                raise ValueError(f"joint {jt.name!r}: friction parameters must be >= 0, got {fr}")
            axis = None
            if prism:
                axis = np.asarray(jt.axis_i, float) / np.linalg.norm(jt.axis_i)
            self._fr.append((k, 2 * k, prism, axis))
            mu.append(fr.mu)
            rest.append(1.0 if fr.static is None or fr.mu == 0.0 else fr.static / fr.mu)
            rad.append(fr.radius)
            length.append(fr.length)
            damping.append(fr.damping)
        self.friction_joints = [self.joints[k].name for k, *_ in self._fr]
        self._mu, self._radius = np.array(mu, float), np.array(rad, float)
        self._rest_scale = np.array(rest, float)  # the Coulomb loads at rest: static / kinetic coefficient
        self._length, self._damping = np.array(length, float), np.array(damping, float)

    # -- friction geometry ----------------------------------------------------------------
    def directions(self, z):
        """G (nf, n): row f is the generalized force of a unit friction load of joint f
        (unit couple on body_i, -1 on body_j; or unit force +e on body_i at P, -e on body_j
        at P), so its relative rate is u_f = G[f] . zd.  Also {prismatic: e} guide directions."""
        G = np.zeros((len(self._fr), self.n))
        guides = {}
        for f, (k, _, prism, axis) in enumerate(self._fr):
            i, j, _, sj, _, _ = self._jd[k]
            if not prism:
                if i >= 0:
                    G[f, 3 * i + 2] += 1.0
                if j >= 0:
                    G[f, 3 * j + 2] -= 1.0
                continue
            e = jr._rot(0.0 if i < 0 else z[3 * i + 2]) @ axis
            P, _ = self._pt(z, j, sj)  # the sliding point (body_j's point s_j)
            guides[self.joints[k].name] = e
            for body, sign in ((i, 1.0), (j, -1.0)):
                if body >= 0:
                    G[f, 3 * body: 3 * body + 2] += sign * e
                    G[f, 3 * body + 2] += sign * jr._cross(P - z[3 * body: 3 * body + 2], e)
        return G, guides

    def _normal_loads(self, lam):
        """rho (nf,): |F| radius (revolute) or |N1| + |N2| (prismatic), its gradient
        (nf, m) with respect to the multipliers, and {prismatic: (N1, N2)}."""
        rho, drho = np.zeros(len(self._fr)), np.zeros((len(self._fr), self.m))
        contact = {}
        for f, (k, r, prism, _) in enumerate(self._fr):
            if not prism:
                F = lam[r: r + 2]
                size = np.hypot(F[0], F[1])
                rho[f] = self._radius[f] * size
                if size > 0.0:
                    drho[f, r: r + 2] = self._radius[f] * F / size
                continue
            N, M = lam[r], lam[r + 1]
            if self._length[f] == 0.0:  # damping only
                contact[self.joints[k].name] = (np.nan, np.nan)
                continue
            L = self._length[f]
            N1, N2 = N / 2 - M / L, N / 2 + M / L
            contact[self.joints[k].name] = (N1, N2)
            rho[f] = abs(N1) + abs(N2)
            drho[f, r] = (np.sign(N1) + np.sign(N2)) / 2
            drho[f, r + 1] = (np.sign(N2) - np.sign(N1)) / L
        return rho, drho, contact

    def rate_signs(self, z, zq, s):
        """Signs of k_f = dz/dq-rate coefficients for motion in direction s (+1/-1): sign(k_f)
        where |k_f| > 1e-9, else the sign of k_f a little further along (q + s 1e-6)."""
        G = self.directions(z)[0]
        sig = _slip_signs(G, zq)
        tiny = np.abs(G @ zq) <= _TINY_RATE
        if np.any(tiny):
            q = self._full(z)[0][-1]
            z2, _, zq2 = self.track(q + s * _LOOK_AHEAD, q, z, zq)
            sig[tiny] = _slip_signs(self.directions(z2)[0], zq2)[tiny]
        return sig

    # Newton's starts: 1 from the frictionless solution; n > 1 continued in the friction
    # coefficients, coef * k / n for k = 1..n, each from the last root (strong friction:
    # the system has several roots, this one on the branch from mu = 0)
    continuation = 1

    def _solve_with_friction(self, A, b, lam_at, G, coef):
        """Solve A x = b + [G^T c(lam); 0], c = -coef * rho(lam), lam = x[lam_at], by Newton
        from the frictionless solution (or continued, see ``continuation``)."""
        x = np.linalg.solve(A, b)
        if not np.any(coef):
            return x
        for k in range(1, self.continuation + 1):
            x = self._newton_with_friction(A, b, lam_at, G, coef * k / self.continuation, x)
        return x

    def _newton_with_friction(self, A, b, lam_at, G, coef, x):
        """Newton from x; stops when the update is below 1e-14 relative (or stalls at rounding)."""
        n, prev = self.n, np.inf
        for _ in range(60):
            rho, drho, _ = self._normal_loads(x[lam_at])
            R = A @ x - b
            R[:n] += G.T @ (coef * rho)
            J = A.copy()
            J[:n, lam_at] += G.T @ (coef[:, None] * drho)
            dx = np.linalg.solve(J, R)
            x = x - dx
            step, scale = np.max(np.abs(dx)), 1.0 + np.max(np.abs(x))
            if step <= 1e-14 * scale or (step <= 1e-10 * scale and step >= 0.5 * prev):
                return x
            prev = step
        raise RuntimeError("friction Newton did not converge (friction too large for a unique solution?)")

    def _loads(self, z, zd, lam, G, signs, scale, tau_power, damper_power):
        """Per-joint friction outputs at a solved state."""
        u = G @ zd
        rho, _, contact = self._normal_loads(lam)
        coulomb = -scale * self._mu * signs * rho
        viscous = -self._damping * u
        return dict(lam=lam, rate=u, coulomb=coulomb, viscous=viscous, contact=contact, signs=signs,
                    p_drive=tau_power, p_friction=coulomb @ u, p_damping=damper_power + viscous @ u)

    # -- dynamics with friction -------------------------------------------------------------
    def forward(self, z, w, tau=0.0, zq=None, signs=None, scale=1.0):
        """Forward dynamics with friction at an assembled z (w in the driver's units/s, tau
        the driver's generalized force).  signs: Coulomb sign per friction joint (default
        sign(u_f)); scale multiplies every Coulomb load (1 = kinetic law).
        Returns dict(wdot, zd, zdd, lam, rate, coulomb, viscous, contact, signs, p_drive,
        p_friction, p_damping)."""
        zq = self.influence(z) if zq is None else zq
        zd = zq * w
        _, Jf, gam = self._full(z, zd)
        Q, p_dampers = self.forces(z, zd, tau, Jf[-1])
        G, _ = self.directions(z)
        u = G @ zd
        signs = _slip_signs(G, zd) if signs is None else np.asarray(signs, float)
        n, m = self.n, self.m
        A = np.zeros((n + m, n + m))
        A[np.arange(n), np.arange(n)] = self.Mdiag
        A[:n, n:] = Jf[:-1].T
        A[n:, :n] = Jf[:-1]
        b = np.concatenate([Q - G.T @ (self._damping * u), gam[:-1]])
        x = self._solve_with_friction(A, b, slice(n, n + m), G, scale * self._mu * signs)
        zdd, lam = x[:n], x[n:]
        out = self._loads(z, zd, lam, G, signs, scale, tau * w, p_dampers)
        out.update(wdot=Jf[-1] @ zdd - gam[-1], zd=zd, zdd=zdd)
        return out

    def inverse(self, z, w, wdot, zq=None, direction=None, signs=None, scale=1.0):
        """Inverse dynamics with friction at an assembled z: the driver effort tau and the
        multipliers producing (w, wdot).  Coulomb signs: ``signs`` if given, else sign(u_f) when
        w != 0; at w == 0 those of motion starting in ``direction`` (default sign(wdot)); at
        w == wdot == 0 without direction, no Coulomb friction (the static effort is then any
        value in holding_range).  scale multiplies the Coulomb loads.  Returns the forward dict
        plus tau."""
        zq = self.influence(z) if zq is None else zq
        zd = zq * w
        _, Jf, gam = self._full(z, zd)
        zdd = np.linalg.solve(Jf, gam + wdot * self._unit())
        Q0, p_dampers = self.forces(z, zd, 0.0, Jf[-1])
        G, _ = self.directions(z)
        u = G @ zd
        if signs is None:
            if w != 0.0:
                signs = _slip_signs(G, zd)
            else:
                d = np.sign(wdot) if direction is None else direction
                signs = d * self.rate_signs(z, zq, d) if d != 0 else np.zeros(len(self._fr))
        signs = np.asarray(signs, float)
        # M zdd + Phi_z^T lam = Q0 + tau D_z^T + friction  <=>  Jf^T [lam; -tau] = rhs
        rhs = Q0 - G.T @ (self._damping * u) - self.Mdiag * zdd
        y = self._solve_with_friction(Jf.T, rhs, slice(0, self.m), G, scale * self._mu * signs)
        lam, tau = y[:-1], -y[-1]
        out = self._loads(z, zd, lam, G, signs, scale, tau * w, p_dampers)
        out.update(tau=tau, wdot=wdot, zd=zd, zdd=zdd)
        return out

    def holding_range(self, z, zq=None):
        """(tau_minus, tau_plus): driver efforts at which the mechanism at rest at z is on the
        verge of moving in the -/+ direction (inverse dynamics at w = dw/dt = 0 with the Coulomb
        signs of that direction, the coefficients at rest).  It is held at rest for
        tau_minus <= tau <= tau_plus."""
        return tuple(self.inverse(z, 0.0, 0.0, zq, direction=s, scale=self._rest_scale)["tau"] for s in (-1, 1))

    def _start_accelerations(self, z, zq, tau):
        """{s: acceleration with w = 0 and the Coulomb signs of motion in direction s, with the
        coefficients at rest (whether it starts is decided by them)}."""
        return {s: self.forward(z, 0.0, tau, zq, signs=s * self.rate_signs(z, zq, s), scale=self._rest_scale)["wdot"]
                for s in (1, -1)}

    def start_direction(self, z, zq, tau):
        """At rest (w = 0) under driver effort tau: +1 / -1 if it starts moving that way,
        0 if it sticks."""
        acc = self._start_accelerations(z, zq, tau)
        go = [s for s in (1, -1) if s * acc[s] > 0.0]
        if len(go) == 2:
            raise RuntimeError(f"ambiguous start from rest: accelerations {acc} for directions +1/-1")
        return go[0] if go else 0

    def stuck(self, z, zq, tau):
        """Loads while stuck at z under driver effort tau (w = dw/dt = 0): the Coulomb pattern
        of the impending direction scaled by alpha in [0, 1] so that dw/dt = 0.  Returns the
        forward dict (plus alpha)."""
        free = self.forward(z, 0.0, tau, zq, signs=np.zeros(len(self._fr)))
        s = int(np.sign(free["wdot"]))
        if s == 0:
            free.update(alpha=0.0)
            return free
        signs = s * self.rate_signs(z, zq, s)
        def wdot(a):
            return self.forward(z, 0.0, tau, zq, signs, a * self._rest_scale)["wdot"]

        # at a break-away instant the full pattern at rest is (to rounding) just enough
        alpha = 1.0 if s * wdot(1.0) >= 0.0 else brentq(wdot, 0.0, 1.0, xtol=1e-15,
                                                        rtol=4 * np.finfo(float).eps)
        out = self.forward(z, 0.0, tau, zq, signs, alpha * self._rest_scale)
        out.update(alpha=alpha)
        return out

    def _break_away(self, z, zq, q, t0, t1, tau, scan):
        """First time in (t0, t1] at which the mechanism stuck at z breaks away, and the
        direction; (None, 0) if it stays stuck until t1."""
        def b(t):
            acc = self._start_accelerations(z, zq, tau(t, q, 0.0))
            return max(acc[1], -acc[-1])

        grid = np.append(np.arange(t0, t1, scan)[1:], t1)
        lo = t0
        for hi in grid:
            if b(hi) > 0.0:
                break
            lo = hi
        else:
            return None, 0
        tb = brentq(b, lo, hi, xtol=1e-14, rtol=4 * np.finfo(float).eps)
        for _ in range(1000):  # step onto the moving side of the root
            if b(tb) > 0.0:
                break
            tb = np.nextafter(tb, np.inf)
        else:
            tb = hi
        return tb, self.start_direction(z, zq, tau(tb, q, 0.0))

    # -- simulation ------------------------------------------------------------------------
    def simulate(self, init: jr.Initial, t1, tau: Callable | None = None, t_eval=None, rtol=1e-12,
                 atol=1e-13, method="DOP853", scan=1e-3, max_step=np.inf, max_segments=10000):
        """Piecewise integration from init to t1 with friction and stiction (see the module
        docstring).  tau(t, q, w): driver generalized force (None = 0).  t_eval: output times
        (default: the solver's steps, and three samples per stuck interval).  scan: step [s]
        of the break-away scan while stuck.  Returns a FrictionResult."""
        run = _Run(self, init, tau or _zero_effort, t_eval,
                   dict(rtol=rtol, atol=atol, method=method, max_step=max_step))
        for _ in range(max_segments):
            if run.t >= t1:
                break
            z, zq = run.assemble(run.q)
            if run.w == 0.0:
                s = self.start_direction(z, zq, run.tau(run.t, run.q, 0.0))
                if s == 0:
                    s = run.stick(z, zq, t1, scan)
                    if s == 0:
                        break
            else:
                s = int(np.sign(run.w))
            run.segment(t1, s, self.rate_signs(z, zq, s))
        else:
            raise RuntimeError(f"more than {max_segments} segments (chattering?)")
        return self._postprocess(run.samples, run.events, run.z0, float(init.q), run.tau)

    def _postprocess(self, samples, events, z0, q0, tau):
        nt = len(samples)
        t = np.array([smp[0] for smp in samples])
        res = FrictionResult(
            t=t, q=np.array([smp[1] for smp in samples]), w=np.array([smp[2] for smp in samples]),
            wdot=np.empty(nt), tau_applied=np.empty(nt), tau_needed=np.full(nt, np.nan),
            holding=np.full((nt, 2), np.nan), stuck=np.array([smp[4] is None for smp in samples], bool),
            T=np.empty(nt), V=np.empty(nt), work_drive=np.array([smp[3][0] for smp in samples]),
            work_friction=np.array([smp[3][1] for smp in samples]),
            work_damping=np.array([smp[3][2] for smp in samples]),
            z=np.empty((nt, self.n)), zd=np.empty((nt, self.n)), zdd=np.empty((nt, self.n)),
            events=events, system=self)
        qa, z, zq = q0, z0, None
        for k, (tk, q, w, _, signs) in enumerate(samples):
            z, _, zq = self.track(q, qa, z, zq)
            qa = q
            ta = tau(tk, q, w)
            if signs is None:
                out = self.stuck(z, zq, ta)
                res.holding[k] = self.holding_range(z, zq)
            else:
                out = self.forward(z, w, ta, zq, signs)
                res.tau_needed[k] = self.inverse(z, w, out["wdot"], zq, signs=signs)["tau"]
            F, C = self.reactions(z, out["lam"])
            for name, v in F.items():
                res.reactions.setdefault(name, np.empty((nt, 2)))[k] = v
            for name, v in C.items():
                res.couples.setdefault(name, np.empty(nt))[k] = v
            _, guides = self.directions(z)
            for f, name in enumerate(self.friction_joints):
                res.friction.setdefault(name, np.empty(nt))[k] = out["coulomb"][f]
                res.damping.setdefault(name, np.empty(nt))[k] = out["viscous"][f]
                res.rates.setdefault(name, np.empty(nt))[k] = out["rate"][f]
            for name, nn in out["contact"].items():
                res.contact.setdefault(name, np.empty((nt, 2)))[k] = nn
                res.guides.setdefault(name, np.empty((nt, 2)))[k] = guides[name]
            res.T[k], res.V[k] = self.energies(z, out["zd"])
            res.wdot[k], res.tau_applied[k] = (0.0 if signs is None else out["wdot"]), ta
            res.z[k], res.zd[k], res.zdd[k] = z, out["zd"], out["zdd"]
        frames = [self.to_frames(zk) for zk in res.z]
        res.coords = {b: np.array([fr[b] for fr in frames]) for b in self.names}
        return res


class _Run:
    """State of one piecewise simulation: the current (t, q, w, works), the samples kept
    and the events met."""

    def __init__(self, system, init, tau, t_eval, solver):
        self.system, self.tau, self.solver = system, tau, solver
        self.t, self.q, self.w = 0.0, float(init.q), float(init.w)
        self.works = np.zeros(3)  # drive, Coulomb friction, damping
        self.z0 = system.newton(self.q, system.to_internal(init.coords))[0]
        self._cache = [self.q, self.z0, None]
        self.t_eval = None if t_eval is None else np.asarray(t_eval, float)
        self.samples, self.events = [], []  # samples: (t, q, w, works, signs or None if stuck)

    def assemble(self, q):
        """(z, dz/dq) at q, continued from the last assembly (keeps the branch)."""
        z, _, zq = self.system.track(q, *self._cache)
        self._cache[:] = q, z, zq
        return z, zq

    def keep(self, ts, qs, ws, W, signs):
        """Append samples later than the last one kept."""
        for k in range(len(ts)):
            if not self.samples or ts[k] > self.samples[-1][0]:
                self.samples.append((ts[k], qs[k], ws[k], W[:, k].copy(), signs))

    def pending(self, lo, hi):
        """Requested output times in [lo, hi] not yet produced."""
        last = self.samples[-1][0] if self.samples else -np.inf
        te = self.t_eval
        return te[(te > last) & (te >= lo) & (te <= hi)]

    def stick(self, z, zq, t1, scan):
        """Stuck from now: keep the stuck samples, move to the break-away time.  Returns the
        break-away direction, or 0 if it stays stuck until t1."""
        self.events.append((self.t, "stick", None))
        tb, s = self.system._break_away(z, zq, self.q, self.t, t1, self.tau, scan)
        t_end = t1 if tb is None else tb
        ts = np.linspace(self.t, t_end, 3) if self.t_eval is None else self.pending(self.t, t_end)
        n = len(ts)
        self.keep(ts, np.full(n, self.q), np.zeros(n), np.repeat(self.works[:, None], n, 1), None)
        if tb is not None:
            self.events.append((tb, "break", None))
            self.t = tb
        return s

    def segment(self, t1, s, sigma):
        """One solve_ivp run in direction s with the Coulomb signs s * sigma frozen, until t1
        or the first rest / switch event."""
        system, tau, t0, signs = self.system, self.tau, self.t, s * sigma

        def rhs(t, y):
            z, zq = self.assemble(y[0])
            out = system.forward(z, y[1], tau(t, y[0], y[1]), zq, signs)
            return [y[1], out["wdot"], out["p_drive"], out["p_friction"], out["p_damping"]]

        a0 = None
        if self.w == 0.0:  # from rest: s w / (t - t0) -> s dw/dt > 0, so t0 is not taken as the root
            z, zq = self.assemble(self.q)
            a0 = s * system.forward(z, 0.0, tau(t0, self.q, 0.0), zq, signs)["wdot"]

        def rest(t, y):
            if a0 is None:
                return s * y[1]
            return s * y[1] / (t - t0) if t > t0 else a0

        events, joints = [rest], [None]
        for f, name in enumerate(system.friction_joints):
            if system._mu[f] == 0.0 or sigma[f] == 0.0:
                continue  # no Coulomb sign to switch

            def switch(t, y, f=f, sg=sigma[f]):
                z, zq = self.assemble(y[0])
                return sg * (system.directions(z)[0][f] @ zq)

            events.append(switch)
            joints.append(name)
        for ev in events:
            ev.terminal, ev.direction = True, -1
        sol = solve_ivp(rhs, (t0, t1), [self.q, self.w, *self.works], events=events,
                        dense_output=self.t_eval is not None, **self.solver)
        if not sol.success:
            raise RuntimeError(sol.message)
        hit = None
        if sol.status == 1:
            hit = min((k for k, tk in enumerate(sol.t_events) if len(tk)), key=lambda k: sol.t_events[k][0])
            self.events.append((sol.t[-1], "rest" if hit == 0 else "switch", joints[hit]))
        ts, Y = sol.t, sol.y.copy()
        if self.t_eval is not None:  # requested times from the dense output (as t_eval would)
            ts = self.pending(t0, sol.t[-1])
            Y = sol.sol(ts) if len(ts) else np.zeros((5, 0))
        if hit == 0:  # a rest event: w is zero there by definition
            Y[1, ts == sol.t[-1]] = 0.0
        self.keep(ts, Y[0], Y[1], Y[2:], signs)
        self.t, self.q, self.works = sol.t[-1], sol.y[0, -1], sol.y[2:, -1].copy()
        self.w = 0.0 if hit == 0 else sol.y[1, -1]


@dataclass
class FrictionResult:
    """Output of FrictionSystem.simulate, one row per sample time (SI units).

    t, q, w, wdot: time, driver coordinate, rate, acceleration (wdot = 0 exactly while stuck);
    stuck: bool per sample; tau_applied: tau(t, q, w); tau_needed: inverse dynamics with
    friction at (q, w, wdot) with the sample's Coulomb signs (NaN while stuck);
    holding: (nt, 2) holding_range (tau_minus, tau_plus) while stuck, NaN while moving;
    reactions[joint]: (nt, 2) force on body_i by body_j; couples[prismatic]: couple on body_i;
    friction[joint]: (nt,) Coulomb load on body_i by body_j (couple N m for a revolute, force
    along the guide e in N for a prismatic, applied at the sliding point);
    damping[joint]: (nt,) viscous joint load, same convention; rates[joint]: relative rate u
    (rad/s or m/s); contact[prismatic]: (nt, 2) block contact forces (N1, N2);
    guides[prismatic]: (nt, 2) guide direction e;
    T, V: kinetic and gravity potential energy; work_drive, work_friction (<= 0),
    work_damping (<= 0): quadratures from t = 0; balance = T + V - all work (constant);
    events: [(t, kind, joint)], kind in {"rest", "stick", "break", "switch"}, joint the
    switching joint's name (None for the others); z, zd, zdd: COM coordinates as in jr.Result.
    Samples are strictly increasing in t; at an event the sample is the left limit."""
    t: np.ndarray
    q: np.ndarray
    w: np.ndarray
    wdot: np.ndarray
    tau_applied: np.ndarray
    tau_needed: np.ndarray
    holding: np.ndarray
    stuck: np.ndarray
    T: np.ndarray
    V: np.ndarray
    work_drive: np.ndarray
    work_friction: np.ndarray
    work_damping: np.ndarray
    z: np.ndarray
    zd: np.ndarray
    zdd: np.ndarray
    events: list
    system: FrictionSystem
    coords: dict = field(default_factory=dict)
    reactions: dict = field(default_factory=dict)
    couples: dict = field(default_factory=dict)
    friction: dict = field(default_factory=dict)
    damping: dict = field(default_factory=dict)
    rates: dict = field(default_factory=dict)
    contact: dict = field(default_factory=dict)
    guides: dict = field(default_factory=dict)

    @property
    def E(self):
        return self.T + self.V

    @property
    def work(self):
        return self.work_drive + self.work_friction + self.work_damping

    @property
    def balance(self):
        return self.T + self.V - self.work

    def event_times(self, kind, joint=None):
        """Times of the events of one kind ("rest", "stick", "break", "switch"), optionally
        of one joint."""
        return np.array([t for t, k, j in self.events if k == kind and joint in (None, j)])


# ----------------------------------------------------------------------------- model
@dataclass
class FrictionModel(jr.Model):
    """jr.Model over a FrictionSystem: simulate(t1, **kw) as jr.Model, plus the state
    functions below at a driver coordinate q reached by continuation from the initial
    assembly (which keeps its branch)."""

    def assembled(self, q):
        """(z, dz/dq) at q, tracked from the initial state."""
        s, init = self.system, self.initial
        z0 = s.newton(init.q, s.to_internal(init.coords))[0]
        z, _, zq = s.track(float(q), init.q, z0)
        return z, zq

    def _report(self, z, out):
        s = self.system
        F, C = s.reactions(z, out["lam"])
        return dict(wdot=out["wdot"], tau=out.get("tau"), reactions=F, couples=C,
                    friction=dict(zip(s.friction_joints, out["coulomb"])),
                    damping=dict(zip(s.friction_joints, out["viscous"])),
                    rates=dict(zip(s.friction_joints, out["rate"])), contact=out["contact"],
                    coords=s.to_frames(z))

    def forward(self, q, w, t=0.0, tau=None):
        """Forward dynamics with friction at (q, w) and time t; tau(t, q, w) defaults to the
        model's.  At w == 0 the stiction rule decides (wdot = 0 if it sticks, with the stuck
        loads).  Returns dict(wdot, tau, reactions, couples, friction, damping, rates,
        contact, coords, stuck)."""
        s = self.system
        z, zq = self.assembled(q)
        ta = (tau or self.tau or _zero_effort)(t, q, w)
        stuck = False
        if w != 0.0:
            out = s.forward(z, w, ta, zq)
        else:
            d = s.start_direction(z, zq, ta)
            stuck = d == 0
            out = s.stuck(z, zq, ta) if stuck else s.forward(z, 0.0, ta, zq, signs=d * s.rate_signs(z, zq, d))
            if stuck:
                out["wdot"] = 0.0
        rep = self._report(z, out)
        rep.update(tau=ta, stuck=stuck)
        return rep

    def inverse(self, q, w, wdot, t=0.0, direction=None):
        """Inverse dynamics with friction: the driver effort tau [N m or N] and the loads
        producing (q, w, wdot) (t is unused: no load here depends on time except tau itself).
        At w == 0 the Coulomb signs are those of motion starting in ``direction`` (default
        sign(wdot)).  Returns dict(tau, wdot, reactions, couples, friction, damping, rates,
        contact, coords)."""
        z, zq = self.assembled(q)
        return self._report(z, self.system.inverse(z, w, wdot, zq, direction=direction))

    def holding_range(self, q):
        """(tau_minus, tau_plus) of FrictionSystem.holding_range at q."""
        return self.system.holding_range(*self.assembled(q))


def with_friction(model: jr.Model, friction: dict) -> FrictionModel:
    """The same mechanism, initial state, driver effort and data with joint friction
    ``friction`` ({joint name: Friction})."""
    s = model.system
    fs = FrictionSystem(s.body_data, s.joints, s.driver, friction, gravity=s.gravity,
                        dampers=s.dampers, max_dq=s.max_dq)
    return FrictionModel(fs, model.initial, model.tau, dict(model.data, friction=dict(friction)))


# ----------------------------------------------------------------------------- builders
SLIDER_CRANK_FRICTION = dict(
    O=Friction(mu=0.2, radius=0.01, damping=1e-3),
    A=Friction(mu=0.2, radius=0.008, damping=1e-3),
    B=Friction(mu=0.2, radius=0.008, damping=1e-3),
    P=Friction(mu=0.15, length=0.04, damping=0.5),
)


def slider_crank(theta0=0.0, omega0=0.0, tau=None, friction=SLIDER_CRANK_FRICTION):
    """jr.slider_crank (crank + RRP dyad, SI) with friction in every joint.  Default:
    pins O (ground, crank), A (crank, rod), B (rod, slider): mu = 0.2, radii 10 / 8 / 8 mm,
    damping 1e-3 N m s/rad; prismatic P (guide = ground, slider): mu = 0.15, block 40 mm,
    damping 0.5 N s/m."""
    return with_friction(jr.slider_crank(theta0, omega0, tau), friction)


WATT_FRICTION = {name: Friction(mu=0.15, radius=0.02, damping=0.01)
                 for name in ("O2", "A", "B", "O4", "C", "D", "E")}


def watt_sixbar(theta2=0.0, omega2=0.0, tau=None, friction=WATT_FRICTION):
    """jr.watt_sixbar (SI) with friction in every joint.  Default: all seven pins mu = 0.15,
    radius 20 mm, damping 0.01 N m s/rad."""
    model = jr.watt_sixbar(theta2, omega2)
    model.tau = tau
    return with_friction(model, friction)


PENDULUM = dict(m=1.0, L=0.2, a=0.1, J_c=1.0 * 0.2**2 / 12)


def pendulum(theta0=0.0, omega0=0.0, tau=None, mu=0.5, radius=0.02, damping=0.0,
             gravity=(0.0, -jr.G)):
    """One bar (SI) pivoted at the ground origin by revolute "O" (ground, bar): m = 1, length
    0.2, COM at a = 0.1 on its x axis, J_c = m L^2 / 12; q = its angle (driver torque tau).
    Pivot friction mu, radius, damping.  Hanging at rest is theta = -pi/2."""
    d = PENDULUM
    bodies = dict(bar=dict(mass=d["m"], inertia=d["J_c"], com_local=(d["a"], 0.0)))
    joints = [jr.Revolute("O", GROUND, "bar", (0, 0), (0, 0))]
    fs = FrictionSystem(bodies, joints, ("bar", "angle"),
                        dict(O=Friction(mu=mu, radius=radius, damping=damping)), gravity=gravity)
    data = dict(d, mu=mu, radius=radius, damping=damping, gravity=gravity)
    return FrictionModel(fs, jr.Initial(theta0, omega0, dict(bar=(0.0, 0.0, theta0))), tau, data)


def pendulum_breakaway_time(k, mu=0.5, radius=0.02, g=jr.G):
    """The hanging pendulum at rest under tau = k t breaks away when k t reaches the static
    limit mu r |F|, F = the weight m g (the COM does not accelerate at break-away)."""
    return mu * radius * PENDULUM["m"] * g / k
