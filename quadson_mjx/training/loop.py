"""Brax PPO training of foot-offset policies: configs, checkpoints, MCAP metrics, resume.

`train(env_cfg, ppo_cfg, run_dir)` calls `brax.training.agents.ppo.train` (not a fork of it) and
writes one run directory:

    run_dir/config.json              resolved env + ppo configs, versions
    run_dir/train.mcap               every evaluation's metrics (/train/metrics), events (/train/log),
                                     configs and versions as metadata, the MJCF as an attachment
    run_dir/checkpoints/step_*.msgpack  (normaliser, policy, value) params at every evaluation
    run_dir/checkpoints/state_*.npz     brax's whole TrainingState (+ Adam's moments, step count)
    run_dir/checkpoints/env_state_*.npz the environments' states, when stopped by a signal
    run_dir/checkpoints/latest       name of the newest checkpoint

Checkpoints are written atomically (temp file + rename), so a killed run never leaves a half file
behind as its newest. `--resume RUN_DIR` restores the whole training state and continues the run
as if it had not stopped (see `train`); the previous log is kept beside the new one, which starts
with its readable contents. SIGINT and SIGTERM stop a run at the next safe point (see `train`).

Several local GPUs: brax splits environments and batches over them; `compat.brax_multi_device`
compiles brax's per-device functions as one sharded jit (ppo.multi_device, ppo.max_devices).
Several processes (jax.distributed): the same jit over every process's devices; process 0 alone
evaluates and writes the run directory (lock, configs, log, checkpoints); the others write nothing.
"""

from __future__ import annotations

import contextlib
import json
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import jax

from quadson_mjx import terrain_tiles
from quadson_mjx.config import to_json
from quadson_mjx.errors import write_text_atomic
from quadson_mjx.provenance import versions
from quadson_mjx.training import guards
from quadson_mjx.training.checkpoints import (
    _load_npz,
    _save_npz,
    checkpoint_sha256,
    env_state_path,
    load_checkpoint,
    save_checkpoint,
    training_state_path,
)
from quadson_mjx.training.monitor import Progress, SignalStop, XlaCompilations
from quadson_mjx.training.networks import make_networks
from quadson_mjx.training.presets import (
    LEARNING_RATE_SCHEDULES,
    check_ppo_config,
    epoch_steps,
    local_devices_to_use,
)
from quadson_mjx.training.runs import (
    LOCK_NAME,
    _reopen_log,
    check_new_run_dir,
    check_writable_dir,
    init_point,
    load_run_config,
    resume_point,
    run_dir_lock,
    source_curriculum_line,
)
from quadson_mjx.training.widen import init_params_for

# config.json's entries besides the configs that a resumed run keeps (see `train`'s record)
KEPT_RECORDS = ("finetune",)


def train(
    env_cfg,
    ppo_cfg,
    run_dir: str | Path,
    resume: bool = False,
    progress_stream=sys.stdout,
    on_eval: Callable[[int, dict], None] | None = None,
    init_from: str | Path | None = None,
    stop: SignalStop | None = None,
    record: dict | None = None,
):
    """Trains with brax PPO and writes the run directory. Returns (make_policy, params, metrics).

    resume=True continues the run in `run_dir` (configs come from it) from its newest checkpoint,
    restoring brax's whole training state: parameters, normaliser, Adam's moments and step count
    (state_*.npz, written at every evaluation), the PRNG keys (derived from the seed and the epoch
    number) and, when the run stopped on a signal or Ctrl-C, the environments' states
    (env_state_*.npz). Then the resumed run's later evaluations and parameters equal those of
    an uninterrupted run (tested on the CPU, bit for bit). After a hard kill (no env_state file)
    the environments restart from the run's initial states, so the curve continues but is not
    identical; a checkpoint without a state file (older versions) restores the parameters and
    normaliser only and the moments restart. A run without a checkpoint starts over from step 0.
    The previous train.mcap is kept as train.before_resume_N.mcap; its readable contents
    (read past damaged records) start the new log.

    init_from (a new run only): a run directory or one of its checkpoint files whose parameters and
    observation normaliser (newest intact checkpoint of a directory) start this run instead of the
    seed's random ones, for fine-tuning a trained policy under changed configs; the optimiser's
    moments and the step count start afresh. Its networks must match this run's (the observation
    and action sizes, ppo.policy_hidden and the like): a ValueError names the mismatch; the
    exceptions are a longer env.obs_history than the source's, the measured servo latency added
    (env.observe_servo_latency), the gait's two actions added (env.gait_action) and a critic's
    ground scan added (env.critic_scan_points), which the networks read with zero weights
    (training/widen.py; "widened_from_<key>" in the record). The source, its step and the
    checkpoint's SHA-256 are kept in config.json ("init_from", kept on resume) and in the log's
    start event, and the step-0 checkpoint is the source's parameters.

    record: more entries of config.json (a new run's; a resumed run keeps those it had), e.g. the
    fine-tune that follows the run ("finetune", cli/finetune.py).

    SIGINT and SIGTERM (Ctrl-C, a scheduler's preemption) are deferred while training: the run
    stops at the next safe point: before a training epoch or an evaluation, or after saving a
    checkpoint. A signal that arrives during an XLA compilation (tens of seconds on the first epoch
    and evaluation) or a training epoch takes effect when it ends. Stopping raises StopRequested
    (a KeyboardInterrupt) after closing the log and saving the state. A second signal, even during
    a compilation, ends the process at once (os._exit(130), see monitor.SignalStop) after closing the
    log; the run stays resumable from its last checkpoint. `stop`: a SignalStop the caller has
    installed already, whose signals (received before this call) count as the run's own; else one is
    installed for the call. jax.distributed.initialize sets a SIGTERM handler of its own that only
    records the signal, so a multi-process caller installs one right after it (see cli/train.py).

    One process at a time trains in a run directory: it holds run_dir/.lock (runs.run_dir_lock);
    another train or resume on it raises RunDirInUse naming the holder's pid. A loss, gradient or
    parameter that becomes non-finite stops the run at that evaluation with TrainingDiverged,
    before its checkpoint is written (checkpoints/latest keeps naming the last finite one); too many
    environments for the memory raise OutOfMemory. Both are UsageErrors: one line, exit status 2.

    Several processes (jax.distributed initialized; every process calls `train` with the same
    configs and run_dir): they train as one process with all their devices would (same keys,
    compat.brax_multi_process). Process 0 alone holds the lock and writes config.json, the log and
    the checkpoints; the others write nothing (on resume they read the run directory, so it must
    be on a filesystem every process sees). A stop on a signal saves no environments' states
    there (they are spread over the processes): the resume restarts them from the initial states.

    It starts by dropping the process's traces and compiled programs (jax.clear_caches): what was
    traced before changes how jax lowers the training's programs, so a second training in one
    process (a sweep, a test suite) would compile them again under other persistent-cache keys;
    cleared, it lowers them as a fresh process does and loads them from the cache (measured on 2
    CPU cores: a second 'test'-preset training 42 s -> 13 s).
    """
    jax.clear_caches()
    owned = stop is None
    stop = SignalStop() if owned else stop
    with stop.installed() if owned else contextlib.nullcontext(), contextlib.ExitStack() as held:
        return _train(
            env_cfg, ppo_cfg, Path(run_dir), resume, progress_stream, on_eval, stop, held, init_from, record
        )


def _claim_new_run_dir(run_dir: Path, held: contextlib.ExitStack) -> bool:
    """Creates and locks a new run's directory. -> whether this call created it."""
    check_new_run_dir(run_dir)
    created = not run_dir.exists()
    run_dir.mkdir(parents=True, exist_ok=True)
    held.enter_context(run_dir_lock(run_dir))
    if any(p.name != LOCK_NAME for p in run_dir.iterdir()):  # another run started in between
        check_new_run_dir(run_dir)
    return created


def _remove_if_unused(run_dir: Path) -> None:
    """Removes a run directory this process created when nothing but its lock file is in it."""
    with contextlib.suppress(OSError):
        if {p.name for p in run_dir.iterdir()} <= {LOCK_NAME}:
            (run_dir / LOCK_NAME).unlink(missing_ok=True)
            run_dir.rmdir()


def _train(
    env_cfg, ppo_cfg, run_dir: Path, resume: bool, stream, on_eval, stop: SignalStop, held, init_from, record
):
    from brax.training.agents.ppo import train as ppo

    from quadson_mjx import compat, warp_build
    from quadson_mjx.env_config import check_env_config
    from quadson_mjx.env_model import scene_xml_text
    from quadson_mjx.envs import make_env
    from quadson_mjx.mcap_log import McapLog
    from quadson_mjx.randomize import randomization_fn
    from quadson_mjx.wrappers import wrap_for_training

    compat.patch_brax()
    primary = jax.process_index() == 0  # the process that writes the run directory
    start_step, ckpt = 0, None
    live = {"log": None, "step": 0}  # what the second signal's emergency exit closes
    log_lock = threading.Lock()

    def emergency(reason: str) -> None:  # on the watcher thread, the main thread compiling
        if live["log"] is not None and log_lock.acquire(timeout=2.0):
            event = {"event": "interrupted", "step": live["step"], "reason": reason}
            live["log"].log("/train/log", event, time.time_ns())
            live["log"].close()
        if (run_dir / "config.json").exists():
            advice = f"the log is closed; continue the run with --resume {run_dir}"
        else:
            advice = "nothing was saved yet: run the same command again"
        print(f"\n{reason}: stopped at once; {advice}", file=sys.stderr)

    stop.emergency = emergency
    origin = None  # the "init_from" record of config.json
    if resume and init_from is not None:
        raise ValueError("init_from starts a new run; a resumed run keeps its own parameters")
    if init_from is not None:
        source, init_ckpt, init_step = init_point(Path(init_from))
        origin = {
            "run": str(source),
            "checkpoint": init_ckpt.name,
            "step": init_step,
            "sha256": checkpoint_sha256(init_ckpt),
        }
    if resume:
        env_cfg, ppo_cfg = load_run_config(run_dir)
        with contextlib.suppress(OSError, ValueError, AttributeError):
            old_config = json.loads((run_dir / "config.json").read_text())
            origin = old_config.get("init_from")
            record = {k: old_config[k] for k in KEPT_RECORDS if k in old_config}
        if primary:
            check_writable_dir(run_dir)
            held.enter_context(run_dir_lock(run_dir))
        notes: list[str] = []
        start_step, ckpt = resume_point(run_dir, ppo_cfg, notes)
        for note in notes:
            print(f"resume: {note}", file=stream)
        if ckpt is None:
            print(
                f"resume: {run_dir} has no checkpoint after step 0: starting from step 0 with its configs",
                file=stream,
            )
    check_env_config(env_cfg)
    check_ppo_config(ppo_cfg)
    guards.check_backend(env_cfg, ppo_cfg, local_devices_to_use(ppo_cfg))
    created = False
    if not resume and primary:
        created = _claim_new_run_dir(run_dir, held)
    try:
        with compat.mjx_local_device():
            env = make_env(env_cfg)
            eval_env = make_env(env_cfg)
        guards.check_memory(env, ppo_cfg.num_envs, local_devices_to_use(ppo_cfg))
        if env.warp_buffers is not None:  # Warp's kernels, built while XLA compiles (warp_build)
            build = warp_build.start(env.mj_model, env.warp_buffers)
            print(f"warp: building {build.modules} kernel modules on {build.workers} threads", file=stream)
        if init_from is not None:  # before anything is written: a mismatch leaves no run behind
            try:
                init_params, widened = init_params_for(init_ckpt, source, env, env_cfg, ppo_cfg)
            except ValueError as e:
                raise ValueError(f"init_from {init_ckpt} does not fit this run's networks: {e}") from None
            origin.update({f"widened_from_{k}": v for k, v in widened.items()})
    except BaseException:
        if created:
            _remove_if_unused(run_dir)
        raise
    live["step"] = start_step
    per_epoch, epochs = epoch_steps(ppo_cfg)
    first_epoch = start_step // per_epoch
    state = compat.BraxTrainingState(first_epoch=first_epoch)
    restore, restored = None, "nothing (a fresh start from the seed)"
    if ckpt is not None:
        restore = load_checkpoint(ckpt, env.observation_size, env.action_size, ppo_cfg)
        restored = "parameters and normaliser only (no state file: the optimiser's moments restart)"
        if training_state_path(run_dir, start_step).exists():
            state.restore_training_state = _load_npz(training_state_path(run_dir, start_step), start_step)
            restored = "the whole training state (Adam's moments, step count, keys)"
            if env_state_path(run_dir, start_step).exists():
                restored += " and the environments"
                state.restore_env_state = _load_npz(env_state_path(run_dir, start_step), start_step, "env")
            else:
                restored += "; the environments restart from the run's initial states"
        print(f"resume from step {start_step:,}: restoring {restored}", file=stream)
    elif init_from is not None:
        restore = init_params
        restored = (
            f"the parameters and normaliser of {init_ckpt} (step {init_step:,}); the optimiser starts afresh"
        )
        if "widened_from_obs_history" in origin:
            restored += (
                f"; its obs_history {origin['widened_from_obs_history']} widened to {env_cfg.obs_history} "
                "(earlier ticks read with zero weights)"
            )
        if "widened_from_critic_scan_points" in origin:
            restored += (
                f"; its critic's ground scan of {origin['widened_from_critic_scan_points']} points a side widened "
                f"to {env_cfg.critic_scan_points} (the new cells read with zero weights)"
            )
        if "widened_from_gait_action" in origin:
            restored += (
                "; the gait's step length and frequency scales added to the policy's actions (mode 0: "
                "the gait as it was) and to both networks' last_action input (read with zero weights)"
            )
        if "widened_from_observe_servo_latency" in origin:
            restored += "; the measured servo latency added to both networks' input (read with zero weights)"
        print(f"init from {init_ckpt}: {restored}", file=stream)
        if env_cfg.terrain == "tiles" and (line := source_curriculum_line(source, env_cfg.tiles)):
            print(line, file=stream)
    devices = local_devices_to_use(ppo_cfg)
    if jax.process_count() > 1:  # every process its rows of the single-process run's keys
        state.epoch_keys = lambda epoch: compat.process_epoch_keys(ppo_cfg.seed, epoch, devices)
    else:
        state.epoch_keys = lambda epoch: compat.brax_epoch_keys(ppo_cfg.seed, epoch, devices)
    vers = versions()
    if primary:
        write_text_atomic(
            run_dir / "config.json",
            json.dumps(
                {
                    "env": json.loads(to_json(env_cfg)),
                    "ppo": json.loads(to_json(ppo_cfg)),
                    "versions": vers,
                    **({"init_from": origin} if origin else {}),
                    **(record or {}),
                },
                indent=2,
            ),
        )

    log_path = run_dir / "train.mcap"
    old, kept, contents = [], None, None
    if not primary:
        log = _NoLog()
    elif resume and log_path.exists():
        log, kept, old, contents = _reopen_log(run_dir, log_path, stream)
    else:
        log = McapLog(log_path, profile="quadson_mjx.train")
    have_meta = {m.name: dict(m.metadata) for m in contents.metadata} if contents else {}
    for name, data in (
        ("env_config", {"json": to_json(env_cfg)}),
        ("ppo_config", {"json": to_json(ppo_cfg)}),
    ):
        if name not in have_meta:
            log.metadata(name, data)
    if have_meta.get("versions") != {k: str(v) for k, v in vers.items()}:
        log.metadata(
            "versions" if "versions" not in have_meta else f"versions_resume_step_{start_step}", vers
        )
    xml_name = f"{env.robot.name}.xml"
    if not (contents and any(a.name == xml_name for a in contents.attachments)):
        log.attachment(
            xml_name,
            scene_xml_text(env.robot, env_cfg).encode(),
            "application/xml",
        )
    event = {"event": "resume" if resume else "start", "step": start_step}
    if origin and not resume:
        event["init_from"] = json.dumps(origin)
    if resume:
        event.update(restored=restored, kept_log=kept.name if kept else "", copied_messages=len(old))
        if contents is not None and contents.damaged:
            event["damaged_records"] = "; ".join(contents.damaged)[:2000]
    log.log("/train/log", event, time.time_ns())
    live["log"] = log  # from here on, a second signal closes it (see emergency)
    logged_steps = {m["progress"]["step"] for t, _, m in old if t == "/train/metrics" and "progress" in m}

    progress = Progress(total_steps=ppo_cfg.num_timesteps, start_step=start_step, stream=stream)
    compilations = XlaCompilations()
    last_metrics: dict = {}
    # brax counts steps from its TrainingState: restored (global) when the state file was, else
    # from 0 in this session; its calls before the first epoch pass step 0.
    offset = 0 if state.restore_training_state is not None else start_step
    state.checkpoint = stop.check
    saved = {"step": None, "epochs": -1}

    def global_step(step) -> int:
        return start_step if int(step) == 0 else int(step) + offset

    def progress_fn(step, metrics):
        step = global_step(step)
        # without evaluations brax hands the training epoch's metrics: its losses, no episodes
        key, label = (
            ("eval/episode_reward", "eval reward") if ppo_cfg.run_evals else ("training/total_loss", "loss")
        )
        value = metrics.get(key)
        extra = progress.update(step, None if value is None else float(value), label)
        record = {
            **{k: float(v) for k, v in metrics.items()},
            **{f"progress/{k}": v for k, v in extra.items()},
        }
        record["progress/step"] = step
        record["progress/xla_compiles"] = compilations.count
        record["progress/xla_compile_s"] = compilations.seconds
        record["progress/xla_cache_hits"] = compilations.cache_hits
        if env.tiles is not None and state.latest is not None and jax.process_count() == 1:
            info = state.latest[1].info  # the training robots' curriculum after the last epoch
            summary = terrain_tiles.curriculum_summary(
                env.tiles, info["tile_type"], info["tile_level"], info["tile_result"]
            )
            record.update({f"curriculum/{k}": v for k, v in summary.items()})
            print(terrain_tiles.curriculum_line(env.tiles, summary), file=stream)
        length = record.get("eval/avg_episode_length")
        if length:  # brax sums per-step metrics over an episode; per-step means are what one reads
            for name in ("forward_speed", "abs_roll", "abs_pitch", "ik_invalid_legs", "nan_reset", "vx_sq_err", "vy_sq_err", "yaw_rate_sq_err", "base_height", "base_below_terrain", "fall", "off_field", "tilt", "standing", "legs_overlap", "chain_guarded_legs", "max_motor_speed"):  # fmt: skip
                if f"eval/episode_{name}" in record:
                    record[f"eval/mean_{name}"] = record[f"eval/episode_{name}"] / length
        if "eval/episode_success" in record:  # the get-up task: the share of drops stood up in time
            print(
                f"  getup: success {record['eval/episode_success']:.1%} of the evaluation drops", file=stream
            )
        if step not in logged_steps:  # a resumed run re-evaluates its checkpoint: logged already
            with log_lock:
                log.log("/train/metrics", _nest(record), time.time_ns())
            logged_steps.add(step)
        bad = guards.non_finite_metrics(metrics)
        if bad:
            raise guards.diverged(_where(step), bad, last_good())
        last_metrics.clear()
        last_metrics.update(record)
        if on_eval is not None:
            on_eval(step, record)
        stop.check()

    def _where(step: int) -> str:
        evaluation = first_epoch + state.epochs_done
        return f"evaluation {evaluation} of {epochs} (after training epoch {evaluation}, step {step:,})"

    def last_good() -> str:
        return f"step {saved['step']:,}" if saved["step"] is not None else "none yet"

    def policy_params_fn(step, make_policy, params):
        if not primary:  # brax calls it at step 0 in every process
            return
        step = global_step(step)
        if state.latest is not None:  # after an epoch: the whole training state too
            leaves = state.training_state_leaves()  # params, normaliser, Adam's moments (gradients)
            bad = guards.non_finite(leaves) or guards.non_finite(params)
            if bad:
                names = guards.non_finite(state.latest[0]) or bad
                raise guards.diverged(_where(step), [f"training state {n}" for n in names], last_good())
            _save_npz(training_state_path(run_dir, step), leaves, step)
        elif step > start_step:
            raise RuntimeError(
                "compat.brax_training_state did not find brax's training epoch (brax changed?)"
            )
        if not (state.epochs_done == 0 and ckpt is not None):  # a resumed checkpoint exists already
            save_checkpoint(run_dir, step, params)
        saved.update(step=step, epochs=state.epochs_done)
        live["step"] = step
        stop.check()

    remaining_epochs = epochs - first_epoch
    episode_length = ppo_cfg.episode_length or env.episode_length
    randomize = randomization_fn(env_cfg.randomization, env.base_body) if env_cfg.randomize else None
    multi_device = (
        compat.brax_multi_device(devices)
        if ppo_cfg.multi_device == "sharded_jit"
        else contextlib.nullcontext()
    )
    try:
        with (
            multi_device,
            compat.brax_multi_process(ppo_cfg.seed, ppo_cfg.num_envs, devices),
            compat.brax_without_evaluator() if not ppo_cfg.run_evals else contextlib.nullcontext(),
            compat.brax_evaluator_compiles_once(),
            compat.brax_training_state(state, eval_offset=first_epoch if ppo_cfg.num_evals > 1 else 0),
            compilations,
        ):
            stop.check()
            make_policy, params, _ = ppo.train(
                environment=env,
                eval_env=eval_env,
                wrap_env_fn=wrap_for_training,
                randomization_fn=randomize,
                num_timesteps=remaining_epochs * per_epoch,
                num_evals=remaining_epochs + 1 if ppo_cfg.num_evals > 1 else 1,
                num_envs=ppo_cfg.num_envs,
                num_eval_envs=ppo_cfg.num_eval_envs,
                episode_length=episode_length,
                unroll_length=ppo_cfg.unroll_length,
                batch_size=ppo_cfg.batch_size,
                num_minibatches=ppo_cfg.num_minibatches,
                num_updates_per_batch=ppo_cfg.num_updates_per_batch,
                learning_rate=ppo_cfg.learning_rate,
                learning_rate_schedule=LEARNING_RATE_SCHEDULES[ppo_cfg.learning_rate_schedule],
                desired_kl=ppo_cfg.desired_kl,
                learning_rate_schedule_min_lr=ppo_cfg.learning_rate_range[0],
                learning_rate_schedule_max_lr=ppo_cfg.learning_rate_range[1],
                entropy_cost=ppo_cfg.entropy_cost,
                discounting=ppo_cfg.discounting,
                gae_lambda=ppo_cfg.gae_lambda,
                clipping_epsilon=ppo_cfg.clipping_epsilon,
                max_grad_norm=ppo_cfg.max_grad_norm,
                reward_scaling=ppo_cfg.reward_scaling,
                normalize_observations=ppo_cfg.normalize_observations,
                network_factory=lambda obs, act, preprocess_observations_fn: make_networks(obs, act, ppo_cfg),
                seed=ppo_cfg.seed,
                progress_fn=progress_fn,
                policy_params_fn=policy_params_fn,
                restore_params=restore,
                max_devices_per_host=ppo_cfg.max_devices or None,
                deterministic_eval=ppo_cfg.deterministic_eval,
                run_evals=ppo_cfg.run_evals,
            )
    except KeyboardInterrupt as e:
        if not isinstance(e, compat.ProcessesStopped):  # the others stop at their next meeting
            compat.processes_stop(str(e) or type(e).__name__)
        event = {"event": "interrupted", "step": saved["step"] if saved["step"] is not None else start_step}
        if state.latest is not None and saved["epochs"] == state.epochs_done and jax.process_count() == 1:
            # stopped between epochs: the environments' states make the resume exact
            _save_npz(env_state_path(run_dir, saved["step"]), state.env_state_leaves(), saved["step"])
            event["env_state"] = env_state_path(run_dir, saved["step"]).name
        event["reason"] = str(e) or type(e).__name__
        with log_lock:
            log.log("/train/log", event, time.time_ns())
            log.close()
            live["log"] = None
        raise
    except BaseException as e:  # any other failure: the log still gets its summary and says why
        compat.processes_stop(f"{type(e).__name__}: {e}")
        event = f"failed: {type(e).__name__}: {e}"[:500]
        with log_lock:
            log.log("/train/log", {"event": event, "step": saved["step"] or start_step}, time.time_ns())
            log.close()
            live["log"] = None
        if guards.is_out_of_memory(e):
            raise guards.out_of_memory(ppo_cfg, e) from None
        raise
    print(compilations.summary(), file=stream, flush=True)
    # brax hands the final parameters to policy_params_fn at its last evaluation: already saved.
    final_step = progress.last[1] if progress.last else ppo_cfg.num_timesteps
    with log_lock:
        log.log("/train/log", {"event": "finished", "step": final_step}, time.time_ns())
        log.close()
        live["log"] = None
    return make_policy, params, last_metrics


class _NoLog:
    """The log of a process other than 0: it writes nothing (process 0's log has the run)."""

    def log(self, *args, **kwargs) -> None:
        pass

    metadata = attachment = close = log


def _nest(record: dict) -> dict:
    from quadson_mjx.mcap_log import nest_metrics

    return nest_metrics(record)
