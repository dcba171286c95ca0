"""Sim-to-sim (quadson_mjx.sim2sim, sim2sim_plant, sim2sim_model): the servo and sensor models against
hand-computed values, the plant's model against the robot's MJCF, and short closed loops on the CPU:
the committed true_state policy exported to ONNX (MCAP written and read back), a sensor-only
policy (no velocity input), one that observes the servos' latency and one with the gait's two
actions, through the deploy loop.
"""

import json
import math

import mujoco
import numpy as np
import pytest

from quadson_mjx import mcap_check
from quadson_mjx import sim2sim as S
from quadson_mjx import sim2sim_plant as P
from quadson_mjx.config import to_json
from quadson_mjx.env_config import env_config
from quadson_mjx.quat import axis_quat, quat_mul, quat_rotate_inverse, quat_to_rpy
from quadson_mjx.robots import get_robot
from quadson_mjx.sim2sim_model import plant_model

RUN = "results/policy_h100_joystick"
KP, KD, PEAK = 25.2662, 0.402124, 3.43775  # Quadson's servo (robots/quadson/constants.py)
W0, STALL = P.MOTOR_TORQUE_SPEED["quadson"]  # 62.83 rad/s, 6.875 N m
QUIET = P.SensorParams(
    gyro_noise=0.0, gyro_bias=0.0, gyro_bias_walk=0.0, attitude_noise=0.0, mount_tilt=0.0, encoder_noise=0.0
)


@pytest.fixture(scope="module")
def robot():
    return get_robot("quadson")


@pytest.fixture(scope="module")
def flat(robot):
    return plant_model(robot, "flat")


def test_servo_torque_hand_values():
    # PD: 25.2662 x 0.1 - 0.402124 x 2 = 2.52662 - 0.804248 = 1.722372 N m (below every limit)
    assert P.servo_torque(0.1, 0.0, 2.0, KP, KD, PEAK, STALL, W0, 0.002) == pytest.approx(1.722372)
    # the peak clamps: 25.2662 x 0.5 = 12.63 -> 3.43775 at rest
    assert P.servo_torque(0.5, 0.0, 0.0, KP, 0.0, PEAK, STALL, W0, 0.002) == pytest.approx(PEAK)
    # motoring at 3/4 of the no-load speed: at most 6.8755 x (1 - 0.75) = 1.71887 N m
    w = 0.75 * W0
    assert P.servo_torque(0.5, 0.0, w, KP, 0.0, PEAK, STALL, W0, 0.0) == pytest.approx(0.25 * STALL)
    # braking (torque against the motion) keeps the peak; beyond the no-load speed no motoring torque
    assert P.servo_torque(0.5, 0.0, -w, KP, 0.0, PEAK, STALL, W0, 0.0) == pytest.approx(PEAK)
    assert P.servo_torque(0.5, 0.0, 1.2 * W0, KP, 0.0, PEAK, STALL, W0, 0.0) == 0.0
    # inside the deadband only the damping acts: -0.402124 x 1 N m
    assert P.servo_torque(0.0015, 0.0, 1.0, KP, KD, PEAK, STALL, W0, 0.002) == pytest.approx(-KD)
    assert P.servo_torque(0.0025, 0.0, 0.0, KP, KD, PEAK, STALL, W0, 0.002) == pytest.approx(KP * 0.0025)
    # without a speed limit (Caramel: back-EMF is the model's joint damping) only the peak
    assert P.servo_torque(0.5, 0.0, 100.0, KP, 0.0, PEAK, None, None, 0.0) == pytest.approx(PEAK)
    # Quadson's numbers: the 10 A limit holds up to half the no-load speed (constants.MOTOR_VELOCITY_LIMIT)
    assert STALL * (1 - 31.4159265 / W0) == pytest.approx(PEAK, rel=1e-6)


def test_plant_model_is_the_robots_mjcf_with_full_contacts_and_torque_motors(robot, flat):
    src = robot.load_model("flat")
    assert (flat.nbody, flat.njnt, flat.neq, flat.nu) == (src.nbody, src.njnt, src.neq, src.nu)
    np.testing.assert_array_equal(flat.body_mass, src.body_mass)
    assert flat.opt.timestep == 0.002 != src.opt.timestep
    assert flat.opt.disableflags == 0
    np.testing.assert_array_equal(flat.actuator_gainprm[:, 0], 1.0)
    np.testing.assert_array_equal(flat.actuator_biasprm, 0.0)
    # the MJCF's contacts: the 4 feet and the base box; here every geom of the legs touches the
    # ground, and the other legs (not its own), and the base box the ground (its drawn twin: nothing)
    base = mujoco.mj_name2id(flat, mujoco.mjtObj.mjOBJ_BODY, robot.root_body)
    legs = np.flatnonzero(flat.geom_bodyid > base)
    assert len(legs) == 24 and np.all(flat.geom_conaffinity[legs] & 1)
    assert int(np.sum(src.geom_conaffinity[legs] > 0)) == 4
    fl, fr = legs[flat.geom_bodyid[legs] == flat.geom_bodyid[legs][0]][0], legs[-1]
    assert (
        flat.geom_contype[fl] & flat.geom_conaffinity[fr]
        and not flat.geom_contype[fl] & flat.geom_conaffinity[fl]
    )
    base_geoms = np.flatnonzero(flat.geom_bodyid == base)
    collide = [g for g in base_geoms if flat.geom_conaffinity[g] or flat.geom_contype[g]]
    assert [mujoco.mj_id2name(flat, mujoco.mjtObj.mjOBJ_GEOM, g) for g in collide] == ["base_collision"]


def test_stone_field_is_trainings_tiled_and_the_start_is_on_stones(robot):
    m = plant_model(robot, "stones")
    rough = robot.load_model("rough")
    d, dr = mujoco.MjData(m), mujoco.MjData(rough)
    mujoco.mj_forward(m, d)
    mujoco.mj_forward(rough, dr)
    mask = np.array([1, 0, 0, 0, 0, 0], np.uint8)

    def height(model, data, x, y):
        return 10.0 - mujoco.mj_ray(
            model, data, np.array([x, y, 10.0]), np.array([0, 0, -1.0]), mask, 1, -1, None
        )

    for x, y in [(1.0, 1.3), (-2.2, 0.7), (3.1, -3.3), (0.9, -0.45)]:  # away from the start patch: the same
        assert height(m, d, x, y) == pytest.approx(height(rough, dr, x, y), abs=1e-9)
    # mirrored at the field's edge x = 4 m: 4 + a has the height of 4 - a at the grid's points (between
    # them MuJoCo's triangles run along the other diagonal)
    for a in (0.04, 0.52, 1.2):
        assert height(m, d, 4 + a, 0.72) == pytest.approx(height(m, d, 4 - a, 0.72), abs=1e-9)
    # the training start patch (|x|, |y| < 0.3 m) is flat; here it has stones
    xs = np.linspace(-0.28, 0.28, 29)
    assert max(height(rough, dr, x, y) for x in xs for y in xs) == 0.0
    assert max(height(m, d, x, y) for x in xs for y in xs) > 0.01


def test_latency_is_whole_physics_steps(robot, flat):
    assert P.latency_steps(0.02, 0.002) == 10  # one 20 ms control tick
    assert P.latency_steps(0.06, 0.002) == 30
    plant = P.Plant(robot, flat, P.ServoParams(latency_s=0.02), QUIET)
    plant.reset()
    new = plant.home_targets + 0.05
    plant.send(new)
    plant.advance(0.02)  # physics steps 0-9, the first 20 ms after sending: the old targets act
    np.testing.assert_array_equal(plant.targets, plant.home_targets)
    plant.advance(0.002)  # step 10 starts 20 ms after sending: the new ones
    np.testing.assert_array_equal(plant.targets, new)


def test_imu_reads_a_known_pose_with_mount_tilt_bias_and_heading_drift(robot, flat):
    plant = P.Plant(robot, flat, P.ServoParams(), QUIET)
    plant.reset(yaw=0.3)
    d = plant.d
    roll, pitch, yaw = 0.1, -0.2, 0.7
    cr, sr, cp, sp, cy, sy = (f(a / 2) for a in (roll, pitch, yaw) for f in (math.cos, math.sin))
    # ZYX: q = qz(yaw) qy(pitch) qx(roll)
    q = np.array([
        cy * cp * cr + sy * sp * sr, cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr, sy * cp * cr - cy * sp * sr,
    ])  # fmt: skip
    d.qpos[3:7] = q
    d.qvel[:] = 0.0
    mujoco.mj_forward(plant.m, d)
    r = plant.read()
    np.testing.assert_allclose(quat_to_rpy(r.imu_quat_wxyz), [roll, pitch, yaw], atol=1e-9)
    np.testing.assert_allclose(r.gyro, 0.0, atol=1e-12)
    plant.gyro_bias = np.array([0.01, -0.02, 0.03])
    plant.mount = axis_quat(0, 0.02)  # the IMU rolled 0.02 rad on the frame
    d.qpos[3:7] = [1.0, 0.0, 0.0, 0.0]
    mujoco.mj_forward(plant.m, d)
    r = plant.read()
    np.testing.assert_allclose(quat_to_rpy(r.imu_quat_wxyz), [0.02, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(r.gyro, [0.01, -0.02, 0.03], atol=1e-12)  # at rest: the bias
    # a 6-axis fusion's heading drifts by the integrated z bias: 0.03 rad/s x 1 s
    plant.sensors = P.SensorParams(**{**QUIET.__dict__, "enabled": True})
    plant.mount = np.array([1.0, 0.0, 0.0, 0.0])
    plant.heading_drift = 0.0
    plant.heading_drift += plant.gyro_bias[2] * 1.0
    assert quat_to_rpy(plant.read().imu_quat_wxyz)[2] == pytest.approx(0.03, abs=1e-9)


def test_heading_drift_accumulates_over_advance(robot, flat):
    plant = P.Plant(
        robot, flat, P.ServoParams(), P.SensorParams(**{**QUIET.__dict__, "gyro_bias": 0.05}), seed=4
    )
    plant.reset()
    bias_z = plant.gyro_bias[2]
    assert 0.0 < abs(bias_z) <= 0.05
    for _ in range(50):  # 1 s of ticks, standing
        plant.send(plant.home_targets)
        plant.advance(0.02)
    assert plant.heading_drift == pytest.approx(bias_z * 1.0, rel=1e-9)


def test_encoders_are_quantised_to_12_bits(robot, flat):
    s = P.SensorParams(**{**QUIET.__dict__, "enabled": True})
    plant = P.Plant(robot, flat, P.ServoParams(), s)
    plant.reset()
    counts = plant.read().motor_pos / (2 * math.pi / 4096)
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)
    true = plant.d.qpos[plant.qadr]
    assert np.max(np.abs(plant.read().motor_pos - true)) <= math.pi / 4096 + 1e-12


class _SmallSensorPolicy:
    """A freshly initialised small MLP (obs -> 32 -> actions, tanh) over the sensor-only observation:
    what an untrained export computes, without training. servo_latency: the observation ends with
    the servos' measured latency (trained for 0-20 ms, 2 ms calibration error); the policy keeps the
    observations it was given."""

    def __init__(self, servo_latency=False):
        from quadson_mjx import deploy

        cfg = env_config(terrain="rough")
        cfg.unlock()
        cfg.observation, cfg.command_tracking = "sensors", True
        cfg.observe_servo_latency = servo_latency
        self.meta = {
            "env_config": json.loads(to_json(cfg)),
            "trained_sensor_model": {
                "actuation_latency_s": [0.0, 0.02],
                "sensor": {"servo_latency_error_s": 0.002},
            },
        }
        self.seen = []
        c = deploy.LoopConfig.from_env_config(self.meta["env_config"], self.meta)
        self.obs_size, self.action_size = c.obs_size, c.action_size
        rng = np.random.default_rng(0)
        self.w1 = rng.normal(0, 0.05, (self.obs_size, 32)).astype(np.float32)
        self.w2 = rng.normal(0, 0.05, (32, self.action_size)).astype(np.float32)

    def __call__(self, obs):
        self.seen.append(np.asarray(obs))
        return np.tanh(np.tanh(obs @ self.w1) @ self.w2)


def test_a_policy_observing_the_servo_latency_is_given_the_plants(robot):
    """run_episode gives a policy that observes the servos' latency the plant's own (whole physics
    steps: 14 ms is 7 steps of 2 ms), which it then observes every tick; a plant slower than the
    policy was trained for (60 ms) is refused before the run, naming the trained range."""
    policy = _SmallSensorPolicy(servo_latency=True)
    adapter = S.LoopAdapter(policy, "true")
    assert (
        adapter.loop.needs_servo_latency
        and adapter.loop.config.obs_spec.names[-1] == "servo_latency.measured"
    )
    plant = S.make_plant(robot, adapter.env_config, "flat", 0.014, seed=0, randomize=False, pushes=False)
    assert plant.delay == 7
    row = S.run_episode(adapter, plant, ((0.0, (0.2, 0.0, 0.0)),), 1.0, seed=0)
    assert row["steps"] == 50 and adapter.loop.servo_latency_s == pytest.approx(0.014)
    assert len(policy.seen) == 50 and all(o[-1] == np.float32(0.014) for o in policy.seen)
    slow = S.make_plant(robot, adapter.env_config, "flat", 0.06, seed=0, randomize=False, pushes=False)
    with pytest.raises(ValueError, match=r"trained for a measured latency in \[0, 0.022\] s"):
        S.run_episode(
            S.LoopAdapter(_SmallSensorPolicy(servo_latency=True), "true"),
            slow,
            ((0.0, (0.2, 0.0, 0.0)),),
            1.0,
        )


def test_gait_action_policy_walks_through_its_deploy_loop(robot, tmp_path):
    """The committed tiles policy fine-tuned with the gait's two actions (results/tiles_ga_more_h200),
    exported to ONNX, in MuJoCo C through the deploy loop on flat ground at 0.3 m/s: 14 actions, the
    last two scaling the gait; it does not fall and walks near the commanded speed."""
    from quadson_mjx import export

    path = export.export_run("results/tiles_ga_more_h200", tmp_path / "ga.onnx")
    adapter = S.LoopAdapter(str(path), "true")
    assert adapter.loop.config.gait_action and adapter.loop.config.action_size == 14
    plant = S.make_plant(robot, adapter.env_config, "flat", 0.02, seed=0, randomize=False, pushes=False)
    row = S.run_episode(adapter, plant, ((0.0, (0.3, 0.0, 0.0)),), 3.0, seed=0, imu_calibration_s=1.0)
    assert row["steps"] == 150 and not row["fell"]
    assert row["vx_mean"] > 0.25, row["vx_mean"]  # measured 0.292 m/s


def test_sensor_only_policy_closed_loop_takes_no_velocity(robot):
    adapter = S.LoopAdapter(_SmallSensorPolicy(), "true")
    assert not adapter.observes_velocity and adapter.velocity_source == "none"
    plant = S.make_plant(robot, adapter.env_config, "flat", 0.02, seed=0, randomize=False, pushes=False)
    row = S.run_episode(adapter, plant, ((0.0, (0.0, 0.0, 0.0)),), 2.0, seed=0)
    assert row["steps"] == 100 and not row["fell"] and row["tracked_steps"] == 50
    assert all(math.isfinite(row[k]) for k in ("vx_rms", "vy_rms", "yaw_rate_rms"))


def test_imu_calibration_standing_in_the_plant_finds_its_mount_and_gyro_bias(robot):
    """run_episode(imu_calibration_s=1): the loop calibrates its IMU from 50 ticks of the plant's
    readings standing at home on flat ground. What it finds is the IMU against level ground: the
    plant's own mounting (drawn as Rx(roll) Ry(pitch); deploy_imu writes Ry Rx) on top of the home
    stance's tilt (the body pitches about 7 mrad standing), through the plant's attitude noise; and
    the plant's gyro bias."""
    adapter = S.LoopAdapter(_SmallSensorPolicy(), "true")
    plant = S.make_plant(robot, adapter.env_config, "flat", 0.02, seed=4, randomize=False, pushes=False)
    S.run_episode(adapter, plant, ((0.0, (0.0, 0.0, 0.0)),), 0.02, seed=0, imu_calibration_s=1.0)
    cal = adapter.loop.imu_calibration
    assert cal is not None and cal.samples == 50
    roll, pitch, _ = plant.truth()["rpy"]  # the stance now, the calibration's last tick
    stance = quat_mul(axis_quat(1, pitch), axis_quat(0, roll))
    down = np.array([0.0, 0.0, -1.0])
    want = quat_rotate_inverse(quat_mul(stance, plant.mount), down)
    got = quat_rotate_inverse(cal.mount_quat, down)
    assert np.linalg.norm(plant.mount[1:]) > 0.005  # a mounting worth finding (~0.6 deg or more)
    assert math.acos(min(1.0, float(want @ got))) < 0.002  # rad
    np.testing.assert_allclose(cal.gyro_bias, plant.gyro_bias, atol=0.005)
    # on the stones: the plant's IMU, read standing on a level twin of the plant (the floor a robot
    # is calibrated on before it walks out); the same stance, so the same answer within the noise
    stones = S.make_plant(robot, adapter.env_config, "stones", 0.02, seed=7, randomize=False, pushes=False)
    S.run_episode(adapter, stones, ((0.0, (0.0, 0.0, 0.0)),), 0.02, 0, None, "stones", 1.0)
    cal = adapter.loop.imu_calibration
    want = quat_rotate_inverse(quat_mul(stance, stones.mount), down)
    assert (
        cal.samples == 50
        and math.acos(min(1.0, float(want @ quat_rotate_inverse(cal.mount_quat, down)))) < 0.002
    )
    np.testing.assert_allclose(cal.gyro_bias, stones.gyro_bias, atol=0.005)
    assert (
        np.linalg.norm(stones.mount[1:] - plant.mount[1:]) > 0.005
    )  # another draw: not the flat run's answer


def test_randomization_ranges_replace_the_trained_ones(robot, gait_policies):
    # each range pinned to one value: the plant's model is the nominal one scaled by exactly it
    env_cfg = {"randomization": {"mass_scale": (0.85, 1.25), "friction": (0.5, 1.2)}}
    ranges = {"mass_scale": (1.1, 1.1), "friction": (0.7, 0.7), "motor_strength": (0.9, 0.9), "base_com_shift_m": (0.01, 0.01)}  # fmt: skip
    nominal = S.make_plant(robot, env_cfg, "flat", 0.02, seed=3, randomize=False, pushes=False)
    plant = S.make_plant(robot, env_cfg, "flat", 0.02, seed=3, randomize=True, pushes=False, ranges=ranges)
    nominal.reset()
    plant.reset()  # draws the episode's model
    np.testing.assert_allclose(plant.m.body_mass, 1.1 * nominal.m.body_mass, rtol=1e-12)
    np.testing.assert_allclose(plant.m.geom_friction[:, 0], 0.7)
    np.testing.assert_allclose(plant.kp, 0.9 * nominal.kp, rtol=1e-12)
    shift = plant.m.body_ipos[plant.root, 0] - nominal.m.body_ipos[nominal.root, 0]
    assert shift == pytest.approx(0.01, abs=1e-12)
    # through a suite: every job carries them to run_one's plant (and its row)
    (job,) = S.suite_jobs(
        [("trot", gait_policies["trot"])], ("flat",), "gait", 1.0, randomize=True, ranges=ranges
    )
    assert job["ranges"] == ranges and S.run_one(job)["ranges"] == ranges
    for bad, match in (
        ({"mass": (0.9, 1.1)}, "mass"),
        ({"friction": (1.2, 0.5)}, "friction"),
        ({"motor_strength": (0.9, float("nan"))}, "motor_strength"),
        ({"base_com_shift_m": (0.0,)}, "two numbers"),
    ):
        with pytest.raises(ValueError, match=match):
            S.check_ranges(bad)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    from quadson_mjx import export

    out = tmp_path_factory.mktemp("sim2sim")
    return export.export_run(RUN, out / "old.onnx"), out


def test_true_state_policy_closed_loop_on_stones_writes_a_readable_mcap(exported):
    path, out = exported
    jobs = S.suite_jobs(
        [("old", path)], terrains=("stones",), which="sweep", seconds=3.0, seeds=(0,),
        velocity_sources=("true", "zero"), out_dir=out, randomize=True, pushes=True,
    )  # fmt: skip
    job = next(j for j in jobs if j["label"] == "cmd02" and j["velocity_source"] == "true")  # vx 0.3 m/s
    (out / "mcap").mkdir(exist_ok=True)
    row = S.run_one(job)
    assert row["steps"] == 150 and not row["fell"] and row["velocity_source"] == "true"
    assert row["tracked_steps"] == 100  # every step after the first second
    assert row["vx_rms"] < 0.3 and row["invalid_ik_steps"] == 0
    report = mcap_check.check(job["mcap"])
    assert report.complete
    assert report.counts["/rollout/step"] == 150 and report.counts["/tf"] == 150
    assert all(report.counts.get(t, 0) > 0 for t in mcap_check.ROLLOUT_TOPICS)
    msgs = mcap_check.read_messages(job["mcap"], topics=("/rollout/step",))
    step = msgs[-1][2]
    targets = np.concatenate([step["motor_targets"][leg] for leg in ("FL", "FR", "RL", "RR")])
    assert targets.shape == (12,) and np.all(np.isfinite(targets))
    assert set(step["sensors"]) == {"imu_quat_wxyz", "gyro", "motor_pos"}
    summary = S.summarize([row])
    assert summary[0]["runs"] == 1 and summary[0]["vx_rms"] == pytest.approx(row["vx_rms"])


def test_cli_bad_inputs_are_one_line_and_exit_status_2(exported, gait_policies, capsys, tmp_path):
    from quadson_mjx.cli.sim2sim import main

    path, _ = exported
    cases = [
        [str(tmp_path / "missing.onnx")],
        [str(path), "--latency-ms", "200"],
        [str(path), "--velocity-source", "estimator"],
        [str(path), "--terrain", "ice"],
        [str(path), "--seeds", "0"],
        [str(path), "--out", "/proc/version/x"],  # below a regular file: not creatable, even as root
        [str(path), "--commands", "trot"],
        [str(gait_policies["trot"])],  # trained without commands: the sweep is not its to run
        [str(path), "--randomization", "mass_scale=0.9,1.1"],  # a range without --randomize
        [str(path), "--randomize", "--randomization", "mass=0.9,1.1"],
        [str(path), "--randomize", "--randomization", "mass_scale=1.1,0.9"],
        [str(path), "--randomize", "--randomization", "friction=0.5"],
        [str(path), "--tiles", "slope_up", "--levels", "3"],  # not trained on the tiled ground
        [str(path), "--terrain", "flat", "--imu-calibration-s", "-1"],
        [str(path), "--imu-mount-tilt", "nan"],
        [str(path), "--imu-mount-tilt", "0.5"],
    ]
    for argv in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert err.startswith("error: ") and "\n" not in err, (argv, err)


def test_cli_refuses_a_policy_trained_for_a_calibrated_imu_without_the_calibration(capsys, tmp_path):
    # the sensor-only run's config with the narrower mounting tilt a calibrated robot trains with
    import shutil

    from quadson_mjx import export

    run = tmp_path / "run"
    shutil.copytree("results/policy_h100_sensors", run, ignore=shutil.ignore_patterns("*.mcap", "*.log"))
    cfg = json.loads((run / "config.json").read_text())
    cfg["env"]["sensor"]["imu_tilt_rad"] = 0.01
    (run / "config.json").write_text(json.dumps(cfg))
    path = export.export_run(run, tmp_path / "cal.onnx")
    assert S.LoopAdapter(path).loop.needs_imu_calibration
    from quadson_mjx.cli.sim2sim import main

    assert main([str(path), "--terrain", "stones"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and "--imu-calibration-s" in err, err


def test_caramel_policy_runs_through_its_deploy_loop_in_the_plant(tmp_path):
    # the plant is robot-generic: Caramel's serial legs, its servos (no second speed limit), its
    # stones (2 cm relief), its termination, through Caramel's deploy loop
    from quadson_mjx import export

    path = export.export_run("results/caramel/policy", tmp_path / "caramel.onnx")
    job = S.suite_jobs([("caramel", path)], terrains=("stones",), which="sweep", seconds=1.5, seeds=(0,))[1]
    row = S.run_one(job)
    assert row["robot"] == "caramel" and row["steps"] == 75 and not row["fell"]
    assert row["commands"] == [[0.08, 0.0, 0.0]]  # 0.15 m/s clipped to Caramel's trained range
    assert all(math.isfinite(row[k]) for k in ("vx_rms", "vy_rms", "yaw_rate_rms"))


@pytest.fixture(scope="module")
def gait_policies(tmp_path_factory):
    """The committed trot and bound policies (trained without commands), exported to ONNX."""
    from quadson_mjx import export

    out = tmp_path_factory.mktemp("sim2sim_gaits")
    return {g: export.export_run(f"results/gaits/{g}", out / f"{g}.onnx") for g in ("trot", "bound")}


def test_phase_table_of_the_loop_by_hand(gait_policies):
    # seed 000's bound: front legs at phase offset 0, hind legs at 0.5, duty 0.4 (LEGS order FL, FR,
    # RL, RR); the table at a fraction of the cycle, whatever the cycle's length
    adapter = S.LoopAdapter(gait_policies["bound"])
    for progress, stance in (
        (0.2, [1, 1, 0, 0]),
        (0.6, [0, 0, 1, 1]),
        (0.45, [0, 0, 0, 0]),
        (0.0, [1, 1, 0, 0]),
    ):
        adapter.loop.progress = progress
        np.testing.assert_array_equal(
            adapter.scheduled_stance(), np.array(stance, bool), err_msg=str(progress)
        )


def test_gait_policy_walks_its_gait_command_and_its_contact_pattern_is_counted(gait_policies):
    path = gait_policies["trot"]
    with pytest.raises(ValueError, match="trained without commands"):
        S.suite_jobs([("trot", path)], terrains=("flat",), which="sweep", seconds=3.0, seeds=(0,))
    (job,) = S.suite_jobs([("trot", path)], terrains=("flat",), which="gait", seconds=3.0, seeds=(0,))
    row = S.run_one(job)
    # the seed's trot: 12 cm per stance of 0.5 x 0.8 s -> 0.3 m/s forward, the command it trained on
    assert row["commands"] == [[0.3, 0.0, 0.0]] and row["label"] == "gait"
    assert row["steps"] == 150 and not row["fell"] and row["invalid_ik_steps"] == 0
    assert row["pattern_steps"] == row["tracked_steps"] == 100  # every step after the first second
    assert row["pattern_hits"] <= row["pattern_1step_hits"] <= 100 and row["foot_agree"] <= 400
    # it trots in MuJoCo C as in MJX (measured 93 % within one step over 20 s) at about its speed
    assert row["pattern_1step"] > 0.85 and 0.8 < row["vx_mean"] / 0.3 < 1.2
    (pooled,) = S.summarize([row])
    assert pooled["commands"] == "gait" and pooled["pattern_1step"] == row["pattern_1step"]
    assert "gait" in S.format_table([pooled]) and f"{100 * row['pattern_1step']:.1f}%" in S.format_table(
        [pooled]
    )


def test_pattern_counts_and_pooling_by_hand():
    from quadson_mjx.gait_pattern import pattern_counts

    # 4 steps; foot FL touches down one step late at step 1 (tolerated), RR is up at step 3 where
    # the table has it down for the whole run (a miss either way)
    stance = np.array([[0, 1, 1, 1], [1, 1, 1, 1], [1, 1, 1, 1], [1, 1, 1, 1]], bool)
    force = np.where(stance, 10.0, 0.0)
    force[1, 0] = 0.5  # below the 1 N threshold: up
    force[3, 3] = 0.0
    c = pattern_counts(force, stance)
    assert c == {"pattern_steps": 4, "pattern_hits": 2, "pattern_1step_hits": 3, "foot_agree": 14}
    with pytest.raises(ValueError, match="differ in shape"):
        pattern_counts(force[:3], stance)
    # pooled over runs by steps, not by runs; a gait run pools apart from the sweep
    base = {k: "x" for k in S.GROUP_KEYS}
    runs = [
        {**base, "label": "gait", "tracked_steps": 4, "sq_err_sum": [0, 0, 0], "vx_sum": 1.2, "fell": False,
         "off_field": False, "invalid_ik_steps": 0, "fault_steps": 0, "steps": 4, **c},
        {**base, "label": "gait", "tracked_steps": 0, "sq_err_sum": [0, 0, 0], "vx_sum": 0.0, "fell": True,
         "off_field": False, "invalid_ik_steps": 0, "fault_steps": 0, "steps": 1, "pattern_steps": 0,
         "pattern_hits": 0, "pattern_1step_hits": 0, "foot_agree": 0},
    ]  # fmt: skip
    (pooled,) = S.summarize(runs)
    assert pooled["commands"] == "gait" and pooled["falls"] == 1
    assert (
        pooled["pattern_1step"] == 0.75
        and pooled["pattern"] == 0.5
        and pooled["vx_mean"] == pytest.approx(0.3)
    )


def test_regression_run_line_of_a_run_that_fell_in_its_first_second():
    # a run that fell before any tracked step has no RMS: the progress line printed a traceback
    from quadson_mjx.cli.sim2sim import run_line

    row = {"policy_name": "bound", "velocity_source": "none", "terrain": "flat", "label": "step", "seed": 0,
           "fell": True, "fall_time_s": 0.84, "vx_rms": None, "vy_rms": None, "yaw_rate_rms": None,
           "vx_mean": None, "pattern_1step": None, "invalid_ik_steps": 3, "wall_s": 0.7}  # fmt: skip
    line = run_line(row)
    assert "FELL at 0.84 s" in line and "rms vx - vy - yaw -" in line and "pattern -" in line


def test_yaw_error_policy_turns_closed_loop_through_its_deploy_loop(robot, tmp_path):
    """The committed sensor-only policy with the yaw error in its observation, exported to ONNX, in
    MuJoCo C through the deploy loop: the file's spec ends with yaw_error and carries its time
    constant; turning at 0.5 rad/s for 3 s it does not fall, and the loop's yaw error is the leaky
    integral of what its gyro read minus the command (|e| < 0.1 rad: the turn is followed)."""
    from quadson_mjx import export

    path = export.export_run("results/policy_h200_sensors_yaw", tmp_path / "yaw.onnx")
    adapter = S.LoopAdapter(str(path), "true")
    assert adapter.velocity_source == "none" and adapter.loop.config.yaw_error_tau_s == 0.5
    assert adapter.loop.config.obs_spec.names[-1] == "yaw_error.z"
    plant = S.make_plant(robot, adapter.env_config, "flat", 0.02, seed=0, randomize=False, pushes=False)
    row = S.run_episode(adapter, plant, ((0.0, (0.0, 0.0, 0.5)),), 3.0, seed=0)
    assert row["steps"] == 150 and not row["fell"] and row["invalid_ik_steps"] == 0
    assert row["yaw_rate_rms"] < 0.2  # measured 0.10; the gait alone is 0.7-0.8 rad/s off (docs/results.md)
    assert 0.0 < abs(float(adapter.loop.observer.yaw_error[0])) < 0.1  # measured 0.013 rad
