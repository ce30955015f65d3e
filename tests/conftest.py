import pytest

from taichi_sph.runtime import init_taichi


@pytest.fixture(autouse=True, scope="session")
def taichi_cpu():
    """All tests run on the CPU in float32 unless a test re-initialises explicitly."""
    init_taichi("cpu", "f32")
    yield
