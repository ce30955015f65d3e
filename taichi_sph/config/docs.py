"""The config reference (`taichi-sph config-doc`, docs/config_reference.md): one row per key from the schema."""

from __future__ import annotations

import dataclasses
import typing

from taichi_sph.config.loader import is_dataclass_type, list_item_type, section_type, to_dict
from taichi_sph.config.schema import Config


def table_cell(text) -> str:
    """Text for a Markdown table cell (this reference's, and the study reports'): a '|' in it (|v|, ||b - A p||)
    would end the cell, so it is escaped, and a line break would end the row, so it becomes a space."""
    return str(text).replace("|", "\\|").replace("\n", " ")


def config_reference() -> str:
    """Markdown table of every key: default, unit, meaning and allowed values."""
    rows = ["| key | default | unit | meaning |", "|---|---|---|---|"]

    def walk(cls: type, prefix: str) -> None:
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            key = f"{prefix}{f.name}"
            tp = hints[f.name]
            section, item = section_type(tp), list_item_type(tp)
            if is_dataclass_type(tp):
                walk(tp, key + ".")
                continue
            if item is not None:
                walk(item, key + "[].")
                continue
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
            if section is not None and default is None:  # an optional section
                doc = f.metadata.get("doc", "")
                rows.append(f"| `{key}` |  |  | {table_cell(doc)}; null = none; its keys: |")
                walk(section, key + ".")
                continue
            doc = f.metadata.get("doc", "")
            if f.metadata.get("choices"):
                doc += " (one of: " + ", ".join(f"`{c}`" for c in f.metadata["choices"]) + ")"
            dflt = "" if default is None else f"`{to_dict(default)}`"
            rows.append(f"| `{key}` | {dflt} | {f.metadata.get('unit', '')} | {table_cell(doc)} |")

    walk(Config, "")
    return "\n".join(rows)

