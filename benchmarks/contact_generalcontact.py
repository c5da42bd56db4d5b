"""Exudyn's GeneralContact on an ObjectKinematicTree: does it work, how exact is it, what does it cost.

Spheres sit on tree links through MarkerKinematicTreeRigid + GeneralContact.AddSphereWithMarker; the ground
is a 2 m x 2 m x 0.04 m box mesh (AddTrianglesRigidBodyBased, staticTriangles=True). GeneralContact puts the
two sides' stiffnesses in series and adds their dampings: k = 1e5 N/m, d = 100 N s/m take 2e5 and 50 a side.
Then a Panda-like 7-joint tree (PD-held pose, 28 spheres), and the same contact as a numba kernel.
Run: .venv/bin/python benchmarks/contact_generalcontact.py (about 10 s of CPU, one core).
"""

from __future__ import annotations

import time
from typing import Any

import exudyn as exu
import exudyn.graphics as gr
import numba
import numpy as np
from exudyn.itemInterface import MarkerBodyRigid as MBody
from exudyn.itemInterface import MarkerKinematicTreeRigid as MTree
from exudyn.itemInterface import NodeGenericODE2, ObjectGround, ObjectKinematicTree, SensorMarker
from exudyn.utilities import InertiaSphere

K, D, G, R = 1.0e5, 100.0, 9.81, 0.05  # effective contact stiffness, damping; gravity; sphere radius
DH = [(0, 0.333, 0), (0, 0, -np.pi / 2), (0, 0.316, np.pi / 2), (0.0825, 0, np.pi / 2),
      (-0.0825, 0.384, -np.pi / 2), (0, 0, np.pi / 2), (0.088, 0, np.pi / 2)]  # fmt: skip
MASSES = [4.97, 0.65, 3.23, 3.59, 1.23, 1.67, 1.44]
POSE = np.array([0.0, 0.3, 0.0, -2.2, 0.0, 2.5 - np.pi / 2, 0.8])  # tool horizontal, 0.264 m high
KP = np.array([600.0, 600.0, 400.0, 400.0, 100.0, 100.0, 30.0])
FAR = -0.3  # a ground top far below every sphere of the arm


def ht(a: float, d: float, alpha: float) -> np.ndarray:
    """Craig DH step RotX(alpha) TransX(a) TransZ(d) as a 4x4 matrix."""
    c, s = np.cos(alpha), np.sin(alpha)
    return np.array([[1, 0, 0, a], [0, c, -s, -s * d], [0, s, c, c * d], [0, 0, 0, 1.0]])


HTS = np.array([ht(*p) for p in DH])
SPHERES = [(0, np.zeros(3))]  # (link, local centre): one at joint 1, then ~every 4 cm to the next joint
for _i in range(7):
    _p = HTS[_i + 1, :3, 3] if _i < 6 else np.array([0.0, 0.0, 0.2])  # last link: a 0.2 m tool
    _n = round(float(np.linalg.norm(_p)) / 0.04)
    SPHERES += [(_i, _p * k / _n) for k in range(1, _n + 1)]


def add_contact(mbs: Any, markers: list[Any], z_top: float, ks: float = 2 * K, ds: float = D / 2) -> Any:
    gc = mbs.AddGeneralContact()
    gc.SetFrictionPairings(np.zeros((1, 1)))
    gc.SetSearchTreeCellSize([8, 8, 4])
    gc.SetSearchTreeBox([-0.8, -1.2, -0.6], [1.4, 1.2, 1.4])
    gc.sphereSphereContact = False  # spheres of adjacent links overlap; there is no per-pair filter
    gc.computeContactForces = True
    gnd = mbs.AddMarker(MBody(bodyNumber=mbs.AddObject(ObjectGround()), localPosition=[0, 0, 0]))
    pts, trigs = gr.ToPointsAndTrigs(gr.Brick(centerPoint=[0.3, 0.0, z_top - 0.02], size=[2.0, 2.0, 0.04]))
    gc.AddTrianglesRigidBodyBased(gnd, ks, ds, 0, pts, trigs, staticTriangles=True)
    for m in markers:
        gc.AddSphereWithMarker(m, R, ks, ds, 0)
    return gc


def tree(mbs: Any, types: list[Any], hts: Any, masses: list[float], coms: list[Any], q0: Any, v0: Any,
         **pd: Any) -> Any:  # fmt: skip
    n = len(types)
    node = mbs.AddNode(NodeGenericODE2(referenceCoordinates=[0.0] * n, initialCoordinates=list(q0),
                                       initialCoordinates_t=list(v0), numberOfODE2Coordinates=n))  # fmt: skip
    lists: Any = exu  # the stubs give Matrix3DList/Vector3DList no arguments; they take a list
    inertias = lists.Matrix3DList([m * np.diag([0.01, 0.01, 0.005]) for m in masses])
    return mbs.AddObject(ObjectKinematicTree(
        nodeNumber=node, jointTypes=types, linkParents=list(range(-1, n - 1)), jointHTs=list(hts),
        linkMasses=masses, linkCOMs=lists.Vector3DList(coms), linkInertiasCOM=inertias, gravity=[0, 0, -G],
        **pd))  # fmt: skip


def arm(z_top: float | None, nsph: int = len(SPHERES)) -> tuple[Any, Any, Any, list[Any]]:
    """The 7-joint tree held at POSE by its PD with nsph sphere markers; GeneralContact unless z_top=None."""
    SC = exu.SystemContainer()
    mbs = SC.AddSystem()
    coms = [list(HTS[i + 1, :3, 3] / 2) for i in range(6)] + [[0.0, 0.0, 0.1]]
    kt = tree(mbs, [exu.JointType.RevoluteZ] * 7, HTS, MASSES, coms, POSE, [0.0] * 7,
              jointPositionOffsetVector=list(POSE), jointVelocityOffsetVector=[0.0] * 7,
              jointPControlVector=list(KP), jointDControlVector=list(0.1 * KP))  # fmt: skip
    ms = [mbs.AddMarker(MTree(objectNumber=kt, linkNumber=i, localPosition=p)) for i, p in SPHERES[:nsph]]
    gc = None if z_top is None else add_contact(mbs, ms, z_top)
    mbs.Assemble()
    return SC, mbs, gc, ms


def single(kind: str, ks: float = 2 * K, ds: float = D / 2, dz0: float = 0.0, v0: float = 0.0,
           contact: bool = True, n: int = 1) -> tuple[Any, Any, Any]:  # fmt: skip
    """1 kg body on the ground (top z = 0) with n spheres of radius R in a row along x (a tree: n = 1):
    rigid body, 1-link prismatic-z tree, or revolute-y tree (lever: COM at 0.25 m, sphere at 0.5 m); the
    spheres' centres start at z = R - dz0, speed -v0."""
    SC = exu.SystemContainer()
    mbs = SC.AddSystem()
    if kind == "rigid body":
        b = mbs.CreateRigidBody(inertia=InertiaSphere(1.0, R), referencePosition=[0, 0, R - dz0],
                                initialVelocity=[0, 0, -v0], gravity=[0, 0, -G],
                                nodeType=exu.NodeType.RotationRotationVector)  # fmt: skip
        xs = 0.04 * (np.arange(n) - (n - 1) / 2)
        ms = [mbs.AddMarker(MBody(bodyNumber=b, localPosition=[x, 0, 0])) for x in xs]
    else:
        lever = kind == "tree lever"
        jt = exu.JointType.RevoluteY if lever else exu.JointType.PrismaticZ
        kt = tree(mbs, [jt], [ht(0, R, 0)], [1.0], [[0.25 * lever, 0, 0]], [-dz0], [-v0])
        ms = [mbs.AddMarker(MTree(objectNumber=kt, linkNumber=0, localPosition=[0.5 * lever, 0, 0]))]
    if contact:
        add_contact(mbs, ms, 0.0, ks, ds)
    out = exu.OutputVariableType.Position
    s = mbs.AddSensor(SensorMarker(markerNumber=ms[0], outputVariableType=out, storeInternal=True))
    mbs.Assemble()
    return SC, mbs, s


def run(mbs: Any, h: float, t_end: float) -> float:
    """RK4 at step h up to t_end; returns the CPU time (s): the machine is shared."""
    s = exu.SimulationSettings()
    s.timeIntegration.solverType = exu.DynamicSolverType.RK44
    s.timeIntegration.numberOfSteps = round(t_end / h)
    s.timeIntegration.endTime = t_end
    s.solution.file.write = False
    s.solution.sensors.writePeriod = h
    t0 = time.process_time()
    exu.SolveDynamic(mbs, s)
    return time.process_time() - t0


def best(build: Any, reps: int = 3) -> tuple[str, Any]:
    """Best CPU and wall ms per simulated second (h = 1e-3 s) of `reps` fresh builds; the last system."""
    cpu, wall = [], []
    for _ in range(reps):
        built = build()
        t0 = time.perf_counter()
        cpu.append(run(built[1], 1e-3, 1.0) * 1e3)
        wall.append((time.perf_counter() - t0) * 1e3)
    return f"{min(cpu):6.1f} (wall {min(wall):6.1f})", built


def pos(mbs: Any, ms: list[Any]) -> np.ndarray:
    return np.array([mbs.GetMarkerOutput(m, exu.OutputVariableType.Position) for m in ms])


@numba.njit(cache=False)
def penalty_tau(q: np.ndarray, qd: np.ndarray, hts: np.ndarray, link: np.ndarray, loc: np.ndarray,
                z_top: float, k: float, d: float, r: float) -> np.ndarray:  # fmt: skip
    """Joint torques of the spheres' penalty forces against the plane z = z_top (the box's top face)."""
    n = q.shape[0]
    org, rot, tau = np.zeros((n, 3)), np.zeros((n, 3, 3)), np.zeros(n)
    Rp, op, A = np.eye(3), np.zeros(3), np.zeros((3, 3))
    for i in range(n):  # link frame i = parent frame * hts[i] * RotZ(q_i)
        for a in range(3):
            org[i, a] = op[a] + Rp[a, 0] * hts[i, 0, 3] + Rp[a, 1] * hts[i, 1, 3] + Rp[a, 2] * hts[i, 2, 3]
            for b in range(3):
                A[a, b] = Rp[a, 0] * hts[i, 0, b] + Rp[a, 1] * hts[i, 1, b] + Rp[a, 2] * hts[i, 2, b]
        c, s = np.cos(q[i]), np.sin(q[i])
        for a in range(3):
            rot[i, a, 0], rot[i, a, 1] = c * A[a, 0] + s * A[a, 1], c * A[a, 1] - s * A[a, 0]
            rot[i, a, 2] = A[a, 2]
        Rp, op = rot[i], org[i]
    for j in range(link.shape[0]):
        li, lp = link[j], loc[j]
        p = org[li] + rot[li, :, 0] * lp[0] + rot[li, :, 1] * lp[1] + rot[li, :, 2] * lp[2]
        pen = z_top - (p[2] - r)
        if pen <= 0.0:
            continue
        vz = 0.0  # z of sum_i qd_i axis_i x (p - o_i); axis_i = rot[i, :, 2]
        for i in range(li + 1):
            vz += qd[i] * (rot[i, 0, 2] * (p[1] - org[i, 1]) - rot[i, 1, 2] * (p[0] - org[i, 0]))
        fz = k * pen - d * vz  # like GeneralContact (explicit): acts while penetrating, not clamped
        for i in range(li + 1):  # tau_i = axis_i . ((p - o_i) x f), f = (0, 0, fz)
            tau[i] += fz * (rot[i, 0, 2] * (p[1] - org[i, 1]) - rot[i, 1, 2] * (p[0] - org[i, 0]))
    return tau


@numba.njit(cache=False)
def kernel_calls(n_calls: int, q: np.ndarray, qd: np.ndarray, link: np.ndarray, loc: np.ndarray,
                 z_top: float) -> float:  # fmt: skip
    acc = 0.0
    for _ in range(n_calls):
        acc += penalty_tau(q, qd, HTS, link, loc, z_top, K, D, R)[0]
    return acc


def main() -> None:
    print(f"exudyn {exu.__version__}, RK4, one thread; k = {K:g} N/m, d = {D:g} N s/m effective")
    print("1) static penetration of the resting 1 kg sphere (h = 1e-4 s, after 1 s) [m]")
    for kind, want in (("rigid body", G / K), ("tree prismatic", G / K), ("tree lever", G / K / 2)):
        for ks in (K, 2 * K):
            _, mbs, s = single(kind, ks=ks)
            run(mbs, 1e-4, 1.0)
            pen = R - mbs.GetSensorStoredData(s)[-1, 3]
            print(f"   {kind:15s} k a side {ks:7.0f}: {pen:.6e}  (expected at k_eff = K: {want:.6e})")
    print("2) effective damping from the decay of a 1 mm/s oscillation at rest (h = 1e-5 s) [N s/m]")
    for kind in ("rigid body", "tree prismatic"):
        _, mbs, s = single(kind, dz0=G / K, v0=1e-3)
        run(mbs, 1e-5, 0.06)
        dat = mbs.GetSensorStoredData(s)
        t, y = dat[:, 0], (R - G / K) - dat[:, 3]
        pk = [i for i in range(1, len(y) - 1) if y[i - 1] < y[i] >= y[i + 1]]
        d_eff = 2.0 * np.log(y[pk[0]] / y[pk[1]]) / (t[pk[1]] - t[pk[0]])  # 2 m sigma, m = 1 kg
        print(f"   {kind:15s} d a side {D / 2:g}: {d_eff:.2f}")
    print("3) CPU (wall) cost per simulated second, h = 1e-3 s, best of 3 [ms]")
    for kind in ("rigid body", "tree prismatic"):
        a, _ = best(lambda kind=kind: single(kind, contact=False))
        b, _ = best(lambda kind=kind: single(kind))
        print(f"   one sphere, {kind:14s}: no GeneralContact {a}, resting in contact {b}")
    print(f"   rigid body, 28 spheres all resting in contact: {best(lambda: single('rigid body', n=28))[0]}")
    SC0, mbs0, _, ms0 = arm(None)
    z_top = pos(mbs0, ms0)[:, 2].min() - R  # ground touching the lowest sphere at POSE
    print(f"   7-joint tree, {len(SPHERES)} sphere markers, no GeneralContact: {best(lambda: arm(None))[0]}")
    for nsph in (0, 7, len(SPHERES)):
        cost, _ = best(lambda nsph=nsph: arm(FAR, nsph))
        print(f"   7-joint tree + GeneralContact, {nsph:2d} spheres, no contact: {cost}")
    con, (_, mbs, gc, ms) = best(lambda: arm(z_top))
    gaps = pos(mbs, ms)[:, 2] - R - z_top
    print(f"   7-joint tree + GeneralContact, 28 spheres, on the box: {con}  ({(gaps < 0).sum()} spheres in"
          f" contact, max penetration {-gaps.min():.3e} m)")  # fmt: skip
    print("4) stability of the arm resting on the box, 1 s at step h (baseline: no GeneralContact)")
    for h in (1e-3, 1.5e-3, 1.75e-3, 2e-3, 3e-3):
        (_, m1, _, _), (_, m2, _, _) = arm(z_top), arm(None)
        for m in (m1, m2):
            run(m, h, 1.0)
        ok = [("stable" if np.isfinite(m.systemData.GetODE2Coordinates()).all() else "NaN") for m in (m1, m2)]
        print(f"   h = {h:.2e}: contact {ok[0]}, baseline {ok[1]}")
    q, qd = np.array(mbs.systemData.GetODE2Coordinates()), np.array(mbs.systemData.GetODE2Coordinates_t())
    link, loc = np.array([i for i, _ in SPHERES]), np.array([p for _, p in SPHERES])
    tau = penalty_tau(q, qd, HTS, link, loc, z_top, K, D, R)
    ref = np.array(gc.GetSystemODE2RhsContactForces(copy=True))
    print(f"5) numba penalty kernel (FK, sphere vs plane z = top, J^T f), {len(SPHERES)} spheres")
    err = np.abs(tau - ref).max()
    print(f"   |tau_numba - GeneralContact's contact forces| at the arm's final state: {err:.2e} N m"
          f" (largest |tau| {np.abs(ref).max():.2f})")  # fmt: skip
    for name, zt in (("no contact", FAR), ("on the box", z_top)):
        kernel_calls(10, q, qd, link, loc, zt)
        t0 = time.process_time()
        kernel_calls(40000, q, qd, link, loc, zt)
        us = (time.process_time() - t0) / 40000 * 1e6
        print(f"   {name}: {us:.2f} us a call = {us * 4:.2f} ms CPU per simulated second (4000 calls)")


if __name__ == "__main__":
    main()
