"""
How faithful synthetic transitions are, measured so that a bad generator shows: a one-step dynamics ensemble
fitted on real transitions judges whether each synthetic s' follows from its (s, a), and nearest-neighbour
distances tell new samples from copies of the buffer. Marginal statistics (mean and std per dimension) are kept for
reference only: they read excellent for samples whose next states are wrong by two typical steps.
"""

from dataclasses import dataclass

import numpy as np
import torch as th
from stable_baselines3.common.utils import get_device
from torch import nn

from sb3_pride.common.entropy import knn_distances
from sb3_pride.reward.ensemble import EnsembleMLP
from sb3_pride.common.utils import check_positive_ints, seeded


class DynamicsEnsemble(nn.Module):
    """
    A one-step dynamics model: ``n_members`` MLPs (SiLU), trained together as one batched network, each predicting the
    z-scored state change (s' − s) from the z-scored (s, a), each on its own minibatches. Errors are in units of
    the per-dimension std of s' − s: ``errors`` is the RMS over dimensions of (ŝ' − s') / std(s' − s) under the
    members' mean.

    ``fit`` keeps a random ``holdout_fraction`` of the transitions out of training: the error on them is how
    consistent *real* data is under this model, the yardstick for synthetic data (``DynamicsEnsemble.ratio``).
    Successive fits warm-start from the previous weights (the normalizer is refit each time).

    :param obs_dim: state dimension
    :param action_dim: action dimension
    :param n_members: ensemble members
    :param width: hidden units of each member's two hidden layers
    :param train_steps: Adam steps per ``fit``
    :param batch_size: minibatch per member
    :param learning_rate: Adam step size
    :param holdout_fraction: share of the transitions held out of training
    :param seed: seed of the model's own random generators
    :param device: torch device
    """

    input_mean: th.Tensor
    input_std: th.Tensor
    delta_mean: th.Tensor
    delta_std: th.Tensor
    changing: th.Tensor

    def __init__(
        self,
        obs_dim: int,
        action_dim: int,
        n_members: int = 3,
        width: int = 200,
        train_steps: int = 1000,
        batch_size: int = 256,
        learning_rate: float = 1e-3,
        holdout_fraction: float = 0.2,
        seed: int | None = None,
        device: th.device | str = "auto",
    ):
        super().__init__()
        check_positive_ints(
            obs_dim=obs_dim,
            action_dim=action_dim,
            n_members=n_members,
            width=width,
            train_steps=train_steps,
            batch_size=batch_size,
        )
        if learning_rate <= 0:
            raise ValueError(f"learning_rate must be > 0, got {learning_rate}")
        if not 0.0 < holdout_fraction < 1.0:
            raise ValueError(f"holdout_fraction must be in (0, 1), got {holdout_fraction}")
        self.obs_dim, self.action_dim = obs_dim, action_dim
        self.n_members, self.train_steps, self.batch_size = n_members, train_steps, batch_size
        self.learning_rate, self.holdout_fraction = learning_rate, holdout_fraction
        self.device_ = get_device(device)
        self.rng = np.random.default_rng(seed)
        # the members are the reward model's batched ensemble MLP with a linear output, initialized from the
        # model's own seed (the global torch RNGs are left as they were)
        with seeded(int(self.rng.integers(2**62))):
            self.members = EnsembleMLP(
                n_members,
                obs_dim + action_dim,
                (width, width),
                obs_dim,
                output_activation=None,
                hidden_activation=nn.functional.silu,
            )
        for name, size in (
            ("input_mean", obs_dim + action_dim),
            ("input_std", obs_dim + action_dim),
            ("delta_mean", obs_dim),
            ("delta_std", obs_dim),
        ):
            self.register_buffer(name, th.zeros(size) if "mean" in name else th.ones(size))
        self.register_buffer("changing", th.ones(obs_dim, dtype=th.bool))
        self.optimizer = th.optim.Adam(self.parameters(), lr=learning_rate)
        self.to(self.device_)

    def forward(self, inputs: th.Tensor) -> th.Tensor:
        """(M, B, obs + action) z-scored inputs -> (M, B, obs) z-scored predicted state changes."""
        return self.members(inputs)

    def _inputs(self, obs: np.ndarray, actions: np.ndarray) -> th.Tensor:
        x = th.as_tensor(np.concatenate([obs, actions], axis=-1), dtype=th.float32, device=self.device_)
        return (x - self.input_mean) / self.input_std

    def _targets(self, obs: np.ndarray, next_obs: np.ndarray) -> th.Tensor:
        delta = th.as_tensor(next_obs - obs, dtype=th.float32, device=self.device_)
        return (delta - self.delta_mean) / self.delta_std

    def fit(self, obs: np.ndarray, actions: np.ndarray, next_obs: np.ndarray) -> None:
        """Train on all but a random held-out share of the transitions (``holdout`` and ``train_indices`` tell which)."""
        obs, actions, next_obs = (np.asarray(a, dtype=np.float32) for a in (obs, actions, next_obs))
        n = len(obs)
        if n < 10:
            raise ValueError(f"the dynamics ensemble needs at least 10 transitions, got {n}")
        order = self.rng.permutation(n)
        n_holdout = max(1, round(self.holdout_fraction * n))
        self.holdout, train = order[:n_holdout], order[n_holdout:]
        inputs = np.concatenate([obs[train], actions[train]], axis=-1)
        deltas = next_obs[train] - obs[train]
        with th.no_grad():
            for name, values in (("input", inputs), ("delta", deltas)):
                getattr(self, f"{name}_mean").copy_(th.as_tensor(values.mean(axis=0)))
                getattr(self, f"{name}_std").copy_(th.as_tensor(values.std(axis=0) + 1e-6))
            changing = varying_dimensions(deltas)
            self.changing.copy_(th.as_tensor(changing if changing.any() else np.ones_like(changing)))
        x, y = self._inputs(obs[train], actions[train]), self._targets(obs[train], next_obs[train])
        for _ in range(self.train_steps):
            batch = th.as_tensor(self.rng.integers(0, len(train), size=(self.n_members, self.batch_size)), device=self.device_)
            loss = ((self(x[batch]) - y[batch]) ** 2).mean()
            self.optimizer.zero_grad()
            loss.backward()
            self.optimizer.step()
        self.train_indices = train

    @th.no_grad()
    def _predictions(self, obs: np.ndarray, actions: np.ndarray) -> th.Tensor:
        x = self._inputs(obs, actions)
        return self(x.unsqueeze(0).expand(self.n_members, -1, -1))

    def errors(self, obs: np.ndarray, actions: np.ndarray, next_obs: np.ndarray) -> np.ndarray:
        """Per transition: RMS over the changing dimensions of (ensemble-mean ŝ' − s') / std(s' − s)."""
        predicted = self._predictions(obs, actions).mean(dim=0)
        squared = (predicted - self._targets(obs, next_obs)) ** 2
        return squared[:, self.changing].mean(dim=-1).sqrt().cpu().numpy()


@dataclass
class Fidelity:
    """
    Fidelity of one generation of synthetic transitions against the real ones it was fitted on.

    :param dynamics_error: mean error of synthetic s' under the dynamics ensemble (units of std(s' − s))
    :param real_dynamics_error: the same for real held-out transitions
    :param dynamics_error_ratio: their ratio; 1.0 = synthetic next states as consistent as real ones
    :param novelty_ratio: median distance of a synthetic transition to its nearest real training transition, over
        the same for real held-out transitions (z-scored transition space, varying dimensions): ~0 = copies of the
        buffer, ~1 = as new as a fresh real transition, >> 1 = off the data
    :param mean_gap: mean over varying dimensions of |mean_syn − mean_real| / std_real (marginal; cannot see dynamics)
    :param std_gap: mean over varying dimensions of |std_syn / std_real − 1| (marginal; cannot see dynamics)
    :param heldout_anchor_error_ratio: ``dynamics_error_ratio`` of the samples generated near (anchored on) real
        transitions the ensemble held out from its last fit; NaN without anchors or if none landed there. Near-real
        samples sit beside their anchors, and the ensemble fits its own training rows better than held-out ones, so
        ``dynamics_error_ratio`` reads samples anchored on training rows too kindly; this one compares like with like
        (held-out anchors against held-out reals; under warm-started refits both may have been trained on before)
    """

    dynamics_error: float
    real_dynamics_error: float
    dynamics_error_ratio: float
    novelty_ratio: float
    mean_gap: float
    std_gap: float
    heldout_anchor_error_ratio: float = float("nan")


def varying_dimensions(values: np.ndarray) -> np.ndarray:
    """
    The columns of ``values`` that vary: std (in float64) above 1e-6 of their scale. A constant float32 column can
    show a std of ~1e-5 from rounding alone, which must not count as variation.
    """
    values = np.asarray(values, dtype=np.float64)
    return values.std(axis=0) > 1e-6 * (1.0 + np.abs(values).mean(axis=0))


def split_transitions(vectors: np.ndarray, obs_dim: int, action_dim: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(s, a, s') of transition vectors [s, a, s', ...] (any trailing column, e.g. a terminal flag, is left out)."""
    return (
        vectors[:, :obs_dim],
        vectors[:, obs_dim : obs_dim + action_dim],
        vectors[:, obs_dim + action_dim : 2 * obs_dim + action_dim],
    )


def marginal_gaps(real: np.ndarray, synthetic: np.ndarray) -> tuple[float, float]:
    """
    Mean over the dimensions that vary in ``real`` of |mean_syn − mean_real| / std_real and of |std_syn / std_real − 1|
    (NaN if none varies).
    """
    varying = varying_dimensions(real)
    if not varying.any():
        return float("nan"), float("nan")
    real, synthetic = real[:, varying].astype(np.float64), synthetic[:, varying].astype(np.float64)
    real_std = real.std(axis=0)
    mean_gap = np.abs(synthetic.mean(axis=0) - real.mean(axis=0)) / real_std
    std_gap = np.abs(synthetic.std(axis=0) / real_std - 1.0)
    return float(mean_gap.mean()), float(std_gap.mean())


def novelty_ratio(
    reference: np.ndarray, real_queries: np.ndarray, synthetic: np.ndarray, rng: np.random.Generator, n_queries: int = 1000
) -> float:
    """
    Median nearest-neighbour distance to ``reference`` of synthetic vectors over that of real held-out vectors, in
    z-scored units over the dimensions that vary in ``reference`` (a constant one, z-scored, would turn noise of
    1e-6 into a distance of a whole std); NaN if none varies.
    """
    varying = varying_dimensions(reference)
    if not varying.any():
        return float("nan")
    reference, real_queries, synthetic = reference[:, varying], real_queries[:, varying], synthetic[:, varying]
    mean, std = reference.mean(axis=0), reference.astype(np.float64).std(axis=0).astype(np.float32)
    points = th.as_tensor((reference - mean) / std, dtype=th.float32)

    def median_distance(queries: np.ndarray) -> float:
        chosen = queries[rng.choice(len(queries), size=min(n_queries, len(queries)), replace=False)]
        return float(knn_distances(th.as_tensor((chosen - mean) / std, dtype=th.float32), points, k=1).median())

    return median_distance(synthetic) / max(median_distance(real_queries), 1e-12)


def check_anchors(anchors: np.ndarray, n_vectors: int, n_rows: int | None = None) -> np.ndarray:
    """
    Check that ``anchors`` hold one integer row index per generated vector (and, given ``n_rows``, that each indexes
    one of the ``n_rows`` real rows), so that no sample is judged against, or kept with, the wrong real transition.

    :param anchors: the real row each generated vector was generated near
    :param n_vectors: how many generated vectors there are
    :param n_rows: how many real rows the anchors index, or None to skip the range check
    :return: ``anchors`` as an array
    """
    anchors = np.asarray(anchors)
    if anchors.shape != (n_vectors,) or not np.issubdtype(anchors.dtype, np.integer):
        raise ValueError(
            f"anchors must be one integer row index per generated vector, shape ({n_vectors},), "
            f"got {anchors.dtype} of shape {anchors.shape}"
        )
    if n_rows is not None and len(anchors) and (anchors.min() < 0 or anchors.max() >= n_rows):
        raise ValueError(f"anchors must index rows of the real data, in [0, {n_rows}), got [{anchors.min()}, {anchors.max()}]")
    return anchors


def measure_fidelity(
    dynamics: DynamicsEnsemble,
    real: np.ndarray,
    synthetic: np.ndarray,
    obs_dim: int,
    action_dim: int,
    refit: bool = True,
    anchors: np.ndarray | None = None,
) -> Fidelity:
    """
    Judge ``synthetic`` transition vectors [s, a, s', ...] against the ``real`` ones: fit ``dynamics`` on ``real``
    (unless ``refit`` is False, reusing its last fit and held-out split), then compare errors and novelty.

    :param dynamics: the one-step dynamics ensemble that judges
    :param real: real transition vectors [s, a, s', ...]; with ``refit=False``, the same array the ensemble was last
        fitted on (its held-out split indexes it)
    :param synthetic: synthetic transition vectors, laid out as ``real``
    :param obs_dim: state dimension
    :param action_dim: action dimension
    :param refit: fit ``dynamics`` on ``real`` first
    :param anchors: for samples generated near real transitions, the row of ``real`` each one was generated from
        (gives ``heldout_anchor_error_ratio``)
    """
    if anchors is not None:
        anchors = check_anchors(anchors, len(synthetic), len(real))
    if len(synthetic) == 0:
        return Fidelity(*(float("nan"),) * 7)

    def split(vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return split_transitions(vectors, obs_dim, action_dim)

    if refit:
        dynamics.fit(*split(real))
    holdout = real[dynamics.holdout]
    real_error = float(dynamics.errors(*split(holdout)).mean())
    synthetic_errors = dynamics.errors(*split(synthetic))
    synthetic_error = float(synthetic_errors.mean())
    heldout_anchor_ratio = float("nan")
    if anchors is not None:
        near_holdout = np.isin(anchors, dynamics.holdout)
        if near_holdout.any():
            heldout_anchor_ratio = float(synthetic_errors[near_holdout].mean()) / max(real_error, 1e-12)
    reference = real[dynamics.train_indices]
    if len(reference) > 20_000:  # bound the k-NN cost: 20k random training transitions stand for all
        reference = reference[dynamics.rng.choice(len(reference), size=20_000, replace=False)]
    novelty = novelty_ratio(reference, holdout, synthetic, dynamics.rng)
    return Fidelity(
        synthetic_error,
        real_error,
        synthetic_error / max(real_error, 1e-12),
        novelty,
        *marginal_gaps(real, synthetic),
        heldout_anchor_ratio,
    )
