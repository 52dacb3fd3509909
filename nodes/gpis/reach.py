"""A thin-plate GPIS that outgrows its R_m is rebuilt with a larger one instead of refusing touches.

The thin-plate covariance is only valid for distances up to R_m (default 0.5 m: objects up to about
0.4 m across, ``GPISConfig``). An unknown object may be larger. Before a touch needs distances beyond
R_m, for its local mesh or for the whole-object mesh that may be asked for after it, ``holding``
rebuilds the estimator with R_m doubled until it is at least 1.25 x those distances (the kernel's rule
for an object's diameter), from the same contacts, normals and prior centre, so every later update
keeps its incremental cost. Up to a cap: the fit degrades once the relative jitter (a fraction of
R_m^3) outweighs the value noise, so beyond ``max_R_m`` the touch is refused as before. A Gaussian
kernel, valid at every distance, is never rebuilt.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import ArrayLike

from palpate.errors import EstimationError
from palpate.inputs import coordinates
from palpate.nodes.gpis.core import SurfaceEstimator
from palpate.nodes.gpis.local import make_estimator
from palpate.nodes.gpis.surface import grid_reach, whole_box

#: R_m after growing is at least this many times the distance that did not fit.
HEADROOM = 1.25


def touch_reach(gp: SurfaceEstimator, position_m: ArrayLike, half_extent_m: float, margin_m: float) -> float:
    """Largest distance, metres, that adding a touch at position_m (3,) needs the kernel to hold: from a
    contact so far to a point of the cube of half edge half_extent_m around the touch (its local mesh's
    grid, as ``surface.add_touch`` checks it), and across the contacts' bounding box, grown by margin_m
    (the whole-object mesh's grid, as ``surface.whole_surface`` meshes it); the touch counts among the
    contacts in both (the first touch's own local grid needs sqrt(3) half_extent_m). InputError (naming
    ``position_m``) for a position beyond palpate.inputs' bounds."""
    p = np.asarray(coordinates(position_m, "position_m"), dtype=np.float64)
    P = np.vstack([gp.positions_m, p])
    local = grid_reach(P, p, half_extent_m)
    lower, upper = whole_box(P, margin_m)
    return max(local, float(np.linalg.norm(upper - lower)))


def holding(gp: SurfaceEstimator, reach_m: float, max_R_m: float) -> SurfaceEstimator:
    """``gp`` itself when its kernel is a covariance up to reach_m metres, or when the R_m that would take
    exceeds max_R_m; else a new estimator of the same kind whose R_m is doubled until it is >= HEADROOM x
    reach_m, holding gp's contacts and prior centre. EstimationError if those do not factor with it."""
    try:
        gp.kernel.check_distances(reach_m)
        return gp
    except EstimationError:
        pass
    R_m = gp.config.R_m
    while R_m < HEADROOM * reach_m:
        R_m *= 2.0
    if R_m > max_R_m:
        return gp
    grown = make_estimator(dataclasses.replace(gp.config, R_m=R_m), prior_centre_m=gp.prior_centre_m)
    if gp.n_contacts:
        grown.add_contacts(gp.positions_m, gp.normals)
    return grown
