"""
The diffusion model PRIDE trains on the agent's transitions (Feng et al., 2025, §3.4 and §4), in the form SynthER
uses (Lu et al., 2023): EDM — "Elucidating the Design Space of Diffusion-Based Generative Models" (Karras et al.,
2022) — preconditioning around a residual-MLP denoiser, log-normal training noise, Karras noise schedule and a
stochastic Heun sampler. It works on any set of flat vectors: ``fit(data)``, then ``sample(n)``.
"""

import copy
import math
import time
from dataclasses import dataclass

import numpy as np
import torch as th
from stable_baselines3.common.utils import get_device
from torch import nn

from sb3_pride.common.utils import check_choice, check_positive_ints, seeded


class ResidualBlock(nn.Module):
    """h + W·act(h) (SynthER's online configuration: no layer norm)."""

    def __init__(self, width: int):
        super().__init__()
        self.linear = nn.Linear(width, width)

    def forward(self, h: th.Tensor) -> th.Tensor:
        return h + self.linear(th.relu(h))


class ResidualMLPDenoiser(nn.Module):
    """
    F_θ(x, c_noise): the input projected to ``dim_t`` plus a random-Fourier embedding of the noise level, then
    ``n_blocks`` residual blocks of ``width`` units, then a projection back to the data dimension.

    :param dim: data dimension
    :param width: residual-block width (SynthER: 1024)
    :param n_blocks: residual blocks (SynthER: 6)
    :param dim_t: width of the time embedding (SynthER: 256)
    :param fourier_features: random Fourier features of the noise level (SynthER: 16)
    """

    frequencies: th.Tensor

    def __init__(self, dim: int, width: int = 256, n_blocks: int = 3, dim_t: int = 128, fourier_features: int = 16):
        super().__init__()
        # frozen random frequencies: the embedding is [t, sin(2π w t), cos(2π w t)]
        self.register_buffer("frequencies", th.randn(fourier_features // 2))
        self.time_mlp = nn.Sequential(nn.Linear(2 * (fourier_features // 2) + 1, dim_t), nn.SiLU(), nn.Linear(dim_t, dim_t))
        self.input_projection = nn.Linear(dim, dim_t)
        self.body = nn.Sequential(nn.Linear(dim_t, width), *[ResidualBlock(width) for _ in range(n_blocks)], nn.ReLU())
        self.output_projection = nn.Linear(width, dim)

    def forward(self, x: th.Tensor, c_noise: th.Tensor) -> th.Tensor:
        t = c_noise.reshape(-1, 1)
        angles = 2 * math.pi * t * self.frequencies
        embedding = th.cat([t, angles.sin(), angles.cos()], dim=-1)
        h = self.input_projection(x) + self.time_mlp(embedding)
        return self.output_projection(self.body(h))


@dataclass
class FitInfo:
    """What one ``fit`` did: the mean loss of its last 10% of steps, its steps and seconds."""

    loss: float
    steps: int
    seconds: float


#: how the diffusion model normalizes its data (``normalization``)
NORMALIZATIONS = ("per_dimension", "whiten")


class ElucidatedDiffusion(nn.Module):
    """
    An EDM diffusion model over flat vectors, normalized (statistics refit at every ``fit``) either per dimension
    (z-scores, SynthER's) or by ZCA whitening: z = (x − μ) R Λ^(−1/2) Rᵀ, with R the eigenvectors and Λ the
    eigenvalues of the data's covariance. Whitening matters where dimensions are strongly correlated: Meta-World's
    observation holds the previous frame beside the current one, so a velocity is the small difference of two
    coordinates, and per-dimension noise of σ = 0.25 wipes it out; whitened, that difference is a unit-variance
    direction of its own and the noise along it is in proportion to its spread. ZCA (rather than PCA's
    z = (x − μ) R Λ^(−1/2)) keeps the model's coordinates close to the data's and does not depend on the sign or order
    eigh gives the eigenvectors, so a warm-started model keeps its meaning across refits.

    Denoiser D(x; σ) = c_skip(σ)·x + c_out(σ)·F_θ(c_in(σ)·x, ln(σ)/4), with c_skip = σ_d²/(σ² + σ_d²),
    c_out = σσ_d/√(σ² + σ_d²), c_in = 1/√(σ² + σ_d²). Training minimizes λ(σ)·‖D(x + σn; σ) − x‖²,
    λ(σ) = (σ² + σ_d²)/(σσ_d)², with ln σ ~ N(P_mean, P_std²). Samples come from the EMA of θ, by the Heun
    sampler with churn on the Karras schedule σ_i = (σ_max^{1/ρ} + i/(N−1)(σ_min^{1/ρ} − σ_max^{1/ρ}))^ρ.
    Defaults are SynthER's EDM constants; sizes and budgets default to a CPU-friendly scale
    (SynthER: width 1024, 6 blocks, dim_t 256, 100k training steps, 128 sampling steps).

    Only the EMA weights and the normalizer are state (``state_dict``); each ``fit`` trains a copy of them with a
    fresh AdamW and cosine schedule (``warm_start=False``: from a fresh initialization, as SynthER).

    :param dim: data dimension
    :param width: residual-block width
    :param n_blocks: residual blocks
    :param dim_t: time-embedding width
    :param train_steps: gradient steps per ``fit``
    :param batch_size: training minibatch
    :param learning_rate: AdamW step size (cosine-annealed to 0 over ``train_steps``)
    :param sample_steps: N, sampler steps (each a Heun step: two network passes but the last)
    :param sample_batch_size: vectors denoised at once
    :param ema_decay: EMA decay (updated every ``ema_every`` steps, with a warm-up)
    :param warm_start: start each ``fit`` from the current EMA weights instead of a new initialization
    :param skip_normalization: dimensions left unnormalized (e.g. a 0/1 terminal flag)
    :param normalization: ``"per_dimension"`` (z-scores) or ``"whiten"`` (ZCA whitening of the other dimensions)
    :param seed: seed of the model's own random generators (the global torch/numpy RNGs are never touched)
    :param device: torch device
    """

    mean: th.Tensor
    std: th.Tensor
    rotation: th.Tensor

    def __init__(
        self,
        dim: int,
        width: int = 256,
        n_blocks: int = 3,
        dim_t: int = 128,
        train_steps: int = 2000,
        batch_size: int = 256,
        learning_rate: float = 3e-4,
        sample_steps: int = 32,
        sample_batch_size: int = 50_000,
        ema_decay: float = 0.995,
        ema_every: int = 10,
        warm_start: bool = True,
        skip_normalization: tuple[int, ...] = (),
        normalization: str = "per_dimension",
        sigma_min: float = 0.002,
        sigma_max: float = 80.0,
        sigma_data: float = 1.0,
        rho: float = 7.0,
        p_mean: float = -1.2,
        p_std: float = 1.2,
        s_churn: float = 80.0,
        s_tmin: float = 0.05,
        s_tmax: float = 50.0,
        s_noise: float = 1.003,
        seed: int | None = None,
        device: th.device | str = "auto",
    ):
        super().__init__()
        check_positive_ints(
            dim=dim, width=width, n_blocks=n_blocks, train_steps=train_steps, batch_size=batch_size, sample_steps=sample_steps
        )
        self.dim = dim
        self.architecture = dict(width=width, n_blocks=n_blocks, dim_t=dim_t)
        self.train_steps = train_steps
        self.batch_size = batch_size
        self.learning_rate = learning_rate
        self.sample_steps = sample_steps
        self.sample_batch_size = sample_batch_size
        self.ema_decay = ema_decay
        self.ema_every = ema_every
        self.warm_start = warm_start
        if any(not -dim <= int(i) < dim for i in skip_normalization):
            raise ValueError(f"skip_normalization must hold dimensions in [-{dim}, {dim}), got {tuple(skip_normalization)}")
        self.skip_normalization = tuple(sorted({int(i) % dim for i in skip_normalization}))  # -1 is the last one
        check_choice("normalization", normalization, NORMALIZATIONS)
        self.normalization = normalization
        self.sigma_min, self.sigma_max, self.sigma_data, self.rho = sigma_min, sigma_max, sigma_data, rho
        self.p_mean, self.p_std = p_mean, p_std
        self.s_churn, self.s_tmin, self.s_tmax, self.s_noise = s_churn, s_tmin, s_tmax, s_noise
        self.device_ = get_device(device)
        self.generator = th.Generator(device=self.device_)
        if seed is None:
            self.generator.seed()  # a non-deterministic seed
        else:
            self.generator.manual_seed(seed)
        self.rng = np.random.default_rng(seed)
        self.ema = self._new_denoiser()
        self.register_buffer("mean", th.zeros(dim))
        self.register_buffer("std", th.ones(dim))
        if normalization == "whiten":  # only then a buffer: models saved with per-dimension statistics still load
            self.register_buffer("rotation", th.eye(dim))
        self.to(self.device_)

    def _new_denoiser(self) -> ResidualMLPDenoiser:
        # initialized from the model's own generator, leaving the global torch RNGs as they were
        seed = int(th.randint(0, 2**62, (1,), generator=self.generator, device=self.generator.device))
        with seeded(seed):
            return ResidualMLPDenoiser(self.dim, **self.architecture).to(self.device_)

    # EDM preconditioning -------------------------------------------------------------------------------------
    def denoise(self, net: nn.Module, x: th.Tensor, sigma: th.Tensor) -> th.Tensor:
        """D(x; σ) = c_skip·x + c_out·F(c_in·x, ln(σ)/4), σ of shape (B, 1)."""
        sd2 = self.sigma_data**2
        c_skip = sd2 / (sigma**2 + sd2)
        c_out = sigma * self.sigma_data / (sigma**2 + sd2).sqrt()
        c_in = 1.0 / (sigma**2 + sd2).sqrt()
        return c_skip * x + c_out * net(c_in * x, sigma.log() / 4)

    def loss(self, net: nn.Module, x: th.Tensor) -> th.Tensor:
        """E[λ(σ)·mean_dims (D(x + σn; σ) − x)²] with ln σ ~ N(P_mean, P_std²)."""
        normal = th.randn((len(x), 1), generator=self.generator, device=x.device)
        sigma = (self.p_mean + self.p_std * normal).exp()
        noise = th.randn(x.shape, generator=self.generator, device=x.device)
        weight = (sigma**2 + self.sigma_data**2) / (sigma * self.sigma_data) ** 2
        return (weight * (self.denoise(net, x + sigma * noise, sigma) - x) ** 2).mean()

    # normalization -------------------------------------------------------------------------------------------
    def _fit_normalizer(self, data: np.ndarray) -> None:
        skipped = list(self.skip_normalization)
        mean, std = data.mean(axis=0), data.std(axis=0) + 1e-5
        if self.normalization == "whiten":
            # the principal axes of the normalized dimensions, from a float64 covariance accumulated in chunks (that of
            # near-constant ones is tiny); std holds the spread along each axis, with the same floor as per dimension
            kept = np.setdiff1d(np.arange(self.dim), skipped)
            covariance = np.zeros((len(kept), len(kept)))
            for start in range(0, len(data), 65_536):
                chunk = data[start : start + 65_536, kept].astype(np.float64) - mean[kept]
                covariance += chunk.T @ chunk
            eigenvalues, eigenvectors = np.linalg.eigh(covariance / len(data))
            rotation = np.eye(self.dim)
            rotation[np.ix_(kept, kept)] = eigenvectors
            std[kept] = np.sqrt(np.clip(eigenvalues, 0.0, None)) + 1e-5
            self.rotation.copy_(th.as_tensor(rotation, dtype=th.float32))
        mean[skipped], std[skipped] = 0.0, 1.0
        self.mean.copy_(th.as_tensor(mean, dtype=th.float32))
        self.std.copy_(th.as_tensor(std, dtype=th.float32))

    def normalize(self, vectors: th.Tensor) -> th.Tensor:
        """Data units -> the model's units: (x − μ) / σ per dimension, or (x − μ) R Λ^(−1/2) Rᵀ when whitening."""
        centered = vectors - self.mean
        if self.normalization == "whiten":
            return ((centered @ self.rotation) / self.std) @ self.rotation.T
        return centered / self.std

    def unnormalize(self, normalized: th.Tensor) -> th.Tensor:
        """The model's units -> data units (the inverse of ``normalize``: R is orthonormal)."""
        if self.normalization == "whiten":
            return ((normalized @ self.rotation) * self.std) @ self.rotation.T + self.mean
        return normalized * self.std + self.mean

    # training ------------------------------------------------------------------------------------------------
    def fit(self, data: np.ndarray, steps: int | None = None) -> FitInfo:
        """
        Train on ``data`` (N, dim): minibatches drawn uniformly, AdamW with a cosine schedule and gradient
        clipping at 1, EMA of the weights. Refits the normalizer first.
        """
        data = np.asarray(data, dtype=np.float32)
        if data.ndim != 2 or data.shape[1] != self.dim:
            raise ValueError(f"data must have shape (N, {self.dim}), got {data.shape}")
        if not np.all(np.isfinite(data)):
            raise ValueError("data contains non-finite values")
        steps = steps or self.train_steps
        start = time.perf_counter()
        self._fit_normalizer(data)
        normalized = self.normalize(th.as_tensor(data, dtype=th.float32, device=self.device_))
        net = copy.deepcopy(self.ema) if self.warm_start else self._new_denoiser()
        net.train()
        optimizer = th.optim.AdamW(net.parameters(), lr=self.learning_rate, betas=(0.9, 0.99), weight_decay=0.0)
        schedule = th.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=steps)
        if not self.warm_start:
            self.ema.load_state_dict(net.state_dict())
        tail_steps = max(1, steps // 10)  # the reported loss: mean of the last 10% of steps
        losses = []
        for step in range(steps):
            batch = normalized[th.as_tensor(self.rng.integers(0, len(normalized), self.batch_size), device=self.device_)]
            loss = self.loss(net, batch)
            optimizer.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            optimizer.step()
            schedule.step()
            if step >= steps - tail_steps:  # .item() waits for the device: only where the value is used
                losses.append(loss.item())
            if (step + 1) % self.ema_every == 0:
                self._update_ema(net, n_updates=(step + 1) // self.ema_every)
        self._update_ema(net, n_updates=steps // self.ema_every + 1)
        return FitInfo(loss=float(np.mean(losses)), steps=steps, seconds=time.perf_counter() - start)

    @th.no_grad()
    def _update_ema(self, net: nn.Module, n_updates: int) -> None:
        # decay warms up as 1 - (1 + n)^(-2/3), capped at ema_decay
        decay = min(self.ema_decay, 1.0 - (1.0 + n_updates) ** (-2.0 / 3.0))
        for ema_param, param in zip(self.ema.parameters(), net.parameters(), strict=True):
            ema_param.lerp_(param, 1.0 - decay)

    # sampling ------------------------------------------------------------------------------------------------
    def noise_levels(self, sigma_max: float | None = None) -> th.Tensor:
        """Karras schedule σ_0 > … > σ_{N−1} from ``sigma_max`` (default: the model's σ_max), then σ_N = 0."""
        ramp = th.linspace(0, 1, self.sample_steps, device=self.device_)
        inv_rho = 1.0 / self.rho
        top = (sigma_max if sigma_max is not None else self.sigma_max) ** inv_rho
        sigmas = (top + ramp * (self.sigma_min**inv_rho - top)) ** self.rho
        return th.cat([sigmas, th.zeros(1, device=self.device_)])

    @th.no_grad()
    def sample(self, n: int) -> np.ndarray:
        """``n`` vectors from the EMA model by the stochastic Heun sampler, in data units."""
        return self._sample_chunked(n, lambda start, size: self._heun(self._noise((size, self.dim)) * self.sigma_max))

    @th.no_grad()
    def sample_near(self, anchors: np.ndarray, start_sigma: float) -> np.ndarray:
        """
        One new vector per anchor, generated *near* it (SDEdit, Meng et al., 2022): the normalized anchor is noised to
        ``start_sigma`` and denoised from there on the Karras schedule that starts at ``start_sigma`` (with the
        sampler's churn, the first step briefly raises the level to ≈ (1 + min(S_churn/N, √2 − 1))·``start_sigma``). Small
        ``start_sigma`` stays close to real data; ``start_sigma = σ_max`` forgets the anchor.
        """
        if not self.sigma_min < start_sigma <= self.sigma_max:
            raise ValueError(
                f"start_sigma must be in (sigma_min={self.sigma_min}, sigma_max={self.sigma_max}], got {start_sigma}"
            )
        normalized = self._normalize(anchors)
        return self._sample_chunked(
            len(normalized),
            lambda start, size: self._heun(
                normalized[start : start + size] + start_sigma * self._noise((size, self.dim)), start_sigma
            ),
        )

    @th.no_grad()
    def sample_given(self, anchors: np.ndarray, known: np.ndarray) -> np.ndarray:
        """
        One new vector per anchor whose ``known`` dimensions are the anchor's and whose other dimensions are generated
        given them (inpainting by replacement, Lugmayr et al., 2022): after every sampler step the known dimensions
        are reset to the anchor noised to the current level, so the rest is denoised consistently with them, e.g.
        s' given a real (s, a). Needs per-dimension normalization (whitening mixes known and generated dimensions).
        """
        if self.normalization != "per_dimension":
            raise ValueError(f"sample_given needs normalization='per_dimension', got {self.normalization!r}")
        normalized = self._normalize(anchors)
        mask = th.zeros(self.dim, dtype=th.bool, device=self.device_)
        mask[th.as_tensor(np.asarray(known), device=self.device_)] = True
        return self._sample_chunked(
            len(normalized),
            lambda start, size: self._heun(
                self._noise((size, self.dim)) * self.sigma_max, known=(mask, normalized[start : start + size])
            ),
        )

    def _normalize(self, vectors: np.ndarray) -> th.Tensor:
        vectors = np.asarray(vectors, dtype=np.float32)
        if vectors.ndim != 2 or vectors.shape[1] != self.dim:
            raise ValueError(f"anchors must have shape (N, {self.dim}), got {vectors.shape}")
        return self.normalize(th.as_tensor(vectors, dtype=th.float32, device=self.device_))

    def _noise(self, shape: tuple[int, ...]) -> th.Tensor:
        return th.randn(shape, generator=self.generator, device=self.device_)

    def _sample_chunked(self, n: int, sample_chunk) -> np.ndarray:
        self.ema.eval()
        chunks = [sample_chunk(start, min(self.sample_batch_size, n - start)) for start in range(0, n, self.sample_batch_size)]
        samples = self.unnormalize(th.cat(chunks))
        return samples.cpu().numpy()

    def _heun(
        self, x: th.Tensor, sigma_max: float | None = None, known: tuple[th.Tensor, th.Tensor] | None = None
    ) -> th.Tensor:
        """EDM's stochastic sampler (Karras et al., 2022, Algorithm 2) from x at σ_0, optionally with known dims."""
        n = len(x)
        sigmas = self.noise_levels(sigma_max)
        churn = min(self.s_churn / self.sample_steps, math.sqrt(2) - 1)
        for i in range(self.sample_steps):
            sigma, sigma_next = sigmas[i], sigmas[i + 1]
            # churn: raise the noise level a little by adding fresh noise (only for σ in [S_tmin, S_tmax])
            gamma = churn if self.s_tmin <= float(sigma) <= self.s_tmax else 0.0
            sigma_hat = sigma * (1 + gamma)
            if gamma > 0:
                x = x + (sigma_hat**2 - sigma**2).sqrt() * self.s_noise * self._noise(x.shape)
            slope = (x - self.denoise(self.ema, x, sigma_hat.expand(n, 1))) / sigma_hat
            x_next = x + (sigma_next - sigma_hat) * slope  # Euler step
            if sigma_next > 0:  # Heun correction, except at the last step
                slope_next = (x_next - self.denoise(self.ema, x_next, sigma_next.expand(n, 1))) / sigma_next
                x_next = x + (sigma_next - sigma_hat) * (slope + slope_next) / 2
            if known is not None:  # the known dimensions: the anchor, noised to the level just reached
                mask, anchor = known
                x_next = th.where(mask, anchor + sigma_next * self._noise(x.shape), x_next)
            x = x_next
        return x
