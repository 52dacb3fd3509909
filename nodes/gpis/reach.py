"""A thin-plate GPIS that outgrows its R_m is rebuilt with a larger one instead of refusing touches.

The thin-plate covariance is only valid for distances up to R_m (default 0.5 m: objects up to about
0.4 m across, ``GPISConfig``). An unknown object may be larger. Before a touch or a whole-object mesh
needs distances beyond R_m, ``holding`` rebuilds the estimator with R_m doubled until it is at least
1.25 x those distances (the kernel's rule for an object's diameter), from the same contacts, normals
and prior centre, so every later update keeps its incremental cost. A Gaussian kernel, valid at every
distance, is never rebuilt.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import ArrayLike

from palpate.errors import EstimationError
from palpate.inputs import coordinates
from palpate.nodes.gpis.core import SurfaceEstimator
from palpate.nodes.gpis.local import make_estimator

#: R_m after growing is at least this many times the distance that did not fit.
HEADROOM = 1.25


def touch_reach(gp: SurfaceEstimator, position_m: ArrayLike, half_extent_m: float) -> float:
    """Largest distance, metres, between a contact (the touch at position_m (3,) included) and a point of
    the cube of half edge half_extent_m around the touch (its local mesh's grid); 0 before any contact.
    InputError (naming ``position_m``) for a position beyond palpate.inputs' bounds."""
    p = np.asarray(coordinates(position_m, "position_m"), dtype=np.float64)
    if not gp.n_contacts:
        return 0.0
    farthest = np.abs(gp.positions_m - p).max(axis=0) + half_extent_m  # per axis, to the far face
    return float(np.linalg.norm(farthest))


def mesh_reach(gp: SurfaceEstimator, margin_m: float) -> float:
    """Largest distance, metres, between a contact and a point of the contacts' bounding box grown by
    margin_m (the whole-object mesh's grid): the box's diagonal; 0 before any contact."""
    if not gp.n_contacts:
        return 0.0
    points = gp.positions_m
    return float(np.linalg.norm(points.max(axis=0) - points.min(axis=0) + 2.0 * margin_m))


def holding(gp: SurfaceEstimator, reach_m: float) -> SurfaceEstimator:
    """``gp`` itself when its kernel is a covariance up to reach_m metres; else a new estimator of the same
    kind whose R_m is doubled until it is >= HEADROOM x reach_m, holding gp's contacts and prior centre."""
    try:
        gp.kernel.check_distances(reach_m)
        return gp
    except EstimationError:
        pass
    R_m = gp.config.R_m
    while R_m < HEADROOM * reach_m:
        R_m *= 2.0
    grown = make_estimator(dataclasses.replace(gp.config, R_m=R_m), prior_centre_m=gp.prior_centre_m)
    if gp.n_contacts:
        grown.add_contacts(gp.positions_m, gp.normals)
    return grown
