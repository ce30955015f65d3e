"""Taichi's compile time: the kernel cache's size and memos for Taichi's front end.

What a run spends before its first step, measured on the 2-core development VM (`dam_break_2d` at dx 0.05, f32,
one thread, the solver built and 20 steps, Taichi 1.7.4; docs/performance.md "Compile time"):

1. The offline cache (~/.cache/taichi) keeps compiled kernels between processes. Taichi's default caps it at 100 MB
   and, past that, drops the least recently used quarter when a process ends. Field shapes are compile-time
   constants here, so each scene, solver and particle count has kernels of its own, and the bundled scenes' fill
   more than 100 MB: a run then compiled again what an earlier run had cached (WCSPH 3.6 s of LLVM on that scene;
   `validate --quick`: 268 s of its runs' 730 s were compile time). `offline_cache_size` asks for 1 GiB.
2. Taichi's front end builds a position string (file, line, the source line and a caret line under the node, both
   wrapped by textwrap) for every AST node it transforms, and reads a function's source with inspect (tokenize)
   each time the function is inlined. A solver inlines the same `ti.func` bodies hundreds of times (30k nodes for
   WCSPH's 26 kernels, 4.7k distinct positions). Both depend on the source text only, so `memoize_frontend`
   remembers them, and the tab expansion (textwrap.fill) of every source line it does per inline: the same strings,
   computed once (WCSPH 4.1 -> 3.2 s, ISPH 6.6 -> 4.6 s with the cache warm, before the textwrap memo).

The memos touch Taichi's internals (taichi.lang.ast.ast_transformer_utils.ASTTransformerContext.get_pos_info and
the `getsourcelines` / `getsourcefile` / `textwrap` names kernel_impl imported), so each is applied only where those
names exist as expected and is otherwise left out: a Taichi without them compiles as before, only slower.
"""

from __future__ import annotations

import functools
import inspect
import os
import textwrap
import types
from typing import Any, Callable

OFFLINE_CACHE_BYTES = 1 << 30
_ENV_CACHE_SIZE = "TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES"

_memoized = False


def offline_cache_size() -> dict[str, int]:
    """The ti.init argument that sizes the kernel cache (1 GiB), or nothing where the user's
    TI_OFFLINE_CACHE_MAX_SIZE_OF_FILES sets it (a ti.init argument would override that variable)."""
    if os.environ.get(_ENV_CACHE_SIZE, "").strip():
        return {}
    return {"offline_cache_max_size_of_files": OFFLINE_CACHE_BYTES}


def memoize_frontend() -> bool:
    """Memoise Taichi's per-node position strings, per-function source lines and per-line tab expansion (once per
    process); True where the first two are in place (the third where kernel_impl uses textwrap as it did)."""
    global _memoized
    if _memoized:
        return True
    try:
        from taichi.lang import kernel_impl
        from taichi.lang.ast import ast_transformer_utils as utils
    except ImportError:
        return False
    context = getattr(utils, "ASTTransformerContext", None)
    position = getattr(context, "get_pos_info", None)
    lines, source_file = getattr(kernel_impl, "getsourcelines", None), getattr(kernel_impl, "getsourcefile", None)
    if not all(callable(f) for f in (position, lines, source_file)):
        return False
    context.get_pos_info = memoized_position_info(position)
    kernel_impl.getsourcelines = memoized_by_code(lines, copy=lambda r: (list(r[0]), r[1]))
    kernel_impl.getsourcefile = memoized_by_code(source_file)
    if getattr(kernel_impl, "textwrap", None) is textwrap:
        kernel_impl.textwrap = memoized_textwrap()
    _memoized = True
    return True


def memoized_textwrap() -> types.ModuleType:
    """The textwrap module with fill and dedent memoised (pure functions of their arguments): kernel_impl fills every
    source line of a function (width 9999: a tab expansion) and dedents the function each time it inlines it."""
    module = types.ModuleType("textwrap", textwrap.__doc__)
    module.__dict__.update({k: v for k, v in vars(textwrap).items() if not k.startswith("__")})
    module.fill = functools.lru_cache(maxsize=None)(textwrap.fill)
    module.dedent = functools.lru_cache(maxsize=None)(textwrap.dedent)
    return module


def position_key(ctx: Any, node: Any) -> tuple:
    """Everything ASTTransformerContext.get_pos_info reads: the file, the function's name, the context's line offset
    and indent, the node's type and span (a multi-line For / While / If / def stops at its body's first line), and
    the source lines the span covers."""
    body = getattr(node, "body", None)
    return (ctx.file, ctx.func.func.__name__, ctx.lineno_offset, ctx.indent, type(node).__name__, node.lineno,
            node.end_lineno, node.col_offset, node.end_col_offset,
            body[0].lineno if isinstance(body, list) and body else None,
            tuple(ctx.src[node.lineno - 1:node.end_lineno]))


def memoized_position_info(original: Callable[[Any, Any], str]) -> Callable[[Any, Any], str]:
    """get_pos_info computed once per position_key; a node or context it cannot key goes to Taichi's own."""
    cache: dict[tuple, str] = {}

    def get_pos_info(self, node):
        try:
            key = position_key(self, node)
        except (AttributeError, TypeError):
            return original(self, node)
        info = cache.get(key)
        if info is None:
            info = cache[key] = original(self, node)
        return info

    get_pos_info.taichi_original = original
    get_pos_info.cache = cache
    return get_pos_info


def memoized_by_code(original: Callable[[Any], Any], copy: Callable[[Any], Any] = lambda r: r) -> Callable[[Any], Any]:
    """`original(obj)` once per code object of the function obj unwraps to (the source a function's code was
    compiled from does not change while the process runs; closures made by one `def` share their code). Objects
    without code go to `original`; `copy` hands out a fresh copy of a mutable result."""
    cache: dict[Any, Any] = {}

    def memoized(obj):
        code = getattr(inspect.unwrap(obj), "__code__", None) if callable(obj) else None
        if code is None:
            return original(obj)
        if code not in cache:
            cache[code] = original(obj)
        return copy(cache[code])

    memoized.taichi_original = original
    memoized.cache = cache
    return memoized
