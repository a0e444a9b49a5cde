"""Built-in sample sources: ``csv`` (follow a growing log file) and ``stdin``.

Both read the replay format line by line through the decoder the monitor hands them
(:class:`fault_screen.io.log_stream.LogDecoder`: header, units, the stop/skip/hold policies),
split into lines and decoded as the file reader does (:class:`fault_screen.io.log_format.
LineSplitter`: UTF-8, Latin-1 or UTF-16; LF, CR LF or old-Mac CR line ends).
"""
from __future__ import annotations

import logging
import os
import queue
import sys
import threading
import time

from fault_screen.io.log_format import LineSplitter

__all__ = ["CsvFollower", "StdinSource"]


class CsvFollower:
    """Follow a growing CSV injection log by polling (no inotify: works on network file systems).

    Every ``poll_interval`` seconds the file is stat'ed and its new bytes read; a line counts
    once its newline is written.  When the path names a different file than the one open
    (rotation: inode or device changed, file replaced), the old file is read to its end and
    the new one from its start; when the file became shorter (truncation), it is read again
    from its start.  Both are logged.  ``flush()`` takes a partial last line as complete.
    """

    main_option = "path"

    def __init__(self, target: str, *, decoder, poll_interval: float = 0.5,
                 log: logging.Logger | None = None):
        self.path = os.fspath(target)
        self.decoder = decoder
        self.poll_interval = float(poll_interval)
        self.log = log or logging.getLogger("fault_screen.sources.csv")
        self.fh = None
        self.ident = None
        self.lines = LineSplitter()
        self.finished = False          # a file can always grow
        self._waiting_logged = False
        self.rotations = 0
        self.truncations = 0

    def _open(self) -> bool:
        try:
            fh = open(self.path, "rb")
        except FileNotFoundError:
            if not self._waiting_logged:
                self.log.info("%s: waiting for the log to appear", self.path)
                self._waiting_logged = True
            return False
        st = os.fstat(fh.fileno())
        self.fh, self.ident = fh, (st.st_dev, st.st_ino)
        self.lines.reset()
        return True

    def _drain(self, out, everything: bool = False):
        # a bounded read: a monitor catching up on a months-long log holds one piece of it at
        # a time (the rest is read at the next poll, at once); a rotated file is read to its end
        while True:
            data = self.fh.read(READ_BYTES)
            if data:
                out.extend(self.decoder.feed_lines(self.lines.push(data)))
            if not everything or len(data) < READ_BYTES:
                return

    def poll(self):
        """Read what is new now; returns the new samples."""
        out = []
        if self.fh is None and not self._open():
            return out
        try:
            st = os.stat(self.path)
        except FileNotFoundError:
            st = None           # moved away, the new one not yet created: finish the old one
        if st is not None and (st.st_dev, st.st_ino) != self.ident:
            self._drain(out, everything=True)
            out.extend(self._finish_partial())
            self.fh.close()
            self.fh = None
            self.rotations += 1
            self.log.warning("%s: log rotated (a new file replaced the one followed); reading "
                             "the new file from its start", self.path)
            self.decoder.new_file()
            if not self._open():
                return out
        elif st is not None and st.st_size < self.fh.tell():
            self.truncations += 1
            self.log.warning("%s: log truncated (size %d < %d bytes read); reading it again "
                             "from its start", self.path, st.st_size, self.fh.tell())
            self.fh.seek(0)
            self.lines.reset()
            self.decoder.new_file()
        self._drain(out)
        return out

    def _finish_partial(self):
        return self.decoder.feed_lines(self.lines.rest())

    def flush(self):
        """Samples of a partial last line (call when no more data is expected)."""
        return self._finish_partial() if self.fh is not None else []

    def read(self, timeout: float):
        deadline = time.monotonic() + max(0.0, timeout)
        while True:
            out = self.poll()
            left = deadline - time.monotonic()
            if out or left <= 0:
                return out
            time.sleep(min(self.poll_interval, left))

    def close(self):
        if self.fh is not None:
            self.fh.close()
            self.fh = None


#: bytes read from the followed file per poll (~6,000 lines of a typical log)
READ_BYTES = 256 * 1024


class StdinSource:
    """Read the log from standard input (``--follow -``); ``finished`` once it is closed."""

    main_option = "path"

    def __init__(self, target: str = "-", *, decoder, poll_interval: float = 0.5,
                 log: logging.Logger | None = None, stream=None):
        self.decoder = decoder
        self.poll_interval = float(poll_interval)
        self.log = log or logging.getLogger("fault_screen.sources.stdin")
        self.stream = stream if stream is not None else sys.stdin.buffer
        self.queue: queue.Queue = queue.Queue()
        self.finished = False
        self._eof = False
        self.lines = LineSplitter()
        # a thread, because a pipe cannot be polled portably with a timeout
        threading.Thread(target=self._pump, name="stdin-source", daemon=True).start()

    def _pump(self):
        # read1 returns what the pipe holds: lines ended by a lone CR arrive as they come
        read = getattr(self.stream, "read1", None)
        while True:
            data = read(65536) if read is not None else self.stream.readline()
            if not data:
                self.queue.put(None)
                return
            self.queue.put(data)

    def read(self, timeout: float):
        out = []
        deadline = time.monotonic() + max(0.0, timeout)
        while not self._eof:
            try:
                item = self.queue.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                break
            if item is None:
                self._eof = True
                out.extend(self.decoder.feed_lines(self.lines.rest()))
                self.finished = True
                self.log.info("standard input closed")
                break
            out.extend(self.decoder.feed_lines(self.lines.push(item)))
            if out and self.queue.empty():
                break
        return out

    def flush(self):
        return []

    def close(self):
        pass
