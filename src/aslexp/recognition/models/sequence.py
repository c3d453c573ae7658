"""Non-graph torch classifiers: an MLP on the whole clip and LSTM/GRU over frames."""

from __future__ import annotations

import torch
from torch import nn


class MLP(nn.Module):
    """Flattened clip (C*T*V, missing joints at 0) -> hidden layers (ReLU, dropout) -> logits."""

    fixed_length = True  # its input size fixes T: a temporal crop is padded back (see augment.py)

    def __init__(self, num_inputs: int, num_classes: int, *, hidden_sizes: list[int], dropout: float) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        previous = num_inputs
        for width in hidden_sizes:
            layers += [nn.Linear(previous, width), nn.ReLU(inplace=True), nn.Dropout(dropout)]
            previous = width
        layers.append(nn.Linear(previous, num_classes))
        self.net = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return self.net(x.flatten(1))


class RecurrentClassifier(nn.Module):
    """LSTM or GRU over frames; the input per frame is all joints' coordinates plus their
    observed-mask (C*V + V values). Outputs are averaged over the frames in which at least
    one joint was observed, so padding and fully missing frames do not vote. ``frame_stride``
    keeps every n-th frame (the recurrence is sequential: its cost is linear in T).
    """

    def __init__(
        self,
        cell: str,
        num_inputs: int,
        num_classes: int,
        *,
        hidden_size: int,
        num_layers: int,
        bidirectional: bool,
        dropout: float,
        frame_stride: int,
        head_layers: int = 0,
        head_size: int | None = None,
        head_dropout: float | None = None,
    ) -> None:
        super().__init__()
        self.frame_stride = frame_stride
        recurrent = {"lstm": nn.LSTM, "gru": nn.GRU}[cell]
        self.rnn = recurrent(
            num_inputs, hidden_size, num_layers=num_layers, batch_first=True,
            bidirectional=bidirectional, dropout=dropout if num_layers > 1 else 0.0,
        )
        # The head: ``head_layers`` hidden linear layers (ReLU, dropout) before the output layer
        # (the thesis' "RNN + MLP in cascade"); 0 = dropout and one linear layer.
        width = hidden_size * (2 if bidirectional else 1)
        head_size = head_size or hidden_size
        head_dropout = dropout if head_dropout is None else head_dropout
        layers: list[nn.Module] = [nn.Dropout(dropout if head_layers == 0 else head_dropout)]
        for _ in range(head_layers):
            layers += [nn.Linear(width, head_size), nn.ReLU(inplace=True), nn.Dropout(head_dropout)]
            width = head_size
        self.head = nn.Sequential(*layers, nn.Linear(width, num_classes))

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        x, mask = x[:, :, :: self.frame_stride], mask[:, :: self.frame_stride]
        n, c, t, v = x.shape
        frames = torch.cat([x.permute(0, 2, 1, 3).reshape(n, t, c * v), mask], dim=2)
        outputs, _ = self.rnn(frames)  # (N, T, H*directions)
        observed = (mask.sum(dim=2) > 0).to(outputs.dtype).unsqueeze(2)  # (N, T, 1)
        pooled = (outputs * observed).sum(dim=1) / observed.sum(dim=1).clamp(min=1.0)
        return self.head(pooled)
