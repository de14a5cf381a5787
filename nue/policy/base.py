"""The interface every policy shares (NUE, its ablations, FR, Nav-A3C), so training and evaluation never branch on type.

* ``forward(inp, state, reset_mask) -> PolicyOutput(logits (B, A), aux_angle (B,) | None, state)``
* ``forward_sequence(inp (T, B, ...), state, reset_mask (T, B)) -> PolicyOutput((T, B, A), (T, B) | None, state)``
* ``initial_state(batch_size, device)``; actions (B,) from the logits with :func:`choose_actions`

``state`` is None for the reactive models, the LSTM's ``(h, c)``, each (B, lstm_dim), for
Nav-A3C and the GRU's ``(h,)`` for NUE with ``gru_dim > 0``. ``reset_mask`` (bool) marks rows whose episode starts at that step: their state is
replaced by the initial state before the step (reactive models ignore it).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from nue.policy.config import ModelConfig
from nue.policy.inputs import PolicyInput

State = tuple[Tensor, ...] | None
"""Recurrent state: None (reactive models), the LSTM's (h, c) or the GRU's (h,), each (B, hidden)."""


@dataclass
class PolicyOutput:
    """``logits``: (B, A) (or (T, B, A)) unnormalised action scores; ``aux_angle``: predicted goal
    angle in radians wrapped to (-pi, pi], (B,) (or (T, B)), None without the auxiliary head;
    ``state``: the state after the step(s); ``goal_view`` / ``goal_log_distance``: the exploitation head's
    goal-in-view logit and log distance to the goal in metres, (B,) (or (T, B)), None without it."""

    logits: Tensor
    aux_angle: Tensor | None
    state: State
    goal_view: Tensor | None = None
    goal_log_distance: Tensor | None = None


def wrap_angle_t(a: Tensor) -> Tensor:
    """Differentiable wrap to (-pi, pi]: ``atan2(sin a, cos a)`` (gradient 1 away from the seam)."""
    return torch.atan2(torch.sin(a), torch.cos(a))


def angle_l1_loss(pred: Tensor, target: Tensor) -> Tensor:
    """Auxiliary-task loss ``mean |wrap(pred - target)|`` in radians.

    Wrapping the difference makes a goal behind the robot (pred = pi - 0.1, target = -pi + 0.1)
    cost 0.2, not 2 pi - 0.2. Values lie in [0, pi].
    """
    return wrap_angle_t(pred - target).abs().mean()


def detach_state(state: State) -> State:
    """Cut the gradient through a recurrent state (truncated BPTT between training chunks)."""
    return None if state is None else tuple(s.detach() for s in state)


def choose_actions(logits: Tensor, greedy: bool = False, generator: torch.Generator | None = None,
                   temperature: float = 1.0) -> Tensor:
    """Actions (B,) long from ``logits`` (B, A): argmax if ``greedy`` or ``temperature`` is 0, else a sample from
    softmax(logits / temperature) (eq. 14 at temperature 1; below 1 the likelier actions gain), drawn on the
    ``generator``'s device (the logits move there)."""
    if greedy or temperature == 0:
        return logits.argmax(dim=-1)
    logits = logits.float() if temperature == 1 else logits.float() / temperature
    probs = torch.softmax(logits.to(generator.device if generator is not None else logits.device), dim=-1)
    return torch.multinomial(probs, 1, generator=generator)[:, 0]


class PolicyModel(nn.Module):
    """Base class: holds the config, implements ``forward_sequence`` by folding T into B."""

    def __init__(self, config: ModelConfig):
        super().__init__()
        self.config = config

    def initial_state(self, batch_size: int, device: torch.device | str | None = None) -> State:
        """State at an episode start (None for reactive models)."""
        return None

    def forward(self, inp: PolicyInput, state: State = None, reset_mask: Tensor | None = None) -> PolicyOutput:
        raise NotImplementedError

    def forward_sequence(
        self, inp: PolicyInput, state: State = None, reset_mask: Tensor | None = None
    ) -> PolicyOutput:
        """Run T steps of a (T, B, ...) batch; reactive models fold T into B (one big batch)."""
        t, b = inp.rgbd.shape[:2]
        out = self.forward(inp.flatten_time(), None)

        def tb(x):
            return None if x is None else x.reshape(t, b)

        return PolicyOutput(out.logits.reshape(t, b, -1), tb(out.aux_angle), state, tb(out.goal_view),
                            tb(out.goal_log_distance))

    def _check_input(self, inp: PolicyInput) -> None:
        c = self.config
        if inp.rgbd.ndim != 4 or inp.rgbd.shape[1] != 4:
            raise ValueError(f"rgbd: expected (B, 4, h, w), got {tuple(inp.rgbd.shape)}")
        if inp.goal.ndim != 4 or inp.goal.shape[1] != 3:
            raise ValueError(f"goal: expected (B, 3, h, w), got {tuple(inp.goal.shape)}")
        if c.uses_i_u and inp.i_u is None:
            raise ValueError(f"model {c.name!r} reads the uncertainty map, but inp.i_u is None")
        if c.uses_i_cog and inp.i_cog is None:
            raise ValueError(f"model {c.name!r} reads the feature map, but inp.i_cog is None")

    def num_parameters(self) -> int:
        """Number of trainable parameters."""
        return sum(p.numel() for p in self.parameters() if p.requires_grad)
