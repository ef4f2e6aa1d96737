"""Soft actor-critic (twin critics, Polyak targets, learned entropy temperature).

Readable like CleanRL's SAC, with the per-update work trimmed: both critics are one batched
network (``TwinCritic``), the target network is updated with one fused ``_foreach_lerp_``, the
actor's and critics' optimizers are fused Adam, actor and temperature losses share one backward
pass, activations are computed in place, and no gradient is computed that no optimizer uses.
There are no terminal states here: the repeated game never ends, so targets always bootstrap
(also across interactions).

``precision="bfloat16"`` runs the forward passes of an update under CPU autocast: matrix
products in bfloat16 (on CPUs with bfloat16 units, e.g. AVX512-BF16 or AMX, they run faster),
while weights, gradients, optimizer state and losses stay float32. The default is chosen per
machine by a timing (``agent/matmul.py``): bfloat16 only where it clearly pays; on Circle 3 it
learned as well as float32 (3 seeds, benchmarks/RESULTS.md).
"""

from __future__ import annotations

from contextlib import nullcontext

import torch
import torch.nn.functional as F

from sili_robots.agent.matmul import PRECISIONS
from sili_robots.agent.networks import Actor, TwinCritic


class SAC:
    """SAC on inputs x (state plus whatever latents the method conditions on)."""

    def __init__(
        self,
        in_dim: int,
        act_dim: int,
        hidden: int = 256,
        lr: float = 3e-4,
        gamma: float = 0.99,
        tau: float = 5e-3,
        precision: str = "float32",
        target_entropy: float | None = None,
        matmul: str = "aten",
    ) -> None:
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, got {precision!r}")
        self.gamma, self.tau = gamma, tau
        self.precision = precision
        self.actor = Actor(in_dim, act_dim, hidden, matmul)
        self.critic = TwinCritic(in_dim + act_dim, hidden, matmul=matmul)
        self.critic_target = TwinCritic(in_dim + act_dim, hidden, matmul=matmul)
        self.critic_target.load_state_dict(self.critic.state_dict())
        self.critic_target.requires_grad_(False)
        self.log_alpha = torch.zeros(1, requires_grad=True)
        self.target_entropy = -float(act_dim) if target_entropy is None else float(target_entropy)
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=lr, fused=True)
        self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=lr, fused=True)
        self.alpha_opt = torch.optim.Adam([self.log_alpha], lr=lr)
        self._critic_params = list(self.critic.parameters())
        self._target_params = list(self.critic_target.parameters())
        self._actor_and_alpha = [*self.actor.parameters(), self.log_alpha]

    def set_lr(self, lr: float) -> None:
        """The step size of all three optimizers (a learning rate schedule sets it per update)."""
        for opt in (self.actor_opt, self.critic_opt, self.alpha_opt):
            for group in opt.param_groups:
                group["lr"] = lr

    def _forward_precision(self) -> torch.autocast | nullcontext:
        if self.precision == "bfloat16":
            return torch.autocast("cpu", dtype=torch.bfloat16)
        return nullcontext()

    @property
    def alpha(self) -> float:
        return float(self.log_alpha.detach().exp())

    def critic_loss(
        self,
        x: torch.Tensor,
        a: torch.Tensor,
        r: torch.Tensor,
        x2: torch.Tensor,
        a2: torch.Tensor,
        logp2: torch.Tensor,
    ) -> torch.Tensor:
        with torch.no_grad():
            q_next = self.critic_target(x2, a2).min(0).values
            y = r + self.gamma * (q_next - self.log_alpha.exp() * logp2)
        q = self.critic(x, a)
        return F.mse_loss(q, y.expand_as(q)) * q.shape[0]

    def critic_objective(
        self, x: torch.Tensor, a: torch.Tensor, r: torch.Tensor, x2: torch.Tensor
    ) -> torch.Tensor:
        """The critics' loss, its targets from the current actor and target critics."""
        with torch.no_grad(), self._forward_precision():
            a2, logp2 = self.actor.sample(x2)
        with self._forward_precision():
            return self.critic_loss(x, a, r, x2, a2, logp2)

    def actor_objective(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(actor loss, temperature loss) against the critics as they are now."""
        alpha = self.log_alpha.exp().detach()
        with self._forward_precision():
            a_pi, logp = self.actor.sample(x)
            actor_loss = (alpha * logp - self.critic(x, a_pi).min(0).values).mean()
        alpha_loss = -(self.log_alpha * (logp.detach() + self.target_entropy)).mean()
        return actor_loss, alpha_loss

    def update(
        self, x: torch.Tensor, a: torch.Tensor, r: torch.Tensor, x2: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        """One gradient step of critic, actor and temperature on a batch of transitions."""
        # gradients cleared and critics frozen on the parameter lists: zero_grad and a module's
        # requires_grad_ cost 20-60 us each through torch's wrappers, 50 updates an interaction
        critic_loss = self.critic_objective(x, a, r, x2)
        _clear_grads(self._critic_params)
        critic_loss.backward()
        self.critic_opt.step()

        _set_requires_grad(self._critic_params, False)
        actor_loss, alpha_loss = self.actor_objective(x)
        _clear_grads(self._actor_and_alpha)
        # one backward pass for both: each loss sees the other's variable detached
        (actor_loss + alpha_loss).backward()
        self.actor_opt.step()
        self.alpha_opt.step()
        _set_requires_grad(self._critic_params, True)

        with torch.no_grad():
            torch._foreach_lerp_(self._target_params, self._critic_params, self.tau)
        return {"critic_loss": critic_loss.detach(), "actor_loss": actor_loss.detach()}

    @torch.no_grad()
    def act(self, x: torch.Tensor, deterministic: bool = False) -> torch.Tensor:
        if deterministic:
            return self.actor.deterministic(x)
        return self.actor.sample_action(x)

    def state_dict(self) -> dict:
        return {
            "actor": self.actor.state_dict(),
            "critic": self.critic.state_dict(),
            "critic_target": self.critic_target.state_dict(),
            "log_alpha": self.log_alpha.detach(),
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
            "alpha_opt": self.alpha_opt.state_dict(),
        }

    def load_state_dict(self, state: dict) -> None:
        self.actor.load_state_dict(state["actor"])
        self.critic.load_state_dict(state["critic"])
        self.critic_target.load_state_dict(state["critic_target"])
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        self.actor_opt.load_state_dict(state["actor_opt"])
        self.critic_opt.load_state_dict(state["critic_opt"])
        self.alpha_opt.load_state_dict(state["alpha_opt"])


def _clear_grads(params: list[torch.Tensor]) -> None:
    for p in params:
        p.grad = None


def _set_requires_grad(params: list[torch.Tensor], flag: bool) -> None:
    for p in params:
        p.requires_grad_(flag)
