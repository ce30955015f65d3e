import gc
import os

import pytest
import taichi as ti

from taichi_sph.run.runtime import init_taichi, reset

# Taichi's offline cache (on in init_taichi; ~/.cache/taichi/ticache, shared by every process, the runs the
# tests start as subprocesses too) keys a kernel on its code and on the fields it touches: their shapes and
# their SNode ids, which count up from 0 after each ti.init. So a second solver in the same runtime compiles
# every kernel again, and a solver is served from the cache only when it is allocated in the same order since
# the last init as one compiled before. The suite writes a few hundred MB; Taichi's default cap is 100 MB with
# LRU cleaning, which evicted kernels the same run had compiled and a re-run compiled them again. Read by
# ti.init; subprocesses inherit it. A value in the environment wins.
os.environ.setdefault("TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES", str(1 << 30))

_ours = None  # the Taichi runtime the fixture below made and no test has allocated in or replaced yet


@pytest.fixture(autouse=True)
def taichi_cpu():
    """Each test starts in a fresh CPU, float32 Taichi runtime (a test may re-initialise explicitly).

    Fresh for two reasons. Taichi frees no field until ti.reset, and past 512 live SNode trees its LLVM
    runtime writes out of bounds (taichi-dev/taichi#8355; Genesis-Embodied-AI/quadrants#814): the whole
    suite in one runtime crashed hundreds of tests later. And a solver built first after an init gets the
    same SNode ids as every other solver built first, so the tests that build the same scene share compiled
    kernels through the offline cache (above) instead of compiling them once per test: test_device_loop's
    ten tests build one column 15 times. A test that allocated nothing leaves the runtime to the next one
    (re-initialising costs ~0.5 s). (The product's multi-run commands release theirs per run:
    executor.release_runtime.)"""
    global _ours
    runtime = ti.lang.impl.get_runtime()
    allocated = runtime.prog is None or runtime.prog.get_snode_tree_size() > 0 or ti.lang.impl.root.ptr.get_num_ch() > 0
    if runtime is not _ours or allocated:
        gc.collect()
        reset()
        init_taichi("cpu", "f32")
        _ours = ti.lang.impl.get_runtime()
    yield


# ----------------------------------------------------------------------------- long tests
# Marked `slow` here, in one list with the reason for each, rather than at each test (so the budget is seen
# whole): `pytest -q` (the README's command) leaves them out (pyproject addopts: -m "not slow"), `pytest -q -m
# slow` runs them, and .ci/run does, after the default set and ruff. Run one by name with `-m slow` or `-m ""`.
# Times: CPU seconds of a cold-cache run on a loaded 2-core machine (this test's process and its children).
SLOW = {
    # three of the five kill moments (the other two, rows 13 and 20, and the SIGINT one stay in the default
    # set): each is a dam-break child process killed, then resumed in-process, ~23 s; the first one in the
    # module also runs the uninterrupted reference (83 s)
    "test_resume.py::test_killed_run_resumes_to_the_uninterrupted_state[6]": "~23-83 s, a kill moment",
    "test_resume.py::test_killed_run_resumes_to_the_uninterrupted_state[28]": "~23 s, a kill moment",
    "test_resume.py::test_killed_run_resumes_to_the_uninterrupted_state[36]": "~23 s, a kill moment",
    "test_resume.py::test_isph_interrupted_run_resumes_within_the_run_to_run_spread": "62 s: ISPH runs to t = 0.5",
    # the pair of patches at the scene's dx 0.02 to t = 0.5 s (the coarse rotating-square runs stay default)
    "test_rotating_square.py::test_tensile_instability_control_keeps_the_patch_without_shifting": "64 s for both",
    # the ISPH stretched drop to t = 0.4 s and the oscillating drop to t = 0.9 s (the WCSPH stretched drop
    # to t = 0.2 s stays default)
    "test_drops.py::test_stretched_drop[isph-0.4-overrides1-0.02]": "215 s wall cold (loaded): ISPH to t = 0.4",
    "test_drops.py::test_oscillating_drop_wcsph_through_the_first_minimum": "175 s wall cold (loaded): to t = 0.9",
    # 3D: the 3D window frame (the 2D one stays default), a 3D dam break and 3D MGCG (3D runs stay default in
    # test_run_render and test_render)
    "test_view.py::test_view_3d_frame_matches_offscreen_and_shows_the_fluid": "55 s: Xvfb, a 3D run in a child",
    "test_wcsph.py::test_dam_break_3d_runs_without_crossings": "50 s: 3D dam break to t = 0.1",
    "test_multigrid.py::test_mgcg_in_1d_and_3d[dam_break_3d.yaml]": "70 s: ISPH with MGCG in 3D (1D stays)",
    # the process-pool battery (two spawned processes compile; test_executor's pool test stays default)
    "test_stability.py::test_battery_on_a_process_pool_assembles_rows_from_the_case_folders": "24 s + spawns",
    # the periodic, shifted variant of the cell walk (the plain one stays default)
    "test_device_loop.py::test_cell_walk_runs_the_same_flow_as_the_lists[over1]": "32 s",
}


@pytest.hookimpl(tryfirst=True)  # before pytest's -m deselection sees the items
def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.nodeid.split("tests/", 1)[-1] in SLOW or item.nodeid.split("tests/", 1)[-1].split("[")[0] in SLOW:
            item.add_marker(pytest.mark.slow)
    # an entry whose test was renamed would silently make a long test default again: refuse it
    modules = {item.module.__name__: item.module for item in items if getattr(item, "module", None) is not None}
    for key in SLOW:
        path, _, name = key.partition("::")
        module = modules.get(path.removesuffix(".py"))
        if module is not None and not hasattr(module, name.split("[")[0]):
            raise pytest.UsageError(f"tests/conftest.py SLOW names {key}, which {path} does not define")
