"""SL-GCN: the decoupled spatial-temporal GCN with attention and DropGraph that the thesis' chapter 4
calls ST-GCN (THESIS.md 2.1 and 10.2).

A re-implementation of the public code, module by module, with the same initialisation:
Jiang et al. 2021, "Skeleton Aware Multi-modal Sign Language Recognition" (jackyjsy/CVPR21Chal-SLR,
``SL-GCN/model/decouple_gcn_attn.py``, ``model/dropSke.py``, ``model/dropT.py``, ``graph/tools.py``),
itself built on Cheng et al. 2020, "Decoupling GCN with DropGraph Module for Skeleton-Based Action
Recognition" (kchengiva/DecoupleGCN-DropGraph); the thesis ran it from
tfederico/ASLPhoneticClassification ``SL-GCN/``. Differences, all forced by this code base:

* the graph comes from the data's :class:`KeypointLayout` (:func:`spatial_graph` orients its edges
  away from the layout's centre, which reproduces SL-GCN's ``sign_27`` listing on the 27-point
  layout, see ``aslexp.keypoints.slgcn27``); one person (M = 1);
* the feeder's per-clip normalisation (x and y minus the centre node's mean over the clip) is done
  here, over observed frames (``normalize``), so it applies to training and test alike;
* the keep-probability schedule (1.0 at epoch 0, falling linearly to ``keep_prob`` at epoch
  ``keep_prob_epochs``) and the frozen graph in the first ``freeze_graph_epochs`` epochs
  (``only_train_epoch``) live in :meth:`SLGCN.on_epoch_start`, which the trainer calls;
* the spatial DropGraph divides by ``max(mask.sum(), 1)`` where the original divides by a sum that
  can be 0.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from aslexp.data.dataset import KeypointLayout
from aslexp.recognition.models.graph import hop_distances


def spatial_graph(layout: KeypointLayout) -> np.ndarray:
    """(3, V, V) float32 [identity, inward, outward] as SL-GCN's ``graph.tools.get_spatial_graph``:
    ``edge2mat`` puts A[j, i] = 1 for a listed edge (i, j), ``normalize_digraph`` divides every
    column by its sum. Edges are oriented from the node nearer the layout's centre to the farther
    one (SL-GCN lists ``sign_27`` that way); equal distances keep the layout's order."""
    num_nodes = layout.num_nodes
    distance = hop_distances(num_nodes, layout.edges, layout.center)
    inward = []
    for i, j in layout.edges:
        if not (0 <= i < num_nodes and 0 <= j < num_nodes) or i == j:
            raise ValueError(f"layout '{layout.name}': bad edge ({i}, {j}) for {num_nodes} nodes")
        inward.append((j, i) if distance[j] < distance[i] else (i, j))

    def edge2mat(links: list[tuple[int, int]]) -> np.ndarray:
        matrix = np.zeros((num_nodes, num_nodes))
        for i, j in links:
            matrix[j, i] = 1
        return matrix

    def normalize_digraph(matrix: np.ndarray) -> np.ndarray:
        column = matrix.sum(axis=0)
        scale = np.where(column > 0, 1.0 / np.where(column > 0, column, 1.0), 0.0)
        return matrix @ np.diag(scale)

    identity = edge2mat([(i, i) for i in range(num_nodes)])
    outward = [(j, i) for i, j in inward]
    return np.stack([identity, normalize_digraph(edge2mat(inward)), normalize_digraph(edge2mat(outward))]).astype(np.float32)


def _conv_init(conv: nn.Conv2d | nn.Conv1d) -> None:
    nn.init.kaiming_normal_(conv.weight, mode="fan_out")
    nn.init.constant_(conv.bias, 0)


def _bn_init(bn: nn.BatchNorm2d | nn.BatchNorm1d, scale: float) -> None:
    nn.init.constant_(bn.weight, scale)
    nn.init.constant_(bn.bias, 0)


class DropGraphSpatial(nn.Module):
    """DropBlock_Ske: drop the graph neighbourhoods of randomly seeded joints (whole joints, all
    channels and frames), seeds drawn in proportion to each joint's mean activation."""

    def __init__(self, adjacency: torch.Tensor) -> None:
        super().__init__()
        self.register_buffer("adjacency", adjacency)  # (V, V): the three partitions summed

    def forward(self, x: torch.Tensor, keep_prob: float) -> torch.Tensor:
        if not self.training or keep_prob == 1:
            return x
        n, _, _, v = x.shape
        activity = x.abs().mean(dim=2).mean(dim=1).detach()  # (N, V)
        activity = activity / activity.sum() * activity.numel()
        gamma = (1.0 - keep_prob) / (1 + 1.92)  # SL-GCN's constant, whatever the skeleton
        seeds = torch.bernoulli(torch.clamp(activity * gamma, max=1.0)).to(x.dtype)
        dropped = (seeds @ self.adjacency.to(x.dtype)) > 0.001
        mask = (~dropped).to(x.dtype).view(n, 1, 1, v)
        return x * mask * mask.numel() / mask.sum().clamp(min=1.0)


class DropGraphTemporal(nn.Module):
    """DropBlockT_1d: drop blocks of ``block_size`` consecutive frames (all joints and channels)."""

    def __init__(self, block_size: int) -> None:
        super().__init__()
        self.block_size = block_size

    def forward(self, x: torch.Tensor, keep_prob: float) -> torch.Tensor:
        if not self.training or keep_prob == 1:
            return x
        n, _, t, _ = x.shape
        activity = x.abs().mean(dim=3).mean(dim=1).detach()  # (N, T)
        activity = (activity / activity.sum() * activity.numel()).view(n, 1, t)
        gamma = (1.0 - keep_prob) / self.block_size
        seeds = torch.bernoulli(torch.clamp(activity * gamma, max=1.0)).to(x.dtype)
        # The original repeats the seeds over C*V rows first; the mask and its mean are the same.
        blocks = F.max_pool1d(seeds, kernel_size=self.block_size, stride=1, padding=self.block_size // 2)
        mask = 1 - blocks[..., :t]
        return x * (mask * mask.numel() / mask.sum().clamp(min=1.0)).view(n, 1, t, 1)


class DecoupledGraphConvolution(nn.Module):
    """unit_gcn: a shared linear map to 3 x C_out channels, then per partition an adjacency that
    is learnt separately for each of ``groups`` channel groups (decoupled), column-normalised."""

    def __init__(self, in_channels: int, out_channels: int, graph: np.ndarray, groups: int) -> None:
        super().__init__()
        if out_channels % groups:
            raise ValueError(f"slgcn: block width {out_channels} is not a multiple of groups={groups}")
        self.num_subset, num_nodes = graph.shape[0], graph.shape[-1]
        self.out_channels, self.groups = out_channels, groups
        decoupled = torch.from_numpy(graph).reshape(self.num_subset, 1, num_nodes, num_nodes).repeat(1, groups, 1, 1)
        self.decoupled_adjacency = nn.Parameter(decoupled.clone())
        if in_channels != out_channels:
            self.down: nn.Module = nn.Sequential(nn.Conv2d(in_channels, out_channels, 1), nn.BatchNorm2d(out_channels))
        else:
            self.down = nn.Identity()
        self.bn0 = nn.BatchNorm2d(out_channels * self.num_subset)
        self.bn = nn.BatchNorm2d(out_channels)
        self.relu = nn.ReLU()
        for module in self.modules():
            if isinstance(module, nn.Conv2d):
                _conv_init(module)
            elif isinstance(module, nn.BatchNorm2d):
                _bn_init(module, 1)
        _bn_init(self.bn, 1e-6)
        self.linear_weight = nn.Parameter(torch.empty(in_channels, out_channels * self.num_subset))
        nn.init.normal_(self.linear_weight, 0, math.sqrt(0.5 / (out_channels * self.num_subset)))
        self.linear_bias = nn.Parameter(torch.full((1, out_channels * self.num_subset, 1, 1), 1e-6))

    def normalised_adjacency(self) -> torch.Tensor:
        """(3, C_out, V, V): group g's adjacency for channel c = g + k * groups (``repeat``), every
        column divided by its sum + 0.001 (SL-GCN's ``norm``)."""
        learnt = self.decoupled_adjacency.repeat(1, self.out_channels // self.groups, 1, 1)
        return learnt / (learnt.sum(dim=2, keepdim=True) + 0.001)

    def forward(self, x0: torch.Tensor) -> torch.Tensor:
        x = torch.einsum("nctw,cd->ndtw", x0, self.linear_weight) + self.linear_bias
        x = self.bn0(x)
        n, kc, t, v = x.shape
        x = x.view(n, self.num_subset, kc // self.num_subset, t, v)
        x = torch.einsum("nkctv,kcvw->nctw", x, self.normalised_adjacency())
        x = self.bn(x)
        x = x + self.down(x0)
        return self.relu(x)


class TemporalConvolution(nn.Module):
    """unit_tcn (kernel 9, optional stride, BN) followed by spatial and temporal DropGraph;
    with ``drop=False`` it is unit_tcn_skip (the residual branch)."""

    def __init__(self, in_channels: int, out_channels: int, *, kernel_size: int, stride: int,
                 adjacency: torch.Tensor | None = None, block_size: int = 41) -> None:  # fmt: skip
        super().__init__()
        pad = (kernel_size - 1) // 2
        self.conv = nn.Conv2d(in_channels, out_channels, (kernel_size, 1), padding=(pad, 0), stride=(stride, 1))
        self.bn = nn.BatchNorm2d(out_channels)
        _conv_init(self.conv)
        _bn_init(self.bn, 1)
        self.drop_spatial = DropGraphSpatial(adjacency) if adjacency is not None else None
        self.drop_temporal = DropGraphTemporal(block_size) if adjacency is not None else None

    def forward(self, x: torch.Tensor, keep_prob: float = 1.0) -> torch.Tensor:
        x = self.bn(self.conv(x))
        if self.drop_spatial is not None:
            x = self.drop_temporal(self.drop_spatial(x, keep_prob), keep_prob)
        return x


class SLGCNBlock(nn.Module):
    """TCN_GCN_unit: decoupled GCN, spatial/temporal/channel attention, TCN with DropGraph, and a
    residual branch with DropGraph."""

    def __init__(self, in_channels: int, out_channels: int, graph: np.ndarray, *, groups: int, block_size: int,
                 stride: int, residual: bool, attention: bool, temporal_kernel: int) -> None:  # fmt: skip
        super().__init__()
        num_nodes = graph.shape[-1]
        adjacency = torch.from_numpy(graph.sum(axis=0))
        self.gcn = DecoupledGraphConvolution(in_channels, out_channels, graph, groups)
        self.tcn = TemporalConvolution(out_channels, out_channels, kernel_size=temporal_kernel, stride=stride,
                                       adjacency=adjacency, block_size=block_size)  # fmt: skip
        self.relu = nn.ReLU()
        if not residual:
            self.residual: nn.Module | None = None
        elif in_channels == out_channels and stride == 1:
            self.residual = nn.Identity()
        else:
            self.residual = TemporalConvolution(in_channels, out_channels, kernel_size=1, stride=stride)
        self.drop_spatial = DropGraphSpatial(adjacency)
        self.drop_temporal = DropGraphTemporal(block_size)
        self.attention = attention
        if attention:
            self.sigmoid = nn.Sigmoid()
            self.conv_ta = nn.Conv1d(out_channels, 1, 9, padding=4)  # temporal attention
            nn.init.constant_(self.conv_ta.weight, 0)
            nn.init.constant_(self.conv_ta.bias, 0)
            kernel = num_nodes - 1 if not num_nodes % 2 else num_nodes  # spatial attention
            self.conv_sa = nn.Conv1d(out_channels, 1, kernel, padding=(kernel - 1) // 2)
            nn.init.xavier_normal_(self.conv_sa.weight)
            nn.init.constant_(self.conv_sa.bias, 0)
            self.fc1c = nn.Linear(out_channels, out_channels // 2)  # channel attention
            self.fc2c = nn.Linear(out_channels // 2, out_channels)
            nn.init.kaiming_normal_(self.fc1c.weight)
            nn.init.constant_(self.fc1c.bias, 0)
            nn.init.constant_(self.fc2c.weight, 0)
            nn.init.constant_(self.fc2c.bias, 0)

    def forward(self, x: torch.Tensor, keep_prob: float) -> torch.Tensor:
        y = self.gcn(x)
        if self.attention:
            weights = self.sigmoid(self.conv_sa(y.mean(-2)))  # (N, 1, V)
            y = y * weights.unsqueeze(-2) + y
            weights = self.sigmoid(self.conv_ta(y.mean(-1)))  # (N, 1, T)
            y = y * weights.unsqueeze(-1) + y
            weights = self.sigmoid(self.fc2c(self.relu(self.fc1c(y.mean(-1).mean(-1)))))  # (N, C)
            y = y * weights.unsqueeze(-1).unsqueeze(-1) + y
        y = self.tcn(y, keep_prob)
        if self.residual is None:
            return self.relu(y)
        skip = self.drop_temporal(self.drop_spatial(self.residual(x), keep_prob), keep_prob)
        return self.relu(y + skip)


class SLGCN(nn.Module):
    """(x (N, C, T, V), mask (N, T, V)) -> logits. Ten blocks of [64 x 4, 128 x 3, 256 x 3]
    channels by default, time halved where the width grows (blocks 5 and 8); DropGraph active from
    block ``drop_from_block`` (1-based; SL-GCN: 7) on."""

    def __init__(
        self,
        num_channels: int,
        num_classes: int,
        graph: np.ndarray,
        *,
        center: int,
        channels: list[int],
        groups: int,
        block_size: int,
        keep_prob: float,
        keep_prob_epochs: int,
        drop_from_block: int,
        freeze_graph_epochs: int,
        attention: bool,
        temporal_kernel: int,
        normalize: bool,
        mask_channel: bool,
        frame_stride: int,
    ) -> None:
        super().__init__()
        if not channels:
            raise ValueError("slgcn: channels must list at least one block width")
        if not 0 < keep_prob <= 1:
            raise ValueError(f"slgcn: keep_prob must be in (0, 1], got {keep_prob}")
        self.center, self.normalize, self.mask_channel, self.frame_stride = center, normalize, mask_channel, frame_stride
        self.target_keep_prob, self.keep_prob_epochs = keep_prob, max(1, keep_prob_epochs)
        self.freeze_graph_epochs, self.drop_from_block = freeze_graph_epochs, drop_from_block
        self.keep_prob = 1.0
        in_channels = num_channels + int(mask_channel)
        num_nodes = graph.shape[-1]
        self.data_bn = nn.BatchNorm1d(in_channels * num_nodes)
        _bn_init(self.data_bn, 1)
        blocks, previous = [], in_channels
        for index, width in enumerate(channels):
            stride = 2 if index > 0 and width > previous else 1
            blocks.append(SLGCNBlock(previous, width, graph, groups=groups, block_size=block_size, stride=stride,
                                     residual=index > 0, attention=attention, temporal_kernel=temporal_kernel))  # fmt: skip
            previous = width
        self.blocks = nn.ModuleList(blocks)
        self.fc = nn.Linear(previous, num_classes)
        nn.init.normal_(self.fc.weight, 0, math.sqrt(2.0 / num_classes))

    def on_epoch_start(self, epoch_index: int) -> None:
        """SL-GCN's schedule: keep_prob = 1 - (1 - keep_rate) * epoch / 100 until epoch 100, and the
        decoupled adjacencies frozen during the first ``freeze_graph_epochs`` epochs."""
        fraction = min(epoch_index, self.keep_prob_epochs) / self.keep_prob_epochs
        self.keep_prob = 1.0 - (1.0 - self.target_keep_prob) * fraction
        for block in self.blocks:
            block.gcn.decoupled_adjacency.requires_grad_(epoch_index >= self.freeze_graph_epochs)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        x, mask = x[:, :, :: self.frame_stride], mask[:, :: self.frame_stride]
        if self.normalize:  # the feeder's normalisation: x, y minus the centre node's clip mean
            observed = mask[:, :, self.center].to(x.dtype)  # (N, T)
            centre = (x[:, :2, :, self.center] * observed[:, None]).sum(dim=2) / observed.sum(dim=1).clamp(min=1)[:, None]
            spatial = x[:, :2] - centre[:, :, None, None] * mask[:, None].to(x.dtype)
            x = torch.cat([spatial, x[:, 2:]], dim=1)
        if self.mask_channel:
            x = torch.cat([x, mask.unsqueeze(1).to(x.dtype)], dim=1)
        n, c, t, v = x.shape
        x = self.data_bn(x.permute(0, 3, 1, 2).reshape(n, v * c, t))
        x = x.view(n, v, c, t).permute(0, 2, 3, 1).contiguous()
        for index, block in enumerate(self.blocks, start=1):
            x = block(x, self.keep_prob if index >= self.drop_from_block else 1.0)
        return self.fc(x.mean(dim=(2, 3)))
