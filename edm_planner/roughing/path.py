"""Tool poses on the five-axis machine and the untimed plunge-milling axis path.

Frames (all in the workpiece frame W, mm and rad):

* tool frame T -- origin at the centre of the flat tool bottom, z = the tool
  axis pointing from the bottom up the shank (the paper's z, along which it
  translates the tool by t). Its x and y axes (free for a tool symmetric about
  its axis) are fixed by the machine, see below.
* carrier frame K = T . CARRIER_IN_TOOL -- the frame the machine's axes move:
  K_x = T_z (the tool axis), K_z = -T_x. The machine's C axis turns K about
  its own z (``edm_planner.cnc.kinematics``: pose = R_x(A) . T(X, Y, Z) .
  T_ref . R_z(C)), which must not be the tool axis if C is to tilt the tool:
  here C tilts the tool axis in the meridional plane and A (the blisk about X)
  sets its angle about the blisk axis.

``reference_pose`` is K at zero axis values: the tool at the channel's
middle angle theta_c (channel 0), bottom centre at (x_ref, r_ref) in the
meridional plane, axis radial towards the blisk axis. With
R_ref = R_x(theta_c) . R_0, R_0 mapping K_x -> -e_y, K_y -> e_x,
K_z -> e_z, a tool axis d (unit, W) is reached by

    A = atan2(-d_z, -d_y) - theta_c   (unwrapped next to channel * pitch),
    C = atan2(d_x, hypot(d_y, d_z))   (the tilt towards +X, |C| < pi/2),

and then ``axis_poses(reference_pose, AXES_5, q)`` is exactly K. Channel k
comes out at A near k * 2 pi / N, the repository's convention.

The path (:func:`plunge_path`) visits the positions in travel order: start
retracted above the first, then for each position plunge along the tool axis
from its retract point to the optimised pose, retract along the same line,
and move (all five axes linearly) to the next retract point; it ends
retracted above the last. Every straight piece in axis space is cut into
equal steps so that no point of the tool bottom disc moves more than
``spacing`` mm between consecutive samples (a rigorous bound, see
:func:`_steps`); a plunge and its retract use the same samples, so the path
is symmetric about every bottom pose.
"""

from dataclasses import dataclass

import numpy as np

from ..cnc.kinematics import AXES_5, axis_poses

#: K = T . CARRIER_IN_TOOL: a rotation by -pi/2 about the tool's y axis (K_x = T_z, K_z = -T_x)
CARRIER_IN_TOOL = np.array([[0.0, 0.0, -1.0, 0.0],
                            [0.0, 1.0, 0.0, 0.0],
                            [1.0, 0.0, 0.0, 0.0],
                            [0.0, 0.0, 0.0, 1.0]])
TOOL_IN_CARRIER = CARRIER_IN_TOOL.T.copy()

_R0 = np.array([[0.0, 1.0, 0.0],
                [-1.0, 0.0, 0.0],
                [0.0, 0.0, 1.0]])        # columns: K_x = -e_y, K_y = e_x, K_z = e_z


def _rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def reference_pose(theta_c, x_ref, r_ref):
    """K at zero axis values (see the module notes) [mm, rad]."""
    T = np.eye(4)
    Rc = _rot_x(theta_c)
    T[:3, :3] = Rc @ _R0
    T[:3, 3] = Rc @ np.array([x_ref, r_ref, 0.0])
    return T


def reference_angle(reference):
    """theta_c of a reference pose made by :func:`reference_pose`."""
    kx = reference[:3, 0]                                    # = R_x(theta_c) (-e_y)
    return float(np.arctan2(-kx[2], -kx[1]))


def axes_for(points, axes, reference, a_near=0.0):
    """Machine axis values placing the tool bottom centre at ``points`` with tool axis ``axes``.

    Parameters
    ----------
    points : (n, 3) float
        Bottom centres in W [mm].
    axes : (n, 3) float
        Tool axes (unit, from the bottom up the shank) in W.
    reference : (4, 4) float
        From :func:`reference_pose`.
    a_near : float
        A is unwrapped to within pi of this [rad].

    Returns
    -------
    (n, 5) float
        X, Y, Z [mm], A, C [rad].
    """
    p = np.atleast_2d(np.asarray(points, dtype=np.float64))
    d = np.atleast_2d(np.asarray(axes, dtype=np.float64))
    d = d / np.linalg.norm(d, axis=1)[:, None]
    theta_c = reference_angle(reference)
    a = np.arctan2(-d[:, 2], -d[:, 1]) - theta_c
    a = a_near + (a - a_near + np.pi) % (2 * np.pi) - np.pi
    c = np.arctan2(d[:, 0], np.hypot(d[:, 1], d[:, 2]))
    ca, sa = np.cos(a), np.sin(a)
    # XYZ = R_x(-A) p - t_ref
    xyz = np.column_stack([p[:, 0], ca * p[:, 1] + sa * p[:, 2], -sa * p[:, 1] + ca * p[:, 2]]) - reference[:3, 3]
    return np.column_stack([xyz, a, c])


def tool_poses(points, axes, reference, a_near=0.0):
    """Tool frames T (z = tool axis) at ``points`` with ``axes`` as the machine reaches them, (n, 4, 4)."""
    q = axes_for(points, axes, reference, a_near)
    return axis_poses(reference, AXES_5, q) @ TOOL_IN_CARRIER


def _steps(q0, q1, reference, radius, spacing):
    """Equal steps of the axis-space segment q0 -> q1 so no bottom-disc point moves more than ``spacing``.

    A body point b (|b| <= radius in K, the disc lies in K's y-z plane) is at
    P = R_x(A) (XYZ + t_ref + R_ref R_z(C) b). Along the segment
    |dP/du| <= |dXYZ| + |dA| (max_end |XYZ + t_ref| + radius) + |dC| radius
    (the norm of a linear interpolation is at most its larger end), so
    ceil(bound / spacing) steps suffice.
    """
    t_ref = reference[:3, 3]
    d = q1 - q0
    lever = max(np.linalg.norm(q0[:3] + t_ref), np.linalg.norm(q1[:3] + t_ref)) + radius
    bound = np.linalg.norm(d[:3]) + abs(d[3]) * lever + abs(d[4]) * radius
    return max(1, int(np.ceil(bound / spacing - 1e-12)))


def _segment(q0, q1, n):
    """n steps from q0 to q1, q0 excluded, q1 included."""
    u = np.arange(1, n + 1)[:, None] / n
    return q0 + u * (q1 - q0)


@dataclass
class AxisPath:
    """Untimed axis path of the plunges.

    Attributes
    ----------
    axis_names : tuple of str
        ("X", "Y", "Z", "A", "C").
    samples : (N, 5) float
        [mm, rad], in order.
    reference_pose : (4, 4) float
        K at zero axis values (the plan's ``final_pose`` for the bridge).
    bottom_index : (n,) int
        Sample index of each plunge's bottom (the optimised pose), in travel order.
    retract_index : (n,) int
        Sample index of each position's retract point before its plunge, in travel order.
    retract_distances : (n,) float
        Retract distance along the tool axis per position, travel order [mm].
    """

    axis_names: tuple
    samples: np.ndarray
    reference_pose: np.ndarray
    bottom_index: np.ndarray
    retract_index: np.ndarray
    retract_distances: np.ndarray

    def carrier_poses(self):
        """K along the path, (N, 4, 4)."""
        return axis_poses(self.reference_pose, self.axis_names, self.samples)

    def tool_poses(self):
        """T (z = tool axis) along the path, (N, 4, 4)."""
        return self.carrier_poses() @ TOOL_IN_CARRIER


def plunge_path(bottom_q, retract, reference, radius, spacing):
    """The plunge-milling axis path through bottom poses given as axis values, in travel order.

    Parameters
    ----------
    bottom_q : (n, 5) float
        Axis values of the optimised poses in travel order.
    retract : (n,) float
        Retract distance along each tool axis [mm].
    reference : (4, 4) float
    radius : float
        Tool radius (the bottom disc whose points the spacing bounds) [mm].
    spacing : float
        Largest move of a bottom-disc point between consecutive samples [mm].

    Returns
    -------
    AxisPath
    """
    bottom_q = np.atleast_2d(np.asarray(bottom_q, dtype=np.float64))
    retract = np.asarray(retract, dtype=np.float64)
    R_ref = reference[:3, :3]
    samples = []
    bottoms, retracts = [], []
    prev = None
    for q, dist in zip(bottom_q, retract):
        # the tool axis in XYZ coordinates: R_ref R_z(C) e_x (A turns XYZ and the axis alike)
        c = q[4]
        axis = R_ref @ np.array([np.cos(c), np.sin(c), 0.0])
        up = q.copy()
        up[:3] += dist * axis
        if prev is None:
            samples.append(up[None])
        else:
            samples.append(_segment(prev, up, _steps(prev, up, reference, radius, spacing)))
        retracts.append(sum(len(s) for s in samples) - 1)
        n = _steps(up, q, reference, radius, spacing)
        samples.append(_segment(up, q, n))
        bottoms.append(sum(len(s) for s in samples) - 1)
        back = _segment(q, up, n)
        back[-1] = up                                   # exactly the same retract point
        samples.append(back)
        prev = up
    return AxisPath(axis_names=AXES_5, samples=np.vstack(samples), reference_pose=reference.copy(),
                    bottom_index=np.array(bottoms, dtype=int), retract_index=np.array(retracts, dtype=int),
                    retract_distances=retract.copy())
