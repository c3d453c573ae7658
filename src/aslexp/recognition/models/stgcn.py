"""Spatial-temporal graph convolutional network (ST-GCN, Yan et al. 2018; as used by SL-GCN).

A block = graph convolution over the skeleton (one 1x1 convolution per partition of the
adjacency, see :mod:`.graph`), batch norm, ReLU, temporal convolution (kernel 9 by default) with
stride 2 where the channel count grows, batch norm, dropout, and a residual connection.
Optional learnable edge importance (ST-GCN) and an additive learnable adjacency (2s-AGCN/SL-GCN
"adaptive" graph, initialised at zero so training starts from the skeleton).
"""

from __future__ import annotations

import torch
from torch import nn


class GraphConvolution(nn.Module):
    """x (N, C_in, T, V) -> (N, C_out, T, V): sum over partitions k of A_k x W_k."""

    def __init__(self, in_channels: int, out_channels: int, adjacency: torch.Tensor, edge_importance: bool, adaptive: bool) -> None:
        super().__init__()
        self.num_partitions = adjacency.shape[0]
        self.register_buffer("adjacency", adjacency)
        self.conv = nn.Conv2d(in_channels, out_channels * self.num_partitions, kernel_size=1)
        self.edge_importance = nn.Parameter(torch.ones_like(adjacency)) if edge_importance else None
        self.adaptive = nn.Parameter(torch.zeros_like(adjacency)) if adaptive else None

    def effective_adjacency(self) -> torch.Tensor:
        adjacency = self.adjacency
        if self.edge_importance is not None:
            adjacency = adjacency * self.edge_importance
        if self.adaptive is not None:
            adjacency = adjacency + self.adaptive
        return adjacency

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n, _, t, v = x.shape
        y = self.conv(x).view(n, self.num_partitions, -1, t, v)
        # A[k, w, v]: node v feeds node w.
        return torch.einsum("nkctv,kwv->nctw", y, self.effective_adjacency())


class STGCNBlock(nn.Module):
    def __init__(
        self,
        in_channels: int,
        out_channels: int,
        adjacency: torch.Tensor,
        *,
        temporal_kernel: int,
        stride: int,
        dropout: float,
        residual: bool,
        edge_importance: bool,
        adaptive: bool,
    ) -> None:
        super().__init__()
        if temporal_kernel % 2 != 1:
            raise ValueError(f"stgcn: temporal_kernel must be odd, got {temporal_kernel}")
        self.gcn = GraphConvolution(in_channels, out_channels, adjacency, edge_importance, adaptive)
        padding = (temporal_kernel - 1) // 2
        self.tcn = nn.Sequential(
            nn.BatchNorm2d(out_channels),
            nn.ReLU(inplace=True),
            nn.Conv2d(out_channels, out_channels, (temporal_kernel, 1), (stride, 1), (padding, 0)),
            nn.BatchNorm2d(out_channels),
            nn.Dropout(dropout),
        )
        if not residual:
            self.residual: nn.Module | None = None
        elif in_channels == out_channels and stride == 1:
            self.residual = nn.Identity()
        else:
            self.residual = nn.Sequential(
                nn.Conv2d(in_channels, out_channels, kernel_size=1, stride=(stride, 1)), nn.BatchNorm2d(out_channels)
            )
        self.relu = nn.ReLU(inplace=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.tcn(self.gcn(x))
        if self.residual is not None:
            y = y + self.residual(x)
        return self.relu(y)


class STGCN(nn.Module):
    """(x (N, C, T, V), mask (N, T, V)) -> logits (N, num_classes).

    ``mask_channel`` appends the observed-mask as an input channel, so a missing joint (zeros)
    is distinguishable from a joint at the origin. ``frame_stride`` keeps every n-th frame
    (cost is linear in T; 25 fps clips lose little at 12.5 fps).
    """

    def __init__(
        self,
        num_channels: int,
        num_classes: int,
        adjacency: torch.Tensor,
        *,
        channels: list[int],
        temporal_kernel: int,
        dropout: float,
        residual: bool,
        edge_importance: bool,
        adaptive: bool,
        mask_channel: bool,
        frame_stride: int,
    ) -> None:
        super().__init__()
        self.frame_stride = frame_stride
        if not channels:
            raise ValueError("stgcn: channels must list at least one block width")
        self.mask_channel = mask_channel
        in_channels = num_channels + int(mask_channel)
        num_nodes = adjacency.shape[-1]
        self.data_bn = nn.BatchNorm1d(in_channels * num_nodes)
        blocks = []
        previous = in_channels
        for index, width in enumerate(channels):
            # Halve time where the width grows (as ST-GCN does); the first block has no residual.
            stride = 2 if index > 0 and width > previous else 1
            blocks.append(
                STGCNBlock(
                    previous, width, adjacency,
                    temporal_kernel=temporal_kernel, stride=stride, dropout=dropout,
                    residual=residual and index > 0, edge_importance=edge_importance, adaptive=adaptive,
                )
            )
            previous = width
        self.blocks = nn.Sequential(*blocks)
        self.head = nn.Sequential(nn.Dropout(dropout), nn.Linear(previous, num_classes))

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        x, mask = x[:, :, :: self.frame_stride], mask[:, :: self.frame_stride]
        if self.mask_channel:
            x = torch.cat([x, mask.unsqueeze(1)], dim=1)
        n, c, t, v = x.shape
        # Normalise every (joint, channel) pair over the batch and time, as ST-GCN's data_bn.
        x = self.data_bn(x.permute(0, 3, 1, 2).reshape(n, v * c, t))
        x = x.view(n, v, c, t).permute(0, 2, 3, 1).contiguous()
        x = self.blocks(x)
        return self.head(x.mean(dim=(2, 3)))
