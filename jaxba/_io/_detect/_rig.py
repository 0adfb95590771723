"""A rig's relative poses from the images' own approximations (docs/conventions.md, Rigs).

Frame f has the reference camera's pose (X0_f, M_f); camera k seen in the same frame with
(X0, M) has b_k = M_f (X0 - X0_f) and M_k = M M_fᵀ. Over the frames both cameras saw, b_k is
the mean and M_k the rotation nearest the mean of the M_k (SVD). Plain NumPy.
"""

import numpy as np

from ..._models._rotation_numpy import matrix_to_opk, opk_to_matrix


def relative_pose(reference: list[np.ndarray], other: list[np.ndarray]) -> np.ndarray:
    """(X0, Y0, Z0, omega, phi, kappa) of a camera in the rig frame, angles in degrees, from
    the EOPs (6,) (angles in degrees) of the reference camera's and this camera's images of
    the same frames, pair by pair (at least one pair)."""
    if not reference or len(reference) != len(other):
        raise ValueError("relative_pose: one or more pairs of images of one frame are needed")
    bases, rotations = [], []
    for eop_f, eop in zip(reference, other):
        m_f, m = opk_to_matrix(np.radians(eop_f[3:])), opk_to_matrix(np.radians(eop[3:]))
        bases.append(m_f @ (eop[:3] - eop_f[:3]))
        rotations.append(m @ m_f.T)
    u, _, vt = np.linalg.svd(np.mean(rotations, axis=0))
    rotation = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return np.r_[np.mean(bases, axis=0), np.degrees(matrix_to_opk(rotation))]
