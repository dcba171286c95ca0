"""Policy export: the numpy inference of the .npz and ONNX Runtime on the .onnx equal brax's JAX policy
to float32 precision; the command line refuses to overwrite and to guess a format (issue 13)."""

import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import onnx
import onnxruntime as ort
import pytest

from quadson_mjx import export, export_meta, training
from quadson_mjx.config import to_json
from quadson_mjx.env_config import env_config
from quadson_mjx.obs_spec import Spec

OBS, ACT = 29, 12


@pytest.fixture(scope="module", params=["tanh_normal", "gait_normal"])
def run_dir(tmp_path_factory, request):
    """A run directory with a perturbed-init checkpoint (two hidden layers) and a non-trivial
    normaliser, for each policy distribution."""
    run = tmp_path_factory.mktemp("run")
    env_cfg = env_config()
    ppo_cfg = training.ppo_config("test")
    ppo_cfg.policy_hidden = (16, 8)
    ppo_cfg.policy_distribution = request.param
    (run / "config.json").write_text(
        json.dumps({"env": json.loads(to_json(env_cfg)), "ppo": json.loads(to_json(ppo_cfg)), "versions": {}})
    )
    normalizer, policy, value = training.params_template(OBS, ACT, ppo_cfg)
    k_mean, k_std, k_pol = jax.random.split(jax.random.PRNGKey(7), 3)
    normalizer = normalizer.replace(
        mean=jax.random.normal(k_mean, (OBS,)), std=0.5 + jax.random.uniform(k_std, (OBS,))
    )
    # brax's init with random biases and kernels, so no layer is trivially zero (gait_normal's mean
    # layer starts at zero) and gait_normal's means leave [-1, 1], where the export must clip
    policy = jax.tree.map(
        lambda p, k: p + (0.5 if p.ndim == 1 else 0.3) * jax.random.normal(k, p.shape),
        policy,
        _keys(policy, k_pol),
    )
    training.save_checkpoint(run, 1000, (normalizer, policy, value))
    return run


def _keys(tree, key):
    leaves, treedef = jax.tree.flatten(tree)
    return jax.tree.unflatten(treedef, list(jax.random.split(key, len(leaves))))


def _jax_actions(run_dir, obs):
    """brax's deterministic policy as the env applies it (clipped to [-1, 1])."""
    policy, _, ppo_cfg, _ = training.load_policy(run_dir)
    want = np.asarray(jax.jit(policy)(obs, jax.random.PRNGKey(0))[0])
    if ppo_cfg.policy_distribution == "gait_normal":  # brax returns the raw mean; the env clips it
        assert np.abs(want).max() > 1.0
        want = np.clip(want, -1.0, 1.0)
    return want


def _random_obs():
    return np.asarray(jax.random.normal(jax.random.PRNGKey(3), (64, OBS)) * 2.0, np.float32)


def test_numpy_inference_matches_the_jax_policy(run_dir, tmp_path):
    out = export.export_run(run_dir, tmp_path / "policy.npz")
    numpy_policy = export.load(out)
    obs = _random_obs()
    want = _jax_actions(run_dir, obs)
    got = numpy_policy(obs)
    assert got.shape == (64, ACT) and got.dtype == np.float32
    assert np.std(want) > 0.1  # the actions spread over (-1, 1): a real comparison
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)  # float32 rounding, summation order
    one = numpy_policy(obs[0])  # an unbatched observation, as on the robot
    np.testing.assert_allclose(one, want[0], rtol=1e-5, atol=1e-5)
    assert numpy_policy.meta["checkpoint"] == "step_000000001000.msgpack"
    assert numpy_policy.meta["action_scale_m"] == 0.05
    with pytest.raises(ValueError, match="29"):
        numpy_policy(np.zeros(30, np.float32))


def test_inference_module_imports_only_numpy(tmp_path):
    # Load policy_file.py (the .npz's numpy inference) by path in a fresh interpreter, as on the
    # robot, and list the heavy modules present.
    from quadson_mjx import policy_file

    path = Path(policy_file.__file__)
    code = (
        "import importlib.util, sys;"
        f"spec = importlib.util.spec_from_file_location('policy_file', {str(path)!r});"
        "m = importlib.util.module_from_spec(spec); spec.loader.exec_module(m);"
        "print(sorted(n for n in ('jax', 'brax', 'flax', 'mujoco', 'quadson_mjx') if n in sys.modules))"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert res.stdout.strip() == "[]"


def test_onnx_export_matches_the_jax_policy(run_dir, tmp_path):
    out = export.export_run(run_dir, tmp_path / "policy.onnx")
    assert out == tmp_path / "policy.onnx" and sorted(p.name for p in tmp_path.iterdir()) == ["policy.onnx"]
    model = onnx.load(out)
    onnx.checker.check_model(model, full_check=True)
    assert {o.domain or "ai.onnx": o.version for o in model.opset_import} == {"ai.onnx": export.ONNX_OPSET}
    props = {p.key: p.value for p in model.metadata_props}
    assert json.loads(props["meta_json"])["checkpoint"] == "step_000000001000.msgpack"
    assert "motor_pos (12) [rad] from encoders" in props["obs_layout"]
    spec = Spec.from_json(props["obs_spec"])  # the table of docs/deploy.md: 9-20 motors, 21-24 sin
    assert (
        spec.size == OBS and spec.slices()["motor_pos"] == slice(9, 21) and spec.names[21] == "phase_sin.FL"
    )
    assert Spec.from_json(props["action_spec"]).size == ACT
    sess = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    (inp,), (outp,) = sess.get_inputs(), sess.get_outputs()
    assert (inp.name, inp.shape[1], inp.type) == ("obs", OBS, "tensor(float)")
    assert (outp.name, outp.shape[1]) == ("action", ACT)
    obs = _random_obs()
    want = _jax_actions(run_dir, obs)
    (got,) = sess.run(None, {"obs": obs})
    assert got.shape == (64, ACT) and got.dtype == np.float32
    assert np.std(want) > 0.1
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5)
    (one,) = sess.run(None, {"obs": obs[:1]})  # a batch of one, as on the robot
    np.testing.assert_allclose(one[0], want[0], rtol=0, atol=1e-5)


def test_export_refuses_to_overwrite_without_the_flag(run_dir, tmp_path, capsys):
    out = tmp_path / "policy.npz"
    out.write_bytes(b"an older export")
    assert export.main([str(run_dir), str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(out) in err and "--overwrite" in err
    assert out.read_bytes() == b"an older export"
    assert export.main([str(run_dir), str(out), "--overwrite"]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    assert export.load(out).obs_size == OBS


def test_export_rejects_an_unknown_suffix_and_writes_nothing(run_dir, tmp_path, capsys):
    # the old CLI wrote policy.bin.npz (numpy appends the suffix) and printed "policy.bin"
    for name in ("policy.bin", "policy"):
        assert export.main([str(run_dir), str(tmp_path / name)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and name in err and ".npz" in err and ".onnx" in err
    with pytest.raises(ValueError, match="unknown output format"):
        export.export_run(run_dir, tmp_path / "policy.bin")
    assert list(tmp_path.iterdir()) == []


def test_export_usage_error_from_the_shell_has_no_traceback(tmp_path):
    res = subprocess.run(
        [sys.executable, "-m", "quadson_mjx.export", str(tmp_path / "no_run"), str(tmp_path / "p.npz")],
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parents[1],
    )
    assert res.returncode == 2
    assert res.stderr.count("\n") == 1 and "not a training run directory" in res.stderr
    assert list(tmp_path.iterdir()) == []


ROOT = Path(__file__).resolve().parents[1]
COMMITTED_RUNS = sorted(p.parent for p in (ROOT / "results").rglob("config.json"))


@pytest.mark.parametrize("run", COMMITTED_RUNS, ids=lambda p: str(p.relative_to(ROOT / "results")))
def test_every_committed_run_exports_and_the_deploy_loop_accepts_its_spec(run, tmp_path):
    """The layout change must keep every committed run loadable and exportable; the exported file's
    observation spec is the one the deploy loop builds (Quadson's or Caramel's), and the loop runs it
    (they are true_state policies: the base velocity is an input)."""
    from quadson_mjx import deploy

    out = export.export_run(run, tmp_path / "policy.onnx")
    props = {p.key: p.value for p in onnx.load(out).metadata_props}
    spec, meta = Spec.from_json(props["obs_spec"]), json.loads(props["meta_json"])
    policy = deploy.load_policy(out)
    assert (policy.obs_size, policy.action_size) == (spec.size, Spec.from_json(props["action_spec"]).size)
    action = policy(np.zeros(policy.obs_size, np.float32))
    assert np.all(np.isfinite(action)) and np.all(np.abs(action) <= 1.0)
    if meta["env_config"].get("task") == "getup":  # a get-up policy runs under the supervisor
        from quadson_mjx.deploy_robots import robot_kinematics
        from quadson_mjx.deploy_supervisor import GetupPolicy

        robot = robot_kinematics(meta["env_config"], meta)
        getup = GetupPolicy(policy, robot, meta["ctrl_dt_s"])
        assert getup.obs_spec == spec and meta["motors"] == list(robot.motor_names)
        lo, hi = robot.motor_limits[:, 0], robot.motor_limits[:, 1]
        for _ in range(10):  # on its back, at home
            targets, _, _ = getup.act(np.array([0.0, 1.0, 0, 0]), np.zeros(3), robot.home_motor)
            assert (
                np.all(np.isfinite(targets)) and np.all(targets >= lo - 1e-9) and np.all(targets <= hi + 1e-9)
            )
        with pytest.raises(ValueError, match="30 observations"):
            deploy.DeployLoop(policy)  # not a walking policy
        return
    loop = deploy.DeployLoop(policy)
    if loop.needs_imu_calibration:  # trained for a calibrated IMU: calibrate standing level and still
        from quadson_mjx.deploy_imu import calibrate_imu

        loop.imu_calibration = calibrate_imu(np.tile([1.0, 0, 0, 0], (50, 1)), np.zeros((50, 3)))
    assert loop.config.obs_spec == spec and loop.config.robot.name == meta["env_config"]["robot"]
    assert meta["motors"] == list(loop.config.robot.motor_names)
    home = loop.config.robot.home_motor
    for _ in range(10):
        out = loop.step(
            np.array([1.0, 0, 0, 0]),
            np.zeros(3),
            home,
            command=loop.gait_command,
            base_lin_vel=np.zeros(3) if loop.needs_lin_vel else None,
        )
        assert out.fault == "ok" and np.all(np.isfinite(out.motor_targets))


# --- format 3: the robot's metadata ------------------------------------------------------------------

CARAMEL_RUN = ROOT / "results" / "caramel" / "policy"
QUADSON_RUN = ROOT / "results" / "policy_h200_seed"


def _meta(path):
    if str(path).endswith(".onnx"):
        return json.loads({p.key: p.value for p in onnx.load(path).metadata_props}["meta_json"])
    return export.load(path).meta


def test_export_metadata_lists_what_the_robot_needs(run_dir, tmp_path):
    from quadson_mjx.robots.quadson import constants as C

    meta = _meta(export.export_run(run_dir, tmp_path / "policy.onnx"))
    assert meta["format_version"] == export.FORMAT_VERSION == 3
    assert meta["robot"] == "quadson" and meta["motors"] == list(C.MOTOR_JOINTS)
    assert meta["actuators"] == list(C.ACTUATORS)
    assert meta["obs_names"] == list(Spec.from_json(meta["obs_spec"]).names) and len(meta["obs_names"]) == OBS
    np.testing.assert_allclose(meta["motor_limits_rad"], np.tile(C.MOTOR_RANGES, (4, 1)))
    assert len(meta["home_motor_pos_rad"]) == 12 and meta["servo_speed_rps"] == C.MOTOR_VELOCITY_LIMIT
    assert meta["action_scale_m"] == 0.05 and meta["ctrl_dt_s"] == 0.02
    sensor = meta["trained_sensor_model"]
    assert sensor["observation"] == "true_state" and sensor["noise"]["motor_pos"] == 0.01
    assert sensor["sensor"]["latency_s"] == [0.0, 0.02] and sensor["actuation_latency_s"] == [0.0, 0.02]
    model = meta["model"]
    assert model["timestep_s"] == C.SIM_DT and len(model["mjcf_sha256"]) == 64
    gains = model["actuator_gains"][C.ACTUATORS[0]]
    assert gains["kp"] == pytest.approx(C.MOTOR_KP) and gains["kv"] == pytest.approx(C.MOTOR_KD)
    assert meta["provenance"] == {}  # the run's config.json versions (this fixture's are empty)
    assert "python" in meta["exported_with"]


def test_model_identity_tells_the_models_apart():
    from quadson_mjx.robots import get_robot
    from quadson_mjx.robots.quadson import constants as C

    flat = export_meta.model_identity(get_robot("quadson"), env_config())
    again = export_meta.model_identity(get_robot("quadson"), env_config())
    rough = export_meta.model_identity(get_robot("quadson"), env_config(terrain="rough"))
    cfg = env_config()
    cfg.unlock()
    cfg.cone = "elliptic"  # a physics option of the training model
    elliptic = export_meta.model_identity(get_robot("quadson"), cfg)
    cfg = env_config()
    cfg.unlock()
    cfg.sim_dt = 0.002  # a physics step finer than the model's (the robot's 2 ms policies)
    fine = export_meta.model_identity(get_robot("quadson"), cfg)
    assert flat == again
    assert flat["timestep_s"] == C.SIM_DT == 0.004 and fine["timestep_s"] == 0.002
    hashes = {flat["mjcf_sha256"], rough["mjcf_sha256"], elliptic["mjcf_sha256"], fine["mjcf_sha256"]}
    assert len(hashes) == 4


def test_provenance_is_the_training_runs_not_the_exporting_machines(tmp_path):
    meta = _meta(export.export_run(CARAMEL_RUN, tmp_path / "c.npz"))
    want = json.loads((CARAMEL_RUN / "config.json").read_text())["versions"]
    assert meta["provenance"] == want and meta["provenance"]["git_revision"].startswith("d4a917e")


def test_caramel_policy_exports_with_caramels_motors_and_runs_in_its_loop(tmp_path):
    from quadson_mjx import deploy
    from quadson_mjx.robots.caramel import constants as CC

    out = export.export_run(CARAMEL_RUN, tmp_path / "caramel.onnx")
    meta = _meta(out)
    assert meta["robot"] == "caramel" and meta["motors"] == list(CC.JOINT_NAMES)
    np.testing.assert_allclose(meta["motor_limits_rad"], np.tile(CC.JOINT_LIMITS, (4, 1)))
    loop = deploy.DeployLoop(deploy.load_policy(out))
    r = loop.config.robot
    assert r.name == "caramel" and r.servo_speed_rps == CC.VELOCITY_LIMIT
    kw = {"base_lin_vel": np.zeros(3)} if loop.needs_lin_vel else {}
    for _ in range(60):
        o = loop.step(np.array([1.0, 0, 0, 0]), np.zeros(3), r.home_motor, command=(0.05, 0, 0), **kw)
        assert o.fault in ("ok", "leg_hold") and np.all(np.isfinite(o.motor_targets))
    assert deploy.main([str(out), "--bench", "5"]) == 0  # the deploy command runs it


# --- bad inputs: one line, exit status 2, nothing written ----------------------------------------------


def _one_line_2(capsys, argv, *words):
    assert export.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: "), err
    for w in words:
        assert w in err, (w, err)
    return err


def test_regression_export_of_another_robots_checkpoint_is_one_line(tmp_path, capsys):
    ckpt = sorted((CARAMEL_RUN / "checkpoints").glob("step_*.msgpack"))[-1]
    _one_line_2(capsys, [str(QUADSON_RUN), str(tmp_path / "p.onnx"), "--checkpoint", str(ckpt)], str(ckpt))
    assert list(tmp_path.iterdir()) == []


def test_regression_export_to_a_missing_folder_or_below_a_file_is_one_line(run_dir, tmp_path, capsys):
    _one_line_2(capsys, [str(run_dir), str(tmp_path / "no" / "p.onnx")], "does not exist")
    (tmp_path / "file").write_text("x")
    _one_line_2(capsys, [str(run_dir), str(tmp_path / "file" / "p.npz")])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


def test_regression_export_to_a_read_only_folder_is_one_line(run_dir, tmp_path, capsys, monkeypatch):
    # as root chmod does not stop writes: the folder's write permission is taken away in os.access
    import os

    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if mode & os.W_OK else real(p, mode))
    _one_line_2(capsys, [str(run_dir), str(tmp_path / "p.onnx")], "not writable")
    assert list(tmp_path.iterdir()) == []


def test_regression_export_refuses_a_non_finite_policy(run_dir, tmp_path, capsys):
    import flax.serialization

    _, _, ppo_cfg, params = training.load_policy(run_dir)
    params = (
        params[0],
        jax.tree.map(lambda p: np.where(np.arange(p.shape[-1]) == 0, np.nan, p), params[1]),
        params[2],
    )
    bad = tmp_path / "step_000000002000.msgpack"  # a diverged run's checkpoint, with its checksum
    bad.write_bytes(flax.serialization.to_bytes(jax.device_get(params)))
    digest = hashlib.sha256(bad.read_bytes()).hexdigest()
    (tmp_path / (bad.name + ".sha256")).write_text(f"{digest}  {bad.name}\n")
    out = tmp_path / "p.npz"
    err = _one_line_2(capsys, [str(run_dir), str(out), "--checkpoint", str(bad)])
    assert "finite" in err and not out.exists()


def test_export_is_written_atomically(run_dir, tmp_path):
    out = tmp_path / "policy.npz"
    out.write_bytes(b"an older export")
    export.export_run(run_dir, out, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["policy.npz"]  # no temporary file left
    assert export.load(out).obs_size == OBS


def test_asymmetric_critic_export_uses_the_actors_normaliser_only(tmp_path):
    """A sensor-only actor with a privileged critic: brax keeps one normaliser per observation key;
    the export takes "state"'s, and its numpy policy equals brax's policy on the dictionary
    observation (the critic's half ignored by the actor)."""
    from quadson_mjx import deploy
    from quadson_mjx.env import LocomotionEnv

    env_cfg = env_config(command_tracking=True)
    env_cfg.unlock()
    env_cfg.observation, env_cfg.asymmetric_critic = "sensors", True
    env_cfg.lock()
    env = LocomotionEnv(env_cfg)
    sizes = env.observation_size
    actor, critic = sizes["state"][0], sizes["privileged_state"][0]
    ppo_cfg = training.ppo_config("test")
    ppo_cfg.policy_hidden = (16, 8)
    (tmp_path / "config.json").write_text(
        json.dumps({"env": json.loads(to_json(env_cfg)), "ppo": json.loads(to_json(ppo_cfg)), "versions": {}})
    )
    normalizer, policy, value = training.params_template(sizes, env.action_size, ppo_cfg)
    keys = jax.random.split(jax.random.PRNGKey(11), 5)
    mean = {
        "state": jax.random.normal(keys[0], (actor,)),
        "privileged_state": jax.random.normal(keys[1], (critic,)),
    }
    std = {
        "state": 0.5 + jax.random.uniform(keys[2], (actor,)),
        "privileged_state": np.full(critic, 9.0, np.float32),
    }
    normalizer = normalizer.replace(mean=mean, std=std)
    policy = jax.tree.map(
        lambda p, k: p + 0.3 * jax.random.normal(k, p.shape), policy, _keys(policy, keys[3])
    )
    training.save_checkpoint(tmp_path, 1000, (normalizer, policy, value))
    out = export.export_run(tmp_path, tmp_path / "policy.npz")
    numpy_policy = export.load(out)
    assert numpy_policy.obs_size == actor and Spec.from_json(numpy_policy.meta["obs_spec"]) == env.obs_spec
    np.testing.assert_allclose(numpy_policy.mean, np.asarray(mean["state"]), rtol=0, atol=0)
    obs = np.asarray(jax.random.normal(keys[4], (32, actor)), np.float32)
    jax_policy, _, _, _ = training.load_policy(tmp_path)
    dict_obs = {"state": obs, "privileged_state": np.zeros((32, critic), np.float32)}
    want = np.asarray(jax.jit(jax_policy)(dict_obs, jax.random.PRNGKey(0))[0])
    np.testing.assert_allclose(numpy_policy(obs), want, rtol=1e-5, atol=1e-5)
    loop = deploy.DeployLoop(numpy_policy)  # a sensor-only policy: no velocity input
    assert not loop.needs_lin_vel and loop.config.observation == "sensors"


def test_a_run_trained_on_warp_exports_its_jax_model(run_dir, tmp_path):
    """A run trained with env.impl=warp (its config says so) exports as the same run on JAX would:
    the same model identity and env_config (the evaluation's physics, no Warp contact sensors),
    and the file records the implementation it trained on."""
    warp_run = tmp_path / "warp_run"
    shutil.copytree(run_dir, warp_run)
    config = json.loads((warp_run / "config.json").read_text())
    config["env"].update(impl="warp", terrain="rough")  # on the stones Warp's model has contact sensors
    (warp_run / "config.json").write_text(json.dumps(config))
    jax_run = tmp_path / "jax_run"
    shutil.copytree(warp_run, jax_run)
    config["env"]["impl"] = "jax"
    (jax_run / "config.json").write_text(json.dumps(config))
    got = _meta(export.export_run(warp_run, tmp_path / "w.npz"))
    want = _meta(export.export_run(jax_run, tmp_path / "j.npz"))
    assert got["trained_impl"] == "warp" and want["trained_impl"] == "jax"
    assert got["model"] == want["model"] and got["env_config"] == want["env_config"]
    assert got["env_config"]["impl"] == "jax" and got["env_config"]["terrain"] == "rough"
