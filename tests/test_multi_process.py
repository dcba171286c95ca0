"""Training across processes (jax.distributed) on one machine: two CPU processes with two host
devices each, against one process with four, through the command line as a cluster runs it.

Each process is started as on a host of its own: its own working directory, the same command,
`--coordinator` with its `--process-id`; CPU collectives go through gloo. The two-process run and
the one-process run train the same global batch from the same seed, so they must end with the
same parameters up to float32 reduction order (see the tolerances below).
"""

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow  # about 80 s on 2 cores: three training processes, then four short ones

# 2 training epochs of one training step (2 Adam updates) each, evaluations at 0, 64 and 128
# steps; 4 environments, one per device in both layouts.
RUN = ["--preset", "test", "--env.episode_length_s=0.2", "--ppo.num_timesteps=128", "--ppo.num_evals=3"]
LEARNING_RATE = 6e-4  # the 'test' preset's: Adam moves every parameter by about this per update

# After epoch 1 both runs have collected the same rollouts with the same initial parameters: they
# differ only in the order in which the all-reduces sum the four devices' gradients and normaliser
# statistics (one process sums in memory, two through gloo), a float32 rounding of ~1e-7
# relative. Adam divides each gradient by its own running size, so a weight whose gradient nearly
# cancels across the devices keeps that rounding at its full relative size (measured with jax
# 0.10.2 on 2 cores: all parameters within 2e-7 but one at 2.1e-6). A different key or batch would
# move each parameter by about one Adam step, LEARNING_RATE; 1e-5 is 1/60 of it.
EPOCH1_ATOL = 1e-5
# the normaliser's summed variance is a difference of large sums, so it keeps the rounding of the
# sums (measured: 2.6e-5 relative on one entry); another batch moves it by percents
EPOCH1_RTOL = 1e-4
# Epoch 2 rolls out with the epoch-1 parameters, which differ by that rounding, and the contacts
# of the physics amplify it: observations drift apart, and PPO's clipped ratio turns a few samples
# on or off, which Adam's normalised step spreads over the policy's parameters (measured: policy
# up to 1.7e-3 apart after four updates that moved it 2.2e-3, so the policy is not compared). The
# value function regresses the same returns and stays close (measured: 1.4e-4 apart, 2.4e-3
# moved): it is compared with 5e-4, a fifth of what training moved it.
EPOCH2_VALUE_ATOL = 5e-4


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env(devices: int) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env.update(
        JAX_PLATFORMS="cpu",
        PYTHONUNBUFFERED="1",
        XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}",
    )
    return env


def _start(args, cwd: Path, devices: int, logs: Path) -> subprocess.Popen:
    """Starts the training command in `cwd`, its stdout and stderr going to logs/<cwd name>.out
    and .err (files: a full pipe would stall a process that no one reads yet)."""
    cwd.mkdir(parents=True, exist_ok=True)
    logs.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "quadson_mjx.cli.train", *args, "--no-compile-cache"]
    with open(logs / f"{cwd.name}.out", "w") as out, open(logs / f"{cwd.name}.err", "w") as err:
        return subprocess.Popen(cmd, cwd=cwd, env=_env(devices), stdout=out, stderr=err)


def _finish(proc: subprocess.Popen, logs: Path, name: str, timeout: float) -> tuple[int, str, str]:
    """Waits for the process (killed after `timeout` s: a failure); -> (status, stdout, stderr)."""
    try:
        proc.wait(timeout=timeout)
        hung = False
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        hung = True
    out, err = ((logs / f"{name}.{kind}").read_text() for kind in ("out", "err"))
    if hung:
        pytest.fail(f"{name} still running after {timeout} s:\n{out[-2000:]}\n{err[-2000:]}")
    return proc.returncode, out, err


def _distributed(port: int, pid: int, *extra) -> list[str]:
    return ["--coordinator", f"127.0.0.1:{port}", "--num-processes", "2", "--process-id", str(pid), *extra]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The one-process run (4 devices) and the two-process run (2 x 2), started together (three
    processes on the machine); -> {"one": run dir, "two": process 0's run dir, "tmp": root}."""
    tmp = tmp_path_factory.mktemp("multi_process")
    logs, port = tmp / "logs", _free_port()
    one = _start([*RUN, "--run-dir", str(tmp / "one" / "run")], tmp / "one", 4, logs)
    # process 1 is given a run directory of its own, as on a host without a shared filesystem:
    # it must not create it (process 0 writes the run)
    procs = [
        _start(
            [*RUN, "--run-dir", str(tmp / f"p{i}" / "run"), *_distributed(port, i)], tmp / f"p{i}", 2, logs
        )
        for i in (0, 1)
    ]
    for name, proc in (("one", one), ("p0", procs[0]), ("p1", procs[1])):
        rc, out, err = _finish(proc, logs, name, timeout=600)
        assert rc == 0, f"{name}: exit {rc}\n{out[-3000:]}\n{err[-3000:]}"
    return {"one": tmp / "one" / "run", "two": tmp / "p0" / "run", "tmp": tmp}


def _state(run_dir: Path, step: int) -> dict:
    """brax's whole TrainingState saved at `step`: Adam's step count and moments, the policy and
    value parameters, the normaliser's count, mean and summed variance, the step count."""
    with np.load(run_dir / "checkpoints" / f"state_{step:012d}.npz") as f:
        return {k: f[k] for k in f.files}


def _params(run_dir: Path, step: int) -> dict:
    """The policy's and the value function's parameters of the checkpoint at `step`."""
    import flax.serialization

    data = flax.serialization.msgpack_restore(
        (run_dir / "checkpoints" / f"step_{step:012d}.msgpack").read_bytes()
    )
    return dict(zip(("policy", "value"), (data["1"], data["2"]), strict=True))


def test_two_processes_train_as_one_process_after_epoch_1(runs):
    one, two = _state(runs["one"], 64), _state(runs["two"], 64)
    assert one.keys() == two.keys() and len(one) > 10
    for key in one:
        assert one[key].dtype == two[key].dtype and one[key].shape == two[key].shape, key
        assert np.all(np.isfinite(two[key].astype(np.float64))), key
        if one[key].dtype.kind in "iu":  # step counts, normaliser count: exact
            np.testing.assert_array_equal(two[key], one[key], err_msg=key)
        else:
            np.testing.assert_allclose(two[key], one[key], atol=EPOCH1_ATOL, rtol=EPOCH1_RTOL, err_msg=key)


def test_two_processes_train_as_one_process_after_epoch_2(runs):
    import jax

    # the counts are exact after any number of epochs
    one_state, two_state = _state(runs["one"], 128), _state(runs["two"], 128)
    for key in one_state:
        if one_state[key].dtype.kind in "iu":
            np.testing.assert_array_equal(two_state[key], one_state[key], err_msg=key)
    one, two = _params(runs["one"], 128), _params(runs["two"], 128)
    for part in ("policy", "value"):
        leaves_one, leaves_two = jax.tree.leaves_with_path(one[part]), jax.tree.leaves(two[part])
        assert len(leaves_one) == len(leaves_two) >= 4
        for (path, a), b in zip(leaves_one, leaves_two, strict=True):
            assert a.shape == b.shape and np.all(np.isfinite(b)), (part, path)
            if part == "value":
                np.testing.assert_allclose(
                    b, a, atol=EPOCH2_VALUE_ATOL, rtol=0, err_msg=jax.tree_util.keystr(path)
                )
    # the tolerance is far below what training moved: the runs did learn, and alike
    start = _params(runs["one"], 0)["value"]
    moved = max(
        float(np.max(np.abs(a - s)))
        for a, s in zip(jax.tree.leaves(one["value"]), jax.tree.leaves(start), strict=True)
    )
    assert moved > 4 * EPOCH2_VALUE_ATOL


def test_only_process_0_writes(runs):
    two, one = runs["two"], runs["one"]
    assert not (runs["tmp"] / "p1" / "run").exists()
    assert list((runs["tmp"] / "p1").iterdir()) == []
    # process 0 wrote the whole run, as one process does
    names = lambda d: sorted(str(p.relative_to(d)) for p in d.rglob("*"))  # noqa: E731
    assert names(two) == names(one)
    assert (two / "checkpoints" / "state_000000000128.npz").exists()


@pytest.mark.parametrize("victim", [0, 1])
def test_killed_process_stops_the_other_with_one_line(tmp_path, victim):
    # Killing process 0 (it hosts the coordination service) is seen by process 1 at once; killing
    # process 1 is seen by process 0 when its heartbeats are missed for --heartbeat-timeout (5 s).
    # Either way the survivor ends, its last stderr line naming what happened; nothing hangs.
    port = _free_port()
    extra = ("--heartbeat-timeout", "5", "--init-timeout", "60")
    logs = tmp_path / "logs"
    procs = [
        _start(
            [*RUN, "--run-dir", str(tmp_path / "run"), *_distributed(port, i, *extra)],
            tmp_path / f"p{i}",
            2,
            logs,
        )
        for i in (0, 1)
    ]
    deadline = time.monotonic() + 120
    while "process 1 of 2" not in (logs / "p1.out").read_text():  # both processes have joined
        assert time.monotonic() < deadline and procs[1].poll() is None, "process 1 did not start"
        time.sleep(0.2)
    procs[victim].send_signal(signal.SIGKILL)
    procs[victim].wait()
    t0 = time.monotonic()
    rc, _, err = _finish(procs[1 - victim], logs, f"p{1 - victim}", timeout=60)
    assert rc != 0
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"error: process {1 - victim} of 2 stopped"), err[-2000:]
    assert "another task died" in last, err[-2000:]
    assert time.monotonic() - t0 < 60


def test_regression_signal_to_one_process_stops_both(tmp_path):
    # A SIGTERM to process 1 alone (a scheduler's preemption of one host) used to leave process 0
    # waiting in its next collective until jax.distributed's shutdown barrier gave up (300 s, then
    # both aborted). Now process 1 stops at its next safe point and tells the others, which stop at
    # their next meeting before a computation across processes: both end as on Ctrl-C (status 130).
    port = _free_port()
    logs = tmp_path / "logs"
    # a run long enough that the signal lands before it ends even when every program comes from
    # the compilation cache (with RUN's 128 steps a cached run could finish first: exit 0)
    long_run = [*RUN, "--ppo.num_timesteps=40000"]
    procs = [
        _start(
            [*long_run, "--run-dir", str(tmp_path / "run"), *_distributed(port, i)],
            tmp_path / f"p{i}",
            2,
            logs,
        )
        for i in (0, 1)
    ]
    deadline = time.monotonic() + 120
    while "process 1 of 2" not in (logs / "p1.out").read_text():  # both processes have joined
        assert time.monotonic() < deadline and procs[1].poll() is None, "process 1 did not start"
        time.sleep(0.2)
    procs[1].send_signal(signal.SIGTERM)
    results = [_finish(proc, logs, f"p{i}", timeout=120) for i, proc in enumerate(procs)]
    for i, (rc, out, err) in enumerate(results):
        assert rc == 130, f"p{i}: exit {rc}\n{out[-2000:]}\n{err[-2000:]}"
        assert "interrupted" in out and "Terminating process" not in err, (
            f"p{i}:\n{out[-2000:]}\n{err[-2000:]}"
        )


# Runs the training command with a SIGTERM sent to itself after jax.distributed.initialize and
# before training.train installs its own handlers: the moment a scheduler's preemption can land
# while a run builds its configs and environments.
_SIGNAL_BEFORE_TRAIN = """
import os, signal, sys, time
from quadson_mjx import training
from quadson_mjx.cli import train as cli
real = training.train
def train(*args, **kwargs):
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(0.5)
    return real(*args, **kwargs)
training.train = train
sys.exit(cli.main(sys.argv[1:]))
"""


def test_regression_sigterm_before_the_training_loop_stops_a_distributed_run(tmp_path):
    # jax.distributed.initialize sets a SIGTERM handler of its own (a preemption notifier) that
    # only records the signal: a SIGTERM that came between joining the run and the training loop
    # was swallowed and the run trained to its end (exit 0; seen when a loaded machine was slow to
    # start the loop). Now the command defers it from the moment it joined: one process of a
    # one-process jax.distributed run stops at the loop's first safe point like on Ctrl-C.
    cwd, logs = tmp_path / "p0", tmp_path / "logs"
    cwd.mkdir()
    logs.mkdir()
    args = ["--coordinator", f"127.0.0.1:{_free_port()}", "--num-processes", "1", "--process-id", "0"]
    cmd = [sys.executable, "-c", _SIGNAL_BEFORE_TRAIN, *RUN, *args, "--run-dir", str(cwd / "run")]
    with open(logs / "p0.out", "w") as out, open(logs / "p0.err", "w") as err:
        proc = subprocess.Popen([*cmd, "--no-compile-cache"], cwd=cwd, env=_env(1), stdout=out, stderr=err)
    rc, out, err = _finish(proc, logs, "p0", timeout=300)
    assert rc == 130, f"exit {rc}\n{out[-2000:]}\n{err[-2000:]}"
    assert "SIGTERM: stopping at the next safe point" in err, err[-2000:]
    assert "interrupted: the log" in out and "done in" not in out, out[-2000:]
    assert not list((cwd / "run" / "checkpoints").glob("*.npz")), "it trained before stopping"
