"""The simulator: task presets, camera + EGL renderer, the gymnasium environment, episodes (ours, the
authors' and habitat-lab's formats) and their records, the geodesic and exploring experts.

    from nue.sim import ImageNavEnv, get_task, load_episodes, make_env

    env = make_env("data/scenes/val_00", "paper")             # = ImageNavEnv(Scene.load(...), "paper")
    env = gymnasium.make("nue/ImageNav-v0", scene="data/scenes/val_00", task="paper")   # after `import nue`
    obs, info = env.reset(seed=0)                              # obs: rgb, depth, pose, goal
"""

from nue.sim.env import ImageNavEnv, make_env
from nue.sim.episodes import Episode, load_episodes, read_episodes, save_episodes
from nue.sim.record import EpisodeRecord, Trajectory
from nue.sim.task import TASK_PRESETS, CameraConfig, TaskConfig, get_task

__all__ = [
    "CameraConfig", "Episode", "EpisodeRecord", "ImageNavEnv", "TASK_PRESETS", "TaskConfig", "Trajectory", "get_task",
    "load_episodes", "make_env", "read_episodes", "save_episodes",
]
