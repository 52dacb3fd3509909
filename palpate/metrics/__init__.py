"""Evaluation metrics shared by the exploration runs and the benchmark tables."""

from palpate.metrics.exploration import (
    COVERING_DENSITY,
    CoverageTracker,
    DistanceField,
    SurfaceRmse,
    angle_to_normal_deg,
    covering_bound_contacts,
    mesh_area,
    packing_bound_contacts,
    prediction_miss_m,
    sample_surface,
    surface_rmse,
)

__all__ = [
    "COVERING_DENSITY",
    "CoverageTracker",
    "DistanceField",
    "SurfaceRmse",
    "angle_to_normal_deg",
    "covering_bound_contacts",
    "mesh_area",
    "packing_bound_contacts",
    "prediction_miss_m",
    "sample_surface",
    "surface_rmse",
]
