"""The planner's parameters (PlannerConfig) and the strategies it rates candidates by (Strategy)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

from palpate.config import NonNegativeFloat, PositiveFloat, PositiveInt, Range, Validated
from palpate.messages.schemas import MAX_MISS_DISTANCE_M

Strategy = Literal["igef", "gpv", "random", "area", "tour"]


@dataclass(frozen=True, kw_only=True)
class PlannerConfig(Validated):
    """Planner parameters; defaults are the paper's YCB settings (Section 2.4 and 2.6)."""

    #: How candidates are rated: "igef" (the product Psi1..Psi4, Algorithm 2), "gpv" (the GP variance),
    #: "random" (uniform), or, not in the paper, "area" and "tour" (new explored area per metre of travel).
    strategy: Strategy = "igef"
    #: sigma_1 of Eq. 7, metres: Psi1 = 1 - exp(-d^2 / sigma_1^2), d the candidate's distance to the nearest
    #: contact (IGEF).
    sigma1_m: PositiveFloat = 0.02
    #: mu_3 of Eq. 10, metres: Psi3 = sum over contacts c of exp(-(|s - c| - mu_3)^2 / sigma_3^2) (IGEF).
    mu3_m: NonNegativeFloat = 0.02
    #: sigma_3 of Eq. 10, metres (IGEF).
    sigma3_m: PositiveFloat = 0.02
    #: sigma_alpha of Eq. 11: Psi4 = exp(-2 sin^2(alpha/2) / sigma_alpha^2), alpha the rotation the fingertip
    #: needs to face the target (IGEF, area and tour); smaller makes rotation costlier.
    sigma_alpha: PositiveFloat = 1.0
    #: Candidate sampling on the estimated surface: step 0.5 cm, up to 5 cm from the last contact.
    candidate_step_m: PositiveFloat = 0.005
    #: How far from the last contact candidates are sampled, metres, for igef, random and area (gpv takes
    #: gpv_radius_m, tour tour_radius_m).
    candidate_radius_m: PositiveFloat = 0.05
    #: GP-V's maximum target distance from the last contact (Section 2.6: 6 cm).
    gpv_radius_m: PositiveFloat = 0.06
    #: beta = scale * |r - s| in the Psi2 path (1/3 = Eq. 15; 1 = Algorithm 2 line 4 literally).
    psi2_control_scale: PositiveFloat = 1.0 / 3.0
    #: Floor on the Psi2 path length, metres (targets closer than the fingertip radius).
    min_path_m: PositiveFloat = 1e-3
    #: Not in the paper, for every strategy alike: drop targets whose executed Eq. 15 curve brings the
    #: fingertip into the estimated object before the end (see ``curves_clear``). Without it GP-V picks
    #: the far side of small objects, the curve runs through them, and the fingertip touches again next
    #: to its start, often with its back (measured: 400 contacts, 3 % coverage on the YCB golf ball).
    check_curves: bool = True
    #: How far the fingertip sphere may dip into the estimated surface along a curve, metres (the
    #: estimate's and the nearest-vertex distance's error): the centre keeps tip_radius_m - this.
    curve_margin_m: NonNegativeFloat = 0.001
    #: Points sampled on each candidate curve for that check (tau in (0, 1)).
    curve_samples: PositiveInt = 16
    #: Not in the paper, for every strategy alike: a target whose fingertip centre (t_p + radius t_n) lies
    #: closer than this to the fingertip centre now is not admissible, metres. Such an action barely
    #: moves the fingertip: where the estimate rounds a concave corner (the floor of a cup meeting its
    #: wall) IGEF's shortest path picked a target the fingertip already touched, and the same contact
    #: repeated hundreds of times (measured on the YCB cups). 6 mm is the coverage radius.
    min_hop_m: NonNegativeFloat = 0.006
    #: Not in the paper, for every strategy alike: a target whose touch landed further than
    #: ``unreached_miss_m`` from it (the curve hit the object on the way, or the estimate was wrong there)
    #: is remembered, and candidates within ``unreached_radius_m`` of a remembered target are not
    #: admissible. Without it a strategy re-picks a target it cannot reach (GP-V: its variance stays high
    #: because no contact lands there) and touches the same spot again and again; IGEF's targets in the
    #: concave corner where a cup's floor meets its wall, which the 8 mm fingertip cannot reach, drew
    #: 500 touches 9.5 mm away on 13 spots (measured on YCB 065-i: coverage stuck at 26 %; with 5 mm it
    #: reached 80 % in 387 contacts). 0 disables it.
    unreached_radius_m: NonNegativeFloat = 0.006
    #: A touch that lands further than this from its target's predicted contact marks the target unreached,
    #: metres (see unreached_radius_m).
    unreached_miss_m: NonNegativeFloat = 0.005
    #: Fingertip radius, metres (the controller's tip_radius_m): the curves guide the fingertip centre.
    tip_radius_m: NonNegativeFloat = 0.008
    #: Area and tour strategies (not in the paper, see ``area_scores``): the radius one touch explores,
    #: metres (the evaluation's 6 mm).
    area_radius_m: PositiveFloat = 0.006
    #: L0, the area strategy's fixed cost of a touch, metres of travel added to each candidate's path
    #: length (score = gain Psi4 / (Len + L0)), which makes a touch that explores more worth a longer path.
    area_touch_cost_m: NonNegativeFloat = 0.02
    #: Extra weight of an unexplored patch per explored fraction of its surroundings (2 rho): holes and
    #: the rim of the explored region first, so that no patch is left for a long trip back.
    area_hole_weight: NonNegativeFloat = 2.0
    #: Experimental: weight kappa of the GP variance in the area strategy's gain, G(s) (1 + kappa
    #: var(s) / max var), so that among equal new areas the least known is touched first; 0 (default)
    #: leaves the variance out (and the strategy then needs none from the GPIS node).
    area_variance_weight: NonNegativeFloat = 0.0
    #: Tour strategy (not in the paper, see ``tour_plan``): candidates up to ``tour_radius_m`` from the
    #: last contact (GP-V's 6 cm, where the GPIS node gives the variance); a tour through at most
    #: ``tour_sites`` of the ``tour_pool`` best candidates is planned and its first site touched.
    tour_radius_m: PositiveFloat = 0.06
    #: Most sites a planned tour visits (the planner touches the first, then plans again after the touch).
    tour_sites: PositiveInt = 4
    #: The tour's sites are picked among this many candidates of largest G(s) / (Len(r -> s) + L0).
    tour_pool: PositiveInt = 32
    #: Fixed cost of a touch on the tour, metres of travel (as area_touch_cost_m).
    tour_touch_cost_m: NonNegativeFloat = 0.02
    #: Patch weight w(q) = 1 + beta e(q) + gamma min(d(q) / D, 1): beta as area_hole_weight; gamma the
    #: weight of the patch's distance d(q) from every contact (how far the GP must extrapolate there),
    #: saturating at D = 3 cm (5 coverage radii): a patch D or more from every contact gains gamma, so
    #: touches spread to where the GP extrapolates most. On the 30 shared objects gamma 3 and D 3 cm
    #: give a better whole estimate than gamma 1 and D 2 cm for the same travel (docs/exploration.md).
    tour_hole_weight: NonNegativeFloat = 2.0
    #: gamma of tour_hole_weight's patch weight: the extra weight of a patch D or more from every contact.
    tour_far_weight: NonNegativeFloat = 3.0
    #: D of tour_hole_weight's patch weight, metres: the distance from every contact at which gamma saturates.
    tour_far_m: PositiveFloat = 0.03
    #: Weight kappa of the GP variance in the patch weight, w(q) (1 + kappa var(q) / max var): the GP's
    #: own doubt, where its estimate bulges away from the contacts. 0 (default): the GPIS node computes
    #: no variance for the tour; kappa 1 with a 3 cm touch cost buys a better whole estimate with 20 %
    #: more travel (docs/exploration.md compares the settings on the 30 shared objects).
    tour_variance_weight: NonNegativeFloat = 0.0
    #: Not in the paper: reach a target by sliding the fingertip along the surface from the last contact
    #: (``TouchTarget.slide``; the controller keeps it in contact and steers it to the target) instead of
    #: lifting it along the Eq. 15 curve, when the target lies within this distance of the last contact
    #: and its normal within ``slide_max_angle_deg`` of that contact's, metres. ``slide_max_m`` holds
    #: for every strategy (0, the default: the paper's strategies lift); ``tour_slide_max_m`` for the
    #: tour alone, which slides to any target in its view (6 cm) by default. 60 degrees against 45 and
    #: 90: the least whole-estimate error for the same travel on the 30 shared objects
    #: (docs/exploration.md, "Slides").
    slide_max_m: NonNegativeFloat = 0.0
    #: slide_max_m for the tour strategy alone, metres (the tour slides within the larger of the two).
    tour_slide_max_m: NonNegativeFloat = 0.06
    #: A slide also needs the target's normal within this angle of the last contact's measured normal, degrees.
    slide_max_angle_deg: Annotated[float, Range(ge=0.0, le=90.0)] = 60.0
    #: Not in the paper: how far past its target the fingertip may go without a contact before Algorithm
    #: 1's recovery (Delta_m, sent as ``TouchTarget.miss_distance_m``), metres, at most
    #: MAX_MISS_DISTANCE_M; 0 sends 0, which leaves it to the controller's own Delta_m (its
    #: ``miss_distance_m``, 1 cm). ``miss_distance_m`` holds for every strategy (0, the default: the
    #: paper's strategies keep the controller's), ``tour_miss_distance_m`` for the tour when not 0: 3 cm,
    #: so that a touch aimed at surface the estimate invents (the GP closes a cup's unexplored inside
    #: with a false floor) goes on to the true surface behind it, where 1 cm ends in the recovery and a
    #: touch where the fingertip left (docs/exploration.md, "A longer reach past a missed target").
    miss_distance_m: Annotated[float, Range(ge=0.0, le=MAX_MISS_DISTANCE_M)] = 0.0
    #: miss_distance_m for the tour strategy, metres; 0: the tour sends miss_distance_m.
    tour_miss_distance_m: Annotated[float, Range(ge=0.0, le=MAX_MISS_DISTANCE_M)] = 0.03

    @property
    def slide_reach_m(self) -> float:
        """How far from the last contact this strategy slides to a target (0: it never slides)."""
        return max(self.slide_max_m, self.tour_slide_max_m if self.strategy == "tour" else 0.0)

    @property
    def target_miss_distance_m(self) -> float:
        """Delta_m this strategy asks of the controller with each target (0: the controller's own)."""
        return (
            self.tour_miss_distance_m
            if self.strategy == "tour" and self.tour_miss_distance_m > 0.0
            else self.miss_distance_m
        )

    @property
    def uses_variance(self) -> bool:
        """Whether the strategy rates candidates by the GP variance (GP-V; area or tour with a variance
        weight)."""
        return (
            self.strategy == "gpv"
            or (self.strategy == "area" and self.area_variance_weight > 0.0)
            or (self.strategy == "tour" and self.tour_variance_weight > 0.0)
        )

    @property
    def radius_m(self) -> float:
        """Largest target distance from the last contact for the configured strategy."""
        if self.strategy == "gpv":
            return self.gpv_radius_m
        if self.strategy == "tour":
            return self.tour_radius_m
        return self.candidate_radius_m
