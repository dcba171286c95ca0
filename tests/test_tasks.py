"""The task registry (quadson_mjx.tasks) and the train command's --task: names, messages, and the same
config whichever way a task is spelled. No MJX compile: configs only (train's main with a fake train)."""

import itertools
import json
import signal
from pathlib import Path

import pytest

from quadson_mjx import tasks, training
from quadson_mjx.cli import train as train_cli
from quadson_mjx.config import apply_overrides, to_json
from quadson_mjx.env_config import check_env_config, env_config, with_added_keys

ROOT = Path(__file__).resolve().parents[1]

# The names, written out (the registry derives them from robot x preset x terrain and the recipes).
NAMES = [
    "QuadsonFlat", "QuadsonRough", "QuadsonCommandFlat", "QuadsonCommandRough",
    "QuadsonJoystickFlat", "QuadsonJoystickRough",
    "QuadsonJoystickTrueStateFlat", "QuadsonJoystickTrueStateRough",
    "QuadsonGetupFlat", "QuadsonGetupRough",
    "CaramelFlat", "CaramelRough", "CaramelCommandFlat", "CaramelCommandRough",
    "CaramelJoystickFlat", "CaramelJoystickRough",
    "CaramelJoystickTrueStateFlat", "CaramelJoystickTrueStateRough",
    "QuadsonJoystickTiles",
    "QuadsonGaitWalk", "QuadsonGaitTrot", "QuadsonGaitPace", "QuadsonGaitBound", "QuadsonGaitGallop",
]  # fmt: skip

# train/ppo_mjx.py's presets and its config construction before the registry (commit e0e1084),
# copied: the reference the registry and the new flag path must reproduce.
OLD_FAST_PHYSICS = {"base_terrain_contact": False, "joint_limits": False}
OLD_ENV_PRESETS = {
    "seed": {**OLD_FAST_PHYSICS},
    "command": {**OLD_FAST_PHYSICS, "command_tracking": True},
    "robust_true_state": {**OLD_FAST_PHYSICS, "joystick": True, "randomize": True, "pushes": True},
}
# since then: the robust preset's actor observes the robot's sensors, its critic the privileged state
OLD_ENV_PRESETS["robust"] = {
    **OLD_ENV_PRESETS["robust_true_state"],
    "observation": "sensors",
    "asymmetric_critic": True,
}
# the get-up task (Quadson only): its own environment, randomized, joint-limit rows off
OLD_ENV_PRESETS["getup"] = {"joint_limits": False, "randomize": True, "task": "getup"}


# since then: the walking presets on rough ground make one contact a foot on the height field
NEW_HFIELD_CONTACTS = {"hfield_foot_contacts": 1}


def old_script_config(robot, env_preset, terrain, gait, gait_action):
    recipe = {"gait": gait, "gait_recipe": True} if gait else {}
    env_cfg = env_config(terrain=terrain, robot=robot, **OLD_ENV_PRESETS[env_preset], **recipe)
    if terrain != "flat" and env_preset != "getup":
        env_cfg.update(NEW_HFIELD_CONTACTS)
    env_cfg.gait_action = gait_action
    return env_cfg


# Committed run directories -> (task, overrides): the saved env config (keys added since, with
# their old values) is the task's config with these overrides.
BOUND_WIDE = ["randomization.mass_scale=0.85,1.25", "randomization.base_com_shift_m=-0.02,0.03"]
BOUND_WEIGHTS = ["reward.weights.contact_pattern=8.0", "reward.weights.forward_velocity_exp=2.0"]
BOUND_SWING = [*BOUND_WIDE, "reward.weights.contact_pattern=8.0", "reward.weights.forward_velocity_exp=3.0",
               "reward.weights.swing_touch=-2.0"]  # fmt: skip


def _replacing(base: list[str], *extra: str) -> list[str]:
    """base's overrides with those of `extra`'s keys replaced by extra."""
    keys = {e.partition("=")[0] for e in extra}
    return [o for o in base if o.partition("=")[0] not in keys] + list(extra)


BOUND_PUSH = _replacing(BOUND_SWING, "pushes=true", "randomization.base_com_shift_m=-0.02,0.04")
BOUND_IT4 = _replacing(
    BOUND_PUSH,
    "solver_iterations=4",
    "randomization.motor_strength=0.7,1.3",
    "randomization.mass_scale=0.8,1.3",
    "randomization.latency_s=0.0,0.03",
)
BOUND_FRIC = _replacing(
    BOUND_IT4, "reward.weights.forward_velocity_exp=5.0", "randomization.friction=0.5,1.3", "sim_dt=0.002"
)
BOUND_FAST = _replacing(BOUND_FRIC, "reward.target_gait_speed=false", "reward.forward_target=0.55")
# the sensor-only joystick recipe with the yaw error, both tracking kernels at 0.15 and a trot cycle
# of 0.48 s (0.6 of the gait table's 0.8 s), trained on MJX's Warp implementation
C048 = [
    "obs_history=3",
    "yaw_error_tau_s=0.5",
    "reward.weights.ang_vel_tracking_exp=1.0",
    "reward.tracking_sigma=0.15",
    "impl=warp",
    "gait_scale.cycle_s=0.6",
]
# the same on MJX's JAX implementation with the walking presets' one contact a foot on the height field
C048_HFC1 = [*(k for k in C048 if k != "impl=warp"), "hfield_foot_contacts=1"]
# the tiles policy's fine-tunes up to the 7 cm step height (results/tiles_swing_h200)
TILES_SWING = [
    "reward.tracking_sigma=0.15",
    "reward.orientation_coeffs=(40.0, 5.0, 0.0)",
    "tiles.type_weights=slope_up:3,stairs_up:3,stairs_down:2",
    "gait_scale.step_height_m=1.4",
]
# and fine-tuned from it for a calibrated IMU with its robots starting at levels 6-9
TILES_SWING_CAL6 = [
    *TILES_SWING,
    "sensor.imu_tilt_rad=0.01",
    "tiles.min_init_level=6",
    "tiles.max_init_level=9",
]
# and that at a 2 ms physics step with the critic's ground scan (results/tiles_dt2_h200)
TILES_SWING_DT2 = [*TILES_SWING_CAL6, "sim_dt=0.002", "critic_scan_points=9"]
COMMITTED_RUNS = {
    # trained before the robust recipe observed the robot's sensors: its true_state twin
    "results/policy_h100_joystick": ("QuadsonJoystickTrueStateRough", []),
    # the robust recipe with 3 ticks of sensor history
    "results/policy_h100_sensors": ("QuadsonJoystickRough", ["obs_history=3"]),
    # the same recipe on MJX's Warp implementation
    "results/policy_h100_sensors_warp": ("QuadsonJoystickRough", ["obs_history=3", "impl=warp"]),
    # the main job with its own PPO settings (training.presets.MAIN_JOB)
    "results/policy_h100_main": ("QuadsonFlat", []),
    # the main job with a 10-step unroll and 18M steps (MAIN_JOB now)
    "results/policy_h100_main_unroll10": ("QuadsonFlat", []),
    # the main job as it runs now: on MJX's Warp implementation (training.presets.main_job_env)
    "results/policy_h100_main_warp": ("QuadsonFlat", ["impl=warp"]),
    # and on the light five-bar model (env.fivebar_model=light)
    "results/policy_h100_main_warp_light": ("QuadsonFlat", ["impl=warp", "fivebar_model=light"]),
    # and the yaw error in the actor's observation, yaw-rate tracking weighed twice
    "results/policy_h200_sensors_yaw": (
        "QuadsonJoystickRough",
        ["obs_history=3", "yaw_error_tau_s=0.5", "reward.weights.ang_vel_tracking_exp=1.0"],
    ),
    # and both tracking kernels at 0.15 (m/s and rad/s)
    "results/policy_h200_sensors_s015": (
        "QuadsonJoystickRough",
        [
            "obs_history=3",
            "yaw_error_tau_s=0.5",
            "reward.weights.ang_vel_tracking_exp=1.0",
            "reward.tracking_sigma=0.15",
        ],
    ),
    # and a trot cycle of 0.48 s (0.6 of the gait table's 0.8 s), trained on MJX's Warp implementation
    "results/policy_h200_sensors_c048": ("QuadsonJoystickRough", C048),
    # that run continued for 280M more steps with its configs (--init-from, 560M in all)
    "results/policy_h200_sensors_c048_560m": ("QuadsonJoystickRough", C048),
    # and that fine-tuned for 60M steps at a 2 ms physics step on MJX's JAX implementation
    "results/policy_h200_sensors_dt2": (
        "QuadsonJoystickRough",
        [*(k for k in C048 if k != "impl=warp"), "sim_dt=0.002"],
    ),
    # and the same fine-tune at half the learning rate (3e-4): the policy for the robot
    "results/policy_h200_sensors_dt2_lr3": (
        "QuadsonJoystickRough",
        [*(k for k in C048 if k != "impl=warp"), "sim_dt=0.002"],
    ),
    # the 0.48 s trot recipe on JAX with one contact a foot, 16384 robots and a 10-step unroll
    "results/policy_h200_sensors_e16u10": ("QuadsonJoystickRough", C048_HFC1),
    # and that fine-tuned for 80M steps at a 2 ms physics step
    "results/policy_h200_sensors_e16u10_dt2": ("QuadsonJoystickRough", [*C048_HFC1, "sim_dt=0.002"]),
    # and the same fine-tune at half the learning rate (3e-4)
    "results/policy_h200_sensors_e16u10_dt2_lr3": ("QuadsonJoystickRough", [*C048_HFC1, "sim_dt=0.002"]),
    # the one-command chain: e16u10 re-run without evaluations, then 48M steps at 2.5 ms with the
    # yaw-rate term doubled (its first stage's checkpoint is not kept: SOURCE_NOT_KEPT)
    "results/policy_h200_sensors_e16u10/comparison/chain_yaw2_dt25_48m/finetune": (
        "QuadsonJoystickRough",
        [*C048_HFC1, "sim_dt=0.0025", "reward.weights.ang_vel_tracking_exp=2.0"],
    ),
    # two more first stages of that chain (seeds 1 and 2, no evaluations), kept as starting points
    # for fine-tune experiments: their sweeps' yaw rates (0.193, 0.202) are the chain's worst seen
    "results/policy_h200_sensors_e16u10/comparison/chain_yaw2ent_dt25_48m_seed1": (
        "QuadsonJoystickRough",
        C048_HFC1,
    ),
    "results/policy_h200_sensors_e16u10/comparison/chain_yaw2ent_dt25_48m_seed2": (
        "QuadsonJoystickRough",
        C048_HFC1,
    ),
    # the chain with its first stage at a 5 ms physics step and a 64M-step fine-tune (seeds 3 and 4):
    # both stages kept, the fine-tunes for the sim-to-sim runs
    **{
        f"results/policy_h200_sensors_e16u10/comparison/chain_s1dt5_315m_ft64m_seed{s}{ft}": (
            "QuadsonJoystickRough",
            [*C048_HFC1, "sim_dt=0.0025", "reward.weights.ang_vel_tracking_exp=2.0"]
            if ft
            else [*C048_HFC1, "sim_dt=0.005"],
        )
        for s in (3, 4)
        for ft in ("", "/finetune")
    },
    # the chain with its first stage at a 6.67 ms physics step (three a control step): 315M steps
    # (seed 0; its 229M and 258M checkpoints kept, each fine-tuned too) and 229M steps (seed 1)
    **{
        f"results/policy_h200_sensors_e16u10/comparison/chain_s1dt667_{run}{ft}": (
            "QuadsonJoystickRough",
            [*C048_HFC1, "sim_dt=0.0025", "reward.weights.ang_vel_tracking_exp=2.0"]
            if ft
            else [*C048_HFC1, "sim_dt=0.006666666666666667"],
        )
        for run, fts in (
            ("315m", ("", "/finetune", "/ft_from_229m", "/ft_from_258m")),
            ("229m_seed1", ("", "/finetune")),
        )
        for ft in fts
    },
    # the robust recipe on the tiled ground with its curriculum
    "results/tiles_h100": ("QuadsonJoystickTiles", []),
    # and two fine-tunes (--init-from): a narrower tracking kernel, then a lighter pitch term
    "results/tiles_s015_h200": ("QuadsonJoystickTiles", ["reward.tracking_sigma=0.15"]),
    "results/tiles_pitch_h100": (
        "QuadsonJoystickTiles",
        ["reward.tracking_sigma=0.15", "reward.orientation_coeffs=(40.0, 5.0, 0.0)"],
    ),
    # and a third: three times the robots on slopes and stairs up, twice on stairs down
    "results/tiles_up_h100": (
        "QuadsonJoystickTiles",
        [
            "reward.tracking_sigma=0.15",
            "reward.orientation_coeffs=(40.0, 5.0, 0.0)",
            "tiles.type_weights=slope_up:3,stairs_up:3,stairs_down:2",
        ],
    ),
    # and a fourth: the gait's swing 1.4 times higher (7 cm)
    "results/tiles_swing_h200": ("QuadsonJoystickTiles", TILES_SWING),
    # and that fine-tuned with a 0.48 s trot on MJX's Warp implementation (not kept; its checkpoint
    # for the analyses of docs/results.md)
    "results/tiles_swing_h200/comparison/tiles_c060_warp": (
        "QuadsonJoystickTiles",
        [*TILES_SWING, "gait_scale.cycle_s=0.6", "impl=warp"],
    ),
    # and fine-tuned for a calibrated IMU with its robots starting at levels 6-9 (not kept; its
    # checkpoint for finetune_rewards.py)
    "results/tiles_swing_h200/comparison/tiles_min6_cal_h200": ("QuadsonJoystickTiles", TILES_SWING_CAL6),
    # and the same at a 2 ms physics step, with the critic's 9 x 9 ground scan and a quarter of the
    # learning rate: the tiles policy trained at 2 ms
    "results/tiles_dt2_h200": ("QuadsonJoystickTiles", TILES_SWING_DT2),
    # and that fine-tuned with the narrower tracking kernel (0.10)
    "results/tiles_dt2_h200/comparison/tiles_dt2_s010_h200": (
        "QuadsonJoystickTiles",
        [*TILES_SWING_DT2, "reward.tracking_sigma=0.1"],
    ),
    # and that fine-tuned with one contact a foot on the height field (hfield_contact)
    "results/tiles_dt2_hfc1_h200": ("QuadsonJoystickTiles", [*TILES_SWING_DT2, "hfield_foot_contacts=1"]),
    # and that fine-tuned with the gait's two actions (step length and frequency scales), then 90M
    # steps more
    "results/tiles_ga_h200": (
        "QuadsonJoystickTiles",
        [*TILES_SWING_DT2, "hfield_foot_contacts=1", "gait_action=true"],
    ),
    "results/tiles_ga_more_h200": (
        "QuadsonJoystickTiles",
        [*TILES_SWING_DT2, "hfield_foot_contacts=1", "gait_action=true"],
    ),
    # and that fine-tuned with the gait's stride 15 % longer
    "results/tiles_stride115_h200": (
        "QuadsonJoystickTiles",
        [*TILES_SWING_DT2, "hfield_foot_contacts=1", "gait_action=true", "gait_scale.step_length_m=1.15"],
    ),
    # trained before the toppled starts
    "results/getup_h100": ("QuadsonGetupFlat", ["getup.topple_prob=0.0"]),
    "results/getup_topple_h100": ("QuadsonGetupFlat", []),
    # trained on one side
    "results/getup_mirror_h100": ("QuadsonGetupFlat", ["getup.mirror_to=left"]),
    # and 40M steps more (--init-from)
    "results/getup_mirror_ft_h200": ("QuadsonGetupFlat", ["getup.mirror_to=left"]),
    # trained on one side on MJX's Warp implementation, 300M steps from scratch (one H100; one H200)
    "results/getup_warp_h100": ("QuadsonGetupFlat", ["getup.mirror_to=left", "impl=warp"]),
    "results/getup_warp_h200": ("QuadsonGetupFlat", ["getup.mirror_to=left", "impl=warp"]),
    "results/gaits/walk": ("QuadsonGaitWalk", []),
    "results/gaits/trot": ("QuadsonGaitTrot", []),
    # fine-tuned (--init-from) from before_finetune/pace under a wider randomization
    "results/gaits/pace": (
        "QuadsonGaitPace",
        [
            "randomization.mass_scale=0.85,1.25",
            "randomization.base_com_shift_m=-0.03,0.03",
            "randomization.motor_strength=0.7,1.2",
        ],
    ),
    "results/gaits/before_finetune/pace": ("QuadsonGaitPace", []),
    # fine-tuned in five steps (--init-from): wider mass and CoM ranges (finetune/bound_wide),
    # more steps (finetune/bound_wide_more), the pattern and forward terms doubled
    # (finetune/bound_pat8_fwd2), a penalty on feet touching in swing with the forward term at 3
    # (finetune/bound_swing_touch), more steps (bound)
    "results/gaits/bound": ("QuadsonGaitBound", BOUND_SWING),
    "results/gaits/finetune/bound_swing_touch": ("QuadsonGaitBound", BOUND_SWING),
    "results/gaits/finetune/bound_pat8_fwd2": ("QuadsonGaitBound", [*BOUND_WIDE, *BOUND_WEIGHTS]),
    "results/gaits/finetune/bound_wide": ("QuadsonGaitBound", BOUND_WIDE),
    "results/gaits/finetune/bound_wide_more": ("QuadsonGaitBound", BOUND_WIDE),
    "results/gaits/before_finetune/bound": ("QuadsonGaitBound", []),
    "results/gaits/gallop": ("QuadsonGaitGallop", []),
    # fine-tuned from results/gaits/bound for MuJoCo C (results/gaits/transfer/README.md): pushes,
    # a CoM range to +4 cm, the solver's iterations; then from it4_push_wide_com4 (more, bound),
    # and from bound with a 2 ms physics step (bound_2ms; from it bound_2ms_more and bound_2ms_fric; from bound_2ms_more bound_2ms_pat)
    "results/gaits/transfer/push_com4": ("QuadsonGaitBound", BOUND_PUSH),
    "results/gaits/transfer/it2_push_com4": ("QuadsonGaitBound", [*BOUND_PUSH, "solver_iterations=2"]),
    "results/gaits/transfer/it4_push_wide_com4": ("QuadsonGaitBound", BOUND_IT4),
    "results/gaits/transfer/more": ("QuadsonGaitBound", BOUND_IT4),
    "results/gaits/transfer/bound_2ms": (
        "QuadsonGaitBound",
        _replacing(BOUND_IT4, "reward.weights.forward_velocity_exp=4.0", "sim_dt=0.002"),
    ),
    "results/gaits/transfer/bound_2ms_more": (
        "QuadsonGaitBound",
        _replacing(BOUND_IT4, "reward.weights.forward_velocity_exp=4.0", "sim_dt=0.002"),
    ),
    "results/gaits/transfer/bound": (
        "QuadsonGaitBound",
        _replacing(BOUND_IT4, "reward.weights.forward_velocity_exp=4.0"),
    ),
    # from bound_2ms with the forward term at 5 and sticky ground (friction to 1.3)
    "results/gaits/transfer/bound_2ms_fric": ("QuadsonGaitBound", BOUND_FRIC),
    # from bound_2ms_more with the forward and pattern terms raised
    "results/gaits/transfer/bound_2ms_pat": (
        "QuadsonGaitBound",
        _replacing(
            BOUND_IT4,
            "reward.weights.forward_velocity_exp=6.0",
            "reward.weights.contact_pattern=10.0",
            "sim_dt=0.002",
        ),
    ),
    # from bound_2ms_fric with the forward kernel centred at 0.55 m/s (bound_2ms_t55), on from it
    # (bound_2ms_fast), and from that with feet touching in swing charged 3 times more
    "results/gaits/transfer/bound_2ms_t55": ("QuadsonGaitBound", BOUND_FAST),
    "results/gaits/transfer/bound_2ms_fast": ("QuadsonGaitBound", BOUND_FAST),
    "results/gaits/transfer/bound_2ms_swing": (
        "QuadsonGaitBound",
        _replacing(BOUND_FAST, "reward.weights.swing_touch=-6.0"),
    ),
    # trials of a fall penalty (not kept as the gaits' policies)
    "results/gaits/trials_termination/t_pace": ("QuadsonGaitPace", ["reward.weights.termination=-100"]),
    "results/gaits/trials_termination/ts_bound": (
        "QuadsonGaitBound",
        ["reward.weights.termination=-100", "reward.forward_sigma=0.15"],
    ),
    "results/gaits/trials_termination/t3s_bound": (
        "QuadsonGaitBound",
        ["reward.weights.termination=-300", "reward.forward_sigma=0.15"],
    ),
    # trained with --robot caramel --env-preset command --terrain rough --env.randomize=true
    "results/caramel/policy": ("CaramelCommandRough", ["randomize=true"]),
    # trained before the training physics (FAST_PHYSICS): the base box touched the ground and the
    # motor joints had limit rows
    "results/policy_h200_seed": ("QuadsonFlat", ["base_terrain_contact=true", "joint_limits=true"]),
}

# Every committed run on rough ground but those that say otherwise trained with MJX's own
# height-field collider (4 contacts a foot): they predate the walking presets' one contact.
for _run, (_task, _over) in COMMITTED_RUNS.items():
    if tasks.make_task_config(_task).hfield_foot_contacts == 1 and not any(
        o.startswith("hfield_foot_contacts=") for o in _over
    ):
        COMMITTED_RUNS[_run] = (_task, [*_over, "hfield_foot_contacts=4"])


def test_registry_names():
    assert tasks.task_names() == NAMES
    assert list(tasks.TASKS) == list(tasks.TASK_FLAGS) == NAMES


@pytest.mark.parametrize("name", NAMES)
def test_every_task_is_a_locked_valid_config(name):
    cfg = tasks.make_task_config(name)
    assert cfg.is_locked
    check_env_config(cfg)
    # the training physics: no motor limit rows, and the base box off the ground's contacts except
    # for get-up, whose robot lands on its back and sides
    assert cfg.joint_limits is False
    assert cfg.base_terrain_contact is ("Getup" in name)
    # one contact a foot on a height field, for the walking tasks (the get-up robot lands on all of it)
    assert cfg.hfield_foot_contacts == (1 if cfg.terrain != "flat" and "Getup" not in name else 4)
    assert cfg.robot == name[:7].lower()
    assert cfg.terrain in name.lower() or "Gait" in name
    with pytest.raises(AttributeError):
        cfg.new_key = 1
    assert tasks.find_task(cfg) == name


def test_task_contents_by_hand():
    joystick = tasks.make_task_config("QuadsonJoystickRough")
    assert (
        joystick.terrain == "rough" and joystick.command_tracking and joystick.randomize and joystick.pushes
    )
    assert joystick.command_resample_s == (4.0, 8.0) and joystick.termination.base_below_terrain
    assert joystick.observation == "sensors" and joystick.asymmetric_critic
    true_state = tasks.make_task_config("QuadsonJoystickTrueStateRough")
    assert true_state.observation == "true_state" and not true_state.asymmetric_critic
    bound = tasks.make_task_config("QuadsonGaitBound")
    assert bound.gait == "bound" and bound.randomize and bound.reward.target_gait_speed
    assert bound.terrain == "flat" and not bound.command_tracking
    getup = tasks.make_task_config("QuadsonGetupRough")
    assert getup.task == "getup" and getup.terrain == "rough" and getup.randomize and not getup.pushes
    assert getup.observation == "sensors" and getup.asymmetric_critic and getup.base_terrain_contact
    assert getup.episode_length_s == 6.0  # the 5 s to stand and the 1 s hold
    caramel = tasks.make_task_config("CaramelCommandRough")
    assert caramel.robot == "caramel" and caramel.command_tracking and not caramel.randomize


@pytest.mark.parametrize(
    "name, close",
    [
        ("QuadsonJoystikRough", "QuadsonJoystickRough"),
        ("quadsonflat", "QuadsonFlat"),
        ("GaitBound", "QuadsonGaitBound"),
    ],
)
def test_unknown_task_names_the_closest(name, close):
    with pytest.raises(ValueError, match=f"unknown task '{name}'; did you mean .*{close}"):
        tasks.make_task_config(name)


def test_unknown_task_far_from_any_lists_them_all():
    with pytest.raises(ValueError, match="choose from QuadsonFlat, .*QuadsonGaitGallop"):
        tasks.make_task_config("xyz")


COMBINATIONS = list(
    itertools.product(
        ("quadson", "caramel"), ("seed", "command", "robust"), ("flat", "rough"),
        (None, "walk", "trot", "pace", "bound", "gallop"), (False, True),
    )
)  # fmt: skip


@pytest.mark.parametrize("robot, env_preset, terrain, gait, gait_action", COMBINATIONS)
def test_flags_give_the_old_scripts_config(robot, env_preset, terrain, gait, gait_action):
    flags = dict(robot=robot, env_preset=env_preset, terrain=terrain, gait=gait, gait_action=gait_action)
    try:
        want = old_script_config(**flags)
    except ValueError as e:  # Caramel has no gait recipes: both refuse
        with pytest.raises(ValueError, match=str(e)[:30]):
            tasks.config_from_flags(**flags)
        return
    if robot == "caramel" and gait_action:  # checked where it is built; the old script refused it later
        with pytest.raises(ValueError, match="env.gait_action: caramel's gait cannot be scaled"):
            tasks.config_from_flags(**flags)
        return
    got = tasks.config_from_flags(**flags)
    assert to_json(got) == to_json(want) and got.is_locked


def _fake_train(monkeypatch):
    """train's main up to training.train: -> dict that receives the env config it would train."""
    seen = {}

    class Stop(Exception):
        pass

    def fake_train(env_cfg, ppo_cfg, run_dir, resume, init_from=None, stop=None, on_eval=None, record=None):
        assert init_from is None  # a new run from its task, not a fine-tune
        assert stop is None  # one process: train installs its own signal handlers
        assert on_eval is None and record is None  # no fine-tune asked for
        seen["env_cfg"] = env_cfg
        raise Stop

    monkeypatch.setattr(training, "train", fake_train)
    sigterm = signal.getsignal(signal.SIGTERM)

    def run(argv):
        try:
            with pytest.raises(Stop):
                train_cli.main([*argv, "--no-compile-cache", "--preset", "test"])
        finally:
            signal.signal(signal.SIGTERM, sigterm)
        return seen.pop("env_cfg")

    return run


@pytest.mark.parametrize("name", NAMES)
def test_train_task_and_flag_spellings_give_one_config(name, monkeypatch, tmp_path):
    run = _fake_train(monkeypatch)
    flags = tasks.TASK_FLAGS[name]
    argv = [a for k, v in flags.items() if v is not None for a in (f"--{k.replace('_', '-')}", v)]
    by_task = run(["--task", name, "--run-dir", str(tmp_path / "a")])
    by_flags = run([*argv, "--run-dir", str(tmp_path / "b")])
    assert to_json(by_task) == to_json(by_flags) == to_json(tasks.make_task_config(name))
    assert to_json(by_flags) == to_json(old_script_config(gait_action=False, **{"gait": None, **flags}))
    # Caramel's gait cannot be scaled, and the get-up task has no gait (check_env_config refuses)
    if flags["robot"] == "quadson" and flags["env_preset"] != "getup":
        with_action = run(["--task", name, "--gait-action", "--run-dir", str(tmp_path / "c")])
        assert to_json(with_action) == to_json(
            run(["--gait-action", *argv, "--run-dir", str(tmp_path / "d")])
        )
        assert with_action.gait_action is True


def test_main_job_alone_gets_the_main_job_ppo_settings(monkeypatch, tmp_path):
    """On the gpu preset, the main command (no flag, or --task QuadsonFlat) trains with MAIN_JOB's
    2048 environments, 10-step unroll and 18M steps, on MJX's Warp implementation (one device,
    warp-lang installed: the dev extra has it); every other task, --gait-action included, with the
    preset's, on JAX; an override still wins."""
    from quadson_mjx.training.presets import MAIN_JOB

    class Stop(Exception):
        pass

    seen = []

    def fake_train(env_cfg, ppo_cfg, run_dir, resume, init_from=None, stop=None, on_eval=None, record=None):
        seen.append((env_cfg, ppo_cfg))
        raise Stop

    monkeypatch.setattr(training, "train", fake_train)
    gpu = training.ppo_config("gpu")
    cases = [
        ([], True),
        (["--task", "QuadsonFlat"], True),
        (["--task", "QuadsonJoystickRough"], False),
        (["--gait-action"], False),
        (["--gait", "trot"], False),
        (["--robot", "caramel"], False),
        (["--ppo.num_timesteps=30000000"], True),
        (["--env.impl=jax"], True),
    ]
    for i, (argv, main) in enumerate(cases):
        sigterm = signal.getsignal(signal.SIGTERM)
        try:
            with pytest.raises(Stop):
                train_cli.main(
                    [*argv, "--preset", "gpu", "--no-compile-cache", "--run-dir", str(tmp_path / str(i))]
                )
        finally:
            signal.signal(signal.SIGTERM, sigterm)
        env_cfg, cfg = seen.pop()
        want = {k: (v if main else gpu[k]) for k, v in MAIN_JOB.items()}
        if argv[:1] == ["--ppo.num_timesteps=30000000"]:
            want["num_timesteps"] = 30_000_000
        assert {k: cfg[k] for k in MAIN_JOB} == want, argv
        assert env_cfg.impl == ("warp" if main and argv != ["--env.impl=jax"] else "jax"), argv
    assert training.ppo_config("cpu", True).to_dict() == training.ppo_config("cpu").to_dict()


def test_main_job_stays_on_jax_on_several_devices_or_without_warp(monkeypatch):
    """main_job_env: Warp on one device with warp-lang; JAX, said in one line, on two devices or
    when warp-lang cannot be imported."""
    from quadson_mjx import warp_notice

    flat = tasks.make_task_config("QuadsonFlat")
    cfg, line = training.main_job_env(flat, 1)
    assert cfg.impl == "warp" and flat.impl == "jax" and "Warp" in line
    cfg, line = training.main_job_env(flat, 2)
    assert cfg.impl == "jax" and "2 devices" in line

    def missing():
        raise ValueError("no warp")

    monkeypatch.setattr(warp_notice, "require_warp", missing)
    cfg, line = training.main_job_env(flat, 1)
    assert cfg.impl == "jax" and "warp-lang is not installed" in line and "\n" not in line


def test_train_defaults_are_quadson_flat(monkeypatch, tmp_path):
    cfg = _fake_train(monkeypatch)(["--run-dir", str(tmp_path / "run")])
    assert to_json(cfg) == to_json(tasks.make_task_config("QuadsonFlat"))


@pytest.mark.parametrize(
    "extra, named",
    [
        (["--robot", "quadson"], "--robot quadson"),
        (["--env-preset", "robust"], "--env-preset robust"),
        (["--terrain", "flat"], "--terrain flat"),
        (["--gait", "bound"], "--gait bound"),
    ],
)
def test_train_task_with_task_flags_is_one_line_and_exit_2(extra, named, monkeypatch, capsys):
    monkeypatch.setattr(training, "train", lambda *a, **k: pytest.fail("nothing may train"))
    assert train_cli.main(["--task", "QuadsonFlat", *extra, "--no-compile-cache"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--task QuadsonFlat" in err and named in err, err


def test_train_unknown_task_exits_2_naming_the_closest(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr(training, "train", lambda *a, **k: pytest.fail("nothing may train"))
    sigterm = signal.getsignal(signal.SIGTERM)
    try:
        rc = train_cli.main(
            ["--task", "QuadsonJoystikRough", "--no-compile-cache", "--run-dir", str(tmp_path)]
        )
    finally:
        signal.signal(signal.SIGTERM, sigterm)
    err = capsys.readouterr().err
    assert rc == 2 and "QuadsonJoystickRough" in err and err.count("\n") == 1, err


def test_train_resume_refuses_task(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr(training, "train", lambda *a, **k: pytest.fail("nothing may train"))
    sigterm = signal.getsignal(signal.SIGTERM)
    try:
        rc = train_cli.main(["--resume", str(tmp_path), "--task", "QuadsonFlat", "--no-compile-cache"])
    finally:
        signal.signal(signal.SIGTERM, sigterm)
    err = capsys.readouterr().err
    assert rc == 2 and "--task" in err and "--resume" in err


def test_list_tasks_prints_every_name_with_its_flags(capsys):
    assert train_cli.main(["--list-tasks"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == NAMES
    bound = lines[NAMES.index("QuadsonGaitBound")]
    assert bound.split()[1:] == "--robot quadson --env-preset seed --terrain flat --gait bound".split()


@pytest.mark.parametrize("run_dir", sorted(COMMITTED_RUNS))
def test_committed_run_configs_are_tasks(run_dir):
    task, overrides = COMMITTED_RUNS[run_dir]
    saved = json.loads((ROOT / run_dir / "config.json").read_text())["env"]
    want = apply_overrides(tasks.make_task_config(task), overrides)
    assert to_json(with_added_keys(saved)) == to_json(want)
    assert tasks.find_task(saved) == (None if overrides else task)
    env_cfg, _ = training.load_run_config(ROOT / run_dir)  # and it loads as a run
    assert to_json(with_added_keys(env_cfg)) == to_json(want)


# Fine-tunes whose source checkpoint was not kept (only the fine-tune's final checkpoint was copied
# off the training machine): the source's config (run_config.json) and logs are committed, and the
# fine-tune's config records the source checkpoint's SHA-256.
SOURCE_NOT_KEPT = {"results/policy_h200_sensors_e16u10/comparison/chain_yaw2_dt25_48m/finetune"}


def test_committed_fine_tunes_name_a_committed_checkpoint_by_its_hash():
    """A run made with --init-from records its source; the source checkpoint is committed and its
    bytes hash (hashlib, independent of the checkpoint code) to the recorded SHA-256."""
    import hashlib

    tuned = 0
    assert SOURCE_NOT_KEPT <= set(COMMITTED_RUNS)
    for run_dir in sorted(COMMITTED_RUNS):
        origin = json.loads((ROOT / run_dir / "config.json").read_text()).get("init_from")
        if origin is None:
            continue
        tuned += 1
        src = ROOT / origin["run"] / "checkpoints" / origin["checkpoint"]
        if run_dir in SOURCE_NOT_KEPT:  # the exemption covers a missing source, never a wrong one
            assert not src.exists() and (ROOT / origin["run"] / "run_config.json").is_file(), run_dir
            assert (
                len(origin["sha256"]) == 64 and origin["checkpoint"] == f"step_{origin['step']:012d}.msgpack"
            )
            continue
        assert origin["run"] in COMMITTED_RUNS and src.is_file(), (run_dir, origin)
        assert hashlib.sha256(src.read_bytes()).hexdigest() == origin["sha256"]
        assert origin["checkpoint"] == f"step_{origin['step']:012d}.msgpack"
    assert tuned >= 1


def test_every_committed_run_is_listed():
    found = {str(p.parent.relative_to(ROOT)) for p in ROOT.glob("results/**/config.json")}
    assert found == set(COMMITTED_RUNS)


# the recipe file of the sensor-only joystick policy inside ten minutes, and committed runs of it:
# as it is, and with its first stage at 6.67 ms and 229M steps (the fastest chain to the tracking
# targets, docs/results.md "A first stage at 6.67 ms")
RECIPE_10MIN = ROOT / "train/recipes/joystick_10min.args"
RECIPE_10MIN_RUN = ROOT / "results/policy_h200_sensors_e16u10/comparison/chain_s1dt5_315m_ft64m_seed4"
RECIPE_RUNS = {
    RECIPE_10MIN_RUN: (["--ppo.seed=4"], 0.005),
    RECIPE_10MIN_RUN.parent / "chain_s1dt667_229m_seed1": (
        [
            "--ppo.seed=1",
            "--env.sim_dt=0.006666666666666667",
            "--ppo.num_timesteps=229376000",
            "--ppo.num_evals=9",
        ],
        0.006666666666666667,
    ),
}


@pytest.mark.parametrize("run", sorted(RECIPE_RUNS), ids=lambda p: p.name)
def test_the_ten_minute_recipe_file_builds_the_configs_its_committed_runs_recorded(run, tmp_path):
    """`python train/ppo_mjx.py @train/recipes/joystick_10min.args [FLAGS]`: the trainer's own parser
    and config code, on this CPU, build the env and PPO configs that the run made on the GPU
    recorded in its config.json files, for both stages (flags after the file override it: the
    run's seed, and for the faster chain its first stage's physics step and steps)."""
    from quadson_mjx.cli import train_configs

    flags, stage1_dt = RECIPE_RUNS[run]
    args, overrides = train_cli.parse([f"@{RECIPE_10MIN}", *flags, "--run-dir", str(tmp_path / "run")])
    env_cfg, ppo_cfg, _, plan, _ = train_configs.run_configs(args, overrides, primary=False)
    tune_env, tune_ppo, _ = train_configs.new_run_configs(env_cfg, ppo_cfg, plan[0], tmp_path / "ft", False)
    stages = {run: (env_cfg, ppo_cfg), run / "finetune": (tune_env, tune_ppo)}
    for stage, (env, ppo) in stages.items():
        saved = json.loads((stage / "config.json").read_text())
        assert to_json(with_added_keys(saved["env"])) == to_json(env), stage
        assert json.loads(to_json(ppo)) == saved["ppo"], stage
    assert env_cfg.sim_dt == stage1_dt and tune_env.sim_dt == 0.0025


def test_a_recipe_file_that_is_missing_is_one_line_and_exit_2(tmp_path, capsys):
    assert train_cli.main([f"@{tmp_path / 'nope.args'}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope.args" in err[0], err
