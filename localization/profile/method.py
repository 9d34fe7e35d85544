"""The profile method's entry points: an aerial side indexed once, a query's profile, a localization.

:func:`profile_index` builds the aerial side from a mask (ray casting) or landmark points
(kernels), :func:`profile_query` the query's profile from its mask or landmarks as its camera
sees them (reading a tilted camera's horizon first when asked), and :func:`run_profile`
searches one against the other (:func:`~localization.profile.locate.localize_profile`). The
pipeline, the region search and the benchmarks call these.

Imports: osmseg core, localization.common, and the profile wing's own modules.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from localization.common.landmarks import Landmarks
from localization.common.result import Localization
from localization.common.views import Camera, SemanticMap
from localization.profile.horizon import estimate_tilt
from localization.profile.locate import localize_profile
from localization.profile.profiles import (
    AerialLandmarkIndex,
    AerialMaskIndex,
    QueryProfile,
    Vista,
    query_from_landmarks,
    query_from_mask,
    query_poses,
    ray_radii,
)
from localization.profile.search import AerialIndex, ProfileConfig
from osmseg.errors import ConfigError

logger = logging.getLogger(__name__)

__all__ = ["profile_index", "profile_query", "run_profile"]


def profile_index(aerial: SemanticMap | Landmarks, resolution_m: float | None,
                  config: ProfileConfig = ProfileConfig()) -> AerialIndex:
    """The aerial side of the profile method: from a mask (ray casting) or landmark points (kernels)."""
    if not resolution_m:
        raise ConfigError("the profile method measures distances in metres: give the aerial resolution "
                          "(--aerial-resolution, m/px), or a GeoTIFF or dataset mask that records it, or use --method paper")
    if isinstance(aerial, SemanticMap):
        return AerialMaskIndex(aerial, resolution_m, config.samples)
    return AerialLandmarkIndex(aerial, resolution_m, sigma_deg=config.sigma_deg, distance_sd=config.distance_sd,
                               d0_m=config.d0_m)


def profile_query(query: SemanticMap | Landmarks, camera: Camera, config: ProfileConfig = ProfileConfig()
                  ) -> QueryProfile:
    """The query side of the profile method, in compass azimuths (heading given) or its own frame (unknown)."""
    radii = ray_radii(camera, config.radii, config.min_range_m, config.max_range_m)
    if isinstance(query, SemanticMap):
        if config.tilt_deg > 0:  # the horizon read from the view: where its sky ends and its ground begins
            tilt = estimate_tilt(query, camera, config.tilt_deg)
            camera = replace(camera, pitch_deg=tilt.pitch_deg, roll_deg=tilt.roll_deg)
        vista = _vista(query, config, radii[0])
        if config.camera_heights:
            return query_poses(query, camera, bins=config.bins or 72, radii=radii, heading_deg=config.heading_deg,
                               heights=config.camera_heights, vista=vista)
        return query_from_mask(query, camera, bins=config.bins or 72, radii=radii, heading_deg=config.heading_deg,
                               vista=vista)
    bins = config.bins or max(8, int(round(360.0 / (config.sigma_deg / 2))))
    return query_from_landmarks(query, camera, bins=bins, radii=radii, heading_deg=config.heading_deg)


def _vista(query: SemanticMap, config: ProfileConfig, radii_m: np.ndarray) -> Vista | None:
    """The vista asked for, or None (said once in the log when it was asked for and cannot be read)."""
    if config.vista_weight <= 0:
        return None
    why = ("the ground view has no sky class (the ground table's 'sky')" if query.sky is None
           else f"its {config.vista_m:g} m lie within the farthest ground distance read ({float(radii_m.max()):.0f} m)"
           if config.vista_m <= float(radii_m.max()) else None)
    if why is not None:
        logger.warning("the open horizon (vista) is left out: %s", why)
        return None
    return Vista(config.vista_m, config.vista_deg, config.vista_weight)


def run_profile(config: ProfileConfig, aerial: AerialIndex, query: SemanticMap | Landmarks | QueryProfile,
                camera: Camera | None = None, prior: np.ndarray | None = None,
                within: tuple[float, float, float, float] | None = None) -> Localization:
    """Localize ``query`` (its mask or landmarks seen by ``camera``, or a ready profile) with the profile method;
    ``within``: the pixel box searched (:func:`~localization.profile.locate.localize_profile`)."""
    if not isinstance(query, QueryProfile):
        if camera is None:
            raise ConfigError("the profile method needs the query camera (image size and field of view)")
        query = profile_query(query, camera, config)
    result = localize_profile(aerial, query, config, prior, within)
    logger.debug("localize (profile): heading %s, confidence %s, %d positions at the finest level",
                 result.heading_deg, result.confidence, len(result.candidates))
    return result
