"""Rollout MCAP files: topics, schemas, counts, timestamps, transforms against MuJoCo C and the five-bar
FK, recovery of a truncated file, and the PID controller wrapper against hand-derived numbers.

One compiled rollout (2 envs x 6 steps, two segments of 3) is shared by the whole module.
"""

import json
import math
import types

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mcap.reader import make_reader

from quadson_mjx import mcap_check
from quadson_mjx import rollout as R
from quadson_mjx.env import LocomotionEnv
from quadson_mjx.env_config import env_config
from quadson_mjx.foxglove_mcap import step_time_ns
from quadson_mjx.recording import record
from quadson_mjx.robots.quadson import constants as C
from quadson_mjx.robots.quadson import fivebar

N_ENVS, N_STEPS, SEGMENT = 2, 6, 3
CTRL_DT = 0.02


@pytest.fixture(scope="module")
def env():
    return LocomotionEnv(env_config())


@pytest.fixture(scope="module")
def rollout_file(env, tmp_path_factory):
    path = tmp_path_factory.mktemp("rollout") / "pid.mcap"
    summary = record(
        path,
        env,
        R.pid_stabilizer(env),
        jax.random.PRNGKey(0),
        N_ENVS,
        N_STEPS,
        command=(0.1, 0.0, 0.25),
        segment_steps=SEGMENT,
        metadata={"seed": 0},
    )
    assert summary == {"steps": N_STEPS, "falls": 0, "off_field": 0, "nan_resets": 0}
    return path


@pytest.fixture(scope="module")
def messages(rollout_file):
    return mcap_check.read_messages(rollout_file)


def _topic(messages, topic):
    return [(t, m) for top, t, m in messages if top == topic]


def test_topics_schemas_counts_and_times(rollout_file, messages):
    report = mcap_check.check(rollout_file)
    assert report.complete, report.error
    n = N_ENVS * N_STEPS
    assert dict(report.counts) == {
        "/tf": N_STEPS,
        "/joint_states": N_STEPS,
        "/scene": 1,
        "/odom": n,
        "/imu": n,
        "/rollout/step": n,
        "/log": 2,  # start and end: no falls in 0.12 s
    }
    assert report.schemas["/tf"] == "foxglove.FrameTransforms"
    assert report.schemas["/scene"] == "foxglove.SceneUpdate"
    assert report.schemas["/joint_states"] == "foxglove.JointStates"
    assert report.schemas["/odom"] == "foxglove.Odometry"
    assert report.schemas["/log"] == "foxglove.Log"
    assert report.metadata == ["rollout", "env_config", "versions"]
    assert report.attachments == ["quadson.xml"]
    steps = [round((k + 1) * CTRL_DT * 1e9) for k in range(N_STEPS)]
    assert [t for t, _ in _topic(messages, "/tf")] == steps  # simulation time, not wall clock
    assert [t for t, _ in _topic(messages, "/scene")] == [0]
    assert [t for t, _ in _topic(messages, "/rollout/step")] == [s for s in steps for _ in range(N_ENVS)]
    assert mcap_check.main([str(rollout_file), "--rollout"]) == 0
    with open(rollout_file, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "quadson_mjx.rollout"
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        assert json.loads(meta["env_config"]["json"])["terrain"] == "flat"
        assert meta["rollout"]["controller"] == "pid" and meta["rollout"]["n_envs"] == str(N_ENVS)
        assert json.loads(meta["rollout"]["command"]) == [0.1, 0.0, 0.25]
        assert "git_revision" in meta["versions"]
        xml = next(iter(reader.iter_attachments())).data.decode()
        assert "<mujoco" in xml and "equality" in xml


def test_json_messages_are_finite_and_complete(rollout_file):
    def no_nan(token):
        raise AssertionError(f"non-JSON number {token}")

    with open(rollout_file, "rb") as f:
        for _, channel, msg in make_reader(f).iter_messages(topics=["/rollout/step", "/imu"]):
            d = json.loads(msg.data, parse_constant=no_nan)
            if channel.topic == "/imu":
                q = d["orientation"]
                assert math.isclose(math.hypot(q["x"], q["y"], q["z"], q["w"]), 1.0, abs_tol=1e-5)
                continue
            assert len(d["observation"]) == 29 and len(d["action"]) == 12
            assert set(d["foot_targets"]) == set(C.LEGS) and len(d["foot_targets"]["FL"]) == 3
            assert {"total", "forward_velocity_exp", "orientation_l2"} <= set(d["reward"])
            assert set(d["contacts"]) == set(C.LEGS)
            for leg in C.LEGS:  # a foot is in contact exactly when the ground pushes it
                assert d["foot_force_n"][leg] >= 0 and d["contacts"][leg] == (d["foot_force_n"][leg] > 0)
            assert all(0 <= v < 2e-3 for v in d["closure_residual_m"].values())  # loop closed to mm
            assert d["command"] == pytest.approx({"vx": 0.1, "vy": 0.0, "yaw_rate": 0.25})
            assert max(abs(a) for a in d["action"]) <= 1.0


def test_scene_draws_every_robot_geom_per_env_and_the_floor_once(env, messages):
    ((_, scene),) = _topic(messages, "/scene")
    frames = [e["frame_id"] for e in scene["entities"]]
    assert frames.count("world") == 1
    m = env.mj_model
    # 26 robot geoms, the collision box coincides with the visual box and is drawn once: 25 per env
    assert len(frames) == 1 + N_ENVS * 25
    fl2 = [e for e in scene["entities"] if e["frame_id"] == "env1/FL_link2"]
    assert (
        sum(len(e["cylinders"]) for e in fl2) == 1 and sum(len(e["spheres"]) for e in fl2) == 3
    )  # capsule + foot
    foot = [e for e in fl2 if len(e["spheres"]) == 1][0]["spheres"][0]
    assert foot["size"]["x"] == pytest.approx(2 * C.FOOT_RADIUS)
    assert foot["pose"]["position"]["x"] == pytest.approx(C.L2 + C.L3)
    del m


def _compose(tfs, child):
    """World pose (position, rotation matrix) of frame `child` from a FrameTransforms message."""
    by_child = {t["child_frame_id"]: t for t in tfs["transforms"]}
    pos, rot = np.zeros(3), np.eye(3)
    chain = []
    while child != "world":
        t = by_child[child]
        chain.append(t)
        child = t["parent_frame_id"]
    for t in reversed(chain):
        q = t["rotation"]
        r = np.zeros(9)
        mujoco.mju_quat2Mat(r, np.array([q["w"], q["x"], q["y"], q["z"]]))
        tr = t["translation"]
        pos = pos + rot @ np.array([tr["x"], tr["y"], tr["z"]])
        rot = rot @ r.reshape(3, 3)
    return pos, rot


def test_tf_puts_every_foot_where_mujoco_and_the_fivebar_fk_say(env, messages):
    m = env.mj_model
    d = mujoco.MjData(m)
    tf = _topic(messages, "/tf")
    joints = _topic(messages, "/joint_states")
    odom = _topic(messages, "/odom")
    assert len(tf[0][1]["transforms"]) == N_ENVS * (m.nbody - 1)
    for k in (0, N_STEPS - 1):
        for i in range(N_ENVS):
            # qpos rebuilt from /odom and /joint_states; MuJoCo C forward kinematics is the reference
            o = [
                msg
                for _, msg in odom[k * N_ENVS : (k + 1) * N_ENVS]
                if msg["body_frame_id"] == f"env{i}/base"
            ][0]
            p, q = o["pose"]["position"], o["pose"]["orientation"]
            qpos = np.zeros(m.nq)
            qpos[:7] = [p["x"], p["y"], p["z"], q["w"], q["x"], q["y"], q["z"]]
            for js in joints[k][1]["joints"]:
                env_name, name = js["name"].split("/")
                if env_name == f"env{i}":
                    qpos[m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)]] = js[
                        "position"
                    ]
            d.qpos[:] = qpos
            mujoco.mj_kinematics(m, d)
            for n, leg in enumerate(C.LEGS):
                site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, C.foot_name(leg))
                pos, rot = _compose(tf[k][1], f"env{i}/{leg}_link2")
                foot = pos + rot @ m.site_pos[site]
                np.testing.assert_allclose(foot, d.site_xpos[site], atol=2e-5)  # float32 sim state
                # five-bar FK of the motor angles, placed by the shoulder frame and the base pose
                angles = [
                    qpos[m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, C.joint_name(leg, p))]]
                    for p in C.MOTORS
                ]
                f_sh = np.asarray(fivebar.leg_fk(jnp.asarray(angles, jnp.float32)), np.float64)
                base_rot = np.zeros(9)
                mujoco.mju_quat2Mat(base_rot, qpos[3:7])
                f_world = qpos[:3] + base_rot.reshape(3, 3) @ (C.SHOULDER_POS[n] + C.SHOULDER_ROT[n] @ f_sh)
                # the simulated loop is closed to a fraction of a mm, which the foot amplifies ~3x
                np.testing.assert_allclose(foot, f_world, atol=3e-3)


def test_truncated_file_yields_its_flushed_segments(rollout_file, tmp_path):
    # Flushes: after the scene, after each 3-step segment. Cut the file in the middle of the chunk
    # of the second segment: the first segment (3 steps) and the scene must come back.
    data = rollout_file.read_bytes()
    with open(rollout_file, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    second = [c for c in chunks if c.message_start_time == step_time_ns(SEGMENT, CTRL_DT)]
    assert len(second) == 1
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: second[0].chunk_start_offset + second[0].chunk_length // 2])
    report = mcap_check.check(cut)
    assert not report.complete
    assert report.counts["/tf"] == SEGMENT and report.counts["/rollout/step"] == SEGMENT * N_ENVS
    assert report.counts["/scene"] == 1 and report.counts["/log"] == 1
    assert mcap_check.main([str(cut), "--rollout"]) == 1
    fixed = tmp_path / "fixed.mcap"
    mcap_check.recover(cut, fixed)
    again = mcap_check.check(fixed)
    assert (
        again.complete
        and again.counts["/tf"] == SEGMENT
        and again.schemas["/tf"] == "foxglove.FrameTransforms"
    )


def _rot_zyx(roll, pitch, yaw=0.0):
    cr, sr, cp, sp, cy, sy = (
        math.cos(roll),
        math.sin(roll),
        math.cos(pitch),
        math.sin(pitch),
        math.cos(yaw),
        math.sin(yaw),
    )
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def test_pid_controller_limiter_case_by_hand(env):
    # First PID step: u = (kp + ki dt + kd / dt) e = 0.75 e with e = -(roll, pitch). Measured
    # (roll, pitch) = (-0.4, 0.2) / 0.75 gives u = (0.4, -0.2) before the limiter: |0.4| + |0.2| = 0.6 > 0.45,
    # scaled by 0.75 -> (0.3, -0.15) (robots.md).
    ctrl = R.pid_stabilizer(env)
    obs = jnp.zeros(env.observation_size).at[:2].set(jnp.array([-0.4, 0.2]) / 0.75)
    # past the 0.5 s start ramp, so the gait targets are the gait's own
    info = {
        "gait_progress": jnp.asarray(0.3),
        "command": jnp.array([0.3, 0.0, 0.0]),
        "episode_time": jnp.asarray(1.0),
    }

    @jax.jit
    def act(carry, obs, info):  # as the rollout runs it: jitted
        return ctrl.act(carry, types.SimpleNamespace(obs=obs, info=info), jax.random.PRNGKey(0))

    carry, action = act(ctrl.init(), obs, info)
    assert action.shape == (env.action_size,) and action.dtype == jnp.float32
    # Reference: keep each foot's world point, rotate the body by roll 0.3, pitch -0.15 (ZYX), express
    # the point in the moved shoulder frame; offset = that - target, clipped to +-5 cm, over 5 cm.
    targets = np.asarray(env.gait_targets(info), np.float64)
    body = _rot_zyx(0.3, -0.15)
    expected = []
    for n in range(4):
        world = C.SHOULDER_POS[n] + C.SHOULDER_ROT[n] @ targets[n]
        moved = C.SHOULDER_ROT[n].T @ (body.T @ world - C.SHOULDER_POS[n])
        expected.append(np.clip(moved - targets[n], -0.05, 0.05) / 0.05)
    expected = np.ravel(expected)
    assert np.any(np.abs(expected) == 1.0)  # the clip is exercised
    np.testing.assert_allclose(action, expected, atol=2e-5)
    np.testing.assert_allclose(carry.error_sum, [0.4 / 0.75, -0.2 / 0.75], rtol=1e-6)


def test_gait_only_controller_is_zero_action(env):
    ctrl = R.gait_only(env)
    _, a = ctrl.act(ctrl.init(), types.SimpleNamespace(obs=jnp.ones(29), info={}), jax.random.PRNGKey(0))
    np.testing.assert_array_equal(a, np.zeros(env.action_size))


def test_imu_acceleration_by_hand():
    # At rest an accelerometer reads +g up; tilted by roll 90 deg about x the base's +y axis points down.
    g = jnp.array([0.0, 0.0, -9.81])
    np.testing.assert_allclose(
        R.imu_acceleration(jnp.array([1.0, 0, 0, 0]), jnp.zeros(3), g), [0, 0, 9.81], atol=1e-6
    )
    h = math.sqrt(0.5)
    np.testing.assert_allclose(
        R.imu_acceleration(jnp.array([h, h, 0, 0]), jnp.zeros(3), g), [0, 9.81, 0], atol=1e-5
    )
    # free fall reads zero
    np.testing.assert_allclose(R.imu_acceleration(jnp.array([1.0, 0, 0, 0]), g, g), [0, 0, 0], atol=1e-6)


def test_report_metrics_by_hand():
    # 2 episodes of 1 s at 50 Hz: x = 0.1 t (0.1 m/s), roll = 0.1 sin(2 pi t) (max - min 0.2 within
    # sampling), pitch constant -0.05; episode 1 falls at its 26th step (0.5 s).
    from quadson_mjx.report import Trial, seed000_stats, seed003_stats

    t = np.arange(1, 51) * CTRL_DT
    zeros = np.zeros((2, 50))
    base = {
        k: zeros.copy() for k in ("x", "y", "z", "roll", "pitch", "yaw", "vx", "vy", "vz", "wx", "wy", "wz")
    }
    base["x"][:] = 0.1 * t
    base["vx"][:] = 0.1
    base["roll"][:] = 0.1 * np.sin(2 * np.pi * t)
    base["pitch"][:] = -0.05
    done = np.zeros((2, 50), bool)
    done[1, 25] = True
    trial = Trial("x", "pid", "flat", (0.1, 0.0, 0.0), CTRL_DT, base, done)
    s3 = seed003_stats(trial)
    assert s3["falls"] == 1 and s3["episodes"] == 2
    np.testing.assert_allclose(s3["speed"], (0.1, 0.0), atol=1e-12)
    np.testing.assert_allclose(s3["d_pitch"], (0.0, 0.0), atol=1e-12)
    d0 = np.ptp(base["roll"][0])  # full cycle
    d1 = np.ptp(base["roll"][1, :26])  # up to and including the falling step
    np.testing.assert_allclose(s3["d_roll"], (np.mean([d0, d1]), np.std([d0, d1])))
    assert abs(d0 - 0.2) < 1e-3
    s0 = seed000_stats(trial, window_s=3.0)  # the window is longer than the trial: all 50 + 26 steps
    np.testing.assert_allclose(s0["vx"], (0.1, 0.0), atol=1e-12)
    np.testing.assert_allclose(s0["pitch"], (-0.05, 0.0), atol=1e-12)
    assert s0["falls"] == 1


def test_report_reads_the_rollout_file(rollout_file, messages):
    from quadson_mjx.report import load_trial, markdown

    trial = load_trial(rollout_file)
    assert trial.controller == "pid" and trial.terrain == "flat" and trial.task == "forward"
    assert trial.base["roll"].shape == (N_ENVS, N_STEPS)
    rolls = [m["base"]["roll"] for _, m in _topic(messages, "/rollout/step") if m["env"] == 1]
    np.testing.assert_allclose(trial.base["roll"][1], rolls)
    table = markdown([trial])
    assert "| pid | flat | forward |" in table


def test_shipped_foxglove_layout_is_the_generated_one():
    from pathlib import Path

    from quadson_mjx.foxglove_layout import layout_json

    shipped = Path(__file__).resolve().parents[1] / "eval" / "foxglove_layout.json"
    assert shipped.read_text() == layout_json(C.LEGS)
    layout = json.loads(shipped.read_text())
    text = json.dumps(layout)
    assert '"panelType": "ThreeDee"' in text and '"followTf": "env0/base"' in text
    assert "/rollout/step{env==0}.base.roll" in text


def test_writer_draws_only_viz_envs_but_logs_every_env(env, tmp_path):
    from quadson_mjx.foxglove_mcap import RolloutWriter

    m = env.mj_model
    B, T = 3, 2

    def z(*shape):
        return np.zeros((T, B, *shape), np.float32)

    qpos = z(m.nq)
    qpos[..., 3] = 1.0
    xquat = z(m.nbody, 4)
    xquat[..., 0] = 1.0
    traj = R.Trajectory(
        episode_step=np.ones((T, B), np.int32), obs=z(29), action=z(12), foot_targets=z(4, 3), command=z(3),
        qpos=qpos, qvel=z(m.nv), xpos=z(m.nbody, 3), xquat=xquat, rpy=z(3), lin_vel=z(3), ang_vel=z(3),
        imu_acc=z(3), foot_force=z(4), actuator_force=z(m.nu), closure_residual=z(4), reward=z(),
        reward_terms={"orientation_l2": z()}, done=np.zeros((T, B), bool), nan_reset=np.zeros((T, B), bool),
        fall=np.zeros((T, B), bool), off_field=np.zeros((T, B), bool), base_height=z(),
        base_below_terrain=np.zeros((T, B), bool),
    )  # fmt: skip
    traj.obs[0, 2, 5] = np.nan  # JSON gets null, not NaN
    path = tmp_path / "viz.mcap"
    with RolloutWriter(path, m, B, CTRL_DT, env.robot.legs, viz_envs=1) as w:
        w.write_scene()
        for k in range(T):
            w.write_step(step_time_ns(k, CTRL_DT), traj, k)
    msgs = mcap_check.read_messages(path)
    counts = mcap_check.check(path).counts
    assert (
        counts["/tf"] == T
        and counts["/odom"] == T
        and counts["/imu"] == T
        and counts["/rollout/step"] == T * B
    )
    ((_, scene),) = _topic(msgs, "/scene")
    assert {e["frame_id"].split("/")[0] for e in scene["entities"]} == {"world", "env0"}
    tfs = _topic(msgs, "/tf")[0][1]["transforms"]
    assert len(tfs) == m.nbody - 1 and {t["parent_frame_id"] for t in tfs} >= {"world", "env0/base"}
    steps = [s for _, s in _topic(msgs, "/rollout/step")]
    assert [s["env"] for s in steps] == [0, 1, 2, 0, 1, 2]
    assert steps[2]["observation"][5] is None and steps[2]["observation"][4] == 0.0


def test_tracking_stats_by_hand():
    # 2 envs x 100 steps (2 s) with their own commands; settle 1 s skips the first 50 steps.
    # env 0: command (0.2, 0, 0.5), vx = 0.2 + 0.1 (+1, -1, ...) alternating: raw RMS 0.1, its
    # 0.8 s (40-step, even) moving mean is exact: 0; wz = 0.4: error -0.1. env 1: command (0, 0.1, 0),
    # vy = 0, falls at step 80 (its errors: steps 51..80, 30 steps), base in the ground 3 steps.
    from quadson_mjx.report import Trial, tracking_by_command, tracking_stats

    T = 100
    base = {
        k: np.zeros((2, T))
        for k in ("x", "y", "z", "roll", "pitch", "yaw", "vx", "vy", "vz", "wx", "wy", "wz")
    }
    base["vx"][0] = 0.2 + 0.1 * (-1.0) ** np.arange(T)
    base["wz"][0] = 0.4
    done = np.zeros((2, T), bool)
    done[1, 79] = True
    below = np.zeros((2, T), bool)
    below[1, 70:73] = True
    commands = np.array([[0.2, 0.0, 0.5], [0.0, 0.1, 0.0]])
    trial = Trial("x", "policy", "rough", tuple(commands[0]), CTRL_DT, base, done, commands=commands,
                  fall=done.copy(), off_field=np.zeros_like(done), below=below)  # fmt: skip
    assert trial.task == "sweep"
    s = tracking_stats(trial, settle_s=1.0, avg_s=0.8)
    n0, n1 = 50, 30  # steps counted per env
    np.testing.assert_allclose(s["vx"], math.sqrt(n0 * 0.01 / (n0 + n1)), rtol=1e-9)
    np.testing.assert_allclose(s["vx_avg"], 0.0, atol=1e-9)
    np.testing.assert_allclose(s["vy"], math.sqrt(n1 * 0.01 / (n0 + n1)), rtol=1e-9)
    np.testing.assert_allclose(s["wz"], math.sqrt(n0 * 0.01 / (n0 + n1)), rtol=1e-9)
    assert s["falls"] == 1 and s["episodes"] == 2 and s["off_field"] == 0
    assert s["below_s"] == pytest.approx(3 * CTRL_DT)
    by_vy = tracking_by_command(trial, axis=1)
    assert [v for v, _ in by_vy] == [0.0, 0.1]
    assert by_vy[1][1]["vy"] == pytest.approx(0.1) and by_vy[1][1]["falls"] == 1
    assert by_vy[0][1]["vx"] == pytest.approx(0.1) and by_vy[0][1]["falls"] == 0


def test_randomized_step_and_per_env_commands():
    # --suite --randomize and the sweep: each env keeps its own command (the env's resampling is off
    # for a given command, its obs tail shows it), and every env steps on its own randomized model.
    # Reference for the model: the same states stepped on the nominal model differ from it.
    env = LocomotionEnv(env_config(joystick=True, randomize=True))
    commands = np.array([[0.3, 0.0, 0.0], [0.0, 0.1, -0.4]], np.float32)
    carry = R.init_carry(env, R.gait_only(env), jax.random.PRNGKey(0), 2, commands)
    np.testing.assert_array_equal(carry.state.info["command"], commands)
    np.testing.assert_array_equal(carry.state.obs[:, -3:], commands)
    assert np.all(np.isinf(np.asarray(carry.state.info["command_timer"])))
    both = jax.jit(
        lambda s, a: (R.randomized_step(env, 2, jax.random.PRNGKey(5))(s, a), jax.vmap(env.step)(s, a))
    )
    randomized, nominal = both(carry.state, jnp.zeros((2, 12)))
    q_r, q_n = np.asarray(randomized.pipeline_state.qpos), np.asarray(nominal.pipeline_state.qpos)
    assert np.all(np.isfinite(q_r)) and not np.allclose(q_r, q_n, atol=1e-7)
    with pytest.raises(ValueError, match="3 commands for 2 environments"):
        R.init_carry(env, R.gait_only(env), jax.random.PRNGKey(0), 2, np.zeros((3, 3)))
    with pytest.raises(ValueError, match="randomize on"):
        next(
            R.run(LocomotionEnv(env_config()), R.gait_only(env), jax.random.PRNGKey(0), 2, 4, randomize=True)
        )


def test_pid_reads_roll_and_pitch_from_either_observation():
    """The PID's measured roll and pitch: seed 000's base_rpy entries as they are, and for the
    sensor-only observation (a gait recipe's dictionary observation) the ZYX roll and pitch of the
    IMU's gravity direction, against MuJoCo's own quaternion of known roll, pitch and yaw."""
    from quadson_mjx import obs_spec
    from quadson_mjx.sensors import gravity_direction

    recipe_env = LocomotionEnv(env_config(gait="bound", gait_recipe=True))
    sensor_spec = recipe_env.obs_spec
    read = jax.jit(R.observed_roll_pitch(sensor_spec))
    k = sensor_spec.names.index("gravity.x")
    for roll, pitch, yaw in [(0.3, -0.2, 1.0), (-1.2, 0.4, -2.5), (0.0, 1.3, 0.2), (2.8, 0.1, 0.0)]:
        quat = np.zeros(4)
        mujoco.mju_euler2Quat(quat, np.array([roll, pitch, yaw]), "XYZ")  # intrinsic x, y, z = ZYX
        state = jnp.zeros(sensor_spec.size).at[k : k + 3].set(gravity_direction(jnp.asarray(quat)))
        got = read(state)
        np.testing.assert_allclose(got, [roll, pitch], atol=1e-5)
    # regression: quadson-gaits' pid row on a gait recipe indexed the dictionary observation
    ctrl = R.pid_stabilizer(recipe_env)
    info = {"gait_progress": jnp.asarray(0.3), "command": jnp.zeros(3), "episode_time": jnp.asarray(1.0)}
    obs = {"state": state, "privileged_state": jnp.zeros(5)}
    act = jax.jit(lambda carry, obs, info: ctrl.act(carry, types.SimpleNamespace(obs=obs, info=info), None))
    carry, action = act(ctrl.init(), obs, info)
    np.testing.assert_allclose(carry.prev_error, [-roll, -pitch], atol=1e-5)  # the last case's
    assert action.shape == (recipe_env.action_size,) and bool(jnp.all(jnp.isfinite(action)))
    true_state = R.observed_roll_pitch(obs_spec.locomotion_observation(C.LEGS, C.MOTOR_JOINTS, False))
    np.testing.assert_allclose(true_state(jnp.arange(29.0)), [0.0, 1.0])
    with pytest.raises(ValueError, match="neither base_rpy nor gravity"):
        R.observed_roll_pitch(obs_spec.getup_action(C.MOTOR_JOINTS))
