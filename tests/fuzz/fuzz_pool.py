"""The fuzz suite's worker process: one long-lived interpreter runs the cases, restarted after a timeout."""

from __future__ import annotations

import json
import os
import select
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

WORKER = Path(__file__).with_name("fuzz_worker.py")


class Worker:
    """Runs case specs in a child process; a case past ``timeout`` seconds kills it (a new one starts)."""

    def __init__(self, timeout: float) -> None:
        self.timeout = timeout
        self.root = Path(tempfile.mkdtemp(prefix="tfw-fuzz-"))
        self.proc: subprocess.Popen[bytes] | None = None
        self.restarts = 0

    def _start(self) -> subprocess.Popen[bytes]:
        env = {**os.environ, "TORCHFLUIDWARP_FUZZ_ROOT": str(self.root), "TMPDIR": str(self.root / "tmp")}
        (self.root / "tmp").mkdir(exist_ok=True)
        proc = subprocess.Popen(
            [sys.executable, str(WORKER)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            env=env,
            cwd=self.root,
        )
        self.proc = proc
        ready = self._read(120.0)
        if ready is None or ready["verdict"] != "ready":
            raise RuntimeError(f"the fuzz worker did not start: {ready}")
        return proc

    def _read(self, timeout: float) -> dict[str, Any] | None:
        assert self.proc is not None and self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        if not ready:
            return None
        line = self.proc.stdout.readline()
        return json.loads(line) if line else {"verdict": "fail", "detail": f"worker died: exit {self.proc.wait()}"}

    def run(self, spec: dict[str, Any]) -> dict[str, Any]:
        proc = self.proc if self.proc is not None and self.proc.poll() is None else self._start()
        assert proc.stdin is not None
        proc.stdin.write((json.dumps(spec) + "\n").encode())
        proc.stdin.flush()
        verdict = self._read(self.timeout)
        if verdict is None or verdict["detail"].startswith("worker died"):
            self.stop()
            self.restarts += 1
            if verdict is None:
                verdict = {"verdict": "fail", "detail": f"no answer within {self.timeout:g} s (a hang?)"}
        return verdict

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.kill()  # our own child, by its handle
            self.proc.wait()
            self.proc = None

    def close(self) -> None:
        self.stop()
        shutil.rmtree(self.root, ignore_errors=True)
