"""nue: image-goal visual navigation with an online, uncertainty-aware NeRF as the robot's memory.

Data flow (and import direction): ``scene`` -> ``sim`` -> ``nerf`` -> ``policy`` ->
``train`` / ``evaluate`` -> ``viz``, with ``cli`` on top.
"""

__version__ = "0.1.0"
