"""MADDPG's update with its gradients written out: an optimisation of ``maddpg.MADDPG.update``, the one the
per-region runs were trained with, and the training's until they are trained again.

The two losses are those of ``MADDPG.update``; their gradients are two matmuls per layer (``backward``), each in the
form the CPU BLAS runs fastest (``stacked_matmul``), and the actor's gradient reads only the critic's own-action
columns. ``make bench`` section 2 times it against the autograd update: 1.13-1.18× faster at the paper's batch of
1024, 1.3× at ``tuned``'s 128. That is under the 1.3× at the paper's batch that would keep it, so it goes with the
runs' next retraining (135 runs, about 147 minutes on two cores: every run's numbers move in their last bits);
``tests/learn/test_maddpg.py`` checks it against the autograd update and against the per-agent loop of
``tests/learn/loop_maddpg.py``. Adam and the soft update work on each run's part of a stack as a tensor of its own,
so a run's arithmetic does not depend on the stack it trains in (a run's curve is bit for bit its single-run curve,
``tests/learn/test_training.py``), and the per-operation overhead that dominates an update at ``tuned``'s batch of
128 is paid once for the stack.

A change of the networks or of a loss in ``MADDPG`` is a change here too, or the training runs ``MADDPG`` itself
(``LEARNER``, below): the test against the autograd update fails until the written-out gradients follow.
"""

from __future__ import annotations

import numpy as np
import torch

from replicate.learn.maddpg import MADDPG, BatchedMLP, clip_grad_per_agent, per_run, soft_update, stacked_matmul
from replicate.learn.replay import Batch


@torch.no_grad()
def backward(net: BatchedMLP, inputs: list[torch.Tensor], grad_out: torch.Tensor,
             weight_grads: bool = True) -> torch.Tensor:
    """Back-propagate ∂L/∂output [N, B, out] through ``net`` (its layers' ``inputs`` from
    ``BatchedMLP.forward_saving``); store ∂L/∂W, ∂L/∂b in each parameter's ``.grad`` (if ``weight_grads``).
    → ∂L/∂(first layer's pre-activation) [N, B, h₁], from which a caller takes the gradient with respect to any
    input columns: ∂L/∂x = (that) @ W₁ᵀ."""
    d = grad_out
    for k in range(len(net.weights) - 1, -1, -1):
        w, b = net.weights[k], net.biases[k]
        if weight_grads:
            w.grad = stacked_matmul(inputs[k].mT, d).contiguous()  # ∂L/∂W = xᵀ d
            b.grad = d.sum(dim=1, keepdim=True)
        if k > 0:  # ∂L/∂x = d Wᵀ, then through the ReLU (its output is the saved input)
            d = stacked_matmul(d, w.mT)
            torch.ops.aten.threshold_backward.grad_input(d, inputs[k], 0, grad_input=d)
    return d


@torch.no_grad()
def adam_step(opt: torch.optim.Adam, runs: int = 1) -> None:
    """``opt.step()`` for a one-group fused Adam over ``runs`` stacked runs, without the ``Optimizer.step``
    wrapper: the same ``_fused_adam_`` kernel on the optimiser's own state, so the result and ``state_dict`` are the
    same. The wrapper's bookkeeping cost as much as the kernel on ``tuned``'s small tensors (``make bench``
    section 2)."""
    (group,) = opt.param_groups
    params = group["params"]
    for p in params:
        if p not in opt.state:  # the first step creates the state, as ``opt.step()`` does
            opt.state[p] = {"step": torch.zeros((), device=p.device), "exp_avg": torch.zeros_like(p),
                            "exp_avg_sq": torch.zeros_like(p)}
    state = [opt.state[p] for p in params]
    steps = [s["step"] for s in state]
    torch._foreach_add_(steps, 1)
    beta1, beta2 = group["betas"]
    torch._fused_adam_(
        per_run(params, runs), per_run([p.grad for p in params], runs), per_run([s["exp_avg"] for s in state], runs),
        per_run([s["exp_avg_sq"] for s in state], runs), [], [step for step in steps for _ in range(runs)],
        lr=group["lr"], beta1=beta1, beta2=beta2, weight_decay=group["weight_decay"], eps=group["eps"],
        amsgrad=False, maximize=False,
    )


class MADDPGByHand(MADDPG):
    """``MADDPG`` whose update computes its gradients by hand (module docstring)."""

    @torch.no_grad()
    def update(self, batch: Batch) -> dict[str, np.ndarray]:
        """``MADDPG.update``, the gradients written out."""
        cfg, v = self.cfg, self.unpack(batch)
        s, bsz = v.runs, v.batch

        # Critic: y_i = r_i + γ Q'_i(x', μ'_1(o'_1), …, μ'_N(o'_N))   (paper eq. y)
        next_act = torch.tanh(self.actor_target(v.per_agent(v.next_obs))).view(s, v.n, bsz, -1).transpose(1, 2)
        y = v.r + v.disc * self.critic_target(v.joint(v.next_obs, next_act)).squeeze(-1)
        q, saved = self.critic.forward_saving(v.joint(v.obs, v.act))
        q = q.squeeze(-1)  # [S·N, B]
        backward(self.critic, saved, (2.0 / bsz) * (q - y).unsqueeze(-1))  # ∂L/∂Q_i = 2(Q_i − y_i)/B
        clip_grad_per_agent(self.params["critic"], cfg.grad_clip)
        adam_step(self.critic_opt, s)

        # Actor: ∇θ_i J = E[∇θ_i μ_i(o_i) ∇a_i Q_i(x, a_1, …, μ_i(o_i), …, a_N)] + 1e-3·mean(pre-tanh²)
        pre, actor_saved = self.actor.forward_saving(v.per_agent(v.obs))  # [S·N, B, ad]
        mu = torch.tanh(pre)
        q_pi, saved_pi = self.critic.forward_saving(self.with_own_actions(v, saved[0], mu))
        d_z1 = backward(self.critic, saved_pi, torch.full_like(q_pi, -1.0 / bsz), weight_grads=False)  # −mean Q_i
        d_mu = stacked_matmul(d_z1, self.critic.weights[0][self.stacked, self.own_action_rows].mT)
        d_pre = d_mu * (1.0 - mu * mu) + (2.0 * cfg.actor_reg / pre[0].numel()) * pre  # through tanh; + reg
        backward(self.actor, actor_saved, d_pre)  # through μ_i only, not into Q's weights
        clip_grad_per_agent(self.params["actor"], cfg.grad_clip)
        adam_step(self.actor_opt, s)

        soft_update(self.params["critic_target"], self.params["critic"], cfg.tau, s)  # θ' ← τθ + (1 − τ)θ'
        soft_update(self.params["actor_target"], self.params["actor"], cfg.tau, s)
        return self.diagnostics(q, y, v)


# the update the per-region runs train with (``train``) and the fingerprint digests (``fingerprint``): MADDPG's, its
# gradients written out; a change of the networks or losses in ``MADDPG`` trains with ``MADDPG`` itself until the
# written-out gradients follow (and raises ``runs.TRAINING_VERSION``)
LEARNER = MADDPGByHand
