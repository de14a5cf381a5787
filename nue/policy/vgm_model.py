"""VGM (Visual Graph Memory, Kwon et al., ICCV 2021) as a nue policy, adapted to one 90-degree RGB-D camera.

Per step, with the graph memory of :mod:`nue.policy.graph_memory` carried in the recurrent state::

    e_t   = normalize(embed(rgb_t))            frozen embedding network, trained contrastively without labels
    e_g   = normalize(embed(goal))              (nue.train.contrastive) before imitation; the graph's node features
    G_t   = localise(G_{t-1}, e_t)              a new node where e_t is below the threshold to every node
    x_i   = MLP([node_i + time_enc(t - visit_i), e_g])        node features fused with the goal's embedding
    X     = GCN(x, D^-1/2 (A + I) D^-1/2) + time_enc(t - visit)
    f_o   = enc_o(rgbd_t);  f_g = enc_g(goal)   trainable encoders (RGB-D frame; goal RGB)
    r_o   = ReadOut_o(W f_o, X);  r_g = ReadOut_g(W' f_g, X)  attention read-outs, observation / goal as query
    h_t   = LSTMCell(MLP([f_o, r_o, r_g]), h_{t-1});   logits = MLP(h_t)

State: ``(h, c, nodes, mask, adj, visit, current, step)`` (the LSTM's and :class:`ViewGraph`'s tensors). The graph is
built in the forward pass from the frames themselves (no pose), so training on (T, B) sequences builds each sequence's
graph from its own frames, as the agent does along an episode. The embedding network stays in eval mode and gets no
gradient: the localisation threshold keeps its meaning while the policy trains.

Adaptation to the single camera (VGM stored 360-degree panoramas): a node is a *view* (a place and a heading), not a
place; the embedding reads RGB only, so the goal photo (RGB) and the frames share one space for localisation and goal
fusion; depth enters the trainable observation encoder. See docs/vgm.md.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from nue.policy.base import PolicyModel, PolicyOutput, State, wrap_angle_t
from nue.policy.blocks import ConvBranch, mlp
from nue.policy.config import ModelConfig
from nue.policy.graph_memory import GraphConv, ReadOut, ViewGraph, localise, normalized_adjacency, time_encoding
from nue.policy.inputs import PolicyInput


class EmbeddingNet(torch.nn.Module):
    """RGB view -> L2-normalised embedding: ``(B, 3, h, w) in [0, 1] -> (B, embed_dim)``, unit length."""

    def __init__(self, config: ModelConfig):
        super().__init__()
        c = config
        self.branch = ConvBranch(3, c.embed_channels, c.embed_grid, c.embed_dim, negative_slope=c.negative_slope)
        self.proj = torch.nn.Linear(c.embed_dim, c.embed_dim)

    def forward(self, rgb: Tensor) -> Tensor:
        return F.normalize(self.proj(self.branch(rgb)), dim=-1)


class VGMPolicy(PolicyModel):
    """Submodules ``embed`` (frozen :class:`EmbeddingNet`), ``obs_encoder``, ``goal_encoder``, ``node_fusion``,
    ``gcn``, ``read_obs``, ``read_goal``, ``fusion``, ``lstm``, ``policy``, ``aux_head`` (or None). After a forward,
    ``last_graph`` is the :class:`ViewGraph` of the last step (for viewers and diagnostics)."""

    def __init__(self, config: ModelConfig):
        if config.kind != "vgm":
            raise ValueError(f"VGMPolicy needs kind 'vgm', got {config.kind!r}")
        super().__init__(config)
        c, s = config, config.negative_slope
        self.embed = EmbeddingNet(c)
        self.embed.requires_grad_(False)
        self.obs_encoder = ConvBranch(4, c.perception_channels, c.perception_grid, c.perception_dim, negative_slope=s)
        self.goal_encoder = ConvBranch(3, c.perception_channels, c.perception_grid, c.perception_dim, negative_slope=s)
        self.node_fusion = mlp([2 * c.embed_dim, c.memory_dim, c.memory_dim], s)
        self.gcn = GraphConv(c.memory_dim, c.memory_dim, c.gcn_layers, s)
        self.obs_query = torch.nn.Linear(c.perception_dim, c.memory_dim)
        self.goal_query = torch.nn.Linear(c.perception_dim, c.memory_dim)
        self.read_obs = ReadOut(c.memory_dim, c.attention_heads, 2 * c.memory_dim, s)
        self.read_goal = ReadOut(c.memory_dim, c.attention_heads, 2 * c.memory_dim, s)
        self.fusion = mlp([c.perception_dim + 2 * c.memory_dim, c.fusion_dim], s)
        self.lstm = torch.nn.LSTMCell(c.fusion_dim, c.lstm_dim)
        self.policy = mlp([c.lstm_dim, c.head_hidden, c.num_actions], s, final_activation=False)
        self.aux_head = mlp([c.lstm_dim, c.aux_hidden, 1], s, final_activation=False) if c.use_aux else None
        self.last_graph: ViewGraph | None = None
        self._goal_cache: tuple[Tensor, tuple, Tensor, Tensor] | None = None
        """(goal tensor, (its version, dtype), e_g, f_g) of the last eval-mode call; holding the tensor keeps its
        identity unique. Cleared by ``train()`` / ``eval()``."""

    def train(self, mode: bool = True) -> "VGMPolicy":
        """As ``nn.Module.train``, but the frozen embedding network stays in eval mode (its BatchNorm statistics fixed)."""
        super().train(mode)
        self.embed.eval()
        self._goal_cache = None
        return self

    def initial_state(self, batch_size: int, device: torch.device | str | None = None) -> State:
        if device is None:
            device = next(self.parameters()).device
        z = torch.zeros(batch_size, self.config.lstm_dim, device=device)
        graph = ViewGraph.empty(batch_size, self.config.graph_nodes, self.config.embed_dim, device)
        return (z, z.clone(), *graph.as_tuple())

    # --- per-frame parts (batched over all T * B frames of a sequence) -------------------------------------------
    def _frames(self, inp: PolicyInput) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """(e_t, e_g, f_o, f_g) of a flat batch: the frozen embeddings in float32 (outside autocast, so the threshold
        compares the same numbers in training and evaluation) and the trainable features."""
        self._check_input(inp)
        goal = inp.goal
        if goal.shape[-2:] != inp.rgbd.shape[-2:]:
            goal = F.interpolate(goal, size=tuple(inp.rgbd.shape[-2:]), mode="area")
        with torch.no_grad(), torch.autocast(inp.rgbd.device.type, enabled=False):
            e_t = self.embed(inp.rgbd[:, :3].float())
        e_g, f_g = self._goal_parts(inp.goal, goal, inp.rgbd.dtype)
        return e_t, e_g, self.obs_encoder(inp.rgbd), f_g

    def _goal_parts(self, raw: Tensor, goal: Tensor, dtype: torch.dtype) -> tuple[Tensor, Tensor]:
        """(e_g, f_g) of the goal photo; in eval mode kept while the same goal tensor comes back unchanged (the agent
        passes one prepared goal for a whole episode), so an agent step encodes the goal once per episode."""
        kept = self._goal_cache
        if not self.training and kept is not None and kept[0] is raw and kept[1] == (raw._version, dtype):
            return kept[2], kept[3]
        with torch.no_grad(), torch.autocast(goal.device.type, enabled=False):
            e_g = self.embed(goal.float())
        f_g = self.goal_encoder(goal.to(dtype))
        self._goal_cache = (raw, (raw._version, dtype), e_g, f_g) if not self.training else None
        return e_g, f_g

    def _step(self, e_t: Tensor, e_g: Tensor, f_o: Tensor, f_g: Tensor, state: State,
              reset: Tensor | None) -> tuple[Tensor, State]:
        """One step of graph update, read-out and LSTM: (h_t, new state)."""
        if state is None:
            state = self.initial_state(e_t.shape[0], e_t.device)
        assert state is not None
        h, c, *g = state
        if reset is not None:
            keep = (~reset.to(device=h.device, dtype=torch.bool)).to(h.dtype)[:, None]
            h, c = h * keep, c * keep
        graph = localise(ViewGraph(*g), e_t, self.config.graph_threshold, reset)
        self.last_graph = graph
        n = max(int(graph.num_nodes.max()), 1)  # the graph convolution and attention see the used slots only
        mask, nodes = graph.mask[:, :n], graph.nodes[:, :n]
        age = (graph.step[:, None] - graph.visit[:, :n]).clamp(min=0)
        x = torch.cat([nodes + time_encoding(age, nodes.shape[-1]).to(nodes.dtype),
                       e_g[:, None].expand(-1, n, -1).to(nodes.dtype)], dim=-1)
        x = self.node_fusion(x) * mask[..., None]
        x = self.gcn(x, normalized_adjacency(graph.adj[:, :n, :n], mask).to(x.dtype))
        # the time again after the convolution (as VGM): it smooths neighbours alike (two linked nodes come out equal)
        x = x + time_encoding(age, x.shape[-1]).to(x.dtype) * mask[..., None]
        r_o = self.read_obs(self.obs_query(f_o), x, mask)
        r_g = self.read_goal(self.goal_query(f_g), x, mask)
        h, c = self.lstm(self.fusion(torch.cat([f_o, r_o, r_g], dim=-1)), (h, c))
        return h, (h, c, *graph.as_tuple())

    def _outputs(self, h: Tensor, state: State) -> PolicyOutput:
        aux = None if self.aux_head is None else wrap_angle_t(self.aux_head(h)[:, 0])
        return PolicyOutput(self.policy(h), aux, state)

    def forward(self, inp: PolicyInput, state: State = None, reset_mask: Tensor | None = None) -> PolicyOutput:
        h, state = self._step(*self._frames(inp), state, reset_mask)
        return self._outputs(h, state)

    def forward_sequence(self, inp: PolicyInput, state: State = None, reset_mask: Tensor | None = None) -> PolicyOutput:
        """Encode all T * B frames in one batch, then step graph, read-outs and LSTM through time."""
        t, b = inp.rgbd.shape[:2]
        parts = [p.reshape(t, b, -1) for p in self._frames(inp.flatten_time())]
        hs = []
        for i in range(t):
            h, state = self._step(parts[0][i], parts[1][i], parts[2][i], parts[3][i], state,
                                  None if reset_mask is None else reset_mask[i])
            hs.append(h)
        out = self._outputs(torch.cat(hs, dim=0), state)
        aux = None if out.aux_angle is None else out.aux_angle.reshape(t, b)
        return PolicyOutput(out.logits.reshape(t, b, -1), aux, state)
