"""Duplicate keys in any JSON or TOML file the training package reads are refused with a typed
error naming the file and the key (the standard parsers keep the last value silently)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from nudge_train.cli import main
from nudge_train.errors import ConfigError
from nudge_train.models.config import ModelConfig, teacher_config
from nudge_train.models.networks import build_model
from nudge_train.training.config import load_config
from nudge_train.training.export import export_generator, read_weights, save_safetensors


def _dup_config_json() -> str:
    text = teacher_config().to_json()
    assert text.endswith("}")
    return text[:-1] + ',"seed":7}'


def test_model_config_json_with_a_duplicate_key_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"duplicate key 'seed'") as ei:
        ModelConfig.from_json(_dup_config_json())
    assert ei.value.key == "seed"
    assert isinstance(ei.value, ValueError)  # callers that catch ValueError keep working


def test_weights_config_with_a_duplicate_key_names_file_and_key(tmp_path: Path) -> None:
    gen, _ = build_model(teacher_config())
    good = export_generator(gen, teacher_config(), tmp_path / "good.safetensors", trained=False, provenance={})
    meta_ok = read_weights(good)
    assert meta_ok.config == teacher_config()
    tensors = {k: v.contiguous() for k, v in gen.state_dict().items()}
    bad = tmp_path / "dup.safetensors"
    save_safetensors(tensors, bad, {"format": "nudge.weights/1", "config": _dup_config_json(),
                                    "trained": "false", "provenance": "{}"})
    with pytest.raises(ConfigError, match=r"dup\.safetensors: config: duplicate key 'seed'") as ei:
        read_weights(bad)
    assert ei.value.path == str(bad)
    save_safetensors(tensors, bad, {"format": "nudge.weights/1", "config": teacher_config().to_json(),
                                    "trained": "false", "provenance": '{"run": 1, "run": 2}'})
    with pytest.raises(ConfigError, match=r"dup\.safetensors: provenance: duplicate key 'run'"):
        read_weights(bad)


@pytest.mark.parametrize(("text", "key"), [
    ('[train]\nlr = 0.01\nepochs = 3\nlr = 0.02\n', "lr"),
    ('[model]\nkind = "teacher"\n[train]\nepochs = 3\n[model]\nseed = 2\n', "model"),
    ('[train]\n"batch_size" = 4\nbatch_size = 8\n', "batch_size"),
])
def test_training_toml_with_a_duplicate_key_names_file_and_key(tmp_path: Path, text: str, key: str,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "dup.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=rf"dup\.toml, row \d+: duplicate key '{key}'") as ei:
        load_config(path)
    assert ei.value.path == str(path) and ei.value.key == key
    assert main(["train", "--config", str(path), "--epochs", "1"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "dup.toml" in err and f"'{key}'" in err


def test_manifests_with_duplicate_keys_are_refused(tmp_path: Path) -> None:
    from nudge_train.data.loader import load_split

    m = tmp_path / "manifest.json"
    m.write_text('{"schema": "nudge.dataset/1", "splits": {}, "splits": {"train": {"shards": []}}}')
    with pytest.raises(ConfigError, match=r"manifest\.json: duplicate key 'splits'"):
        load_split(tmp_path, "train")
    m.write_text('{"schema": "nudge.dataset/1", "splits": {"train": {"shards": [], "shards": []}}}')
    with pytest.raises(ConfigError, match=r"manifest\.json: duplicate key 'shards'"):
        load_split(tmp_path, "train")


def test_well_formed_files_still_load(tmp_path: Path) -> None:
    p = tmp_path / "ok.toml"
    p.write_text('[model]\nkind = "student"\n[train]\nepochs = 2\n[train.nothing]\n')
    with pytest.raises(ValueError, match="nothing"):
        load_config(p)
    p.write_text('[model]\nkind = "student"\n[train]\nepochs = 2\n')
    assert load_config(p)[1].epochs == 2
    assert json.loads(teacher_config().to_json())["seed"] == 1
    assert ModelConfig.from_json(teacher_config().to_json()) == teacher_config()
