"""The face model's own log lines, kept off the user's terminal around the library's calls to it.

mediapipe's C++ graph writes to file descriptor 2 directly, below Python: TensorFlow Lite's ``INFO: Created
TensorFlow Lite XNNPACK delegate for CPU.``, absl's ``WARNING: All log messages before absl::InitializeLog() is
called are written to STDERR`` and glog lines such as ``W0000 00:00:... inference_feedback_manager.cc:114]
Feedback manager requires a model with a single signature inference ...``. Python's ``sys.stderr`` and the
``logging``/``warnings`` machinery never see them, so they can only be caught at the descriptor.

:func:`native_logs_filtered` does that for the duration of one face-model call and no longer: it points
descriptor 2 at a temporary file, runs the call, points descriptor 2 back at what it was, and writes back
everything that was captured except the model's informational lines (:data:`NOISE`). So nothing is changed for
the rest of the process: no global log level is set, no environment variable, no handler; a line that another
thread wrote to stderr during the call is delayed until the call ends, not lost; and the model's errors
(glog ``E``/``F`` lines) still come through.
"""

from __future__ import annotations

import os
import re
import sys
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["NOISE", "native_logs_filtered"]

NOISE = re.compile(
    rb"^(INFO: Created TensorFlow Lite"
    rb"|WARNING: All log messages before absl::InitializeLog\(\) is called"
    rb"|[IW]\d{4} \d\d:\d\d:\d\d[\d.]*\s+\d+ [\w.-]+:\d+\] )"
)
"""The lines dropped: TensorFlow Lite's delegate notice, absl's pre-init notice, glog info and warning lines."""

_LOCK = threading.RLock()  # descriptor 2 is the process's: one redirection at a time


def _flush_python_stderr() -> None:
    try:
        sys.stderr.flush()
    except (AttributeError, OSError, ValueError):  # no stderr, or a closed one: nothing buffered to keep
        pass


def _write_all(fd: int, data: bytes) -> None:
    while data:
        data = data[os.write(fd, data) :]


@contextmanager
def native_logs_filtered() -> Iterator[None]:
    """Run the body with descriptor 2 captured, then write back what was captured less :data:`NOISE`.

    Where descriptor 2 cannot be duplicated (a process started without one), the body runs as it is.
    """
    with _LOCK:
        _flush_python_stderr()
        try:
            saved = os.dup(2)
        except OSError:
            yield
            return
        try:
            with tempfile.TemporaryFile() as captured:
                os.dup2(captured.fileno(), 2)
                try:
                    yield
                finally:
                    _flush_python_stderr()
                    os.dup2(saved, 2)
                    captured.seek(0)
                    kept = [line for line in captured.read().splitlines(keepends=True) if not NOISE.match(line)]
                    _write_all(2, b"".join(kept))
        finally:
            os.close(saved)
