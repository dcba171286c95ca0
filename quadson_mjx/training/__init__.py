"""Brax PPO training of foot-offset policies (the run directory it writes: loop.py). Modules by reason
to change: presets (PPO hyperparameters), networks, checkpoints (files under run_dir/checkpoints),
runs (a run directory's configs, lock, resume point, log, policy), monitor (progress, XLA
compilations, signals), guards (divergence, memory, backend), widen (a checkpoint into a longer
observation history, for --init-from), loop (`train`), precompile (a fine-tune's programs compiled
in a process of their own while the run before it trains). This face only
re-exports them: `training.train(...)`, `training.ppo_config(...)`."""

# ruff: noqa: F401 (every import here is a re-export)
from quadson_mjx.provenance import versions
from quadson_mjx.training.checkpoints import (
    CHECKPOINT_DIR,
    CheckpointDamaged,
    _load_npz,
    checkpoint_sha256,
    checksum_path,
    env_state_path,
    latest_checkpoint,
    list_checkpoints,
    load_checkpoint,
    newest_good_checkpoint,
    save_checkpoint,
    training_state_path,
    verify_checkpoint,
)
from quadson_mjx.training.guards import OutOfMemory, TrainingDiverged
from quadson_mjx.training.loop import KEPT_RECORDS, train
from quadson_mjx.training.monitor import (
    Progress,
    SignalStop,
    StopRequested,
    XlaCompilations,
    enable_compilation_cache,
)
from quadson_mjx.training.networks import make_networks, params_template
from quadson_mjx.training.precompile import Compiled, Precompile, compile_only
from quadson_mjx.training.presets import (
    POLICY_DISTRIBUTIONS,
    PPO_KEYS_ADDED,
    PPO_RULES,
    PRESETS,
    check_ppo_config,
    epoch_steps,
    local_devices_to_use,
    main_job_env,
    ppo_config,
)
from quadson_mjx.training.runs import (
    RunDirInUse,
    check_new_run_dir,
    check_writable_dir,
    init_point,
    load_policy,
    load_run_config,
    lock_holder,
    resume_point,
    run_dir_lock,
)
