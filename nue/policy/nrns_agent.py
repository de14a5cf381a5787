"""The NRNS agent (Hahn et al., NeurIPS 2021): a topological graph, a distance network, a local controller.

At each decision (episode start, a subgoal reached or given up) the agent

1. localises itself in its graph (:class:`nue.policy.nrns_graph.TopoGraph`): the explored node within
   ``node_radius`` of its pose, or a new node joined to the one it came from;
2. encodes the current view with the goal photo and predicts the distance to the goal from where it stands
   (:class:`nue.policy.nrns_model.DistanceNetwork`, offset (0, 0)); with a STOP action it stops below
   ``stop_distance``; below ``switch_distance`` it *switches to the goal*: ghosts are read from this view at the short
   ``near_range`` and the one predicted nearest the goal is taken without travel cost (NRNS switches to a separate
   goal-location network there; see ``docs/nrns.md``);
3. else adds the ghosts its depth shows (:func:`nue.policy.nrns_graph.ghost_offsets`, each with its predicted
   distance) and, at a new node, turn ghosts; then chooses the ghost of least predicted distance + travel cost;
4. drives there with a local controller on its own depth-built map (:class:`nue.policy.seen_map.SeenMap`, steered
   by :class:`nue.sim.expert.PathDriver` as the last-mile wrapper does), turning in place for a turn ghost; a ghost
   not reached within ``max_drive_steps``, or without a path on the map for ``max_unreachable`` steps, is dropped.

The agent reads the task (camera, actions) and the floor height at ``reset``, and per step the observation (RGB,
depth, pose, goal photo); never the scene, its navigation grid or the goal's position.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import torch

from nue.policy.inputs import PolicyInput, prepare_goal, prepare_input
from nue.policy.nrns_graph import Ghost, GhostConfig, TopoGraph, ghost_offsets
from nue.policy.nrns_model import DistanceNetwork
from nue.policy.seen_map import SeenMap, SeenMapConfig
from nue.sim.camera import wrap_angle
from nue.sim.expert import ExpertConfig, PathDriver


@dataclass(frozen=True)
class NRNSAgentConfig:
    """How the NRNS agent builds its graph, chooses subgoals and drives (metres, radians, steps)."""

    ghosts: GhostConfig = field(default_factory=GhostConfig)
    """Ghost placement and node merging."""
    map: SeenMapConfig = field(default_factory=SeenMapConfig)
    """The local controller's map built from the robot's depth."""
    travel_weight: float = 1.0
    """Weight of the travel distance (graph path to the ghost) in a ghost's cost."""
    turn_cost: float = 0.955
    """Cost per radian of heading change to face a ghost (NRNS: 0.25 m per 15 degrees)."""
    switch_distance: float = 1.5
    """Below this predicted distance the agent goes for the goal (ghosts at ``near_range``, no travel cost)."""
    near_range: float = 0.75
    """Range of the ghosts read after the switch."""
    stop_distance: float = 0.6
    """With a STOP action: stop when the predicted distance from here is below this."""
    arrive_radius: float = 0.3
    """A ghost is reached within this."""
    max_drive_steps: int = 40
    """A ghost not reached after this many steps is dropped."""
    max_unreachable: int = 5
    """A ghost without a path on the map this many steps in a row is dropped."""
    lookahead: float = 0.8
    """The controller aims at the farthest point of its path within this that is in straight reach."""

    def to_dict(self) -> dict:
        """Every setting as plain JSON values (nested dicts)."""
        return dataclasses.asdict(self)


class NRNSAgent:
    """An :class:`nue.policy.protocols.Agent` acting with a trained :class:`DistanceNetwork`."""

    def __init__(self, model: DistanceNetwork, config: NRNSAgentConfig = NRNSAgentConfig(),
                 device: str | torch.device = "cpu", git_commit: str = ""):
        self.model = model.to(device).eval()
        self.config = config
        self.model_config = model.config
        self.device = torch.device(device)
        self.git_commit = git_commit
        """The commit the weights were trained at ('' unknown); recorded with evaluation records."""
        self.last_input: PolicyInput | None = None
        """The network's input at the last decision (as :class:`nue.policy.agent.PolicyAgent` keeps its last one)."""
        self.last_aux: float | None = None
        """Always None: the distance network has no goal-angle head (the attribute readers of agents expect)."""

    # -- the Agent protocol ---------------------------------------------------------------------
    def reset(self, env, obs, seed: int = 0) -> None:
        """New episode: an empty graph and map centred on the start, the goal photo prepared once."""
        cfg, task = self.config, env.task
        self.task, self.camera = task, task.camera
        self.map = SeenMap(task.camera, env.floor_z, obs["pose"][:2], cfg.map)
        self.driver = PathDriver(self.map, task, ExpertConfig(lookahead=cfg.lookahead))  # type: ignore[arg-type]
        self.graph = TopoGraph(cfg.ghosts)
        self.goal = prepare_goal(obs["goal"], self.model_config, self.device)
        self.stop = task.action_id("STOP")
        left, right = task.action_id("TURN_LEFT"), task.action_id("TURN_RIGHT")
        if left is None or right is None:
            raise ValueError(f"task {task.name!r}: the NRNS agent needs TURN_LEFT and TURN_RIGHT actions")
        self.left, self.right = left, right
        self.node: int | None = None
        self.target: Ghost | None = None
        self.drive_steps = self.unreachable = 0
        self.near = False
        self.last_distance: float | None = None
        """The distance to the goal predicted at the last decision, metres."""
        self.events: list[tuple[int, str, object]] = []
        self.t = -1

    def act(self, obs, maps) -> int:
        """This step's action: drive toward the current subgoal, choosing a new one when it is reached or dropped."""
        self.t += 1
        pose = np.asarray(obs["pose"], dtype=np.float64)
        self.map.add_position(pose[:2])
        self.map.add_frame(obs["depth"], pose)
        for _ in range(2):  # at most one new decision per step
            if self.target is None:
                stop = self._decide(obs, pose)
                if stop:
                    return self.driver.remember(self.stop, pose[:2])
                if self.target is None:
                    break
            action = self._drive(pose)
            if action is not None:
                return action
        if not self.events or self.events[-1][1] != "no_ghost":  # once per run of such steps
            self.events.append((self.t, "no_ghost", None))
        return self.driver.remember(self.left, pose[:2])  # nothing left to explore: look around

    def executed(self, action: int) -> None:
        """Told by a wrapper which action was executed (the steering's blocked-move check uses it)."""
        self.driver.last_action = action

    # -- decisions ------------------------------------------------------------------------------
    def _decide(self, obs, pose) -> bool:
        """Localise, predict, add ghosts and choose the next one (``self.target``); True to stop here."""
        cfg = self.config
        xy, yaw = pose[:2], float(pose[2])
        self.node, new = self.graph.localize(xy, self.node)
        inp = self.last_input = prepare_input(obs["rgb"], obs["depth"], None, None, None, self.model_config,
                                              device=self.device, goal_input=self.goal)
        near_ghosts = dataclasses.replace(cfg.ghosts, ranges=(cfg.near_range,))
        offsets = {False: ghost_offsets(obs["depth"], self.camera, cfg.ghosts),
                   True: ghost_offsets(obs["depth"], self.camera, near_ghosts)}
        with torch.no_grad():
            f = self.model.encode(inp.rgbd, inp.goal)
            here = float(self.model.distance_from(f, f.new_zeros(1, 1, 2))[0, 0])
            dists = {k: self.model.distance_from(f, torch.as_tensor(o, dtype=f.dtype, device=f.device)[None])[0].cpu().numpy()
                     for k, o in offsets.items() if len(o)}
        self.last_distance = here
        if self.stop is not None and here < cfg.stop_distance:
            self.events.append((self.t, "stop", round(here, 3)))
            return True
        if new:
            for h in np.radians(cfg.ghosts.turn_headings_deg):
                self.graph.add_ghost(xy, self.node, float(wrap_angle(yaw + h)), here, turn=True)
        self.near = here < cfg.switch_distance
        if self.near and True in dists:
            i = int(np.argmin(dists[True]))
            if dists[True][i] < here:
                self.target = Ghost(self._world(pose, offsets[True][i]), self.node, self._heading(yaw, offsets[True][i]),
                                    float(dists[True][i]))
                self.events.append((self.t, "goal_switch", round(here, 3)))
                return self._start()
        for o, d in zip(offsets[False], dists.get(False, ())):
            self.graph.add_ghost(self._world(pose, o), self.node, self._heading(yaw, o), float(d))
        gid = self.graph.choose(self.node, yaw, cfg.travel_weight, cfg.turn_cost)
        if gid is not None:
            self.target = self.graph.ghosts.pop(gid)
            self.events.append((self.t, "subgoal", gid))
        return self._start()

    def _start(self) -> bool:
        self.drive_steps = self.unreachable = 0
        self.driver.reset()
        return False

    @staticmethod
    def _world(pose, offset) -> np.ndarray:
        """World (x, y) of a robot-frame (forward, left) offset from ``pose``."""
        c, s = np.cos(pose[2]), np.sin(pose[2])
        return pose[:2] + np.array([c * offset[0] - s * offset[1], s * offset[0] + c * offset[1]])

    @staticmethod
    def _heading(yaw: float, offset) -> float:
        return float(wrap_angle(yaw + np.arctan2(offset[1], offset[0])))

    # -- local controller -----------------------------------------------------------------------
    def _drive(self, pose) -> int | None:
        """The controller's action toward the target, or None when it is reached or dropped (target cleared)."""
        cfg, g = self.config, self.target
        assert g is not None
        xy, yaw = pose[:2], float(pose[2])
        self.drive_steps += 1
        if g.turn and np.linalg.norm(g.xy - xy) <= cfg.arrive_radius:  # at its node: turn there
            err = wrap_angle(g.heading - yaw)
            if abs(err) <= 0.5 * self.task.turn_angle + 1e-6:
                self.target = None
                return None
            return self.driver.remember(self.left if err > 0 else self.right, xy)
        if not g.turn and np.linalg.norm(g.xy - xy) <= cfg.arrive_radius:
            self.target = None
            return None
        if self.drive_steps > cfg.max_drive_steps:
            return self._drop("timeout")
        if not self.map.reachable(xy, g.xy):
            self.unreachable += 1
            if self.unreachable >= cfg.max_unreachable:
                return self._drop("unreachable")
        else:
            self.unreachable = 0
        return self.driver.drive(xy, yaw, g.xy, safe=True)

    def _drop(self, reason: str) -> int | None:
        """Give up the target (None: the caller decides again)."""
        self.events.append((self.t, f"drop_{reason}", None))
        self.target = None
        return None

    def summary(self) -> dict:
        """The record's ``extra["nrns"]``: the graph (explored nodes' world (x, y), edges, the ghosts left with their
        predicted distances), the last predicted distance and the decisions ``[step, what, detail]``."""
        g = self.graph.graph
        r = lambda v: round(float(v), 3)  # noqa: E731
        return {"nodes": {str(n): [r(d["xy"][0]), r(d["xy"][1])] for n, d in g.nodes(data=True)},
                "edges": [[int(a), int(b)] for a, b in g.edges],
                "ghosts": [[r(h.xy[0]), r(h.xy[1]), r(h.distance), int(h.turn)] for h in self.graph.ghosts.values()],
                "last_distance": None if self.last_distance is None else r(self.last_distance),
                "events": [[s, w, d] for s, w, d in self.events]}
