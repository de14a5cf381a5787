"""Policy networks: NUE (uncertainty + feature maps of the NeRF memory), its ablations, and the FR / Nav-A3C / VGM baselines.

Every model shares one interface (:class:`PolicyModel`)::

    cfg = get_model_config("nue").for_task(task)
    model = build_model(cfg)
    inp = prepare_input(rgb, depth, goal_rgb, i_u, i_cog, cfg)     # PolicyInput, batch 1
    state = model.initial_state(1)
    out = model(inp, state)                                         # eval mode, under torch.no_grad()
    actions, state = choose_actions(out.logits, greedy=False, generator=g), out.state
    out = model.forward_sequence(batch_TB, state, reset_mask)      # training: logits (T, B, A)
    loss = F.cross_entropy(...) + lam * angle_l1_loss(out.aux_angle, target)  # aux_angle None without AT
"""

from nue.policy.base import (PolicyModel, PolicyOutput, State, angle_l1_loss, choose_actions, detach_state,
                             wrap_angle_t)
from nue.policy.baselines import FRPolicy, NavA3CPolicy
from nue.policy.blocks import CBAM, ChannelAttention, ConvBranch, ResidualBlock, SpatialAttention, SubsampledPointwiseConv
from nue.policy.config import ABLATION_PRESETS, MODEL_PRESETS, ModelConfig, get_model_config
from nue.policy.inputs import PolicyInput, prepare_goal, prepare_input
from nue.policy.nrns_model import DistanceNetwork
from nue.policy.nue_model import FusionHead, NUEPolicy
from nue.policy.vgm_model import VGMPolicy

_KINDS: dict[str, type[PolicyModel]] = {"nue": NUEPolicy, "fr": FRPolicy, "nav_a3c": NavA3CPolicy,
                                     "nrns": DistanceNetwork, "vgm": VGMPolicy}


def build_model(config: ModelConfig | str) -> PolicyModel:
    """The policy network a config (or preset name) describes, freshly initialised from torch's global RNG."""
    config = get_model_config(config)
    return _KINDS[config.kind](config)


__all__ = [
    "ABLATION_PRESETS", "CBAM", "ChannelAttention", "ConvBranch", "DistanceNetwork", "FRPolicy", "FusionHead", "MODEL_PRESETS",
    "ModelConfig", "NUEPolicy", "NavA3CPolicy", "PolicyInput", "PolicyModel", "PolicyOutput", "ResidualBlock",
    "SpatialAttention", "State", "SubsampledPointwiseConv", "VGMPolicy", "angle_l1_loss", "build_model", "choose_actions", "detach_state", "get_model_config",
    "prepare_goal", "prepare_input", "wrap_angle_t",
]
