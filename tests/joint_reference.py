"""Independent joint-coordinate reference for planar one-degree-of-freedom linkages.

numpy + scipy only: this module must share no code (and no jax) with ``assurjax``,
so that the package can be checked against it.

Formulation
-----------
Absolute coordinates per moving body.  The user-facing coordinates of a body are
those of its *frame*: origin (x, y) and angle theta (counterclockwise from +x).
Internally each body is described by its centre of mass ``r_c = origin + A(theta) com``
and theta, so that the mass matrix is diagonal ``diag(m, m, J_c)``.

Kinematic constraints ``Phi(z) = 0`` (revolute: 2 rows, prismatic: 2 rows) plus one
driving relation ``D(z) = q`` fix all body coordinates ``z`` for a given generalized
coordinate ``q`` (the driver body's angle, or its frame origin's x or y).

Forward dynamics solves the index-1 Lagrange-multiplier system

    [ M      Phi_z^T ] [ zdd ]   [ Q + tau D_z^T ]
    [ Phi_z  0       ] [ lam ] = [ gamma         ]

with ``gamma = -(Phi_z zd)_z zd``; the driver acceleration is ``wdot = D_z zdd - gamma_D``.
Time integration uses generalized coordinate partitioning (Wehage-Haug): only
``(q, w)`` (and a work quadrature) are integrated with ``solve_ivp``; at every
evaluation ``z`` is recovered by Newton from ``[Phi; D - q] = 0`` starting from the
previous solution (predicted along dz/dq, which keeps the assembly branch), and
``zd = (dz/dq) w``.  Constraint drift is therefore at Newton precision (~1e-15).

Sign conventions
----------------
* Angles counterclockwise from +x; gravity is a vector (default (0, -9.81)).
* ``tau`` is the generalized force conjugate to ``q``: a torque on the driver body
  (angle driver) or a force along +x / +y on its frame origin (translating driver).
  ``tau_needed`` (inverse dynamics) is the ``tau`` that produces the given motion.
* Joint reaction of joint ``(name, body_i, body_j)``: the global vector (Fx, Fy) of the
  force exerted ON body_i BY body_j (body_j receives the opposite).  For a revolute it
  acts at the joint point.  For a prismatic it acts at the sliding point of body_j
  (normal to the guide), and ``couples[name]`` is the additional couple on body_i by
  body_j (body_j receives the opposite).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.integrate import solve_ivp
from scipy.special import ellipj, ellipk

GROUND = "ground"
G = 9.81


# ----------------------------------------------------------------------------- elements
@dataclass(frozen=True)
class Revolute:
    """Point s_i (body_i frame) coincides with point s_j (body_j frame).
    For the ground, points are global."""
    name: str
    body_i: str
    body_j: str
    s_i: tuple
    s_j: tuple


@dataclass(frozen=True)
class Prismatic:
    """Point s_j of body_j stays on the line through s_i with direction axis_i (body_i
    frame), and theta_j - theta_i = angle0 (relative rotation locked)."""
    name: str
    body_i: str
    body_j: str
    s_i: tuple = (0.0, 0.0)
    s_j: tuple = (0.0, 0.0)
    axis_i: tuple = (1.0, 0.0)
    angle0: float = 0.0


@dataclass(frozen=True)
class Damper:
    """Linear translational viscous damper, force c * dL/dt along the line between
    point s_a of body_a and point s_b of body_b (resisting elongation rate)."""
    name: str
    body_a: str
    s_a: tuple
    body_b: str
    s_b: tuple
    c: float


@dataclass(frozen=True)
class Spring:
    """Linear spring between point s_a of body_a and point s_b of body_b (body frames;
    global for the ground): tension k (L - L0) pulls the two points together when
    stretched; potential k (L - L0)^2 / 2."""
    name: str
    body_a: str
    s_a: tuple
    body_b: str
    s_b: tuple
    k: float
    free_length: float = 0.0


@dataclass(frozen=True)
class PointLoad:
    """A constant force (global frame, N) at point s of body (body frame; the body's
    COM for a force at its centre of mass); potential -force . P."""
    name: str
    body: str
    s: tuple
    force: tuple


@dataclass
class Initial:
    """Assembled initial state: q, w and frame coordinates {body: (x, y, theta)}."""
    q: float
    w: float
    coords: dict


def _rot(th):
    c, s = np.cos(th), np.sin(th)
    return np.array([[c, -s], [s, c]])


def _perp(v):
    """v rotated by +90 degrees (so d(A s)/dtheta = perp(A s))."""
    return np.array([-v[1], v[0]])


def _cross(a, b):
    return a[0] * b[1] - a[1] * b[0]


# ----------------------------------------------------------------------------- system
class System:
    """Planar multibody system with one degree of freedom.

    bodies: {name: dict(mass, inertia, com_local=(x, y))}, inertia about the COM.
    joints: list of Revolute / Prismatic; "ground" is the fixed body.
    driver: (body, kind), kind in {"angle", "x", "y"} -- q is that frame coordinate.
    dampers: list of Damper; springs: list of Spring; point_loads: list of PointLoad.
    """

    def __init__(self, bodies, joints, driver, gravity=(0.0, -G), dampers=(), max_dq=0.05, springs=(), point_loads=()):
        self.names = list(bodies)
        self.body_data = {b: dict(d) for b, d in bodies.items()}
        self.idx = {b: k for k, b in enumerate(self.names)}
        self.idx[GROUND] = -1  # index -1 = the ground slot appended in _full
        self.n = 3 * len(self.names)
        self.com = {b: np.asarray(d.get("com_local", (0.0, 0.0)), float) for b, d in bodies.items()}
        self.com[GROUND] = np.zeros(2)
        self.mass = np.array([bodies[b]["mass"] for b in self.names], float)
        self.Mdiag = np.concatenate([[d["mass"], d["mass"], d["inertia"]] for d in bodies.values()])
        self.gravity = np.asarray(gravity, float)
        self.joints = list(joints)
        self.dampers = list(dampers)
        self.springs = list(springs)
        self.point_loads = list(point_loads)
        self.m = 2 * len(self.joints)
        if self.m != self.n - 1:
            raise ValueError(f"{self.m} constraint rows for {self.n} coordinates: not 1-DOF")
        self.driver = driver
        self.max_dq = max_dq  # continuation step keeping Newton on the same branch
        self.Qg = np.concatenate([[m * self.gravity[0], m * self.gravity[1], 0.0] for m in self.mass])
        # joint data with points relative to the COM, as plain floats (speed)
        self._jd = []
        for jt in self.joints:
            nl = None
            if isinstance(jt, Prismatic):
                ax = np.asarray(jt.axis_i, float)
                nl = tuple(_perp(ax / np.linalg.norm(ax)))
            self._jd.append((self.idx[jt.body_i], self.idx[jt.body_j],
                             tuple(self._rel(jt.body_i, jt.s_i)), tuple(self._rel(jt.body_j, jt.s_j)),
                             nl, getattr(jt, "angle0", 0.0)))

    # -- coordinates ------------------------------------------------------------
    def _rel(self, body, s):
        """Local point relative to the COM."""
        return np.asarray(s, float) - self.com[body]

    def to_internal(self, coords):
        """{body: (x, y, theta) of the frame} -> z (COM coordinates)."""
        z = np.empty(self.n)
        for k, b in enumerate(self.names):
            x, y, th = coords[b]
            z[3 * k: 3 * k + 2] = np.array([x, y]) + _rot(th) @ self.com[b]
            z[3 * k + 2] = th
        return z

    def to_frames(self, z):
        """z -> {body: array (x, y, theta) of the frame}."""
        out = {}
        for k, b in enumerate(self.names):
            th = z[3 * k + 2]
            out[b] = np.array([*(z[3 * k: 3 * k + 2] - _rot(th) @ self.com[b]), th])
        return out

    def _pt(self, z, k, s):
        """Global point and its arm A s from the COM; s is COM-relative."""
        if k < 0:
            return s, np.zeros(2)
        a = _rot(z[3 * k + 2]) @ s
        return z[3 * k: 3 * k + 2] + a, a

    @staticmethod
    def _vel(zd, k, a):
        return np.zeros(2) if k < 0 else zd[3 * k: 3 * k + 2] + _perp(a) * zd[3 * k + 2]

    # -- constraints --------------------------------------------------------------
    def _full(self, z, zd=None):
        """Kinematic constraints with the driving relation as last row:
        F = [Phi; D] (n,), Jf = [Phi_z; D_z] (n, n), gam = [gamma; gamma_D] (n,) where
        gamma = -(Phi_z zd)_z zd (zero if zd is None).  Scalar code: the blocks are tiny."""
        n = self.n
        F, Jf, gam = np.empty(n), np.zeros((n, n)), np.zeros(n)
        # per-body lists with the ground appended at index -1
        X, Y, th = (list(z[0::3]) + [0.0], list(z[1::3]) + [0.0], list(z[2::3]) + [0.0])
        c, s = [np.cos(t) for t in th], [np.sin(t) for t in th]
        if zd is None:
            VX = VY = W = [0.0] * (len(th))
        else:
            VX, VY, W = list(zd[0::3]) + [0.0], list(zd[1::3]) + [0.0], list(zd[2::3]) + [0.0]

        def arm(k, p):
            return c[k] * p[0] - s[k] * p[1], s[k] * p[0] + c[k] * p[1]

        for r, (i, j, si, sj, nl, a0) in zip(range(0, self.m, 2), self._jd):
            aix, aiy = arm(i, si)
            ajx, ajy = arm(j, sj)
            wi2, wj2 = W[i] ** 2, W[j] ** 2
            if nl is None:  # revolute: P_i - P_j = 0
                F[r], F[r + 1] = X[i] + aix - X[j] - ajx, Y[i] + aiy - Y[j] - ajy
                if i >= 0:
                    Jf[r, 3 * i], Jf[r + 1, 3 * i + 1] = 1.0, 1.0
                    Jf[r, 3 * i + 2], Jf[r + 1, 3 * i + 2] = -aiy, aix
                if j >= 0:
                    Jf[r, 3 * j], Jf[r + 1, 3 * j + 1] = -1.0, -1.0
                    Jf[r, 3 * j + 2], Jf[r + 1, 3 * j + 2] = ajy, -ajx
                gam[r], gam[r + 1] = aix * wi2 - ajx * wj2, aiy * wi2 - ajy * wj2
            else:  # prismatic: n_i . (P_j - P_i) = 0, theta_j - theta_i = angle0
                nx, ny = arm(i, nl)
                dx, dy = X[j] + ajx - X[i] - aix, Y[j] + ajy - Y[i] - aiy
                F[r], F[r + 1] = nx * dx + ny * dy, th[j] - th[i] - a0
                if i >= 0:
                    Jf[r, 3 * i], Jf[r, 3 * i + 1] = -nx, -ny
                    Jf[r, 3 * i + 2] = (nx * dy - ny * dx) + (nx * aiy - ny * aix)
                    Jf[r + 1, 3 * i + 2] = -1.0
                if j >= 0:
                    Jf[r, 3 * j], Jf[r, 3 * j + 1] = nx, ny
                    Jf[r, 3 * j + 2] = ny * ajx - nx * ajy
                    Jf[r + 1, 3 * j + 2] = 1.0
                ddx = VX[j] - ajy * W[j] - VX[i] + aiy * W[i]
                ddy = VY[j] + ajx * W[j] - VY[i] - aix * W[i]
                gam[r] = ((nx * dx + ny * dy) * wi2 - 2 * W[i] * (nx * ddy - ny * ddx)
                          - nx * (aix * wi2 - ajx * wj2) - ny * (aiy * wi2 - ajy * wj2))
        body, kind = self.driver
        k = self.idx[body]
        if kind == "angle":
            F[-1], Jf[-1, 3 * k + 2] = th[k], 1.0
        else:  # x or y of the frame origin, arm -A com from the COM
            ax, ay = arm(k, -self.com[body])
            col = {"x": 0, "y": 1}[kind]
            F[-1] = (X[k] + ax, Y[k] + ay)[col]
            Jf[-1, 3 * k + col], Jf[-1, 3 * k + 2] = 1.0, (-ay, ax)[col]
            gam[-1] = (ax, ay)[col] * W[k] ** 2
        return F, Jf, gam

    def constraints(self, z, zd=None):
        """Phi (m,), Phi_z (m, n), gamma (m,) of the joints (driver excluded)."""
        F, Jf, gam = self._full(z, zd)
        return F[:-1], Jf[:-1], gam[:-1]

    def driver_row(self, z, zd=None):
        """D(z), D_z (n,), gamma_D, so that qdd = D_z zdd - gamma_D."""
        F, Jf, gam = self._full(z, zd)
        return F[-1], Jf[-1], gam[-1]

    # -- position / velocity level ---------------------------------------------------
    def newton(self, q, z, maxit=30):
        """Solve Phi(z) = 0, D(z) = q by Newton from z.  Returns z and Jf at z."""
        z = np.array(z, float)
        done = False
        for _ in range(maxit):
            F, Jf, _ = self._full(z)
            F[-1] -= q
            if done:
                if np.max(np.abs(F)) > 1e-10 * (1.0 + np.max(np.abs(z))):
                    break
                return z, Jf
            dz = np.linalg.solve(Jf, F)
            z -= dz
            # quadratic convergence: once |dz| < 1e-10 the updated z is exact to rounding
            done = np.max(np.abs(dz)) <= 1e-10 * (1.0 + np.max(np.abs(z)))
        raise RuntimeError(f"Newton did not converge at q={q}")

    def _unit(self):
        e = np.zeros(self.n)
        e[-1] = 1.0
        return e

    def influence(self, z):
        """dz/dq at an assembled z: zd = influence * w."""
        return np.linalg.solve(self._full(z)[1], self._unit())

    def track(self, q, q_prev, z_prev, zq_prev=None):
        """Solution at q continued from one at q_prev, in steps <= max_dq along the
        tangent dz/dq, so that Newton cannot jump to another assembly branch.
        Returns z, Jf and dz/dq at q."""
        nsub = max(1, int(np.ceil(abs(q - q_prev) / self.max_dq)))
        z, qa = z_prev, q_prev
        zq = self.influence(z) if zq_prev is None else zq_prev
        for qb in np.linspace(q_prev, q, nsub + 1)[1:]:
            z, Jf = self.newton(qb, z + zq * (qb - qa))
            zq = np.linalg.solve(Jf, self._unit())
            qa = qb
        return z, Jf, zq

    def assemble(self, q, guess):
        """Assembled frame coordinates at q, from guess {body: (x, y, theta)}."""
        return self.to_frames(self.newton(q, self.to_internal(guess))[0])

    # -- forces and dynamics ---------------------------------------------------------
    def _at(self, z, body, s):
        """Global position of point s (body frame) of body."""
        return self._pt(z, self.idx[body], self._rel(body, s))[0]

    def applied_point_forces(self, z):
        """Springs and point loads as [(body, point P, force at P)] (a spring gives two)."""
        out = []
        for sp in self.springs:
            Pa, Pb = self._at(z, sp.body_a, sp.s_a), self._at(z, sp.body_b, sp.s_b)
            d = Pb - Pa
            length = np.linalg.norm(d)
            f = sp.k * (length - sp.free_length) * d / length  # on a, towards b when stretched
            out += [(sp.body_a, Pa, f), (sp.body_b, Pb, -f)]
        for pl in self.point_loads:
            out.append((pl.body, self._at(z, pl.body, pl.s), np.asarray(pl.force, float)))
        return out

    def forces(self, z, zd, tau=0.0, row=None):
        """Generalized forces Q (n,) (gravity, driver tau, dampers, springs, point loads)
        and damper power."""
        row = self._full(z)[1][-1] if row is None else row
        Q = self.Qg + tau * row
        for body, P, f in self.applied_point_forces(z):
            k = self.idx[body]
            if k >= 0:
                Q[3 * k: 3 * k + 2] += f
                Q[3 * k + 2] += _cross(P - z[3 * k: 3 * k + 2], f)
        power = 0.0
        for dm in self.dampers:
            a, b = self.idx[dm.body_a], self.idx[dm.body_b]
            Pa, aa = self._pt(z, a, self._rel(dm.body_a, dm.s_a))
            Pb, ab = self._pt(z, b, self._rel(dm.body_b, dm.s_b))
            d = Pb - Pa
            e = d / np.linalg.norm(d)
            Ld = e @ (self._vel(zd, b, ab) - self._vel(zd, a, aa))
            f = -dm.c * Ld * e  # on body_b; body_a gets -f
            if b >= 0:
                Q[3 * b: 3 * b + 2] += f
                Q[3 * b + 2] += _cross(ab, f)
            if a >= 0:
                Q[3 * a: 3 * a + 2] -= f
                Q[3 * a + 2] -= _cross(aa, f)
            power -= dm.c * Ld**2
        return Q, power

    def accelerations(self, z, w, tau=0.0, zq=None):
        """Forward dynamics at an assembled z: (wdot, zd, zdd, lam, damper power)."""
        zq = self.influence(z) if zq is None else zq
        zd = zq * w
        _, Jf, gam = self._full(z, zd)
        Q, power = self.forces(z, zd, tau, Jf[-1])
        n, m = self.n, self.m
        A = np.zeros((n + m, n + m))
        A[np.arange(n), np.arange(n)] = self.Mdiag
        A[:n, n:] = Jf[:-1].T
        A[n:, :n] = Jf[:-1]
        sol = np.linalg.solve(A, np.concatenate([Q, gam[:-1]]))
        zdd, lam = sol[:n], sol[n:]
        return Jf[-1] @ zdd - gam[-1], zd, zdd, lam, power

    def inverse_dynamics(self, z, w, wdot):
        """Driver generalized force and multipliers producing (w, wdot) at assembled z.
        Returns (tau_needed, lam, zd, zdd)."""
        zd = self.influence(z) * w
        _, Jf, gam = self._full(z, zd)
        zdd = np.linalg.solve(Jf, gam + wdot * self._unit())
        Q0, _ = self.forces(z, zd, 0.0, Jf[-1])
        # M zdd + Phi_z^T lam = Q0 + tau D_z^T  <=>  Jf^T [lam; -tau] = Q0 - M zdd
        mu = np.linalg.solve(Jf.T, Q0 - self.Mdiag * zdd)
        return -mu[-1], mu[:-1], zd, zdd

    def state(self, q, w, guess, wdot=None, tau=0.0):
        """Everything at one state, assembled by Newton from guess {body: (x, y, theta)}
        (which selects the branch).  Forward dynamics under driver force tau or, if wdot
        is given, inverse dynamics (tau := the force needed).
        Returns dict(coords, wdot, tau, reactions, couples, T, V)."""
        z, _ = self.newton(q, self.to_internal(guess))
        if wdot is None:
            wdot, zd, zdd, lam, _ = self.accelerations(z, w, tau)
        else:
            tau, lam, zd, zdd = self.inverse_dynamics(z, w, wdot)
        F, C = self.reactions(z, lam)
        T, V = self.energies(z, zd)
        return dict(coords=self.to_frames(z), wdot=wdot, tau=tau, reactions=F, couples=C, T=T, V=V)

    def reactions(self, z, lam):
        """{joint: (Fx, Fy) on body_i by body_j}, {prismatic joint: couple on body_i}."""
        F, C = {}, {}
        for r, jt, (i, _, _, _, nl, _) in zip(range(0, self.m, 2), self.joints, self._jd):
            if nl is None:
                F[jt.name] = -lam[r: r + 2]  # constraint force on body_i = -Phi_ri^T lam
            else:
                F[jt.name] = lam[r] * (_rot(0.0 if i < 0 else z[3 * i + 2]) @ nl)
                C[jt.name] = lam[r + 1]
        return F, C

    def energies(self, z, zd):
        """Kinetic and potential energy (gravity, springs, constant point loads)."""
        T = 0.5 * np.sum(self.Mdiag * zd**2)
        V = -np.sum(self.mass * (z[0::3] * self.gravity[0] + z[1::3] * self.gravity[1]))
        for sp in self.springs:
            length = np.linalg.norm(self._at(z, sp.body_b, sp.s_b) - self._at(z, sp.body_a, sp.s_a))
            V += 0.5 * sp.k * (length - sp.free_length) ** 2
        for pl in self.point_loads:
            V -= np.dot(pl.force, self._at(z, pl.body, pl.s))
        return T, V

    # -- simulation ------------------------------------------------------------------
    def simulate(self, init: Initial, t1, tau: Callable | None = None, t_eval=None,
                 rtol=1e-12, atol=1e-13, method="DOP853", standstill=None, max_step=np.inf):
        """Integrate from init to t1.

        tau(t, q, w): applied generalized force on the driver (None = 0).
        standstill: None, or direction (+1, -1, 0) of w crossing zero; integration stops
        at the first such crossing (located by solve_ivp's event root finding).
        """
        tau = tau or (lambda t, q, w: 0.0)
        z0 = self.newton(init.q, self.to_internal(init.coords))[0]
        cache = [init.q, z0, None]  # last (q, z, dz/dq): Newton start and predictor

        def rhs(t, y):
            q, w = y[0], y[1]
            z, _, zq = self.track(q, *cache)
            cache[:] = q, z, zq
            ta = tau(t, q, w)
            wdot, *_, power = self.accelerations(z, w, ta, zq)
            return [w, wdot, ta * w + power]

        events = None
        if standstill is not None:
            wdot0 = self.accelerations(z0, init.w, tau(0.0, init.q, init.w))[0]

            def stop(t, y):
                # A start from rest would register as a crossing at t=0: use the sign
                # the velocity is about to take instead.
                if t == 0.0 and y[1] == 0.0:
                    return np.sign(wdot0) * 1e-300
                return y[1]

            stop.terminal, stop.direction = True, standstill
            events = [stop]

        sol = solve_ivp(rhs, (0.0, t1), [init.q, init.w, 0.0], method=method, t_eval=t_eval,
                        rtol=rtol, atol=atol, events=events, max_step=max_step)
        if not sol.success:
            raise RuntimeError(sol.message)
        t, Y = sol.t, sol.y
        if standstill is not None and len(sol.t_events[0]) and (t_eval is not None):
            t, Y = np.append(t, sol.t_events[0]), np.hstack([Y, sol.y_events[0].T])
        return self._postprocess(t, Y, z0, init.q, tau, sol)

    def _postprocess(self, t, Y, z0, q0, tau, sol):
        nt = len(t)
        res = Result(t=t, q=Y[0], w=Y[1], work=Y[2], wdot=np.empty(nt), T=np.empty(nt),
                     V=np.empty(nt), tau_applied=np.empty(nt), tau_needed=np.empty(nt),
                     residual=np.empty(nt), z=np.empty((nt, self.n)),
                     zd=np.empty((nt, self.n)), zdd=np.empty((nt, self.n)),
                     t_events=(sol.t_events[0] if sol.t_events else np.array([])), system=self)
        qa, z, zq = q0, z0, None
        for k in range(nt):
            q, w = Y[0, k], Y[1, k]
            z, _, zq = self.track(q, qa, z, zq)
            qa = q
            ta = tau(t[k], q, w)
            wdot, zd, zdd, lam, _ = self.accelerations(z, w, ta, zq)
            F, C = self.reactions(z, lam)
            for name, v in F.items():
                res.reactions.setdefault(name, np.empty((nt, 2)))[k] = v
            for name, v in C.items():
                res.couples.setdefault(name, np.empty(nt))[k] = v
            res.T[k], res.V[k] = self.energies(z, zd)
            res.wdot[k], res.tau_applied[k] = wdot, ta
            res.tau_needed[k] = self.inverse_dynamics(z, w, wdot)[0]
            res.residual[k] = np.max(np.abs(self.constraints(z)[0]))
            res.z[k], res.zd[k], res.zdd[k] = z, zd, zdd
        frames = [self.to_frames(zk) for zk in res.z]
        res.coords = {b: np.array([f[b] for f in frames]) for b in self.names}
        return res


def newton_euler_residuals(system, z, zd, zdd, reactions, couples, tau=0.0):
    """Per-body residuals (nb, 3) of m a_c = sum F and J alpha = sum M_c, built from
    joint reactions given in this module's convention ({joint: force on body_i by body_j},
    {prismatic: couple on body_i}), gravity, the driver force tau and the dampers.
    Works without the multiplier machinery, so it checks the reaction convention."""
    nb = len(system.names)
    F = np.zeros((nb, 2))
    Mc = np.zeros(nb)

    def apply(body, point, force, couple=0.0):
        k = system.idx[body]
        if k >= 0:
            F[k] += force
            Mc[k] += _cross(point - z[3 * k: 3 * k + 2], force) + couple

    for jt in system.joints:
        if isinstance(jt, Revolute):
            P, _ = system._pt(z, system.idx[jt.body_i], system._rel(jt.body_i, jt.s_i))
            cpl = 0.0
        else:  # force acts at the sliding point of body_j
            P, _ = system._pt(z, system.idx[jt.body_j], system._rel(jt.body_j, jt.s_j))
            cpl = couples[jt.name]
        f = np.asarray(reactions[jt.name])
        apply(jt.body_i, P, f, cpl)
        apply(jt.body_j, P, -f, -cpl)
    body, kind = system.driver
    k = system.idx[body]
    origin, _ = system._pt(z, k, -system.com[body])
    if kind == "angle":
        apply(body, origin, np.zeros(2), tau)
    else:
        apply(body, origin, tau * np.eye(2)[{"x": 0, "y": 1}[kind]])
    for dm in system.dampers:
        a, b = system.idx[dm.body_a], system.idx[dm.body_b]
        Pa, aa = system._pt(z, a, system._rel(dm.body_a, dm.s_a))
        Pb, ab = system._pt(z, b, system._rel(dm.body_b, dm.s_b))
        e = (Pb - Pa) / np.linalg.norm(Pb - Pa)
        f = -dm.c * (e @ (system._vel(zd, b, ab) - system._vel(zd, a, aa))) * e
        apply(dm.body_b, Pb, f)
        apply(dm.body_a, Pa, -f)
    for body, P, f in system.applied_point_forces(z):
        apply(body, P, f)
    res = np.empty((nb, 3))
    for k, m in enumerate(system.mass):
        res[k, :2] = m * zdd[3 * k: 3 * k + 2] - m * system.gravity - F[k]
        res[k, 2] = system.Mdiag[3 * k + 2] * zdd[3 * k + 2] - Mc[k]
    return res


@dataclass
class Result:
    """Simulation output.  coords[body]: (nt, 3) frame (x, y, theta); reactions[joint]:
    (nt, 2) force on body_i by body_j; couples[prismatic]: couple on body_i by body_j;
    work: integral of tau*w + damper power (so T + V - work is conserved);
    tau_needed: inverse dynamics at (q, w, wdot), equal to tau_applied;
    residual: max |Phi|; z, zd, zdd: internal COM coordinates (x_c, y_c, theta) per
    body in system.names order."""
    t: np.ndarray
    q: np.ndarray
    w: np.ndarray
    wdot: np.ndarray
    T: np.ndarray
    V: np.ndarray
    work: np.ndarray
    tau_applied: np.ndarray
    tau_needed: np.ndarray
    residual: np.ndarray
    z: np.ndarray
    zd: np.ndarray
    zdd: np.ndarray
    t_events: np.ndarray
    system: System
    coords: dict = field(default_factory=dict)
    reactions: dict = field(default_factory=dict)
    couples: dict = field(default_factory=dict)

    @property
    def E(self):
        return self.T + self.V


@dataclass
class Model:
    """A concrete mechanism: system, consistent initial state, applied driver force."""
    system: System
    initial: Initial
    tau: Callable | None = None
    data: dict = field(default_factory=dict)

    def simulate(self, t1, **kw):
        kw.setdefault("tau", self.tau)
        return self.system.simulate(self.initial, t1, **kw)


def with_loads(model: Model, springs=(), point_loads=(), dampers=()) -> Model:
    """The same mechanism, initial state, driver effort and data with ``springs``,
    ``point_loads`` and ``dampers`` added (lists of Spring / PointLoad / Damper)."""
    s = model.system
    system = System(s.body_data, s.joints, s.driver, gravity=s.gravity, dampers=list(s.dampers) + list(dampers), max_dq=s.max_dq,
                    springs=list(s.springs) + list(springs), point_loads=list(s.point_loads) + list(point_loads))
    return Model(system, model.initial, model.tau, dict(model.data))


# ----------------------------------------------------------------------------- geometry
def circle_intersection(P, rP, Q, rQ, left=True):
    """Point X with |X-P| = rP, |X-Q| = rQ, on the left (or right) of the line P -> Q."""
    P, Q = np.asarray(P, float), np.asarray(Q, float)
    d = np.linalg.norm(Q - P)
    a = (rP**2 - rQ**2 + d**2) / (2 * d)
    h = np.sqrt(rP**2 - a**2)
    u = (Q - P) / d
    return P + a * u + (h if left else -h) * _perp(u)


def _angle(P, Q):
    return np.arctan2(Q[1] - P[1], Q[0] - P[0])


def _link(m, L, J=None):
    """Uniform bar along its frame x axis, frame at its proximal joint."""
    return dict(mass=m, inertia=m * L**2 / 12 if J is None else J, com_local=(L / 2, 0.0))


# ----------------------------------------------------------------------------- Watt six-bar
WATT = dict(O2=(0.0, 0.0), O4=(1.6, 0.0), L2=1.0, L3=1.5, L4=1.5, L5=1.0, L6=1.0,
            m=dict(crank=1.0, coupler=1.5, rocker=1.5, link5=1.0, link6=1.0),
            J=dict(crank=0.0833, coupler=0.2813, rocker=0.2813, link5=0.0833, link6=0.0833))


def watt_sixbar_points(theta2):
    """Closed-form assembly: points and link angles.  B left of A -> O4, E left of C -> D."""
    d = WATT
    O2, O4 = np.array(d["O2"]), np.array(d["O4"])
    A = O2 + d["L2"] * np.array([np.cos(theta2), np.sin(theta2)])
    B = circle_intersection(A, d["L3"], O4, d["L4"], left=True)
    C, D = (A + B) / 2, (O4 + B) / 2
    E = circle_intersection(C, d["L5"], D, d["L6"], left=True)
    pts = dict(O2=O2, O4=O4, A=A, B=B, C=C, D=D, E=E)
    ang = dict(crank=theta2, coupler=_angle(A, B), rocker=_angle(O4, B),
               link5=_angle(C, E), link6=_angle(D, E))
    return pts, ang


def watt_sixbar(theta2=0.0, omega2=0.0):
    """Watt six-bar (SI).  Bodies crank (O2->A), coupler (A->B), rocker (O4->B),
    link5 (C->E), link6 (D->E); each frame at the first point, x along the link.
    Joints (body_i, body_j): O2 (ground, crank), A (crank, coupler), B (coupler, rocker),
    O4 (rocker, ground), C (coupler, link5), D (rocker, link6), E (link5, link6)."""
    d = WATT
    L = dict(crank=d["L2"], coupler=d["L3"], rocker=d["L4"], link5=d["L5"], link6=d["L6"])
    bodies = {b: _link(d["m"][b], L[b], d["J"][b]) for b in L}
    joints = [
        Revolute("O2", GROUND, "crank", d["O2"], (0, 0)),
        Revolute("A", "crank", "coupler", (d["L2"], 0), (0, 0)),
        Revolute("B", "coupler", "rocker", (d["L3"], 0), (d["L4"], 0)),
        Revolute("O4", "rocker", GROUND, (0, 0), d["O4"]),
        Revolute("C", "coupler", "link5", (d["L3"] / 2, 0), (0, 0)),
        Revolute("D", "rocker", "link6", (d["L4"] / 2, 0), (0, 0)),
        Revolute("E", "link5", "link6", (d["L5"], 0), (d["L6"], 0)),
    ]
    pts, ang = watt_sixbar_points(theta2)
    origin = dict(crank="O2", coupler="A", rocker="O4", link5="C", link6="D")
    coords = {b: (*pts[origin[b]], ang[b]) for b in L}
    return Model(System(bodies, joints, ("crank", "angle")), Initial(theta2, omega2, coords), data=d)


# ----------------------------------------------------------------------------- slider-crank
SLIDER_CRANK = dict(r=0.1, l=0.3, m_crank=0.5, J_crank=0.001, m_rod=1.0, J_rod=0.0075,
                    m_slider=0.8, J_slider=0.0)


def slider_crank(theta0=0.0, omega0=0.0, tau=None):
    """Centred slider-crank (SI), gravity (0, -9.81).  Crank O->A: r = 0.1, m = 0.5,
    J_c = 0.001 (about its COM at the midpoint of OA); rod A->B: l = 0.3, m = 1.0,
    J_c = 0.0075 (COM at midpoint); slider: m = 0.8, J = 0 (rotation locked), COM at the
    pin B on the x axis.  Assembly: B at x > 0 (x_B = r cos + sqrt(l^2 - r^2 sin^2)).
    Joints: O (ground, crank), A (crank, rod), B (rod, slider),
    P prismatic (ground, slider) along the global x axis."""
    d = SLIDER_CRANK
    r, l = d["r"], d["l"]
    bodies = dict(crank=_link(d["m_crank"], r, d["J_crank"]), rod=_link(d["m_rod"], l, d["J_rod"]),
                  slider=dict(mass=d["m_slider"], inertia=d["J_slider"], com_local=(0.0, 0.0)))
    joints = [Revolute("O", GROUND, "crank", (0, 0), (0, 0)),
              Revolute("A", "crank", "rod", (r, 0), (0, 0)),
              Revolute("B", "rod", "slider", (l, 0), (0, 0)),
              Prismatic("P", GROUND, "slider", (0, 0), (0, 0), (1, 0))]
    A = r * np.array([np.cos(theta0), np.sin(theta0)])
    B = np.array([A[0] + np.sqrt(l**2 - A[1] ** 2), 0.0])
    coords = dict(crank=(0, 0, theta0), rod=(*A, _angle(A, B)), slider=(*B, 0.0))
    return Model(System(bodies, joints, ("crank", "angle")), Initial(theta0, omega0, coords), tau, d)


def slider_crank_lagrange(theta, omega, tau=0.0, g=G):
    """Hand-derived Lagrange equation of the slider-crank above, in closed form:
    m(th) thdd + c(th) thd^2 + dV/dth = tau.  Returns (thdd, m, c, dV)."""
    d = SLIDER_CRANK
    r, l = d["r"], d["l"]
    s, co = np.sin(theta), np.cos(theta)
    lam = r / l
    sphi = -lam * s                       # rod angle phi: A_y + l sin(phi) = 0
    cphi = np.sqrt(1 - sphi**2)
    p1 = -lam * co / cphi                 # dphi/dth
    p2 = lam * s / cphi - lam * co * sphi * p1 / cphi**2   # d2phi/dth2
    kA, kA2 = r * np.array([-s, co]), -r * np.array([co, s])
    xb1 = -r * s - l * sphi * p1
    xb2 = -r * co - l * cphi * p1**2 - l * sphi * p2
    kG, kG2 = (kA + [xb1, 0.0]) / 2, (kA2 + [xb2, 0.0]) / 2
    mc, mr, ms = d["m_crank"], d["m_rod"], d["m_slider"]
    mass = d["J_crank"] + mc * kA @ kA / 4 + mr * kG @ kG + d["J_rod"] * p1**2 + ms * xb1**2
    cor = mc * kA @ kA2 / 4 + mr * kG @ kG2 + d["J_rod"] * p1 * p2 + ms * xb1 * xb2
    dV = g * (mc * kA[1] / 2 + mr * kG[1])
    return (tau - cor * omega**2 - dV) / mass, mass, cor, dV


# ----------------------------------------------------------------------------- four-bar + motor
FOUR_BAR = dict(O2=(0.0, 0.0), O4=(0.4, 0.0), L2=0.1, L3=0.35, L4=0.3,
                m2=0.2, m3=0.5, m4=0.4, T_stall=1.5, w_noload=10.0,
                damper_anchor=(0.2, -0.3), damper_c=1.0)


def four_bar_motor(theta0=0.0, omega0=0.0, **overrides):
    """Crank-rocker four-bar (SI) driven by a DC-motor line on the crank,
    tau = T_stall (1 - w / w_noload), T_stall = 1.5 N m, w_noload = 10 rad/s.
    O2 = (0, 0), O4 = (0.4, 0); crank O2->A 0.1 m 0.2 kg, coupler A->B 0.35 m 0.5 kg,
    rocker O4->B 0.3 m 0.4 kg; uniform bars (COM at midpoint, J = m L^2 / 12).
    B left of A -> O4.  Viscous damper c = 1.0 N s/m between the ground point
    (0.2, -0.3) and the coupler midpoint.  Joints: O2 (ground, crank), A (crank, coupler),
    B (coupler, rocker), O4 (rocker, ground); damper "damper" (ground, coupler)."""
    d = {**FOUR_BAR, **overrides}
    bodies = dict(crank=_link(d["m2"], d["L2"]), coupler=_link(d["m3"], d["L3"]),
                  rocker=_link(d["m4"], d["L4"]))
    joints = [Revolute("O2", GROUND, "crank", d["O2"], (0, 0)),
              Revolute("A", "crank", "coupler", (d["L2"], 0), (0, 0)),
              Revolute("B", "coupler", "rocker", (d["L3"], 0), (d["L4"], 0)),
              Revolute("O4", "rocker", GROUND, (0, 0), d["O4"])]
    dampers = [Damper("damper", GROUND, d["damper_anchor"], "coupler", (d["L3"] / 2, 0), d["damper_c"])]
    O2, O4 = np.array(d["O2"]), np.array(d["O4"])
    A = O2 + d["L2"] * np.array([np.cos(theta0), np.sin(theta0)])
    B = circle_intersection(A, d["L3"], O4, d["L4"], left=True)
    coords = dict(crank=(*O2, theta0), coupler=(*A, _angle(A, B)), rocker=(*O4, _angle(O4, B)))

    def motor(t, q, w):
        return d["T_stall"] * (1.0 - w / d["w_noload"])

    sys_ = System(bodies, joints, ("crank", "angle"), dampers=dampers)
    return Model(sys_, Initial(theta0, omega0, coords), motor, d)


# ----------------------------------------------------------------------------- two dead points at once
TWO_DEAD_POINTS = dict(O2=(0.0, 0.0), O4=(0.4, -0.25), O6=(0.6, 0.25), L2=0.1, L3=0.3, L4B=0.25, L4C=0.3, L5=0.2, L6=0.2,
                       m=dict(crank=0.5, coupler=1.0, rocker=1.0, link5=0.5, link6=0.5),
                       J=dict(crank=0.0005, coupler=0.0075, rocker=0.0075, link5=0.002, link6=0.002))


def two_dead_points(theta0=0.0, omega0=0.0, tau=None):
    """Two four-bars in series (SI) whose dead points coincide at theta0 = 0: the crank
    O2->A (0.1) and coupler A->B (0.3) are stretched, so the rocker O4->B (0.25, C at 0.3
    along it) stands still; and O4, C and D are in line, so the second rocker O6->D (0.2)
    stands still to second order: its rate d theta6/dq vanishes like q^3. Coupler C->D
    (0.2). COMs at the links' midpoints (the rocker's at 0.15). B left of A -> O4, D left
    of C -> O6. Joints: O2 (ground, crank), A (crank, coupler), B (coupler, rocker),
    O4 (rocker, ground), C (rocker, link5), D (link5, link6), O6 (link6, ground)."""
    d = TWO_DEAD_POINTS
    L = dict(crank=d["L2"], coupler=d["L3"], rocker=d["L4C"], link5=d["L5"], link6=d["L6"])
    bodies = {b: _link(d["m"][b], L[b], d["J"][b]) for b in L}
    bodies["rocker"]["com_local"] = (0.15, 0.0)
    joints = [Revolute("O2", GROUND, "crank", d["O2"], (0, 0)),
              Revolute("A", "crank", "coupler", (d["L2"], 0), (0, 0)),
              Revolute("B", "coupler", "rocker", (d["L3"], 0), (d["L4B"], 0)),
              Revolute("O4", "rocker", GROUND, (0, 0), d["O4"]),
              Revolute("C", "rocker", "link5", (d["L4C"], 0), (0, 0)),
              Revolute("D", "link5", "link6", (d["L5"], 0), (d["L6"], 0)),
              Revolute("O6", "link6", GROUND, (0, 0), d["O6"])]
    O2, O4, O6 = (np.array(d[k]) for k in ("O2", "O4", "O6"))
    A = O2 + d["L2"] * np.array([np.cos(theta0), np.sin(theta0)])
    B = circle_intersection(A, d["L3"], O4, d["L4B"], left=True)
    C = O4 + d["L4C"] / d["L4B"] * (B - O4)
    D = circle_intersection(C, d["L5"], O6, d["L6"], left=True)
    coords = dict(crank=(*O2, theta0), coupler=(*A, _angle(A, B)), rocker=(*O4, _angle(O4, B)),
                  link5=(*C, _angle(C, D)), link6=(*O6, _angle(O6, D)))
    return Model(System(bodies, joints, ("crank", "angle")), Initial(theta0, omega0, coords), tau, d)


# ----------------------------------------------------------------------------- slider-driven
SLIDER_DRIVEN = dict(O3=(0.0, 0.3), L_rod=0.25, L_rocker=0.2, m_slider=0.5, m_rod=0.3,
                     m_rocker=0.4)


def slider_driven(x0=0.17, v0=0.0, tau=None):
    """Slider-driven rocker (SI), gravity (0, -9.81).  The driver is the slider, its
    coordinate q = x of the pin B on the global x axis (force tau along +x).
    Slider: m = 0.5, J = 0 (rotation locked), COM at B.  Rod B->C: 0.25 m, 0.3 kg;
    rocker O3->C with O3 = (0, 0.3): 0.2 m, 0.4 kg; uniform bars (COM at midpoint,
    J = m L^2 / 12).  Assembly: C left of the directed line B -> O3 (rocker hanging
    down; stable equilibrium near x = 0.23; singular at |O3 B| = 0.45, x = 0.335).
    From rest at x0 = 0.17 it oscillates between x = 0.17 and about 0.28.  Joints: P prismatic (ground, slider) along x,
    B (slider, rod), C (rod, rocker), O3 (rocker, ground)."""
    d = SLIDER_DRIVEN
    bodies = dict(slider=dict(mass=d["m_slider"], inertia=0.0, com_local=(0.0, 0.0)),
                  rod=_link(d["m_rod"], d["L_rod"]), rocker=_link(d["m_rocker"], d["L_rocker"]))
    joints = [Prismatic("P", GROUND, "slider", (0, 0), (0, 0), (1, 0)),
              Revolute("B", "slider", "rod", (0, 0), (0, 0)),
              Revolute("C", "rod", "rocker", (d["L_rod"], 0), (d["L_rocker"], 0)),
              Revolute("O3", "rocker", GROUND, (0, 0), d["O3"])]
    B, O3 = np.array([x0, 0.0]), np.array(d["O3"])
    C = circle_intersection(B, d["L_rod"], O3, d["L_rocker"], left=True)
    coords = dict(slider=(x0, 0.0, 0.0), rod=(*B, _angle(B, C)), rocker=(*O3, _angle(O3, C)))
    return Model(System(bodies, joints, ("slider", "x")), Initial(x0, v0, coords), tau, d)


# ----------------------------------------------------------------------------- quick-return
QUICK_RETURN = dict(O4=(0.0, -0.2), r=0.1, L_rocker=0.5, m_crank=0.3, m_block=0.2,
                    J_block=1e-4, m_rocker=1.0)


def quick_return(theta0=0.0, omega0=0.0, tau=None):
    """Crank and slotted rocker (inverted slider-crank, RPR dyad; SI, gravity (0, -9.81)).
    Crank O->A about O = (0, 0): r = 0.1, m = 0.3, uniform bar (J = m r^2 / 12).
    Block: frame and COM at the pin A, m = 0.2, J = 1e-4, turns with the rocker.
    Rocker O4->tip about O4 = (0, -0.2): 0.5 m, 1.0 kg, uniform bar; the block slides on
    the rocker's axis.  Joints: O (ground, crank), A (crank, block),
    P prismatic (rocker, block) along the rocker x axis through O4, O4 (ground, rocker)."""
    d = QUICK_RETURN
    bodies = dict(crank=_link(d["m_crank"], d["r"]),
                  block=dict(mass=d["m_block"], inertia=d["J_block"], com_local=(0.0, 0.0)),
                  rocker=_link(d["m_rocker"], d["L_rocker"]))
    joints = [Revolute("O", GROUND, "crank", (0, 0), (0, 0)),
              Revolute("A", "crank", "block", (d["r"], 0), (0, 0)),
              Prismatic("P", "rocker", "block", (0, 0), (0, 0), (1, 0)),
              Revolute("O4", GROUND, "rocker", d["O4"], (0, 0))]
    A = d["r"] * np.array([np.cos(theta0), np.sin(theta0)])
    phi = _angle(np.array(d["O4"]), A)
    coords = dict(crank=(0, 0, theta0), block=(*A, phi), rocker=(*d["O4"], phi))
    return Model(System(bodies, joints, ("crank", "angle")), Initial(theta0, omega0, coords), tau, d)


# ----------------------------------------------------------------------------- N four-bar
def n_four_bar(N):
    """IFToMM A02 N-four-bar: 2N+1 bars of 1 m, 1 kg, J = 1/12 about the centre.
    rocker{i}: O_i = (i, 0) -> B_i, i = 0..N (rocker0 drives, q = its angle);
    coupler{i}: B_i -> B_{i+1}, i = 0..N-1.  Joints O{i} (ground, rocker{i}),
    B{i}R (rocker{i}, coupler{i}) and B{i+1}L (coupler{i}, rocker{i+1}).
    Initial: rockers vertical up (q = pi/2), Bx velocity of B_0 = +1 (w = -1 rad/s).
    The partitioned integrator is singular when the rockers are horizontal; use
    n_four_bar_exact for the motion."""
    bodies, joints, coords = {}, [], {}
    for i in range(N + 1):
        bodies[f"rocker{i}"] = _link(1.0, 1.0)
        joints.append(Revolute(f"O{i}", GROUND, f"rocker{i}", (i, 0.0), (0, 0)))
        coords[f"rocker{i}"] = (i, 0.0, np.pi / 2)
    for i in range(N):
        bodies[f"coupler{i}"] = _link(1.0, 1.0)
        joints.append(Revolute(f"B{i}R", f"rocker{i}", f"coupler{i}", (1, 0), (0, 0)))
        joints.append(Revolute(f"B{i + 1}L", f"coupler{i}", f"rocker{i + 1}", (1, 0), (1, 0)))
        coords[f"coupler{i}"] = (i, 1.0, 0.0)
    return Model(System(bodies, joints, ("rocker0", "angle")), Initial(np.pi / 2, -1.0, coords))


def n_four_bar_alpha(N, g=G):
    """theta'' = -alpha cos(theta) for the parallelogram motion: N+1 rockers
    (J_O = 1/3) and N translating couplers (T = theta'^2 / 2 each) give
    I = (N+1)/3 + N and V = g sin(theta) ((N+1)/2 + N)."""
    return g * ((N + 1) / 2 + N) / ((N + 1) / 3 + N)


def n_four_bar_exact(N, t):
    """Exact rocker angle and rate (theta, omega) of the N-four-bar at times t.

    With beta = theta + pi/2 the equation is the pendulum beta'' = -alpha sin(beta),
    started inverted (beta = pi) with beta' = -1: a rotating pendulum with
    beta'^2 = (1 + 4 alpha) (1 - k^2 sin^2(beta/2)), k^2 = 4 alpha / (1 + 4 alpha), so
    beta / 2 = am(K(k) - Omega t | k^2), Omega = sqrt(1 + 4 alpha) / 2."""
    t = np.asarray(t, float)
    a = n_four_bar_alpha(N)
    m = 4 * a / (1 + 4 * a)
    Om = np.sqrt(1 + 4 * a) / 2
    sn, cn, dn, ph = ellipj(ellipk(m) - Om * t, m)
    return 2 * ph - np.pi / 2, -2 * Om * dn


def n_four_bar_ode(N, t, rtol=1e-13, atol=1e-14):
    """The same motion by integrating theta'' = -alpha cos(theta) (cross-check)."""
    a = n_four_bar_alpha(N)
    t = np.asarray(t, float)
    sol = solve_ivp(lambda _, y: [y[1], -a * np.cos(y[0])], (0.0, t[-1]), [np.pi / 2, -1.0],
                    method="DOP853", t_eval=t, rtol=rtol, atol=atol)
    return sol.y[0], sol.y[1]


def n_four_bar_coords(N, theta):
    """Frame coordinates of the parallelogram configuration at rocker angle theta."""
    c, s = np.cos(theta), np.sin(theta)
    coords = {f"rocker{i}": (i, 0.0, theta) for i in range(N + 1)}
    coords.update({f"coupler{i}": (i + c, s, 0.0) for i in range(N)})
    return coords
