"""Trajectory downloads that stream from the stored Parquet file in bounded chunks.

An episode's ``trajectory.parquet`` holds one row per step and agent, agent-major (every step of
the first agent, then of the next; :meth:`~hptvsim.episodes.frames.Trajectories.columns`). The API
serves it as CSV, as the frame schema's ``Trajectories`` JSON document, as JSON lines, or as the
file itself, and never holds more than a few batches of rows: every format is written piece by
piece while the file is read a batch at a time, so the API's memory does not grow with the
episode (a 16-agent, 1024-beam, 20000-step episode is over 1 GB of JSON). Since every format
streams, none has a size limit; what is bounded instead is how many stream at once
(``HPTVSIM_MAX_DOWNLOADS``, :class:`DownloadSlots`: more are answered 503 with ``Retry-After``), so
that the API's memory is bounded whatever the episodes and the clients.

* **CSV** (:func:`csv_chunks`): a header naming each column with its SI unit (``x [m]``), then
  one row per step and agent; each row's sonar ranges are one space-separated field of
  centimetre-rounded values (``12.34 50.00``).
* **JSON** (:func:`json_chunks`): the ``Trajectories`` document, ``{"step": [...], "time":
  [...], "agents": [{"name", "x": [...], ..., "ranges": [[...], ...]}]}``. It is column-major
  per agent, so it is written agent by agent and column by column, each a pass over that
  agent's rows of that one column (Parquet reads one column without the others).
* **JSON lines** (:func:`jsonl_chunks`): one JSON object per step and agent (a CSV row as a
  record: the file's columns by name, ``ranges`` last as an array), for clients that want
  records.

The writer (:func:`~hptvsim.service.engine.write_outputs`) keeps each Parquet row group near
:data:`ROW_GROUP_BYTES` (:func:`row_group_rows`), so that a read of any row range touches only the
row groups it needs; files written before that are still read in bounded memory, only slower.
"""

from __future__ import annotations

import contextlib
import functools
import io
import json
import threading
import weakref
from collections.abc import Generator, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from starlette.responses import StreamingResponse
from starlette.types import Receive, Scope, Send

from hptvsim.cosim import trajectory  # the one trajectory schema

if TYPE_CHECKING:
    import pyarrow as pa
    import pyarrow.parquet as pq

__all__ = [
    "MEDIA_TYPES",
    "BusyError",
    "DownloadSlots",
    "ParquetRows",
    "StreamedDownload",
    "TableRows",
    "TrajectoryRows",
    "csv_chunks",
    "json_chunks",
    "jsonl_chunks",
    "row_group_rows",
]

ROW_GROUP_BYTES = 8 << 20
"""Uncompressed bytes [B] the trajectory writer puts in one Parquet row group (about 2000 rows of
a 1024-beam sonar)."""

BATCH_BYTES = 256 << 10
"""Decoded bytes [B] of the selected columns in one batch of rows read for a download."""

MAX_BATCH_ROWS = 16384
"""Most rows in one batch (columns of a few bytes would otherwise make batches of millions)."""

READ_BUFFER_BYTES = 1 << 20
"""Bytes [B] the Parquet reader buffers from a column chunk (0 would read whole chunks)."""

CHUNK_BYTES = 256 << 10
"""Bytes [B] of text gathered before a chunk goes to the client."""


RETRY_AFTER_S = 5
"""``Retry-After`` [s] of an answer when every download slot is taken."""

MEDIA_TYPES = {
    "json": "application/json",
    "jsonl": "application/x-ndjson",
    "csv": "text/csv",
    "parquet": "application/vnd.apache.parquet",
}
"""The media type of each download format."""

_WIDTH = {"BOOLEAN": 1, "INT32": 4, "FLOAT": 4, "INT64": 8, "DOUBLE": 8, "INT96": 12}
"""Bytes [B] of one decoded value of each Parquet physical type (16 for strings and the rest)."""

_RANGES = trajectory.RANGES.name
"""The sonar ranges' column (a list per row, written last in every format)."""

_JSON = json.JSONEncoder(ensure_ascii=False, allow_nan=False, separators=(",", ":"))
"""Encodes as the API's JSON responses do (Starlette's ``JSONResponse``)."""


def row_group_rows(table: pa.Table) -> int:
    """Rows per Parquet row group that keep a row group of ``table`` near :data:`ROW_GROUP_BYTES`.

    Args:
        table: The trajectory table about to be written.
    """
    per_row = table.nbytes / max(table.num_rows, 1)  # B per row
    return int(min(max(ROW_GROUP_BYTES // max(per_row, 1.0), 64), 1 << 20))


class TrajectoryRows(Protocol):
    """A trajectory table read in batches of rows (a Parquet file, or a table in memory)."""

    @property
    def column_names(self) -> list[str]:
        """The columns, in stored order."""
        ...

    @property
    def num_rows(self) -> int:
        """Rows (steps times agents)."""
        ...

    def batches(
        self, columns: Sequence[str], start: int = 0, stop: int | None = None
    ) -> Iterator[pa.RecordBatch]:
        """Rows ``start`` to ``stop`` (exclusive; None: the last) of ``columns``, in bounded batches."""
        ...

    def close(self) -> None:
        """Release the file (nothing for a table)."""
        ...


class ParquetRows:
    """A stored trajectory file, read a bounded batch of rows at a time.

    Only the row groups that hold the rows asked for are read, each through a buffer of
    :data:`READ_BUFFER_BYTES` (page by page, not a whole column chunk at once); batches hold
    about :data:`BATCH_BYTES` of the columns asked for.

    Args:
        path: The episode's ``trajectory.parquet``.
    """

    def __init__(self, path: str | Path) -> None:
        import pyarrow.parquet as pq

        self._file: pq.ParquetFile = pq.ParquetFile(path, buffer_size=READ_BUFFER_BYTES, pre_buffer=False)
        meta = self._file.metadata
        self._starts = [0]  # first row of each row group, then the row count
        for i in range(meta.num_row_groups):
            self._starts.append(self._starts[-1] + meta.row_group(i).num_rows)
        # decoded bytes per row of each top-level column, the largest over row groups: at least
        # its values times their width (a run of equal ranges takes a few bytes encoded)
        per_row: dict[str, float] = {}
        for i in range(meta.num_row_groups):
            group = meta.row_group(i)
            sizes: dict[str, int] = {}
            for j in range(group.num_columns):
                chunk = group.column(j)
                top = chunk.path_in_schema.split(".")[0]
                decoded = max(
                    chunk.total_uncompressed_size, chunk.num_values * _WIDTH.get(chunk.physical_type, 16)
                )
                sizes[top] = sizes.get(top, 0) + decoded
            for name, size in sizes.items():
                per_row[name] = max(per_row.get(name, 0.0), size / max(group.num_rows, 1))
        self._per_row = per_row

    @property
    def column_names(self) -> list[str]:
        """The columns, in stored order."""
        return list(self._file.schema_arrow.names)

    @property
    def num_rows(self) -> int:
        """Rows (steps times agents)."""
        return self._starts[-1]

    def batch_rows(self, columns: Sequence[str]) -> int:
        """Rows per batch of ``columns``: about :data:`BATCH_BYTES`, at most :data:`MAX_BATCH_ROWS`."""
        per_row = sum(self._per_row.get(c, 8.0) for c in columns)  # B per row
        return int(min(max(BATCH_BYTES // max(per_row, 1.0), 1), MAX_BATCH_ROWS))

    def batches(
        self, columns: Sequence[str], start: int = 0, stop: int | None = None
    ) -> Iterator[pa.RecordBatch]:
        """Rows ``start`` to ``stop`` (exclusive; None: the last) of ``columns``, in bounded batches."""
        stop = self.num_rows if stop is None else min(stop, self.num_rows)
        if start >= stop:
            return
        groups = [
            i for i in range(len(self._starts) - 1) if self._starts[i] < stop and self._starts[i + 1] > start
        ]
        row = self._starts[groups[0]]  # the first row of the next batch
        for batch in self._file.iter_batches(
            batch_size=self.batch_rows(columns), row_groups=groups, columns=list(columns), use_threads=False
        ):
            lo, hi = max(start - row, 0), min(stop - row, batch.num_rows)
            row += batch.num_rows
            if hi <= lo:
                continue
            yield batch.slice(lo, hi - lo) if (lo, hi) != (0, batch.num_rows) else batch
            if row >= stop:
                return

    def close(self) -> None:
        """Close the file."""
        self._file.close()


class TableRows:
    """A trajectory table already in memory, read as :class:`ParquetRows` reads a file.

    Args:
        table: The table (as ``pyarrow.parquet.read_table`` gives it).
        batch_rows: Rows per batch.
    """

    def __init__(self, table: pa.Table, batch_rows: int = 4096) -> None:
        self._table = table
        self._batch_rows = batch_rows

    @property
    def column_names(self) -> list[str]:
        """The columns, in stored order."""
        return list(self._table.column_names)

    @property
    def num_rows(self) -> int:
        """Rows (steps times agents)."""
        return int(self._table.num_rows)

    def batches(
        self, columns: Sequence[str], start: int = 0, stop: int | None = None
    ) -> Iterator[pa.RecordBatch]:
        """Rows ``start`` to ``stop`` (exclusive; None: the last) of ``columns``, in bounded batches."""
        stop = self.num_rows if stop is None else min(stop, self.num_rows)
        if start >= stop:
            return
        part = self._table.select(list(columns)).slice(start, stop - start)
        yield from part.to_batches(max_chunksize=self._batch_rows)

    def close(self) -> None:
        """Nothing to release."""


# --- a bounded number of streams ------------------------------------------------------------------


class BusyError(Exception):
    """Every download slot of the service is taken (:class:`DownloadSlots`)."""


class DownloadSlots:
    """The trajectory downloads (json, jsonl, csv) one API process streams at once, at most ``n``.

    Each stream holds a few MB while it runs (measured: 3 MB of Python objects, 6 MB of Arrow
    buffers; the allocators keep about 30 MB more per concurrent stream), so ``n`` bounds the
    API's memory for downloads, whatever the episodes and the clients; Parquet files and
    recordings are sent from disk and not counted.

    Args:
        n: The most streams at once (``HPTVSIM_MAX_DOWNLOADS``).
    """

    def __init__(self, n: int) -> None:
        self.n = n
        self._free = threading.BoundedSemaphore(n)

    def take(self) -> _Slot:
        """A slot, given back by :meth:`_Slot.release`.

        Raises:
            BusyError: All ``n`` are taken.
        """
        if not self._free.acquire(blocking=False):
            raise BusyError(
                f"{self.n} trajectory downloads are streaming (HPTVSIM_MAX_DOWNLOADS); retry in "
                f"{RETRY_AFTER_S} s, or take format=parquet (sent from disk, no such limit)"
            )
        return _Slot(self._free)


class _Slot:
    """One slot of a :class:`DownloadSlots`, given back once."""

    def __init__(self, free: threading.BoundedSemaphore) -> None:
        self._free = free
        self._lock = threading.Lock()
        self._held = True

    def release(self) -> None:
        """Give the slot back (again: nothing)."""
        with self._lock:
            if self._held:
                self._held = False
                self._free.release()


class StreamedDownload(StreamingResponse):
    """A streamed trajectory download, holding one of the service's download slots while it runs.

    The slot is taken when the answer is made (so that a busy service answers 503 before the
    download starts) and given back when the answer ends: sent, failed, or left by its client;
    the chunks are then closed, which closes their file. An answer never sent gives its slot back
    when it is dropped.

    Args:
        chunks: What to send (a generator of :func:`csv_chunks`, :func:`json_chunks` or
            :func:`jsonl_chunks`).
        media_type: Its media type.
        slots: The service's download slots.
        headers: More headers.

    Raises:
        BusyError: No slot is free.
    """

    def __init__(
        self,
        chunks: Iterator[bytes],
        media_type: str,
        slots: DownloadSlots,
        headers: dict[str, str] | None = None,
    ) -> None:
        self._slot = slots.take()
        self._chunks = chunks
        weakref.finalize(self, self._slot.release)
        super().__init__(chunks, media_type=media_type, headers=headers)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Send the answer; give the slot back and close the chunks however it ends."""
        try:
            await super().__call__(scope, receive, send)
        finally:
            self._slot.release()
            if isinstance(self._chunks, Generator):
                # no chunk is being made here: a thread's call to next() is never abandoned
                with contextlib.suppress(ValueError):
                    self._chunks.close()


# --- formatting of the sonar ranges ----------------------------------------------------------------


@functools.cache
def _centimetres(json_numbers: bool) -> pa.StringArray:
    """The digits after the point of 0 to 99 cm: ``05``, ``10`` (CSV) or ``05``, ``1`` (JSON)."""
    import pyarrow as pa

    digits = [f"{i:02d}" for i in range(100)]
    return pa.array([d.rstrip("0") or "0" for d in digits] if json_numbers else digits, pa.string())


def _ranges_text(ranges: pa.Array, *, sep: str, json_numbers: bool) -> list[str]:
    """Each row's sonar ranges [m] rounded to centimetres, joined with ``sep``.

    CSV writes each value as ``f"{v:.2f}"``; JSON as ``repr(round(v, 2))`` (the trailing zero of
    the centimetres dropped, ``12.3``, ``50.0``), as encoding Python floats would. Ranges stored as
    float32 (as the writer stores them) are formatted in Arrow's and numpy's kernels: a float32
    times 100 is exact in a float64, so rounding it half to even is the correctly rounded value.
    Anything else goes through Python's formatting, value by value.

    Args:
        ranges: A list array (one list of ranges per row).
        sep: Between values of a row.
        json_numbers: JSON's spelling (else CSV's).

    Raises:
        ValueError: JSON of a non-finite range (JSON has no spelling for it).
    """
    import numpy as np
    import pyarrow as pa
    import pyarrow.compute as pc

    offsets = np.asarray(ranges.offsets, dtype=np.int64)
    values = ranges.values.slice(int(offsets[0]), int(offsets[-1] - offsets[0]))
    offsets = offsets - offsets[0]
    v = values.to_numpy(zero_copy_only=False).astype(np.float64)
    finite = np.isfinite(v)
    if json_numbers and not finite.all():
        raise ValueError("a sonar range is not finite; JSON cannot hold it (the CSV and Parquet formats can)")
    fast = pa.types.is_float32(values.type) and not (np.abs(v[finite]) >= 1e15).any()
    if not fast:
        text = [repr(round(x, 2)) if json_numbers else f"{x:.2f}" for x in v.tolist()]
        return [sep.join(text[offsets[i] : offsets[i + 1]]) for i in range(len(offsets) - 1)]
    cents = np.abs(np.rint(np.where(finite, v, 0.0) * 100.0)).astype(np.int64)
    whole, frac = np.divmod(cents, 100)
    whole_text = pc.cast(pa.array(whole), pa.string())
    negative = np.signbit(v) & finite
    if negative.any():
        whole_text = pc.binary_join_element_wise(pc.if_else(pa.array(negative), "-", ""), whole_text, "")
    frac_text = _centimetres(json_numbers).take(pa.array(frac))
    text = pc.binary_join_element_wise(whole_text, frac_text, ".")
    if not finite.all():  # CSV: as Python writes them
        special = pa.array(np.where(np.isnan(v), "nan", np.where(v > 0, "inf", "-inf")), pa.string())
        text = pc.if_else(pa.array(finite), text, special)
    rows = pa.ListArray.from_arrays(pa.array(offsets, pa.int32()), text)
    joined: list[str] = pc.binary_join(rows, sep).to_pylist()
    return joined


# --- the formats -----------------------------------------------------------------------------------


class _Chunker:
    """Gathers text into chunks of about :data:`CHUNK_BYTES`."""

    def __init__(self) -> None:
        self._parts: list[str] = []
        self._size = 0

    def add(self, text: str) -> bytes | None:
        """Add ``text``; a chunk once enough has gathered."""
        self._parts.append(text)
        self._size += len(text)
        return self.flush() if self._size >= CHUNK_BYTES else None

    def flush(self) -> bytes | None:
        """What has gathered, or None."""
        if not self._parts:
            return None
        out = "".join(self._parts).encode("utf-8")
        self._parts, self._size = [], 0
        return out


def csv_chunks(rows: TrajectoryRows) -> Iterator[bytes]:
    """The trajectory as CSV, in chunks.

    The header names each column with its SI unit, ``x [m]`` (the Parquet file's fields carry the
    same units as metadata, from :data:`hptvsim.cosim.trajectory.UNITS`); each row's
    sonar ranges become one space-separated field. Values are written by Arrow's CSV writer,
    one batch of rows at a time.

    Args:
        rows: The trajectory (closed at the end).
    """
    import pyarrow as pa
    import pyarrow.csv as pacsv

    try:
        names = rows.column_names
        header = [trajectory.header(c, trajectory.UNITS.get(c)) for c in names]
        buf = io.BytesIO()
        writer: pacsv.CSVWriter | None = None
        for batch in rows.batches(names):
            arrays = list(batch.columns)
            if _RANGES in names:
                i = names.index(_RANGES)
                arrays[i] = pa.array(_ranges_text(arrays[i], sep=" ", json_numbers=False), pa.string())
            out = pa.RecordBatch.from_arrays(arrays, names=header)
            if writer is None:
                writer = pacsv.CSVWriter(buf, out.schema)
            writer.write_batch(out)
            if buf.tell() >= CHUNK_BYTES:
                yield buf.getvalue()
                buf.seek(0)
                buf.truncate()
        if writer is None:  # no rows: the header alone
            writer = pacsv.CSVWriter(buf, pa.schema([pa.field(h, pa.string()) for h in header]))
        writer.close()
        if buf.tell():
            yield buf.getvalue()
    finally:
        rows.close()


def _agents(rows: TrajectoryRows) -> list[str]:
    """The agents in the order of their first row."""
    import pyarrow.compute as pc

    seen: dict[str, None] = {}
    for batch in rows.batches([trajectory.AGENT.name]):
        for name in pc.unique(batch.column(0)).to_pylist():
            seen.setdefault(str(name), None)
    return list(seen)


def _column_text(rows: TrajectoryRows, column: str, start: int, stop: int) -> Iterator[str]:
    """One column's values of rows ``start`` to ``stop`` as the inside of a JSON array."""
    first = True
    for batch in rows.batches([column], start, stop):
        if column == _RANGES:
            body = ",".join(f"[{r}]" for r in _ranges_text(batch.column(0), sep=",", json_numbers=True))
        else:
            body = _JSON.encode(batch.column(0).to_pylist())[1:-1]
        if body:
            yield body if first else "," + body
            first = False


def json_chunks(rows: TrajectoryRows) -> Iterator[bytes]:
    """The trajectory as the frame schema's ``Trajectories`` JSON document, in chunks.

    The same text that encoding :func:`~hptvsim.service.api.trajectory_json`'s dict would give:
    per agent, one array per column (None for a column an older episode did not store, the
    reward terms or the sonar ranges), sonar ranges rounded to centimetres. The rows are
    agent-major with the same number of steps per agent.

    Args:
        rows: The trajectory (closed at the end).

    Raises:
        ValueError: A non-finite value (JSON cannot hold it; the stream ends there).
    """
    out = _Chunker()
    try:
        names = set(rows.column_names)
        agents = _agents(rows) if rows.num_rows else []
        n_steps = rows.num_rows // max(len(agents), 1)
        pieces: list[Iterator[str] | str] = []
        for k, col in enumerate(trajectory.PER_AGENT_INDEX):  # the per-agent layout: step, time once
            pieces += [
                ("{" if k == 0 else "],") + f'"{col.name}":[',
                _column_text(rows, col.name, 0, n_steps),
            ]
        pieces.append('],"agents":[')
        for chunk in _pieces(pieces, out):
            yield chunk
        for k, name in enumerate(agents):
            start, stop = k * n_steps, (k + 1) * n_steps
            agent: list[Iterator[str] | str] = [("," if k else "") + '{"name":' + _JSON.encode(name)]
            for c in (*trajectory.AGENT_COLUMN_NAMES, _RANGES):
                if c in names:
                    agent += [f',"{c}":[', _column_text(rows, c, start, stop), "]"]
                else:
                    agent.append(f',"{c}":null')
            agent.append("}")
            for chunk in _pieces(agent, out):
                yield chunk
        last = out.add("]}")
        if last is not None:
            yield last
        rest = out.flush()
        if rest is not None:
            yield rest
    finally:
        rows.close()


def _pieces(pieces: list[Iterator[str] | str], out: _Chunker) -> Iterator[bytes]:
    """The chunks of a sequence of texts and iterators of texts."""
    for p in pieces:
        for text in [p] if isinstance(p, str) else p:
            chunk = out.add(text)
            if chunk is not None:
                yield chunk


def jsonl_chunks(rows: TrajectoryRows) -> Iterator[bytes]:
    """The trajectory as JSON lines, in chunks: one object per step and agent.

    Each line is ``{"step": 0, "time": 0.0, "agent": "pursuer_0", "x": ..., "ranges": [...]}``:
    the file's columns by name (a column an older episode did not store is absent), ``ranges``
    last, rounded to centimetres as in the JSON format.

    Args:
        rows: The trajectory (closed at the end).

    Raises:
        ValueError: A non-finite value (JSON cannot hold it; the stream ends there).
    """
    out = _Chunker()
    try:
        names = rows.column_names
        scalars = [c for c in names if c != _RANGES]
        for batch in rows.batches(names):
            cols = {c: batch.column(names.index(c)).to_pylist() for c in scalars}
            ranges = (
                _ranges_text(batch.column(names.index(_RANGES)), sep=",", json_numbers=True)
                if _RANGES in names
                else None
            )
            lines = []
            for i in range(batch.num_rows):
                record = _JSON.encode({c: cols[c][i] for c in scalars})
                if ranges is not None:
                    record = record[:-1] + ("," if scalars else "") + f'"{_RANGES}":[{ranges[i]}]}}'
                lines.append(record + "\n")
            chunk = out.add("".join(lines))
            if chunk is not None:
                yield chunk
        rest = out.flush()
        if rest is not None:
            yield rest
    finally:
        rows.close()
