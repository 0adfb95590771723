"""A pose followed by a pose: a rig camera's exterior orientation from its frame's pose and
its own pose in the rig frame (a camera on a GNSS/INS platform likewise: the body's pose,
then lever arm and boresight)."""

import equinox as eqx
from jaxtyping import PyTree

from ..._custom_types import Matrix3, Vector3


class ComposedPose(eqx.Module):
    """p_camera = M_c (M_f (X - X0_f) - X0_c): `outer` maps object points into the rig
    frame (the frame's pose, M_f and X0_f), `inner` maps rig-frame points into the camera
    (the camera's relative pose, M_c = R_rig^camera and X0_c its perspective centre in the
    rig frame). Both are poses or frames (`to_camera`, `rotation`, `station`), so the
    composition is one too: M = M_c M_f, X0 = X0_f + M_fᵀ X0_c.
    """

    outer: PyTree
    inner: PyTree

    def to_camera(self, point: Vector3) -> Vector3:
        return self.inner.to_camera(self.outer.to_camera(point))

    def rotation(self) -> Matrix3:
        return self.inner.rotation() @ self.outer.rotation()

    def station(self) -> Vector3:
        return self.outer.station() + self.outer.rotation().T @ self.inner.station()
