"""The agents of the shared loop (:func:`nue.rollout.run_episode`): observation + memory maps -> action.

:class:`ExpertAgent` (geodesic or exploring expert), :class:`PolicyAgent` (a trained network: the same
``prepare_input`` as in training turns the raw observation and the NeRF maps into its input; the
recurrent state of Nav-A3C is carried across steps and reset per episode), :class:`MixedAgent`
(DAgger's mix), :class:`NoisyAgent` (DART noise injection) and :class:`RandomAgent` (a random walk).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from nue.policy.base import PolicyModel, choose_actions
from nue.policy.inputs import PolicyInput, prepare_goal, prepare_input
from nue.policy.protocols import expert_label, tell_executed
from nue.policy.uncertainty_expert import UncertaintyExpert
from nue.sim.env import ImageNavEnv
from nue.sim.expert import ExpertConfig, GeodesicExpert
from nue.sim.explorer import ExplorerConfig, ExploringExpert

EXPERT_KINDS = ("geodesic", "explore", "uncertainty")
"""``ExpertAgent(kind=...)``: the geodesic expert, the exploring expert (``nue.sim.explorer``), or the
uncertainty-seeking expert (:mod:`nue.policy.uncertainty_expert`; needs a memory whose maps carry a panorama)."""


class ExpertAgent:
    """An expert as an :class:`Agent` (it reads the pose and the env's goal, never the maps).

    ``kind="geodesic"`` (default): :class:`GeodesicExpert`; ``kind="explore"``:
    :class:`nue.sim.explorer.ExploringExpert` (frontier exploration on what its depth frames saw until
    the goal is in view, then the geodesic expert), configured by ``explorer``.
    """

    def __init__(self, config: ExpertConfig = ExpertConfig(), kind: str = "geodesic",
                 explorer: ExplorerConfig | None = None):
        if kind not in EXPERT_KINDS:
            raise ValueError(f"unknown expert kind {kind!r}; expected one of {EXPERT_KINDS}")
        self.config = config
        self.kind = kind
        self.explorer_config = explorer
        self.expert: GeodesicExpert | ExploringExpert | None = None

    def reset(self, env: ImageNavEnv, obs, seed: int = 0) -> None:
        e = self.expert
        if e is None or e.nav is not env.navgrid or e.task is not env.task or getattr(e, "floor_z", env.floor_z) != env.floor_z:
            if self.kind == "explore":
                self.expert = ExploringExpert(env.navgrid, env.task, self.explorer_config or ExplorerConfig(),
                                              self.config, floor_z=env.floor_z)
            elif self.kind == "uncertainty":
                self.expert = UncertaintyExpert(env.navgrid, env.task, expert_config=self.config, floor_z=env.floor_z)
            else:
                self.expert = GeodesicExpert(env.navgrid, env.task, self.config)
        self.expert.reset(env.nav_goal_xy)

    def act(self, obs, maps) -> int:
        if self.kind == "explore":
            return self.expert.act(obs["pose"], obs["depth"])
        if self.kind == "uncertainty":
            panorama = getattr(maps, "panorama", None)
            if panorama is None:
                raise ValueError("the uncertainty expert needs memory maps with a panorama (a memory preset with "
                                 "panorama_headings > 0, e.g. fast_pano)")
            return self.expert.act(obs["pose"], obs["depth"], panorama)
        return self.expert.act(obs["pose"])

    def executed(self, action: int) -> None:
        """Told by a wrapper (noise injection) which action was actually executed this step."""
        self.expert.executed(action)


class RandomAgent:
    """A random walk: each step a move drawn uniformly from the task's actions except STOP, seeded per episode
    (the exploration benchmark's lower reference)."""

    def reset(self, env, obs, seed: int = 0) -> None:
        self.moves = np.array([i for i, a in enumerate(env.task.actions) if a != "STOP"], dtype=np.int64)
        self.rng = np.random.default_rng(np.random.SeedSequence([seed, 4]))

    def act(self, obs, maps) -> int:
        return int(self.rng.choice(self.moves))


class PolicyAgent:
    """Acts with ``model`` (sampling from softmax(logits / temperature), or argmax if ``greedy`` or at temperature 0)."""

    def __init__(self, model: PolicyModel, greedy: bool = False, device: str | torch.device = "cpu", git_commit: str = "",
                 temperature: float = 1.0):
        self.model = model.to(device).eval()
        self.git_commit = git_commit
        """The commit the weights were trained at ('' unknown); recorded with evaluation records."""
        self.config = model.config
        self.greedy = greedy
        self.temperature = float(temperature)
        """Sampling temperature of the action distribution (1 = the paper's eq. 14; 0 = argmax)."""
        self.device = torch.device(device)
        self.generator = torch.Generator(device="cpu")
        self.last_aux: float | None = None
        """The last step's auxiliary goal angle, radians (None without the head)."""
        self.last_goal_view: float | None = None
        """The last step's goal-in-view probability from the exploitation head (None without it)."""
        self.last_goal_distance: float | None = None
        """... and its goal distance, metres."""
        self.last_input = None
        self._goal: tuple[np.ndarray, torch.Tensor] | None = None  # the last goal photo and its prepared tensor

    def reset(self, env, obs, seed: int = 0) -> None:
        """New episode: initial recurrent state; action sampling seeded by the episode's ``seed``."""
        self.state = self.model.initial_state(1, self.device)
        self.generator.manual_seed(int(np.random.SeedSequence([seed, 1]).generate_state(1)[0]))
        self._goal = None

    def policy_input(self, obs, maps):
        i_u = getattr(maps, "i_u", None) if maps is not None else None
        i_cog = getattr(maps, "i_cog", None) if maps is not None else None
        return prepare_input(obs["rgb"], obs["depth"], obs["goal"], i_u, i_cog, self.config, device=self.device,
                             goal_input=self._goal_input(obs["goal"]),
                             panorama=getattr(maps, "panorama", None) if maps is not None else None)

    def _goal_input(self, goal) -> torch.Tensor | None:
        """The prepared goal, kept while the photo stays the same (it does for a whole episode)."""
        if not isinstance(goal, np.ndarray) or goal.ndim != 3:
            return None
        kept = self._goal
        if kept is None or kept[0].dtype != goal.dtype or kept[0].shape != goal.shape or not np.array_equal(kept[0], goal):
            kept = self._goal = (goal.copy(), prepare_goal(goal, self.config, self.device))
        return kept[1]

    def act(self, obs, maps) -> int:
        inp = self.policy_input(obs, maps)
        self.last_input = inp
        with torch.no_grad():
            out = self.model(inp, self.state)
        self.state = out.state
        self.last_aux = None if out.aux_angle is None else float(out.aux_angle[0])
        if out.goal_view is not None and out.goal_log_distance is not None:
            self.last_goal_view = float(torch.sigmoid(out.goal_view[0].float()))
            self.last_goal_distance = float(torch.exp(out.goal_log_distance[0].float()))
        return int(choose_actions(out.logits, self.greedy, self.generator, self.temperature)[0])

    def twin(self) -> "PolicyAgent":
        """Another agent on the same model (weights shared, own recurrent state and action sampling): one per
        slot of the lock-step loop, whose :meth:`act_batch` runs them in one forward."""
        return PolicyAgent(self.model, greedy=self.greedy, device=self.device, git_commit=self.git_commit,
                           temperature=self.temperature)

    def batch_key(self) -> tuple:
        """Agents with equal keys share one forward in :meth:`act_batch` (same model object, action rule, device)."""
        return (id(self.model), self.greedy, self.temperature, str(self.device))

    @staticmethod
    def act_batch(agents: list["PolicyAgent"], obs_list: list, maps_list: list, rows: int = 0,
                  positions: list[int] | None = None) -> list[int]:
        """The actions of ``agents`` (equal :meth:`batch_key`) for their observations and maps, in one forward of
        the shared model. Each agent prepares its own input, keeps its own recurrent state and samples with its own
        generator, as in :meth:`act`.

        The batch has ``max(rows, len(agents))`` rows: agent k sits in row ``positions[k]`` (default k), the other
        rows repeat the first agent's input and are dropped. A CPU forward's rounding depends on the batch size
        and may depend on the row's position, never on the other rows' contents (measured on the NUE checkpoint:
        8 rows bit-identical at every position; 3 rows differ in the last bit at position 2), so with a fixed
        ``rows`` and position an agent's numbers depend on its own inputs only."""
        if not agents:
            return []
        positions = list(range(len(agents))) if positions is None else list(positions)
        n = max(rows, len(agents), max(positions) + 1)
        inputs = [a.policy_input(o, m) for a, o, m in zip(agents, obs_list, maps_list)]
        order = [0] * n  # row -> agent
        for k, p in enumerate(positions):
            order[p] = k
        batch = _stack_inputs([inputs[k] for k in order])
        state = agents[0].state
        if state is not None:
            state = tuple(torch.cat([agents[k].state[j] for k in order]) for j in range(len(state)))  # type: ignore[index]
        with torch.no_grad():
            out = agents[0].model(batch, state)
        actions = []
        for k, (a, p) in enumerate(zip(agents, positions)):
            a.last_input = inputs[k]
            a.state = None if out.state is None else tuple(s[p:p + 1] for s in out.state)
            a.last_aux = None if out.aux_angle is None else float(out.aux_angle[p])
            if out.goal_view is not None and out.goal_log_distance is not None:
                a.last_goal_view = float(torch.sigmoid(out.goal_view[p].float()))
                a.last_goal_distance = float(torch.exp(out.goal_log_distance[p].float()))
            actions.append(int(choose_actions(out.logits[p:p + 1], a.greedy, a.generator, a.temperature)[0]))
        return actions


def _stack_inputs(inputs: list[PolicyInput]) -> PolicyInput:
    """One batch of single-row inputs (concatenated along the batch dimension)."""
    return PolicyInput(**{f.name: None if getattr(inputs[0], f.name) is None else torch.cat([getattr(x, f.name) for x in inputs])
                          for f in dataclasses.fields(PolicyInput)})  # type: ignore[arg-type]


class MixedAgent:
    """DAgger's rollout policy: with probability ``beta`` the expert's action, else the policy's.

    ``last_expert_action`` always holds the expert's label for the current state. After
    ``policy_steps`` steps (e.g. 3x the expert's step count for the episode) the expert takes over
    and finishes the episode.
    """

    def __init__(self, policy: PolicyAgent, expert, beta: float, policy_steps: int | None = None):
        self.policy, self.expert, self.beta = policy, expert, float(beta)
        self.policy_steps = policy_steps
        self.rng = np.random.default_rng(0)
        self.last_expert_action: int | None = None

    def reset(self, env, obs, seed: int = 0) -> None:
        self.policy.reset(env, obs, seed)
        self.expert.reset(env, obs, seed)
        self.rng = np.random.default_rng(np.random.SeedSequence([seed, 2]))
        self.t = 0

    def act(self, obs, maps) -> int:
        self.last_expert_action = int(self.expert.act(obs, maps))
        policy_action = self.policy.act(obs, maps)  # always run: keeps the recurrent state in step
        self.t += 1
        if self.policy_steps is not None and self.t > self.policy_steps:
            action = self.last_expert_action
        else:
            action = self.last_expert_action if self.rng.random() < self.beta else policy_action
        self.executed(action)
        return action

    def executed(self, action: int) -> None:
        """Pass the executed action on to the expert (its blocked-move check compares against it)."""
        tell_executed(self.expert, action)


class NoisyAgent:
    """DART-style noise injection (Laskey et al. 2017): with probability ``epsilon`` the executed action is
    replaced by one drawn uniformly from the task's moves (never STOP); the label stays the inner agent's.

    ``last_expert_action`` is the inner agent's label for the current state (an expert's own action, or a
    :class:`MixedAgent`'s expert label), so demonstrations get the expert's answer in states the expert
    would not have visited itself: after a random turn, next to walls, after a blocked move. The
    executed action is reported back to the inner agent (``executed``), so its blocked-move recovery
    sees what really happened. Seeded per episode: the same seed gives the same noise.
    """

    def __init__(self, inner, epsilon: float, actions: tuple[str, ...]):
        if not 0.0 <= epsilon <= 1.0:
            raise ValueError(f"noise epsilon must be in [0, 1], got {epsilon}")
        self.inner, self.epsilon = inner, float(epsilon)
        self.moves = np.array([i for i, a in enumerate(actions) if a != "STOP"], dtype=np.int64)
        self.rng = np.random.default_rng(0)
        self.last_expert_action: int | None = None
        self.noisy_steps = 0

    def reset(self, env, obs, seed: int = 0) -> None:
        self.inner.reset(env, obs, seed)
        self.rng = np.random.default_rng(np.random.SeedSequence([seed, 3]))
        self.noisy_steps = 0

    def act(self, obs, maps) -> int:
        action = int(self.inner.act(obs, maps))
        label = expert_label(self.inner)
        self.last_expert_action = action if label is None else int(label)
        if self.rng.random() < self.epsilon:
            action = int(self.rng.choice(self.moves))
            self.noisy_steps += 1
            tell_executed(self.inner, action)
        return action
