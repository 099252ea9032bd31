"""Shared fixtures: the two registered environments."""

import pytest

import wrl_jax

ENV_NAMES = ["Warehouse-8x8-v0", "Warehouse-12x12-v0"]


@pytest.fixture(params=ENV_NAMES)
def env_name(request):
    return request.param


@pytest.fixture
def env_and_params(env_name):
    return wrl_jax.make(env_name)
