"""Watching a training run: terminal progress, XLA compilations (and jax's persistent compilation
cache), and SIGINT / SIGTERM deferred to the loop's safe points."""

from __future__ import annotations

import contextlib
import dataclasses
import os
import signal
import sys
import threading
import time
from pathlib import Path

import jax


def enable_compilation_cache(path: str | Path) -> Path:
    """Keeps XLA executables in `path` across processes (jax's persistent compilation cache): a
    second run of the same configuration on the same machine loads its programs instead of
    compiling them. Every program is kept, however small: the main job compiles about 90 programs
    of under 0.5 s each, about 6 s together on one H100."""
    from quadson_mjx.errors import UsageError

    path = Path(path).expanduser()
    hint = "choose another with --compile-cache DIR, or --no-compile-cache"
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UsageError(f"compile cache {path}: cannot create it ({e.strerror}); {hint}") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise UsageError(f"compile cache {path} is not writable (read-only?); {hint}")
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    return path


class XlaCompilations:
    """Counts this process's XLA compilations while active, from jax.monitoring's events: `count`
    (executables jax had to build: a new function or a new shape, dtype or placement of one),
    `seconds` spent building them, and `cache_hits` (those the persistent cache served)."""

    _COMPILE = "/jax/core/compile/backend_compile_duration"
    _HIT = "/jax/compilation_cache/cache_hits"

    def __init__(self):
        self.count = 0
        self.seconds = 0.0
        self.cache_hits = 0
        self.programs: list[tuple[str, float]] = []  # (function name, seconds), in order

    def _on_duration(self, event: str, duration: float, **kwargs) -> None:
        if event == self._COMPILE:
            self.count += 1
            self.seconds += duration
            self.programs.append((str(kwargs.get("fun_name", "?")), float(duration)))

    def summary(self, top: int = 4) -> str:
        """One line: count, total seconds, the slowest programs."""
        slow = sorted(self.programs, key=lambda p: -p[1])[:top]
        names = ", ".join(f"{n} {s:.1f} s" for n, s in slow)
        small = [s for _, s in self.programs if s < 0.5]
        return (
            f"{self.count} XLA compilations, {self.seconds:.1f} s ({self.cache_hits} from the cache): {names}; "
            f"{len(small)} under 0.5 s, {sum(small):.1f} s together"
        )

    def _on_event(self, event: str, **kwargs) -> None:
        if event == self._HIT:
            self.cache_hits += 1

    def __enter__(self):
        jax.monitoring.register_event_duration_secs_listener(self._on_duration)
        jax.monitoring.register_event_listener(self._on_event)
        return self

    def __exit__(self, *exc):
        from jax._src import monitoring  # public registration has no public removal

        monitoring.unregister_event_duration_listener(self._on_duration)
        monitoring.unregister_event_listener(self._on_event)
        return False


@dataclasses.dataclass
class Progress:
    """Terminal progress: one line per evaluation with steps, steps/s, ETA and the latest reward
    (or, without evaluations, the training loss)."""

    total_steps: int
    start_step: int = 0
    stream: object = sys.stdout
    t0: float = dataclasses.field(default_factory=time.monotonic)
    last: tuple[float, int] | None = None

    def update(self, step: int, value: float | None, label: str = "eval reward") -> dict[str, float]:
        """Prints the line of `step` with `value` shown as `label`: the evaluation's reward, or
        the training loss of a run without evaluations."""
        now = time.monotonic()
        done = step - self.start_step
        if self.last is not None and step > self.last[1]:
            sps = (step - self.last[1]) / max(now - self.last[0], 1e-9)
        else:
            sps = float("nan")
        remaining = max(self.total_steps - step, 0)
        eta = remaining / sps if sps == sps and sps > 0 else float("nan")
        self.last = (now, step)
        width = 30
        filled = int(width * min(step / max(self.total_steps, 1), 1.0))
        bar = "#" * filled + "-" * (width - filled)
        eta_txt = f"{int(eta // 60)}m{int(eta % 60):02d}s" if eta == eta else "--"
        sps_txt = f"{sps:,.0f}" if sps == sps else "--"
        rew_txt = f"{value:.3f}" if value is not None else "--"
        print(
            f"[{bar}] {step:,}/{self.total_steps:,} steps | {sps_txt} steps/s | ETA {eta_txt} | "
            f"{label} {rew_txt} | {now - self.t0:.0f}s",
            file=self.stream,
            flush=True,
        )
        return {"env_steps_per_s": sps, "steps_this_session": float(done)}


class StopRequested(KeyboardInterrupt):
    """SIGINT or SIGTERM asked a training run to stop; raised at the next safe point (see train)."""


def exit_at_once(signum: int, emergency=None) -> None:
    """Ends the process now with status 130 after a second signal: `emergency(reason)` (closes what
    must be closed, says how to continue) or one line "second SIG...: stopped at once"; stdout and
    stderr flushed; os._exit, so no interpreter shutdown runs."""
    reason = f"second {signal.Signals(signum).name}"
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    with contextlib.suppress(Exception):
        if callable(emergency):
            emergency(reason)
        else:
            os.write(sys.stderr.fileno(), f"\n{reason}: stopped at once\n".encode())
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(130)


@dataclasses.dataclass
class SignalStop:
    """Signals deferred to a flag that the training loop checks at safe points.

    Python runs a signal handler only between bytecodes of the main thread, so while the main
    thread is inside an XLA compilation (tens of seconds) a handler would wait for it, and raising
    from one then lands inside jax's machinery (the second Ctrl-C used to end in a segfault). So
    the signals are read from `signal.set_wakeup_fd` by a watcher thread, which runs at once: the
    first signal sets the flag; a second one calls `emergency` (the loop closes its log there),
    flushes stdout and stderr and ends the process with os._exit(130), without unwinding the
    compiling main thread or running interpreter shutdown next to XLA's threads. Checkpoints and
    config.json are written atomically, so the run stays resumable.

    The same signal again within `same_request_s` of the first is the same request, not a second
    one: GNU `timeout` signals the command and then its whole process group, so a run under
    `timeout` receives its SIGTERM twice, microseconds apart, and would otherwise skip the safe
    point it was asked to stop at.
    """

    signum: int | None = None
    emergency: object = None  # () -> None, called on the second signal before the process exits
    signals: int = 0
    same_request_s: float = 0.1
    clock: object = time.monotonic  # () -> seconds; replaceable in tests
    _first_at: float | None = None
    _watcher: threading.Thread | None = None

    def check(self) -> None:
        if self.signum is not None:
            raise StopRequested(f"stopped by {signal.Signals(self.signum).name}")

    def _on_signal(self, signum: int) -> None:
        now = self.clock()
        if (
            self.signum == signum
            and self._first_at is not None
            and now - self._first_at < self.same_request_s
        ):
            return  # the same request delivered twice (the process and its group)
        self.signals += 1
        if self.signals >= 2:
            self._exit_now(signum)
        self.signum = signum
        self._first_at = now
        message = (
            f"\n{signal.Signals(signum).name}: stopping at the next safe point (after the compilation or "
            "training epoch under way; a second signal stops at once)\n"
        )
        with contextlib.suppress(OSError, ValueError):  # an unbuffered write: safe inside a handler
            os.write(sys.stderr.fileno(), message.encode())

    def _exit_now(self, signum: int) -> None:
        exit_at_once(signum, self.emergency)

    def handler(self, signum, frame):
        if self._watcher is None:  # no watcher thread (not the main thread's loop): count here
            self._on_signal(signum)

    def _watch(self, fd: int) -> None:
        while True:
            try:
                data = os.read(fd, 64)
            except OSError:
                return
            for signum in data:
                if signum == 0:  # uninstalled
                    return
                if signum in (signal.SIGINT, signal.SIGTERM):
                    self._on_signal(signum)

    @contextlib.contextmanager
    def installed(self):
        if threading.current_thread() is not threading.main_thread():
            yield  # signal handlers can only be set from the main thread
            return
        read_fd, write_fd = os.pipe()
        os.set_blocking(write_fd, False)
        # watcher first, then the wakeup fd, then the handlers: no signal is counted twice or lost
        self._watcher = threading.Thread(
            target=self._watch, args=(read_fd,), name="signal-watcher", daemon=True
        )
        self._watcher.start()
        old_wakeup = signal.set_wakeup_fd(write_fd, warn_on_full_buffer=False)
        previous = {s: signal.signal(s, self.handler) for s in (signal.SIGINT, signal.SIGTERM)}
        try:
            yield
        finally:
            for s, h in previous.items():
                signal.signal(s, h)
            signal.set_wakeup_fd(old_wakeup)
            with contextlib.suppress(OSError):
                os.write(write_fd, b"\0")
            self._watcher.join(timeout=5.0)
            self._watcher = None
            os.close(write_fd)
            os.close(read_fd)
