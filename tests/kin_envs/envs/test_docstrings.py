"""Every env's class docstring is its specification (README, "Environments"): the Gymnasium sections."""

from __future__ import annotations

import importlib
import inspect

import pytest

from kin_envs.envs import ENV_IDS, VECTOR_ENTRY_POINTS

SECTIONS = ("Description", "Action Space", "Observation Space", "Rewards", "Starting State", "Episode End",
            "Arguments", "Version History")  # fmt: skip
CURRENT = {
    **{f"{k} (vector)": v for k, v in VECTOR_ENTRY_POINTS.items() if k.endswith("-v2")},
    **{k: v for k, v in ENV_IDS.items() if k.endswith("-v2")},
    "aggregation_v2": "kin_envs.envs.aggregation:AggregationEnv",
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


OLD = {
    **{k: v for k, v in ENV_IDS.items() if not k.endswith("-v2")},
    **{f"{k} (vector)": v for k, v in VECTOR_ENTRY_POINTS.items() if not k.endswith("-v2")},
    "aggregation_v1": "kin_envs.envs.aggregation:AggregationEnvV1",
    "aggregation_v0": "kin_envs.envs.aggregation:AggregationEnvV0",
}


@pytest.mark.parametrize("env_id", sorted(OLD))
def test_old_versions_point_to_the_current_spec(env_id):
    """v1 and v0 subclass the current (v2) class, name it, and its Version History tells them apart."""
    cls = _cls(OLD[env_id])
    parent = cls.__mro__[1]
    version = env_id.split()[0][-2:]
    assert parent.__name__ in (inspect.getdoc(cls) or ""), env_id
    assert f"* {version}:" in (inspect.getdoc(parent) or ""), env_id
    assert parent in {_cls(v) for v in CURRENT.values()}, env_id
