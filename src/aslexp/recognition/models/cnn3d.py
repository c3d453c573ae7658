"""A small 3D CNN over keypoint heat-map videos rendered on the fly.

Each joint becomes a Gaussian blob on an H x W grid spanning [-1, 1]^2 (the normalised x, y
coordinates), frame by frame; missing joints render nothing. Joints are either separate input
channels (V channels) or summed into one. Rendering happens per batch inside ``forward``, so a
data set of clips never exists as videos in memory. A Gaussian is separable, so the heat-map is
the outer product of a 1D profile in x and one in y: cheap to compute.
"""

from __future__ import annotations

import torch
from torch import nn


class HeatmapRenderer(nn.Module):
    """(x (N, C, T, V), mask (N, T, V)) -> heat-maps (N, V or 1, T', size, size), T' = ceil(T / frame_stride)."""

    def __init__(self, *, size: int, sigma: float, sum_joints: bool, xy_channels: tuple[int, int], frame_stride: int) -> None:
        super().__init__()
        if size < 4:
            raise ValueError(f"cnn3d: heatmap_size must be >= 4, got {size}")
        if sigma <= 0:
            raise ValueError(f"cnn3d: sigma must be > 0 (in normalised units, the grid spans 2), got {sigma}")
        self.sigma = float(sigma)
        self.sum_joints = sum_joints
        self.xy_channels = xy_channels
        self.frame_stride = frame_stride
        self.register_buffer("grid", torch.linspace(-1.0, 1.0, size))

    def profile(self, coordinate: torch.Tensor) -> torch.Tensor:
        """(N, T, V) -> (N, T, V, size) Gaussian profile along one axis."""
        return torch.exp(-((self.grid - coordinate.unsqueeze(-1)) ** 2) / (2 * self.sigma**2))

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        x = x[:, :, :: self.frame_stride]
        mask = mask[:, :: self.frame_stride]
        along_x = self.profile(x[:, self.xy_channels[0]]) * mask.unsqueeze(-1)
        along_y = self.profile(x[:, self.xy_channels[1]])
        if self.sum_joints:
            return torch.einsum("ntvh,ntvw->nthw", along_y, along_x).unsqueeze(1)
        return torch.einsum("ntvh,ntvw->nvthw", along_y, along_x)


class HeatmapCNN3D(nn.Module):
    """Heat-map video -> [Conv3d 3x3x3, BN, ReLU, MaxPool 2] per width -> global average -> linear."""

    def __init__(
        self,
        num_nodes: int,
        num_classes: int,
        *,
        channels: list[int],
        dropout: float,
        heatmap_size: int,
        sigma: float,
        sum_joints: bool,
        xy_channels: tuple[int, int],
        frame_stride: int,
    ) -> None:
        super().__init__()
        self.render = HeatmapRenderer(
            size=heatmap_size, sigma=sigma, sum_joints=sum_joints, xy_channels=xy_channels, frame_stride=frame_stride
        )
        layers: list[nn.Module] = []
        previous = 1 if sum_joints else num_nodes
        for width in channels:
            layers += [
                nn.Conv3d(previous, width, kernel_size=3, padding=1, bias=False),
                nn.BatchNorm3d(width),
                nn.ReLU(inplace=True),
                # ceil_mode keeps a length-1 axis alive when a short clip runs out of time steps.
                nn.MaxPool3d(kernel_size=2, ceil_mode=True),
            ]
            previous = width
        self.features = nn.Sequential(*layers)
        self.head = nn.Sequential(nn.Dropout(dropout), nn.Linear(previous, num_classes))

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        video = self.render(x, mask)
        return self.head(self.features(video).mean(dim=(2, 3, 4)))
