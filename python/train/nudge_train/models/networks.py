"""Social-GAN prediction networks (teacher φ_T and student φ_S) in PyTorch.

Module and parameter names are chosen so that ``TrajectoryGenerator.state_dict()`` is exactly the
tensor list of the shared network spec (docs/models.md), which the Rust predictor loads.

Shapes use these letters: ``T`` observed steps (``cfg.obs_len``), ``A`` agents of all scenes of a
batch stacked, ``S`` scenes, ``K`` decoded steps. Positions are absolute, in metres. Scenes are
given by ``seq_start_end`` ``[S, 2]`` (half-open agent ranges that partition ``0..A`` in order);
the first agent of each scene is its ego. Scenes never see each other in pooling.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from nudge_train.models.config import ModelConfig

__all__ = [
    "Decoder",
    "Encoder",
    "PoolHiddenNet",
    "SceneIndex",
    "TrajectoryDiscriminator",
    "TrajectoryGenerator",
    "build_model",
    "positions_to_rel",
]


def make_mlp(dims: list[int]) -> nn.Sequential:
    """``Linear → ReLU`` for every consecutive pair of ``dims``; ReLU after the last layer too."""
    layers: list[nn.Module] = []
    for d_in, d_out in zip(dims[:-1], dims[1:], strict=True):
        layers.append(nn.Linear(d_in, d_out))
        layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def positions_to_rel(traj: Tensor) -> Tensor:
    """Displacements of a window of positions ``[T, A, 2]``: ``rel[0] = 0``, ``rel[t] = p[t] − p[t−1]``."""
    if traj.dim() != 3 or traj.shape[-1] != 2:
        raise ValueError(f"positions: expected shape [T, A, 2], got {list(traj.shape)}")
    return torch.cat([torch.zeros_like(traj[:1]), traj[1:] - traj[:-1]], dim=0)


@dataclass(frozen=True)
class SceneIndex:
    """Index tensors describing how a batch of agents splits into scenes.

    Built once per forward pass and reused by every pooling call.
    """

    seq_start_end: Tensor
    """``[S, 2]`` int64: half-open agent range of each scene."""
    ego: Tensor
    """``[S]`` int64: index of each scene's first agent (the ego)."""
    agent_scene: Tensor
    """``[A]`` int64: scene of each agent."""
    pair_i: Tensor
    """``[Σ n_s²]`` int64: receiving agent i of every ordered pair (i, j) inside one scene."""
    pair_j: Tensor
    """``[Σ n_s²]`` int64: neighbour j of every pair (j = i included)."""
    num_agents: int
    """A: total agents."""

    @property
    def num_scenes(self) -> int:
        """S."""
        return int(self.seq_start_end.shape[0])

    @staticmethod
    def build(seq_start_end: Tensor, num_agents: int, device: torch.device | str) -> SceneIndex:
        """Validates ``seq_start_end`` against ``num_agents`` and builds the pair indices.

        Raises:
            ValueError: the ranges are not a gap-free, in-order partition of ``0..num_agents``
                into non-empty scenes.
        """
        if seq_start_end.dim() != 2 or seq_start_end.shape[1] != 2:
            raise ValueError(f"seq_start_end: expected shape [S, 2], got {list(seq_start_end.shape)}")
        if seq_start_end.dtype.is_floating_point or seq_start_end.dtype == torch.bool:
            raise ValueError(f"seq_start_end: expected an integer tensor, got {seq_start_end.dtype}")
        ranges = seq_start_end.detach().to("cpu", torch.int64)
        if ranges.shape[0] == 0:
            raise ValueError("seq_start_end: no scenes")
        starts, ends = ranges[:, 0], ranges[:, 1]
        if int(starts[0]) != 0:
            raise ValueError(f"seq_start_end: first scene must start at 0, got {int(starts[0])}")
        if int(ends[-1]) != num_agents:
            raise ValueError(
                f"seq_start_end: last scene must end at the agent count {num_agents}, "
                f"got {int(ends[-1])}"
            )
        sizes = ends - starts
        if bool((sizes <= 0).any()):
            bad = int(torch.nonzero(sizes <= 0)[0, 0])
            raise ValueError(f"seq_start_end: scene {bad} is empty or reversed {ranges[bad].tolist()}")
        if bool((starts[1:] != ends[:-1]).any()):
            bad = int(torch.nonzero(starts[1:] != ends[:-1])[0, 0]) + 1
            raise ValueError(
                f"seq_start_end: scene {bad} starts at {int(starts[bad])}, "
                f"expected {int(ends[bad - 1])} (scenes must be contiguous and in order)"
            )
        num_scenes = int(ranges.shape[0])
        agent_scene = torch.repeat_interleave(torch.arange(num_scenes), sizes)
        pair_counts = sizes * sizes
        pair_scene = torch.repeat_interleave(torch.arange(num_scenes), pair_counts)
        first_pair = torch.cumsum(pair_counts, 0) - pair_counts
        k = torch.arange(int(pair_counts.sum())) - first_pair[pair_scene]
        n = sizes[pair_scene]
        pair_i = starts[pair_scene] + torch.div(k, n, rounding_mode="floor")
        pair_j = starts[pair_scene] + torch.remainder(k, n)
        return SceneIndex(
            seq_start_end=ranges.to(device),
            ego=starts.to(device),
            agent_scene=agent_scene.to(device),
            pair_i=pair_i.to(device),
            pair_j=pair_j.to(device),
            num_agents=num_agents,
        )


class Encoder(nn.Module):
    """Embeds displacements and runs an LSTM over them; returns the final hidden state."""

    def __init__(self, embedding_dim: int, h_dim: int) -> None:
        super().__init__()
        self.h_dim = h_dim
        self.spatial_embedding = nn.Linear(2, embedding_dim)
        self.encoder = nn.LSTM(embedding_dim, h_dim, num_layers=1)

    def forward(self, traj_rel: Tensor) -> Tensor:
        """``traj_rel`` ``[T, A, 2]`` displacements (m) → final hidden state ``[A, h_dim]``."""
        emb = self.spatial_embedding(traj_rel)
        _, (h_n, _) = self.encoder(emb)
        return h_n[0]


class PoolHiddenNet(nn.Module):
    """Social-GAN pooling: ``pool_i = max_j mlp([emb(p_j − p_i) ; h_j])`` over j in i's scene."""

    def __init__(self, embedding_dim: int, h_dim: int, pool_hidden_dim: int, bottleneck_dim: int) -> None:
        super().__init__()
        self.embedding_dim = embedding_dim
        self.h_dim = h_dim
        self.bottleneck_dim = bottleneck_dim
        self.spatial_embedding = nn.Linear(2, embedding_dim)
        self.mlp_pre_pool = make_mlp([embedding_dim + h_dim, pool_hidden_dim, bottleneck_dim])
        self.soft_temperature = 0.0
        """Training only (not a weight, never exported): > 0 replaces the max over j by the
        smooth maximum τ·log Σ_j exp(u_ij / τ) (at least the max and at most τ·log n above it), so
        that every neighbour, not only the winning one, receives a gradient. 0 (the default, and
        always at inference) is Social-GAN's max."""

    def forward(self, h: Tensor, pos: Tensor, scenes: SceneIndex) -> Tensor:
        """``h`` ``[A, h_dim]``, ``pos`` ``[A, 2]`` (m) → pooled ``[A, bottleneck_dim]``.

        Evaluated over every ordered pair inside each scene at once (no padding); the first
        Linear is split into its displacement part (per pair) and its hidden part (per agent,
        then gathered), which is the same affine map.
        """
        first, second = self.mlp_pre_pool[0], self.mlp_pre_pool[2]
        assert isinstance(first, nn.Linear) and isinstance(second, nn.Linear)
        e = self.embedding_dim
        rel = pos[scenes.pair_j] - pos[scenes.pair_i]  # [pairs, 2]
        rel_emb = self.spatial_embedding(rel)  # [pairs, E]
        per_agent = nn.functional.linear(h, first.weight[:, e:])  # [A, P]
        pre = nn.functional.linear(rel_emb, first.weight[:, :e], first.bias) + per_agent[scenes.pair_j]
        u = torch.relu(second(torch.relu(pre)))  # [pairs, B], >= 0
        index = scenes.pair_i.unsqueeze(1).expand(-1, self.bottleneck_dim)
        out = torch.zeros(scenes.num_agents, self.bottleneck_dim, dtype=u.dtype, device=u.device)
        hard = out.scatter_reduce(0, index, u, reduce="amax", include_self=False)
        tau = self.soft_temperature
        if tau <= 0:
            return hard
        top = hard.detach()
        w = torch.exp((u - top[scenes.pair_i]) / tau)  # <= 1: no overflow
        return top + tau * torch.log(torch.zeros_like(out).index_add(0, scenes.pair_i, w))


class Decoder(nn.Module):
    """LSTM decoder: one step = LSTM → Δp = hidden2pos(h) → position; optional re-pooling."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.spatial_embedding = nn.Linear(2, cfg.embedding_dim)
        self.decoder = nn.LSTM(cfg.embedding_dim, cfg.decoder_h_dim, num_layers=1)
        self.hidden2pos = nn.Linear(cfg.decoder_h_dim, 2)
        if cfg.pool_every_timestep:
            self.pool_net = PoolHiddenNet(
                cfg.embedding_dim, cfg.decoder_h_dim, cfg.pool_hidden_dim, cfg.bottleneck_dim
            )
            self.mlp = make_mlp([cfg.decoder_h_dim + cfg.bottleneck_dim, cfg.mlp_dim, cfg.decoder_h_dim])

    def forward(
        self,
        last_pos: Tensor,
        last_rel: Tensor,
        h0: Tensor,
        scenes: SceneIndex,
        steps: int,
        ego_future: Tensor | None,
    ) -> tuple[Tensor, Tensor]:
        """Decodes ``steps`` steps.

        Args:
            last_pos: ``[A, 2]`` last observed positions (m).
            last_rel: ``[A, 2]`` last observed displacement (m).
            h0: ``[A, decoder_h_dim]`` initial hidden state (c0 = 0).
            scenes: scene split of the A agents.
            steps: K, steps to decode.
            ego_future: ``[K, S, 2]`` positions imposed on each scene's ego, or None.

        Returns:
            positions ``[K, A, 2]`` and displacements ``[K, A, 2]``.
        """
        h = h0.unsqueeze(0)
        c = torch.zeros_like(h)
        inp = self.spatial_embedding(last_rel)
        pos = last_pos
        out_pos: list[Tensor] = []
        out_rel: list[Tensor] = []
        for t in range(steps):
            out, (h, c) = self.decoder(inp.unsqueeze(0), (h, c))
            rel = self.hidden2pos(out[0])
            new_pos = pos + rel
            if ego_future is not None:
                target = ego_future[t]
                rel = rel.index_put((scenes.ego,), target - pos[scenes.ego])
                new_pos = new_pos.index_put((scenes.ego,), target)
            pos = new_pos
            if self.cfg.pool_every_timestep:
                pooled = self.pool_net(h[0], pos, scenes)
                h = self.mlp(torch.cat([h[0], pooled], dim=1)).unsqueeze(0)
            inp = self.spatial_embedding(rel)
            out_pos.append(pos)
            out_rel.append(rel)
        return torch.stack(out_pos), torch.stack(out_rel)


class TrajectoryGenerator(nn.Module):
    """Social-GAN generator (encoder → pool → context mlp → [ctx ; z] → decoder).

    ``fixed_noise`` ``[noise_dim]`` (only when ``noise_dim > 0``) is a buffer drawn from N(0, 1)
    with ``cfg.noise_seed``: the z used when the caller gives none (planner, distillation data).
    """

    fixed_noise: Tensor

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        cfg.validate()
        self.cfg = cfg
        self.encoder = Encoder(cfg.embedding_dim, cfg.encoder_h_dim)
        self.pool_net = PoolHiddenNet(
            cfg.embedding_dim, cfg.encoder_h_dim, cfg.pool_hidden_dim, cfg.bottleneck_dim
        )
        self.mlp_decoder_context = make_mlp(
            [cfg.encoder_h_dim + cfg.bottleneck_dim, cfg.mlp_dim, cfg.decoder_h_dim - cfg.noise_dim]
        )
        self.decoder = Decoder(cfg)
        if cfg.noise_dim > 0:
            rng = torch.Generator(device="cpu").manual_seed(cfg.noise_seed)
            self.register_buffer("fixed_noise", torch.randn(cfg.noise_dim, generator=rng))

    @property
    def device(self) -> torch.device:
        """Device of the parameters."""
        return self.encoder.spatial_embedding.weight.device

    def sample_noise(self, num_scenes: int, generator: torch.Generator | None = None) -> Tensor:
        """Fresh N(0, 1) noise ``[num_scenes, noise_dim]`` on the model's device (for training)."""
        weight = self.encoder.spatial_embedding.weight
        return torch.randn(
            num_scenes, self.cfg.noise_dim, generator=generator, device=weight.device, dtype=weight.dtype
        )

    def scene_index(self, seq_start_end: Tensor, num_agents: int) -> SceneIndex:
        """:meth:`SceneIndex.build` on the model's device."""
        return SceneIndex.build(seq_start_end, num_agents, self.device)

    def context(self, obs_traj: Tensor, scenes: SceneIndex) -> Tensor:
        """History-only part: ``obs_traj`` ``[T, A, 2]`` → context ``[A, decoder_h_dim − noise_dim]``."""
        self._check_obs(obs_traj)
        h_enc = self.encoder(positions_to_rel(obs_traj))
        pooled = self.pool_net(h_enc, obs_traj[-1], scenes)
        return self.mlp_decoder_context(torch.cat([h_enc, pooled], dim=1))

    def decode(
        self,
        ctx: Tensor,
        obs_traj: Tensor,
        scenes: SceneIndex,
        noise: Tensor | None = None,
        ego_future: Tensor | None = None,
        steps: int | None = None,
    ) -> tuple[Tensor, Tensor]:
        """Decoder part given the :meth:`context`; see :meth:`forward` for the arguments."""
        steps = self.cfg.pred_len if steps is None else steps
        if steps <= 0:
            raise ValueError(f"steps: must be positive, got {steps}")
        s = scenes.num_scenes
        if self.cfg.noise_dim > 0:
            z = self.fixed_noise.unsqueeze(0).expand(s, -1) if noise is None else noise
            if tuple(z.shape) != (s, self.cfg.noise_dim):
                raise ValueError(f"noise: expected shape [{s}, {self.cfg.noise_dim}], got {list(z.shape)}")
            h0 = torch.cat([ctx, z.to(ctx.dtype)[scenes.agent_scene]], dim=1)
        else:
            if noise is not None and noise.numel() > 0:
                raise ValueError(f"noise: this generator has noise_dim 0, got shape {list(noise.shape)}")
            h0 = ctx
        if ego_future is not None and tuple(ego_future.shape) != (steps, s, 2):
            raise ValueError(f"ego_future: expected shape [{steps}, {s}, 2], got {list(ego_future.shape)}")
        last_rel = obs_traj[-1] - obs_traj[-2]
        return self.decoder(obs_traj[-1], last_rel, h0, scenes, steps, ego_future)

    def forward(
        self,
        obs_traj: Tensor,
        seq_start_end: Tensor,
        noise: Tensor | None = None,
        ego_future: Tensor | None = None,
        steps: int | None = None,
    ) -> tuple[Tensor, Tensor]:
        """One generator call.

        Args:
            obs_traj: ``[obs_len, A, 2]`` observed absolute positions (m).
            seq_start_end: ``[S, 2]`` scene ranges (first agent of a scene = its ego).
            noise: ``[S, noise_dim]`` one z per scene; None → ``fixed_noise`` for every scene.
            ego_future: ``[K, S, 2]`` ego positions to impose (student), or None.
            steps: K, decoded steps; default ``cfg.pred_len``.

        Returns:
            predicted positions ``[K, A, 2]`` (m) and displacements ``[K, A, 2]`` (m).
        """
        self._check_obs(obs_traj)
        scenes = self.scene_index(seq_start_end, obs_traj.shape[1])
        ctx = self.context(obs_traj, scenes)
        return self.decode(ctx, obs_traj, scenes, noise=noise, ego_future=ego_future, steps=steps)

    def _check_obs(self, obs_traj: Tensor) -> None:
        if obs_traj.dim() != 3 or obs_traj.shape[0] != self.cfg.obs_len or obs_traj.shape[2] != 2:
            raise ValueError(
                f"obs_traj: expected shape [{self.cfg.obs_len}, A, 2], got {list(obs_traj.shape)}"
            )


class TrajectoryDiscriminator(nn.Module):
    """Local Social-GAN discriminator: encodes each agent's whole displacement sequence
    (observed + future) and scores it with ``Linear → ReLU → Linear`` (a raw logit)."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        cfg.validate()
        self.cfg = cfg
        self.encoder = Encoder(cfg.embedding_dim, cfg.d_encoder_h_dim)
        self.real_classifier = nn.Sequential(
            nn.Linear(cfg.d_encoder_h_dim, cfg.d_mlp_dim),
            nn.ReLU(),
            nn.Linear(cfg.d_mlp_dim, 1),
        )

    def forward(self, traj_rel: Tensor) -> Tensor:
        """``traj_rel`` ``[T, A, 2]`` displacements (first one 0 by convention) → logits ``[A]``."""
        if traj_rel.dim() != 3 or traj_rel.shape[2] != 2:
            raise ValueError(f"traj_rel: expected shape [T, A, 2], got {list(traj_rel.shape)}")
        return self.real_classifier(self.encoder(traj_rel))[:, 0]


def build_model(
    cfg: ModelConfig, device: torch.device | str = "cpu"
) -> tuple[TrajectoryGenerator, TrajectoryDiscriminator]:
    """Builds the generator and discriminator of ``cfg``, initialised from ``cfg.seed``.

    Initialisation happens on the CPU with a private RNG state (the global one is left
    untouched), so the weights are the same whatever ``device`` they are moved to.
    """
    cfg.validate()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(cfg.seed)
        generator = TrajectoryGenerator(cfg)
        discriminator = TrajectoryDiscriminator(cfg)
    return generator.to(device), discriminator.to(device)
