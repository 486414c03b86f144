"""Test session setup: the LLVM backend with all cores, chosen once for the whole suite."""

import pytest

import sgdr.backend


def pytest_configure(config):
    sgdr.backend.init("llvm")


@pytest.fixture
def rng():
    import numpy as np

    return np.random.default_rng(1234)
