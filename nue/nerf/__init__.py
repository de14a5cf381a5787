"""The online NeRF memory: field, rays and samplers, volume rendering, loss, OnlineNeRF and presets.

Data flow: frames (rgb, z-depth, pose) -> :mod:`rays` (camera model + depth-guided samples) ->
:mod:`field` / :mod:`grid_field` (density, rgb, variance, feature) -> :mod:`rendering`
(weights, I_u, I_cog) -> :mod:`loss`; :mod:`online` runs the per-episode schedule and
:mod:`config` holds the presets ``authors``, ``reference`` and ``fast``.
"""

from nue.nerf.config import MEMORY_PRESETS, MemoryConfig, get_memory
from nue.nerf.online import MemoryMaps, OnlineNeRF, UpdateStats
from nue.nerf.rays import MemoryInputError

__all__ = ["MEMORY_PRESETS", "MemoryConfig", "MemoryInputError", "MemoryMaps", "OnlineNeRF", "UpdateStats", "get_memory"]
