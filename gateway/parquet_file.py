"""A table of float64 columns written as one Parquet file, with JSON metadata: the Parquet form
of the measurement file that ``leadthrough export`` writes and ``leadthrough analyze`` reads
(:mod:`control.identification.datafile`, which holds the layout: ``t, q1.., dq1.., tau1..``).
pyarrow is imported only when a file is written.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np


def write_parquet(
    path: str | Path,
    names: Sequence[str],
    data: np.ndarray,
    metadata: Mapping[str, Any] | None = None,
) -> None:
    """Write columns ``names`` of ``data`` (rows, len(names)) as float64 to a Parquet file,
    in that order; ``metadata`` goes into the file-level metadata, each value as JSON (the
    sidecar's keys: :func:`read_measurements` takes ``drive_gains_nm_per_a`` from there)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    values = np.asarray(data, dtype=np.float64)
    if values.ndim != 2 or values.shape[1] != len(names):
        raise ValueError(f"data of shape {values.shape} for {len(names)} columns {list(names)}")
    table = pa.Table.from_arrays([pa.array(column) for column in values.T], names=list(names))
    meta = {str(k).encode(): json.dumps(v).encode() for k, v in (metadata or {}).items()}
    pq.write_table(table.replace_schema_metadata(meta), Path(path))
