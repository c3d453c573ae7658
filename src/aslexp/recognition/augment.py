"""Training-time augmentation of keypoint batches, on the batch's device (any model).

Both follow SL-GCN's training feeder (jackyjsy/CVPR21Chal-SLR ``SL-GCN/feeders/feeder.py`` and
``feeders/tools.py``, as the thesis' code runs it), vectorised over the batch:

* :func:`random_temporal_crop` (``random_choose`` with ``window_size``): drop the trailing frames
  in which nothing was observed, then take ``window`` consecutive frames at a random start; a clip
  shorter than the window is placed at a random offset in an empty window (``auto_pading`` with
  ``random_pad``).
* :func:`random_shift` (``random_shift`` of the feeder): one random offset per clip, uniform in
  [-amplitude, amplitude), added to the spatial channels (x, y) of every observed keypoint. SL-GCN
  adds up to 10 pixels on 512-pixel frames; here coordinates are per-clip normalised to [-1, 1],
  so the amplitude is in those units (``conf/trainer/slgcn.yaml`` explains its value).

Random numbers come from a ``torch.Generator`` of their own, so a run without augmentation draws
exactly what it drew before augmentation existed.
"""

from __future__ import annotations

import torch


def random_temporal_crop(
    x: torch.Tensor, mask: torch.Tensor, window: int, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """x (N, C, T, V), mask (N, T, V) -> (N, C, window, V), (N, window, V)."""
    n, _, t, _ = x.shape
    observed = mask.amax(dim=2) > 0  # (N, T): frames with any keypoint
    frames = torch.arange(t, device=x.device)
    valid = torch.where(observed, frames + 1, torch.zeros_like(frames)).amax(dim=1).clamp(min=1)  # (N,)
    draw = torch.rand(n, generator=generator, device=generator.device).to(x.device)
    long_clip = valid >= window
    # long: start in [0, valid - window]; short: start in [-(window - valid), 0] (random padding)
    start = torch.where(
        long_clip,
        torch.floor(draw * (valid - window + 1).clamp(min=1)).long(),
        -torch.floor(draw * (window - valid + 1).clamp(min=1)).long(),
    )
    source = start[:, None] + torch.arange(window, device=x.device)[None, :]  # (N, window)
    inside = (source >= 0) & (source < valid[:, None])
    index = source.clamp(0, t - 1)
    cropped = torch.gather(x, 2, index[:, None, :, None].expand(-1, x.shape[1], -1, x.shape[3]))
    cropped_mask = torch.gather(mask, 1, index[:, :, None].expand(-1, -1, mask.shape[2]))
    cropped = cropped * inside[:, None, :, None]
    cropped_mask = cropped_mask * inside[:, :, None]
    return cropped, cropped_mask


def pad_frames(x: torch.Tensor, mask: torch.Tensor, length: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Pad a (cropped) batch back to ``length`` frames with unobserved zeros (for models with a
    fixed input length, e.g. the MLP)."""
    missing = length - x.shape[2]
    if missing <= 0:
        return x, mask
    return (torch.nn.functional.pad(x, (0, 0, 0, missing)), torch.nn.functional.pad(mask, (0, 0, 0, missing)))


def random_shift(
    x: torch.Tensor, mask: torch.Tensor, amplitude: float, channels: tuple[int, ...], generator: torch.Generator
) -> torch.Tensor:
    """Add one uniform offset in [-amplitude, amplitude) per clip and channel in ``channels`` to
    the observed keypoints of x (N, C, T, V); returns a new tensor."""
    n = x.shape[0]
    offsets = (torch.rand(n, len(channels), generator=generator, device=generator.device) * 2 - 1) * amplitude
    shifted = x.clone()
    observed = mask.to(x.dtype)
    for k, channel in enumerate(channels):
        shifted[:, channel] += offsets[:, k].to(x.device, x.dtype)[:, None, None] * observed
    return shifted
