"""Loss terms on hand-object distances shared by GRIP and the learned baselines.

GRIP's proximity L1 (Eq. 1's ``exp(-50 d)`` compared between prediction and ground truth)
and a penetration term; RNet's loss and ManipNet-style's ``ContactTerms`` both use them, so
they live below both (``docs/architecture.md``, layer ``nn``).
"""

from __future__ import annotations

import torch

from ..core import constants as C


def proximity_attention(signed_distance: torch.Tensor) -> torch.Tensor:
    """GRIP Eq. 1 on signed distances (m): ``exp(-50 d)``, 1 inside the object."""
    return torch.exp(-C.PROXIMITY_DECAY * torch.relu(signed_distance))


def proximity_l1(pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """Mean absolute proximity-feature error; pred, gt (..., 2, P) in exp(-50 d) units."""
    return (pred - gt).abs().mean()


def penetration_depth(
    signed_distance: torch.Tensor, mask: torch.Tensor | None = None
) -> torch.Tensor:
    """Summed depth (m) of the vertices inside the object, averaged over the hands.

    signed_distance (..., V) of each hand's vertices (negative inside); mask (...) bool or
    float selects the hands that count (None: all). Zero for a hand that touches without
    entering, so it pushes fingers out of the object and never away from its surface.
    """
    depth = torch.relu(-signed_distance).sum(-1)  # (...)
    if mask is None:
        return depth.mean()
    w = mask.to(depth.dtype)
    return (depth * w).sum() / w.sum().clamp(min=1.0)
