"""run/compile_time.py: the kernel cache's size and the memoised front end change what Taichi compiles by nothing.

The time they save is `bench`'s compile time (docs/performance.md), not timed here."""

import pytest
import taichi as ti
from taichi.lang import kernel_impl
from taichi.lang.ast import ast_transformer_utils
from taichi.lang.exception import TaichiNameError

from taichi_sph.run import compile_time
from taichi_sph.run.compile_time import OFFLINE_CACHE_BYTES, memoize_frontend, offline_cache_size
from taichi_sph.run.runtime import init_taichi, reset


@ti.func
def _pair_term(a: ti.f32, b: ti.f32) -> ti.f32:
    s = 0.0
    for k in range(3):
        if a > b:
            s += (a - b) * k
        else:
            s += (
                b - a
            ) * 0.5
    return s


def test_memoised_positions_are_taichis_own_strings(monkeypatch):
    """Every node a kernel's front end asks about gets the string Taichi's own get_pos_info gives (one-line and
    multi-line nodes, a For, an If), and a ti.func inlined twice is served from the memo the second time."""
    assert memoize_frontend()
    context = ast_transformer_utils.ASTTransformerContext
    memo = context.get_pos_info
    assert hasattr(memo, "taichi_original")
    seen = []

    def spy(self, node):
        seen.append((self, node))
        return memo(self, node)

    monkeypatch.setattr(context, "get_pos_info", spy)
    out = ti.field(ti.f32, shape=2)

    @ti.kernel
    def twice():
        out[0] = _pair_term(1.0, 2.0)
        out[1] = _pair_term(3.0, 2.0)

    hits_before = len(memo.cache)
    twice()
    assert out.to_numpy().tolist() == pytest.approx([1.5, 3.0])
    assert len(seen) > 40
    inlined = [(ctx, node) for ctx, node in seen if ctx.func.func.__name__ == "_pair_term"]
    assert len({id(ctx) for ctx, _ in inlined}) == 2  # the func's body transformed once per call site
    assert len(memo.cache) - hits_before < len(seen)  # the second call site's positions were memoised already
    multi_line = [node for _, node in seen if node.end_lineno > node.lineno]
    assert multi_line
    for ctx, node in seen:
        assert memo(ctx, node) == memo.taichi_original(ctx, node)


def test_a_compile_error_still_names_the_file_line_and_node():
    """The memoised strings are what Taichi puts in front of a compile error: file, line, the source line, carets."""
    memoize_frontend()

    @ti.kernel
    def broken() -> ti.f32:
        return undefined_name + 1.0  # noqa: F821

    with pytest.raises(TaichiNameError) as error:
        broken()
    message = str(error.value)
    assert "test_compile_time.py" in message and "in broken" in message
    assert "return undefined_name + 1.0" in message and "^^^" in message
    assert 'Name "undefined_name" is not defined' in message


def _plain(x):
    return (x
            + 1)


def test_source_lines_are_memoised_per_code_object_and_handed_out_as_copies():
    memoize_frontend()
    lines = kernel_impl.getsourcelines
    first, start = lines(_plain)
    assert (first, start) == lines.taichi_original(_plain)
    assert len(first) == 3
    first.append("mutated")
    assert lines(_plain)[0][-1] != "mutated"
    assert kernel_impl.getsourcefile(_plain) == __file__

    def closure(k):
        def inner():
            return k
        return inner

    a, b = closure(1), closure(2)
    before = len(lines.cache)
    lines(a)
    assert lines(b) == lines.taichi_original(b)
    assert len(lines.cache) == before + 1  # one def, one entry, whatever the closure


def test_kernel_impls_textwrap_is_textwrap_with_fill_and_dedent_memoised():
    import textwrap

    memoize_frontend()
    memo = kernel_impl.textwrap
    assert memo is not textwrap and memo.TextWrapper is textwrap.TextWrapper
    line = "\tif a > b:  # a tab, then a comment " + "x" * 120
    assert memo.fill(line, tabsize=4, width=9999) == textwrap.fill(line, tabsize=4, width=9999)
    assert memo.fill(line, width=40) == textwrap.fill(line, width=40)  # the arguments are part of the key
    block = "    def f():\n        return 1\n"
    assert memo.dedent(block) == textwrap.dedent(block) == "def f():\n    return 1\n"
    hits = memo.fill.cache_info().hits
    out = ti.field(ti.f32, shape=2)

    @ti.kernel
    def twice():
        out[0] = _pair_term(1.0, 2.0)
        out[1] = _pair_term(2.0, 1.0)

    twice()
    assert memo.fill.cache_info().hits > hits  # the second inline of _pair_term's lines (Taichi's own call)


def test_the_kernel_cache_is_sized_at_a_gibibyte_unless_the_environment_says(monkeypatch):
    """Taichi's default (100 MB, the least recently used quarter dropped when a process ends) evicted the kernels
    of the bundled scenes' earlier runs; init_taichi asks for 1 GiB. TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES wins."""
    monkeypatch.delenv("TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES", raising=False)
    assert offline_cache_size() == {"offline_cache_max_size_of_files": OFFLINE_CACHE_BYTES}
    reset()
    init_taichi("cpu", "f32")
    assert ti.lang.impl.current_cfg().offline_cache_max_size_of_files == OFFLINE_CACHE_BYTES
    # more than the default: the reset below finalises a runtime of this size, and Taichi drops the least recently
    # used quarter of the cache when it is over it (at 200 MB this test evicted the suite's kernels: the slow set,
    # after the default set, compiled again what it had cached)
    monkeypatch.setenv("TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES", str(OFFLINE_CACHE_BYTES + (1 << 20)))  # (an int32 in Taichi)
    assert offline_cache_size() == {}
    reset()
    init_taichi("cpu", "f32")
    assert ti.lang.impl.current_cfg().offline_cache_max_size_of_files == OFFLINE_CACHE_BYTES + (1 << 20)
    reset()


def test_a_taichi_without_the_patched_names_is_left_alone(monkeypatch):
    monkeypatch.setattr(compile_time, "_memoized", False)
    monkeypatch.delattr(kernel_impl, "getsourcelines")
    assert memoize_frontend() is False
