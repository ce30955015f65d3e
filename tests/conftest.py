import gc
import os

import pytest

from taichi_sph.run.runtime import init_taichi, reset

# Taichi's offline cache (on in init_taichi; ~/.cache/taichi/ticache, shared by every process, the runs the
# tests start as subprocesses too) keys a kernel on its code and the shapes of the fields it touches, so each
# particle count compiles its own copy: the suite writes several hundred MB. Taichi's default cap is 100 MB
# with LRU cleaning, which evicted kernels the same run compiled minutes before and a re-run compiled much of
# the suite again. Read by ti.init; subprocesses inherit it. A value in the environment wins.
os.environ.setdefault("TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES", str(1 << 30))


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
