"""VGM's visual graph memory as batched tensors: online localisation by embedding similarity, graph convolution and
attention read-outs (Kwon et al., ICCV 2021; :mod:`nue.policy.vgm_model` is the policy around it).

A batch of B graphs of at most N nodes is a :class:`ViewGraph` of fixed-size tensors, so it travels in the policy's
recurrent state (a tuple of tensors) and a whole batch is updated at once. One step of :func:`localise`, given the
current view's L2-normalised embedding e (cosine similarity = dot product, threshold th):

1. at an episode start the graph is emptied;
2. if e is at least th similar to the node the robot was last localised at, it stays there;
3. else, if some node is at least th similar, the robot is localised at the most similar one, that node takes e as
   its embedding, and an edge joins it to the previous node;
4. else e becomes a new node with an edge to the previous node (when the graph is full: step 3 with the most
   similar node, whatever its similarity, and the node keeps its embedding).

The visited node's time is set to the step count (node features carry the time since their last visit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn


@dataclass
class ViewGraph:
    """B graphs of at most N nodes of E-dim embeddings (every field's first dim is B)."""

    nodes: Tensor
    """(B, N, E) node embeddings (zeros where no node)."""
    mask: Tensor
    """(B, N) float, 1 where a node exists; nodes fill indices 0, 1, ... in the order they are added."""
    adj: Tensor
    """(B, N, N) float, symmetric 0/1 adjacency without self-loops."""
    visit: Tensor
    """(B, N) float, the step at which each node was last visited."""
    current: Tensor
    """(B,) long, the node the robot is localised at."""
    step: Tensor
    """(B,) float, steps since the episode started (0 at the first)."""

    @classmethod
    def empty(cls, batch: int, nodes: int, dim: int, device=None) -> "ViewGraph":
        z = torch.zeros(batch, nodes, device=device)
        return cls(torch.zeros(batch, nodes, dim, device=device), z, torch.zeros(batch, nodes, nodes, device=device),
                   z.clone(), torch.zeros(batch, dtype=torch.long, device=device),
                   torch.full((batch,), -1.0, device=device))

    def as_tuple(self) -> tuple[Tensor, ...]:
        return (self.nodes, self.mask, self.adj, self.visit, self.current, self.step)

    @property
    def num_nodes(self) -> Tensor:
        """(B,) long, nodes in each graph."""
        return self.mask.sum(1).long()


@torch.no_grad()
def localise(graph: ViewGraph, emb: Tensor, threshold: float, start: Tensor | None = None) -> ViewGraph:
    """The graph after one step with view embedding ``emb`` (B, E) (L2-normalised); ``start`` (B,) bool marks rows whose
    episode starts at this step (their graph is emptied first). Returns new tensors; ``graph`` is not modified."""
    b, n = graph.mask.shape
    rows = torch.arange(b, device=emb.device)
    emb = emb.to(graph.nodes.dtype)
    nodes, mask, adj, visit = graph.nodes.clone(), graph.mask.clone(), graph.adj.clone(), graph.visit.clone()
    cur, step = graph.current.clone(), graph.step + 1
    if start is not None:
        s = start.to(device=emb.device, dtype=torch.bool)
        keep = (~s).to(nodes.dtype)
        nodes, mask, adj, visit = nodes * keep[:, None, None], mask * keep[:, None], adj * keep[:, None, None], visit * keep[:, None]
        cur, step = torch.where(s, torch.zeros_like(cur), cur), torch.where(s, torch.zeros_like(step), step)
    had = mask.sum(1) > 0
    sim = torch.einsum("bne,be->bn", nodes, emb).masked_fill(mask == 0, -math.inf)
    stay = had & (sim[rows, cur] >= threshold)
    best_sim, best = sim.max(dim=1)
    count = mask.sum(1).long()
    full = count >= n
    move = ~stay & had & ((best_sim >= threshold) | full)
    add = ~stay & ~move
    new = torch.where(stay, cur, torch.where(move, best, count.clamp(max=n - 1)))
    write = add | (move & (best_sim >= threshold))
    nodes[rows[write], new[write]] = emb[write]
    mask[rows[add], new[add]] = 1.0
    link = had & (new != cur)
    adj[rows[link], cur[link], new[link]] = 1.0
    adj[rows[link], new[link], cur[link]] = 1.0
    visit[rows, new] = step
    return ViewGraph(nodes, mask, adj, visit, new, step)


def normalized_adjacency(adj: Tensor, mask: Tensor) -> Tensor:
    """GCN propagation matrix D^-1/2 (A + I) D^-1/2 over the existing nodes (Kipf & Welling 2017): ``adj`` (B, N, N),
    ``mask`` (B, N); rows and columns of empty nodes are zero (they neither send nor receive)."""
    a = (adj + torch.diag_embed(mask)) * mask[:, :, None] * mask[:, None, :]
    deg = a.sum(-1)
    inv = torch.where(deg > 0, deg.clamp(min=1e-12).rsqrt(), torch.zeros_like(deg))
    return inv[:, :, None] * a * inv[:, None, :]


class GraphConv(nn.Module):
    """Graph convolution layers ``H <- act(A_hat H W + b)`` (no activation after the last), ``(B, N, d_in) -> (B, N, d)``."""

    def __init__(self, d_in: int, d: int, layers: int, negative_slope: float = 0.01):
        super().__init__()
        self.linears = nn.ModuleList(nn.Linear(d_in if i == 0 else d, d) for i in range(layers))
        self.act = nn.LeakyReLU(negative_slope)

    def forward(self, x: Tensor, a_hat: Tensor) -> Tensor:
        for i, lin in enumerate(self.linears):
            x = a_hat @ lin(x)
            if i < len(self.linears) - 1:
                x = self.act(x)
        return x


def masked_attention(q: Tensor, k: Tensor, v: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
    """Scaled dot-product attention of one query per row over the existing nodes: ``q`` (B, H, d), ``k``/``v``
    (B, H, N, d), ``mask`` (B, N) -> (read-out (B, H, d), weights (B, H, N)); empty nodes get weight 0, and a row
    without nodes reads zeros."""
    scores = torch.einsum("bhd,bhnd->bhn", q, k) / math.sqrt(q.shape[-1])
    valid = mask[:, None, :] > 0
    scores = scores.masked_fill(~valid, -1e9 if scores.dtype == torch.float32 else -1e4)
    w = torch.softmax(scores, dim=-1) * valid
    return torch.einsum("bhn,bhnd->bhd", w, v), w


class ReadOut(nn.Module):
    """Attention read-out of the graph with one query vector (a transformer decoder step, as VGM's): multi-head
    attention of the query over the node features, residual and LayerNorm, feed-forward, residual and LayerNorm.
    ``(query (B, d), nodes (B, N, d), mask (B, N)) -> (B, d)``; ``last_weights`` keeps the attention (B, heads, N)."""

    def __init__(self, d: int, heads: int, hidden: int, negative_slope: float = 0.01):
        super().__init__()
        self.heads = heads
        self.q, self.k, self.v, self.o = (nn.Linear(d, d) for _ in range(4))
        self.norm1, self.norm2 = nn.LayerNorm(d), nn.LayerNorm(d)
        self.ff = nn.Sequential(nn.Linear(d, hidden), nn.LeakyReLU(negative_slope), nn.Linear(hidden, d))
        self.last_weights: Tensor | None = None

    def forward(self, query: Tensor, nodes: Tensor, mask: Tensor) -> Tensor:
        b, n, d = nodes.shape
        h = self.heads

        def split(x: Tensor) -> Tensor:
            return x.reshape(b, n, h, d // h).transpose(1, 2)

        read, w = masked_attention(self.q(query).reshape(b, h, d // h), split(self.k(nodes)), split(self.v(nodes)), mask)
        self.last_weights = w.detach()
        x = self.norm1(query + self.o(read.reshape(b, d)))
        return self.norm2(x + self.ff(x))


def time_encoding(dt: Tensor, dim: int, scale: float = 10_000.0) -> Tensor:
    """Sinusoidal encoding (Vaswani et al. 2017) of step counts ``dt`` (...,) -> (..., dim), dim even: sin at the even,
    cos at the odd positions, frequencies ``scale ** (-2i / dim)``."""
    i = torch.arange(0, dim, 2, device=dt.device, dtype=torch.float32)
    ang = dt.float()[..., None] * torch.exp(-math.log(scale) * i / dim)
    out = torch.zeros(*dt.shape, dim, device=dt.device)
    out[..., 0::2] = torch.sin(ang)
    out[..., 1::2] = torch.cos(ang)
    return out
