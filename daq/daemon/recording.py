"""The daemon's one recording slot: the recorder process writing now, and the last one that died on us.

:class:`RecordingSlot` checks the operator's file path before a recorder starts (a bad folder or a full
disk is answered at once, not by a dying child), notices the moment a recorder it did not stop exits
(recovers its file, reports it, frees the slot), and carries that failure until the next recording.

Decision records: docs/decisions/0017-crash-truth.md, docs/decisions/0038-daemon-as-a-coordinator.md.
"""

from __future__ import annotations

import datetime as _dt
import sys
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path

from daq.errors import InputError
from daq.streaming.recorder import MIN_FREE_BYTES, free_space_refusal

from .children import RecorderProcess
from .session_state import RecordingEnd, RecordingRef, describe_exit, recover_recording, utcnow

Publish = Callable[[str, str, str], None]  # (kind, source, detail): an event on the bus


def run_file_path(asked: str | None, data_dir: Path, rig: str) -> Path:
    """The run file a ``record_start`` writes: ``asked``, or DATA_DIR/RIG-STAMP.h5; InputError (before any
    process starts) if it exists, is not .h5/.hdf5, its folder is not writable or its disk is nearly full."""
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    path = Path(asked or data_dir / f"{rig}-{stamp}.h5").absolute()
    if path.exists():
        raise InputError(str(path), "path", "exists; recordings are never overwritten")
    if path.suffix.lower() not in (".h5", ".hdf5"):
        raise InputError(str(path), "path", "must end in .h5 or .hdf5")
    try:  # here, not in the recorder process: a bad folder is the operator's input, answered at once
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path.parent):
            pass
    except OSError as exc:
        raise InputError(str(path), "path", f"cannot write in {path.parent}: {exc.strerror or exc}") from None
    low = free_space_refusal(path.parent, MIN_FREE_BYTES)  # the recorder's own margin, answered at once
    if low is not None:
        raise InputError(str(path), "path", f"cannot record: {low}")
    return path


class RecordingSlot:
    """At most one recorder at a time; ``lock`` is the daemon's (shutdown holds it while it stops the recorder)."""

    def __init__(self, lock: threading.RLock, publish: Publish, recording_gone: Callable[[], None]) -> None:
        self.recorder: RecorderProcess | None = None
        self.failure: RecordingEnd | None = None  # a recorder that died on us, until the next start
        self._lock = lock
        self._publish = publish
        self._recording_gone = recording_gone  # the session state forgets the recording (OSError: it tried)

    def ref(self) -> RecordingRef | None:
        rec = self.recorder
        return RecordingRef(path=str(rec.path), recorder_pid=rec.pid) if rec is not None else None

    def refuse_if_busy(self) -> None:
        """RuntimeError if a recorder runs (asked before the new file's path is checked)."""
        if self.recorder is not None and self.recorder.alive:
            raise RuntimeError(f"already recording to {self.recorder.path}")

    def start(self, path: Path, endpoints: list[str], rig_arg: str, flush_s: float,
              timeout: float) -> tuple[RecorderProcess, RecordingEnd | None]:
        """A recorder for ``path`` (RuntimeError if one runs); the failure before it, which this start clears."""
        with self._lock:
            self.refuse_if_busy()
            rec = self.recorder = RecorderProcess(path, rig_arg, endpoints, flush_s, timeout)
            lost, self.failure = self.failure, None
            rec.watch(self._on_exit)
        return rec, lost

    def rotate(self, path: Path, endpoints: list[str], rig_arg: str, flush_s: float,
               timeout: float) -> tuple[RecorderProcess, RecorderProcess]:
        """A recorder for ``path`` put in the slot while the running one goes on writing (make before break): the
        new one has seen our data when this returns, so the caller stops the old one with no hole between the two
        files. Returns (new, old); RuntimeError if nothing is recording (then there is nothing to rotate)."""
        with self._lock:
            old = self.recorder
            if old is None or not old.alive:
                raise RuntimeError("not recording: nothing to rotate (record_start begins a recording)")
            rec = RecorderProcess(path, rig_arg, endpoints, flush_s, timeout)
            if not rec.alive:  # it ended before it saw our data: the old one goes on, nothing is lost
                raise RuntimeError(f"the recorder for {path} ended as it started ({rec.closed_line or rec.progress}); "
                                   f"still recording to {old.path}")
            self.recorder = rec
            rec.watch(self._on_exit)
        return rec, old

    def take(self) -> RecorderProcess:
        """The running recorder, out of the slot (the caller stops it); RuntimeError if there is none."""
        with self._lock:
            if self.recorder is None:
                raise RuntimeError("not recording")
            rec, self.recorder = self.recorder, None
        return rec

    def _on_exit(self, rec: RecorderProcess) -> None:
        """A recorder ended: if the daemon did not end it, report it, recover its file, free the slot."""
        if rec.stopping:
            return
        with self._lock:
            if rec.stopping:  # shutdown holds the lock while it stops the recorder
                return
            if self.recorder is rec:
                self.recorder = None
            rc = rec.proc.returncode
            failure = RecordingEnd(path=str(rec.path), pid=rec.pid, exit=describe_exit(rc), returncode=rc,
                                   ended_at=rec.ended_at or utcnow(), last_progress=rec.progress,
                                   recovery="recovering the file")
            self.failure = failure
        changed, what, dt = recover_recording(rec.path)
        failure = failure.model_copy(update={"recovered": changed, "recovery": what, "recovery_s": dt})
        with self._lock:
            if self.failure is not None and self.failure.pid == rec.pid:
                self.failure = failure
        self._publish("recorder_died", "daemon", failure.summary())
        print(f"daq daemon: {failure.summary()}", file=sys.stderr, flush=True)
        self._recording_gone()
