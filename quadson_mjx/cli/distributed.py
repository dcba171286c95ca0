"""Joining a multi-process training run (jax.distributed) from the train command's flags, and the
one-line errors of a run whose peer died: the runtime's fatal report folded by a child process that
reads this process's stderr, a failed collective as one line."""

from __future__ import annotations

import os
import sys

import jax

from quadson_mjx.errors import UsageError


def start_distributed(args) -> bool:
    """Joins a multi-process run (jax.distributed) when the flags ask for one: --coordinator with
    --num-processes and --process-id, or --distributed (the cluster's environment: SLURM, Open MPI,
    as jax.distributed detects them). CPU devices talk through gloo (jax's default on the CPU has no
    collectives across processes). -> whether it joined one."""
    if args.coordinator is None and not args.distributed:
        if args.num_processes != 1 or args.process_id != 0:
            raise UsageError("--num-processes and --process-id need --coordinator HOST:PORT")
        return False
    if args.coordinator is not None and args.distributed:
        raise UsageError("--distributed takes the coordinator from the cluster: remove --coordinator")
    if args.coordinator is not None and not 0 <= args.process_id < args.num_processes:
        raise UsageError(f"--process-id {args.process_id} is not in 0..{args.num_processes - 1}")
    for flag, seconds in (
        ("--init-timeout", args.init_timeout),
        ("--heartbeat-timeout", args.heartbeat_timeout),
    ):
        if seconds < 1:
            raise UsageError(f"{flag} must be at least 1 s, got {seconds}")
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    given = {}
    if args.coordinator is not None:
        given = dict(
            coordinator_address=args.coordinator, num_processes=args.num_processes, process_id=args.process_id
        )
    try:
        jax.distributed.initialize(
            **given,
            initialization_timeout=args.init_timeout,
            heartbeat_timeout_seconds=args.heartbeat_timeout,
        )
    except (ValueError, RuntimeError, jax.errors.JaxRuntimeError) as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        where = "--distributed (SLURM, Open MPI)" if args.distributed else f"--coordinator {args.coordinator}"
        raise UsageError(f"cannot join the multi-process run through {where}: {first}") from None
    fold_runtime_fatal_errors(f"process {jax.process_index()} of {jax.process_count()}")
    return True


# Run as a child process that reads this process's stderr (see fold_runtime_fatal_errors).
_FOLD = r"""
import re, signal, sys
signal.signal(signal.SIGINT, signal.SIG_IGN)  # it ends when the trainer's stderr closes
signal.signal(signal.SIGTERM, signal.SIG_IGN)
fatal = re.compile(rb"^F\d{4} [\d:.]+ +\d+ [^\]]+\] (.*)")
out, folded = sys.stderr.buffer, False
for line in sys.stdin.buffer:
    match = None if folded else fatal.match(line)
    if match:
        text = match.group(1).decode(errors="replace")
        why, _, status = text.partition("absl::Status: ")
        why = why.split(" Disable Python buffering")[0].strip()
        line = f"error: {sys.argv[1]} stopped: {why} ({status.strip()})\n".encode()
        folded = True  # the rest is the runtime's stack trace
    elif folded:
        continue
    out.write(line)
    out.flush()
"""


def fold_runtime_fatal_errors(who: str) -> None:
    """Passes this process's stderr through a child process that folds a fatal report of the
    distributed runtime into one line. When another process of the run dies, jax's coordination
    client ends this one at once from C++ (abort, exit status 134) with a log line and a stack
    trace: that line becomes `error: process I of N stopped: ...another task died...`, the stack
    trace is dropped, everything else passes unchanged."""
    import subprocess

    read, write = os.pipe()
    subprocess.Popen([sys.executable, "-c", _FOLD, who], stdin=read, close_fds=True)
    os.close(read)
    sys.stderr.flush()
    os.dup2(write, 2)
    os.close(write)


def lost_peer(e: BaseException) -> str:
    """One line for a collective that failed in a multi-process run (another process died)."""
    first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
    return (
        f"process {jax.process_index()} of {jax.process_count()}: a collective across the processes "
        f"failed, another process has likely stopped ({first[:300]}); resume from process 0's run "
        "directory with --resume"
    )
