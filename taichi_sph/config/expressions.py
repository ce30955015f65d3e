"""The expression language of config values (velocities, pressures): numpy expressions of x, y, z, evaluated
safely (whitelisted AST nodes and names), and the scene fields with no closed form that expressions may call."""

from __future__ import annotations

import ast
import math

import numpy as np

from taichi_sph.errors import ConfigError


def square_poisson(x, y, side: float, n_terms: int = 40) -> np.ndarray:
    """phi(x, y) with lap phi = 1 inside the square |x|, |y| < a = side / 2 and phi = 0 on its edges.

    Colagrossi (2005) writes the rotating square patch's initial pressure as a double sine series,
        p = rho sum_{m,n odd} -32 omega^2 / (m n pi^2 [(m pi / L)^2 + (n pi / L)^2]) sin(m pi x'/L) sin(n pi y'/L)
    (x' = x + L/2), i.e. p = 2 rho omega^2 phi: the solution of lap p = -rho du_i/dx_j du_j/dx_i = 2 rho omega^2
    for the rigid rotation u = omega (y, -x), with p = 0 on the free surface. Summed here in its single-series
    form (the x-part of the double series done in closed form; Timoshenko & Goodier's torsion of a square bar),
        phi = (x^2 - a^2) / 2 + sum_{n odd} b_n cos(k_n x) cosh(k_n y) / cosh(k_n a),
        k_n = n pi / (2 a),  b_n = 16 a^2 (-1)^((n - 1) / 2) / (n pi)^3,
    which converges like cosh(k_n y) / cosh(k_n a) (40 terms: 1e-12 of phi(0, 0) = -0.07367 L^2 inside; the
    edge x = +-a is exact term by term). Points outside the square get the value at the nearest edge
    point (0). Mean over the square: -0.03514 L^2 (the torsion constant 0.1406 L^4 / 4)."""
    a = 0.5 * side
    x = np.clip(np.asarray(x, dtype=np.float64), -a, a)
    y = np.clip(np.asarray(y, dtype=np.float64), -a, a)
    phi = 0.5 * (x * x - a * a)
    for j in range(n_terms):
        n = 2 * j + 1
        k = n * math.pi / (2.0 * a)
        b = 16.0 * a * a * (-1.0) ** j / (n * math.pi) ** 3
        # cosh(k y) / cosh(k a) = exp(k (|y| - a)) (1 + exp(-2 k |y|)) / (1 + exp(-2 k a)), no overflow
        ay = np.abs(y)
        phi = phi + b * np.cos(k * x) * np.exp(k * (ay - a)) * (1.0 + np.exp(-2.0 * k * ay)) / (1.0 + math.exp(-2.0 * k * a))
    return phi



_SAFE_FUNCS = {name: getattr(np, name) for name in (
    "sin", "cos", "tan", "exp", "log", "sqrt", "abs", "tanh", "sinh", "cosh", "arctan", "arctan2", "minimum",
    "maximum", "where", "sign", "floor")}
# scene-specific fields with no closed form: square_poisson(x, y, L) is phi with lap phi = 1 in the square
# |x|, |y| < L/2, phi = 0 on its edges (the rotating square patch's initial pressure 2 rho omega^2 phi)
_SAFE_FUNCS["square_poisson"] = square_poisson
_SAFE_CONSTS = {"pi": math.pi, "e": math.e}
_SAFE_NODES = (ast.Expression, ast.BinOp, ast.UnaryOp, ast.Call, ast.Name, ast.Load, ast.Constant, ast.Add, ast.Sub,
               ast.Mult, ast.Div, ast.Pow, ast.Mod, ast.USub, ast.UAdd, ast.Compare, ast.Lt, ast.Gt, ast.LtE, ast.GtE)


def evaluate_expression(expr: str, coords: dict[str, np.ndarray], key: str = "expression",
                        rng: np.random.Generator | None = None) -> np.ndarray:
    """Evaluate a numpy-style expression of x, y, z safely (whitelisted names, no attributes)."""
    try:
        tree = ast.parse(expr, mode="eval")
    except SyntaxError:
        raise ConfigError(f"cannot parse expression '{expr}'", key=key) from None
    names = dict(_SAFE_FUNCS)
    names.update(_SAFE_CONSTS)
    names.update({k: np.array(v, dtype=np.float64, copy=True) for k, v in coords.items()})  # no writes back
    if rng is not None:
        n = len(next(iter(coords.values())))
        names["random"] = lambda: rng.uniform(-1.0, 1.0, size=n)
    for node in ast.walk(tree):
        if not isinstance(node, _SAFE_NODES):
            raise ConfigError(f"expression '{expr}' uses '{type(node).__name__}', which is not allowed; use +-*/**, "
                              f"numbers, x/y/z and {', '.join(sorted(_SAFE_FUNCS))}", key=key)
        if isinstance(node, ast.Name) and node.id not in names:
            raise ConfigError(f"expression '{expr}' uses unknown name '{node.id}'; allowed: "
                              f"{', '.join(sorted(set(names) - {'random'}))}, random()", key=key)
        if isinstance(node, ast.Call) and not isinstance(node.func, ast.Name):
            raise ConfigError(f"expression '{expr}' may only call plain function names", key=key)
        if isinstance(node, ast.Call) and (node.keywords or len(node.args) > 3):
            raise ConfigError(f"expression '{expr}': functions take at most 3 positional arguments", key=key)
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Pow):
            exponent = node.right.operand if isinstance(node.right, ast.UnaryOp) else node.right
            if not (isinstance(exponent, ast.Constant) and isinstance(exponent.value, (int, float))
                    and abs(exponent.value) <= 16):
                raise ConfigError(f"expression '{expr}': exponents must be numbers up to 16", key=key)
    value = eval(compile(tree, "<expression>", "eval"), {"__builtins__": {}}, names)  # noqa: S307 (whitelisted AST)
    n = len(next(iter(coords.values())))
    return np.broadcast_to(np.asarray(value, dtype=np.float64), (n,)).copy()
