"""Model configuration of the prediction networks (teacher φ_T and student φ_S).

Every size of the networks is a field of :class:`ModelConfig`; nothing in :mod:`nudge_train.models.networks`
hard-codes a width. The JSON form (``to_dict`` / ``from_dict``) is the ``config`` metadata string of
the exported ``.safetensors`` files and is read by the Rust loader, so its keys are exactly the
field names below (see docs/models.md).
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from typing import Any, Literal

from nudge_train.constants import DT, OBS_LEN, PRED_LEN
from nudge_train.jsonio import loads_json

ModelKind = Literal["teacher", "student"]

_KINDS: tuple[str, ...] = ("teacher", "student")
_ACTIVATIONS: tuple[str, ...] = ("relu",)


@dataclass(frozen=True)
class ModelConfig:
    """Sizes and settings of one Social-GAN generator/discriminator pair.

    Units: ``dt`` in seconds; lengths (``obs_len``, ``pred_len``, ``t_plan``) in 0.3 s steps.
    """

    kind: ModelKind
    """``"teacher"`` (one-step generator used recursively) or ``"student"`` (one pass, reads the
    ego candidate)."""
    obs_len: int = OBS_LEN
    """Observed steps per agent (t_obs)."""
    pred_len: int = 1
    """Steps the generator decodes in one call (teacher 1, student = t_plan)."""
    t_plan: int = PRED_LEN
    """Planning horizon in steps (length of an ego candidate)."""
    dt: float = DT
    """Step length, seconds."""
    embedding_dim: int = 16
    """E: width of every spatial embedding Linear(2, E)."""
    encoder_h_dim: int = 32
    """He: hidden width of the encoder LSTM."""
    decoder_h_dim: int = 32
    """Hd: hidden width of the decoder LSTM."""
    mlp_dim: int = 64
    """M: hidden width of the context mlp and the decoder mlp."""
    bottleneck_dim: int = 32
    """B: output width of the pooling module."""
    pool_hidden_dim: int = 512
    """P: pre-pool hidden width of the pooling mlp (Social-GAN hard-codes 512)."""
    noise_dim: int = 8
    """Z: noise width appended to the decoder's h0 (0 = deterministic generator)."""
    pool_every_timestep: bool = False
    """Re-pool after every decoder step (student) or only once after the encoder (teacher)."""
    activation: str = "relu"
    """Activation after every Linear of every mlp; only ``"relu"`` is supported."""
    d_encoder_h_dim: int = 48
    """Hidden width of the discriminator's encoder LSTM."""
    d_mlp_dim: int = 64
    """Hidden width of the discriminator's classifier."""
    seed: int = 0
    """Seed of the weight initialisation."""
    noise_seed: int = 1
    """Seed of the fixed noise vector ``fixed_noise`` (the planner's z)."""

    # ------------------------------------------------------------------ validation
    def validate(self) -> ModelConfig:
        """Checks every field; returns ``self`` so calls can be chained.

        Raises:
            ValueError: naming the first bad field and why.
        """
        if self.kind not in _KINDS:
            raise ValueError(f"kind: must be one of {_KINDS}, got {self.kind!r}")
        positive_ints = (
            "obs_len",
            "pred_len",
            "t_plan",
            "embedding_dim",
            "encoder_h_dim",
            "decoder_h_dim",
            "mlp_dim",
            "bottleneck_dim",
            "pool_hidden_dim",
            "d_encoder_h_dim",
            "d_mlp_dim",
        )
        for name in positive_ints:
            value = getattr(self, name)
            if not _is_int(value):
                raise ValueError(f"{name}: must be an int, got {type(value).__name__} {value!r}")
            if value <= 0:
                raise ValueError(f"{name}: must be positive, got {value}")
        for name in ("noise_dim", "seed", "noise_seed"):
            value = getattr(self, name)
            if not _is_int(value):
                raise ValueError(f"{name}: must be an int, got {type(value).__name__} {value!r}")
            if value < 0:
                raise ValueError(f"{name}: must be non-negative, got {value}")
        if self.obs_len < 2:
            raise ValueError(f"obs_len: must be at least 2 (displacements), got {self.obs_len}")
        if self.noise_dim >= self.decoder_h_dim:
            raise ValueError(
                f"noise_dim: must be smaller than decoder_h_dim={self.decoder_h_dim} "
                f"(h0 = [context ; z]), got {self.noise_dim}"
            )
        if not isinstance(self.dt, (int, float)) or isinstance(self.dt, bool):
            raise ValueError(f"dt: must be a number, got {type(self.dt).__name__} {self.dt!r}")
        if not math.isfinite(self.dt) or self.dt <= 0:
            raise ValueError(f"dt: must be positive and finite, got {self.dt}")
        if not isinstance(self.pool_every_timestep, bool):
            raise ValueError(
                "pool_every_timestep: must be a bool, got "
                f"{type(self.pool_every_timestep).__name__} {self.pool_every_timestep!r}"
            )
        if self.activation not in _ACTIVATIONS:
            raise ValueError(f"activation: must be one of {_ACTIVATIONS}, got {self.activation!r}")
        if self.kind == "teacher" and self.pred_len != 1:
            raise ValueError(
                f"pred_len: the teacher generator predicts one step per call, got {self.pred_len}"
            )
        if self.kind == "student" and self.pred_len != self.t_plan:
            raise ValueError(
                f"pred_len: the student decodes the whole horizon t_plan={self.t_plan}, "
                f"got {self.pred_len}"
            )
        return self

    # ------------------------------------------------------------------ JSON
    def to_dict(self) -> dict[str, Any]:
        """Plain dict with exactly the field names as keys (JSON-serialisable)."""
        return dataclasses.asdict(self)

    def to_json(self) -> str:
        """Compact JSON with sorted keys (deterministic bytes)."""
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ModelConfig:
        """Builds and validates a config; every key must be a known field, ``kind`` is required.

        Raises:
            ValueError: unknown or missing keys, or a field failing :meth:`validate`.
        """
        if not isinstance(data, dict):
            raise ValueError(f"config: expected a JSON object, got {type(data).__name__}")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"{unknown[0]}: unknown config key (known: {sorted(known)})")
        if "kind" not in data:
            raise ValueError("kind: missing from config")
        return cls(**data).validate()

    @classmethod
    def from_json(cls, text: str) -> ModelConfig:
        """Parses :meth:`to_json` output (or any JSON object with valid keys).

        Raises:
            ConfigError (a ValueError): not JSON, or a duplicate key (naming it).
            ValueError: unknown or missing keys, or a field failing :meth:`validate`.
        """
        return cls.from_dict(loads_json(text, "config"))

    def replace(self, **changes: Any) -> ModelConfig:
        """Copy with some fields changed, validated."""
        return dataclasses.replace(self, **changes).validate()


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def teacher_config() -> ModelConfig:
    """φ_T of the paper: E16 He32 Hd32 M64 B32 P512 Z8, one-step generator, pool once."""
    return ModelConfig(
        kind="teacher",
        obs_len=OBS_LEN,
        pred_len=1,
        t_plan=PRED_LEN,
        dt=DT,
        embedding_dim=16,
        encoder_h_dim=32,
        decoder_h_dim=32,
        mlp_dim=64,
        bottleneck_dim=32,
        pool_hidden_dim=512,
        noise_dim=8,
        pool_every_timestep=False,
        activation="relu",
        d_encoder_h_dim=48,
        d_mlp_dim=64,
        seed=1,
        noise_seed=2,
    ).validate()


def student_config() -> ModelConfig:
    """φ_S of the paper: E16 He16 Hd16 M16 B16 P16, no noise, pooling at every decoder step."""
    return ModelConfig(
        kind="student",
        obs_len=OBS_LEN,
        pred_len=PRED_LEN,
        t_plan=PRED_LEN,
        dt=DT,
        embedding_dim=16,
        encoder_h_dim=16,
        decoder_h_dim=16,
        mlp_dim=16,
        bottleneck_dim=16,
        pool_hidden_dim=16,
        noise_dim=0,
        pool_every_timestep=True,
        activation="relu",
        d_encoder_h_dim=24,
        d_mlp_dim=16,
        seed=3,
        noise_seed=4,
    ).validate()
