"""A tiny SeedLink server on 127.0.0.1 for tests (no network beyond loopback).

It answers the commands of a multi-station client (``HELLO`` with a server id line and an
organisation line; ``STATION``, ``SELECT``, ``DATA`` with ``OK``; ``END`` starts the stream)
and then sends each given 512-byte miniSEED record as a SeedLink packet: ``SL``, six hex digits
of sequence number, the record."""
from __future__ import annotations

import io
import socket
import threading

RECLEN = 512


def records_of(stream, interleave: bool = False) -> list[bytes]:
    """The stream as 512-byte miniSEED records (float32 samples, as obspy's example holds),
    trace after trace, or with ``interleave`` in turn across the traces, as a server streams
    channels recorded together."""
    per_trace = []
    for tr in stream:
        buf = io.BytesIO()
        tr.write(buf, format="MSEED", reclen=RECLEN)
        data = buf.getvalue()
        assert len(data) % RECLEN == 0
        per_trace.append([data[i:i + RECLEN] for i in range(0, len(data), RECLEN)])
    if not interleave:
        return [rec for recs in per_trace for rec in recs]
    return [recs[i] for i in range(max(map(len, per_trace))) for recs in per_trace if i < len(recs)]


class FakeSeedLinkServer:
    """``hold_after``: send that many records, then wait for :meth:`release` to send the rest
    (a channel whose records come late)."""

    def __init__(self, records: list[bytes], hold_after: int | None = None):
        self.records = records
        self.hold_after = hold_after
        self._released = threading.Event()
        self.commands: list[str] = []
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(1)
        self.address = f"127.0.0.1:{self.sock.getsockname()[1]}"
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self):
        self.sock.settimeout(0.2)
        while not self._stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except OSError:
                continue
            with conn:
                self._session(conn)

    def _session(self, conn):
        conn.settimeout(0.2)
        pending = b""
        while not self._stop.is_set():
            try:
                chunk = conn.recv(1024)
            except socket.timeout:
                continue
            except OSError:
                return
            if not chunk:
                return
            pending += chunk
            *lines, pending = pending.replace(b"\n", b"\r").split(b"\r")
            for line in (x.strip().decode() for x in lines if x.strip()):
                self.commands.append(line)
                verb = line.split()[0].upper()
                if verb == "HELLO":
                    conn.sendall(b"SeedLink v3.1 (fault_screen test server)\r\n"
                                 b"fault_screen tests\r\n")
                elif verb in ("STATION", "SELECT", "DATA"):
                    conn.sendall(b"OK\r\n")
                elif verb == "END":
                    for seq, rec in enumerate(self.records):
                        if seq == self.hold_after:
                            while not (self._released.wait(0.1) or self._stop.is_set()):
                                pass
                        conn.sendall(b"SL%06X" % seq + rec)
                        self.sent += 1
                else:
                    conn.sendall(b"ERROR\r\n")

    def release(self):
        self._released.set()

    def close(self):
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.sock.close()
