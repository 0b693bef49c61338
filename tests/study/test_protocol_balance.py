"""target_n against the block: an arm must get a participant whatever the concealed draw puts first."""
from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from _study_data import PROTOCOL, write_protocol
from nao_trainer.cli import main
from nao_trainer.study.protocol import load_protocol
from nao_trainer.study.registry import allocation_sequence


@pytest.mark.parametrize("block, target", [(6, 4), (6, 3), (30, 12), (12, 8)])
def test_a_target_the_first_block_may_not_reach_every_arm_with_is_refused(tmp_path, capsys, block, target):
    text = PROTOCOL.replace("block_size: 6", f"block_size: {block}").replace("target_n: 12", f"target_n: {target}")
    path = write_protocol(tmp_path, text)
    code = main(["study", "init", str(path), "--out", str(tmp_path / "study")])
    err = capsys.readouterr().err
    need = block - block // 3 + 1
    assert code == 2 and "no participants possible" in err and f"give at least {need}" in err, err
    assert len(err.strip().splitlines()) == 1 and f"{path}:" in err and not (tmp_path / "study").exists()


def test_the_bound_is_tight_some_seed_leaves_an_arm_empty_just_below_it(tmp_path):
    """With blocks of 6 and 3 arms, 4 participants can miss an arm (so 4 is refused); 5 never can."""
    empty_at_4 = False
    p = load_protocol(write_protocol(tmp_path))
    for seed in range(30):
        seq = allocation_sequence(p, np.random.default_rng(seed))[""]
        assert len(Counter(seq[:5])) == 3
        empty_at_4 |= len(Counter(seq[:4])) < 3
    assert empty_at_4


@pytest.mark.parametrize("block, target", [(6, 5), (3, 3), (12, 9)])
def test_a_target_that_reaches_every_arm_is_accepted(tmp_path, block, target):
    text = PROTOCOL.replace("block_size: 6", f"block_size: {block}").replace("target_n: 12", f"target_n: {target}")
    assert load_protocol(write_protocol(tmp_path, text)).target_n == target
