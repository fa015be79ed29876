"""Five-axis EDM kinematics after Huang & Liu eq. 2.

Axes: X, Y, Z linear [mm]; A [rad] about X, carrying the blisk; C [rad]
about the tool's Z axis, carrying the electrode. Axis values are measured
from the final machining pose of the electrode in channel 0 (all zero there,
as Huang's nodes start at the end position): the electrode frame's pose in
the workpiece frame W is

    T_WE(q) = R_x(A - A0) . T(X, Y, Z) . T_final . T(c) . R_z(C) . T(-c)

with ``c`` the C axis' pivot in the electrode frame (Huang's T_d) and
``T_final`` the electrode's final pose in channel 0. Channel k is selected
by A = A0 + 2*pi*k/N (Huang III.A). Huang's H_x H_y H_z H_rc product acting
in the tool frame, conjugated by H_wt, is exactly this composition.
"""

from dataclasses import dataclass, field

import numpy as np

from ..geometry.frames import rotation_about_x

AXES_5 = ("X", "Y", "Z", "A", "C")


def _rot_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    m = np.zeros(np.shape(angle) + (4, 4))
    m[..., 0, 0], m[..., 0, 1], m[..., 1, 0], m[..., 1, 1] = c, -s, s, c
    m[..., 2, 2] = m[..., 3, 3] = 1.0
    return m


def _rot_x(angle):
    c, s = np.cos(angle), np.sin(angle)
    m = np.zeros(np.shape(angle) + (4, 4))
    m[..., 1, 1], m[..., 1, 2], m[..., 2, 1], m[..., 2, 2] = c, -s, s, c
    m[..., 0, 0] = m[..., 3, 3] = 1.0
    return m


@dataclass(frozen=True)
class FiveAxisKinematics:
    """Forward and inverse kinematics of the X, Y, Z, A, C machine for one electrode.

    Parameters
    ----------
    final_pose : (4, 4) float
        Electrode frame -> W at the machining pose in channel 0.
    pitch : float
        Blade pitch 2*pi/N [rad].
    c_pivot : (3,) float
        C axis pivot in the electrode frame [mm].
    a_zero : float
        A0 [rad].
    """

    final_pose: np.ndarray
    pitch: float
    c_pivot: tuple = (0.0, 0.0, 0.0)
    a_zero: float = 0.0
    axis_names: tuple = field(default=AXES_5)

    def forward(self, q):
        """Electrode poses in W for axis values.

        Parameters
        ----------
        q : (n, 5) float
            X, Y, Z [mm], A, C [rad].

        Returns
        -------
        poses : (n, 4, 4) float
        """
        q = np.atleast_2d(np.asanyarray(q, dtype=np.float64))
        c = np.asarray(self.c_pivot, dtype=np.float64)
        pivot, unpivot = np.eye(4), np.eye(4)
        pivot[:3, 3], unpivot[:3, 3] = c, -c
        inner = self.final_pose @ pivot @ _rot_z(q[:, 4]) @ unpivot      # (n, 4, 4)
        inner[:, :3, 3] += q[:, :3]
        return _rot_x(q[:, 3] - self.a_zero) @ inner

    def inverse(self, poses, channel=None):
        """Axis values reaching electrode poses in W.

        The rotation left after removing the A rotation must be a rotation about Z
        (what C can do); A is taken from ``channel`` when given, else solved.

        Returns
        -------
        q : (n, 5) float
        residual : (n,) float
            Frobenius norm of the rotation part this machine cannot reach (0 when exact).
        """
        poses = np.asanyarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        R0 = self.final_pose[:3, :3]
        out = np.empty((len(poses), 5))
        resid = np.empty(len(poses))
        for i, T in enumerate(poses):
            # R = Rx(a) R0 Rz(C): solve a, C from M = R0^T Rx(-a) R, which must be Rz(C)
            if channel is not None:
                a_rel = channel * self.pitch
            else:
                # choose a so that R0^T Rx(-a) R is a rotation about Z (what C can do)
                a_rel = _solve_a(T[:3, :3], R0)
            A = a_rel + self.a_zero
            Ra = rotation_about_x(-a_rel)
            local = Ra @ T
            M = R0.T @ local[:3, :3]
            C = np.arctan2(M[1, 0], M[0, 0])
            resid[i] = np.linalg.norm(M - _rot_z(C)[:3, :3])
            pivot_term = self.final_pose @ _pivot_matrix(self.c_pivot, C)
            out[i, :3] = local[:3, 3] - pivot_term[:3, 3]
            out[i, 3], out[i, 4] = A, C
        return out, resid


def _pivot_matrix(c_pivot, C):
    c = np.asarray(c_pivot, dtype=np.float64)
    pivot, unpivot = np.eye(4), np.eye(4)
    pivot[:3, 3], unpivot[:3, 3] = c, -c
    return pivot @ _rot_z(C) @ unpivot


def _solve_a(R, R0):
    """Angle a with R0^T Rx(-a) R a rotation about Z (closed form on the (3,3) element)."""
    # M = R0^T Rx(-a) R; M[2, 2] = 1 for a z-rotation: maximise e3^T R0^T Rx(-a) R e3
    u = R0[:, 2]            # R0 e3
    v = R[:, 2]             # R e3
    # u . Rx(-a) v = u0 v0 + cos a (u1 v1 + u2 v2) + sin a (u1 v2 - u2 v1)
    return float(np.arctan2(u[1] * v[2] - u[2] * v[1], u[1] * v[1] + u[2] * v[2]))


def state_poses(final_pose, position, a, c, b=None):
    """Electrode poses from planner states (a machine with the C/B pivot at the electrode origin).

    The pose is ``R_x(A) . T(X, Y, Z) . T_final . R_z(C) . R_y(B)``; the planner
    works with the electrode origin's position ``p`` in W instead of the machine's
    X, Y, Z: ``p = R_x(A) (XYZ + t_final)``.

    Parameters
    ----------
    final_pose : (4, 4) float
    position : (n, 3) float
        Electrode origin in W [mm].
    a, c : (n,) float
        A and C [rad].
    b : (n,) float, optional
        B [rad] (six-axis machines).

    Returns
    -------
    poses : (n, 4, 4) float
    """
    position = np.atleast_2d(np.asanyarray(position, dtype=np.float64))
    a = np.atleast_1d(np.asanyarray(a, dtype=np.float64))
    c = np.atleast_1d(np.asanyarray(c, dtype=np.float64))
    rot = _rot_x(a)[:, :3, :3] @ final_pose[:3, :3] @ _rot_z(c)[:, :3, :3]
    if b is not None:
        rot = rot @ _rot_y(np.atleast_1d(np.asanyarray(b, dtype=np.float64)))[:, :3, :3]
    poses = np.zeros((len(position), 4, 4))
    poses[:, :3, :3] = rot
    poses[:, :3, 3] = position
    poses[:, 3, 3] = 1.0
    return poses


def state_axes(final_pose, position, a, c, b=None):
    """Machine axis values [X, Y, Z, A, C(, B)] of planner states (inverse of ``state_poses``)."""
    position = np.atleast_2d(np.asanyarray(position, dtype=np.float64))
    a = np.atleast_1d(np.asanyarray(a, dtype=np.float64))
    xyz = np.einsum("nji,nj->ni", _rot_x(a)[:, :3, :3], position) - final_pose[:3, 3]
    cols = [xyz, a[:, None], np.atleast_1d(c)[:, None]]
    if b is not None:
        cols.append(np.atleast_1d(b)[:, None])
    return np.hstack(cols)


def _rot_y(angle):
    c, s = np.cos(angle), np.sin(angle)
    m = np.zeros(np.shape(angle) + (4, 4))
    m[..., 0, 0], m[..., 0, 2], m[..., 2, 0], m[..., 2, 2] = c, s, -s, c
    m[..., 1, 1] = m[..., 3, 3] = 1.0
    return m


def axis_poses(final_pose, axis_names, q):
    """Electrode poses in W from machine axis values in the planner's convention.

    Inverse of :func:`state_axes` for the axis sets ("X", "Y", "Z", "C"),
    ("X", "Y", "Z", "A", "C") and ("X", "Y", "Z", "A", "C", "B").

    Parameters
    ----------
    final_pose : (4, 4) float
    axis_names : sequence of str
    q : (n, k) float
        Axis values [mm, rad] in the order of ``axis_names``.

    Returns
    -------
    (n, 4, 4) float
    """
    q = np.atleast_2d(np.asanyarray(q, dtype=np.float64))
    col = {name: q[:, i] for i, name in enumerate(axis_names)}
    zero = np.zeros(len(q))
    a = col.get("A", zero)
    xyz = np.stack([col["X"], col["Y"], col["Z"]], axis=1) + final_pose[:3, 3]
    position = np.einsum("nij,nj->ni", _rot_x(a)[:, :3, :3], xyz)
    return state_poses(final_pose, position, a, col["C"], col.get("B"))


def offset_axes(final_pose, axis_names, q, offset):
    """Axis values that move the electrode by ``offset`` [mm] in its own frame: axis_poses(result) equals
    axis_poses(q) @ T(offset) (a tool offset, e.g. the wear compensation along the front).

    The electrode origin is R_x(A) (X, Y, Z + t_final), so X, Y, Z change by R_x(A)^T R offset, with R the
    pose's rotation: only C (and B) turn it, A cancels. The other axes keep their values.
    """
    q = np.array(np.atleast_2d(q), dtype=np.float64, copy=True)
    names = list(axis_names)
    rot = axis_poses(final_pose, names, q)[:, :3, :3]
    a = q[:, names.index("A")] if "A" in names else np.zeros(len(q))
    move = np.einsum("nji,njk,k->ni", _rot_x(a)[:, :3, :3], rot, np.asarray(offset, dtype=np.float64))
    for i, name in enumerate(("X", "Y", "Z")):
        q[:, names.index(name)] += move[:, i]
    return q


def axes_to_poses(axis_names, axes, final_pose, channel, pitch):
    """Electrode poses in W from exported axis values: the machine's axis values measured from the final machining
    pose in channel 0 (``edm_planner.records.plan_export.AXES_CONVENTION``); a machine without A indexes the
    channel with a fixed A, so its poses are turned into ``channel`` (``pitch`` [rad] apart)."""
    poses = axis_poses(final_pose, axis_names, axes)
    if "A" not in axis_names:
        poses = rotation_about_x(channel * pitch)[None] @ poses
    return poses
