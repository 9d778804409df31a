"""MuJoCo (MJCF) models of the Watt six-bar and the N-four-bar, for benchmarks.

The mechanisms come from the independent reference ``tests/joint_reference.py``
(same bodies, masses, inertias and joint points).  Loops are cut into a tree of
hinges (all axes along z, plane x-y, gravity -9.81 along y) and closed again with
``connect`` equality constraints between two sites, one on each side of each cut joint.

The XML is written at a reference configuration (the driver at ``theta_ref``, all
hinges at qpos = 0); ``simulate_mujoco`` reads the mechanism's name and ``theta_ref``
from the model's <custom> section, assembles the reference at ``theta0`` and sets the
hinge angles (and rates) consistently with the constraints.
"""

from __future__ import annotations

import os
import sys

import mujoco
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))
import joint_reference as jr  # noqa: E402

INTEGRATORS = {"euler": mujoco.mjtIntegrator.mjINT_EULER, "rk4": mujoco.mjtIntegrator.mjINT_RK4,
               "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
               "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST}

WATT_TREE = dict(crank=jr.GROUND, coupler="crank", link5="coupler", rocker=jr.GROUND, link6="rocker")
WATT_CUTS = ("B", "E")


def _n_four_bar_tree(N):
    tree = {}
    for i in range(N + 1):
        tree[f"rocker{i}"] = jr.GROUND
        if i < N:
            tree[f"coupler{i}"] = f"rocker{i}"
    return tree, tuple(f"B{i + 1}L" for i in range(N))


def _reference(name, N):
    """Reference model and a frame-coordinate function of the driver angle."""
    if name == "watt_sixbar":
        return jr.watt_sixbar(), lambda th: jr.watt_sixbar(th).initial.coords
    if name == "n_four_bar":
        return jr.n_four_bar(N), lambda th: jr.n_four_bar_coords(N, th)
    raise ValueError(name)


def _f(*v):
    return " ".join(repr(float(x)) for x in v)  # shortest exact round-trip


def _build(name, N, theta_ref, tree, cuts, dt, integrator, solref, solimp, tolerance):
    model, coords_of = _reference(name, N)
    sys_ = model.system
    coords = coords_of(theta_ref)
    joints = {j.name: j for j in sys_.joints}
    sites = {}  # body -> list of (site name, local point)
    for c in cuts:
        j = joints[c]
        sites.setdefault(j.body_i, []).append((f"{c}_{j.body_i}", j.s_i))
        sites.setdefault(j.body_j, []).append((f"{c}_{j.body_j}", j.s_j))

    def body_xml(b, indent):
        p = tree[b]
        xb, yb, tb = coords[b]
        if p == jr.GROUND:
            pos, rel = (xb, yb), tb
        else:  # child frame in the parent frame; the hinge sits at the child's origin
            xp, yp, tp = coords[p]
            pos, rel = jr._rot(tp).T @ np.array([xb - xp, yb - yp]), tb - tp
        bd = sys_.body_data[b]
        J, (cx, cy) = bd["inertia"], bd["com_local"]
        tip = max((np.hypot(*s) for _, s in sites.get(b, [])), default=2 * np.hypot(cx, cy))
        pad = " " * indent
        out = [f'{pad}<body name="{b}" pos="{_f(*pos, 0)}" euler="0 0 {rel:.17g}">',
               f'{pad}  <joint name="{b}" type="hinge" pos="0 0 0" axis="0 0 1"/>',
               # only Izz acts about the z hinges; Ixx + Iyy >= Izz must hold for MuJoCo
               f'{pad}  <inertial pos="{_f(cx, cy, 0)}" mass="{bd["mass"]:.17g}" '
               f'diaginertia="{_f(J / 2, J / 2, J)}"/>',
               f'{pad}  <geom type="capsule" fromto="0 0 0 {tip:.6g} 0 0" size="0.02" '
               f'contype="0" conaffinity="0"/>']
        out += [f'{pad}  <site name="{sn}" pos="{_f(*s, 0)}"/>' for sn, s in sites.get(b, [])]
        for child in (c for c, pc in tree.items() if pc == b):
            out += body_xml(child, indent + 2)
        return out + [f"{pad}</body>"]

    world = [line for b, p in tree.items() if p == jr.GROUND for line in body_xml(b, 4)]
    sr = solref if solref is not None else (2 * dt, 1.0)
    eqs = [f'    <connect name="{c}" site1="{c}_{joints[c].body_i}" site2="{c}_{joints[c].body_j}" '
           f'solref="{_f(*sr)}" solimp="{_f(*solimp)}"/>' for c in cuts]
    return "\n".join([
        f'<mujoco model="{name}">',
        '  <compiler angle="radian" inertiafromgeom="false"/>',
        f'  <option timestep="{dt:.17g}" integrator="{integrator}" gravity="0 -9.81 0" '
        f'tolerance="{tolerance:.3g}" iterations="200">',
        '    <flag contact="disable"/>',
        "  </option>",
        "  <custom>",
        f'    <text name="reference" data="{name}"/>',
        f'    <text name="driver" data="{sys_.driver[0]}"/>',
        f'    <numeric name="theta_ref" data="{theta_ref:.17g}"/>',
        f'    <numeric name="N" data="{N}"/>',
        "  </custom>",
        "  <worldbody>", *world, "  </worldbody>",
        "  <equality>", *eqs, "  </equality>",
        "</mujoco>"])


def watt_sixbar_xml(dt=1e-4, integrator="RK4", solref=None, solimp=(0.9999, 0.9999, 0.001),
                    theta_ref=0.0, tolerance=1e-10):
    """Watt six-bar: tree crank -> coupler -> link5 and rocker -> link6 from the ground,
    loops closed at B (coupler-rocker) and E (link5-link6).  solref defaults to
    (2 dt, 1): time constant 2 dt, critical damping."""
    return _build("watt_sixbar", 0, theta_ref, WATT_TREE, WATT_CUTS, dt, integrator, solref,
                  solimp, tolerance)


def n_four_bar_xml(N, dt=1e-3, integrator="RK4", solref=None, solimp=(0.9999, 0.9999, 0.001),
                   tolerance=1e-10):
    """IFToMM A02 N-four-bar: rocker{i} hinged to the ground at (i, 0), coupler{i}
    hinged to rocker{i} at B_i; loops closed at B_{i+1} (coupler{i} tip - rocker{i+1}
    tip).  Built with the rockers vertical (theta_ref = pi/2)."""
    tree, cuts = _n_four_bar_tree(N)
    return _build("n_four_bar", N, np.pi / 2, tree, cuts, dt, integrator, solref, solimp, tolerance)


def _text(m, name):
    i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TEXT, name)
    a = m.text_adr[i]
    return bytes(m.text_data[a: a + m.text_size[i] - 1]).decode()


def initial_data(m, theta0, omega0=0.0):
    """MjData with hinge angles and rates assembled from the reference at driver angle
    theta0 and rate omega0 (constraints satisfied to rounding).  Returns (data, qpos
    address of the driver hinge, theta_ref)."""
    name, driver = _text(m, "reference"), _text(m, "driver")
    theta_ref, N = m.numeric("theta_ref").data[0], int(m.numeric("N").data[0])
    ref, coords_of = _reference(name, N)
    s = ref.system
    c0, cref = coords_of(theta0), coords_of(theta_ref)
    zd = s.influence(s.newton(theta0, s.to_internal(c0))[0]) * omega0
    d = mujoco.MjData(m)
    for b in s.names:
        jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, b)
        bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, b)
        p = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, m.body_parentid[bid])
        p = p if p in s.idx else jr.GROUND
        rel = lambda c: c[b][2] - (0.0 if p == jr.GROUND else c[p][2])  # noqa: E731
        dq = rel(c0) - rel(cref)
        # hinge angles are only defined mod 2 pi; keep the driver's turn count exact
        d.qpos[m.jnt_qposadr[jid]] = dq if b == driver else np.angle(np.exp(1j * dq))
        w = lambda k: 0.0 if k == jr.GROUND else zd[3 * s.idx[k] + 2]  # noqa: E731
        d.qvel[m.jnt_dofadr[jid]] = w(b) - w(p)
    qadr = m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, driver)]
    return d, qadr, theta_ref


def simulate_mujoco(model_xml, theta0, t1, dt=None, integrator=None, omega0=0.0):
    """Integrate from the assembled configuration with the driver at theta0 (rate
    omega0) to t1.  dt / integrator override the XML's timestep / integrator (solref
    is left as written).  Returns (t, theta): times and driver angle after each step,
    starting with (0, theta0)."""
    m = mujoco.MjModel.from_xml_string(model_xml)
    if dt is not None:
        m.opt.timestep = dt
    if integrator is not None:
        m.opt.integrator = INTEGRATORS[integrator.lower()]
    d, qadr, theta_ref = initial_data(m, theta0, omega0)
    nstep = int(round(t1 / m.opt.timestep))
    th = np.empty(nstep + 1)
    th[0] = d.qpos[qadr] + theta_ref
    for k in range(1, nstep + 1):
        mujoco.mj_step(m, d)
        th[k] = d.qpos[qadr] + theta_ref
    return np.arange(nstep + 1) * m.opt.timestep, th  # k dt: no accumulated rounding
