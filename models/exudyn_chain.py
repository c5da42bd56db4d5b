"""The arm's chain in Exudyn: one KinematicTree on a generic ODE2 node, with sensors on every link.

Built once per `Simulation` from `mechanics.ChainArrays`; a changed link length, mass, radius or payload
only updates the item parameters (no rebuild, tested). The sensors are not read in a run (the pose rows
come from the numba forward kinematics over the same arrays); they are the independent cross-check.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

import numpy as np

from . import chain_dynamics
from .mechanics import ChainArrays

_EXU: Any = None


def exudyn() -> Any:
    """The exudyn module, imported on first use; the faster build (no range checks) unless exudyn was
    already imported by someone else (the two builds cannot share a process)."""
    global _EXU
    if _EXU is None:
        if "exudyn" not in sys.modules:
            sys.exudynFast = True  # type: ignore[attr-defined]  # read by exudyn's __init__
        import exudyn as exu

        _EXU = exu
    return _EXU


class ExudynChain:
    """The Exudyn system of one arm: `mbs` (the MainSystem), `kt` (the KinematicTree object number)."""

    def __init__(
        self,
        mech: ChainArrays,
        tool_local: np.ndarray,
        gravity: np.ndarray,
        prestep: Callable[[Any, float], bool],
    ) -> None:
        """`gravity`: m/s^2 in world axes, the model's (the `gravity.*` parameters); the drives' in-step
        load predictor (chain_dynamics.bias_forces) takes the same vector."""
        exu = exudyn()
        from exudyn.itemInterface import NodeGenericODE2, ObjectKinematicTree, SensorKinematicTree

        pre_R, pre_p, masses, coms, inertias = mech
        n = masses.shape[0]
        self.n = n
        self.SC: Any = exu.SystemContainer()
        mbs = self.SC.AddSystem()
        self.node = mbs.AddNode(
            NodeGenericODE2(
                referenceCoordinates=[0.0] * n,
                initialCoordinates=[0.0] * n,
                initialCoordinates_t=[0.0] * n,
                numberOfODE2Coordinates=n,
            )
        )
        self.kt = mbs.AddObject(
            ObjectKinematicTree(
                nodeNumber=self.node,
                jointTypes=[exu.JointType.RevoluteZ] * n,
                linkParents=list(range(-1, n - 1)),
                jointHTs=_joint_hts(mech),
                linkInertiasCOM=exu.Matrix3DList([inertias[i] for i in range(n)]),
                linkCOMs=exu.Vector3DList([coms[i] for i in range(n)]),
                linkMasses=list(masses),
                jointForceVector=[0.0] * n,
                gravity=[float(g) for g in gravity],
            )
        )
        self.sens_p: list[Any] = []
        self.sens_r: list[Any] = []
        for i in range(n):
            for lst, ovt in (
                (self.sens_p, exu.OutputVariableType.Position),
                (self.sens_r, exu.OutputVariableType.RotationMatrix),
            ):
                lst.append(
                    mbs.AddSensor(
                        SensorKinematicTree(
                            objectNumber=self.kt,
                            linkNumber=i,
                            localPosition=[0.0, 0.0, 0.0],
                            outputVariableType=ovt,
                            writeToFile=False,
                            storeInternal=False,
                        )
                    )
                )
        self.sens_tool = mbs.AddSensor(
            SensorKinematicTree(
                objectNumber=self.kt,
                linkNumber=n - 1,
                localPosition=list(tool_local),
                outputVariableType=exu.OutputVariableType.Position,
                writeToFile=False,
                storeInternal=False,
            )
        )
        mbs.SetPreStepUserFunction(prestep)
        mbs.Assemble()
        self.mbs: Any = mbs

    def close(self) -> None:
        """Drop the system (and with it the PreStep function's reference to the simulation)."""
        self.mbs = None
        self.SC = None

    def update(self, mech: ChainArrays, tool_local: np.ndarray) -> None:
        """New link data into the existing items (between runs): no rebuild, no new Assemble."""
        exu = exudyn()
        pre_R, pre_p, masses, coms, inertias = mech
        mbs = self.mbs
        mbs.SetObjectParameter(self.kt, "jointHTs", _joint_hts(mech))
        mbs.SetObjectParameter(self.kt, "linkMasses", list(masses))
        mbs.SetObjectParameter(self.kt, "linkCOMs", exu.Vector3DList([coms[i] for i in range(self.n)]))
        mbs.SetObjectParameter(
            self.kt, "linkInertiasCOM", exu.Matrix3DList([inertias[i] for i in range(self.n)])
        )
        mbs.SetSensorParameter(self.sens_tool, "localPosition", list(tool_local))

    def set_gravity(self, gravity: np.ndarray) -> None:
        self.mbs.SetObjectParameter(self.kt, "gravity", [float(g) for g in gravity])

    def sensor_poses(self, Rrpy: np.ndarray) -> np.ndarray:
        """Link and tool poses now (rows x, y, z, qw, qx, qy, qz), read from the Exudyn sensors: the
        cross-check of `chain_dynamics.pose_rows`. `Rrpy` turns each joint frame into its link frame."""
        mbs = self.mbs
        n = self.n
        Rs = np.zeros((n + 1, 3, 3))
        out = np.zeros((n + 1, 7))
        for i in range(n):
            out[i, :3] = mbs.GetSensorValues(self.sens_p[i])
            Rs[i] = np.asarray(mbs.GetSensorValues(self.sens_r[i])).reshape(3, 3) @ Rrpy[i]
        Rs[n] = Rs[n - 1]
        out[n, :3] = mbs.GetSensorValues(self.sens_tool)
        quats = np.zeros((n + 1, 4))
        chain_dynamics.quats_from_matrices(Rs, quats)
        out[:, 3:] = quats
        return out


def _joint_hts(mech: ChainArrays) -> list[Any]:
    """The joint frames as homogeneous transforms (exudyn.HT where this Exudyn has it)."""
    exu = exudyn()
    pre_R, pre_p = mech.pre_R, mech.pre_p
    out = []
    for i in range(pre_R.shape[0]):
        T = np.eye(4)
        T[:3, :3] = pre_R[i]
        T[:3, 3] = pre_p[i]
        out.append(exu.HT(T) if hasattr(exu, "HT") else T)
    return out
