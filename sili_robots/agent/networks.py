"""Small torch building blocks: MLPs, a fused twin critic, a squashed-Gaussian actor."""

from __future__ import annotations

import math

import torch
from torch import nn

from sili_robots.agent.matmul import Linear, ensemble_linear


def mlp(inp: int, out: int, hidden: int, layers: int = 2, matmul: str = "aten") -> nn.Sequential:
    """``layers`` hidden layers of ``hidden`` units with ReLU (the paper's 2 x 256)."""
    mods: list[nn.Module] = []
    d = inp
    for _ in range(layers):
        mods += [Linear(d, hidden, matmul), nn.ReLU(inplace=True)]
        d = hidden
    mods.append(Linear(d, out, matmul))
    return nn.Sequential(*mods)


class EnsembleLinear(nn.Module):
    """``n`` independent linear layers: one batched matmul on ``aten``, one oneDNN product per
    layer on ``onednn`` (a width-1 layer, a critic's Q, as one weighted sum on both)."""

    def __init__(self, n: int, inp: int, out: int, matmul: str = "aten") -> None:
        super().__init__()
        self.matmul = matmul
        bound = 1.0 / math.sqrt(inp)
        self.weight = nn.Parameter(torch.empty(n, inp, out).uniform_(-bound, bound))
        self.bias = nn.Parameter(torch.empty(n, 1, out).uniform_(-bound, bound))

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # x: [n, B, inp]
        if self.weight.shape[-1] == 1:
            # a critic's Q: a weighted sum. As a product, into width 1 and (backward) as an
            # outer product, it runs 5-20x slower on MKL (benchmarks/RESULTS.md)
            return (x * self.weight.mT).sum(-1, keepdim=True) + self.bias
        out = ensemble_linear(x, self.weight, self.bias, self.matmul)
        if out is not None:
            return out
        if torch.is_autocast_enabled("cpu"):  # bfloat16: the bias is added before rounding
            return torch.baddbmm(self.bias, x, self.weight)
        # float32: bmm, then the bias added in place (the same result); baddbmm would first copy
        # the broadcast bias into a fresh output, one more pass over a [n, B, out] buffer
        return torch.bmm(x, self.weight).add_(self.bias)


class TwinCritic(nn.Module):
    """Both SAC critics fused: one [2, B, .] batched network instead of two modules."""

    def __init__(self, inp: int, hidden: int, n: int = 2, matmul: str = "aten") -> None:
        super().__init__()
        self.n = n
        self.l1 = EnsembleLinear(n, inp, hidden, matmul)
        self.l2 = EnsembleLinear(n, hidden, hidden, matmul)
        self.l3 = EnsembleLinear(n, hidden, 1, matmul)

    def forward(self, x: torch.Tensor, a: torch.Tensor) -> torch.Tensor:
        """Q-values of shape [n, B]."""
        h = torch.cat([x, a], dim=-1).unsqueeze(0).expand(self.n, -1, -1)
        h = torch.relu_(self.l1(h))  # in place: no second [n, B, hidden] buffer per layer
        h = torch.relu_(self.l2(h))
        return self.l3(h).squeeze(-1).float()  # float32 even under bfloat16 autocast


LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0


class Actor(nn.Module):
    """tanh-squashed Gaussian policy over actions in [-1, 1]^d (CleanRL's parameterisation)."""

    def __init__(self, inp: int, act_dim: int, hidden: int, matmul: str = "aten") -> None:
        super().__init__()
        self.trunk = nn.Sequential(
            Linear(inp, hidden, matmul),
            nn.ReLU(inplace=True),
            Linear(hidden, hidden, matmul),
            nn.ReLU(inplace=True),
        )
        self.head = Linear(hidden, 2 * act_dim, matmul)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        # float32 even under bfloat16 autocast: the distribution's arithmetic stays exact
        mean, log_std = self.head(self.trunk(x)).float().chunk(2, dim=-1)
        log_std = LOG_STD_MIN + 0.5 * (LOG_STD_MAX - LOG_STD_MIN) * (torch.tanh(log_std) + 1)
        return mean, log_std

    def _draw(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """A reparameterised pre-tanh action, with the noise and log-std that drew it."""
        mean, log_std = self(x)
        std = log_std.exp()
        eps = torch.randn_like(mean)
        return mean + std * eps, eps, log_std

    def sample(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A reparameterised action and its log-probability."""
        pre, eps, log_std = self._draw(x)
        action = torch.tanh(pre)
        logp = (-0.5 * eps.pow(2) - log_std - 0.5 * math.log(2 * math.pi)).sum(-1)
        logp = logp - (2 * (math.log(2) - pre - nn.functional.softplus(-2 * pre))).sum(-1)
        return action, logp

    def sample_action(self, x: torch.Tensor) -> torch.Tensor:
        """``sample(x)[0]`` (the same draw) without the log-probability acting does not use."""
        return torch.tanh(self._draw(x)[0])

    def deterministic(self, x: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self(x)[0])
