"""Every env's class docstring is its specification (README, "Environments"): the Gymnasium sections."""

from __future__ import annotations

import importlib
import inspect

import pytest

from kin_envs.envs import ENV_IDS, VECTOR_ENTRY_POINTS

SECTIONS = ("Description", "Action Space", "Observation Space", "Rewards", "Starting State", "Episode End",
            "Arguments", "Version History")  # fmt: skip
CURRENT = {
    **{f"{k} (vector)": v for k, v in VECTOR_ENTRY_POINTS.items()},
    **{k: v for k, v in ENV_IDS.items() if k.endswith("-v1")},
    "aggregation_v1": "kin_envs.envs.aggregation:AggregationEnv",
}


def _cls(entry_point: str):
    module, name = entry_point.split(":")
    return getattr(importlib.import_module(module), name)


@pytest.mark.parametrize("env_id", sorted(CURRENT))
def test_current_envs_document_every_section(env_id):
    # the vector envs had a one-line docstring: their batched spaces, seeding and autoreset were nowhere
    doc = inspect.getdoc(_cls(CURRENT[env_id])) or ""
    missing = [s for s in SECTIONS if f"\n## {s}\n" not in f"\n{doc}\n"]
    assert not missing, f"{env_id}: docstring lacks {missing}"


@pytest.mark.parametrize("env_id", sorted(k for k in ENV_IDS if k.endswith("-v0")) + ["aggregation_v0"])
def test_old_versions_point_to_the_current_spec(env_id):
    entry = ENV_IDS.get(env_id, "kin_envs.envs.aggregation:AggregationEnvV0")
    cls = _cls(entry)
    parent = cls.__mro__[1]  # v0 is v1 with the v0 info layout: v1's docstring is the spec
    assert parent.__name__ in (inspect.getdoc(cls) or "") and "v0" in (inspect.getdoc(parent) or "")
