"""Shape aliases shared by the package (jaxtyping)."""

from jaxtyping import Array, Float

Vector2 = Float[Array, "2"]
Vector3 = Float[Array, "3"]
Matrix3 = Float[Array, "3 3"]
Scalar = Float[Array, ""]
