import gc
import json
import os
from pathlib import Path

import pytest
import taichi as ti

from taichi_sph.run.runtime import init_taichi, reset
from taichi_sph.studies.executor import worker_threads

# Taichi's offline cache (on in init_taichi; ~/.cache/taichi/ticache, shared by every process, the runs the
# tests start as subprocesses too) keys a kernel on its code and on the fields it touches: their shapes and
# their SNode ids, which count up from 0 after each ti.init. So a second solver in the same runtime compiles
# every kernel again, and a solver is served from the cache only when it is allocated in the same order since
# the last init as one compiled before. The suite writes a few hundred MB: init_taichi sizes the cache at 1 GiB
# (run/compile_time.py; Taichi's default of 100 MB evicted kernels the same run had compiled).
# Under pytest-xdist with two or more workers (the README's command runs two on two cores) each worker's Taichi gets
# its share of the cores, as the product's process pool gives its workers (executor.worker_threads: one each here):
# with a thread per core in every worker, the threads of one loop waited on each other across workers (the slow
# set's standing-wave and drop files: 191 s wall with Taichi's default threads, 165 s with one). Subprocesses the
# tests start inherit it. A value in the environment wins.
_workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
if _workers >= 2:
    os.environ.setdefault("TI_CPU_MAX_NUM_THREADS", str(worker_threads(_workers)))

_ours = None  # the Taichi runtime the fixture below made and no test has allocated in or replaced yet


@pytest.fixture(autouse=True)
def taichi_cpu():
    """Each test starts in a fresh CPU, float32 Taichi runtime (a test may re-initialise explicitly). With
    TAICHI_SPH_TEST_ARCH set (the device set, tests/test_vulkan.py; or the whole suite on a GPU) init_taichi
    serves this request for the CPU by that arch instead, still float32.

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
    "test_executor.py::test_ray_cluster_gives_the_same_sweep_as_one_process": "~13 s: starts a local Ray cluster",
    "test_gradient_normalisation.py::test_the_bundled_tank_holds_rho0_g_d_to_a_tenth_of_a_percent": "~55 s: WCSPH, 6.4k fluid, 5k steps in f64",
    "test_wall_motion.py::test_a_piston_makes_the_wave_height_of_biesels_transfer_function": "~50 s (WCSPH, 2.3k fluid), 25 s (ISPH, 4k): to t = 6",
    "test_drops.py::test_isph_defaults_keep_a_users_drop_within_two_percent": "71 s under load 6 (~25 s quiet): ISPH to t = 0.4",
    # the drop into a pool at half the default step, with and without the switch's noise source
    "test_viscosity_switch.py::test_the_noise_source_holds_a_pool_at_a_small_step[2.0-ok]": "~15-25 s: ISPH to t = 0.75",
    "test_viscosity_switch.py::test_the_noise_source_holds_a_pool_at_a_small_step[0.0-unstable]": "~10-20 s: to 0.57 s",
    # the wave with ISPH's defaults over 3 periods (the two short unstable set-ups stay default)
    "test_standing_wave.py::test_isph_defaults_keep_the_wave_for_three_periods[0.025]": "~10-35 s: to t = 5",
    "test_standing_wave.py::test_isph_defaults_keep_the_wave_for_three_periods[0.0125]": "~25-50 s: 12.8k fluid, to t = 5",
    "test_standing_wave.py::test_wcsph_defaults_keep_the_wave_for_three_periods": "~70 s quiet, 134 s loaded: to t = 5",
    "test_standing_wave.py::test_the_wall_particles_in_the_shift_feed_the_wave": "~40 s: to t = 5",
    "test_standing_wave.py::test_isph_defaults_keep_the_3d_wave": "~30-45 s: 3D, 8k fluid, to t = 5",
    "test_standing_wave.py::test_the_fixed_surface_depth_makes_the_wave_slow": "~15-40 s: to t = 5",
    # the deep-water wave with the defaults stays default (~11 s); the fixed-depth failing mode is slow
    "test_standing_wave.py::test_the_fixed_depth_makes_a_deep_water_wave_slow": "~11-20 s: to t = 3.4",
    # the three kill moments: each is a dam-break child process killed, then resumed in-process, ~23 s; the
    # first one in the module also runs the uninterrupted reference (83 s)
    "test_resume.py::test_killed_run_resumes_to_the_uninterrupted_state[6]": "~23-83 s, a kill moment",
    "test_resume.py::test_killed_run_resumes_to_the_uninterrupted_state[36]": "~23 s, a kill moment",
    "test_resume.py::test_isph_interrupted_run_resumes_within_the_run_to_run_spread": "62 s: ISPH runs to t = 0.5",
    # the hexagonal packing's settled wave (in its own file: the slow set's workers take a file each)
    "test_packing.py::test_wcsph_on_a_hexagonal_packing_meets_the_wave_targets": "~70-120 s: 0.6 s settling, to t = 5",
    # the pair of patches at the scene's dx 0.02 to t = 0.5 s (the coarse rotating-square runs stay default)
    "test_rotating_square.py::test_tensile_instability_control_keeps_the_patch_without_shifting": "64 s for both",
    # the ISPH stretched drop to t = 0.4 s and the oscillating drop to t = 0.9 s (the WCSPH stretched drop
    # to t = 0.2 s stays default)
    "test_drops.py::test_stretched_drop[isph-0.4-overrides1-0.035-0.45]": "215 s wall cold (loaded): ISPH to t = 0.4",
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
    # every test of 40 s or more in a profile of the whole default set (session 10: 596 tests, 89 test-minutes on
    # 2 workers under load 3-5, about 2x a quiet machine's): these 52 held 62 of the 89 minutes, most of it
    # compiling a solver for one scene; each runs in .ci/run's slow set. Times: that profile's wall seconds.
    "test_multigrid.py::test_mgcg_iterations_stay_flat_while_cg_grows": "185 s",
    "test_multigrid.py::test_mgcg_on_a_periodic_box": "180 s",
    "test_executor.py::test_pool_gives_the_same_errors_as_one_process": "143 s",
    "test_run_render.py::test_dam_break_renders_frames_and_video[dam_break_3d.yaml-0.06-0.04-4]": "118 s",
    "test_run_safety.py::test_disk_full_in_a_snapshot_fails_cleanly_and_resume_continues": "108 s",
    "test_validation.py::test_cavity_coarse_run_approaches_ghia": "108 s",
    "test_isph.py::test_the_bundled_cavity_keeps_going_past_its_corner_blow_up": "40 s (session 18)",
    "test_particle_order.py::test_a_hole_in_a_lattice_is_a_void_and_only_its_rim_is_flagged[3]": "93 s",
    "test_validation.py::test_poiseuille_coarse_start_up_follows_the_series": "91 s",
    "test_ppe_loop.py::test_runs_do_not_depend_on_check_every[mgcg]": "84 s",
    "test_multigrid.py::test_ppe_loop_schedules_give_bit_identical_runs[mgcg]": "81 s",
    "test_wcsph.py::test_kinematic_wall_condition_keeps_an_impact_inside_the_box": "80 s",
    "test_validation.py::test_taylor_green_coarse_short_run_keeps_its_energy": "77 s",
    "test_eulerian_isph.py::test_the_bundled_taylor_green_in_the_eulerian_frame": "40 s",
    "test_multigrid.py::test_mgcg_and_cg_give_the_same_pressure_on_the_same_step[mixed]": "75 s",
    "test_isph.py::test_kinematic_wall_condition_holds_a_splash_off_the_walls": "73 s",
    "test_isph.py::test_density_source_corrects_compression_only": "68 s",
    "test_run_safety.py::test_a_truncated_newest_checkpoint_of_a_run_resumes_from_the_previous_one": "67 s",
    "test_multigrid.py::test_mgcg_hydrostatic_tank_in_f64": "66 s",
    "test_readme_api.py::test_readme_python_api_example_runs_as_written": "66 s",
    "test_run_safety.py::test_disk_full_in_a_checkpoint_keeps_the_previous_one": "65 s",
    "test_device_loop.py::test_batches_equal_single_steps_bit_for_bit[True]": "64 s",
    "test_resume.py::test_interrupted_run_exits_130_and_resumes": "63 s",
    "test_compare.py::test_compare_tiny_writes_the_report": "62 s",
    "test_multigrid.py::test_mgcg_and_cg_give_the_same_pressure_on_the_same_step[neumann_pinned]": "62 s",
    "test_executor.py::test_resume_runs_only_the_case_whose_summary_is_missing": "61 s",
    "test_drops.py::test_stretched_drop[wcsph-0.2-overrides0-0.03-0.5]": "61 s",
    "test_stability.py::test_six_times_the_cfl_limit_is_classified_unstable": "60 s",
    "test_multigrid.py::test_preconditioner_is_symmetric_positive_definite[dirichlet_only]": "59 s",
    "test_wcsph.py::test_hydrostatic_small_tank_pressure": "58 s",
    "test_resume.py::test_killed_run_resumes_to_the_uninterrupted_state[20]": "58 s",
    "test_wcsph.py::test_dam_break_with_the_tensile_correction_runs_to_the_end_inside_the_walls": "57 s",
    "test_multigrid.py::test_preconditioner_is_symmetric_positive_definite[mixed]": "57 s",
    "test_ppe_loop.py::test_runs_do_not_depend_on_check_every[cg]": "56 s",
    "test_wcsph.py::test_hydrostatic_leapfrog_agrees": "55 s",
    "test_multigrid.py::test_level_kernels_and_the_one_thread_cycle_apply_the_same_preconditioner": "54 s",
    "test_multigrid.py::test_preconditioner_symmetric_and_positive_on_random_vectors_of_a_larger_tank": "54 s",
    "test_run_safety.py::test_a_real_full_filesystem": "53 s",
    "test_wcsph.py::test_momentum_conserved_periodic_random_velocities": "53 s",
    "test_rotating_square.py::test_rotating_square_short[wcsph]": "52 s",
    "test_ppe_loop.py::test_fused_iteration_equals_the_split_one[True]": "52 s",
    "test_multigrid.py::test_preconditioner_is_symmetric_positive_definite[neumann_pinned]": "52 s",
    "test_particle_order.py::test_interior_density_error_leaves_out_the_surface_band[wcsph]": "51 s",
    "test_multigrid.py::test_ppe_loop_schedules_give_bit_identical_runs[cg]": "50 s",
    "test_walls.py::test_a_sliding_wall_over_a_shear_flow_never_triggers_the_condition": "47 s",
    "test_executor.py::test_a_killed_case_status_running_is_run_again_on_resume": "46 s",
    "test_wcsph.py::test_f64_precision_runs_in_float64": "46 s",
    "test_preflight.py::test_force_runs_a_refused_setup": "46 s",
    "test_multigrid.py::test_mgcg_in_1d_and_3d[column_1d.yaml]": "46 s",
    "test_ppe_loop.py::test_jacobi_stops_on_the_iteration_and_does_not_depend_on_check_every": "44 s",
    "test_wcsph.py::test_too_large_fixed_dt_is_caught_as_unstable": "41 s",
    # and the longest of the default set that was left (a second profile, 556 tests in 10:46 under load 3-4)
    "test_view.py::test_realtime_view_writes_the_rtf_and_frame_rate": "50 s: Xvfb, a measurement and a paced run",
    "test_resume.py::test_a_finished_run_extends_with_t_end": "49 s",
    "test_isph.py::test_jacobi_reaches_the_same_solution_with_more_iterations": "27 s",
    "test_neighbors.py::test_cell_walk_visits_the_list_entries_in_list_order[3-periodic7]": "31 s (5 other 3D cases stay)",
    "test_neighbors.py::test_periodic_matches_minimum_image_brute_force[3-periodic4]": "26 s (2 other 3D cases stay)",
    # the longest of the default set in a cold-cache profile on a quiet machine (session 15: 586 tests in 9:02,
    # over the README command's 8 minutes; seconds of that profile)
    "test_realtime.py::test_real_measurement_and_choice_on_a_tiny_scene": "57 s: compiles two particle counts",
    "test_wcsph.py::test_antuono_diffusion_vanishes_on_the_hydrostatic_column_where_molteni_does_not": "29 s",
    "test_ppe_loop.py::test_fused_iteration_equals_the_split_one[False]": "27 s",
    "test_wcsph.py::test_loop_schedule_gives_identical_results": "23 s",
    "test_validate.py::test_quick_run_of_a_tiny_scene_writes_the_table_with_numbers": "23 s",
    "test_validate.py::test_a_quick_convergence_study_adds_its_runs_and_section": "17 s: three tank runs",
    "test_standing_wave.py::test_a_wave_that_gains_energy_ends_unstable[overrides0-1.5]": "30 s (the other two stay)",
    "test_run_safety.py::test_disk_full_in_the_timeseries_or_the_summary[timeseries]": "22 s (the summary case stays)",
    "test_executor.py::test_a_failed_case_does_not_stop_the_others_and_is_in_the_report": "22 s",
    "test_device_loop.py::test_batches_equal_single_steps_bit_for_bit[False]": "21 s",
    "test_drops.py::test_wcsph_defaults_keep_a_users_drop_within_two_percent": "21 s",
    # the longest of the default set in a cold-cache profile on a quiet machine (session 37: 689 tests in 8:50 with
    # an empty Taichi kernel cache, over the README command's 8 minutes; 4:43 warm; seconds of that profile)
    "test_isph.py::test_artificial_viscosity_does_not_expand_a_free_surface": "35 s",
    "test_isph_loop.py::test_batches_with_mgcg_and_continuity_density_equal_single_steps": "28 s",
    "test_viscosity_switch.py::test_a_users_drop_into_a_pool_ends_ok_with_the_defaults": "27 s each solver: to t = 1",
    "test_drops.py::test_oscillating_drop_isph_through_the_first_minimum": "23 s",
    "test_shift_density.py::test_the_continuity_density_makes_a_shift_do_the_work_of_the_pressure_and_gravity": "18-21 s each",
    # the longest of the default set in a profile of .ci/run on a clean clone (session 48: 763 tests in 573 s, the
    # kernel cache cold, over the README command's 8 minutes; seconds of that profile)
    "test_standing_wave.py::test_isph_defaults_keep_a_deep_water_waves_period": "22 s: ISPH to 1.2 periods",
    "test_transport_velocity.py::test_background_pressure_is_zero_on_the_lattice_and_pushes_a_close_pair_apart": "21 s",
    "test_isph.py::test_jacobi_and_cg_agree_on_the_tank": "19 s: two solves to a tight tolerance",
    "test_ppe_loop.py::test_atomic_sums_of_the_gpu_path_converge_alike": "17 s",
}


def node_key(item) -> str:
    """'test_file.py::test_name[param]': a test's name in SLOW and in tests/durations.json."""
    return item.nodeid.split("tests/", 1)[-1]


@pytest.hookimpl(tryfirst=True)  # before pytest's -m deselection sees the items
def pytest_collection_modifyitems(config, items):
    for item in items:
        if node_key(item) in SLOW or node_key(item).split("[")[0] in SLOW:
            item.add_marker(pytest.mark.slow)
    # an entry whose test was renamed would silently make a long test default again: refuse it
    modules = {item.module.__name__: item.module for item in items if getattr(item, "module", None) is not None}
    for key in SLOW:
        path, _, name = key.partition("::")
        module = modules.get(path.removesuffix(".py"))
        if module is not None and not hasattr(module, name.split("[")[0]):
            raise pytest.UsageError(f"tests/conftest.py SLOW names {key}, which {path} does not define")


# ----------------------------------------------------------------------------- the longest files first
# The two xdist workers take a file at a time (pyproject addopts: --dist loadfile), in collection order
# (--no-loadscope-reorder: xdist's own order is by the number of tests in a file, which sent a file holding one
# long test last, and one worker ran it while the other had finished). Here the files are ordered by the seconds
# their selected tests took in the last profile (tests/durations.json, `pytest --durations=0` of the default and
# the slow set, scripts/test_durations.py; a test it does not list counts DEFAULT_SECONDS), the longest first: the
# files that end the run are short ones. Only on the workers (both order alike); a run without xdist keeps the
# files' order.
DURATIONS = Path(__file__).with_name("durations.json")
DEFAULT_SECONDS = 0.05  # the profile leaves out what took less (pytest hides < 5 ms, the script < 0.05 s)


class LongestFilesFirst:
    @pytest.hookimpl(trylast=True)  # after -m has deselected: the estimate is of the tests that will run
    def pytest_collection_modifyitems(self, config, items):
        seconds = json.loads(DURATIONS.read_text()) if DURATIONS.is_file() else {}
        per_file: dict[str, float] = {}  # in the order the files come: the stable sort keeps it among equals
        for item in items:
            path = node_key(item).split("::", 1)[0]
            per_file[path] = per_file.get(path, 0.0) + seconds.get(node_key(item), DEFAULT_SECONDS)
        rank = {path: i for i, path in enumerate(sorted(per_file, key=lambda path: -per_file[path]))}
        items.sort(key=lambda item: rank[node_key(item).split("::", 1)[0]])  # stable: a file's tests keep their order


def pytest_configure(config):
    if os.environ.get("PYTEST_XDIST_WORKER"):
        config.pluginmanager.register(LongestFilesFirst(), "taichi_sph_longest_files_first")
