import gc

import pytest

from taichi_sph.run.runtime import init_taichi, reset


@pytest.fixture(autouse=True, scope="module")
def taichi_cpu():
    """All tests run on the CPU in float32 unless a test re-initialises explicitly; a fresh runtime for each
    test module. Taichi frees no field until ti.reset, and past 512 live SNode trees its LLVM runtime writes
    out of bounds (taichi-dev/taichi#8355; Genesis-Embodied-AI/quadrants#814): the whole suite in one
    runtime crashed hundreds of tests later. (The product's multi-run commands release theirs per run:
    executor.release_runtime.)"""
    gc.collect()
    reset()
    init_taichi("cpu", "f32")
    yield
