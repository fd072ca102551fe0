"""The Python examples a user copies from the docs run against this package.

Every ```python block of ``docs/concepts.md`` runs here, in order, in one namespace (a later block uses what an
earlier one built), on the real simulator; the README's one block is the first of them, word for word. A block
written as a fragment of the user's own loop gets only what it names and does not build: ``collector`` (a TorchRL
collector of two small batches) and, for the reward-learning loop, a ``reward`` not yet attached to an env, as its
text says. Without this, a renamed argument or method leaves an example that fails on the user's first paste.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FENCE = re.compile(r"^```python\n(.*?)^```", re.S | re.M)


def python_blocks(page: Path) -> list[str]:
    return FENCE.findall(page.read_text())


def test_readme_example_is_the_first_concepts_example():
    readme, concepts = python_blocks(ROOT / "README.md"), python_blocks(ROOT / "docs" / "concepts.md")
    assert len(readme) == 1, "README.md should keep one Python example (the rest live on the docs site)"
    assert readme[0] == concepts[0], "README.md's example differs from docs/concepts.md's first: keep them equal"


def fragment_names(ns: dict) -> dict:
    """What the loop fragment (the second block) leaves to the user: a collector and an unattached reward."""
    from torchrl.collectors import Collector

    from drs_torchrl.transforms import DrSReward

    env = ns["env"]
    return {
        "collector": Collector(env, None, frames_per_batch=32, total_frames=64),
        "reward": DrSReward.from_spec(env.observation_spec, 3, ["observation", "stage_indicators"]),
    }


@pytest.mark.sim
def test_concepts_examples_run(tmp_path, monkeypatch):
    blocks = python_blocks(ROOT / "docs" / "concepts.md")
    assert len(blocks) == 3, "docs/concepts.md's examples changed: say here what each new one needs"
    monkeypatch.chdir(tmp_path)  # the examples write reward.pt into the working directory
    ns: dict = {"__name__": "docs_example"}
    for i, block in enumerate(blocks):
        if "for batch in collector:" in block:
            ns.update(fragment_names(ns))
        try:
            exec(compile(block, f"docs/concepts.md, python block {i + 1}", "exec"), ns)
        except Exception as exc:  # the block's own traceback names its line
            raise AssertionError(f"docs/concepts.md's python block {i + 1} fails: {exc!r}") from exc
        CLAIMS[i](ns, tmp_path)


def stage_pieces_claims(ns, _):
    assert ns["batch"].shape[:2] == (3, 2), "the discriminator batch should be (N, 2, B): negatives / positives"
    assert {"loss_discriminator", "loss_0", "accuracy_2", "active_2"} <= set(ns["out"].keys())


def learner_loop_claims(ns, tmp_path):
    from drs_torchrl.transforms import DrSReward, load_reward

    assert len(ns["replay"]) == 64, "the loop should have stored both collector batches"
    assert isinstance(load_reward(tmp_path / "reward.pt"), DrSReward), "the loop should save a reusable reward.pt"


def factories_claims(ns, _):
    assert ns["rewards"].numel() > 0 and len(ns["stats"].keys()) > 0, "one SAC update should report its losses"


CLAIMS = (stage_pieces_claims, learner_loop_claims, factories_claims)
