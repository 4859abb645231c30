"""Tests of the network definitions (config, sizes, names, pooling, interactive semantics)."""

from __future__ import annotations

from collections.abc import Iterator
import dataclasses
import json

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from torch import nn

from nudge_train.models.config import ModelConfig, student_config, teacher_config
from nudge_train.models.interactive import batch_scenes, student_interactive, teacher_interactive
from nudge_train.models.networks import PoolHiddenNet, SceneIndex, TrajectoryGenerator, build_model, positions_to_rel


@pytest.fixture(autouse=True)
def _one_thread() -> Iterator[None]:
    """Single-threaded torch: these small ops only slow down with threads on a shared machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def spec_shapes(cfg: ModelConfig) -> dict[str, list[int]]:
    """The generator tensor list of the shared spec, written out independently of models.py."""
    e, he, hd, m, b, p, z = (
        cfg.embedding_dim,
        cfg.encoder_h_dim,
        cfg.decoder_h_dim,
        cfg.mlp_dim,
        cfg.bottleneck_dim,
        cfg.pool_hidden_dim,
        cfg.noise_dim,
    )
    shapes = {
        "encoder.spatial_embedding.weight": [e, 2],
        "encoder.spatial_embedding.bias": [e],
        "encoder.encoder.weight_ih_l0": [4 * he, e],
        "encoder.encoder.weight_hh_l0": [4 * he, he],
        "encoder.encoder.bias_ih_l0": [4 * he],
        "encoder.encoder.bias_hh_l0": [4 * he],
        "pool_net.spatial_embedding.weight": [e, 2],
        "pool_net.spatial_embedding.bias": [e],
        "pool_net.mlp_pre_pool.0.weight": [p, e + he],
        "pool_net.mlp_pre_pool.0.bias": [p],
        "pool_net.mlp_pre_pool.2.weight": [b, p],
        "pool_net.mlp_pre_pool.2.bias": [b],
        "mlp_decoder_context.0.weight": [m, he + b],
        "mlp_decoder_context.0.bias": [m],
        "mlp_decoder_context.2.weight": [hd - z, m],
        "mlp_decoder_context.2.bias": [hd - z],
        "decoder.spatial_embedding.weight": [e, 2],
        "decoder.spatial_embedding.bias": [e],
        "decoder.decoder.weight_ih_l0": [4 * hd, e],
        "decoder.decoder.weight_hh_l0": [4 * hd, hd],
        "decoder.decoder.bias_ih_l0": [4 * hd],
        "decoder.decoder.bias_hh_l0": [4 * hd],
        "decoder.hidden2pos.weight": [2, hd],
        "decoder.hidden2pos.bias": [2],
    }
    if cfg.pool_every_timestep:
        shapes.update(
            {
                "decoder.pool_net.spatial_embedding.weight": [e, 2],
                "decoder.pool_net.spatial_embedding.bias": [e],
                "decoder.pool_net.mlp_pre_pool.0.weight": [p, e + hd],
                "decoder.pool_net.mlp_pre_pool.0.bias": [p],
                "decoder.pool_net.mlp_pre_pool.2.weight": [b, p],
                "decoder.pool_net.mlp_pre_pool.2.bias": [b],
                "decoder.mlp.0.weight": [m, hd + b],
                "decoder.mlp.0.bias": [m],
                "decoder.mlp.2.weight": [hd, m],
                "decoder.mlp.2.bias": [hd],
            }
        )
    if z > 0:
        shapes["fixed_noise"] = [z]
    return shapes


ODD_CONFIG = ModelConfig(
    kind="teacher",
    embedding_dim=5,
    encoder_h_dim=7,
    decoder_h_dim=11,
    mlp_dim=13,
    bottleneck_dim=3,
    pool_hidden_dim=17,
    noise_dim=4,
    pool_every_timestep=True,
    d_encoder_h_dim=9,
    d_mlp_dim=6,
    seed=5,
    noise_seed=6,
).validate()

CONFIGS = [teacher_config(), student_config(), ODD_CONFIG, student_config().replace(pool_every_timestep=False)]


def random_history(generator: torch.Generator, n: int, obs_len: int = 8) -> torch.Tensor:
    """``[n, obs_len, 2]`` plausible moving agents around the origin."""
    start = torch.rand(n, 1, 2, generator=generator) * torch.tensor([80.0, 14.0]) - torch.tensor([40.0, 7.0])
    vel = torch.rand(n, 1, 2, generator=generator) * torch.tensor([6.0, 0.3]) + torch.tensor([1.5, -0.15])
    steps = torch.arange(obs_len, dtype=torch.float32).view(1, obs_len, 1) - (obs_len - 1)
    return start + vel * steps


def random_candidates(generator: torch.Generator, history: torch.Tensor, b: int, t: int = 6) -> torch.Tensor:
    last = history[0, -1]
    vel = history[0, -1] - history[0, -2]
    steps = torch.arange(1, t + 1, dtype=torch.float32).view(1, t, 1)
    jitter = torch.randn(b, 1, 2, generator=generator) * torch.tensor([0.5, 0.3])
    return last + (vel + jitter) * steps


# ---------------------------------------------------------------------------------------- config


class TestConfig:
    def test_shipped_configs_match_spec(self) -> None:
        t, s = teacher_config(), student_config()
        assert (t.embedding_dim, t.encoder_h_dim, t.decoder_h_dim, t.mlp_dim, t.bottleneck_dim) == (16, 32, 32, 64, 32)
        assert (t.pool_hidden_dim, t.noise_dim, t.pool_every_timestep, t.pred_len) == (512, 8, False, 1)
        assert (t.d_encoder_h_dim, t.d_mlp_dim) == (48, 64)
        assert (s.embedding_dim, s.encoder_h_dim, s.decoder_h_dim, s.mlp_dim, s.bottleneck_dim) == (16, 16, 16, 16, 16)
        assert (s.pool_hidden_dim, s.noise_dim, s.pool_every_timestep, s.pred_len) == (16, 0, True, 6)
        assert (s.d_encoder_h_dim, s.d_mlp_dim) == (24, 16)
        for cfg in (t, s):
            assert (cfg.obs_len, cfg.t_plan, cfg.dt, cfg.activation) == (8, 6, 0.3, "relu")

    @pytest.mark.parametrize(
        ("changes", "field"),
        [
            ({"embedding_dim": 0}, "embedding_dim"),
            ({"encoder_h_dim": -3}, "encoder_h_dim"),
            ({"pool_hidden_dim": 0}, "pool_hidden_dim"),
            ({"bottleneck_dim": 0}, "bottleneck_dim"),
            ({"d_mlp_dim": 0}, "d_mlp_dim"),
            ({"noise_dim": 32}, "noise_dim"),
            ({"noise_dim": 40}, "noise_dim"),
            ({"noise_dim": -1}, "noise_dim"),
            ({"obs_len": 1}, "obs_len"),
            ({"pred_len": 6}, "pred_len"),
            ({"dt": 0.0}, "dt"),
            ({"dt": float("nan")}, "dt"),
            ({"activation": "tanh"}, "activation"),
            ({"kind": "oracle"}, "kind"),
            ({"mlp_dim": 64.0}, "mlp_dim"),
            ({"mlp_dim": True}, "mlp_dim"),
            ({"pool_every_timestep": 1}, "pool_every_timestep"),
            ({"seed": -1}, "seed"),
        ],
    )
    def test_validate_names_the_bad_field(self, changes: dict[str, object], field: str) -> None:
        with pytest.raises(ValueError, match=rf"^{field}:"):
            dataclasses.replace(teacher_config(), **changes).validate()

    def test_student_pred_len_must_equal_t_plan(self) -> None:
        with pytest.raises(ValueError, match="^pred_len:"):
            student_config().replace(pred_len=1)

    def test_json_round_trip(self) -> None:
        for cfg in CONFIGS:
            text = cfg.to_json()
            assert ModelConfig.from_json(text) == cfg
            assert set(json.loads(text)) == {f.name for f in dataclasses.fields(ModelConfig)}

    def test_from_dict_rejects_unknown_and_missing_keys(self) -> None:
        data = teacher_config().to_dict()
        with pytest.raises(ValueError, match="^hidden_dim: unknown config key"):
            ModelConfig.from_dict({**data, "hidden_dim": 3})
        del data["kind"]
        with pytest.raises(ValueError, match="^kind: missing"):
            ModelConfig.from_dict(data)
        with pytest.raises(ValueError, match="^config: not valid JSON"):
            ModelConfig.from_json("{kind: teacher")
        with pytest.raises(ValueError, match="^config: expected a JSON object"):
            ModelConfig.from_json("[1, 2]")

    def test_frozen(self) -> None:
        with pytest.raises(dataclasses.FrozenInstanceError):
            teacher_config().mlp_dim = 3  # type: ignore[misc]


# ---------------------------------------------------------------------------------------- sizes


@pytest.mark.parametrize("cfg", CONFIGS, ids=lambda c: f"{c.kind}-Z{c.noise_dim}-pool{c.pool_every_timestep}-E{c.embedding_dim}")
def test_state_dict_names_and_shapes_match_spec(cfg: ModelConfig) -> None:
    gen, _ = build_model(cfg)
    got = {name: list(t.shape) for name, t in gen.state_dict().items()}
    assert got == spec_shapes(cfg)
    assert all(t.dtype == torch.float32 for t in gen.state_dict().values())


def test_parameter_counts() -> None:
    teacher, t_disc = build_model(teacher_config())
    student, s_disc = build_model(student_config())
    n_teacher = sum(p.numel() for p in teacher.parameters())
    n_student = sum(p.numel() for p in student.parameters())
    # Sum of the spec table minus the fixed_noise buffer (not a parameter).
    assert n_teacher == sum(int(torch.tensor(s).prod()) for k, s in spec_shapes(teacher_config()).items() if k != "fixed_noise")
    assert n_teacher == 60_234  # "about 60k" in the paper
    assert n_student == 7_778
    # Discriminators: encoder (E·2+E + LSTM) + Linear(dH, dM) + Linear(dM, 1).
    e = 16
    assert sum(p.numel() for p in t_disc.parameters()) == (2 * e + e) + 4 * 48 * (e + 48 + 2) + (48 * 64 + 64) + (64 + 1)
    assert sum(p.numel() for p in s_disc.parameters()) == (2 * e + e) + 4 * 24 * (e + 24 + 2) + (24 * 16 + 16) + (16 + 1)


def test_discriminator_structure_and_per_agent() -> None:
    _, disc = build_model(teacher_config())
    assert isinstance(disc.real_classifier[-1], nn.Linear)  # raw logit, no ReLU at the end
    g = torch.Generator().manual_seed(0)
    rel = torch.randn(14, 9, 2, generator=g) * 3
    logits = disc(rel)
    assert logits.shape == (9,)
    alone = disc(rel[:, 4:5])
    torch.testing.assert_close(alone, logits[4:5], rtol=1e-6, atol=1e-6)
    with pytest.raises(ValueError, match="traj_rel"):
        disc(rel[:, :, :1])


def test_discriminator_logits_take_both_signs() -> None:
    _, disc = build_model(student_config())
    with torch.no_grad():
        disc.real_classifier[-1].bias.fill_(0.0)
        disc.real_classifier[-1].weight.copy_(torch.linspace(-1, 1, disc.real_classifier[-1].weight.numel()).view(1, -1))
    logits = disc(torch.randn(14, 64, 2, generator=torch.Generator().manual_seed(3)))
    assert (logits < 0).any() and (logits > 0).any()


# ---------------------------------------------------------------------------------------- pooling


def naive_pool(net: PoolHiddenNet, h: torch.Tensor, pos: torch.Tensor, seq_start_end: list[tuple[int, int]]) -> torch.Tensor:
    out = torch.zeros(h.shape[0], net.bottleneck_dim, dtype=h.dtype)
    for start, end in seq_start_end:
        for i in range(start, end):
            best = None
            for j in range(start, end):
                x = torch.cat([net.spatial_embedding(pos[j] - pos[i]), h[j]])
                u = net.mlp_pre_pool(x)
                best = u if best is None else torch.maximum(best, u)
            assert best is not None
            out[i] = best
    return out


def test_pooling_equals_naive_double_loop() -> None:
    torch.manual_seed(0)
    net = PoolHiddenNet(embedding_dim=6, h_dim=5, pool_hidden_dim=19, bottleneck_dim=7).double()
    ranges = [(0, 1), (1, 4), (4, 9), (9, 11)]
    g = torch.Generator().manual_seed(1)
    h = torch.randn(11, 5, generator=g, dtype=torch.float64)
    pos = torch.randn(11, 2, generator=g, dtype=torch.float64) * 20
    scenes = SceneIndex.build(torch.tensor(ranges), 11, "cpu")
    with torch.no_grad():
        fast = net(h, pos, scenes)
        slow = naive_pool(net, h, pos, ranges)
    torch.testing.assert_close(fast, slow, rtol=1e-12, atol=1e-12)
    # and the pooling really mixes agents: changing agent 5 changes its scene-mates only
    pos2 = pos.clone()
    pos2[5] += torch.tensor([3.0, -1.0], dtype=torch.float64)
    with torch.no_grad():
        moved = net(h, pos2, scenes)
    assert torch.equal(moved[:4], fast[:4]) and torch.equal(moved[9:], fast[9:])
    assert not torch.equal(moved[4:9], fast[4:9])


@settings(max_examples=25, deadline=None)
@given(sizes=st.lists(st.integers(min_value=1, max_value=6), min_size=1, max_size=5), seed=st.integers(0, 2**31 - 1))
def test_pooling_property_any_scene_split(sizes: list[int], seed: int) -> None:
    g = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    net = PoolHiddenNet(embedding_dim=4, h_dim=3, pool_hidden_dim=8, bottleneck_dim=5).double()
    total = sum(sizes)
    ends = torch.tensor(sizes).cumsum(0)
    ranges = [(int(e) - n, int(e)) for e, n in zip(ends, sizes, strict=True)]
    h = torch.randn(total, 3, generator=g, dtype=torch.float64)
    pos = torch.randn(total, 2, generator=g, dtype=torch.float64) * 30
    with torch.no_grad():
        fast = net(h, pos, SceneIndex.build(torch.tensor(ranges), total, "cpu"))
        slow = naive_pool(net, h, pos, ranges)
    torch.testing.assert_close(fast, slow, rtol=1e-12, atol=1e-12)
    assert (fast >= 0).all()


@pytest.mark.parametrize(
    ("ranges", "total", "message"),
    [
        ([[0, 2], [3, 5]], 5, "scene 1 starts at 3"),
        ([[1, 5]], 5, "first scene must start at 0"),
        ([[0, 2], [2, 4]], 5, "must end at the agent count 5"),
        ([[0, 2], [2, 2], [2, 5]], 5, "scene 1 is empty"),
        ([], 0, "no scenes"),
    ],
)
def test_scene_index_rejects_bad_ranges(ranges: list[list[int]], total: int, message: str) -> None:
    sse = torch.tensor(ranges, dtype=torch.int64).reshape(-1, 2)
    with pytest.raises(ValueError, match=message):
        SceneIndex.build(sse, total, "cpu")
    with pytest.raises(ValueError, match="integer"):
        SceneIndex.build(torch.zeros(1, 2), 1, "cpu")


# ---------------------------------------------------------------------------------------- generator


def test_positions_to_rel() -> None:
    traj = torch.tensor([[[0.0, 0.0]], [[1.0, 0.5]], [[3.0, 0.5]]])
    assert torch.equal(positions_to_rel(traj)[:, 0], torch.tensor([[0.0, 0.0], [1.0, 0.5], [2.0, 0.0]]))


@pytest.mark.parametrize("cfg", [teacher_config(), student_config(), ODD_CONFIG], ids=["teacher", "student", "odd"])
def test_scenes_never_see_each_other(cfg: ModelConfig) -> None:
    gen, _ = build_model(cfg)
    g = torch.Generator().manual_seed(2)
    a = random_history(g, 3).transpose(0, 1)
    b = random_history(g, 5).transpose(0, 1)
    both = torch.cat([a, b], dim=1)
    ego = torch.randn(cfg.pred_len, 2, 2, generator=g) + 10
    noise = torch.randn(2, cfg.noise_dim, generator=g)
    with torch.no_grad():
        p_both, r_both = gen(both, torch.tensor([[0, 3], [3, 8]]), noise=noise, ego_future=ego)
        p_a, r_a = gen(a, torch.tensor([[0, 3]]), noise=noise[:1], ego_future=ego[:, :1])
        p_b, _ = gen(b, torch.tensor([[0, 5]]), noise=noise[1:], ego_future=ego[:, 1:])
    torch.testing.assert_close(p_both[:, :3], p_a, rtol=1e-6, atol=1e-5)
    torch.testing.assert_close(p_both[:, 3:], p_b, rtol=1e-6, atol=1e-5)
    torch.testing.assert_close(r_both[:, :3], r_a, rtol=1e-6, atol=1e-5)
    # the egos follow the imposed future exactly
    assert torch.equal(p_both[:, 0], ego[:, 0]) and torch.equal(p_both[:, 3], ego[:, 1])


def test_forward_shapes_noise_and_errors() -> None:
    cfg = teacher_config()
    gen, _ = build_model(cfg)
    g = torch.Generator().manual_seed(4)
    obs = random_history(g, 6).transpose(0, 1)
    sse = torch.tensor([[0, 2], [2, 6]])
    pos, rel = gen(obs, sse)
    assert pos.shape == rel.shape == (1, 6, 2)
    torch.testing.assert_close(pos[0], obs[-1] + rel[0])
    pos3, _ = gen(obs, sse, steps=3)
    assert pos3.shape == (3, 6, 2)
    # default noise = fixed_noise for every scene; other noise changes the output
    fixed = gen.fixed_noise.expand(2, -1)
    assert torch.equal(gen(obs, sse, noise=fixed)[0], pos)
    assert not torch.equal(gen(obs, sse, noise=gen.sample_noise(2, torch.Generator().manual_seed(0)))[0], pos)
    with pytest.raises(ValueError, match="noise"):
        gen(obs, sse, noise=torch.zeros(3, cfg.noise_dim))
    with pytest.raises(ValueError, match="obs_traj"):
        gen(obs[1:], sse)
    with pytest.raises(ValueError, match="ego_future"):
        gen(obs, sse, ego_future=torch.zeros(2, 2, 2))
    with pytest.raises(ValueError, match="seq_start_end"):
        gen(obs, torch.tensor([[0, 2], [2, 5]]))


def test_fixed_noise_is_seeded_standard_normal() -> None:
    cfg = teacher_config()
    gen, _ = build_model(cfg)
    expected = torch.randn(cfg.noise_dim, generator=torch.Generator().manual_seed(cfg.noise_seed))
    assert torch.equal(gen.fixed_noise, expected)


def test_training_step_backpropagates() -> None:
    for cfg in (teacher_config(), student_config()):
        gen, disc = build_model(cfg)
        g = torch.Generator().manual_seed(5)
        obs = random_history(g, 5).transpose(0, 1)
        sse = torch.tensor([[0, 2], [2, 5]])
        noise = gen.sample_noise(2, g) if cfg.noise_dim else None
        pos, rel = gen(obs, sse, noise=noise)
        score = disc(torch.cat([positions_to_rel(obs), rel]))
        (pos.square().mean() + score.mean()).backward()
        for name, p in gen.named_parameters():
            assert p.grad is not None and torch.isfinite(p.grad).all(), name
        assert gen.pool_net.mlp_pre_pool[0].weight.grad.abs().sum() > 0


def test_build_model_is_deterministic_and_keeps_global_rng() -> None:
    torch.manual_seed(123)
    before = torch.get_rng_state()
    g1, d1 = build_model(teacher_config())
    assert torch.equal(torch.get_rng_state(), before)
    g2, d2 = build_model(teacher_config())
    for (n1, t1), (n2, t2) in zip(g1.state_dict().items(), g2.state_dict().items(), strict=True):
        assert n1 == n2 and torch.equal(t1, t2)
    for t1, t2 in zip(d1.state_dict().values(), d2.state_dict().values(), strict=True):
        assert torch.equal(t1, t2)
    g3, _ = build_model(teacher_config().replace(seed=99))
    assert not torch.equal(g3.encoder.spatial_embedding.weight, g1.encoder.spatial_embedding.weight)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_matches_cpu() -> None:
    cfg = student_config()
    cpu, _ = build_model(cfg)
    gpu, _ = build_model(cfg, "cuda")
    g = torch.Generator().manual_seed(6)
    history = random_history(g, 7)
    cands = random_candidates(g, history, 3)
    torch.testing.assert_close(student_interactive(gpu, history, cands).cpu(), student_interactive(cpu, history, cands), rtol=1e-4, atol=1e-4)


# ---------------------------------------------------------------------------------------- interactive


def hand_written_teacher(gen: TrajectoryGenerator, history: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
    """One candidate, six explicit one-step generator calls: [N-1, 6, 2]."""
    n = history.shape[0]
    window = history.clone()
    preds = []
    with torch.no_grad():
        for tau in range(6):
            obs = window.transpose(0, 1)
            pos, _ = gen(obs, torch.tensor([[0, n]]), noise=gen.fixed_noise.view(1, -1))
            step = pos[0].clone()
            step[0] = cand[tau]
            preds.append(step[1:])
            window = torch.cat([window[:, 1:], step.unsqueeze(1)], dim=1)
    return torch.stack(preds, dim=1)


def test_teacher_interactive_equals_six_explicit_calls() -> None:
    gen, _ = build_model(teacher_config())
    g = torch.Generator().manual_seed(7)
    history = random_history(g, 6)
    cands = random_candidates(g, history, 3)
    out = teacher_interactive(gen, history, cands)
    assert out.shape == (3, 5, 6, 2)
    for b in range(3):
        torch.testing.assert_close(out[b], hand_written_teacher(gen, history, cands[b]), rtol=1e-6, atol=2e-5)
    # explicit z = fixed_noise gives the same; another z differs
    assert torch.equal(teacher_interactive(gen, history, cands, z=gen.fixed_noise), out)
    assert not torch.equal(teacher_interactive(gen, history, cands, z=torch.zeros(8)), out)
    # the first step does not depend on the candidate
    assert torch.equal(out[0, :, 0], out[1, :, 0])
    assert not torch.equal(out[0, :, 1:], out[1, :, 1:])


def test_student_interactive_matches_generator_with_ego_future() -> None:
    gen, _ = build_model(student_config())
    g = torch.Generator().manual_seed(8)
    history = random_history(g, 5)
    cands = random_candidates(g, history, 3)
    out = student_interactive(gen, history, cands)
    assert out.shape == (3, 4, 6, 2)
    for b in range(3):
        with torch.no_grad():
            pos, rel = gen(history.transpose(0, 1), torch.tensor([[0, 5]]), ego_future=cands[b].unsqueeze(1))
        torch.testing.assert_close(out[b], pos[:, 1:].transpose(0, 1), rtol=1e-6, atol=1e-5)
        assert torch.equal(pos[:, 0], cands[b])  # the ego is the candidate ...
        torch.testing.assert_close(rel[1:, 0], cands[b, 1:] - cands[b, :-1])  # ... and so is its Δp
        torch.testing.assert_close(rel[0, 0], cands[b, 0] - history[0, -1])


def test_student_ego_substitution_drives_the_others() -> None:
    gen, _ = build_model(student_config())
    g = torch.Generator().manual_seed(9)
    history = random_history(g, 4)
    cands = random_candidates(g, history, 2)
    out = student_interactive(gen, history, cands)
    assert not torch.equal(out[0], out[1])
    # a candidate's own later steps cannot affect the others' earlier steps (causality)
    changed = cands.clone()
    changed[:, 3:] += 5.0
    out2 = student_interactive(gen, history, changed)
    assert torch.equal(out2[:, :, :4], out[:, :, :4])
    assert not torch.equal(out2[:, :, 4:], out[:, :, 4:])


@pytest.mark.parametrize("kind", ["teacher", "student"])
def test_permuting_non_ego_agents_permutes_output(kind: str) -> None:
    cfg = teacher_config() if kind == "teacher" else student_config()
    fn = teacher_interactive if kind == "teacher" else student_interactive
    gen, _ = build_model(cfg)
    g = torch.Generator().manual_seed(10)
    history = random_history(g, 7)
    cands = random_candidates(g, history, 2)
    perm = torch.tensor([0, 4, 2, 6, 1, 5, 3])
    out = fn(gen, history, cands)
    out_perm = fn(gen, history[perm], cands)
    torch.testing.assert_close(out_perm, out[:, perm[1:] - 1], rtol=1e-6, atol=2e-5)


@pytest.mark.parametrize("kind", ["teacher", "student"])
def test_interactive_edge_cases_and_determinism(kind: str) -> None:
    cfg = teacher_config() if kind == "teacher" else student_config()
    fn = teacher_interactive if kind == "teacher" else student_interactive
    gen, _ = build_model(cfg)
    gen.train()
    g = torch.Generator().manual_seed(11)
    history = random_history(g, 3)
    cands = random_candidates(g, history, 2)
    first = fn(gen, history, cands)
    assert gen.training  # mode restored
    assert torch.equal(fn(gen, history, cands), first)
    assert fn(gen, history[:1], cands).shape == (2, 0, 6, 2)
    # a batch of candidates equals candidates one by one
    torch.testing.assert_close(fn(gen, history, cands[1:]), first[1:], rtol=1e-6, atol=1e-5)
    with pytest.raises(ValueError, match="history"):
        fn(gen, history[:, 1:], cands)
    with pytest.raises(ValueError, match="candidates"):
        fn(gen, history, cands[:, :5])
    bad = history.clone()
    bad[1, 2, 0] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        fn(gen, bad, cands)


def test_batch_scenes() -> None:
    assert batch_scenes(3, 2, "cpu").tolist() == [[0, 3], [3, 6]]
