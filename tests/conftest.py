import numpy as np
import pytest

import sili_robots  # noqa: F401  (registers tasks)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(0)
