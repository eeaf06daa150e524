"""Training-time dropout with torch's own CPU mask, drawn ~1.7x cheaper.

``torch.nn.Dropout`` on a CPU float tensor computes ``x * (bernoulli_(1 - p) / (1 - p))``; on
this torch build the scalar ``bernoulli_`` kernel draws one uniform double per element in
memory order, serially (``at::bernoulli_distribution<double>``: ``u < 1 - p`` with ``u`` from
two 32-bit Mersenne-Twister outputs), about 9 ns an element. ``torch.rand(..., float64)``
draws the very same doubles from the same generator, in the same order, in about 4 ns, so
``rand < 1 - p`` is the same mask and leaves the generator in the same state. In GRIP's
training the 8 dropouts of ANet's forward were 21 % of a training step (256 samples, hidden
256; measured with ``time.thread_time``, 1 thread).

The equality is a property of torch's kernels, not a documented contract, so
:func:`uniform_mask_matches` checks it once per process on a private generator (mask and
generator state after the draw) and :class:`UniformMaskDropout` falls back to
``torch.nn.Dropout``'s own path where it does not hold, and for anything but a contiguous
float32 CPU tensor in training mode (CUDA's fused dropout draws differently).
"""

from __future__ import annotations

import functools

import torch
from torch import nn

# elements of the one-off check: above the kernels' small-size paths, a few microseconds
_CHECK_ELEMENTS = 4099
_CHECK_SEED = 20240917
_CHECK_KEEP = (0.7, 0.5, 0.9)  # keep probabilities checked (GRIP's dropout is 0.3)


@functools.cache
def uniform_mask_matches() -> bool:
    """Whether this torch's CPU ``bernoulli_(keep)`` equals ``rand(float64) < keep`` bit for
    bit and leaves the generator where ``rand`` does (checked on a private generator, so
    the global random state is not touched)."""
    for keep in _CHECK_KEEP:
        a, b = torch.Generator(), torch.Generator()
        a.manual_seed(_CHECK_SEED)
        b.manual_seed(_CHECK_SEED)
        mask = torch.empty(_CHECK_ELEMENTS).bernoulli_(keep, generator=a)
        same = torch.rand(_CHECK_ELEMENTS, dtype=torch.float64, generator=b) < keep
        if not (torch.equal(mask, same.to(mask.dtype)) and torch.equal(a.get_state(),
                                                                        b.get_state())):
            return False
    return True


class UniformMaskDropout(nn.Dropout):
    """``nn.Dropout`` whose CPU float32 training path draws the mask as uniform doubles: the
    same values, gradients and random state as ``nn.Dropout`` (module docstring)."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not (self.training and not self.inplace and 0.0 < self.p < 1.0
                and x.device.type == "cpu" and x.dtype == torch.float32 and x.is_contiguous()
                and x.numel() > 0 and uniform_mask_matches()):
            return super().forward(x)
        keep = 1.0 - self.p  # the double at::dropout computes
        noise = (torch.rand(x.shape, dtype=torch.float64) < keep).to(x.dtype)
        noise.div_(keep)  # at::dropout's steps: 0/1 noise, divided in place, then one product
        return x * noise


def use_uniform_mask_dropout(net: nn.Module) -> nn.Module:
    """Replace every plain ``nn.Dropout`` inside ``net`` by :class:`UniformMaskDropout` (same
    ``p``); returns ``net``. Dropout holds no parameters or buffers, so state dicts and
    checkpoints are unchanged."""
    for module in list(net.modules()):
        for name, child in list(module.named_children()):
            if type(child) is nn.Dropout:
                setattr(module, name, UniformMaskDropout(child.p, child.inplace))
    return net
