"""The library path applies the config's thread count as train.py does (docs/guide/library.md)."""

import pytest
import torch

import cmdp_rl
from cmdp_rl.config.run_config import compose_config


@pytest.fixture
def restore_threads():
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


def test_load_config_sets_torchs_thread_count(restore_threads):
    torch.set_num_threads(2)
    cfg = cmdp_rl.load_config({"algo": {"name": "ppo_lag"}})  # the library guide's example, threads=1 by default
    assert cfg.threads == 1 and torch.get_num_threads() == 1
    cmdp_rl.load_config({"threads": 2})
    assert torch.get_num_threads() == 2


def test_compose_config_sets_it_too(restore_threads):
    torch.set_num_threads(2)
    compose_config(["env=reach1d_torch"])
    assert torch.get_num_threads() == 1
