"""A solver's checkpoint state, found generically (run/checkpoint.py writes it, run/simulation.py restores it)."""

import numpy as np
import taichi as ti


def _is_plain(value) -> bool:
    """Numbers, strings, None and (nested) lists, tuples and dicts of them: safe to pickle and restore."""
    if value is None or isinstance(value, (bool, int, float, str, np.generic)):
        return True
    if isinstance(value, (list, tuple)):
        return all(_is_plain(v) for v in value)
    if isinstance(value, dict):
        return all(_is_plain(k) and _is_plain(v) for k, v in value.items())
    return False


def _is_project_object(value) -> bool:
    """An instance of one of this project's classes that holds state (not a frozen config dataclass)."""
    import dataclasses
    module = type(value).__module__ or ""
    return (module.startswith("taichi_sph") and hasattr(value, "__dict__") and not isinstance(value, type)
            and not dataclasses.is_dataclass(value))


class CheckpointState:
    """`state_items` / `restore_state` for SolverBase: every field, array and plain value it holds."""

    def state_items(self) -> tuple[dict[str, ti.Field], dict[str, np.ndarray], dict[str, dict]]:
        """Everything a bit-identical restart needs, found generically: every Taichi field, numpy array
        and plain Python value (numbers, strings, lists, dicts) held by the solver or by a project object
        it holds (particles, neighbour search, PPE, shifting, loop schedule), current particle order and
        neighbour lists included. Returns (fields, arrays, plain values per owner), keyed `owner.attr`."""
        fields: dict[str, ti.Field] = {}
        arrays: dict[str, np.ndarray] = {}
        plain: dict[str, dict] = {}
        seen: set[int] = set()

        def walk(obj, prefix: str) -> None:
            seen.add(id(obj))
            values = {}
            transient = getattr(obj, "transient_state", ())  # rewritten before each use: not state
            for name, value in vars(obj).items():
                if name in transient:
                    continue
                key = f"{prefix}.{name}"
                if isinstance(value, ti.Field):
                    fields[key] = value
                elif isinstance(value, np.ndarray):
                    arrays[key] = value
                elif _is_plain(value):
                    values[name] = value
                elif _is_project_object(value) and id(value) not in seen:
                    walk(value, key)
            plain[prefix] = values

        walk(self, "solver")
        return fields, arrays, plain

    def missing_state(self, fields: dict[str, np.ndarray]) -> str:
        """What a checkpoint's arrays lack of this solver's state ('' when nothing)."""
        own_fields, own_arrays, _ = self.state_items()
        missing = (set(own_fields) | set(own_arrays)) - set(fields)
        return f"checkpoint lacks {sorted(missing)[:3]}: written by another solver or version" if missing else ""

    def restore_state(self, fields: dict[str, np.ndarray], plain: dict[str, dict]) -> None:
        """Put back what `state_items` saved (fields and numpy arrays by key, plain values by owner)."""
        own_fields, own_arrays, own_plain = self.state_items()
        missing = self.missing_state(fields)
        if missing:
            raise ValueError(missing)
        for key, f in own_fields.items():
            f.from_numpy(fields[key])
        for key, a in own_arrays.items():
            a[...] = fields[key]
        owners = {"solver": self}
        for prefix in sorted(own_plain, key=len):
            if prefix != "solver":
                parent, name = prefix.rsplit(".", 1)
                owners[prefix] = getattr(owners[parent], name)
            for name, value in plain.get(prefix, {}).items():
                setattr(owners[prefix], name, value)
