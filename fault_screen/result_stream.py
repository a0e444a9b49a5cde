"""Results streamed to their HDF5 file as a run goes, so memory stays bounded however long it is.

The file has the layout :meth:`fault_screen.result.Result.save` writes (and
:meth:`~fault_screen.result.Result.load` reads it), with every growing array a resizable,
chunked dataset. Arrays grow in *streams*: a stream is a set of datasets that grow together by
one record at a time (``rows``: ``/time`` and the per-step series; ``profiles``: ``/fault/time``
and the (time, x) profiles; callers add theirs: ``/screening/`` metrics, level changes, the
log's samples). Records are buffered and written in small batches; :meth:`ResultWriter.flush`
writes what is buffered and flushes the file.

The file is opened with ``libver="latest"`` and switched to single-writer/multiple-reader mode
once every dataset exists, so another process may open it while the run writes
(``h5py.File(path, "r", libver="latest", swmr=True)``, then ``dataset.refresh()``; or
``Result.load``). What is only known at the end (``meta``, and groups such as ``/events``) is
written by :meth:`ResultWriter.close`, after leaving that mode.

Restarts: :meth:`ResultWriter.counts` (after a flush) is what a checkpoint stores;
:meth:`ResultWriter.reopen` truncates every stream to those counts and appends from there. A
file left by a killed writer is still marked as open for writing; it is then copied, as a
reader can read it, to a fresh file (once per restart).
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from .outputs import unit

#: records per compressed stream (the profiles) buffered before they are written: one batch
#: fills its chunks once
BATCH = 64
#: an uncompressed stream (the series rows, the screening: a few scalars a record) buffers up to
#: this many records, at most LIGHT_BYTES of their data: a write costs a call per dataset
#: whatever its length (the bundled run's 280 rows: 5 writes of each of 19 datasets -> 1)
LIGHT_BATCH = 1024
LIGHT_BYTES = 256 * 1024
#: gzip level of the compressed streams (with HDF5's byte shuffle before it)
GZIP_LEVEL = 1
#: HDF5's chunk cache of the writer's file, per dataset (HDF5's default is 1 MiB): the writer
#: appends, so a dataset's cache only ever needs the chunk being filled (chunks are ~64 kB, a
#: compressed one at most BATCH records). With the default the written chunks of the 40-odd
#: growing datasets stayed cached, and a long run's memory grew with its steps (the Basel 2006
#: replay: 244 -> 272 MB over 111,708 steps); with this the same file bytes, the same CPU time
CHUNK_CACHE_BYTES = 256 * 1024


def _opened_for_writing(path, mode):
    """The result file ``path`` opened to write (``mode`` "w" or "r+") as the writer opens it:
    HDF5's latest format (SWMR) and the chunk cache of CHUNK_CACHE_BYTES a dataset."""
    import h5py

    return h5py.File(path, mode, libver="latest", rdcc_nbytes=CHUNK_CACHE_BYTES)


#: root attribute listing what close() wrote (removed again when the file is reopened)
_FINAL = "final_groups"


def _dataset_path(path: str) -> tuple[str, str]:
    group, _, name = path.strip("/").rpartition("/")
    return group, name


class ResultWriter:
    """Append-only writer of one result file; see the module docstring.

    ``streams``: stream name -> {dataset path: (dtype, shape of one record)}; ``fixed``:
    dataset path -> array written once (the fault geometry); ``attrs``: root attributes
    (``scene``, a first ``meta``). ``compress``: stream names whose datasets are byte-shuffled
    and gzip-compressed (the profiles). ``batch``: records buffered per stream before a write
    (None: BATCH for a compressed stream, else as many as LIGHT_BATCH and LIGHT_BYTES allow)."""

    def __init__(self, h5, path: Path, streams: dict, counts: dict | None = None,
                 batch: int | None = None, compress=("profiles",)):
        self.h5 = h5
        self.path = Path(path)
        self.streams = {name: dict(spec) for name, spec in streams.items()}
        self.counts_written = {name: 0 for name in self.streams}
        if counts:
            self.counts_written.update(counts)
        self.buffers = {name: [] for name in self.streams}
        self.batches = {name: batch if batch is not None else _batch(spec, name in compress)
                        for name, spec in self.streams.items()}
        # each stream's datasets, looked up once: h5py's lookup by path cost more than writing
        # a batch of scalars (a third of the writes' time on the bundled scene)
        self._datasets = {}

    # ------------------------------------------------------------------ creation
    @classmethod
    def create(cls, path, *, streams: dict, fixed: dict, attrs: dict, compress=("profiles",),
               batch: int | None = None) -> "ResultWriter":
        path = Path(path)
        h5 = _opened_for_writing(path, "w")
        try:
            for k, v in attrs.items():
                h5.attrs[k] = v
            for p, v in fixed.items():
                group, name = _dataset_path(p)
                h5.require_group(group or "/").create_dataset(name, data=v).attrs["unit"] = unit(group, name)
            for sname, spec in streams.items():
                for p, (dtype, shape) in spec.items():
                    _create(h5, p, dtype, shape, gzip=sname in compress)
            h5.swmr_mode = True        # from here on no new object: readers may open the file
        except BaseException:
            h5.close()
            raise
        return cls(h5, path, streams, batch=batch, compress=compress)

    @classmethod
    def reopen(cls, path, counts: dict, *, streams: dict, compress=("profiles",),
               batch: int | None = None) -> "ResultWriter":
        """The file ``path`` truncated to ``counts`` records per stream, open for appending.
        Streams missing from the file (``streams`` declares them) are created."""
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"{path}: the result file this checkpoint streamed to is missing")
        try:
            h5 = _opened_for_writing(path, "r+")
        except OSError as exc:
            if "already open for write" not in str(exc):
                raise
            _copy_from_reader(path)             # left marked open by a killed writer
            h5 = _opened_for_writing(path, "r+")
        try:
            for p in json.loads(h5.attrs.get(_FINAL, "[]")):
                if p in h5:
                    del h5[p]
            if _FINAL in h5.attrs:
                del h5.attrs[_FINAL]
            for sname, spec in streams.items():
                n = int(counts.get(sname, 0))
                for p, (dtype, shape) in spec.items():
                    if p not in h5:
                        _create(h5, p, dtype, shape, gzip=sname in compress)
                    ds = h5[p]
                    if ds.shape[0] < n:
                        raise ValueError(f"{path}: {p} holds {ds.shape[0]} records, the checkpoint "
                                         f"counts {n}: not the file this checkpoint streamed to")
                    ds.resize(n, axis=0)
            h5.swmr_mode = True
        except BaseException:
            h5.close()
            raise
        return cls(h5, path, streams, counts={k: int(counts.get(k, 0)) for k in streams}, batch=batch,
                   compress=compress)

    # ------------------------------------------------------------------ appending
    def append(self, stream: str, record: dict) -> None:
        """One record of ``stream`` (dataset path -> value); written with the next batch."""
        buf = self.buffers[stream]
        if len(buf) >= self.batches[stream]:
            self._write(stream)
        buf.append(record)

    def count(self, stream: str) -> int:
        """Records of ``stream`` so far, buffered ones included."""
        return self.counts_written[stream] + len(self.buffers[stream])

    def _write(self, stream: str) -> None:
        buf = self.buffers[stream]
        if not buf:
            return
        n0, k = self.counts_written[stream], len(buf)
        datasets = self._datasets.get(stream)
        if datasets is None:
            datasets = self._datasets[stream] = [(p, self.h5[p]) for p in self.streams[stream]]
        for p, ds in datasets:
            block = np.asarray([r[p] for r in buf], dtype=ds.dtype)
            ds.resize(n0 + k, axis=0)
            ds[n0:n0 + k] = block
        self.counts_written[stream] = n0 + k
        buf.clear()

    def flush(self) -> None:
        """Write every buffered record and flush the file (readers see it from now on)."""
        for stream in self.streams:
            self._write(stream)
        self.h5.flush()

    def counts(self) -> dict:
        """Records per stream in the file (call after :meth:`flush`): what a checkpoint keeps."""
        return {k: int(v) for k, v in self.counts_written.items()}

    # ------------------------------------------------------------------ the end
    def close(self, *, meta: dict | None = None, groups: dict | None = None) -> Path:
        """Write what is buffered, then ``meta`` (root attribute, JSON) and ``groups`` (group ->
        {name: array}: known only at the end), sync, close."""
        self.flush()
        self.h5.close()
        with _opened_for_writing(self.path, "r+") as h5:
            if meta is not None:
                h5.attrs["meta"] = json.dumps(meta, default=float)
            written = []
            for gname, arrays in (groups or {}).items():
                grp = h5.require_group(gname)
                for k, v in arrays.items():
                    if k in grp:
                        del grp[k]
                    grp.create_dataset(k, data=v).attrs["unit"] = unit(gname, k)
                    written.append(f"/{gname}/{k}")
            h5.attrs[_FINAL] = json.dumps(written)
            h5.flush()
            os.fsync(h5.id.get_vfd_handle())
        return self.path

    def abandon(self) -> None:
        """Close without writing the end (the file stays as the last flush left it)."""
        try:
            self.h5.close()
        except Exception:   # noqa: BLE001 - closing a file in an error path
            pass


def _record_bytes(spec: dict) -> int:
    """Bytes of one record of a stream (``spec``: dataset path -> (dtype, shape of one record))."""
    return sum(np.dtype(dtype).itemsize * int(np.prod(shape, dtype=np.int64))
               for dtype, shape in spec.values())


def _batch(spec: dict, compressed: bool) -> int:
    """Records of a stream buffered before a write (see BATCH, LIGHT_BATCH)."""
    if compressed:
        return BATCH
    return max(BATCH, min(LIGHT_BATCH, LIGHT_BYTES // max(_record_bytes(spec), 1)))


def _create(h5, p: str, dtype, shape, gzip: bool) -> None:
    group, name = _dataset_path(p)
    shape = tuple(shape)
    row_bytes = np.dtype(dtype).itemsize * int(np.prod(shape, dtype=np.int64) if shape else 1)
    chunk = max(1, min(4096, (64 * 1024) // max(row_bytes, 1)))   # ~64 kB chunks
    if gzip:   # a compressed chunk written again moves in the file and leaves its old space
        chunk = min(chunk, BATCH)   # unused: one batch fills a chunk once
    # the byte shuffle groups the doubles' exponent bytes, so gzip at its fastest level packs the
    # profiles smaller than level 4 alone does, in about half of its CPU time (HDF5 compresses the
    # chunks held in its cache when the file is flushed: this is most of a short run's close)
    ds = h5.require_group(group or "/").create_dataset(
        name, shape=(0, *shape), maxshape=(None, *shape), chunks=(chunk, *shape), dtype=dtype,
        **(dict(compression="gzip", compression_opts=GZIP_LEVEL, shuffle=True) if gzip else {}))
    ds.attrs["unit"] = unit(group, name)


def _copy_from_reader(path: Path) -> None:
    """Rewrite ``path`` (marked open by a writer that was killed) from what a reader sees."""
    import h5py

    tmp = path.with_name(path.name + ".recover")
    with h5py.File(path, "r", libver="latest", swmr=True) as src, \
            h5py.File(tmp, "w", libver="latest") as dst:
        for k, v in src.attrs.items():
            dst.attrs[k] = v
        for k in src:
            src.copy(src[k], dst, name=k)
        dst.flush()
        os.fsync(dst.id.get_vfd_handle())
    os.replace(tmp, path)
