"""The reward model r̂: an ensemble of MLPs on (s, a) trained on preferences with the Bradley–Terry loss."""

from typing import Optional

import numpy as np
import torch as th
from stable_baselines3.common.torch_layers import create_mlp
from stable_baselines3.common.utils import get_device
from torch import nn
from torch.nn import functional as F


def preference_loss(returns: th.Tensor, labels: th.Tensor) -> th.Tensor:
    """
    Bradley–Terry cross-entropy (Eqs. 1–2): P[σ1 ≻ σ0] = softmax([R̂0, R̂1])[1], with R̂ the sum of r̂ over
    a segment; ``labels`` are the target probabilities μ that σ1 is preferred (0, 1, or 0.5 for "equal").

    :param returns: (..., 2) predicted segment returns
    :param labels: (...) targets in [0, 1]
    :return: mean loss
    """
    log_p = F.log_softmax(returns, dim=-1)
    return -((1.0 - labels) * log_p[..., 0] + labels * log_p[..., 1]).mean()


class PreferenceDataset:
    """
    The preference dataset D: segment pairs as (s, a) inputs and the teacher's labels μ.

    :param segment_length: steps per segment
    :param input_dim: obs_dim + action_dim
    """

    def __init__(self, segment_length: int, input_dim: int):
        self.inputs = np.zeros((0, 2, segment_length, input_dim), dtype=np.float32)
        self.labels = np.zeros(0, dtype=np.float32)

    def __len__(self) -> int:
        return len(self.labels)

    def add(self, inputs: np.ndarray, labels: np.ndarray) -> None:
        self.inputs = np.concatenate([self.inputs, inputs.astype(np.float32)])
        self.labels = np.concatenate([self.labels, labels.astype(np.float32)])


class RewardEnsemble(nn.Module):
    """
    PEBBLE's reward model: ``n_members`` MLPs r̂_m(s, a) with a tanh output (per-step reward in [-1, 1]).
    ``predict`` is the ensemble mean; members disagree on what the labels do not pin down, which the
    "disagreement" and "entropy" query selections exploit.

    :param obs_dim: observation size
    :param action_dim: action size
    :param n_members: ensemble size (PEBBLE: 3)
    :param net_arch: hidden layers of each member (PEBBLE: 3 × 256)
    :param learning_rate: Adam step size (PEBBLE: 3e-4)
    :param device: torch device
    """

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        n_members: int = 3,
        net_arch: tuple[int, ...] = (256, 256, 256),
        learning_rate: float = 3e-4,
        device: th.device | str = "auto",
    ):
        super().__init__()
        if n_members < 1:
            raise ValueError(f"ensemble_size must be >= 1, got {n_members}")
        self.input_dim = obs_dim + action_dim
        self.members = nn.ModuleList(
            nn.Sequential(*create_mlp(self.input_dim, 1, list(net_arch), nn.LeakyReLU), nn.Tanh()) for _ in range(n_members)
        )
        self.device = get_device(device)
        self.to(self.device)
        self.optimizer = th.optim.Adam(self.parameters(), lr=learning_rate)

    def forward(self, inputs: th.Tensor) -> th.Tensor:
        """Per-member rewards: (..., input_dim) -> (members, ..., 1)."""
        return th.stack([member(inputs) for member in self.members])

    @th.no_grad()
    def predict(self, observations: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """r̂(s, a): the ensemble mean, numpy in and out, shape (...) for inputs of shape (..., dim)."""
        inputs = th.as_tensor(np.concatenate([observations, actions], axis=-1), dtype=th.float32, device=self.device)
        return self(inputs).mean(dim=0).squeeze(-1).cpu().numpy()

    @th.no_grad()
    def member_segment_returns(self, inputs: np.ndarray, batch_size: int = 256) -> th.Tensor:
        """Each member's return of each segment: (n, 2, k, input_dim) -> (members, n, 2)."""
        chunks = [
            self(th.as_tensor(inputs[i : i + batch_size], device=self.device)).sum(dim=(-2, -1))
            for i in range(0, len(inputs), batch_size)
        ]
        return th.cat(chunks, dim=1).cpu()

    def train_epochs(
        self,
        dataset: PreferenceDataset,
        max_epochs: int,
        batch_size: int = 128,
        target_accuracy: float = 0.97,
        rng: Optional[np.random.Generator] = None,
    ) -> tuple[float, float, int]:
        """
        Train on D for up to ``max_epochs`` epochs, each member on its own shuffling of D (the loss is summed
        over members); stop early once the training accuracy of an epoch exceeds ``target_accuracy`` (PEBBLE).
        Accuracy counts pairs with a strict label (0 or 1) that the member ranks the same way.

        :return: (last epoch's mean loss per member, its accuracy, epochs run)
        """
        rng = rng if rng is not None else np.random.default_rng()
        inputs = th.as_tensor(dataset.inputs, device=self.device)
        labels = th.as_tensor(dataset.labels, device=self.device)
        n, n_members = len(labels), len(self.members)
        loss_value, accuracy, epoch = float("nan"), 0.0, 0
        for epoch in range(1, max_epochs + 1):
            orders = np.stack([rng.permutation(n) for _ in range(n_members)])
            total_loss, correct, counted = 0.0, 0.0, 0.0
            for start in range(0, n, batch_size):
                loss = th.zeros((), device=self.device)
                for m, member in enumerate(self.members):
                    idx = th.as_tensor(orders[m, start : start + batch_size], device=self.device)
                    returns = member(inputs[idx]).sum(dim=(-2, -1))  # (b, 2): R̂0, R̂1
                    member_loss = preference_loss(returns, labels[idx])
                    loss = loss + member_loss
                    strict = labels[idx] != 0.5
                    predicted = (returns[:, 1] > returns[:, 0]).float()
                    correct += float(((predicted == labels[idx]) & strict).sum())
                    counted += float(strict.sum())
                    total_loss += member_loss.item() * len(idx)
                self.optimizer.zero_grad()
                loss.backward()
                self.optimizer.step()
            loss_value = total_loss / (n * n_members)
            accuracy = correct / max(counted, 1.0)
            if accuracy > target_accuracy:
                break
        return loss_value, accuracy, epoch
