"""nue: image-goal visual navigation with an online, uncertainty-aware NeRF as the robot's memory.

Data flow (and import direction): ``scene`` -> ``sim`` -> ``nerf`` -> ``policy`` -> ``train`` | ``evaluate``
(side by side, neither imports the other) -> ``selection`` -> ``viz``, with ``cli`` on top. Importing ``nue``
registers the gymnasium environment ``nue/ImageNav-v0`` (:class:`nue.sim.env.ImageNavEnv`; keyword arguments ``scene``, ``task``,
``episodes``, ...), so ``gymnasium.make("nue/ImageNav-v0", scene="data/scenes/val_00", task="paper")`` works.
"""

import gymnasium

__version__ = "0.1.0"

ENV_ID = "nue/ImageNav-v0"
"""The gymnasium id of :class:`nue.sim.env.ImageNavEnv`."""

if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="nue.sim.env:ImageNavEnv")
