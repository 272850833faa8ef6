"""Reading an .rrd file back as plain Python: per entity, its columns merged over chunks.

For tests and quick inspection; the rerun viewer is the real reader.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pyarrow as pa
from rerun.chunk import RrdReader

CONTROL_COLUMNS = ("rerun.controls.RowId",)


def _column(array: pa.Array) -> list:
    """Python values of one column; durations (e.g. sim_time) as float seconds, timestamps as int ns."""
    if pa.types.is_duration(array.type):
        unit = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}[array.type.unit]
        return [None if v is None else v * unit for v in array.cast(pa.int64()).to_pylist()]
    if pa.types.is_timestamp(array.type):
        return array.cast(pa.int64()).to_pylist()
    return array.to_pylist()


@dataclasses.dataclass
class EntityData:
    """What one entity holds: static components {column: value} and timed rows {column: values}.

    Timed rows are sorted by the `step` timeline when every row has one.
    """

    static: dict[str, object] = dataclasses.field(default_factory=dict)
    rows: dict[str, list] = dataclasses.field(default_factory=dict)

    @property
    def n_rows(self) -> int:
        return len(next(iter(self.rows.values()))) if self.rows else 0


def read_entities(path: str | Path) -> dict[str, EntityData]:
    """{entity path: EntityData} over all chunks of the first recording in an .rrd file.

    `sim_time` comes back in seconds. Recording properties are under '/__properties/...'.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"rerun file {path}: not found")
    out: dict[str, EntityData] = {}
    for chunk in RrdReader(path).stream().to_chunks():
        batch = chunk.to_record_batch()
        table = {name: _column(batch.column(name)) for name in batch.schema.names if name not in CONTROL_COLUMNS}
        ent = out.setdefault(chunk.entity_path, EntityData())
        if chunk.is_static:
            ent.static.update({name: values[-1] for name, values in table.items()})
            continue
        have, n = ent.n_rows, chunk.num_rows
        for name in set(ent.rows) | set(table):
            ent.rows.setdefault(name, [None] * have).extend(table.get(name, [None] * n))
    for ent in out.values():
        steps = ent.rows.get("step")
        if steps and all(v is not None for v in steps):
            order = sorted(range(len(steps)), key=steps.__getitem__)
            ent.rows = {name: [col[i] for i in order] for name, col in ent.rows.items()}
    return out
