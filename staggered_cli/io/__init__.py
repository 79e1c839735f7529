"""File formats: the only modules that open files (BVH, C3D, documents)."""
