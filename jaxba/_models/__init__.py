"""Models of one observation: cameras, distortion, refraction, poses, rotations, robust losses."""
